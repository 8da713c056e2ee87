"""The compiled training loop: N environments, an on-device replay, a reward source, MPO;
for one run or a population of runs (members) side by side in the same program.

One call of `Trainer.iteration` (a single jitted program) does, for every member:
  1. collect: every environment takes `unroll_length` steps with actions sampled from the
     online policy; the unrolls (observations [N, T+1, D], actions, behaviour log-probs,
     discounts, and the task reward only if the reward source asks for it) go to the replay;
  2. standardisation: the observation normaliser's EMA is updated with the new observations;
  3. learn: `updates_per_iteration` learner updates, each on `batch_size` unrolls sampled
     from the replay and relabelled by the reward source, which trains on the first of every
     `source_update_every` of those batches (every batch by default).
With a cloning source (BC: reward_sources.py, `policy_targets`) step 3's updates fit the policy
to the source's pairs instead (mjx_form.rl.cloning; the source still trains on the replay's
batches), and step 2 standardises as the observations of those pairs.
Python only loops over iterations (logging, evaluation, checkpoints).

Sharding (`LAYOUTS`): the environments' batch [P * N] is split over the mesh's batch axis.
A single run, or a population whose members do not split evenly over the devices, splits its
replay slots and sampled batches over the devices within each member too ("environments");
parameters, optimiser states and normaliser are replicated and XLA averages gradients. A
population of P members on D devices with D dividing P puts whole members on each device
("members": every member-axis leaf split over the devices), so a member's updates run on one
device with no gradient exchange. Either way the environments' batch is stepped as one
(`Trainer(per_device_env_steps=True)`: each device steps its own part; see AutoReset).
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
import numpy as np

import tasks
from mjx_form import cpu
from mjx_form import mesh as mesh_lib
from mjx_form.rl import learner as learner_lib
from mjx_form.rl import cloning, distributions, grid, normalizer, replay
from mjx_form.rl import networks as networks_lib
from mjx_form.rl.reward_sources import make_reward_source
from mjx_form.sim import env as env_lib
from mjx_form.sim import physics as physics_lib
from mjx_form.sim.wrappers import AutoReset

# How a population's state lies on the devices of the mesh (`Trainer(layout=...)`).
LAYOUTS = ("environments", "members")


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
  # The reward source trains (`update`: FORM's imitator step, and its running statistics: the
  # imitator's observation standardisation, the reward's mean and sd) on the first of every k
  # learner batches and relabels every batch with its current state; 1: on every batch (the
  # paper's imitator). A divisor of updates_per_iteration.
  source_update_every: int = 1
  network_width: int = 256
  policy_head: str = "paper"  # the policy's Gaussian head (networks.POLICY_HEADS)
  # c of the actors' noise e_t = c e_{t-1} + sqrt(1 - c^2) xi_t (action = mean + scale e_t): 0
  # draws it afresh every step (the paper's); 0 < c < 1 correlates it in time, each action's
  # marginal still the policy's Gaussian.
  action_noise_correlation: float = 0.0
  # k of each env's noise multiplier: a member's environments act with the policy's noise
  # scaled by multipliers spread evenly from k (its first env) to 1 (its last), the behaviour
  # density Retrace needs scaled alike; k = 0 gives its first env the mean action (to 1e-6 of
  # the scale), so that the states the mean action leads to reach the replay (a FORM
  # walker_stand policy ends crouched or half-up from 34% of starts by its mean action, from
  # none by sampled actions: benchmarks/NOTES.md, session 60). The train return then mixes in
  # the less noisy envs' episodes. 1: every env acts with the policy itself (the paper's).
  noise_scale_min: float = 1.0
  normalizer_decay: float = 0.99  # observation EMA decay per iteration
  # The agent wraps the task's unbounded raw angles (`Task.periodic_observations`) into
  # [-pi, pi) before standardising them (the observation normaliser's `period`); off: it sees
  # them raw, as the paper's agent does.
  wrap_angles: bool = False
  # The agent sees each of those angles as its cos and sin instead (the normaliser's `angles`):
  # one input per pose, no jump anywhere. Not the paper's.
  angle_features: bool = False
  eval_envs: int = 16
  seed: int = 0
  stagger_episodes: bool = True  # first episodes start at random phases (see module docstring)
  # The trained policy every member starts from, as "<its task> <its file's sha256>" (its
  # parameters and observation statistics: `Trainer.start_from`, `--init_policy`); None: the
  # networks' random initialisation (the paper's).
  init_policy: str | None = None
  learner: learner_lib.LearnerConfig = learner_lib.LearnerConfig()

  def check(self, num_devices: int) -> None:
    """Raises ValueError naming the first bad setting."""
    if self.task not in tasks.TASKS:
      raise ValueError(f"unknown task {self.task!r}; valid tasks: {', '.join(tasks.TASKS)}")
    for name in ("num_envs", "unroll_length", "batch_size", "replay_capacity",
                 "updates_per_iteration", "source_update_every", "network_width", "eval_envs"):
      value = getattr(self, name)
      if not isinstance(value, int) or value <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    for name in ("num_envs", "batch_size", "replay_capacity", "eval_envs"):
      if getattr(self, name) % num_devices:
        raise ValueError(f"{name}={getattr(self, name)} must be a multiple of the number of "
                         f"devices ({num_devices})")
    if self.updates_per_iteration % self.source_update_every:
      raise ValueError(f"source_update_every={self.source_update_every} must divide "
                       f"updates_per_iteration={self.updates_per_iteration}")
    networks_lib.policy_head(self.policy_head)  # ValueError naming the valid heads
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
    grid.check_value("policy_average_decay", self.learner.policy_average_decay)
    if self.learner.sampled_q_float32_head and not self.learner.sampled_q_bfloat16:
      raise ValueError("sampled_q_float32_head applies to the bfloat16 sampled Q only: give "
                       "sampled_q_bfloat16 too (in float32 the whole Q already is)")
    if not 0.0 <= self.action_noise_correlation < 1.0:
      raise ValueError("action_noise_correlation must be in [0, 1), got "
                       f"{self.action_noise_correlation}")
    grid.check_value("noise_scale_min", self.noise_scale_min)
    if self.noise_scale_min < 1.0 and self.num_envs < 2:
      raise ValueError("noise_scale_min spreads the multipliers over a member's environments: "
                       f"it needs num_envs >= 2, got {self.num_envs}")

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
  """The state of a population of P runs ("members"; P = 1 for a single run). Every leaf has
  a leading member axis, but the environments, whose members sit side by side on one axis."""

  learner: learner_lib.LearnerState  # [P, ...]
  normalizer: normalizer.NormalizerState  # [P, D]
  replay: replay.ReplayState  # data [P, capacity, ...], position and size [P]
  env: env_lib.State  # [P * N]: member i's environments are [i * N, (i + 1) * N)
  episode_return: jax.Array  # [P * N] task return of each env's running episode (for logging);
                             # NaN while an env runs its shortened (staggered) first episode
  source: Any  # the reward source's state, [P, ...]
  # [P * N, A]: each env's actor noise of its last step (`action_noise_correlation`), NaN where
  # the next step starts afresh (a new episode); [P * N, 0] with independent noise.
  noise: jax.Array
  key: jax.Array  # [P, 2]
  iteration: jax.Array  # int32 []: the members take their iterations together
  # Each member's own value of the settings members override (mjx_form.rl.grid), [P] each;
  # {} where none does. Data, not constants: grids of other values share the compiled program.
  settings: dict


class _WithData:
  """A jitted function with its `data` argument bound: called, or lowered, without it."""

  def __init__(self, jitted, data):
    self.jitted, self.data = jitted, data

  def __call__(self, *args, **kwargs):
    return self.jitted(*args, data=self.data, **kwargs)

  def lower(self, *args, **kwargs):
    return self.jitted.lower(*args, data=self.data, **kwargs)


class Trainer:
  """Builds and compiles the functions of a run, or of a population of runs, for `config` on
  `mesh`.

  A population (`seeds` with several entries) runs one member per seed in one compiled
  program; `overrides` give members their own values of some settings (mjx_form.rl.grid).
  Each member has its own environments, replay, networks, optimiser and dual states,
  normaliser, reward-source state and random stream, and computes what a single run with its
  seed and settings computes: the learner, normaliser, replay and source are `vmap`ped over
  the member axis, and the members' environments share one batch, so the auto-reset's
  `lax.cond` stays one branch taken for all (a `vmap` of it would run every reset at every
  step).
  """

  def __init__(self, config: TrainConfig, mesh=None, reward_source=None,
               seeds: tuple[int, ...] | None = None,
               overrides: tuple[dict, ...] | None = None, layout: str | None = None,
               per_device_env_steps: bool = False, source_data: bool = True):
    """`reward_source` overrides the source named by `config.reward_source` (see
    mjx_form.rl.reward_sources for the interface); `seeds`: the members' seeds (default:
    `config.seed` alone); `overrides`: each member's own values of settings that may differ
    between members (mjx_form.rl.grid; default: none), one dict per seed; `layout`: one of
    `LAYOUTS` (default: "members" where the members split evenly over several devices, else
    "environments"); `per_device_env_steps`: each device steps its own environments
    (`AutoReset(per_device=True)`; off: the batch is stepped as one, see AutoReset);
    `source_data`: put the source's `data` on the devices for `iteration` (off for a trainer
    that only evaluates)."""
    self.mesh = mesh if mesh is not None else mesh_lib.make_mesh()
    config.check(self.mesh.devices.size)
    self.seeds = tuple(seeds) if seeds is not None else (config.seed,)
    self.overrides = tuple(dict(o) for o in overrides) if overrides is not None else tuple(
        {} for _ in self.seeds)
    if not self.seeds or not all(isinstance(s, int) and not isinstance(s, bool)
                                 for s in self.seeds):
      raise ValueError(f"seeds must be integers, got {seeds!r}")
    if len(self.overrides) != len(self.seeds):
      raise ValueError(f"{len(self.overrides)} overrides for {len(self.seeds)} seeds")
    names = sorted({n for o in self.overrides for n in o})
    members = [(s, tuple(sorted(o.items()))) for s, o in zip(self.seeds, self.overrides)]
    if len(set(members)) != len(members):
      raise ValueError("the members must differ (in seed or settings), got "
                       + "; ".join(grid.label(s, o) for s, o in zip(self.seeds, self.overrides)))
    self.members = len(self.seeds)
    self.config = config
    self.env = tasks.make(config.task, physics=config.physics)
    self.layout = self._choose_layout(layout)
    # [P * N, ...] environments: split over the devices (whole members per device when the
    # members split evenly over them: member i's environments are [i * N, (i + 1) * N)).
    self._batch = mesh_lib.batch_sharding(self.mesh)
    self._replicated = mesh_lib.replicated(self.mesh)
    if self.layout == "members":  # [P, ...] leaves split by member
      self._member = self._member_batch = mesh_lib.member_sharding(self.mesh)
    else:  # [P, ...] replicated, [P, N, ...] batches split within each member
      self._member = self._replicated
      self._member_batch = mesh_lib.member_batch_sharding(self.mesh)
    self.auto_reset = AutoReset(self.env, self._batch, per_device=per_device_env_steps)
    self.networks = networks_lib.make_networks(self.env.action_size, config.network_width,
                                               config.policy_head)
    self.source = reward_source or make_reward_source(config.reward_source)
    # A cloning source: the policy is fitted to its pairs (`_learn`), not trained by MPO.
    self.clones = hasattr(self.source, "policy_targets")
    if self.source.name != config.reward_source:
      raise ValueError(f"the config names reward source {config.reward_source!r}, the trainer "
                       f"was given {self.source.name!r}")
    variable = tuple(getattr(self.source, "variable_settings", ()))
    for name in names:
      if name not in grid.LEARNER and name not in grid.ACTOR and name not in variable:
        raise ValueError(f"{name!r} cannot differ between members of a {self.source.name} "
                         f"run (it can: {', '.join((*grid.LEARNER, *grid.ACTOR, *variable))})")
    for i, overrides in enumerate(self.overrides):
      for name, value in overrides.items():
        grid.check_value(name, value)
      # (each member's whole settings, as its single run's: e.g. a float32 head without
      # bfloat16, or noise multipliers over a single env)
      self.member_config(i).check(self.mesh.devices.size)
      # (the source refuses values it cannot take, e.g. FORM's mean of an ensemble's log pD
      # without an ensemble)
      self._source_with(grid.split(overrides)[2])
    # Each member's value of every setting some member overrides (TrainState.settings).
    self._settings = [{**{n: self._default(n) for n in names}, **o} for o in self.overrides]
    self._setting_names = names
    # Whether some member's actors correlate their noise (TrainState.noise holds a state then).
    self._correlated = any(self.member_config(i).action_noise_correlation
                           for i in range(self.members))
    # Whether some member's envs scale their noise (`noise_scale_min` below 1).
    self._scaled = any(self.member_config(i).noise_scale_min < 1.0 for i in range(self.members))
    # The learner state's structure: the action penalty's dual is there if any member penalises
    # (a member whose flag is off leaves it at its initial value), the average policy if any
    # member averages (a member at 0 keeps a copy of its policy).
    learners = [self.member_config(i).learner for i in range(self.members)]
    self._init_learner = grid.learner_config(config.learner, {
        "action_penalty": any(c.mpo.action_penalty for c in learners),
        "policy_average_decay": max(c.policy_average_decay for c in learners)})
    if self._angle_features() and not self.env.periodic_observations:
      raise ValueError(f"angle_features: {self.env.name} observes no unbounded angle")
    abstract = jax.eval_shape(self._init, self.keys(0))
    self.state_sharding = self._shardings(abstract)
    self.abstract_state = jax.tree.map(  # shapes, dtypes, shardings
        lambda a, s: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=s), abstract,
        self.state_sharding)
    self.init = jax.jit(self._init, out_shardings=self.state_sharding,
                        compiler_options=cpu.run_once_compiler_options())
    self.iteration = jax.jit(self._iteration, donate_argnums=0,
                             out_shardings=(self.state_sharding, self._replicated))
    # A source's constant arrays (`data`, reward_sources.py: e.g. GAIfO's demonstrations) enter
    # the compiled iteration as an argument, replicated: neither compiled in as constants nor
    # part of the state that checkpoints save.
    data = self.source.data() if source_data and hasattr(self.source, "data") else None
    if data is not None:
      self.source_data = jax.device_put(data, self._replicated)
      self.iteration = _WithData(self.iteration, self.source_data)
    self.evaluate = jax.jit(self._evaluate, static_argnames="num_envs",
                            out_shardings=self._replicated)

  def _angle_features(self) -> bool:
    """Whether some member sees angle features (every member's normaliser has `angles` then)."""
    return any(self.member_config(i).angle_features for i in range(self.members))

  def _angle_rows(self) -> np.ndarray:
    """[K, D]: the normaliser's `angles` of a member that sees angle features."""
    return normalizer.angle_rows(self.env.observation_period())

  @property
  def per_device_env_steps(self) -> bool:
    """Whether each device steps its own environments (`AutoReset.per_device`)."""
    return self.auto_reset.per_device

  def _choose_layout(self, layout: str | None) -> str:
    devices = self.mesh.devices.size
    even = self.members % devices == 0
    if layout is None:
      return "members" if devices > 1 and even else "environments"
    if layout not in LAYOUTS:
      raise ValueError(f"unknown layout {layout!r}; valid layouts: {', '.join(LAYOUTS)}")
    if layout == "members" and not even:
      raise ValueError(f"layout 'members' needs the members ({self.members}) to be a multiple "
                       f"of the devices ({devices})")
    return layout

  def _default(self, name: str):
    """The run's own value of a setting that members may override."""
    if name in grid.LEARNER:
      value = self.config.learner
      for part in grid.LEARNER[name][0]:
        value = getattr(value, part)
      return value
    if name in grid.ACTOR:
      return getattr(self.config, name)
    return getattr(self.source, name)  # (its settings() may leave out a default value)

  def member_config(self, i: int) -> TrainConfig:
    """Member i's settings (its seed and overrides applied; the source's are `member_source`)."""
    learner_values, actor_values, _ = grid.split(self.overrides[i])
    return dataclasses.replace(self.config, seed=self.seeds[i], **actor_values,
                               learner=grid.learner_config(self.config.learner, learner_values))

  def member_source(self, i: int):
    """Member i's reward source (its overrides of the source's settings applied; a source with
    something of its own per member, e.g. FORM's demonstrators, as member i)."""
    source = self._source_with(grid.split(self.overrides[i])[2])
    return source.as_member(i) if hasattr(source, "as_member") else source

  def _source_with(self, values: dict, data=None):
    """The reward source with `values` (Python, or a member's traced ones) for its settings,
    and reading `data` (its constant arrays as an iteration has them: `with_data`) if given."""
    source = self.source.specialise(values) if values else self.source
    return source if data is None else source.with_data(data)

  def keys(self, offset: int = 0) -> jax.Array:
    """[P, 2]: PRNGKey(seed + offset) of each member (offset 0 starts a run, 1 evaluates)."""
    return jnp.stack([jax.random.PRNGKey(s + offset) for s in self.seeds])

  def compile_ahead(self, keys: jax.Array, policies_per_evaluation: int = 1,
                    evaluation: bool = True) -> None:
    """Compiles `init`, `iteration` and (`evaluation`) `evaluate` of `policies_per_evaluation`
    policies at once together, in threads, before their first call.

    Without it each program compiles at its first call, one after the other; XLA compiles in
    parallel threads (tracing takes turns), so a run starts sooner. The compiled programs land in
    JAX's cache; the later calls (`keys` [P, 2] of the kind that will be passed) reuse them.
    """
    state = self.abstract_state
    held, norms, inputs = self.evaluation_example(policies_per_evaluation)
    jobs = [(self.init, (keys,), {}), (self.iteration, (state,), {})] + (
        [(self.evaluate, (held, norms, keys), inputs)] if evaluation else [])
    with concurrent.futures.ThreadPoolExecutor(len(jobs)) as pool:
      compiled = [f.result() for f in [pool.submit(lambda f=f, a=a, k=k: f.lower(*a, **k)
                                                   .compile()) for f, a, k in jobs]]
    check_memory(compiled[1], self.mesh, f"{self.members} member(s) of {self.config.task}")

  def evaluation_example(self, policies: int, sharding=None) -> tuple[tuple, tuple, dict]:
    """Abstract `evaluate` arguments but the keys, for `policies` policies per member: the
    policies, their normalisers and `evaluation_inputs`, placed as the state is, or every
    leaf by `sharding`."""
    state = self.abstract_state
    if sharding is not None:
      state = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=sharding),
                           state)
    return ((state.learner.policy,) * policies, (state.normalizer,) * policies,
            self.evaluation_inputs(state))

  def evaluation_inputs(self, state) -> dict:
    """The keyword arguments `evaluate` takes for `state` (the one call form, compiled ahead
    and used by the runner): the source states where the source scores evaluation episodes
    (`evaluation_log_prob`), with the members' own values of its settings, else none."""
    if not hasattr(self.source, "evaluation_log_prob"):
      return {}
    return {"source": state.source, "source_settings": grid.split(state.settings)[2]}

  def member(self, tree, i: int):
    """Member i's part of a tree with a leading member axis (e.g. `state.learner`)."""
    return jax.tree.map(lambda x: x[i], tree)

  # --- state ------------------------------------------------------------------------------

  def _unroll_example(self) -> dict:
    t, d, a = self.config.unroll_length, self.env.observation_size, self.env.action_size
    example = {"observation": jnp.zeros((t + 1, d)), "action": jnp.zeros((t, a)),
               "behaviour_log_prob": jnp.zeros((t,)), "discount": jnp.zeros((t,))}
    if self.source.needs_task_reward:  # otherwise the task reward never enters the replay
      example["reward"] = jnp.zeros((t,))
    return example

  def _init_member(self, key: jax.Array):
    """One member's state but its environments, which `_init` starts for all members at once:
    (TrainState with env=None, its env keys [N, 2], its episode phases [N])."""
    cfg = self.config
    env_key, learner_key, source_key, key = jax.random.split(key, 4)
    storage = jax.tree.map(lambda x: jnp.zeros((cfg.replay_capacity,) + x.shape, x.dtype),
                           self._unroll_example())
    key, stagger_key = jax.random.split(key)
    start = jnp.zeros((cfg.num_envs,), jnp.int32)
    if cfg.stagger_episodes:
      phases = max(1, env_lib.EPISODE_LENGTH // cfg.unroll_length)
      start = cfg.unroll_length * jax.random.randint(stagger_key, (cfg.num_envs,), 0, phases)
    angles = self._angle_rows() if self._angle_features() else None
    norm = normalizer.init(self.env.observation_size, angles=angles)  # `_init`: each member's
    state = TrainState(
        learner=learner_lib.init(self.networks, self._init_learner, learner_key,
                                 norm.mean.shape[-1], self.env.action_size),
        normalizer=norm,
        replay=replay.ReplayState(storage, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32)),
        env=None, episode_return=None,
        source=self.source.init(source_key, self.env.observation_size, self.env.action_size),
        noise=None, key=key, iteration=None, settings=None)
    return state, jax.random.split(env_key, cfg.num_envs), start

  def _init(self, keys: jax.Array) -> TrainState:
    """Fresh members from their keys [P, 2] (`keys()`)."""
    members, env_keys, start = jax.vmap(self._init_member)(keys)
    if hasattr(self.source, "member_states"):  # what the source gives each member of its own
      members = members._replace(source=self.source.member_states(members.source,
                                                                  self.members))
    wraps = [self.member_config(i).wrap_angles for i in range(self.members)]
    if any(wraps):  # each member's period [P, D]; zeros in a member that wraps nothing
      period = jnp.asarray(self.env.observation_period(), jnp.float32)
      members = members._replace(normalizer=members.normalizer._replace(period=jnp.stack(
          [period if w else jnp.zeros_like(period) for w in wraps])))
    if self._angle_features():  # each member's angles [P, K, D]; zero rows: raw angles
      rows = jnp.asarray(self._angle_rows())
      members = members._replace(normalizer=members.normalizer._replace(angles=jnp.stack(
          [rows if self.member_config(i).angle_features else jnp.zeros_like(rows)
           for i in range(self.members)])))
    env_state = self.auto_reset.reset_from_keys(env_keys.reshape(-1, 2))  # [P * N]
    start = start.reshape(-1)
    episode_return = jnp.zeros(start.shape, jnp.float32)
    if self.config.stagger_episodes:
      env_state = env_state.replace(info=dict(
          env_state.info, step=start.astype(env_state.info["step"].dtype)))
      # Partial episodes are not reported. (float32, not weak-typed: a weak-typed leaf here
      # would differ from the iteration's output and make its second call compile again.)
      episode_return = jnp.where(start > 0, jnp.nan, 0.0).astype(jnp.float32)
    width = self.env.action_size if self._correlated else 0
    noise = jnp.full((start.shape[0], width), jnp.nan, jnp.float32)
    return members._replace(
        noise=jax.lax.with_sharding_constraint(noise, self._batch),
        replay=members.replay._replace(
            data=jax.lax.with_sharding_constraint(members.replay.data, self._member_batch)),
        env=jax.lax.with_sharding_constraint(env_state, self._batch),
        episode_return=jax.lax.with_sharding_constraint(episode_return, self._batch),
        iteration=jnp.zeros((), jnp.int32),
        settings=grid.arrays(self._settings, self._setting_names))

  def start_from(self, state: TrainState, policy, norm: normalizer.NormalizerState
                 ) -> TrainState:
    """`state` (fresh from `init`) with every member's policy, target policy (and average
    policy) set to `policy`
    (flax params of this run's policy network, e.g. a trained expert's) and its observation
    statistics to `norm`'s mean and variance, as long-run averages (the next update moves
    them by 1 - decay, not from scratch). Each member keeps its own `period`; the critic, the
    duals and the optimisers start as `init` made them. ValueError where `policy` does not fit
    this run's network."""
    mine = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype),
                        state.learner.policy)
    given = jax.tree.map(lambda x: jax.ShapeDtypeStruct(jnp.shape(x), jnp.result_type(x)),
                         policy)
    if jax.tree.structure(mine) != jax.tree.structure(given) or any(
        a.shape != b.shape for a, b in zip(jax.tree.leaves(mine), jax.tree.leaves(given))):
      raise ValueError("the starting policy's parameters do not fit this run's policy network "
                       f"(width {self.config.network_width}, head {self.config.policy_head})")
    if jnp.shape(norm.mean) != state.normalizer.mean.shape[1:]:
      raise ValueError(f"the starting policy's observation statistics have shape "
                       f"{jnp.shape(norm.mean)}, this run's {state.normalizer.mean.shape[1:]}")
    put = lambda new, old: jax.device_put(
        jnp.broadcast_to(jnp.asarray(new, old.dtype), old.shape), old.sharding)
    learner = state.learner._replace(
        policy=jax.tree.map(put, policy, state.learner.policy),
        target_policy=jax.tree.map(put, policy, state.learner.target_policy))
    if learner.average_policy is not None:  # (the first update replaces it anyway)
      learner = learner._replace(average_policy=jax.tree.map(put, policy,
                                                             learner.average_policy))
    # A count past which the bias correction 1 - d**count is 1 (to float precision for decays up
    # to ~0.99998; 0.99, the default: d**1e6 = 0).
    stats = state.normalizer._replace(
        mean=put(norm.mean, state.normalizer.mean), var=put(norm.var, state.normalizer.var),
        count=put(1_000_000, state.normalizer.count))
    return state._replace(learner=learner, normalizer=stats)

  def _shardings(self, abstract: TrainState) -> TrainState:
    per_member = lambda tree: jax.tree.map(lambda _: self._member, tree)  # [P, ...]
    bat = lambda tree: jax.tree.map(lambda _: self._batch, tree)
    return TrainState(
        learner=per_member(abstract.learner), normalizer=per_member(abstract.normalizer),
        replay=replay.ReplayState(jax.tree.map(lambda _: self._member_batch,
                                               abstract.replay.data),
                                  self._member, self._member),
        env=bat(abstract.env), episode_return=self._batch, source=per_member(abstract.source),
        noise=self._batch, key=self._member, iteration=self._replicated,
        settings=per_member(abstract.settings))

  # --- one iteration ----------------------------------------------------------------------

  def _policies(self, policy_params, norm, obs: jax.Array):
    """Each member's policy on its environments: obs [P * N, D] -> DiagonalGaussian [P, N, A]."""
    obs = obs.reshape((self.members, -1, obs.shape[-1]))
    apply = lambda params, norm, obs: self.networks.policy.apply(
        params, normalizer.normalize(norm, obs))
    return jax.vmap(apply)(policy_params, norm, obs)

  def _noise_multipliers(self, state: TrainState) -> jax.Array:
    """Each env's multiplier of its member's policy scale when acting, [P, N]: evenly from the
    member's `noise_scale_min` (its first env) to 1 (its last), at least 1e-6 (so that the
    behaviour density stays finite: an env at 0 acts with the mean action to 1e-6 of the
    scale, and Retrace's importance weights there are ~0, its targets one-step)."""
    p, n = self.members, self.config.num_envs
    low = state.settings.get("noise_scale_min", jnp.full((p,), self.config.noise_scale_min))
    spread = jnp.linspace(0.0, 1.0, n)  # (n >= 2 where any member scales: TrainConfig.check)
    return jnp.maximum(low[:, None] + (1.0 - low[:, None]) * spread, 1e-6)

  def _collect(self, state: TrainState, keys: jax.Array):
    """`unroll_length` steps of every env with its member's online policy; keys [P, 2].
    Returns (env, returns, noise, unrolls [P, N, ...], stats [P])."""
    p, t = self.members, self.config.unroll_length
    # Each member's correlation: [P] where members have their own, else the run's constant.
    c = state.settings.get("action_noise_correlation",
                           jnp.full((p,), self.config.action_noise_correlation)
                           if self._correlated else 0.0)
    multipliers = self._noise_multipliers(state) if self._scaled else None  # [P, N]

    def step(carry, key):  # key [P, 2]
      env_state, running, noise = carry  # noise [P * N, A or 0]
      pi = self._policies(state.learner.policy, state.normalizer, env_state.obs)
      by_member = noise.reshape(pi.mean.shape[:2] + noise.shape[-1:])  # [P, N, A or 0]
      in_axes = (0, 0, 0, 0 if self._correlated else None)  # (pi, key, noise, c) per member
      if multipliers is None:
        action, noise = jax.vmap(lambda pi, k, e, c: pi.sample_correlated(k, e, c),
                                 in_axes=in_axes)(pi, key, by_member, c)  # [P, N, A]
        # The behaviour density Retrace needs: the policy's Gaussian, each action's marginal.
        log_prob = pi.log_prob(action).reshape(-1)  # [P * N]
      else:  # each env's behaviour: the policy, its noise scaled by the env's multiplier
        pi = distributions.DiagonalGaussian(pi.mean, pi.scale * multipliers[..., None])
        e, noise = jax.vmap(lambda pi, k, e, c: pi.unit_noise(k, e, c), in_axes=in_axes)(
            pi, key, by_member, c)  # [P, N, A] each
        action = pi.mean + pi.scale * e
        # (from the draw's noise: at a multiplier of 1e-6, action - mean is mostly rounding)
        log_prob = pi.noise_log_prob(e).reshape(-1)  # [P * N]
      noise = noise.reshape(noise.shape[0] * noise.shape[1], noise.shape[2])
      action = action.reshape((-1, action.shape[-1]))  # [P * N, A]
      stepped = self.auto_reset.step(env_state, action)
      running = running + stepped.reward
      done = stepped.done > 0
      noise = jnp.where(done[:, None], jnp.nan, noise)  # a new episode's noise starts afresh
      whole = done & jnp.isfinite(running)  # a whole episode ended (not a staggered first one)
      out = {"observation": env_state.obs, "action": action, "behaviour_log_prob": log_prob,
             "reward": stepped.reward, "done": done, "whole": whole,
             "error": stepped.info["physics_error"] > 0,
             "finished_return": jnp.where(whole, running, 0.0)}
      return (stepped, jnp.where(done, 0.0, running), noise), out

    step_keys = jnp.swapaxes(jax.vmap(lambda k: jax.random.split(k, t))(keys), 0, 1)  # [T, P, 2]
    (env_state, running, noise), traj = jax.lax.scan(
        step, (state.env, state.episode_return, state.noise), step_keys)
    # traj leaves are time-major [T, P * N, ...]. The last observation is the true successor of
    # the last step: the ended episode's final observation where an episode ended there.
    observation = jnp.concatenate([traj["observation"], env_state.info["final_obs"][None]])
    discount = 1.0 - traj["done"].astype(jnp.float32)
    discount = discount.at[-1].set(1.0 - traj["error"][-1].astype(jnp.float32))
    unrolls = {"observation": observation, "action": traj["action"],
               "behaviour_log_prob": traj["behaviour_log_prob"], "discount": discount}
    if self.source.needs_task_reward:
      unrolls["reward"] = traj["reward"]
    by_member = lambda x: x.reshape((x.shape[0], p, -1) + x.shape[2:])  # [T, P, N, ...]
    unrolls = jax.tree.map(lambda x: jnp.moveaxis(by_member(x), 0, 2), unrolls)  # [P, N, T..]
    unrolls = jax.lax.with_sharding_constraint(unrolls, self._member_batch)
    traj = jax.tree.map(by_member, traj)
    total = lambda x: jnp.sum(x, axis=(0, 2))  # [P]
    episodes, whole = total(traj["done"]), total(traj["whole"])
    stats = {"episodes": episodes,
             # NaN in an iteration where no whole episode ended (not a return of 0)
             "train_return": jnp.where(whole > 0, total(traj["finished_return"])
                                       / jnp.maximum(whole, 1), jnp.nan),
             "train_reward": jnp.mean(traj["reward"], axis=(0, 2)),
             "physics_errors": total(traj["error"])}
    return env_state, running, noise, unrolls, stats

  def _learn(self, learner, source, norm, buffer, settings: dict, keys: jax.Array,
             train_source: bool = True, data=None):
    """One learner update of every member; keys [P, 2]. Returns (learner, source, metrics).
    Without `train_source` the source only relabels (its state and metrics unchanged)."""
    cfg = self.config
    learner_values, _, source_values = grid.split(settings)
    sample_key, source_key, update_key = jnp.moveaxis(
        jax.vmap(lambda k: jax.random.split(k, 3))(keys), 1, 0)  # [3, P, 2]
    batch = jax.vmap(lambda b, k: replay.sample(b, k, cfg.batch_size))(buffer, sample_key)
    batch = jax.lax.with_sharding_constraint(batch, self._member_batch)  # [P, B, ...]
    # Settings members may override come in as each member's entry of a [P] array.
    source_metrics = {}
    if train_source:
      source, source_metrics = jax.vmap(
          lambda s, b, k, v: self._source_with(v, data).update(s, b, k))(
              source, batch, source_key, source_values)
    if self.clones:  # the policy fitted to the source's pairs (cloning.py); no reward, no MPO
      def clone(learner, norm, source, key, values, svalues):
        obs, actions, target_metrics = self._source_with(svalues, data).policy_targets(
            source, key, cfg.batch_size * cfg.unroll_length)
        config = grid.learner_config(cfg.learner, values)
        learner, metrics = cloning.update(self.networks, config, learner, norm, obs, actions)
        return learner, {**metrics, **target_metrics}
      learner, metrics = jax.vmap(clone)(learner, norm, source, update_key, learner_values,
                                         source_values)
      return learner, source, {**metrics, **source_metrics}
    rewards, reward_metrics = jax.vmap(
        lambda s, b, v: self._source_with(v, data).relabel(s, b))(
        source, batch, source_values)
    def update(learner, norm, batch, rewards, key, values):
      config = grid.learner_config(cfg.learner, values)
      return learner_lib.update(self.networks, config, learner, norm, batch, rewards, key)
    learner, metrics = jax.vmap(update)(learner, norm, batch, rewards, update_key,
                                        learner_values)
    # (`_iteration` averages the source's metrics over its steps, the others over all updates)
    assert not source_metrics.keys() & (metrics.keys() | reward_metrics.keys()), (
        "a reward source's update metric shares its name with a learner or relabel metric")
    return learner, source, {**metrics, **source_metrics, **reward_metrics}

  def _iteration(self, state: TrainState, data=None) -> tuple[TrainState, dict]:
    """One iteration of every member; metrics are [P] arrays. `data`: the source's constant
    arrays (`source_data`), where it has some."""
    cfg = self.config
    key, collect_key, learn_key = jnp.moveaxis(
        jax.vmap(lambda k: jax.random.split(k, 3))(state.key), 1, 0)  # [3, P, 2]
    env_state, running, noise, unrolls, stats = self._collect(state, collect_key)
    if hasattr(self.source, "fresh_metrics"):  # diagnostics only (reward_sources.py)
      source_values = grid.split(state.settings)[2]
      stats = {**stats, **jax.vmap(
          lambda s, u, v: self._source_with(v, data).fresh_metrics(s, u))(
          state.source, unrolls, source_values)}
    observed = unrolls["observation"][:, :, :-1]  # [P, N, T, D]
    if self.clones:  # standardised as the observations the policy is fitted on
      n = observed.shape[1] * observed.shape[2]
      def targets(source, key, values):
        return self._source_with(values, data).policy_targets(source, key, n)[0]
      # (fold_in(k, i) is split(k, U)[i], update i's key: U is one no update takes)
      norm_keys = jax.vmap(lambda k: jax.random.fold_in(k, cfg.updates_per_iteration))(learn_key)
      observed = jax.vmap(targets)(state.source, norm_keys,
                                   grid.split(state.settings)[2])  # [P, N * T, D]
    norm = jax.vmap(lambda n, obs: normalizer.update(n, obs, cfg.normalizer_decay))(
        state.normalizer, observed)
    buffer = jax.vmap(replay.insert)(state.replay, unrolls)

    k = cfg.source_update_every

    def learn(carry, keys):  # keys [k, P, 2]: an update that trains the source, k - 1 that do not
      learner, source, metrics = self._learn(*carry, norm, buffer, state.settings, keys[0],
                                             data=data)
      if k > 1:
        def relabel_only(learner, key):
          learner, _, more = self._learn(learner, source, norm, buffer, state.settings, key,
                                         train_source=False, data=data)
          return learner, more
        learner, more = jax.lax.scan(relabel_only, learner, keys[1:])  # [k - 1, P]
        # every update's learner and reward metrics, the source's of its one step
        metrics = {name: (value + jnp.sum(more[name], axis=0)) / k if name in more else value
                   for name, value in metrics.items()}
      return (learner, source), metrics

    learn_keys = jax.vmap(lambda key: jax.random.split(key, cfg.updates_per_iteration))(
        learn_key)
    learn_keys = jnp.swapaxes(learn_keys, 0, 1)  # [U, P, 2]
    (learner, source), metrics = jax.lax.scan(
        learn, (state.learner, state.source),
        learn_keys.reshape((-1, k) + learn_keys.shape[1:]))  # [U / k, k, P, 2]
    metrics = {**jax.tree.map(lambda m: jnp.mean(m, axis=0), metrics), **stats}
    state = TrainState(learner=learner, normalizer=norm, replay=buffer, env=env_state,
                       episode_return=running, source=source, noise=noise, key=key,
                       iteration=state.iteration + 1, settings=state.settings)
    return state, metrics

  # --- evaluation -------------------------------------------------------------------------

  def _evaluate(self, policies: tuple, norms: tuple, keys: jax.Array,
                num_envs: int | None = None, source=None, source_settings=None, sampled=None):
    """Task returns [K, P, num_envs] (default eval_envs) of full episodes with the mean action of
    each of K policies per member (`policies`, `norms`: K trees [P, ...] each, e.g. the online
    and the average policy), or, where `sampled` [K] is 1, actions drawn from that policy afresh
    each step (the policy as the learner trains it, without the actors' correlated noise; the
    same standard normal draws for every sampled policy of a call, wherever it sits), all
    K on the same starts (keys [P, 2], `keys(1)`) and stepped as
    one batch: an episode is 1000 steps one after the other, each step's cost set by latency
    more than by the batch on a GPU, so K policies at once cost about what one does. With the
    members' `source` states (a source with `evaluation_log_prob`, e.g. FORM's) and their own
    values of its settings (`source_settings`, [P] each), also each episode's mean score of its
    transitions [K, P, num_envs], each member's by its own source: (returns, scores)."""
    n = num_envs or self.config.eval_envs
    k, p = len(policies), self.members
    # Each member's envs [K * n]: its n starts once per policy (the members stay the outer
    # axis, as the batch is sharded).
    reset_keys = jax.vmap(lambda key: jnp.tile(jax.random.split(key, n), (k, 1)))(keys)
    states = self.auto_reset.reset_from_keys(reset_keys.reshape(-1, 2))  # (its info keys too:
    states = jax.lax.with_sharding_constraint(states, self._batch)  # and sharding: one step trace)
    by_member = lambda x: x.reshape((p, k * n) + x.shape[1:])
    stack = lambda trees: jax.tree.map(lambda *x: jnp.stack(x, axis=1), *trees)  # [P, K, ...]
    policy_params, norm = stack(policies), stack(norms)

    def act(obs, key):  # obs [P * K * n, D], key [P, 2] -> the actions [P * K * n, A]
      obs = obs.reshape((p, k, n, obs.shape[-1]))
      pi = jax.vmap(self._policies, in_axes=1, out_axes=1)(policy_params, norm, obs)
      action = pi.mode()  # [P, K, n, A]
      if sampled is not None:  # (one draw per member and env, shared by the K policies)
        xi = jax.vmap(lambda key: jax.random.normal(key, action.shape[2:], action.dtype))(key)
        action = action + sampled[None, :, None, None] * pi.scale * xi[:, None]
      return action.reshape((-1, action.shape[-1]))

    def step(carry, key):
      env_state, total, score = carry
      step_all = jax.vmap(self.env.step)
      if self.per_device_env_steps:
        step_all = mesh_lib.per_device(step_all, self._batch)
      stepped = step_all(env_state, act(env_state.obs, key))
      # (one episode, no reset: obs -> stepped.obs is a transition; after a physics error the
      # state stands still, its steps scored as x -> x as its rewards are 0)
      if source is not None:
        score = score + jax.vmap(
            lambda s, x, x_next, v: self._source_with(v).evaluation_log_prob(s, x, x_next))(
                source, by_member(env_state.obs), by_member(stepped.obs),
                source_settings or {}).reshape(-1)
      return (stepped, total + stepped.reward, score), None

    zeros = jnp.zeros(p * k * n)
    # each step's key per member [T, P, 2], apart from the starts' (where `sampled`)
    step_keys = None if sampled is None else jnp.swapaxes(jax.vmap(lambda key: jax.random.split(
        jax.random.fold_in(key, 1), env_lib.EPISODE_LENGTH))(keys), 0, 1)
    (_, total, score), _ = jax.lax.scan(step, (states, zeros, zeros), step_keys,
                                        length=env_lib.EPISODE_LENGTH)
    by_policy = lambda x: jnp.swapaxes(x.reshape((p, k, n)), 0, 1)  # [K, P, n]
    if source is None:
      return by_policy(total)
    return by_policy(total), by_policy(score) / env_lib.EPISODE_LENGTH


