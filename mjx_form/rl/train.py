"""The compiled training loop: N environments, an on-device replay, a reward source, MPO.

One call of `Trainer.iteration` (a single jitted program) does:
  1. collect: every environment takes `unroll_length` steps with actions sampled from the
     online policy; the unrolls (observations [N, T+1, D], actions, behaviour log-probs,
     discounts, and the task reward only if the reward source asks for it) go to the replay;
  2. standardisation: the observation normaliser's EMA is updated with the new observations;
  3. learn: `updates_per_iteration` learner updates, each on `batch_size` unrolls sampled
     from the replay and relabelled by the reward source.
Python only loops over iterations (logging, evaluation, checkpoints).

Sharding: environments, replay slots and sampled batches are split over the mesh's batch
axis; parameters, optimiser states and normaliser are replicated; XLA averages gradients.
Every random draw is made on global arrays, so a run does not depend on the device count
beyond float rounding.

Episode phases: with `stagger_episodes` (the default) each environment starts its first episode
at a random multiple of `unroll_length` steps into the 1000 (a shorter first episode, left out
of `train_return`), so every iteration collects every phase of an episode. Started together,
thousands of environments would stay in lockstep (no task ends early), and a replay holding
fewer than 1000 / unroll_length iterations (10,000 unrolls at more than 1000 envs) would hold
only the same few hundred steps of every episode at a time, cycling through the episode.

Episode ends inside an unroll: the transition whose next observation belongs to a new episode
gets discount 0 (no bootstrap). With `unroll_length` dividing the 1000-step episodes, time-limit
ends fall on the last step of an unroll (staggered starts are multiples of it), where the
episode's final observation is kept and bootstrapped from; only an episode cut short by a
physics error (NaN/inf) puts an environment off those boundaries.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

import tasks
from mjx_form import mesh as mesh_lib
from mjx_form.rl import learner as learner_lib
from mjx_form.rl import normalizer, replay
from mjx_form.rl.networks import make_networks
from mjx_form.rl.reward_sources import make_reward_source
from mjx_form.sim import env as env_lib
from mjx_form.sim import physics as physics_lib
from mjx_form.sim.wrappers import AutoReset


@dataclasses.dataclass(frozen=True)
class TrainConfig:
  """A training run's settings. Defaults are the paper's where it has one."""

  task: str = "cheetah_run"
  physics: str = physics_lib.DEFAULT_PHYSICS
  reward_source: str = "task"
  num_envs: int = 16
  unroll_length: int = 100
  batch_size: int = 64  # unrolls per learner update
  replay_capacity: int = 10_000  # unrolls
  updates_per_iteration: int = 8  # learner updates per collected unroll of every env
  network_width: int = 256
  normalizer_decay: float = 0.99  # observation EMA decay per iteration
  eval_envs: int = 16
  seed: int = 0
  stagger_episodes: bool = True  # first episodes start at random phases (see module docstring)
  learner: learner_lib.LearnerConfig = learner_lib.LearnerConfig()

  def check(self, num_devices: int) -> None:
    """Raises ValueError naming the first bad setting."""
    if self.task not in tasks.TASKS:
      raise ValueError(f"unknown task {self.task!r}; valid tasks: {', '.join(tasks.TASKS)}")
    for name in ("num_envs", "unroll_length", "batch_size", "replay_capacity",
                 "updates_per_iteration", "network_width", "eval_envs"):
      value = getattr(self, name)
      if not isinstance(value, int) or value <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    for name in ("num_envs", "batch_size", "replay_capacity", "eval_envs"):
      if getattr(self, name) % num_devices:
        raise ValueError(f"{name}={getattr(self, name)} must be a multiple of the number of "
                         f"devices ({num_devices})")
    if self.num_envs > self.replay_capacity:
      raise ValueError(f"replay_capacity={self.replay_capacity} must hold at least one "
                       f"iteration's unrolls (num_envs={self.num_envs})")
    for name in ("num_action_samples", "target_update_period"):
      value = getattr(self.learner, name)
      if not isinstance(value, int) or value <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if self.reward_source != "task" and env_lib.EPISODE_LENGTH % self.unroll_length:
      raise ValueError(f"unroll_length={self.unroll_length} must divide the episode length "
                       f"({env_lib.EPISODE_LENGTH}) for imitation: an episode's final "
                       "observation is kept only where an unroll ends")
    if not 0.0 <= self.normalizer_decay < 1.0:
      raise ValueError(f"normalizer_decay must be in [0, 1), got {self.normalizer_decay}")

  def to_dict(self) -> dict:
    return dataclasses.asdict(self)

  @property
  def env_steps_per_iteration(self) -> int:
    return self.num_envs * self.unroll_length

  @property
  def updates_per_env_step(self) -> float:
    """The ratio of learner updates to environment steps."""
    return self.updates_per_iteration / self.env_steps_per_iteration

  @property
  def replay_ratio(self) -> float:
    """Transitions sampled by the learner per transition collected."""
    return self.updates_per_iteration * self.batch_size / self.num_envs


class TrainState(NamedTuple):
  learner: learner_lib.LearnerState
  normalizer: normalizer.NormalizerState
  replay: replay.ReplayState
  env: env_lib.State  # batched [N]
  episode_return: jax.Array  # [N] task return of each env's running episode (for logging);
                             # NaN while an env runs its shortened (staggered) first episode
  source: Any  # the reward source's state
  key: jax.Array
  iteration: jax.Array  # int32 []


class Trainer:
  """Builds and compiles a run's functions for `config` on `mesh`."""

  def __init__(self, config: TrainConfig, mesh=None, reward_source=None):
    """`reward_source` overrides the source named by `config.reward_source` (see
    mjx_form.rl.reward_sources for the interface)."""
    self.mesh = mesh if mesh is not None else mesh_lib.make_mesh()
    config.check(self.mesh.devices.size)
    self.config = config
    self.env = tasks.make(config.task, physics=config.physics)
    self._batch = mesh_lib.batch_sharding(self.mesh)
    self.auto_reset = AutoReset(self.env, self._batch)
    self.networks = make_networks(self.env.action_size, config.network_width)
    self.source = reward_source or make_reward_source(config.reward_source)
    if self.source.name != config.reward_source:
      raise ValueError(f"the config names reward source {config.reward_source!r}, the trainer "
                       f"was given {self.source.name!r}")
    self._replicated = mesh_lib.replicated(self.mesh)
    abstract = jax.eval_shape(self._init, jax.random.PRNGKey(0))
    self.state_sharding = self._shardings(abstract)
    self.abstract_state = jax.tree.map(  # shapes, dtypes, shardings
        lambda a, s: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=s), abstract,
        self.state_sharding)
    self.init = jax.jit(self._init, out_shardings=self.state_sharding)
    self.iteration = jax.jit(self._iteration, donate_argnums=0,
                             out_shardings=(self.state_sharding, self._replicated))
    self.evaluate = jax.jit(self._evaluate, static_argnames="num_envs",
                            out_shardings=self._replicated)

  def compile_ahead(self, key: jax.Array) -> None:
    """Compiles `init`, `iteration` and `evaluate` at once, in threads, before their first call.

    Without it each program compiles at its first call, one after the other; XLA compiles in
    parallel threads (tracing takes turns), so a run starts sooner. The compiled programs land in
    JAX's cache; the later calls (`key` of the kind that will be passed) reuse them.
    """
    state = self.abstract_state
    jobs = [(self.init, (key,)), (self.iteration, (state,)),
            (self.evaluate, (state.learner.policy, state.normalizer, key))]
    with concurrent.futures.ThreadPoolExecutor(len(jobs)) as pool:
      for future in [pool.submit(lambda f=f, a=a: f.lower(*a).compile()) for f, a in jobs]:
        future.result()

  # --- state ------------------------------------------------------------------------------

  def _unroll_example(self) -> dict:
    t, d, a = self.config.unroll_length, self.env.observation_size, self.env.action_size
    example = {"observation": jnp.zeros((t + 1, d)), "action": jnp.zeros((t, a)),
               "behaviour_log_prob": jnp.zeros((t,)), "discount": jnp.zeros((t,))}
    if self.source.needs_task_reward:  # otherwise the task reward never enters the replay
      example["reward"] = jnp.zeros((t,))
    return example

  def _init(self, key: jax.Array) -> TrainState:
    cfg = self.config
    env_key, learner_key, source_key, key = jax.random.split(key, 4)
    example = self._unroll_example()
    storage = jax.tree.map(lambda x: jnp.zeros((cfg.replay_capacity,) + x.shape, x.dtype),
                           example)
    storage = jax.lax.with_sharding_constraint(storage, self._batch)
    key, stagger_key = jax.random.split(key)
    env_state = self.auto_reset.reset(env_key, cfg.num_envs)
    episode_return = jnp.zeros((cfg.num_envs,))
    if cfg.stagger_episodes:
      phases = max(1, env_lib.EPISODE_LENGTH // cfg.unroll_length)
      start = cfg.unroll_length * jax.random.randint(stagger_key, (cfg.num_envs,), 0, phases)
      env_state = env_state.replace(info=dict(
          env_state.info, step=start.astype(env_state.info["step"].dtype)))
      # Partial episodes are not reported. (float32, not weak-typed: a weak-typed leaf here
      # would differ from the iteration's output and make its second call compile again.)
      episode_return = jnp.where(start > 0, jnp.nan, 0.0).astype(jnp.float32)
    env_state = jax.lax.with_sharding_constraint(env_state, self._batch)
    return TrainState(
        learner=learner_lib.init(self.networks, cfg.learner, learner_key,
                                 self.env.observation_size, self.env.action_size),
        normalizer=normalizer.init(self.env.observation_size),
        replay=replay.ReplayState(storage, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32)),
        env=env_state,
        episode_return=jax.lax.with_sharding_constraint(episode_return, self._batch),
        source=self.source.init(source_key, self.env.observation_size, self.env.action_size),
        key=key, iteration=jnp.zeros((), jnp.int32))

  def _shardings(self, abstract: TrainState) -> TrainState:
    rep = lambda tree: jax.tree.map(lambda _: self._replicated, tree)
    bat = lambda tree: jax.tree.map(lambda _: self._batch, tree)
    return TrainState(
        learner=rep(abstract.learner), normalizer=rep(abstract.normalizer),
        replay=replay.ReplayState(bat(abstract.replay.data), self._replicated, self._replicated),
        env=bat(abstract.env), episode_return=self._batch, source=rep(abstract.source),
        key=self._replicated, iteration=self._replicated)

  # --- one iteration ----------------------------------------------------------------------

  def _collect(self, state: TrainState, key: jax.Array):
    """`unroll_length` steps of every env with the online policy; (env, returns, unrolls, stats)."""
    policy = self.networks.policy

    def step(carry, key):
      env_state, running = carry
      pi = policy.apply(state.learner.policy, normalizer.normalize(state.normalizer,
                                                                   env_state.obs))
      action = pi.sample(key)  # [N, A]
      stepped = self.auto_reset.step(env_state, action)
      running = running + stepped.reward
      done = stepped.done > 0
      whole = done & jnp.isfinite(running)  # a whole episode ended (not a staggered first one)
      out = {"observation": env_state.obs, "action": action,
             "behaviour_log_prob": pi.log_prob(action), "reward": stepped.reward,
             "done": done, "whole": whole, "error": stepped.info["physics_error"] > 0,
             "finished_return": jnp.where(whole, running, 0.0)}
      return (stepped, jnp.where(done, 0.0, running)), out

    keys = jax.random.split(key, self.config.unroll_length)
    (env_state, running), traj = jax.lax.scan(step, (state.env, state.episode_return), keys)
    # traj leaves are time-major [T, N, ...]. The last observation is the true successor of the
    # last step: the ended episode's final observation where an episode ended there.
    observation = jnp.concatenate([traj["observation"], env_state.info["final_obs"][None]])
    discount = 1.0 - traj["done"].astype(jnp.float32)
    discount = discount.at[-1].set(1.0 - traj["error"][-1].astype(jnp.float32))
    unrolls = {"observation": observation, "action": traj["action"],
               "behaviour_log_prob": traj["behaviour_log_prob"], "discount": discount}
    if self.source.needs_task_reward:
      unrolls["reward"] = traj["reward"]
    unrolls = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), unrolls)  # [N, T(+1), ...]
    unrolls = jax.lax.with_sharding_constraint(unrolls, self._batch)
    episodes, whole = jnp.sum(traj["done"]), jnp.sum(traj["whole"])
    stats = {"episodes": episodes,
             # NaN in an iteration where no whole episode ended (not a return of 0)
             "train_return": jnp.where(whole > 0, jnp.sum(traj["finished_return"])
                                       / jnp.maximum(whole, 1), jnp.nan),
             "train_reward": jnp.mean(traj["reward"]),
             "physics_errors": jnp.sum(traj["error"])}
    return env_state, running, unrolls, stats

  def _iteration(self, state: TrainState) -> tuple[TrainState, dict]:
    cfg = self.config
    key, collect_key, learn_key = jax.random.split(state.key, 3)
    env_state, running, unrolls, stats = self._collect(state, collect_key)
    norm = normalizer.update(state.normalizer, unrolls["observation"][:, :-1],
                             cfg.normalizer_decay)
    buffer = replay.insert(state.replay, unrolls)

    def learn(carry, key):
      learner, source = carry
      sample_key, source_key, update_key = jax.random.split(key, 3)
      batch = replay.sample(buffer, sample_key, cfg.batch_size)
      batch = jax.lax.with_sharding_constraint(batch, self._batch)
      source, source_metrics = self.source.update(source, batch, source_key)
      rewards, reward_metrics = self.source.relabel(source, batch)
      source_metrics = {**source_metrics, **reward_metrics}
      learner, metrics = learner_lib.update(self.networks, cfg.learner, learner, norm, batch,
                                            rewards, update_key)
      return (learner, source), {**metrics, **source_metrics}

    (learner, source), metrics = jax.lax.scan(
        learn, (state.learner, state.source),
        jax.random.split(learn_key, cfg.updates_per_iteration))
    metrics = {**jax.tree.map(jnp.mean, metrics), **stats}
    state = TrainState(learner=learner, normalizer=norm, replay=buffer, env=env_state,
                       episode_return=running, source=source, key=key,
                       iteration=state.iteration + 1)
    return state, metrics

  # --- evaluation -------------------------------------------------------------------------

  def _evaluate(self, policy_params, norm: normalizer.NormalizerState, key: jax.Array,
                num_envs: int | None = None) -> jax.Array:
    """Task returns [num_envs] (default eval_envs) of full episodes with the policy's mean
    action."""
    n = num_envs or self.config.eval_envs
    states = self.auto_reset.reset(key, n)  # (its info keys too: the same env.step trace)
    states = jax.lax.with_sharding_constraint(states, self._batch)

    def step(carry, _):
      env_state, total = carry
      pi = self.networks.policy.apply(policy_params, normalizer.normalize(norm, env_state.obs))
      env_state = jax.vmap(self.env.step)(env_state, pi.mode())
      return (env_state, total + env_state.reward), None

    (_, total), _ = jax.lax.scan(step, (states, jnp.zeros((n,))), None,
                                 length=env_lib.EPISODE_LENGTH)
    return total


def iterations_for(config: TrainConfig, env_steps: int) -> int:
  """Iterations needed to take at least `env_steps` environment steps."""
  return max(1, math.ceil(env_steps / config.env_steps_per_iteration))
