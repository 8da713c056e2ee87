"""Task registry, specs and models against dm_control's (no compilation of MJX steps here)."""

import dataclasses

import jax
import numpy as np
import pytest

import tasks
from mjx_form.sim import parity

# From ../shared/DESIGN.md: the paper's 13 tasks with dm_control's timing and sizes.
EXPECTED = {  # name: (control dt, substeps, obs dims, action dims)
    "reacher_easy": (0.02, 1, 6, 2), "reacher_hard": (0.02, 1, 6, 2),
    "cheetah_run": (0.01, 1, 17, 6),
    "quadruped_walk": (0.02, 4, 78, 12), "quadruped_run": (0.02, 4, 78, 12),
    "hopper_stand": (0.02, 4, 15, 4), "hopper_hop": (0.02, 4, 15, 4),
    "walker_stand": (0.025, 10, 24, 6), "walker_walk": (0.025, 10, 24, 6),
    "walker_run": (0.025, 10, 24, 6),
    "humanoid_stand": (0.025, 5, 67, 21), "humanoid_walk": (0.025, 5, 67, 21),
    "humanoid_run": (0.025, 5, 67, 21),
}


def test_registry_holds_the_papers_13_tasks():
  assert set(tasks.TASKS) == set(EXPECTED)


def test_unknown_task_is_a_clear_error():
  with pytest.raises(ValueError, match="unknown task 'humanoid_fly'.*humanoid_run"):
    tasks.make("humanoid_fly")


def test_unknown_physics_mode_is_a_clear_error():
  with pytest.raises(ValueError, match="unknown physics mode 'slow'.*parity.*fast"):
    tasks.make("reacher_easy", physics="slow")


@pytest.mark.parametrize("name", tasks.TASKS)
def test_specs_and_model_match_dm_control(name):
  env = tasks.make(name, physics="parity")
  dm_env = parity.load_dm_control_env(name, seed=0)
  control_dt, substeps, obs_dims, act_dims = EXPECTED[name]
  assert env.n_substeps == dm_env._n_sub_steps == substeps
  assert env.control_timestep == pytest.approx(dm_env.control_timestep()) == pytest.approx(control_dt)
  assert env.action_size == dm_env.action_spec().shape[0] == act_dims
  # The control range MuJoCo clamps actions to is the action spec's (quadruped's is not [-1, 1]).
  low, high = env.action_bounds
  np.testing.assert_array_equal(low, dm_env.action_spec().minimum.astype(np.float32))
  np.testing.assert_array_equal(high, dm_env.action_spec().maximum.astype(np.float32))
  dm_layout = {k: int(np.prod(v.shape)) for k, v in dm_env.observation_spec().items()}
  assert list(env.observation_layout.items()) == list(dm_layout.items())  # names, sizes, order
  assert env.observation_size == obs_dims
  # 1000 control steps per episode, as dm_control's time limit gives.
  assert round(dm_env._step_limit) == 1000

  ours, theirs = env.mj_model, dm_env.physics.model._model
  for field in ("nq", "nv", "nu", "na", "nbody", "ngeom", "njnt", "nsensor"):
    assert getattr(ours, field) == getattr(theirs, field), field
  for field in ("body_mass", "body_inertia", "body_pos", "geom_size", "geom_pos", "geom_type",
                "geom_contype", "geom_conaffinity", "geom_friction", "jnt_range", "jnt_limited",
                "dof_damping", "dof_armature", "actuator_gear", "actuator_ctrlrange",
                "actuator_gainprm", "actuator_biasprm", "actuator_dynprm", "sensor_type",
                "qpos0"):
    np.testing.assert_array_equal(getattr(ours, field), getattr(theirs, field), err_msg=field)
  for field in ("timestep", "iterations", "ls_iterations", "tolerance", "solver", "cone",
                "integrator", "disableflags"):
    assert getattr(ours.opt, field) == getattr(theirs.opt, field), field


@pytest.mark.parametrize("name", ["cheetah_run", "humanoid_run"])
def test_fast_mode_changes_only_solver_settings(name):
  parity_model = tasks.make(name, physics="parity").mj_model
  fast = tasks.make(name, physics="fast")
  settings = fast.solver_settings
  assert settings.iterations is not None and settings.iterations < parity_model.opt.iterations
  assert fast.mj_model.opt.iterations == settings.iterations
  assert fast.mj_model.opt.timestep == parity_model.opt.timestep
  np.testing.assert_array_equal(fast.mj_model.body_mass, parity_model.body_mass)
  np.testing.assert_array_equal(fast.mj_model.geom_size, parity_model.geom_size)


def test_a_wrong_observation_declaration_is_caught_while_tracing():
  """The declared layout is checked against get_observation by every reset and step trace.
  (Objects of its own, `tasks.build`: the one `tasks.make` shares must stay as built.)"""
  env = tasks.build("reacher_easy")
  env.observation_elements = (("position", 2), ("velocity", 2), ("to_target", 2))  # reordered
  with pytest.raises(ValueError, match="reacher_easy: get_observation gives .*to_target"):
    jax.eval_shape(env.reset, jax.random.PRNGKey(0))
  state = jax.eval_shape(tasks.build("reacher_easy").reset, jax.random.PRNGKey(0))
  assert tasks.make("reacher_easy").observation_elements != env.observation_elements
  env.observation_elements = (("position", 2), ("to_target", 3), ("velocity", 2))  # a size
  with pytest.raises(ValueError, match="observation_elements"):
    jax.eval_shape(env.step, state, jax.numpy.zeros(2))


@pytest.mark.parametrize("name", ["walker_walk", "humanoid_run", "reacher_easy"])
def test_fast_ls4_is_fast_with_the_line_search_capped(name):
  fast = tasks.make(name, physics="fast").solver_settings
  capped = tasks.make(name, physics="fast_ls4")
  if fast.ls_iterations is None:  # reacher: contacts disabled, nothing to cap
    assert capped.solver_settings == fast
  else:
    assert capped.solver_settings == dataclasses.replace(fast, ls_iterations=4)
    assert capped.mj_model.opt.ls_iterations == 4 and capped.physics == "fast_ls4"
