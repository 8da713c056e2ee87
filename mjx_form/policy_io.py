"""Trained policies on disk: one small `.npz` file, no pickle (for committing experts to git).

File format ("mjx-form-policy", version 1)
------------------------------------------
A zip archive written by `numpy.savez_compressed`, read back with `numpy.load(path,
allow_pickle=False)`. Entries:

  <a>/<b>/.../<leaf>  one array per leaf of the saved nested dict, keyed by its '/'-joined path,
                      e.g. "params/Dense_0/kernel", or "normalizer/mean" when the caller stores
                      extra array groups next to the parameters. Dtypes are kept as given.
  metadata            a UTF-8 JSON object, stored as a 1-d uint8 array of its bytes.

The metadata object holds the caller's keys, which include

  task                the task name, e.g. "walker_walk"
  observation_size    the flat observation size D
  action_size         the action size A
  observation_layout  optional [[name, size], ...] summing to D

(and whatever else describes the policy: network settings, normaliser, training steps, return),
plus the keys written here:

  format              "mjx-form-policy"
  version             1
  sha256              hex SHA-256 over the arrays, in sorted name order: for each, the UTF-8
                      header "<name>:<dtype.str>:<d0>,<d1>,...\\n" followed by its bytes in C
                      order (the convention of `mjx_form.demos`).

Files are written atomically (a temporary file in the same directory, then a rename or a no-clobber
hard link); `load_policy` checks all of the above and raises `PolicyFileError`.
"""

from __future__ import annotations

import os
from typing import Any, Mapping

import numpy as np

from mjx_form import npz_files

FORMAT = "mjx-form-policy"
VERSION = 1
_RESERVED = ("format", "version", "sha256")
_REQUIRED = ("task", "observation_size", "action_size")


class PolicyFileError(ValueError):
  """A policy file is missing, corrupt, or does not fit this run."""


def _flatten(tree, prefix: str = "") -> dict[str, np.ndarray]:
  """A nested dict of arrays as {"a/b/leaf": array}."""
  if not isinstance(tree, Mapping) or not tree:
    raise ValueError(f"{prefix or 'params'} must be a non-empty dict of arrays")
  flat = {}
  for key, value in tree.items():
    if not isinstance(key, str) or not key or "/" in key:
      raise ValueError(f"key {key!r} under {prefix or 'params'} must be a non-empty str "
                       "without '/'")
    name = f"{prefix}{key}"
    if isinstance(value, Mapping):
      flat.update(_flatten(value, name + "/"))
    else:
      array = np.asarray(value)
      if array.dtype.kind not in "biuf":
        raise ValueError(f"{name} has dtype {array.dtype}; only bool, int and float arrays")
      flat[name] = array
  return flat


def _unflatten(flat: dict[str, np.ndarray]) -> dict[str, Any]:
  """{"a/b/leaf": array} as a nested dict; ValueError if the names do not form a tree."""
  tree: dict[str, Any] = {}
  for name, array in flat.items():
    *parents, leaf = name.split("/")
    node = tree
    for key in parents:
      node = node.setdefault(key, {})
      if not isinstance(node, dict):
        raise ValueError(f"entry {name} lies under the array {key}")
    if not all(parents + [leaf]) or leaf in node:
      raise ValueError(f"entry {name} is not a leaf of a nested dict")
    node[leaf] = array
  return tree


def checksum(arrays: dict[str, np.ndarray]) -> str:
  """The `sha256` metadata field of the flattened arrays (see the module docstring)."""
  return npz_files.digest(arrays, sorted(arrays))


def _is_size(value) -> bool:
  return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def save_policy(path, params, metadata: dict, overwrite: bool = False) -> str:
  """Writes `params` (a nested dict of arrays) and `metadata` to `path`; returns the path.

  `metadata` needs "task" (str), "observation_size" and "action_size" (positive ints); other
  JSON-serialisable keys are kept as given. Raises FileExistsError if `path` exists and not
  `overwrite`, ValueError on bad params or metadata.
  """
  path = os.fspath(path)
  arrays = _flatten(params)
  if "metadata" in arrays:
    raise ValueError("a top-level leaf may not be called 'metadata'")
  meta = dict(metadata)
  missing = [key for key in _REQUIRED if key not in meta]
  if missing:
    raise ValueError(f"metadata needs {missing}")
  if not isinstance(meta["task"], str):
    raise ValueError(f"metadata 'task' must be a str, got {meta['task']!r}")
  for key in ("observation_size", "action_size"):
    if not _is_size(meta[key]):
      raise ValueError(f"metadata {key!r} must be a positive int, got {meta[key]!r}")
  if "observation_layout" in meta:
    meta["observation_layout"] = npz_files.layout_pairs(meta["observation_layout"])
    total = sum(size for _, size in meta["observation_layout"])
    if total != meta["observation_size"]:
      raise ValueError(f"observation_layout sums to {total}, "
                       f"observation_size is {meta['observation_size']}")
  reserved = [key for key in _RESERVED if key in meta]
  if reserved:
    raise ValueError(f"metadata keys {reserved} are written by save_policy")
  meta.update(format=FORMAT, version=VERSION, sha256=checksum(arrays))
  return npz_files.write(path, arrays, meta, overwrite=overwrite, compress=True)


def _read(path: str) -> tuple[dict[str, np.ndarray], dict]:
  """The arrays and metadata of a file, checked against each other."""
  def fail(problem):
    return PolicyFileError(f"{path}: {problem}")

  entries = npz_files.read(path, "policy file", fail)
  raw = entries.pop("metadata", None)
  if raw is None:
    raise fail("no metadata entry")
  meta = npz_files.metadata(raw, fail, FORMAT, VERSION)
  if not isinstance(meta.get("task"), str):
    raise fail(f"metadata 'task' is {meta.get('task')!r}, expected a str")
  for key in ("observation_size", "action_size"):
    if not _is_size(meta.get(key)):
      raise fail(f"metadata {key!r} is {meta.get(key)!r}, expected a positive int")
  if not entries:
    raise fail("no arrays")
  if checksum(entries) != meta.get("sha256"):
    raise fail("checksum mismatch: the arrays are not the ones the file was written with")
  return entries, meta


def load_policy(path, *, task: str | None = None, observation_size: int | None = None,
                action_size: int | None = None,
                observation_layout=None) -> tuple[dict[str, Any], dict[str, Any]]:
  """Reads and validates a policy file: (params as a nested dict of numpy arrays, metadata).

  `task`, `observation_size`, `action_size` and `observation_layout` (dict or [name, size]
  pairs), when given, must match the file's. Raises `PolicyFileError` naming the file.
  """
  path = os.fspath(path)
  arrays, meta = _read(path)
  if task is not None and meta["task"] != task:
    raise PolicyFileError(f"{path}: the policy is for {meta['task']}, this run is {task}")
  for key, ours in (("observation_size", observation_size), ("action_size", action_size)):
    if ours is not None and meta[key] != ours:
      what = key.replace("_", " ")
      raise PolicyFileError(f"{path}: the policy's {what} is {meta[key]}, this run's is {ours}")
  if observation_layout is not None:
    ours = npz_files.layout_pairs(observation_layout)
    if meta.get("observation_layout") != ours:
      raise PolicyFileError(f"{path}: the policy's observation layout "
                            f"{meta.get('observation_layout')} does not match this run's {ours}")
  try:
    params = _unflatten(arrays)
  except ValueError as e:
    raise PolicyFileError(f"{path}: {e}") from None
  return params, meta
