"""The diagonal Gaussian and the Gaussian mixture against scipy / numpy closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from mjx_form.rl.distributions import (DiagonalGaussian, GaussianMixture, correlated_noise,
                                       scale_from_raw)


def _random_gaussian(rng, shape):
  return DiagonalGaussian(rng.normal(size=shape).astype(np.float32),
                          rng.uniform(0.2, 2.0, size=shape).astype(np.float32))


def _np_kl(m1, s1, m2, s2):
  """KL(N(m1, s1^2) || N(m2, s2^2)) per dimension, float64."""
  m1, s1, m2, s2 = (np.asarray(v, np.float64) for v in (m1, s1, m2, s2))
  return np.log(s2 / s1) + (s1 ** 2 + (m1 - m2) ** 2) / (2 * s2 ** 2) - 0.5


def test_log_prob_and_entropy_match_scipy():
  rng = np.random.default_rng(0)
  dist = _random_gaussian(rng, (5, 3))
  x = rng.normal(size=(7, 5, 3)).astype(np.float32)
  expected = stats.norm(dist.mean, dist.scale).logpdf(x).sum(-1)
  np.testing.assert_allclose(dist.log_prob(x), expected, rtol=1e-5, atol=1e-5)
  assert dist.log_prob(x).shape == (7, 5)
  np.testing.assert_allclose(dist.entropy(), stats.norm(dist.mean, dist.scale).entropy().sum(-1),
                             rtol=1e-5, atol=1e-5)
  np.testing.assert_array_equal(dist.mode(), dist.mean)


def test_kl_matches_closed_form():
  rng = np.random.default_rng(1)
  p, q = _random_gaussian(rng, (4, 6)), _random_gaussian(rng, (4, 6))
  expected = _np_kl(p.mean, p.scale, q.mean, q.scale)
  np.testing.assert_allclose(p.kl_divergence(q, per_dim=True), expected, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(p.kl_divergence(q), expected.sum(-1), rtol=1e-5, atol=1e-5)
  assert p.kl_divergence(q).shape == (4,)
  # Monte Carlo check of the direction, KL(p || q) = E_p[log p - log q].
  x = p.sample(jax.random.key(0), (200_000,))
  mc = jnp.mean(p.log_prob(x) - q.log_prob(x), axis=0)
  np.testing.assert_allclose(mc, expected.sum(-1), rtol=0.03, atol=0.02)


def test_kl_precise_for_nearly_equal_scales():
  # The scale constraint is ~1e-5: the KL must stay accurate well below that in float32.
  s1 = np.float32(1.0)
  s2 = np.float32(1.001)
  kl = DiagonalGaussian(jnp.zeros(1), jnp.full(1, s1)).kl_divergence(
      DiagonalGaussian(jnp.zeros(1), jnp.full(1, s2)))
  np.testing.assert_allclose(kl, _np_kl(0, s1, 0, np.float64(s2)), rtol=1e-3)


def test_kl_of_equal_distributions_is_zero():
  rng = np.random.default_rng(2)
  p = _random_gaussian(rng, (3, 5))
  np.testing.assert_array_equal(p.kl_divergence(p, per_dim=True), np.zeros((3, 5)))
  grads = jax.grad(lambda m, s: DiagonalGaussian(m, s).kl_divergence(p).sum(), argnums=(0, 1))(
      jnp.asarray(p.mean), jnp.asarray(p.scale))
  np.testing.assert_allclose(grads[0], 0.0, atol=1e-6)
  np.testing.assert_allclose(grads[1], 0.0, atol=1e-6)


def test_sample_moments_and_shapes():
  mean = jnp.array([-1.0, 0.5, 3.0])
  scale = jnp.array([0.1, 1.0, 2.5])
  dist = DiagonalGaussian(mean, scale)
  x = dist.sample(jax.random.key(3), (100_000,))
  assert x.shape == (100_000, 3) and x.dtype == jnp.float32
  np.testing.assert_allclose(x.mean(0), mean, atol=4 * 2.5 / np.sqrt(100_000))
  np.testing.assert_allclose(x.std(0), scale, rtol=0.01)
  assert dist.sample(jax.random.key(0)).shape == (3,)
  # Broadcast batch shape, and reparameterised: d sample / d mean = 1.
  batched = DiagonalGaussian(jnp.zeros((4, 3)), jnp.ones(3))
  assert batched.sample(jax.random.key(1), (2,)).shape == (2, 4, 3)
  grad = jax.grad(lambda m: DiagonalGaussian(m, scale).sample(jax.random.key(4)).sum())(mean)
  np.testing.assert_allclose(grad, 1.0)


def test_is_a_pytree_under_jit_and_vmap():
  dist = DiagonalGaussian(jnp.zeros((6, 2)), jnp.ones((6, 2)))
  log_probs = jax.jit(jax.vmap(lambda d, x: d.log_prob(x)))(dist, jnp.zeros((6, 2)))
  np.testing.assert_allclose(log_probs, -np.log(2 * np.pi), rtol=1e-6)


@pytest.mark.parametrize("min_scale", [1e-4, 1e-2])
def test_scale_from_raw(min_scale):
  raw = jnp.array([-100.0, -1.0, 0.0, 3.0, 50.0])
  expected = np.log1p(np.exp(np.asarray(raw, np.float64))) + min_scale
  np.testing.assert_allclose(scale_from_raw(raw, min_scale), expected, rtol=1e-6)
  assert float(scale_from_raw(jnp.array(-1e4), min_scale)) == pytest.approx(min_scale)


def _random_mixture(rng, batch, k, d):
  return GaussianMixture(rng.normal(size=batch + (k,)).astype(np.float32),
                         rng.normal(size=batch + (k, d)).astype(np.float32),
                         rng.uniform(0.3, 2.0, size=batch + (k, d)).astype(np.float32))


def test_mixture_log_prob_matches_scipy():
  rng = np.random.default_rng(3)
  mix = _random_mixture(rng, (5,), 4, 3)
  x = rng.normal(size=(5, 3)).astype(np.float32) * 2
  weights = np.exp(mix.logits - np.logaddexp.reduce(mix.logits.astype(np.float64), -1,
                                                    keepdims=True))
  expected = np.log([sum(weights[b, k] * stats.multivariate_normal(
      mix.mean[b, k], np.diag(np.square(mix.scale[b, k].astype(np.float64)))).pdf(x[b])
      for k in range(4)) for b in range(5)])
  np.testing.assert_allclose(mix.log_prob(x), expected, rtol=1e-5, atol=1e-5)
  # Broadcasting: the same mixture scored at several points per batch element.
  many = rng.normal(size=(2, 5, 3)).astype(np.float32)
  assert mix.log_prob(many).shape == (2, 5)


def test_mixture_samples_follow_its_weights_and_components():
  """Component frequencies, mean and variance of many draws against the mixture's moments."""
  mix = GaussianMixture(jnp.log(jnp.array([0.2, 0.5, 0.3])),
                        jnp.array([[-3.0, 0.0], [0.0, 1.0], [4.0, -1.0]]),
                        jnp.array([[0.4, 1.0], [0.4, 0.2], [0.3, 0.3]]))
  n = 200_000
  batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), mix)
  x = np.asarray(batch.sample(jax.random.PRNGKey(0)))
  w = np.array([0.2, 0.5, 0.3])
  mean = w @ np.asarray(mix.mean)
  var = w @ (np.asarray(mix.scale) ** 2 + np.asarray(mix.mean) ** 2) - mean ** 2
  np.testing.assert_allclose(x.mean(0), mean, atol=0.02)
  np.testing.assert_allclose(x.var(0), var, rtol=0.02)
  # The first coordinate separates the components: their shares are the weights.
  shares = np.array([np.mean(x[:, 0] < -1.5), np.mean(np.abs(x[:, 0]) < 1.5),
                     np.mean(x[:, 0] > 2.5)])
  np.testing.assert_allclose(shares, w, atol=0.01)


