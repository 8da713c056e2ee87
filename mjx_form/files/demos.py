"""Expert demonstrations on disk: one `.npz` file, no pickle.

File format ("mjx-form-demonstrations", version 1)
--------------------------------------------------
A zip archive written by `numpy.savez` (uncompressed, one `.npy` member per entry), read back
with `numpy.load(path, allow_pickle=False)`. Entries, and nothing else:

  observations  float32 (little-endian '<f4'), shape [K, T+1, D]: K episodes of T steps, each
                with its T+1 observations (the first one is the reset observation). D is the
                flat observation size, the elements concatenated in `observation_layout` order.
  actions       float32 '<f4', shape [K, T, A]; present if and only if `has_actions` is true.
                actions[k, t] was applied to observations[k, t] and led to observations[k, t+1].
  metadata      a UTF-8 JSON object, stored as a 1-d uint8 array of its bytes (readers also accept
                a 0-d unicode array).

All arrays are finite (no NaN or inf). The metadata object has these keys:

  format              "mjx-form-demonstrations"
  version             1
  task                the task name, e.g. "walker_walk"
  observation_layout  [[name, size], ...]: the observation elements in flattening order
  observation_size    D, the sum of the layout's sizes
  action_size         A, or null when there are no actions
  episodes            K >= 1
  steps               T >= 1
  physics             the physics mode the demonstrations were recorded with, e.g. "parity"
  expert              a JSON object describing the expert and the recording settings ({} if none)
  has_actions         true or false
  sha256              hex SHA-256 over the arrays: for each of "observations" then (if present)
                      "actions", the UTF-8 header "<name>:<dtype.str>:<d0>,<d1>,...\\n"
                      (e.g. "observations:<f4:10,1001,24\\n") followed by the array's bytes in
                      C order.

The caller may add further keys to the metadata (JSON values); they are kept as given.
Files are written atomically: a temporary file in the same directory, fsync, then `os.replace`
(with overwrite=True) or a hard link, which fails rather than replace a file that exists.
`load_demonstrations` checks all of the above and raises `DemonstrationError` naming the file
and the problem.
"""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np

from mjx_form.files import npz_files

FORMAT = "mjx-form-demonstrations"
VERSION = 1
_ARRAYS = ("observations", "actions")
_COMPUTED = ("observation_size", "action_size", "episodes", "steps", "has_actions")
_RESERVED = ("format", "version", "sha256")


class DemonstrationError(ValueError):
  """A demonstration file is missing, corrupt, or does not fit this run."""


class Demonstrations(NamedTuple):
  observations: np.ndarray         # [K, T+1, D] float32
  actions: np.ndarray | None       # [K, T, A] float32, or None
  metadata: dict[str, Any]         # the file's metadata object (see the module docstring)


def checksum(arrays: dict[str, np.ndarray]) -> str:
  """The `sha256` metadata field of `arrays` (see the module docstring)."""
  return npz_files.digest(arrays, _ARRAYS)


def save_demonstrations(path, observations, actions=None, *, metadata: dict,
                        overwrite: bool = False) -> str:
  """Writes observations [K, T+1, D] (and actions [K, T, A]) to `path`; returns the path.

  `metadata` needs "task", "observation_layout" (dict or [name, size] pairs) and "physics";
  "expert" (a dict) and other JSON-serialisable keys are optional. Raises FileExistsError if
  `path` exists and not `overwrite`, ValueError on inconsistent or non-finite data.
  """
  path = os.fspath(path)
  obs = np.asarray(observations, dtype="<f4")
  if obs.ndim != 3 or obs.shape[0] < 1 or obs.shape[1] < 2:
    raise ValueError(f"observations must be [K, T+1, D] with K >= 1, T >= 1; "
                     f"got shape {obs.shape}")
  k, t, d = obs.shape[0], obs.shape[1] - 1, obs.shape[2]
  arrays = {"observations": obs}
  if actions is not None:
    act = np.asarray(actions, dtype="<f4")
    if act.ndim != 3 or act.shape[:2] != (k, t):
      raise ValueError(f"actions must be [K, T, A] = [{k}, {t}, A]; got shape {act.shape}")
    arrays["actions"] = act
  for name, a in arrays.items():
    if not np.all(np.isfinite(a)):
      raise ValueError(f"{name} contain non-finite values")

  meta = dict(metadata)
  for key in ("task", "observation_layout", "physics"):
    if key not in meta:
      raise ValueError(f"metadata needs {key!r}")
  if not isinstance(meta["task"], str) or not isinstance(meta["physics"], str):
    raise ValueError("metadata 'task' and 'physics' must be strings")
  if not isinstance(meta.setdefault("expert", {}), dict):
    raise ValueError("metadata 'expert' must be a dict")
  bad = [key for key in _RESERVED if key in meta]
  if bad:
    raise ValueError(f"metadata keys {bad} are written by save_demonstrations")
  meta["observation_layout"] = npz_files.layout_pairs(meta["observation_layout"])
  layout_size = sum(size for _, size in meta["observation_layout"])
  if layout_size != d:
    raise ValueError(f"observation_layout sums to {layout_size} but observations have D = {d}")
  has_actions = actions is not None
  computed = dict(observation_size=d, action_size=act.shape[2] if has_actions else None,
                  episodes=k, steps=t, has_actions=has_actions)
  for key, value in computed.items():
    if key in meta and meta[key] != value:
      raise ValueError(f"metadata {key}={meta[key]!r} disagrees with the arrays ({value!r})")
  meta.update(computed, format=FORMAT, version=VERSION, sha256=checksum(arrays))
  return npz_files.write(path, arrays, meta, overwrite=overwrite)


