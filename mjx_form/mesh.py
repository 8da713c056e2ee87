"""The device mesh: environment batches sharded over devices, parameters replicated."""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

BATCH_AXIS = "batch"


def make_mesh(devices=None) -> Mesh:
  """A one-axis mesh over `devices` (default: all devices of the default backend)."""
  devices = jax.devices() if devices is None else devices
  return Mesh(np.asarray(devices), (BATCH_AXIS,))


def check_batch_size(num_envs: int, mesh: Mesh) -> None:
  n = mesh.devices.size
  if num_envs <= 0:
    raise ValueError(f"num_envs must be positive, got {num_envs}")
  if num_envs % n:
    raise ValueError(f"num_envs={num_envs} must be a multiple of the number of devices ({n})")


def batch_sharding(mesh: Mesh) -> NamedSharding:
  """Leading axis split over the mesh."""
  return NamedSharding(mesh, PartitionSpec(BATCH_AXIS))


def member_batch_sharding(mesh: Mesh) -> NamedSharding:
  """A population's per-member batches [P, N, ...]: the second axis split over the mesh."""
  return NamedSharding(mesh, PartitionSpec(None, BATCH_AXIS))


def member_sharding(mesh: Mesh) -> NamedSharding:
  """A population's per-member state [P, ...]: the member axis split over the mesh."""
  return NamedSharding(mesh, PartitionSpec(BATCH_AXIS))


def replicated(mesh: Mesh) -> NamedSharding:
  return NamedSharding(mesh, PartitionSpec())


def per_device(fn, sharding: NamedSharding | None):
  """`fn` of arguments batched as `sharding` splits them, run by each device of its mesh on its
  own part of the batch (`jax.shard_map`; `fn` itself where there is one device or no mesh).

  For independent environments: a loop over a batch (MJX's solver iterations, a restart branch)
  then ends when the device's own environments are done, where over the whole batch the devices
  would agree at every iteration on whether any environment anywhere goes on. A batch that does
  not split evenly over the devices (e.g. a final evaluation's) is stepped as one, as before."""
  mesh = getattr(sharding, "mesh", None)
  if mesh is None or mesh.devices.size == 1:
    return fn
  split = jax.shard_map(fn, mesh=mesh, in_specs=sharding.spec, out_specs=sharding.spec,
                        check_vma=False)  # (MJX is not written for shard_map's type check)

  def run(*args):
    batch = jax.tree.leaves(args)[0].shape[0]
    return (split if batch % mesh.devices.size == 0 else fn)(*args)
  return run


def shard_batch(tree, mesh: Mesh):
  """Places every leaf of a batched pytree with its leading axis split over the mesh."""
  return jax.device_put(tree, batch_sharding(mesh))
