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
                      order (the convention of `mjx_form.files.demos`).

Files are written atomically (a temporary file in the same directory, then a rename or a no-clobber
hard link); `load_policy` checks all of the above and raises `PolicyFileError`.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from mjx_form.files import npz_files

FORMAT = "mjx-form-policy"
VERSION = 1
_SIZES = ("observation_size", "action_size")  # required positive ints, beside "task"


class PolicyFileError(ValueError):
  """A policy file is missing, corrupt, or does not fit this run."""


def checksum(arrays: dict[str, np.ndarray]) -> str:
  """The `sha256` metadata field of the flattened arrays (see the module docstring)."""
  return npz_files.tree_checksum(arrays)


def save_policy(path, params, metadata: dict, overwrite: bool = False) -> str:
  """Writes `params` (a nested dict of arrays) and `metadata` to `path`; returns the path.

  `metadata` needs "task" (str), "observation_size" and "action_size" (positive ints); other
  JSON-serialisable keys are kept as given. Raises FileExistsError if `path` exists and not
  `overwrite`, ValueError on bad params or metadata.
  """
  return npz_files.save_tree(path, params, metadata, FORMAT, VERSION, _SIZES,
                             overwrite=overwrite)


def _read(path: str) -> tuple[dict[str, np.ndarray], dict]:
  """The arrays and metadata of a file, checked against each other."""
  return npz_files.read_tree(path, "policy file", FORMAT, VERSION, _SIZES,
                             lambda problem: PolicyFileError(f"{path}: {problem}"))


def load_policy(path, *, task: str | None = None, observation_size: int | None = None,
                action_size: int | None = None,
                observation_layout=None) -> tuple[dict[str, Any], dict[str, Any]]:
  """Reads and validates a policy file: (params as a nested dict of numpy arrays, metadata).

  `task`, `observation_size`, `action_size` and `observation_layout` (dict or [name, size]
  pairs), when given, must match the file's. Raises `PolicyFileError` naming the file.
  """
  path = os.fspath(path)
  arrays, meta = _read(path)
  fail = lambda problem: PolicyFileError(f"{path}: {problem}")
  npz_files.check_fits(meta, "policy", fail, task=task, observation_layout=observation_layout,
                       observation_size=observation_size, action_size=action_size)
  return npz_files.unflatten_tree(arrays, fail), meta
