"""Training checkpoints with orbax-checkpoint: atomic, pruned, checked against the run's config.

On-disk layout (an orbax `CheckpointManager` directory with step_prefix "step")
--------------------------------------------------------------------------------
  <directory>/
    step_<N>/                  one finalised checkpoint per saved training step N
      state/                   the state pytree (orbax StandardCheckpointHandler: arrays in
                               tensorstore/OCDBT, the tree structure in _METADATA; no pickle)
      config/metadata          the run's config, JSON
      info/metadata            JSON {"format": "mjx-form-checkpoint", "version": 1, "step": N,
                               "versions": {package: version, ...}}
      _CHECKPOINT_METADATA, commit_success.txt   orbax's bookkeeping
    step_<N>.orbax-checkpoint-tmp*/   a save in progress, or one killed midway

A save is written into the temporary directory and renamed to `step_<N>` once complete (orbax's
atomic rename on local file systems; a commit_success.txt marker on GCS), so unfinished saves
are never listed, restored or counted by `latest_step`. Saves are synchronous: `save` returns
once the checkpoint is final and older ones beyond `keep` are deleted. PRNG keys, both raw
uint32 `jax.random.PRNGKey`s and typed `jax.random.key`s, are stored as their uint32 data.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import platform
from typing import Any, Iterable

import jax
import numpy as np
import orbax.checkpoint as ocp

FORMAT = "mjx-form-checkpoint"
VERSION = 1
_PACKAGES = ("mjx-form", "jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "numpy",
             "mujoco", "mujoco-mjx")
_MISSING = object()


class CheckpointError(ValueError):
  """No usable checkpoint, or one that does not fit this run (`keys`: the dotted config keys
  that differ, where that is why; empty otherwise)."""

  def __init__(self, message: str, keys: tuple[str, ...] = ()):
    super().__init__(message)
    self.keys = tuple(keys)


def package_versions() -> dict[str, str]:
  """Python and the installed versions of the packages a checkpoint depends on."""
  versions = {"python": platform.python_version()}
  for name in _PACKAGES:
    try:
      versions[name] = importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
      pass
  return versions


def _manager(directory: str, keep: int | None = None) -> ocp.CheckpointManager:
  """A synchronous manager; read-only (creates and deletes nothing) unless `keep` is given."""
  read_only = keep is None
  options = ocp.CheckpointManagerOptions(
      max_to_keep=keep, step_prefix="step", enable_async_checkpointing=False,
      create=not read_only, read_only=read_only, save_interval_steps=0 if read_only else 1)
  handlers = {"state": ocp.StandardCheckpointHandler(), "config": ocp.JsonCheckpointHandler(),
              "info": ocp.JsonCheckpointHandler()}
  return ocp.CheckpointManager(directory, options=options, item_handlers=handlers)


def _json(config: dict, what: str = "config") -> dict:
  """`config` as it reads back from JSON (tuples become lists); ValueError if it cannot."""
  if not isinstance(config, dict):
    raise TypeError(f"{what} must be a dict, got {type(config).__name__}")
  try:
    return json.loads(json.dumps(config, allow_nan=False))
  except (TypeError, ValueError) as e:
    raise ValueError(f"{what} is not JSON-serialisable: {e}") from None


def save(directory, step: int, state, config: dict, keep: int = 2) -> str:
  """Saves `state` and `config` as training step `step`; keeps the newest `keep` checkpoints.

  Returns the checkpoint's path, `directory/step_<step>`. Raises CheckpointError if the directory
  already holds a checkpoint for `step` or a later one (start a fresh directory instead).
  """
  directory = os.fspath(directory)
  if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 0:
    raise ValueError(f"step must be a non-negative integer, got {step!r}")
  if isinstance(keep, bool) or not isinstance(keep, int) or keep < 1:
    raise ValueError(f"keep must be a positive integer, got {keep!r}")
  step = int(step)
  config = _json(config)
  info = dict(format=FORMAT, version=VERSION, step=step, versions=package_versions())
  with _manager(os.path.abspath(directory), keep) as mngr:
    latest = mngr.latest_step()
    if latest is not None and latest >= step:
      raise CheckpointError(f"{directory} already holds a checkpoint for step {latest} >= {step}; "
                            "resume from it or use a fresh directory")
    mngr.save(step, force=True, args=ocp.args.Composite(
        state=ocp.args.StandardSave(_flat(state)), config=ocp.args.JsonSave(config),
        info=ocp.args.JsonSave(info)))
    mngr.wait_until_finished()
    mngr.reload()  # a safety net: report success only once the step is final on disk
    if step not in mngr.all_steps():
      raise CheckpointError(f"saving step {step} to {directory} failed (see the log above)")
  return os.path.join(directory, f"step_{step}")


def latest_step(directory) -> int | None:
  """The newest finalised step in `directory`, or None if there is none (or no directory)."""
  directory = os.path.abspath(os.fspath(directory))
  if not os.path.isdir(directory):
    return None
  with _manager(directory) as mngr:
    return mngr.latest_step()


def _resolve_step(mngr: ocp.CheckpointManager, directory: str, step: int | None) -> int:
  steps = mngr.all_steps()
  if not steps:
    raise CheckpointError(f"no checkpoint in {directory}")
  if step is None:
    return max(steps)
  if step not in steps:
    raise CheckpointError(f"{directory} has no checkpoint for step {step} "
                          f"(it has steps {sorted(steps)})")
  return int(step)


def read_info(directory, step: int | None = None) -> dict[str, Any]:
  """{"step", "config", "versions", ...} of a checkpoint (default: the latest)."""
  directory = os.fspath(directory)
  if not os.path.isdir(directory):
    raise CheckpointError(f"no checkpoint in {directory} (no such directory)")
  with _manager(os.path.abspath(directory)) as mngr:
    step = _resolve_step(mngr, directory, step)
    items = mngr.restore(step, args=ocp.args.Composite(config=ocp.args.JsonRestore(),
                                                       info=ocp.args.JsonRestore()))
  return {**items["info"], "step": step, "config": items["config"]}


def _flatten_config(config: dict, prefix: str = "") -> dict[str, Any]:
  """Nested dicts as one level of dotted keys."""
  flat = {}
  for key, value in config.items():
    if isinstance(value, dict) and value:
      flat.update(_flatten_config(value, f"{prefix}{key}."))
    else:
      flat[f"{prefix}{key}"] = value
  return flat


def _show(value) -> str:
  if value is _MISSING:
    return "(unset)"
  return value if isinstance(value, str) else json.dumps(value)


def config_differences(stored: dict, config: dict, ignore: Iterable[str] = (),
                       added: dict[str, Any] | None = None) -> list[str]:
  """The (dotted) keys whose values differ between two configs, except those under `ignore`.

  `added`: settings introduced after `stored` may have been written, with the value that
  reproduces what ran before them; a stored config without such a key counts as having it.
  """
  a, b = _flatten_config(_json(stored)), _flatten_config(_json(config))
  for key, value in (added or {}).items():
    a.setdefault(key, value)
  ignore = tuple(ignore)
  ignored = lambda key: any(key == p or key.startswith(p + ".") for p in ignore)
  return [key for key in sorted(a.keys() | b.keys())
          if not ignored(key) and a.get(key, _MISSING) != b.get(key, _MISSING)]


def check_config(where: str, stored: dict, config: dict, ignore: Iterable[str] = (),
                 added: dict[str, Any] | None = None) -> None:
  """Raises CheckpointError naming the keys where `config` differs from `stored` (written
  in `where`), except those under `ignore` (`added`: see `config_differences`)."""
  keys = config_differences(stored, config, ignore, added)
  if keys:
    a, b = _flatten_config(_json(stored)), _flatten_config(_json(config))
    was = ", ".join(f"{k}={_show(a.get(k, _MISSING))}" for k in keys)
    now = ", ".join(f"{k}={_show(b.get(k, _MISSING))}" for k in keys)
    raise CheckpointError(f"{where} was written with {was}; this run has {now}", keys)


def _path_name(path) -> str:
  parts = []
  for k in path:
    for attr in ("key", "name", "idx"):
      if hasattr(k, attr):
        parts.append(str(getattr(k, attr)))
        break
    else:
      parts.append(str(k))
  return "/".join(parts) or "(root)"


def _is_empty(x) -> bool:
  return hasattr(x, "shape") and 0 in tuple(x.shape)


def _flat(tree) -> dict:
  """{'a/b/c': leaf} of the leaves with data. Zero-size arrays (e.g. MJX's `act` for a model
  without actuator state) are not stored (orbax cannot); `restore` takes them from the target
  (`_empty_like`)."""
  return {_path_name(p): x for p, x in jax.tree_util.tree_flatten_with_path(tree)[0]
          if not _is_empty(x)}


def _abstract(x):
  """Target leaf -> what orbax restores into: jax arrays keep the target's sharding."""
  if isinstance(x, (jax.ShapeDtypeStruct, jax.Array)):
    sharding = x.sharding
    if sharding is None:  # abstract leaf without a sharding: the default device, like jnp
      sharding = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding)
  return x  # numpy arrays and Python scalars are restored as such


