"""Retrace targets against an independent numpy loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_form.rl import retrace


def _reference(q_t, v_tp1, r, discounts, log_rhos, lambda_):
  """Retrace written forwards from its definition: G_t = r_t + sum over later steps of
  discounted, trace-weighted TD errors, accumulated in float64 with an explicit double loop."""
  q_t, v_tp1, r, discounts, log_rhos = (np.asarray(v, np.float64)
                                        for v in (q_t, v_tp1, r, discounts, log_rhos))
  T = len(r)
  c = lambda_ * np.minimum(1.0, np.exp(log_rhos))
  # delta_s = r_s + discount_s * v_tp1_s - q_t_s, the expected-SARSA TD error at step s.
  delta = r + discounts * v_tp1 - q_t
  targets = np.zeros(T)
  for t in range(T):
    g = q_t[t] + delta[t]
    coef = 1.0
    for s in range(t + 1, T):
      coef *= discounts[s - 1] * c[s]
      g += coef * delta[s]
    targets[t] = g
  return targets


def _random_sequence(rng, T, boundaries=(), gamma=0.97):
  q_t = rng.normal(size=T) * 3
  v_tp1 = rng.normal(size=T) * 3
  r = rng.normal(size=T)
  discounts = np.full(T, gamma)
  discounts[list(boundaries)] = 0.0
  log_rhos = rng.normal(size=T) * 1.5  # both signs: traces below 1 and truncated at 1
  return [v.astype(np.float32) for v in (q_t, v_tp1, r, discounts, log_rhos)]


@pytest.mark.parametrize("unroll", [1, True])  # a loop, and straight-line code (the learner's)
@pytest.mark.parametrize("lambda_", [1.0, 0.9])
@pytest.mark.parametrize("boundaries", [(), (3,), (0, 6, 7)])
def test_matches_numpy_reference(lambda_, boundaries, unroll):
  rng = np.random.default_rng(len(boundaries))
  args = _random_sequence(rng, 12, boundaries)
  assert (args[-1] > 0).any() and (args[-1] < 0).any()
  got = retrace.retrace_targets(*args, lambda_=lambda_, unroll=unroll)
  np.testing.assert_allclose(got, _reference(*args, lambda_), rtol=1e-5, atol=1e-5)


def test_boundary_cuts_the_trace():
  rng = np.random.default_rng(5)
  q_t, v_tp1, r, discounts, log_rhos = _random_sequence(rng, 10, boundaries=(4,))
  base = retrace.retrace_targets(q_t, v_tp1, r, discounts, log_rhos)
  r2 = r.copy()
  r2[5:] += 100.0  # rewards of the next episode
  moved = retrace.retrace_targets(q_t, v_tp1, r2, discounts, log_rhos)
  np.testing.assert_array_equal(base[:5], moved[:5])
  assert np.all(np.abs(np.asarray(moved[5:] - base[5:])) > 50)


def test_lambda_zero_is_one_step_td():
  args = _random_sequence(np.random.default_rng(6), 9, boundaries=(2,))
  q_t, v_tp1, r, discounts, log_rhos = args
  got = retrace.retrace_targets(*args, lambda_=0.0)
  np.testing.assert_allclose(got, r + discounts * v_tp1, rtol=1e-6, atol=1e-6)


def test_on_policy_is_n_step_return():
  # With c = 1 and Q(x_{t+1}, a_{t+1}) == V(x_{t+1}) the corrections cancel exactly, leaving
  # the discounted return to the end of the unroll bootstrapped with V(x_T).
  rng = np.random.default_rng(7)
  T = 8
  _, v_tp1, r, discounts, _ = _random_sequence(rng, T, boundaries=(5,))
  q_t = np.concatenate([[rng.normal()], v_tp1[:-1]]).astype(np.float32)
  got = retrace.retrace_targets(q_t, v_tp1, r, discounts, np.zeros(T, np.float32), lambda_=1.0)
  expected = np.zeros(T)
  for t in range(T):
    g, coef = 0.0, 1.0
    for s in range(t, T):
      g += coef * r[s]
      coef *= discounts[s]
    expected[t] = g + coef * v_tp1[-1]
  np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)
  # Positive log_rhos are truncated to a trace of 1: same targets.
  got_pos = retrace.retrace_targets(q_t, v_tp1, r, discounts, np.full(T, 2.0, np.float32))
  np.testing.assert_allclose(got_pos, got, rtol=1e-6, atol=1e-6)


def test_importance_weights():
  log_rhos = jnp.array([-100.0, -1.0, 0.0, 0.5, 100.0])
  expected = 0.9 * np.minimum(1.0, np.exp(np.asarray(log_rhos, np.float64)))
  c = retrace.importance_weights(log_rhos, 0.9)
  np.testing.assert_allclose(c, expected, rtol=1e-6, atol=1e-30)
  assert np.all(np.isfinite(c))


def test_jit_and_vmap_over_batch():
  rng = np.random.default_rng(8)
  batch = [_random_sequence(rng, 7, boundaries=(b,)) for b in range(4)]
  stacked = [np.stack(parts) for parts in zip(*batch)]
  fn = jax.jit(jax.vmap(lambda *a: retrace.retrace_targets(*a, lambda_=0.95)))
  got = fn(*stacked)
  assert got.shape == (4, 7)
  for i, args in enumerate(batch):
    np.testing.assert_allclose(got[i], _reference(*args, 0.95), rtol=1e-5, atol=1e-5)


def test_no_gradient_flows_to_inputs():
  args = [jnp.asarray(a) for a in _random_sequence(np.random.default_rng(9), 6)]

  def total(*a):
    return jnp.sum(retrace.retrace_targets(*a, lambda_=0.9) ** 2)

  grads = jax.grad(total, argnums=tuple(range(5)))(*args)
  for g in grads:
    np.testing.assert_array_equal(g, np.zeros(6))