def program_bytes(compiled) -> int | None:
  """Device memory a compiled program needs per device (arguments, outputs, temporaries; XLA's
  own analysis), or None where the backend does not say."""
  try:
    m = compiled.memory_analysis()
  except (AttributeError, NotImplementedError, RuntimeError):
    return None
  if m is None:
    return None
  return (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
          - m.alias_size_in_bytes)


def check_memory(compiled, mesh, what: str, limit: int | None = None) -> None:
  """Refuses, before it runs, a program that needs more device memory than a device of `mesh`
  has (`limit`: default the device's own `bytes_limit`; the CPU reports none: no check)."""
  if limit is None:
    stats = mesh.devices.flat[0].memory_stats() if hasattr(mesh.devices.flat[0],
                                                           "memory_stats") else None
    limit = (stats or {}).get("bytes_limit")
  needed = program_bytes(compiled)
  if limit and needed and needed > limit:
    raise ValueError(f"{what}: one training iteration needs {needed / 2**30:.1f} GiB per "
                     f"device, a device has {limit / 2**30:.1f} GiB; use fewer members, fewer "
                     "environments or a smaller replay")


def iterations_for(config: TrainConfig, env_steps: int) -> int:
  """Iterations needed to take at least `env_steps` environment steps."""
  return max(1, math.ceil(env_steps / config.env_steps_per_iteration))