def _empty_like(x):
  """A zero-size target leaf as restored: an abstract one becomes an array with its sharding."""
  if isinstance(x, jax.ShapeDtypeStruct):
    return jax.device_put(np.zeros(x.shape, x.dtype), _abstract(x).sharding)
  return x


def _stored_form(x) -> tuple[tuple, np.dtype | None]:
  """(shape, dtype) a target leaf has on disk; dtype None for Python scalars (not checked)."""
  if not hasattr(x, "dtype"):
    return (), None
  shape, dtype = tuple(np.shape(x)), x.dtype
  if jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key):
    data = jax.eval_shape(jax.random.key_data, jax.ShapeDtypeStruct(shape, dtype))
    return tuple(data.shape), np.dtype(data.dtype)
  return shape, np.dtype(dtype)


def _describe(shape, dtype) -> str:
  return f"{dtype} {list(shape)}" if dtype is not None else f"scalar {list(shape)}"


def _check_tree(where: str, stored_tree, target) -> None:
  is_meta = lambda x: hasattr(x, "shape") and hasattr(x, "dtype")
  stored = {_path_name(p): m for p, m in
            jax.tree_util.tree_flatten_with_path(stored_tree, is_leaf=is_meta)[0]}
  ours = _flat(target)
  problems = [f"leaf {name} is missing from the checkpoint" for name in ours if name not in stored]
  problems += [f"the checkpoint has a leaf {name} the target lacks"
               for name in stored if name not in ours]
  for name, x in ours.items():
    if name in stored:
      shape, dtype = _stored_form(x)
      meta = stored[name]
      got_shape, got_dtype = tuple(meta.shape), np.dtype(meta.dtype)
      if got_shape != shape or (dtype is not None and got_dtype != dtype):
        problems.append(f"leaf {name} is {_describe(got_shape, got_dtype)} in the checkpoint, "
                        f"{_describe(shape, dtype)} in the target")
  if problems:
    more = f" (and {len(problems) - 1} more differences)" if len(problems) > 1 else ""
    raise CheckpointError(f"checkpoint {where} does not match the target state: "
                          f"{problems[0]}{more}")


