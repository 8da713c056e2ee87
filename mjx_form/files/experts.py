"""Expert policies as files, and demonstrations recorded from them on the device.

An expert file is the `policy.npz` a training run writes (mjx_form.rl.runner.export_policy): the
policy parameters and the observation normaliser, with the task, observation layout, network
width and policy head in its metadata (files from before heads existed have the paper's).
`record` runs K full episodes in parallel (one jitted scan of 1000 steps over a vmapped batch)
and returns what `mjx_form.files.demos.save_demonstrations` stores.
"""

from __future__ import annotations

import functools
import os
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form.files import policy_io
from mjx_form.rl import normalizer
from mjx_form.rl.networks import GaussianPolicy, make_networks
from mjx_form.sim import env as env_lib


class Expert(NamedTuple):
  params: dict  # flax params of the GaussianPolicy
  normalizer: normalizer.NormalizerState
  metadata: dict


def policy_network(metadata: dict, action_size: int) -> GaussianPolicy:
  """The policy module an expert file's parameters belong to (width and head from its
  metadata); ValueError naming an unknown head."""
  return make_networks(action_size, metadata["network_width"],
                       metadata.get("policy_head", "paper")).policy


def load_expert(path: str, env: env_lib.Task, any_task: bool = False) -> Expert:
  """Loads an expert for `env`'s task; refuses files of another task or observation layout.
  `any_task`: a policy of any task with `env`'s observation layout and action size (e.g.
  hopper_stand's for hopper_hop: a run that starts from it, `--init_policy`)."""
  arrays, metadata = policy_io.load_policy(
      path, task=None if any_task else env.name, observation_size=env.observation_size,
      action_size=env.action_size, observation_layout=env.observation_layout)
  for group in ("policy", "normalizer"):
    if not isinstance(arrays.get(group), dict) or (
        group == "normalizer" and not {"mean", "var"} <= arrays[group].keys()):
      raise policy_io.PolicyFileError(f"{path}: no {group} in the file (not a trained policy)")
  stats = arrays["normalizer"]
  norm = normalizer.NormalizerState(
      jnp.asarray(stats["mean"]), jnp.asarray(stats["var"]), jnp.asarray(1, jnp.int32),
      None if "period" not in stats else jnp.asarray(stats["period"]),  # wrapped angles
      None if "angles" not in stats else jnp.asarray(stats["angles"]))  # cos and sin of angles
  d = metadata["observation_size"]
  if norm.period is not None and norm.period.shape != (d,):
    raise policy_io.PolicyFileError(f"{path}: normalizer/period has shape {norm.period.shape}, "
                                    f"the observations {d} features")
  if norm.angles is not None:
    try:
      normalizer.check_angles(norm.angles, d)
    except ValueError as e:
      raise policy_io.PolicyFileError(f"{path}: normalizer/{e}") from None
  k = 0 if norm.angles is None else norm.angles.shape[0]
  if norm.mean.shape != (d + 2 * k,) or norm.var.shape != (d + 2 * k,):
    raise policy_io.PolicyFileError(
        f"{path}: normalizer/mean and var have shapes {norm.mean.shape}, {norm.var.shape}; "
        f"expected ({d + 2 * k},) for {d} observations" + (f" and {k} angles" if k else ""))
  return Expert(jax.tree.map(jnp.asarray, arrays["policy"]), norm, metadata)


def policy_id(expert: Expert) -> str:
  """How a run's config names the policy it starts from (`TrainConfig.init_policy`)."""
  return f"{expert.metadata['task']} {expert.metadata['sha256']}"


