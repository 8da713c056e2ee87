"""The functional API, auto-reset, NaN handling, the device mesh and the command line.

Reacher keeps these fast: its step compiles in seconds.
"""

from __future__ import annotations

import functools
import os
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.extend import core as jax_core

import tasks
from conftest import load_script
from mjx_form import cpu
from mjx_form import mesh as mesh_lib
from mjx_form.sim import env as env_lib
from mjx_form.sim.wrappers import AutoReset

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NUM_ENVS = 4
# The tests that use `compiled()` run in one xdist worker, which compiles reset and step once.
COMPILED_ONCE = pytest.mark.xdist_group("env")
# The programs here run a few times on a few environments (or are only read): XLA's backend
# optimisation would only cost compile time (CI time; mjx_form.cpu).
RUN_ONCE = cpu.run_once_compiler_options()


@functools.cache
def reacher():
  return AutoReset(tasks.make("reacher_easy"))


@functools.cache
def compiled():
  env = reacher()
  return (jax.jit(env.reset, static_argnums=1, compiler_options=RUN_ONCE),
          jax.jit(env.step, compiler_options=RUN_ONCE))


def test_make_keeps_one_task_per_physics_device_and_width():
  """tasks.make gives the same object again (its traced reset and step are reused by every run
  of the process), a new one for another physics mode, another default device (the host
  evaluation's model stays on its device) or float64, and after clear_cache(); tasks.build
  always a new one."""
  first = tasks.make("reacher_easy")
  assert tasks.make("reacher_easy") is first
  assert tasks.make("reacher_easy", physics="parity") is not first
  assert tasks.make("reacher_hard") is not first
  with jax.default_device(jax.devices()[1]):
    other = tasks.make("reacher_easy")
  assert other is not first
  assert other.mjx_model.body_mass.devices() == {jax.devices()[1]}
  assert first.mjx_model.body_mass.devices() == {jax.devices()[0]}
  with jax.enable_x64(True):
    wide = tasks.make("reacher_easy")
  assert wide is not first and wide.mjx_model.body_mass.dtype == np.float64
  assert first.mjx_model.body_mass.dtype == np.float32
  assert tasks.build("reacher_easy") is not first
  tasks.clear_cache()
  assert tasks.make("reacher_easy") is not first


@COMPILED_ONCE
def test_state_shapes_under_jit_and_vmap():
  reset, step = compiled()
  state = reset(jax.random.PRNGKey(0), NUM_ENVS)
  state = step(state, jnp.zeros((NUM_ENVS, 2)))
  assert state.obs.shape == (NUM_ENVS, 6)
  assert set(state.obs_parts) == {"position", "to_target", "velocity"}
  assert state.reward.shape == state.done.shape == state.truncation.shape == (NUM_ENVS,)
  np.testing.assert_array_equal(state.info["step"], 1)
  np.testing.assert_allclose(np.concatenate([state.obs_parts[k] for k in
                                             ("position", "to_target", "velocity")], axis=1),
                             state.obs)


@COMPILED_ONCE
def test_nan_or_inf_action_resets_that_env_and_is_counted():
  reset, step = compiled()
  state = step(reset(jax.random.PRNGKey(1), NUM_ENVS), jnp.zeros((NUM_ENVS, 2)))
  action = jnp.zeros((NUM_ENVS, 2)).at[1, 0].set(jnp.nan).at[3, 1].set(jnp.inf)
  after = step(state, action)
  np.testing.assert_array_equal(after.info["physics_errors"], [0, 1, 0, 1])
  np.testing.assert_array_equal(after.done, [0, 1, 0, 1])
  np.testing.assert_array_equal(after.info["step"], [2, 0, 2, 0])  # 1 and 3 restarted
  np.testing.assert_array_equal(np.asarray(after.reward)[[1, 3]], 0.0)
  assert np.isfinite(after.obs).all() and np.isfinite(after.data.qvel).all()
  assert np.isfinite(after.info["final_obs"]).all()
  # Later steps keep counting per environment.
  again = step(after, action)
  np.testing.assert_array_equal(again.info["physics_errors"], [0, 2, 0, 2])


