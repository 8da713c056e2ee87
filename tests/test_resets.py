"""Reset distributions against dm_control's, with their constraints."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from scipy import stats

import tasks
from mjx_form import cpu
from mjx_form.sim import parity

NUM_RESETS = 200
# Every program here runs once (or a few times, on a few states): XLA's backend optimisation
# would only cost compile time (CI time; mjx_form.cpu).
RUN_ONCE = cpu.run_once_compiler_options()
# One task per domain: the tasks of a domain share their reset (initialize_episode).
DOMAIN_TASKS = [pytest.param(name, marks=pytest.mark.xdist_group(name.split("_")[0]))
                for name in ("reacher_easy", "cheetah_run", "hopper_hop", "walker_walk",
                             "quadruped_walk", "humanoid_walk")]


@functools.cache
def our_resets(name: str):
  env = tasks.make(name)
  # (quadruped's reset loops on contacts: at level 0 it runs 23 s instead of 6, more than the
  # 8 s of compile time it saves; every other domain's compiles 3-7 s faster at level 0)
  options = {} if name.startswith("quadruped") else RUN_ONCE
  reset = jax.jit(jax.vmap(env.reset), compiler_options=options)
  states = reset(jax.random.split(jax.random.PRNGKey(7), NUM_RESETS))
  return env, jax.tree.map(np.asarray, states)


@functools.cache
def dm_control_resets(name: str):
  dm_env = parity.load_dm_control_env(name, seed=11)
  obs, qpos, targets = [], [], []
  for _ in range(NUM_RESETS):
    timestep = dm_env.reset()
    obs.append(parity.flat_observation(timestep.observation))
    qpos.append(np.array(dm_env.physics.data.qpos))
    targets.append(parity.task_variables(name, dm_env.physics).get("target", np.zeros(2)))
  return np.stack(obs), np.stack(qpos), np.stack(targets)


def _ks_pvalues(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
  """Two-sample Kolmogorov-Smirnov p-value per column (1 for columns constant in both).

  Values are rounded to 1e-4 first: elements that are physically zero at reset (quadruped's
  force/torque and accelerometer in free fall) are float32 rounding noise in ours and float64
  noise in dm_control, and the test would otherwise compare the noise.
  """
  ours, theirs = np.round(ours, 4) + 0.0, np.round(theirs, 4) + 0.0
  pvalues = []
  for a, b in zip(ours.T, theirs.T):
    if np.ptp(a) == 0 and np.ptp(b) == 0:
      pvalues.append(1.0 if np.allclose(a[0], b[0], atol=1e-5) else 0.0)
    else:
      pvalues.append(stats.ks_2samp(a, b).pvalue)
  return np.array(pvalues)


@pytest.mark.parametrize("name", DOMAIN_TASKS)
def test_reset_observation_distribution_matches_dm_control(name, parity_report):
  """Every observation dimension at reset: the same distribution as dm_control's resets."""
  env, states = our_resets(name)
  dm_obs, _, _ = dm_control_resets(name)
  pvalues = _ks_pvalues(states.obs, dm_obs)
  parity_report.append(dict(test="reset distribution", task=name, physics=env.physics,
                            dims=len(pvalues), min_ks_pvalue=float(pvalues.min()),
                            worst_dim=int(pvalues.argmin())))
  # Bonferroni over the dimensions at an overall level of 1e-3 (seeds are fixed).
  assert pvalues.min() > 1e-3 / len(pvalues), (pvalues.argmin(), pvalues.min())
  assert np.all(states.info["step"] == 0) and np.all(states.reward == 0)
  assert np.isfinite(states.obs).all()


@pytest.mark.xdist_group("cheetah")
def test_reset_distribution_test_can_fail():
  """The same check tells a wrong reset apart: dm_control's cheetah before settling differs."""
  dm_env = parity.load_dm_control_env("cheetah_run", seed=3)
  m = dm_env.physics.model
  rng = np.random.RandomState(0)
  limited = m.jnt_limited == 1
  unsettled = np.zeros((NUM_RESETS, m.nq))
  unsettled[:, limited] = rng.uniform(*m.jnt_range[limited].T, size=(NUM_RESETS, limited.sum()))
  _, dm_qpos, _ = dm_control_resets("cheetah_run")
  assert _ks_pvalues(unsettled[:, 1:], dm_qpos[:, 1:]).min() < 1e-6


@pytest.mark.xdist_group("reacher")
def test_reacher_target_placement():
  env, states = our_resets("reacher_easy")
  _, _, dm_targets = dm_control_resets("reacher_easy")
  radius = np.linalg.norm(states.task["target"], axis=1)
  assert radius.min() >= .05 - 1e-6 and radius.max() <= .20 + 1e-6
  angle = np.arctan2(states.task["target"][:, 0], states.task["target"][:, 1])  # x = r sin
  dm_angle = np.arctan2(dm_targets[:, 0], dm_targets[:, 1])
  assert stats.ks_2samp(radius, np.linalg.norm(dm_targets, axis=1)).pvalue > 1e-3
  assert stats.ks_2samp(angle, dm_angle).pvalue > 1e-3
  # to_target in the observation is target minus fingertip.
  finger = env.geom_id("finger")
  np.testing.assert_allclose(states.obs_parts["to_target"],
                             states.task["target"] - states.data.geom_xpos[:, finger, :2],
                             atol=1e-6)


def _mujoco_ncon(env, qpos: np.ndarray) -> int:
  """Contacts MuJoCo's own C collision reports for a pose (independent of MJX)."""
  data = mujoco.MjData(env.mj_model)
  data.qpos[:] = qpos
  mujoco.mj_forward(env.mj_model, data)
  return int(data.ncon)


