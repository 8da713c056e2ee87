"""What the project's pickle-free file formats share (mjx_form.files.demos,
mjx_form.files.policy_io): named arrays plus a JSON metadata object in one `.npz`, a sha256 over
the arrays, atomic no-clobber writes, and reading with `allow_pickle=False` into clear errors."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
import zlib
from typing import Callable, Iterable, Mapping

import numpy as np


def digest(arrays: dict[str, np.ndarray], names: Iterable[str]) -> str:
  """sha256 over `names` (those present, in that order): for each, the UTF-8 header
  "<name>:<dtype.str>:<d0>,<d1>,...\\n" followed by the array's bytes in C order."""
  h = hashlib.sha256()
  for name in names:
    if name in arrays:
      a = arrays[name]
      h.update(f"{name}:{a.dtype.str}:{','.join(map(str, a.shape))}\n".encode())
      h.update(np.ascontiguousarray(a).tobytes())
  return h.hexdigest()


def layout_pairs(layout) -> list[list]:
  """An observation layout (dict name -> size, or sequence of (name, size)) as
  [[name, size], ...]; ValueError unless every entry is [str, positive int]."""
  items = layout.items() if isinstance(layout, dict) else layout
  try:
    pairs = [[name, size] for name, size in items]
  except (TypeError, ValueError):
    raise ValueError("observation_layout must be a dict or a list of [name, size] pairs, "
                     f"got {layout!r}") from None
  for name, size in pairs:
    if (not isinstance(name, str) or isinstance(size, bool)
        or not isinstance(size, (int, np.integer)) or size < 1):
      raise ValueError(f"observation_layout entry [{name!r}, {size!r}] is not [str, positive int]")
  return [[name, int(size)] for name, size in pairs]


def write(path: str, arrays: dict[str, np.ndarray], metadata: dict, *, overwrite: bool,
          compress: bool = False) -> str:
  """Writes `arrays` and `metadata` (as a `metadata` entry of UTF-8 JSON bytes) to `path`.

  Atomic: a temporary file in the same directory, fsync, then `os.replace` (overwrite) or a
  hard link, which fails rather than replace a file that appeared meanwhile. Raises
  FileExistsError if `path` exists and not `overwrite`, ValueError if `metadata` is not JSON.
  """
  try:
    text = json.dumps(metadata, sort_keys=True, allow_nan=False)
  except (TypeError, ValueError) as e:
    raise ValueError(f"metadata is not JSON-serialisable: {e}") from None
  entries = {**arrays, "metadata": np.frombuffer(text.encode("utf-8"), dtype=np.uint8)}
  if not overwrite and os.path.exists(path):
    raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
  directory = os.path.dirname(os.path.abspath(path))
  fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(path)}.", suffix=".tmp")
  try:
    with os.fdopen(fd, "wb") as f:
      (np.savez_compressed if compress else np.savez)(f, allow_pickle=False, **entries)
      f.flush()
      os.fsync(f.fileno())
    if overwrite:
      os.replace(tmp, path)
    else:
      try:
        os.link(tmp, path)  # atomic and never clobbers: fails if `path` appeared meanwhile
      except FileExistsError:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it") from None
      except OSError:  # no hard links on this file system: checked above, replace
        os.replace(tmp, path)
      else:
        os.unlink(tmp)
  except BaseException:
    if os.path.exists(tmp):
      os.unlink(tmp)
    raise
  _fsync_directory(directory)
  return path


def _fsync_directory(directory: str) -> None:
  try:
    fd = os.open(directory, os.O_RDONLY)
  except OSError:
    return
  try:
    os.fsync(fd)
  except OSError:
    pass
  finally:
    os.close(fd)


def read(path: str, what: str, fail: Callable[[str], Exception]) -> dict[str, np.ndarray]:
  """All entries of the `.npz` at `path`, loaded without pickle; raises `fail(problem)` for a
  missing file (`what` names the kind, e.g. "policy file") or one that is not a readable npz."""
  if not os.path.isfile(path):
    raise fail(f"no such {what}")
  try:
    npz = np.load(path, allow_pickle=False)
  except (zipfile.BadZipFile, zlib.error, OSError, ValueError, EOFError, KeyError) as e:
    npz, error = None, e
  if npz is not None and not isinstance(npz, np.lib.npyio.NpzFile):  # a plain .npy array
    raise fail("not an .npz archive")
  if npz is not None:
    try:
      with npz:
        return {name: npz[name] for name in npz.files}
    except (zipfile.BadZipFile, zlib.error, OSError, ValueError, EOFError, KeyError) as e:
      error = e
  problem = "not a readable .npz archive of plain arrays (truncated, corrupt or pickled?)"
  raise fail(f"{problem}: {error}")


def metadata(raw: np.ndarray, fail: Callable[[str], Exception], fmt: str, version: int,
             accept_unicode: bool = False) -> dict:
  """The JSON object of a `metadata` entry (uint8 bytes; a 0-d unicode array too when
  `accept_unicode`), checked to be of format `fmt` and `version`; else raises `fail(problem)`."""
  try:
    if raw.dtype == np.uint8 and raw.ndim == 1:
      meta = json.loads(raw.tobytes().decode("utf-8"))
    elif accept_unicode and raw.dtype.kind == "U" and raw.ndim == 0:
      meta = json.loads(str(raw))
    else:
      raise ValueError(f"metadata entry has dtype {raw.dtype} and shape {raw.shape}")
  except ValueError as e:
    raise fail(f"unreadable metadata: {e}") from None
  if not isinstance(meta, dict):
    raise fail("metadata is not a JSON object")
  if meta.get("format") != fmt:
    raise fail(f"unknown format {meta.get('format')!r} (expected {fmt!r})")
  if meta.get("version") != version:
    raise fail(f"unsupported format version {meta.get('version')!r} (this reader knows {version})")
  return meta


