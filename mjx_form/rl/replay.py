"""An on-device ring buffer of unrolls, as pure functions over a `ReplayState`.

The storage is a pytree whose leaves are [capacity, ...] arrays, typically placed with the
mesh's batch sharding (axis 0 split over devices); `position` and `size` are replicated int32
scalars. Every operation has global semantics (a scatter / gather with explicit indices), so
results do not depend on how many devices the storage is sharded over. All argument checks run
at trace time (shapes, dtypes and structures are static), so the functions work inside `jit`.

  state = replay.init(example_unroll, capacity=4096, sharding=mesh_lib.batch_sharding(mesh))
  state = replay.insert(state, unrolls)          # unrolls: leaves [N, ...], N <= capacity
  batch = replay.sample(state, key, 256)         # leaves [256, ...], drawn from written slots
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec, Sharding


class ReplayState(NamedTuple):
  data: Any            # pytree of [capacity, ...] arrays
  position: jax.Array  # int32 []: the slot the next unroll is written to
  size: jax.Array      # int32 []: number of written slots, at most capacity


def capacity(state: ReplayState) -> int:
  """The number of slots (static)."""
  return jax.tree.leaves(state.data)[0].shape[0]


def _spec(x) -> jax.ShapeDtypeStruct:
  """Shape and (canonical) dtype of an array, a ShapeDtypeStruct or a Python/NumPy scalar."""
  if not (hasattr(x, "shape") and hasattr(x, "dtype")):
    x = np.asarray(x)
  return jax.ShapeDtypeStruct(tuple(x.shape), jax.dtypes.canonicalize_dtype(x.dtype))


def _positive_int(value, name: str) -> int:
  if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
    raise ValueError(f"{name} must be a positive integer, got {value!r}")
  return int(value)


def _replicated_like(sharding: Sharding) -> Sharding:
  if isinstance(sharding, NamedSharding):
    return NamedSharding(sharding.mesh, PartitionSpec())
  devices = sorted(sharding.device_set, key=lambda d: d.id)
  return NamedSharding(Mesh(np.asarray(devices), ("replica",)), PartitionSpec())


def init(example, capacity: int, sharding: Sharding | None = None) -> ReplayState:
  """An empty buffer of `capacity` slots shaped like `example` (one unroll, no leading axis).

  With `sharding` (e.g. `mjx_form.mesh.batch_sharding(mesh)`), every storage leaf [capacity, ...] is
  placed with it and `position`/`size` are replicated over the same devices.
  """
  capacity = _positive_int(capacity, "capacity")
  specs = jax.tree.map(_spec, example)
  leaves = jax.tree.leaves(specs)
  if not leaves:
    raise ValueError("example has no array leaves")
  storage = jax.tree.map(lambda s: jax.ShapeDtypeStruct((capacity,) + s.shape, s.dtype), specs)
  if sharding is None:
    make = jax.jit(lambda: _zeros(storage))
  else:
    if not isinstance(sharding, Sharding):
      raise ValueError(f"sharding must be a jax.sharding.Sharding, got {type(sharding).__name__}")
    for s in jax.tree.leaves(storage):
      try:
        sharding.shard_shape(s.shape)
      except ValueError:
        raise ValueError(f"capacity {capacity} (storage leaf {s.shape}) cannot be split over the "
                         f"{len(sharding.device_set)} devices of {sharding}") from None
    rep = _replicated_like(sharding)
    out = ReplayState(jax.tree.map(lambda _: sharding, storage), rep, rep)
    make = jax.jit(lambda: _zeros(storage), out_shardings=out)
  return make()


def _zeros(storage) -> ReplayState:
  data = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), storage)
  return ReplayState(data, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))


def _check_unrolls(state: ReplayState, unrolls) -> int:
  """Trace-time checks of `unrolls` against the storage; returns N, the number of unrolls."""
  data_def, unroll_def = jax.tree.structure(state.data), jax.tree.structure(unrolls)
  if data_def != unroll_def:
    raise ValueError(f"unrolls have structure {unroll_def}, the buffer stores {data_def}")
  cap = capacity(state)
  sizes = set()
  leaves = zip(jax.tree_util.tree_leaves_with_path(state.data), jax.tree.leaves(unrolls))
  for (path, d), u in leaves:
    name = jax.tree_util.keystr(path)
    u = _spec(u)
    if u.ndim == 0:
      raise ValueError(f"unrolls{name} is a scalar; every leaf needs a leading axis N")
    if u.shape[1:] != d.shape[1:]:
      expected = "(N" + "".join(f", {k}" for k in d.shape[1:]) + ")"
      raise ValueError(f"unrolls{name} has shape {u.shape}, expected {expected}")
    if u.dtype != d.dtype:
      raise ValueError(f"unrolls{name} has dtype {u.dtype}, the buffer stores {d.dtype}")
    sizes.add(u.shape[0])
  if len(sizes) != 1:
    raise ValueError(f"unroll leaves have mismatched leading axes {sorted(sizes)}")
  n = sizes.pop()
  if not 1 <= n <= cap:
    raise ValueError(f"cannot insert {n} unrolls into a buffer of capacity {cap} "
                     "(need 1 <= N <= capacity)")
  return n


def insert(state: ReplayState, unrolls) -> ReplayState:
  """Writes N unrolls (leaves [N, ...]) at slots (position + arange(N)) % capacity."""
  n, cap = _check_unrolls(state, unrolls), capacity(state)
  idx = (state.position + jnp.arange(n, dtype=jnp.int32)) % cap  # [N], distinct since N <= cap
  data = jax.tree.map(lambda d, u: d.at[idx].set(u, unique_indices=True), state.data, unrolls)
  position = ((state.position + n) % cap).astype(jnp.int32)
  size = jnp.minimum(state.size + n, cap).astype(jnp.int32)
  return ReplayState(data, position, size)


def sample(state: ReplayState, key: jax.Array, batch_size: int):
  """`batch_size` unrolls drawn uniformly with replacement from the written slots [0, size).

  The indices depend only on `key` and `size`, never on the sharding. On an empty buffer the
  result is slot 0 (zeros): check `can_sample` first.
  """
  batch_size = _positive_int(batch_size, "batch_size")
  idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(state.size, 1))  # [B]
  return jax.tree.map(lambda d: d[idx], state.data)


def can_sample(state: ReplayState, min_size: int = 1) -> jax.Array:
  """Whether at least `min_size` (>= 1) slots are written; a bool scalar usable under jit.

  Sampling is with replacement, so any batch size works once one slot is written; pass e.g.
  the batch size to wait for that many distinct unrolls.
  """
  return state.size >= max(int(min_size), 1)
