"""The functional environment API shared by every task: `reset(key)` and `step(state, action)`.

A `Task` owns the compiled MuJoCo/MJX model of its domain and defines, like dm_control's
`base.Task`, how an episode starts (`initialize_episode`), what is observed (`get_observation`)
and what is rewarded (`get_reward`). Everything here is pure JAX on one environment; batch it
with `jax.vmap` and auto-reset it with `mjx_form.sim.wrappers.AutoReset`.
"""

from __future__ import annotations

import abc
import collections
import dataclasses
import xml.etree.ElementTree as ET
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import mjx

from mjx_form.sim import physics as physics_lib

EPISODE_LENGTH = 1000  # control steps; no Control Suite task terminates early


def action_bounds(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
  """([A], [A]) float32: the range MuJoCo clamps each actuator's control to, its `ctrlrange`
  where it is control-limited, -inf / inf where not (or where the model disables clamping).
  dm_control's action_spec gives the same bounds (+-mjMAXVAL where unlimited; every task's
  actuators are limited): [-1, 1] but for quadruped's lift actuators, to 1.1, and extenders,
  to 0.8."""
  limited = model.actuator_ctrllimited.astype(bool)
  if model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL:
    limited = np.zeros_like(limited)
  low = np.where(limited, model.actuator_ctrlrange[:, 0], -np.inf).astype(np.float32)
  high = np.where(limited, model.actuator_ctrlrange[:, 1], np.inf).astype(np.float32)
  return low, high


def observation_names(layout: dict[str, int]) -> list[str]:
  """One name per flat observation dimension of `layout` ({'position': 8, 'height': 1, ...}):
  'height' for a size-1 element, 'position[1]' for the second entry of a larger one."""
  return [name if size == 1 else f"{name}[{i}]" for name, size in layout.items()
          for i in range(size)]


@struct.dataclass
class State:
  """One environment's state. Batched states carry a leading batch axis on every leaf."""

  data: mjx.Data  # MJX physics data, position and velocity stages up to date
  obs: jax.Array  # (obs_dim,) flat observation, dm_control's flattening order
  obs_parts: dict[str, jax.Array]  # the named observation elements, as dm_control names them
  reward: jax.Array  # () reward of the last step (0 after a reset)
  done: jax.Array  # () 1.0 where the episode ended at this step
  truncation: jax.Array  # () 1.0 where it ended by the time limit or a physics error
  task: dict[str, jax.Array]  # per-episode task variables (e.g. reacher's target position)
  info: dict[str, jax.Array]  # step count, episode return, RNG key, physics-error flag


class Task(abc.ABC):
  """Base class for the Control Suite tasks on MJX."""

  domain: str = ""
  task: str = ""
  n_substeps: int = 1
  # The observation elements' names and sizes, in dm_control's flattening order. Declared, not
  # traced (tracing a reset to learn them cost seconds per task object); every reset and step
  # checks `get_observation` against it while tracing (`check_observation_layout`).
  observation_elements: tuple[tuple[str, int], ...] = ()
  # Observation dimensions that are unbounded hinge angles given raw (qpos of a joint without
  # limits, e.g. a planar body's pitch), named as `observation_names` names them: whole turns
  # apart they are the same state. The agent may wrap them (`TrainConfig.wrap_angles`).
  periodic_observations: tuple[str, ...] = ()
  # Fast-mode solver settings for this domain; see mjx_form.sim.physics and the README's tables.
  fast_settings: physics_lib.SolverSettings = physics_lib.PARITY

  def __init__(self, physics: str | physics_lib.SolverSettings = physics_lib.DEFAULT_PHYSICS):
    self.physics = physics_lib.check_physics_mode(physics)
    if isinstance(physics, physics_lib.SolverSettings):
      settings = physics
    else:
      settings = physics_lib.PARITY if physics == "parity" else self.fast_settings
      if physics == "fast_bounded":
        settings = dataclasses.replace(settings, bounded_solver_loop=True)
      if physics == "fast_ls4" and settings != physics_lib.PARITY:  # (reacher: no contacts)
        settings = dataclasses.replace(settings, ls_iterations=min(
            settings.ls_iterations or 50, physics_lib.FAST_LS_ITERATIONS))  # (None: MuJoCo's 50)
    root = self.model_xml()
    physics_lib.apply_solver_settings(root, settings)
    self.solver_settings = settings
    self.mj_model = physics_lib.compile_model(root, self.model_assets())
    self.mjx_model = physics_lib.put_model(self.mj_model)
    self._reset_model = physics_lib.without_actuation(self.mj_model)
    # Jitted per task object, so the rollout, the auto-reset's restarts and the evaluation of a
    # run all reuse one trace of each for the same argument types: tracing MJX in Python, not
    # XLA, was most of a run's start-up (README). XLA inlines the nested programs.
    self.reset = jax.jit(self.reset)
    self.step = jax.jit(self.step)

  # --- what each task defines -------------------------------------------------------------

  @abc.abstractmethod
  def model_xml(self) -> ET.Element:
    """The domain's MJCF tree (dm_control's XML, possibly edited as dm_control edits it)."""

  @abc.abstractmethod
  def model_assets(self) -> dict[str, bytes]:
    """Files the XML includes, by the names it includes them under."""

  @abc.abstractmethod
  def initialize_episode(self, data: mjx.Data, key: jax.Array) -> tuple[mjx.Data, dict]:
    """Sets the initial qpos/qvel/act from dm_control's reset distribution.

    `data` is MuJoCo's reset state (qpos0, zero velocities). Returns the data (its stages need
    not be computed) and the episode's task variables.
    """

  @abc.abstractmethod
  def get_observation(self, data: mjx.Data, task: dict) -> collections.OrderedDict:
    """dm_control's observation dict, element by element."""

  @abc.abstractmethod
  def get_reward(self, data: mjx.Data, task: dict) -> jax.Array:
    """dm_control's reward for the current data."""

  # --- the functional API -----------------------------------------------------------------

  @property
  def name(self) -> str:
    return f"{self.domain}_{self.task}"

  @property
  def action_size(self) -> int:
    return self.mj_model.nu

  @property
  def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
    """([A], [A]): the control range MuJoCo clamps actions to (`action_bounds`)."""
    return action_bounds(self.mj_model)

  def clip_action(self, action: jax.Array) -> jax.Array:
    """Actions [..., A] clipped to `action_bounds`: what the simulator applies, the action to
    record or show. (`step` of either gives the same physics; the tasks' control costs,
    hopper's and humanoid's, are 0 at and beyond their bounds, so the same reward too.)"""
    low, high = self.action_bounds
    return jnp.clip(action, low, high)

  @property
  def observation_size(self) -> int:
    return sum(self.observation_layout.values())

  @property
  def observation_layout(self) -> dict[str, int]:
    """Names and sizes of the observation elements, in flattening order."""
    return dict(self.observation_elements)

  @property
  def observation_names(self) -> list[str]:
    return observation_names(self.observation_layout)

  def observation_period(self) -> np.ndarray:
    """[D] float32: 2 pi at each of `periodic_observations`, 0 elsewhere."""
    period = np.zeros(self.observation_size, np.float32)
    for name in self.periodic_observations:
      period[self.observation_names.index(name)] = 2 * np.pi
    return period

  def check_observation_layout(self, parts: dict[str, Any]) -> None:
    """Raises ValueError where `get_observation`'s elements differ from the declared layout."""
    got = [(k, int(np.prod(np.shape(v)))) for k, v in parts.items()]
    if got != list(self.observation_elements):
      raise ValueError(f"{self.name}: get_observation gives {got}, but the task declares "
                       f"observation_elements = {list(self.observation_elements)}")

  @property
  def control_timestep(self) -> float:
    return float(self.mj_model.opt.timestep) * self.n_substeps

  @physics_lib.full_precision
  def reset(self, key: jax.Array) -> State:
    """Draws a fresh initial state from dm_control's reset distribution."""
    key, init_key = jax.random.split(key)
    data, task = self.initialize_episode(mjx.make_data(self.mjx_model), init_key)
    return self._first_state(data, task, key)

  @physics_lib.full_precision
  def reset_to(self, qpos: jax.Array, qvel: jax.Array, act: jax.Array, task: dict,
               key: jax.Array) -> State:
    """The first state of an episode starting at these positions, velocities, actuator
    activations and task variables (as `State.task` holds them): e.g. a dm_control episode's
    start, replayed here. For a state `s` drawn by `reset`, `reset_to(s.data.qpos, s.data.qvel,
    s.data.act, s.task, key)` is `s` again, but for the RNG key and the solver's warm start
    (zero here; a reset that settles the model, as cheetah's, leaves one)."""
    data = mjx.make_data(self.mjx_model)
    data = data.replace(qpos=jnp.asarray(qpos, data.qpos.dtype),
                        qvel=jnp.asarray(qvel, data.qvel.dtype),
                        act=jnp.asarray(act, data.act.dtype))
    return self._first_state(data, dict(task), key)

  def _first_state(self, data: mjx.Data, task: dict, key: jax.Array) -> State:
    """An episode's first state from its initial qpos/qvel/act and task variables."""
    data = self.after_reset(data)
    obs_parts = self.get_observation(data, task)
    self.check_observation_layout(obs_parts)
    zero = jnp.zeros(())
    info = {"step": jnp.zeros((), jnp.int32), "episode_return": zero, "key": key,
            "physics_error": zero}
    return State(data=data, obs=flatten_observation(obs_parts), obs_parts=dict(obs_parts),
                 reward=zero, done=zero, truncation=zero, task=task, info=info)

  @physics_lib.full_precision
  def step(self, state: State, action: jax.Array) -> State:
    """One control step. Actions are written to `ctrl` unclipped; MuJoCo clamps them to
    `ctrlrange` and the control-cost rewards see them as given, as in dm_control.

    A NaN/inf in the action or the resulting physics state ends the episode with
    `info['physics_error'] = 1`, zero reward and the previous observation; the auto-reset
    wrapper then draws a new start. Physics, observation and reward run at full float32
    matmul precision (`physics.full_precision`), also on GPUs.
    """
    action = jnp.asarray(action, state.data.ctrl.dtype)
    data = state.data.replace(ctrl=action)
    data = physics_lib.physics_step(self.mjx_model, data, self.n_substeps,
                                    self.solver_settings.bounded_solver_loop)
    obs_parts = self.get_observation(data, state.task)
    self.check_observation_layout(obs_parts)
    obs = flatten_observation(obs_parts)
    reward = jnp.asarray(self.get_reward(data, state.task), jnp.float32)

    ok = jnp.all(jnp.isfinite(action)) & physics_lib.physics_state_is_finite(data)
    ok = ok & jnp.all(jnp.isfinite(obs)) & jnp.isfinite(reward)
    reward = jnp.where(ok, reward, 0.0)
    obs = jnp.where(ok, obs, state.obs)
    obs_parts = jax.tree.map(lambda new, old: jnp.where(ok, new, old), dict(obs_parts),
                             state.obs_parts)

    step_count = state.info["step"] + 1
    truncation = (step_count >= EPISODE_LENGTH) | ~ok
    info = dict(state.info, step=step_count, episode_return=state.info["episode_return"] + reward,
                physics_error=(~ok).astype(jnp.float32))
    return state.replace(data=data, obs=obs, obs_parts=obs_parts, reward=reward,
                         done=truncation.astype(jnp.float32),
                         truncation=truncation.astype(jnp.float32), info=info)

  # --- helpers shared by the tasks --------------------------------------------------------

  def after_reset(self, data: mjx.Data) -> mjx.Data:
    """dm_control's `after_reset`: `mj_forward` with actuation disabled."""
    if self.solver_settings.bounded_solver_loop:
      return physics_lib.partitionable.forward(self._reset_model, data)
    return mjx.forward(self._reset_model, data)

  def body_id(self, name: str) -> int:
    return mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_BODY, name)

  def geom_id(self, name: str) -> int:
    return mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_GEOM, name)

  def sensor_slice(self, name: str) -> slice:
    i = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_SENSOR, name)
    if i < 0:
      raise KeyError(f"no sensor named {name!r} in the {self.domain} model")
    adr = int(self.mj_model.sensor_adr[i])
    return slice(adr, adr + int(self.mj_model.sensor_dim[i]))

  def sensor_indices(self, *sensor_types: int) -> np.ndarray:
    """sensordata indices of all sensors of the given types, in model order (as dm_control)."""
    m = self.mj_model
    ids = np.nonzero(np.isin(m.sensor_type, sensor_types))[0]
    return np.concatenate([np.arange(m.sensor_adr[i], m.sensor_adr[i] + m.sensor_dim[i])
                           for i in ids]).astype(np.int32)


def flatten_observation(parts: dict[str, Any]) -> jax.Array:
  """Concatenates observation elements in order, as dm_control's `flatten_observation`."""
  return jnp.concatenate([jnp.ravel(v) for v in parts.values()]).astype(jnp.float32)

