"""Expert policies as files, and demonstrations recorded from them on the device.

An expert file is the `policy.npz` a training run writes (mjx_form.runner.export_policy): the
policy parameters and the observation normaliser, with the task, observation layout and network
width in its metadata. `record` runs K full episodes in parallel (one jitted scan of 1000 steps
over a vmapped batch) and returns what `mjx_form.demos.save_demonstrations` stores.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form import env as env_lib
from mjx_form import normalizer, policy_io
from mjx_form.networks import make_networks


class Expert(NamedTuple):
  params: dict  # flax params of the GaussianPolicy
  normalizer: normalizer.NormalizerState
  metadata: dict


def load_expert(path: str, env: env_lib.Task) -> Expert:
  """Loads an expert for `env`'s task; refuses files of another task or observation layout."""
  arrays, metadata = policy_io.load_policy(
      path, task=env.name, observation_size=env.observation_size, action_size=env.action_size,
      observation_layout=env.observation_layout)
  norm = normalizer.NormalizerState(jnp.asarray(arrays["normalizer"]["mean"]),
                                    jnp.asarray(arrays["normalizer"]["var"]),
                                    jnp.asarray(1, jnp.int32))
  return Expert(jax.tree.map(jnp.asarray, arrays["policy"]), norm, metadata)


def record(env: env_lib.Task, expert: Expert, key: jax.Array, episodes: int,
           stochastic: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """`episodes` full episodes of the expert, in parallel on the device.

  Returns observations [K, T+1, D], actions [K, T, A] (clipped to [-1, 1], what the simulator
  applied) and task returns [K]. Actions are the policy's mean unless `stochastic`.
  """
  rollout = _rollout_fn(env, expert.metadata["network_width"], episodes, stochastic)
  obs, actions, returns = jax.device_get(rollout(expert.params, expert.normalizer, key))
  return np.asarray(obs, np.float32), np.asarray(actions, np.float32), np.asarray(returns)


@functools.cache
def _rollout_fn(env: env_lib.Task, network_width: int, episodes: int, stochastic: bool):
  """The jitted rollout of `record`, built once per task object and size (chunks reuse it)."""
  policy = make_networks(env.action_size, network_width).policy

  @jax.jit
  def rollout(params, norm, key):
    reset_key, action_key = jax.random.split(key)
    states = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))

    def step(states, key):
      pi = policy.apply(params, normalizer.normalize(norm, states.obs))
      action = jnp.clip(pi.sample(key) if stochastic else pi.mode(), -1.0, 1.0)
      next_states = jax.vmap(env.step)(states, action)
      return next_states, (states.obs, action, next_states.reward)

    final, (obs, actions, rewards) = jax.lax.scan(
        step, states, jax.random.split(action_key, env_lib.EPISODE_LENGTH))
    obs = jnp.concatenate([obs, final.obs[None]])  # [T+1, K, D]
    return jnp.swapaxes(obs, 0, 1), jnp.swapaxes(actions, 0, 1), rewards.sum(axis=0)

  return rollout