@COMPILED_ONCE
def test_nan_in_physics_state_is_detected():
  reset, step = compiled()
  state = reset(jax.random.PRNGKey(2), NUM_ENVS)
  state = state.replace(data=state.data.replace(qvel=state.data.qvel.at[2, 0].set(jnp.inf)))
  after = step(state, jnp.zeros((NUM_ENVS, 2)))
  np.testing.assert_array_equal(after.info["physics_errors"], [0, 0, 1, 0])
  assert np.isfinite(after.data.qvel).all()


@COMPILED_ONCE
def test_episode_lasts_1000_steps_and_restarts_from_fresh_draws():
  env = reacher()

  @functools.partial(jax.jit, compiler_options=RUN_ONCE)
  def run(state):
    def body(state, _):
      state = env.step(state, jnp.full((NUM_ENVS, 2), 0.3))
      return state, state.done
    return jax.lax.scan(body, state, None, length=env_lib.EPISODE_LENGTH)

  first = compiled()[0](jax.random.PRNGKey(3), NUM_ENVS)
  last, dones = run(first)
  dones = np.asarray(dones)
  assert dones[:-1].sum() == 0 and dones[-1].all()  # ends at step 1000 exactly, not before
  np.testing.assert_array_equal(last.truncation, 1.0)
  np.testing.assert_array_equal(last.info["step"], 0)
  # The new episodes are fresh draws: not the first starts, not copies of each other.
  assert not np.allclose(last.task["target"], first.task["target"])
  assert len({tuple(np.round(t, 6)) for t in np.asarray(last.task["target"])}) == NUM_ENVS
  assert not np.allclose(last.obs, last.info["final_obs"])
  assert np.all(np.asarray(last.info["final_obs"])[:, 4:] != 0)  # moving at the end


@COMPILED_ONCE
def test_two_devices_match_one():
  """The same rollout with the batch sharded over 2 (forced host) devices and on 1."""
  assert jax.device_count() >= 2, "tests run with --xla_force_host_platform_device_count=2"
  env = reacher()
  actions = jax.random.uniform(jax.random.PRNGKey(5), (30, NUM_ENVS, 2), minval=-1, maxval=1)

  def rollout(state, actions):  # actions: (num_envs, steps, 2), sharded like the batch
    def body(state, action):
      state = env.step(state, action)
      return state, state.reward
    return jax.lax.scan(body, state, actions.swapaxes(0, 1))

  results = []
  for devices in (jax.devices()[:1], jax.devices()[:2]):
    mesh = mesh_lib.make_mesh(devices)
    state = mesh_lib.shard_batch(compiled()[0](jax.random.PRNGKey(6), NUM_ENVS), mesh)
    run = jax.jit(rollout, compiler_options=RUN_ONCE)
    final, rewards = run(state, mesh_lib.shard_batch(actions.swapaxes(0, 1), mesh))
    assert len(final.obs.sharding.device_set) == len(devices)
    results.append((np.asarray(final.obs), np.asarray(rewards)))
  np.testing.assert_allclose(results[0][0], results[1][0], rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(results[0][1], results[1][1], rtol=1e-5, atol=1e-6)


@pytest.mark.slow
@COMPILED_ONCE
def test_each_device_steps_its_own_environments():
  """On 2 devices AutoReset steps each device's half of the batch alone: environment 1 (on the
  first device) ends its episode and restarts, the second device's do not, and the states are
  those of the batch stepped as one; the per-device program agrees nothing between devices,
  where the batch stepped as one agrees, at least, on whether to run the restart branch."""
  mesh = mesh_lib.make_mesh(jax.devices()[:2])
  sharding = mesh_lib.batch_sharding(mesh)
  env = tasks.make("reacher_easy")
  state = mesh_lib.shard_batch(compiled()[0](jax.random.PRNGKey(7), NUM_ENVS), mesh)
  state = state.replace(info=dict(state.info, step=jnp.asarray([3, 999, 3, 3])))
  action = mesh_lib.shard_batch(jnp.full((NUM_ENVS, 2), 0.2), mesh)
  stepped, collectives = [], []
  for per_device in (True, False):
    step = jax.jit(AutoReset(env, sharding, per_device=per_device).step)
    compiled_step = step.lower(state, action).compile(RUN_ONCE)
    collectives.append(re.findall(r"\b(all-reduce|all-gather|all-to-all|collective-permute)"
                                  r"(?:-start)?\(", compiled_step.as_text()))
    stepped.append(compiled_step(state, action))
  assert collectives[0] == [] and "all-reduce" in collectives[1], collectives
  ours, whole = stepped
  np.testing.assert_array_equal(ours.done, [0, 1, 0, 0])
  np.testing.assert_array_equal(ours.info["step"], [4, 0, 4, 4])  # 1 restarted
  assert len(ours.obs.sharding.device_set) == 2
  for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(ours), jax.tree.leaves(whole)):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6,
                               err_msg=jax.tree_util.keystr(path))


