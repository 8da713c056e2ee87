"""Comparing our tasks with dm_control's: reference data from dm_control, the same states in MJX.

`collect_reference` (needs dm-control, a test dependency) rolls dm_control's own environment
with random actions and records, per sampled step: the physics state before the step, the
action, and dm_control's observation, reward and physics state after it. `reference_state`
puts a recorded state into one of our `State`s, so the two can be compared element by element,
in a test on the CPU or in a benchmark on the GPU (the arrays travel as an .npz file).
"""

from __future__ import annotations

import numpy as np
import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_form import physics as physics_lib
from mjx_form.env import State, Task

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
                      stride: int = 7, action_scale: float = 1.0) -> dict[str, np.ndarray]:
  """Samples `num_states` transitions of dm_control's env under uniform random actions.

  The samples are spread over episodes: `burn_in` steps after each reset, then one sample
  every `stride` steps. Keys: `<field>` (state before), `next_<field>` (state after),
  `action`, `obs`/`reward` (after the step), `task_<name>` (task variables).
  """
  env = load_dm_control_env(task_name, seed)
  rng = np.random.RandomState(seed + 1)
  spec = env.action_spec()
  records: dict[str, list] = {}
  step_in_episode = 0
  timestep = env.reset()
  while len(records.get("action", [])) < num_states:
    action = action_scale * rng.uniform(spec.minimum, spec.maximum)
    sample = step_in_episode >= burn_in and (step_in_episode - burn_in) % stride == 0
    if sample:
      before = physics_state(env.physics)
      task = task_variables(task_name, env.physics)
    timestep = env.step(action)
    step_in_episode += 1
    if sample:
      row = {**before, **{f"next_{k}": v for k, v in physics_state(env.physics).items()},
             **{f"task_{k}": v for k, v in task.items()}, "action": action,
             "obs": _flat_obs(timestep.observation), "reward": np.float64(timestep.reward)}
      for k, v in row.items():
        records.setdefault(k, []).append(v)
    if timestep.last():
      timestep = env.reset()
      step_in_episode = 0
  return {k: np.stack(v) for k, v in records.items()}


def _flat_obs(observation) -> np.ndarray:
  return np.concatenate([np.asarray(v, np.float64).ravel() for v in observation.values()])


def reference_state(env: Task, arrays: dict[str, jax.Array]) -> State:
  """Our `State` holding one recorded dm_control physics state (works under jit/vmap).

  The position and velocity stages are recomputed from qpos/qvel, as they are in dm_control's
  data after a step; the observation fields are left empty (they are outputs of `step`).
  """
  d = mjx.make_data(env.mjx_model)
  d = d.replace(**{f: jnp.asarray(arrays[f], d.qpos.dtype) for f in STATE_FIELDS})
  d = physics_lib.position_velocity_stages(env.mjx_model, d)
  task = {k[len("task_"):]: jnp.asarray(v, jnp.float32) for k, v in arrays.items()
          if k.startswith("task_")}
  zero = jnp.zeros(())
  info = {"step": jnp.zeros((), jnp.int32), "episode_return": zero,
          "key": jax.random.PRNGKey(0), "physics_error": zero}
  obs = jnp.zeros((env.observation_size,))
  parts = {k: jnp.zeros((n,)) for k, n in env.observation_layout.items()}
  return State(data=d, obs=obs, obs_parts=parts, reward=zero, done=zero, truncation=zero,
               task=task, info=info)


def step_from_reference(env: Task, arrays: dict[str, jax.Array]) -> State:
  """One of our control steps from a recorded state with the recorded action."""
  return env.step(reference_state(env, arrays), arrays["action"])