@pytest.mark.xdist_group("humanoid")
def test_humanoid_starts_without_contacts():
  env, states = our_resets("humanoid_walk")
  assert not states.task["reset_penetrating"].any()
  assert all(_mujoco_ncon(env, q) == 0 for q in states.data.qpos)
  # Rejection sampling really rejects: many draws needed, as in dm_control.
  assert states.task["reset_draws"].max() > 1


@pytest.mark.xdist_group("quadruped")
def test_quadruped_starts_at_lowest_contact_free_height():
  env, states = our_resets("quadruped_walk")
  for qpos in states.data.qpos[:50]:
    height = qpos[2]
    assert abs(height / 0.01 - round(height / 0.01)) < 1e-3  # on dm_control's 1 cm grid
    assert _mujoco_ncon(env, qpos) == 0
    lower = qpos.copy()
    lower[2] -= 0.01
    if height > 1e-6:
      assert _mujoco_ncon(env, lower) > 0  # one step lower still touches
    np.testing.assert_allclose(np.linalg.norm(qpos[3:7]), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(qpos[:2], 0.0)


@pytest.mark.xdist_group("cheetah")
def test_cheetah_settling_is_dm_controls():
  """Settling from the same random pose gives dm_control's settled state (float64)."""
  dm_env = parity.load_dm_control_env("cheetah_run", seed=5)
  physics = dm_env.physics
  rng = np.random.RandomState(1)
  m = physics.model
  limited = m.jnt_limited == 1
  with jax.enable_x64(True):
    env = tasks.make("cheetah_run", physics="parity")
    settle = jax.jit(lambda qpos: env.settle(mjx.make_data(env.mjx_model), qpos),
                     compiler_options=RUN_ONCE)
    for _ in range(3):
      qpos = np.zeros(m.nq)
      qpos[limited] = rng.uniform(*m.jnt_range[limited].T)
      with physics.reset_context():
        physics.data.qpos[:] = qpos
        physics.step(nstep=200)
        physics.data.time = 0
      ours = settle(jnp.asarray(qpos))
      np.testing.assert_allclose(ours.qpos, physics.data.qpos, atol=1e-8)
      np.testing.assert_allclose(ours.qvel, physics.data.qvel, atol=1e-6)
      assert float(ours.time) == 0.0


@pytest.mark.parametrize("name", [pytest.param("reacher_easy", marks=pytest.mark.xdist_group(
    "reacher")), pytest.param("hopper_hop", marks=pytest.mark.xdist_group("hopper"))])
def test_reset_to_gives_back_a_drawn_start(name):
  """`reset_to` at the qpos/qvel/act and task variables `reset` drew: the same first state."""
  env, states = our_resets(name)
  n = 16
  again = jax.jit(jax.vmap(env.reset_to), compiler_options=RUN_ONCE)(
      states.data.qpos[:n], states.data.qvel[:n], states.data.act[:n],
      jax.tree.map(lambda x: x[:n], states.task), jax.random.split(jax.random.PRNGKey(0), n))
  np.testing.assert_allclose(again.obs, states.obs[:n], atol=1e-6)
  np.testing.assert_array_equal(again.data.qpos, states.data.qpos[:n])
  assert np.all(np.asarray(again.reward) == 0) and np.all(np.asarray(again.info["step"]) == 0)


@pytest.mark.xdist_group("hopper")
def test_reset_to_starts_where_dm_control_is():
  """A dm_control hopper state with velocities (random actions after its reset), set with
  `reset_to`: dm_control's observation there, and the same rewards for the next steps."""
  dm_env = parity.load_dm_control_env("hopper_stand", seed=5)
  rng = np.random.RandomState(1)
  dm_env.reset()
  for _ in range(20):
    dm_env.step(rng.uniform(-1, 1, dm_env.action_spec().shape))
  d = dm_env.physics.data
  assert np.abs(d.qvel).max() > 0.1  # the velocities are really tested
  env = tasks.make("hopper_stand", physics="parity")
  # (compiled, not run op by op: one compile each costs less than MJX's ops one at a time)
  reset_to = jax.jit(env.reset_to, compiler_options=RUN_ONCE)
  step = jax.jit(env.step, compiler_options=RUN_ONCE)
  state = reset_to(np.array(d.qpos), np.array(d.qvel), np.array(d.act), {},
                   jax.random.PRNGKey(0))
  expected = parity.flat_observation(dm_env.task.get_observation(dm_env.physics))
  np.testing.assert_allclose(state.obs, expected, atol=1e-5)
  for _ in range(5):
    action = rng.uniform(-1, 1, env.action_size)
    theirs = dm_env.step(action)
    state = step(state, jnp.asarray(action, jnp.float32))
    np.testing.assert_allclose(state.obs, parity.flat_observation(theirs.observation),
                               atol=1e-3)
    np.testing.assert_allclose(state.reward, theirs.reward, atol=1e-4)


@pytest.mark.parametrize("name", DOMAIN_TASKS)
def test_periodic_observations_are_the_raw_unlimited_hinge_angles(name):
  """A task declares as periodic exactly the observation dimensions that equal, at every drawn
  start, the qpos of a hinge joint without limits (found from MuJoCo's model)."""
  env, states = our_resets(name)
  m = env.mj_model
  unlimited = [int(m.jnt_qposadr[j]) for j in range(m.njnt)
               if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE and not m.jnt_limited[j]]
  raw = {env.observation_names[d] for d in range(env.observation_size) for a in unlimited
         if np.allclose(states.obs[:, d], states.data.qpos[:, a], atol=1e-6)}
  assert set(env.periodic_observations) == raw
  period = env.observation_period()
  assert sorted(np.flatnonzero(period)) == sorted(
      env.observation_names.index(n) for n in env.periodic_observations)
  assert np.all(period[period > 0] == np.float32(2 * np.pi))
