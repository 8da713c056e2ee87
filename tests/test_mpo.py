"""The MPO loss: E-step weights, dual updates, gradient routing and the policy improvement."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from scipy import special

from mjx_form.rl import mpo
from mjx_form.rl.distributions import DiagonalGaussian

N, S, A = 20, 16, 3


def _problem(seed=0, q_scale=1.0):
  """Target policy, samples from it and a quadratic Q peaked at a per-state best action."""
  rng = np.random.default_rng(seed)
  target = DiagonalGaussian(jnp.asarray(rng.normal(size=(S, A)), jnp.float32),
                            jnp.asarray(rng.uniform(0.3, 1.0, size=(S, A)), jnp.float32))
  actions = target.sample(jax.random.key(seed), (N,))  # [N, S, A]
  best = target.mean + jnp.asarray(rng.normal(size=(S, A)), jnp.float32)
  q_values = -q_scale * jnp.sum(jnp.square(actions - best), axis=-1)  # [N, S]
  return target, actions, q_values, best


def _grads(duals, online, target, actions, q_values, config):
  return jax.grad(lambda d, o, t, a, q: mpo.mpo_loss(d, o, t, a, q, config)[0],
                  argnums=(0, 1, 2, 3, 4))(duals, online, target, actions, q_values)


def test_init_duals_shapes_and_values():
  config = mpo.MPOConfig()
  duals = mpo.init_duals(config, A)
  assert duals.log_temperature.shape == () and duals.log_alpha_mean.shape == (A,)
  np.testing.assert_allclose(mpo.dual_value(duals.log_alpha_scale), np.log1p(np.exp(10.0)),
                             rtol=1e-6)
  flat = mpo.init_duals(mpo.MPOConfig(per_dim_constraining=False), A)
  assert flat.log_alpha_mean.shape == () and flat.log_alpha_scale.shape == ()
  clipped = mpo.clip_duals(duals._replace(log_temperature=jnp.array(-50.0)))
  assert float(clipped.log_temperature) == mpo.MIN_RAW_DUAL


def test_e_step_weights_normalised_and_ordered():
  _, _, q_values, _ = _problem()
  w = mpo.e_step_weights(q_values, jnp.array(0.7))
  assert w.shape == (N, S)
  np.testing.assert_allclose(w.sum(0), 1.0, rtol=1e-5)
  np.testing.assert_array_equal(jnp.argmax(w, 0), jnp.argmax(q_values, 0))
  np.testing.assert_allclose(w, special.softmax(np.asarray(q_values, np.float64) / 0.7, axis=0),
                             rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("per_dim", [True, False])
def test_equal_policies_zero_kl_and_alphas_pushed_down(per_dim):
  config = mpo.MPOConfig(per_dim_constraining=per_dim)
  target, actions, q_values, _ = _problem()
  duals = mpo.init_duals(config, A)
  loss, metrics = mpo.mpo_loss(duals, target, target, actions, q_values, config)
  assert float(metrics["kl_mean"]) == 0.0 and float(metrics["kl_scale"]) == 0.0
  g_duals = _grads(duals, target, target, actions, q_values, config)[0]
  # d loss / d raw alpha = softplus'(raw) * (epsilon - KL) > 0: gradient descent lowers alpha.
  for raw, g, eps in ((duals.log_alpha_mean, g_duals.log_alpha_mean, config.epsilon_mean),
                      (duals.log_alpha_scale, g_duals.log_alpha_scale, config.epsilon_scale)):
    np.testing.assert_allclose(g, jax.nn.sigmoid(raw) * eps, rtol=1e-5)
    assert np.all(np.asarray(g) > 0)


@pytest.mark.parametrize("per_dim", [True, False])
def test_alphas_grow_when_kl_exceeds_bound(per_dim):
  config = mpo.MPOConfig(per_dim_constraining=per_dim)
  target, actions, q_values, _ = _problem()
  online = DiagonalGaussian(target.mean + 0.5, target.scale * 1.5)
  duals = mpo.init_duals(config, A)
  _, metrics = mpo.mpo_loss(duals, online, target, actions, q_values, config)
  assert metrics["kl_mean_rel"] > 1 and metrics["kl_scale_rel"] > 1
  g_duals = _grads(duals, online, target, actions, q_values, config)[0]
  # Exactly softplus'(raw) * (epsilon - KL) with KL the batch-mean of the decoupled KLs.
  kl_scale = jnp.mean(target.kl_divergence(DiagonalGaussian(target.mean, online.scale),
                                           per_dim=per_dim), axis=0)
  np.testing.assert_allclose(g_duals.log_alpha_scale, jax.nn.sigmoid(duals.log_alpha_scale)
                             * (config.epsilon_scale - kl_scale), rtol=1e-5)
  opt = optax.adam(1e-2)
  updates, _ = opt.update(g_duals, opt.init(duals))
  new = optax.apply_updates(duals, updates)
  assert np.all(np.asarray(mpo.dual_value(new.log_alpha_mean)) >
                np.asarray(mpo.dual_value(duals.log_alpha_mean)))
  assert np.all(np.asarray(mpo.dual_value(new.log_alpha_scale)) >
                np.asarray(mpo.dual_value(duals.log_alpha_scale)))


def _np_temperature_dual(eta, q, eps):
  q = np.asarray(q, np.float64)
  return eta * eps + eta * np.mean(special.logsumexp(q / eta, axis=0) - np.log(q.shape[0]))


@pytest.mark.parametrize("raw", [-1.0, 0.5, 2.0])
def test_temperature_gradient_matches_finite_difference(raw):
  config = mpo.MPOConfig()
  target, actions, q_values, _ = _problem(1)
  duals = mpo.init_duals(config, A)._replace(log_temperature=jnp.array(raw))
  online = DiagonalGaussian(target.mean + 0.1, target.scale)
  g = _grads(duals, online, target, actions, q_values, config)[0].log_temperature
  eta = float(mpo.dual_value(duals.log_temperature))
  h = 1e-5
  fd = (_np_temperature_dual(eta + h, q_values, config.epsilon)
        - _np_temperature_dual(eta - h, q_values, config.epsilon)) / (2 * h)
  np.testing.assert_allclose(g, fd * float(jax.nn.sigmoid(raw)), rtol=1e-3, atol=1e-6)


def test_temperature_decreases_with_larger_epsilon():
  target, actions, q_values, _ = _problem(2)
  results = {}
  for eps in (0.05, 0.5):
    config = mpo.MPOConfig(epsilon=eps)
    duals = mpo.init_duals(config, A)
    opt = optax.adam(0.05)
    state = opt.init(duals)

    @jax.jit
    def step(duals, state, config=config):
      g = _grads(duals, target, target, actions, q_values, config)[0]
      updates, state = opt.update(g, state)
      return optax.apply_updates(duals, updates), state

    for _ in range(1500):
      duals, state = step(duals, state)
    _, metrics = mpo.mpo_loss(duals, target, target, actions, q_values, config)
    results[eps] = metrics
    # At the optimum of the dual, KL(E-step weights || uniform) meets the bound.
    np.testing.assert_allclose(metrics["kl_nonparametric_rel"], 1.0, rtol=0.05)
  assert results[0.5]["temperature"] < 0.5 * results[0.05]["temperature"]
  assert results[0.5]["ess_fraction"] < results[0.05]["ess_fraction"]


def test_policy_gradient_moves_mean_towards_best_actions():
  config = mpo.MPOConfig()
  target, actions, q_values, best = _problem(3)
  duals = mpo.init_duals(config, A)._replace(log_temperature=jnp.array(-1.0))
  online = target
  for _ in range(20):
    g_online = _grads(duals, online, target, actions, q_values, config)[1]
    online = DiagonalGaussian(online.mean - 0.05 * g_online.mean, online.scale)
  # The weighted sample mean is the M-step optimum; the mean moves from the target towards it.
  w = mpo.e_step_weights(q_values, mpo.dual_value(duals.log_temperature))
  weighted_mean = jnp.einsum("ns,nsa->sa", w, actions)
  before = jnp.linalg.norm(target.mean - weighted_mean, axis=-1)
  after = jnp.linalg.norm(online.mean - weighted_mean, axis=-1)
  assert np.all(np.asarray(after) < np.asarray(before))
  # ... and so towards the best actions, on average over states.
  assert jnp.mean(jnp.linalg.norm(online.mean - best, axis=-1)) < jnp.mean(
      jnp.linalg.norm(target.mean - best, axis=-1))


def test_gradient_routing():
  """Target, samples and Q get no gradient; the policy gradient is that of the M-step
  cross-entropy plus the alpha-weighted KLs alone, checked against numpy finite differences."""
  config = mpo.MPOConfig()
  target, actions, q_values, _ = _problem(4)
  duals = mpo.init_duals(config, A)._replace(
      log_alpha_mean=jnp.array([0.0, 1.0, 2.0]), log_alpha_scale=jnp.array([3.0, 5.0, 8.0]))
  rng = np.random.default_rng(4)
  online = DiagonalGaussian(target.mean + 0.2 * rng.normal(size=(S, A)).astype(np.float32),
                            target.scale * rng.uniform(0.8, 1.2, size=(S, A)).astype(np.float32))
  _, g_online, g_target, g_actions, g_q = _grads(duals, online, target, actions, q_values, config)
  for g in (g_target.mean, g_target.scale, g_actions, g_q):
    np.testing.assert_array_equal(g, np.zeros_like(g))

  def f64(x):
    return np.asarray(x, np.float64)

  a, q, tm, ts = f64(actions), f64(q_values), f64(target.mean), f64(target.scale)
  eta = float(mpo.dual_value(duals.log_temperature))
  w = special.softmax(q / eta, axis=0)
  alpha_m, alpha_s = f64(mpo.dual_value(duals.log_alpha_mean)), f64(mpo.dual_value(
      duals.log_alpha_scale))

  def policy_objective(mean, scale):
    def log_normal(m, s):
      return np.sum(-0.5 * ((a - m) / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi), axis=-1)
    cross_entropy = -np.mean(np.sum(w * (log_normal(mean, ts) + log_normal(tm, scale)), axis=0))
    kl_m = np.mean((tm - mean) ** 2 / (2 * ts ** 2), axis=0)
    kl_s = np.mean(np.log(scale / ts) + ts ** 2 / (2 * scale ** 2) - 0.5, axis=0)
    return cross_entropy + np.sum(alpha_m * kl_m) + np.sum(alpha_s * kl_s)

  mean, scale = f64(online.mean), f64(online.scale)
  h = 1e-6
  for (i, j) in [(0, 0), (5, 1), (15, 2)]:
    e = np.zeros_like(mean)
    e[i, j] = h
    fd_mean = (policy_objective(mean + e, scale) - policy_objective(mean - e, scale)) / (2 * h)
    fd_scale = (policy_objective(mean, scale + e) - policy_objective(mean, scale - e)) / (2 * h)
    np.testing.assert_allclose(g_online.mean[i, j], fd_mean, rtol=2e-3, atol=1e-5)
    np.testing.assert_allclose(g_online.scale[i, j], fd_scale, rtol=2e-3, atol=1e-5)


@pytest.mark.parametrize("per_dim", [True, False])
def test_finite_for_extreme_q_and_jits(per_dim):
  config = mpo.MPOConfig(per_dim_constraining=per_dim)
  target, actions, q_values, _ = _problem(5)
  q_values = 1e4 * q_values / jnp.max(jnp.abs(q_values))  # Q in [-1e4, 0]
  online = DiagonalGaussian(target.mean + 0.3, target.scale * 0.7)
  loss_and_grads = jax.jit(jax.value_and_grad(
      lambda d, o, q: mpo.mpo_loss(d, o, target, actions, q, config), (0, 1), has_aux=True))
  for log_temperature in (-18.0, 1.0, 20.0):
    duals = mpo.init_duals(config, A)._replace(log_temperature=jnp.array(log_temperature))
    for q in (q_values, -q_values, q_values + 1e4):
      (loss, metrics), grads = loss_and_grads(duals, online, q)
      assert np.isfinite(loss) and all(np.isfinite(v) for v in metrics.values())
      assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))
      assert 1.0 - 1e-4 <= metrics["ess_fraction"] * N <= N + 1e-3
  # d(E-step dual) / d eta = epsilon - KL(w || uniform); at a tiny temperature that must hold
  # without the cancellation of two terms of size max|Q| / eta (here ~1e11).
  for log_temperature in (-18.0, -5.0):
    duals = mpo.init_duals(config, A)._replace(log_temperature=jnp.array(log_temperature))
    (_, metrics), grads = loss_and_grads(duals, online, q_values)
    g_eta = grads[0].log_temperature / jax.nn.sigmoid(log_temperature)
    kl_weights = metrics["kl_nonparametric_rel"] * config.epsilon
    np.testing.assert_allclose(g_eta, config.epsilon - kl_weights, rtol=1e-3, atol=1e-3)


# --- action penalty (MO-MPO's cost on sampled actions outside [-1, 1]) -------------------------

def _saturated_problem(seed=6):
  """A target policy whose means lie outside [-1, 1] in some dimensions, and flat Q: the task
  prefers no action, so only the penalty can say where the mean should go."""
  rng = np.random.default_rng(seed)
  mean = rng.normal(size=(S, A)) + np.array([3.0, -2.5, 0.0])  # dims 0, 1 saturate
  target = DiagonalGaussian(jnp.asarray(mean, jnp.float32), jnp.full((S, A), 0.5))
  actions = target.sample(jax.random.key(seed), (N,))
  return target, actions, jnp.zeros((N, S))


def test_action_penalty_duals_only_when_on():
  off, on = mpo.init_duals(mpo.MPOConfig(), A), mpo.init_duals(
      mpo.MPOConfig(action_penalty=True), A)
  assert off.log_penalty_temperature is None and len(jax.tree.leaves(off)) == 3
  assert on.log_penalty_temperature.shape == () and len(jax.tree.leaves(on)) == 4
  # Without the penalty the loss and its metrics are those of plain MPO, whatever the duals.
  target, actions, q_values, _ = _problem()
  online = DiagonalGaussian(target.mean + 0.1, target.scale)
  config = mpo.MPOConfig()
  loss_off, m_off = mpo.mpo_loss(off, online, target, actions, q_values, config)
  loss_on_duals, _ = mpo.mpo_loss(on, online, target, actions, q_values, config)
  assert float(loss_off) == float(loss_on_duals) and "penalty_temperature" not in m_off
  with pytest.raises(ValueError, match="action_penalty"):
    mpo.mpo_loss(off, online, target, actions, q_values, mpo.MPOConfig(action_penalty=True))


def test_action_penalty_as_a_members_traced_flag():
  """A population member's flag (a traced bool, grid.py): off gives plain MPO's loss and
  gradients (to float rounding: the compiled sums differ in order), with the penalty's dual untouched (zero gradient) and its metrics NaN;
  on gives the Python True's."""
  target, actions, q_values = _saturated_problem()
  online = DiagonalGaussian(target.mean + 0.1, target.scale * 1.1)
  duals = mpo.init_duals(mpo.MPOConfig(action_penalty=True), A)._replace(
      log_penalty_temperature=jnp.array(-2.0))
  plain = mpo.MPOConfig()
  plain_duals = duals._replace(log_penalty_temperature=None)

  @jax.jit
  def traced(flag):
    config = mpo.MPOConfig(action_penalty=flag)
    loss, metrics = mpo.mpo_loss(duals, online, target, actions, q_values, config)
    return loss, metrics, _grads(duals, online, target, actions, q_values, config)

  @jax.jit
  def untraced():  # compiled too, so that both sides fuse alike
    loss, metrics = mpo.mpo_loss(plain_duals, online, target, actions, q_values, plain)
    return loss, metrics, _grads(plain_duals, online, target, actions, q_values, plain)

  loss, metrics, grads = untraced()
  loss_off, metrics_off, grads_off = traced(jnp.array(False))
  np.testing.assert_allclose(loss_off, loss, rtol=1e-6)
  without_penalty_dual = (grads_off[0]._replace(log_penalty_temperature=None), grads_off[1])
  for a, b in zip(jax.tree.leaves(without_penalty_dual), jax.tree.leaves(grads[:2]),
                  strict=True):  # duals, online
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-8)
  assert float(grads_off[0].log_penalty_temperature) == 0.0
  assert np.isnan(metrics_off["penalty_temperature"]) and np.isnan(
      metrics_off["penalty_kl_nonparametric_rel"])
  np.testing.assert_array_equal(metrics_off["kl_mean"], metrics["kl_mean"])
  on = mpo.MPOConfig(action_penalty=True)
  loss_true, metrics_true = mpo.mpo_loss(duals, online, target, actions, q_values, on)
  grads_true = _grads(duals, online, target, actions, q_values, on)
  loss_on, metrics_on, grads_on = traced(jnp.array(True))
  np.testing.assert_allclose(loss_on, loss_true, rtol=1e-6)
  np.testing.assert_allclose(metrics_on["penalty_temperature"],
                             metrics_true["penalty_temperature"], rtol=1e-6)
  for a, b in zip(jax.tree.leaves(grads_on[:2]), jax.tree.leaves(grads_true[:2]), strict=True):
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
  assert abs(float(grads_on[0].log_penalty_temperature)) > 1e-6  # its dual learns when on
  assert abs(float(loss_on - loss_off)) > 1e-3  # and the penalty changes the loss