# --- nested parameter trees (policies, effect models) -------------------------------------

_RESERVED = ("format", "version", "sha256")


def flatten_tree(tree, prefix: str = "") -> dict[str, np.ndarray]:
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
      flat.update(flatten_tree(value, name + "/"))
    else:
      array = np.asarray(value)
      if array.dtype.kind not in "biuf":
        raise ValueError(f"{name} has dtype {array.dtype}; only bool, int and float arrays")
      flat[name] = array
  return flat


def unflatten_tree(flat: dict[str, np.ndarray], fail: Callable[[str], Exception]) -> dict:
  """{"a/b/leaf": array} as a nested dict; raises `fail(problem)` if the names form no tree."""
  tree: dict = {}
  for name, array in flat.items():
    *parents, leaf = name.split("/")
    node = tree
    for key in parents:
      node = node.setdefault(key, {})
      if not isinstance(node, dict):
        raise fail(f"entry {name} lies under the array {key}")
    if not all(parents + [leaf]) or leaf in node:
      raise fail(f"entry {name} is not a leaf of a nested dict")
    node[leaf] = array
  return tree


def tree_checksum(arrays: dict[str, np.ndarray]) -> str:
  """sha256 of flattened tree arrays, in sorted name order (see `digest`)."""
  return digest(arrays, sorted(arrays))


def _is_size(value) -> bool:
  return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def save_tree(path, tree, metadata: dict, fmt: str, version: int, sizes: Iterable[str], *,
              overwrite: bool) -> str:
  """Writes a nested dict of arrays and `metadata` (compressed) as format `fmt`.

  `metadata` needs "task" (str) and each key of `sizes` (positive ints); an
  "observation_layout" must sum to its "observation_size". Adds format, version and sha256.
  """
  path = os.fspath(path)
  arrays = flatten_tree(tree)
  if "metadata" in arrays:
    raise ValueError("a top-level leaf may not be called 'metadata'")
  meta = dict(metadata)
  missing = [key for key in ("task", *sizes) if key not in meta]
  if missing:
    raise ValueError(f"metadata needs {missing}")
  if not isinstance(meta["task"], str):
    raise ValueError(f"metadata 'task' must be a str, got {meta['task']!r}")
  for key in sizes:
    if not _is_size(meta[key]):
      raise ValueError(f"metadata {key!r} must be a positive int, got {meta[key]!r}")
  if "observation_layout" in meta:
    meta["observation_layout"] = layout_pairs(meta["observation_layout"])
    total = sum(size for _, size in meta["observation_layout"])
    if total != meta["observation_size"]:
      raise ValueError(f"observation_layout sums to {total}, "
                       f"observation_size is {meta['observation_size']}")
  reserved = [key for key in _RESERVED if key in meta]
  if reserved:
    raise ValueError(f"metadata keys {reserved} are written by the file writer")
  meta.update(format=fmt, version=version, sha256=tree_checksum(arrays))
  return write(path, arrays, meta, overwrite=overwrite, compress=True)


def read_tree(path: str, what: str, fmt: str, version: int, sizes: Iterable[str],
              fail: Callable[[str], Exception]) -> tuple[dict[str, np.ndarray], dict]:
  """The flat arrays and metadata of a `save_tree` file, checked against each other."""
  entries = read(path, what, fail)
  raw = entries.pop("metadata", None)
  if raw is None:
    raise fail("no metadata entry")
  meta = metadata(raw, fail, fmt, version)
  if not isinstance(meta.get("task"), str):
    raise fail(f"metadata 'task' is {meta.get('task')!r}, expected a str")
  for key in sizes:
    if not _is_size(meta.get(key)):
      raise fail(f"metadata {key!r} is {meta.get(key)!r}, expected a positive int")
  if not entries:
    raise fail("no arrays")
  if tree_checksum(entries) != meta.get("sha256"):
    raise fail("checksum mismatch: the arrays are not the ones the file was written with")
  return entries, meta


def check_fits(meta: dict, noun: str, fail: Callable[[str], Exception], *,
               task: str | None = None, observation_layout=None, **sizes) -> None:
  """Raises `fail(problem)` where the file's task, sizes or observation layout (those given)
  differ from this run's; `noun` names the file's content ("policy", "demonstrator")."""
  if task is not None and meta["task"] != task:
    raise fail(f"the {noun} is for {meta['task']}, this run is {task}")
  for key, ours in sizes.items():
    if ours is not None and meta.get(key) != ours:
      raise fail(f"the {noun}'s {key.replace('_', ' ')} is {meta.get(key)}, this run's is "
                 f"{ours}")
  if observation_layout is not None:
    ours = layout_pairs(observation_layout)
    if meta.get("observation_layout") != ours:
      raise fail(f"the {noun}'s observation layout {meta.get('observation_layout')} does not "
                 f"match this run's {ours}")
