"""mjx_form.sim.partitionable: contact culling by a stable sort picks lax.top_k's contacts;
MJX's solve with its while_loop run as a fixed-length scan (`--physics fast_bounded`) computes
the same states; with both, a batch split over devices steps without any exchange between
them."""

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import tasks
from mjx_form import mesh as mesh_lib
from mjx_form.sim import partitionable, physics
from mjx_form.sim.wrappers import AutoReset


def test_bounded_while_loop_is_a_while_loop():
  """Halvings of x until below 1 (a data-dependent count per element), vmapped, against
  lax.while_loop and a Python loop; the cap stops a condition that would go on."""
  def halvings(x, max_iterations):
    cond = lambda c: (c[0] >= 1.0) & (c[1] < max_iterations)
    body = lambda c: (c[0] / 2, c[1] + 1)
    return (jax.lax.while_loop(cond, body, (x, 0))[1],
            partitionable.bounded_while_loop(cond, body, (x, 0), max_iterations)[1])

  xs = jnp.asarray([0.5, 1.0, 3.0, 100.0, 1e6])
  reference = [0, 1, 2, 7, 20]
  loop, bounded = jax.jit(jax.vmap(lambda x: halvings(x, 25)))(xs)
  np.testing.assert_array_equal(loop, reference)
  np.testing.assert_array_equal(bounded, reference)
  loop, bounded = jax.jit(jax.vmap(lambda x: halvings(x, 5)))(xs)  # the cap binds
  np.testing.assert_array_equal(bounded, np.minimum(reference, 5))
  np.testing.assert_array_equal(loop, bounded)


def test_stable_top_k_is_top_k_ties_included():
  rng = np.random.default_rng(0)
  x = jnp.asarray(rng.integers(0, 5, size=(6, 19)).astype(np.float32))  # many ties
  x = x.at[0].set(jnp.asarray(rng.normal(size=19), jnp.float32))
  for k in (1, 4, 19):
    values, indices = jax.lax.top_k(x, k)
    ours = partitionable.stable_top_k(x, k)
    np.testing.assert_array_equal(ours[1], indices)
    np.testing.assert_array_equal(ours[0], values)


def test_collision_culls_with_the_stable_sort():
  from mujoco.mjx._src import collision_driver
  assert collision_driver.jax.lax.top_k is partitionable.stable_top_k
  assert collision_driver.jax.lax.scan is jax.lax.scan  # the rest is jax's own


def _states(name, physics_mode, steps=15, num_envs=4):
  """`num_envs` states of `name` after `steps` random-action steps (contacts by then)."""
  env = tasks.make(name, physics_mode)
  auto = AutoReset(env)
  state = jax.jit(lambda k: auto.reset(k, num_envs))(jax.random.PRNGKey(0))
  actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, num_envs, env.action_size),
                               minval=-1.0, maxval=1.0)
  step = jax.jit(jax.vmap(env.step))
  for action in actions:
    state = step(state, action)
  return env, state


@pytest.mark.parametrize("name,iterations", [("cheetah_run", None), ("hopper_stand", 3)])
def test_bounded_solve_steps_as_mjx_solve(name, iterations):
  """From the same states, one physics step with MJX's solve and with the bounded loop: the
  same qacc and next state. With 3 iterations the cap binds (the solver has not converged),
  so a loop one pass short or long would show."""
  env, state = _states(name, "fast")
  settings = env.fast_settings
  if iterations is not None:
    settings = dataclasses.replace(settings, iterations=iterations)
    env = tasks.make(name, settings)
  data = state.data
  assert int(jnp.sum(data._impl.contact.dist < 0)) > 0  # there is something to solve
  steps = {}
  for bounded in (False, True):
    step = jax.jit(jax.vmap(lambda d: physics.physics_step(env.mjx_model, d, 1, bounded)))
    steps[bounded] = step(data)
  for field in ("qacc", "qpos", "qvel", "qfrc_constraint"):
    np.testing.assert_allclose(getattr(steps[True], field), getattr(steps[False], field),
                               rtol=1e-5, atol=1e-5, err_msg=field)
  if iterations is not None:  # one iteration fewer gives another answer
    few = tasks.make(name, dataclasses.replace(settings, iterations=iterations - 1))
    fewer = jax.jit(jax.vmap(lambda d: physics.physics_step(few.mjx_model, d, 1, True)))(data)
    assert np.abs(np.asarray(fewer.qacc - steps[False].qacc)).max() > 1e-3


def test_fast_bounded_is_fast_with_the_bounded_loop():
  env = tasks.make("walker_walk", "fast_bounded")
  assert env.solver_settings == dataclasses.replace(tasks.make("walker_walk").fast_settings,
                                                    bounded_solver_loop=True)
  assert env.physics == "fast_bounded"


def test_bounded_loop_steps_a_split_batch_without_collectives():
  """cheetah_run's batch split over 2 devices, stepped as one program-wide batch: with MJX's
  while_loop the devices agree at every solver iteration (an all-reduce of its condition);
  with the bounded loop the step exchanges nothing (with lax.top_k's culling it gathered the
  batch's contact distances: two all-gathers)."""
  mesh = mesh_lib.make_mesh(jax.devices()[:2])
  collectives = {}
  for mode in ("fast", "fast_bounded"):
    env = tasks.make("cheetah_run", mode)
    state = mesh_lib.shard_batch(
        jax.jit(lambda k: AutoReset(env).reset(k, 4))(jax.random.PRNGKey(0)), mesh)
    action = mesh_lib.shard_batch(jnp.zeros((4, env.action_size)), mesh)
    text = jax.jit(jax.vmap(env.step)).lower(state, action).compile().as_text()
    collectives[mode] = re.findall(r"\b(all-reduce|all-gather|all-to-all|collective-permute)"
                                   r"(?:-start)?\(", text)
  assert "all-reduce" in collectives["fast"], collectives
  assert collectives["fast_bounded"] == [], collectives