def record(env: env_lib.Task, expert: Expert, key: jax.Array, episodes: int,
           stochastic: bool = False, noise_correlation: float = 0.0
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """`episodes` full episodes of the expert, in parallel on the device.

  Returns observations [K, T+1, D], actions [K, T, A] (clipped to the task's control range,
  `Task.action_bounds`: what the simulator applied) and task returns [K]. Actions are the
  policy's mean unless `stochastic`, then sampled with noise correlated in time by
  `noise_correlation` as a training run's actors sample them
  (`TrainConfig.action_noise_correlation`; 0: independent draws).
  """
  if noise_correlation and not stochastic:
    raise ValueError("noise_correlation applies to sampled actions only (stochastic=True)")
  rollout = _rollout_fn(env, policy_network(expert.metadata, env.action_size), episodes,
                        stochastic, float(noise_correlation))
  obs, actions, returns = jax.device_get(rollout(expert.params, expert.normalizer, key))
  return np.asarray(obs, np.float32), np.asarray(actions, np.float32), np.asarray(returns)


@functools.cache
def _rollout_fn(env: env_lib.Task, policy: GaussianPolicy, episodes: int, stochastic: bool,
                noise_correlation: float = 0.0):
  """The jitted rollout of `record`, built once per task object, policy module and size
  (chunks reuse it)."""

  @jax.jit
  def rollout(params, norm, key):
    reset_key, action_key = jax.random.split(key)
    states = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))

    def step(carry, key):
      states, noise = carry
      pi = policy.apply(params, normalizer.normalize(norm, states.obs))
      if stochastic:  # as the actors of a run with this noise correlation act
        action, noise = pi.sample_correlated(key, noise, noise_correlation)
      else:
        action = pi.mode()
      # (the control range, as MuJoCo clamps it and a run's actors and evaluations act; not
      # [-1, 1]: quadruped's lift actuators go to 1.1)
      action = env.clip_action(action)
      next_states = jax.vmap(env.step)(states, action)
      return (next_states, noise), (states.obs, action, next_states.reward)

    fresh = jnp.full((episodes, env.action_size), jnp.nan)  # each episode's noise starts afresh
    (final, _), (obs, actions, rewards) = jax.lax.scan(
        step, (states, fresh), jax.random.split(action_key, env_lib.EPISODE_LENGTH))
    obs = jnp.concatenate([obs, final.obs[None]])  # [T+1, K, D]
    return jnp.swapaxes(obs, 0, 1), jnp.swapaxes(actions, 0, 1), rewards.sum(axis=0)

  return rollout


def record_demonstrations(env: env_lib.Task, expert: Expert, key: jax.Array, episodes: int,
                          chunk: int = 1000, stochastic: bool = False,
                          print_fn=print, noise_correlation: float = 0.0
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """`record` in chunks of `chunk` episodes (one compiled rollout, reused), with a progress
  line per chunk: observations [K, T+1, D], actions [K, T, A], returns [K]."""
  if episodes < 1 or chunk < 1:
    raise ValueError(f"episodes and chunk must be positive, got {episodes} and {chunk}")
  chunk = min(chunk, episodes)
  parts, done, start = [], 0, time.perf_counter()
  while done < episodes:
    key, sub = jax.random.split(key)
    parts.append(record(env, expert, sub, chunk, stochastic=stochastic,
                        noise_correlation=noise_correlation))
    done += chunk
    returns = np.concatenate([p[2] for p in parts])
    print_fn(f"{min(done, episodes)}/{episodes} expert episodes, mean return "
             f"{returns.mean():.1f}, {time.perf_counter() - start:.0f}s")
  return tuple(np.concatenate([p[i] for p in parts])[:episodes] for i in range(3))


def recording_info(policy_path: str, policy_metadata: dict, returns: np.ndarray, seed: int,
                   stochastic: bool) -> dict:
  """The `expert` metadata of demonstrations recorded from a policy file (mjx_form.files.demos)."""
  return {"policy_file": os.path.basename(policy_path),
          "policy_sha256": policy_metadata["sha256"],
          "policy_env_steps": policy_metadata.get("env_steps"), "seed": seed,
          "stochastic": stochastic, "mean_return": float(np.mean(returns)),
          "min_return": float(np.min(returns)), "max_return": float(np.max(returns))}