def restore(directory, target, config: dict, step: int | None = None, *,
            ignore: Iterable[str] = (), added: dict[str, Any] | None = None):
  """Restores step `step` (default: the latest) of `directory` into the structure of `target`.

  `target` is a pytree of arrays or jax.ShapeDtypeStructs: the result has its structure, shapes,
  dtypes and shardings (abstract leaves without a sharding land on the default device). The
  stored config must equal `config` except for the (dotted) keys under `ignore` (and keys in
  `added` it lacks, where `config` has their value: see `config_differences`). Raises
  CheckpointError naming the differing config keys or the first differing leaf, or when there
  is no checkpoint.
  """
  directory = os.fspath(directory)
  if not os.path.isdir(directory):
    raise CheckpointError(f"no checkpoint in {directory} (no such directory)")
  with _manager(os.path.abspath(directory)) as mngr:
    step = _resolve_step(mngr, directory, step)
    where = os.path.join(directory, f"step_{step}")
    stored = mngr.restore(step, args=ocp.args.Composite(config=ocp.args.JsonRestore()))["config"]
    check_config(f"checkpoint in {directory}", stored, config, ignore, added)
    metadata = mngr.item_metadata(step)["state"]
    _check_tree(where, getattr(metadata, "tree", metadata), target)
    abstract = {name: _abstract(x) for name, x in _flat(target).items()}
    restored = mngr.restore(step, args=ocp.args.Composite(
        state=ocp.args.StandardRestore(abstract)))["state"]
  paths, treedef = jax.tree_util.tree_flatten_with_path(target)
  return jax.tree_util.tree_unflatten(treedef, [
      _empty_like(x) if _is_empty(x) else restored[_path_name(p)] for p, x in paths])