def test_correlated_noise_is_a_unit_variance_ar1_restarted_by_nan():
  """`correlated_noise` iterated over many chains against the AR(1)'s own formulas (numpy):
  stationary variance 1 and lag-k correlation c^k from a fresh start; NaN restarts with xi."""
  c, chains, steps = 0.8, 20_000, 12
  xi = np.random.default_rng(0).standard_normal((steps, chains)).astype(np.float32)
  e = np.full((chains,), np.nan, np.float32)
  path = []
  for t in range(steps):
    e = np.asarray(correlated_noise(e, xi[t], c))
    path.append(e)
  path = np.stack(path)
  np.testing.assert_array_equal(path[0], xi[0])  # a fresh start takes the draw itself
  np.testing.assert_allclose(path.var(axis=1), 1.0, atol=0.04)  # stationary from the start
  for lag in (1, 3):
    corr = np.corrcoef(path[5], path[5 + lag])[0, 1]
    assert abs(corr - c ** lag) < 0.02, (lag, corr)
  assert abs(np.corrcoef(path[5], path[6])[0, 1]) > 0.7  # and c = 0 would give ~0:
  independent = np.asarray(correlated_noise(path[5], xi[6], 0.0))
  np.testing.assert_array_equal(independent, xi[6])
  # The Gaussian's correlated draw: from a fresh start (NaN) and with c = 0 it is `sample`'s
  # draw; later it is mean + scale * the continued noise.
  pi = DiagonalGaussian(jnp.array([[0.5, -1.0]]), jnp.array([[2.0, 0.1]]))
  key, fresh = jax.random.PRNGKey(4), jnp.full((1, 2), jnp.nan)
  for c in (0.0, 0.8):
    draw, noise = pi.sample_correlated(key, fresh, c)
    np.testing.assert_array_equal(draw, pi.sample(key))
  assert np.isnan(pi.sample_correlated(key, fresh, 0.0)[1]).all()  # c = 0: last unchanged
  last = jnp.array([[1.0, -2.0]])
  draw, noise = pi.sample_correlated(key, last, 0.8)
  expected = 0.8 * last + 0.6 * (pi.sample(key) - pi.mean) / pi.scale
  np.testing.assert_allclose(noise, expected, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(draw, pi.mean + pi.scale * noise, rtol=1e-6)
  # A population member's c is an array (traced): at 0 it still draws exactly `sample`'s draw,
  # also after an earlier step's noise, and keeps that draw's noise as its state.
  zero = jax.jit(lambda last, c: pi.sample_correlated(key, last, c))
  draw, noise = zero(last, jnp.float32(0.0))
  np.testing.assert_array_equal(draw, pi.sample(key))
  np.testing.assert_array_equal(noise, jax.random.normal(key, (1, 2)))  # `sample`'s xi
  np.testing.assert_allclose(zero(last, jnp.float32(0.8))[1], expected, rtol=1e-5, atol=1e-6)


def test_noise_log_prob_is_exact_where_the_draw_rounds_away_its_noise():
  """`noise_log_prob(e)` is log_prob of mean + scale e, computed from e: equal to it at a
  moderate scale, and right (float64's value) at a scale of 1e-8 beside a mean of 2, where the
  float32 draw loses its noise to rounding and `log_prob` of it is nats off."""
  e = jax.random.normal(jax.random.PRNGKey(0), (64, 3))
  exact = lambda scale: (-0.5 * np.square(np.asarray(e, np.float64)) - np.log(scale)
                         - 0.5 * np.log(2 * np.pi)).sum(-1)
  for scale, faithful in ((0.5, True), (1e-8, False)):
    pi = DiagonalGaussian(jnp.full((64, 3), 2.0), jnp.full((64, 3), scale))
    np.testing.assert_allclose(pi.noise_log_prob(e), exact(scale), rtol=1e-5)
    off = np.abs(np.asarray(pi.log_prob(pi.mean + pi.scale * e)) - exact(scale)).max()
    assert (off < 1e-3) if faithful else (off > 1), (scale, off)
  # and it is the noise of `sample_correlated`'s draw, for either kind of c
  pi = DiagonalGaussian(jnp.zeros((4, 3)), jnp.full((4, 3), 0.7))
  last = jnp.full((4, 3), jnp.nan)
  for c in (0.0, jnp.array(0.5)):
    draw, state = pi.sample_correlated(jax.random.PRNGKey(1), last, c)
    noise, same_state = pi.unit_noise(jax.random.PRNGKey(1), last, c)
    np.testing.assert_array_equal(draw, pi.mean + pi.scale * noise)
    np.testing.assert_array_equal(state, same_state)