def test_action_penalty_pulls_saturated_means_inside_the_bounds():
  target, actions, q_values = _saturated_problem()
  g_mean = {}
  for penalty in (False, True):
    config = mpo.MPOConfig(action_penalty=penalty)
    duals = mpo.init_duals(config, A)
    if penalty:  # a sharper penalty E-step (eta_p 0.13) than at the start (1.31)
      duals = duals._replace(log_penalty_temperature=jnp.array(-2.0))
    g_mean[penalty] = np.asarray(_grads(duals, target, target, actions, q_values, config)[1].mean)
  # Flat Q, no penalty: uniform weights, the M-step only refits the target's samples.
  refit = (target.mean - actions.mean(0)) / jnp.square(target.scale) / S
  np.testing.assert_allclose(g_mean[False], refit, rtol=1e-3, atol=1e-6)
  # The penalty's part of the step (gradient descent: -g) points inwards, towards [-1, 1], in
  # the saturated dimensions: on average and for nearly every state (its cost is the norm over
  # all dimensions, so single states may differ).
  step = -(g_mean[True] - g_mean[False])[:, :2]
  inward = step * -np.sign(np.asarray(target.mean[:, :2]))  # > 0: moves inwards
  assert np.all(inward.mean(0) > 0) and (inward > 0).mean() > 0.8, inward
  _, metrics = mpo.mpo_loss(duals, target, target, actions, q_values, config)
  assert 0.3 < float(metrics["sampled_out_of_bounds"]) < 0.9
  assert 0.5 < float(metrics["mean_out_of_bounds"]) < 0.8  # 2 of 3 dimensions, mostly