def test_per_device_steps_a_batch_that_does_not_split_as_one():
  """(A final evaluation of 3 episodes on 2 devices.) The same numbers either way."""
  mesh = mesh_lib.make_mesh(jax.devices()[:2])
  double = mesh_lib.per_device(lambda x: x * 2, mesh_lib.batch_sharding(mesh))
  np.testing.assert_array_equal(jax.jit(double)(jnp.arange(3.0)), [0.0, 2.0, 4.0])
  even = mesh_lib.shard_batch(jnp.arange(4.0), mesh)
  np.testing.assert_array_equal(jax.jit(double)(even), [0.0, 2.0, 4.0, 6.0])
  assert "all-reduce" not in jax.jit(double).lower(even).compile().as_text()


def test_mesh_rejects_bad_batch_sizes():
  mesh = mesh_lib.make_mesh(jax.devices()[:2])
  with pytest.raises(ValueError, match="multiple of the number of devices"):
    mesh_lib.check_batch_size(3, mesh)
  with pytest.raises(ValueError, match="positive"):
    mesh_lib.check_batch_size(0, mesh)


def _run_cli(*args):
  # The command line inherits the tests' XLA_FLAGS (conftest), so it compiles as they do.
  return subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "run.py"), *args],
                        capture_output=True, text=True, timeout=300, cwd=ROOT)


def _cli_in_process(capsys, *args) -> tuple[int, str]:
  """scripts/run.py's main in this process (a process each cost CI ~4 s): exit status, stderr."""
  capsys.readouterr()
  try:
    status = load_script("run").main(list(args))
  except SystemExit as e:  # (argparse's errors)
    status = e.code
  return status, capsys.readouterr().err


def test_cli_lists_tasks_and_rejects_bad_input(capsys):
  listed = _run_cli("--list")
  # (MJX may print a note about the optional Warp backend before the list.)
  assert listed.returncode == 0 and listed.stdout.split()[-len(tasks.TASKS):] == list(tasks.TASKS)
  unknown = _run_cli("--task", "humanoid_fly")  # (a process's exit status and message)
  assert unknown.returncode != 0
  assert "unknown task 'humanoid_fly'" in unknown.stderr and "humanoid_run" in unknown.stderr
  assert "Traceback" not in unknown.stderr
  for bad in (["--num_envs", "0"], ["--num_envs", "-3"], ["--steps", "0"]):
    status, err = _cli_in_process(capsys, "--task", "reacher_easy", *bad)
    assert status != 0 and "must be a positive integer" in err, (bad, status, err)
  status, err = _cli_in_process(capsys, "--task", "reacher_easy", "--num_envs", "3")
  assert status != 0 and "multiple of the number of devices" in err, (status, err)


