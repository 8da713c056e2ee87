"""Comparing our tasks with dm_control's: reference data from dm_control, the same states in MJX.

`collect_reference` (needs dm-control, a test dependency) rolls dm_control's own environment
with random actions and records, per sampled step: the physics state before the step, the
action, and dm_control's observation, reward and physics state after it. `physics_batch` and
`observe_batch` redo those steps with our physics and task functions, so the two can be
compared element by element, in a test on the CPU or in a benchmark on the GPU (the arrays
travel as an .npz file).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from mjx_form import cpu
from mjx_form.sim import physics as physics_lib
from mjx_form.sim.env import Task, flatten_observation

STATE_FIELDS = ("qpos", "qvel", "act", "qacc_warmstart", "ctrl")


def load_dm_control_env(task_name: str, seed: int):
  """dm_control's environment for one of our task names, e.g. 'humanoid_run'."""
  try:
    from dm_control import suite
  except ImportError as e:  # pragma: no cover - depends on the environment
    raise ImportError("parity checks need dm-control: pip install -e '.[test]'") from e
  domain, task = task_name.split("_", 1)
  return suite.load(domain, task, task_kwargs={"random": seed})


def physics_state(physics) -> dict[str, np.ndarray]:
  d = physics.data
  return {f: np.array(getattr(d, f), np.float64) for f in STATE_FIELDS}


def task_variables(task_name: str, physics) -> dict[str, np.ndarray]:
  """The per-episode task variables our tasks keep in `State.task`."""
  if task_name.startswith("reacher"):
    return {"target": np.array(physics.named.model.geom_pos["target", :2])}
  return {}


def collect_reference(task_name: str, num_states: int, seed: int = 0, burn_in: int = 5,
                      stride: int = 37, action_scale: float = 1.2) -> dict[str, np.ndarray]:
  """Samples `num_states` transitions of dm_control's env under uniform random actions.

  Actions are uniform in `action_scale` times the control range, so some components lie
  outside it (dm_control passes them to MuJoCo unclipped). The samples are spread over
  episodes: `burn_in` steps after each reset, then one sample every `stride` steps. Keys: `<field>` (state before), `next_<field>` (state after),
  `action`, `obs`/`reward` (after the step), `task_<name>` (task variables).
  """
  env = load_dm_control_env(task_name, seed)
  rng = np.random.RandomState(seed + 1)
  spec = env.action_spec()
  records: dict[str, list] = {}
  step_in_episode = 0
  timestep = env.reset()
  while len(records.get("action", [])) < num_states:
    action = rng.uniform(action_scale * spec.minimum, action_scale * spec.maximum)
    sample = step_in_episode >= burn_in and (step_in_episode - burn_in) % stride == 0
    if sample:
      before = physics_state(env.physics)
      task = task_variables(task_name, env.physics)
    timestep = env.step(action)
    step_in_episode += 1
    if sample:
      row = {**before, **{f"next_{k}": v for k, v in physics_state(env.physics).items()},
             **{f"task_{k}": v for k, v in task.items()}, "action": action,
             "obs": flat_observation(timestep.observation), "reward": np.float64(timestep.reward)}
      for k, v in row.items():
        records.setdefault(k, []).append(v)
    if timestep.last():
      timestep = env.reset()
      step_in_episode = 0
  return {k: np.stack(v) for k, v in records.items()}


def flat_observation(observation) -> np.ndarray:
  """dm_control's observation dict flattened in order, as float64."""
  return np.concatenate([np.asarray(v, np.float64).ravel() for v in observation.values()])


@physics_lib.full_precision  # (physics_step's context: its stages reuse this trace)
def reference_data(model: mjx.Model, arrays: dict[str, jax.Array]) -> mjx.Data:
  """MJX data holding one recorded dm_control state, its position and velocity stages
  recomputed from qpos/qvel as they are in dm_control's data after a step."""
  d = mjx.make_data(model)
  d = d.replace(**{f: jnp.asarray(arrays[f], d.qpos.dtype) for f in STATE_FIELDS})
  return physics_lib.shared_position_velocity_stages(model, d)


def reference_task(arrays: dict[str, jax.Array]) -> dict[str, jax.Array]:
  return {k[len("task_"):]: jnp.asarray(v, jnp.float32) for k, v in arrays.items()
          if k.startswith("task_")}


def _state_fields(arrays):
  return {f: arrays[f] for f in STATE_FIELDS}


def _physics_batch_fn(model, states, actions, n_substeps, bounded_solver_loop=False):
  def one(state, action):
    d = reference_data(model, state).replace(ctrl=jnp.asarray(action, state["qpos"].dtype))
    return physics_lib.physics_step(model, d, n_substeps, bounded_solver_loop,
                                    stages=physics_lib.shared_position_velocity_stages)
  return jax.vmap(one)(states, actions)


@functools.cache
def _physics_batch():
  """The batched step, compiled once per model structure (a parity check runs it once)."""
  return jax.jit(_physics_batch_fn, static_argnums=(3, 4),
                 compiler_options=cpu.run_once_compiler_options())


def physics_batch(env: Task, states: dict, actions) -> mjx.Data:
  """One control step of the physics alone from each recorded state (batched).

  The model is an argument of the compiled function, so tasks that share a domain's model
  (walker stand/walk/run, ...) share one compilation.
  """
  return _physics_batch()(env.mjx_model, _state_fields(states), actions, env.n_substeps,
                          env.solver_settings.bounded_solver_loop)


def observe_batch(env: Task, data: mjx.Data, task: dict) -> tuple[jax.Array, jax.Array]:
  """Flat observations and rewards of batched data (what `step` reports after physics)."""
  return _observe_fn(env)(data, task)


@functools.cache
def _observe_fn(env: Task):
  """One jitted observe per task object, so repeated calls (a rollout) do not re-trace."""
  @physics_lib.full_precision
  def one(d, t):
    return flatten_observation(env.get_observation(d, t)), env.get_reward(d, t)
  return jax.jit(jax.vmap(one), compiler_options=cpu.run_once_compiler_options())