def test_action_penalty_temperature_dual_moves_the_right_way():
  """Its dual, like eta's, grows when the penalty's E-step weights move further from the
  target's samples than epsilon_penalty allows, and shrinks when they are within it."""
  target, actions, q_values = _saturated_problem()
  for log_penalty_temperature, grows in ((-8.0, True), (100.0, False)):
    config = mpo.MPOConfig(action_penalty=True)
    duals = mpo.init_duals(config, A)._replace(
        log_penalty_temperature=jnp.array(log_penalty_temperature))
    g_duals = _grads(duals, target, target, actions, q_values, config)[0]
    _, metrics = mpo.mpo_loss(duals, target, target, actions, q_values, config)
    # Gradient descent on the dual loss: a negative gradient raises the temperature.
    assert (float(g_duals.log_penalty_temperature) < 0) == grows
    assert (float(metrics["penalty_kl_nonparametric_rel"]) > 1.0) == grows
  # All samples inside the bounds: no cost, uniform penalty weights, KL 0, the dual shrinks.
  inside = jnp.clip(actions, -0.99, 0.99)
  _, metrics = mpo.mpo_loss(duals, target, target, inside, q_values, config)
  assert float(metrics["penalty_kl_nonparametric_rel"]) == 0.0
  assert float(_grads(duals, target, target, inside, q_values, config)[0]
               .log_penalty_temperature) > 0