def _read(path: str) -> tuple[dict, dict[str, np.ndarray]]:
  """The metadata and arrays of a file, checked against each other."""
  def fail(problem):
    return DemonstrationError(f"{path}: {problem}")

  entries = npz_files.read(path, "demonstration file", fail)
  unknown = sorted(set(entries) - {"metadata", *_ARRAYS})
  if unknown or "metadata" not in entries or "observations" not in entries:
    raise fail(f"entries {sorted(entries)}; expected metadata, observations and optionally actions")
  meta = npz_files.metadata(entries.pop("metadata"), fail, FORMAT, VERSION, accept_unicode=True)

  types = dict(task=str, observation_layout=list, observation_size=int, episodes=int, steps=int,
               physics=str, expert=dict, has_actions=bool, sha256=str)
  for key, kind in types.items():
    value = meta.get(key)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
      raise fail(f"metadata {key!r} is {value!r}, expected a {kind.__name__}")
  try:
    meta["observation_layout"] = npz_files.layout_pairs(meta["observation_layout"])
  except ValueError as e:
    raise fail(f"bad metadata: {e}") from None
  layout_size = sum(size for _, size in meta["observation_layout"])
  if layout_size != meta["observation_size"]:
    raise fail(f"observation_layout sums to {layout_size}, "
               f"observation_size is {meta['observation_size']}")

  k, t, d, a = meta["episodes"], meta["steps"], meta["observation_size"], meta.get("action_size")
  if meta["has_actions"] != ("actions" in entries):
    has = "has" if "actions" in entries else "has no"
    raise fail(f"has_actions is {meta['has_actions']} but the file {has} actions")
  expected = {"observations": (k, t + 1, d)}
  if meta["has_actions"]:
    if isinstance(a, bool) or not isinstance(a, int):
      raise fail(f"metadata 'action_size' is {a!r}, expected an int")
    expected["actions"] = (k, t, a)
  elif a is not None:
    raise fail(f"metadata 'action_size' is {a!r} but the file has no actions")
  for name, shape in expected.items():
    arr = entries[name]
    if arr.dtype != np.dtype("<f4") or arr.shape != shape:
      raise fail(f"{name} are {arr.dtype} {list(arr.shape)}, "
                 f"the metadata says float32 {list(shape)}")
  if checksum(entries) != meta["sha256"]:
    raise fail("checksum mismatch: the arrays are not the ones the file was written with")
  for name, arr in entries.items():
    if not np.all(np.isfinite(arr)):
      raise fail(f"{name} contain non-finite values")
  return meta, entries


def load_demonstrations(path, *, task: str | None = None, observation_size: int | None = None,
                        observation_layout=None, need_actions: bool = False) -> Demonstrations:
  """Reads and validates a demonstration file, and checks it fits this run.

  `task`, `observation_size` and `observation_layout` (dict or [name, size] pairs), when given,
  must match the file's; `need_actions` requires actions. Raises `DemonstrationError`.
  """
  path = os.fspath(path)
  meta, arrays = _read(path)
  if task is not None and meta["task"] != task:
    raise DemonstrationError(f"{path}: demonstrations are for {meta['task']}, this run is {task}")
  if observation_size is not None and meta["observation_size"] != observation_size:
    raise DemonstrationError(f"{path}: observation size {meta['observation_size']} does not match "
                             f"this run's {observation_size}")
  if observation_layout is not None:
    ours = npz_files.layout_pairs(observation_layout)
    if meta["observation_layout"] != ours:
      raise DemonstrationError(f"{path}: observation layout {meta['observation_layout']} does not "
                               f"match this run's {ours}")
  if need_actions and not meta["has_actions"]:
    raise DemonstrationError(f"{path}: this run needs actions, the demonstrations have none "
                             f"(scripts/make_demos.py --actions records them)")
  return Demonstrations(arrays["observations"], arrays.get("actions"), meta)
