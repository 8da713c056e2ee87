"""Batched environment wrappers: auto-reset with fresh draws."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjx_form import mesh as mesh_lib
from mjx_form.sim.env import State, Task


def _select(mask: jax.Array, on_true, on_false):
  """Per-environment `where` over two batched pytrees (mask has shape (batch,))."""
  def pick(a, b):
    return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)
  return jax.tree.map(pick, on_true, on_false)


class AutoReset:
  """Steps a batch of environments and restarts the ones whose episode ended.

  Restarted environments draw a fresh initial state from the task's reset distribution (never
  a cached one). The reset runs inside a `lax.cond` on "any episode ended", so the cost of
  resetting (cheetah's 200 settling steps, humanoid's rejection sampling, quadruped's height
  search) is paid only at the steps where an episode ends, not at every step.

  The state returned for an ended environment is its new episode's first state, while
  `reward`, `done` and `truncation` still describe the transition that ended the old one and
  `info['final_obs']` holds its last observation. `info['physics_errors']` counts, per
  environment, the episodes cut short by NaN/inf in actions or physics.

  On a mesh of several devices the batch is stepped as one program-wide batch: MJX's solver
  loops and the restart branch then agree over all devices at every iteration on whether any
  environment goes on. With `per_device` each device steps its own part instead
  (`mjx_form.mesh.per_device`, a shard_map), with the same result (the environments are
  independent and each carries its own key); off by default: on two H200s (jax 0.11.2,
  2026-11-26) XLA's GPU compiler crashed (segmentation fault) compiling it.
  """

  def __init__(self, env: Task, sharding=None, per_device: bool = False):
    """`sharding`: where the batch lives on a device mesh (None: wherever JAX puts it). Fresh
    starts are drawn from keys placed there, so `env.reset` sees the same argument types in
    `reset` as in the restarts of `step` and is traced once for both."""
    self.env = env
    self.sharding = sharding
    self.per_device = per_device

  def _constrain(self, tree):
    if self.sharding is None:
      return tree
    return jax.lax.with_sharding_constraint(tree, self.sharding)

  def reset(self, key: jax.Array, num_envs: int) -> State:
    """`num_envs` independent fresh starts; every leaf gets a leading (num_envs,) axis."""
    return self.reset_from_keys(jax.random.split(key, num_envs))

  def reset_from_keys(self, keys: jax.Array) -> State:
    """One fresh start per key of keys [num_envs, 2] (`reset` splits one key into them)."""
    state = jax.vmap(self.env.reset)(self._constrain(keys))
    info = dict(state.info, final_obs=state.obs, physics_errors=jnp.zeros(keys.shape[:1]))
    return state.replace(info=info)

  def step(self, state: State, action: jax.Array) -> State:
    """One control step of every environment; action has shape (num_envs, action_size)."""
    if self.per_device:
      return mesh_lib.per_device(self._step, self.sharding)(state, action)
    return self._step(state, action)

  def _step(self, state: State, action: jax.Array) -> State:
    stepped = jax.vmap(self.env.step)(state, action)  # carries the wrapper's info keys along
    info = dict(stepped.info, final_obs=stepped.obs,
                physics_errors=stepped.info["physics_errors"] + stepped.info["physics_error"])
    stepped = stepped.replace(info=info)

    def restart_ended(stepped: State) -> State:
      key, reset_key = jax.vmap(jax.random.split, out_axes=1)(stepped.info["key"])
      fresh = jax.vmap(self.env.reset)(reset_key)
      fresh = fresh.replace(info=dict(fresh.info, key=key))
      ended = stepped.done > 0
      new_start = stepped.replace(
          data=fresh.data, obs=fresh.obs, obs_parts=fresh.obs_parts, task=fresh.task,
          info=dict(stepped.info, step=fresh.info["step"], key=fresh.info["key"],
                    episode_return=fresh.info["episode_return"]))
      return _select(ended, new_start, stepped)

    return jax.lax.cond(jnp.any(stepped.done > 0), restart_ended, lambda s: s, stepped)