def test_clip_mean_targets_fits_the_mean_to_the_clipped_samples():
  """Flat Q (uniform weights): the mean's gradient is the refit of the samples clipped to the
  bounds widened by the target's scale, so where the mean lies beyond that its step points
  back; the scale's gradient is the raw samples' refit either way. A member's traced flag gives the
  Python flag's values."""
  target, actions, q_values = _saturated_problem()
  duals = mpo.init_duals(mpo.MPOConfig(), A)
  grads = {}
  for flag in (False, True):
    grads[flag] = _grads(duals, target, target, actions, q_values,
                         mpo.MPOConfig(clip_mean_targets=flag))[1]
  bound = 1.0 + np.asarray(target.scale)  # [S, A]
  clipped = np.clip(np.asarray(actions), -bound, bound)
  refit = (np.asarray(target.mean) - clipped.mean(0)) / np.square(np.asarray(target.scale)) / S
  np.testing.assert_allclose(grads[True].mean, refit, rtol=1e-3, atol=1e-6)
  step = -np.asarray(grads[True].mean)[:, :2]  # gradient descent, the saturated dimensions
  beyond = np.abs(np.asarray(target.mean[:, :2])) > 1.0 + 2 * np.asarray(target.scale[:, :2])
  assert beyond.mean() > 0.7
  assert np.all((step * -np.sign(np.asarray(target.mean[:, :2])))[beyond] > 0)  # inwards
  np.testing.assert_array_equal(grads[True].scale, grads[False].scale)
  inside = jnp.clip(actions, -1.4, 1.4)  # nothing beyond 1 + scale: the paper's M-step
  for a, b in zip(jax.tree.leaves(_grads(duals, target, target, inside, q_values,
                                         mpo.MPOConfig(clip_mean_targets=True))),
                  jax.tree.leaves(_grads(duals, target, target, inside, q_values,
                                         mpo.MPOConfig())), strict=True):
    np.testing.assert_array_equal(a, b)
  traced = jax.jit(lambda flag: _grads(duals, target, target, actions, q_values,
                                       mpo.MPOConfig(clip_mean_targets=flag))[1].mean)
  for flag in (False, True):
    np.testing.assert_allclose(traced(jnp.array(flag)), grads[flag].mean, rtol=1e-5, atol=1e-8)