def test_cli_random_rollout_reports_steps_per_second(tmp_path):
  cache = tmp_path / "jax_cache"
  result = _run_cli("--task", "reacher_easy", "--method", "random", "--num_envs", "4",
                    "--steps", "20", "--log_every", "10", "--compilation_cache", str(cache))
  assert result.returncode == 0, result.stderr
  assert "steps/s" in result.stdout and "done:" in result.stdout
  assert any(cache.iterdir())  # the compiled rollout went to the persistent cache


def _dot_precisions(jaxpr) -> list:
  """The `precision` of every dot_general in a jaxpr, its sub-jaxprs included."""
  found = []
  for eqn in jaxpr.eqns:
    if eqn.primitive.name == "dot_general":
      found.append(eqn.params["precision"])
    for sub in jax_core.jaxprs_in_params(eqn.params):
      found += _dot_precisions(sub)
  return found


def test_physics_matmuls_run_at_full_precision():
  """On GPUs JAX's default runs float32 matmuls as TF32, which put one step 100-1000x further
  from dm_control (README); reset and step must ask for full precision in every matmul."""
  env = AutoReset(tasks.make("cheetah_run"))  # contacts, and 200 settling steps in its reset
  action = jnp.zeros((2, env.env.action_size))
  # One trace of reset then step (the reset branch of the auto-reset is traced too).
  jaxpr = jax.make_jaxpr(lambda k: env.step(env.reset(k, 2), action))(jax.random.PRNGKey(0))
  precisions = _dot_precisions(jaxpr.jaxpr)
  assert precisions, "expected matrix products in the physics"
  highest = (jax.lax.Precision.HIGHEST, jax.lax.Precision.HIGHEST)
  assert all(p == highest for p in precisions), set(map(str, precisions))


def test_observation_names_name_each_dimension_in_layout_order():
  """The names reports and `--by_start` use for observation dimensions (the reward landscape's
  posture report, expert_eval's start split, `Task.periodic_observations`)."""
  from mjx_form.sim import env as env_lib
  assert env_lib.observation_names({"orientations": 2, "height": 1, "velocity": 2}) == [
      "orientations[0]", "orientations[1]", "height", "velocity[0]", "velocity[1]"]
  layout = tasks.make("cheetah_run").observation_layout
  assert len(env_lib.observation_names(layout)) == sum(layout.values())


@pytest.mark.parametrize("clamp", ["enable", "disable"])
def test_action_bounds_are_what_mujoco_clamps_controls_to(clamp):
  """env.action_bounds against MuJoCo itself: a limited actuator's force is its control clamped
  to the bounds, an unlimited one's (or any, with clamping disabled) the control as given."""
  import mujoco
  xml = f"""<mujoco><option><flag clampctrl="{clamp}"/></option>
    <worldbody><body><joint name="j" type="hinge"/><geom size=".1" mass="1"/></body></worldbody>
    <actuator><motor joint="j" ctrlrange="-1 1.1" ctrllimited="true"/>
      <motor joint="j" ctrlrange="-.8 .8" ctrllimited="true"/>
      <motor joint="j" ctrllimited="false"/></actuator></mujoco>"""
  model = mujoco.MjModel.from_xml_string(xml)
  low, high = env_lib.action_bounds(model)
  data = mujoco.MjData(model)
  for ctrl in ([5.0, 5.0, 5.0], [-5.0, -5.0, -5.0], [0.3, -0.2, 0.1]):
    data.ctrl[:] = ctrl
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.actuator_force, np.clip(ctrl, low, high), rtol=1e-6)
  expected = ([-1, -0.8, -np.inf], [1.1, 0.8, np.inf]) if clamp == "enable" else (
      [-np.inf] * 3, [np.inf] * 3)
  np.testing.assert_array_equal(low, np.float32(expected[0]))
  np.testing.assert_array_equal(high, np.float32(expected[1]))
