"""Distributions as NamedTuples of arrays, so they are pytrees (jit, vmap, stop_gradient and
tree_map apply to them): the policy's diagonal Gaussian ([..., A]; the last axis is the action)
and the effect models' mixture of diagonal Gaussians ([..., K, D]); and the actors' noise
correlated in time (`correlated_noise`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def scale_from_raw(raw: jax.Array, min_scale: float = 1e-4,
                   max_scale: float | None = None) -> jax.Array:
  """Maps an unconstrained network output to a standard deviation: s = softplus(raw) +
  min_scale, or with `max_scale` m the soft cap s m / (s + m), written m / (1 + m / s) so that
  no product overflows (about s where s << m, below m always, smooth in raw)."""
  s = jax.nn.softplus(raw) + min_scale
  return s if max_scale is None else max_scale / (1.0 + max_scale / s)


class DiagonalGaussian(NamedTuple):
  """Independent normals over the last axis. `mean`, `scale` (standard deviation): [..., A]."""

  mean: jax.Array
  scale: jax.Array

  def sample(self, key: jax.Array, sample_shape: tuple[int, ...] = ()) -> jax.Array:
    """Reparameterised draws, [*sample_shape, ..., A]."""
    shape = tuple(sample_shape) + jnp.broadcast_shapes(jnp.shape(self.mean), jnp.shape(self.scale))
    dtype = jnp.result_type(self.mean, self.scale)
    return self.mean + self.scale * jax.random.normal(key, shape, dtype)

  def sample_correlated(self, key: jax.Array, last: jax.Array,
                        c: float) -> tuple[jax.Array, jax.Array]:
    """One draw [..., A] whose noise continues `last` [..., A] (`correlated_noise`), and that
    noise; c = 0 as a Python number: `sample`'s draw, `last` returned unchanged (as an array, c =
    0 gives the same draw and returns its noise)."""
    noise, state = self.unit_noise(key, last, c)
    return self.mean + self.scale * noise, state

  def unit_noise(self, key: jax.Array, last: jax.Array,
                 c: float) -> tuple[jax.Array, jax.Array]:
    """The standard normal noise e [..., A] of `sample_correlated`'s draw (mean + scale e), and
    the noise state it leaves (`last` unchanged where c is a Python 0)."""
    shape = jnp.broadcast_shapes(jnp.shape(self.mean), jnp.shape(self.scale))
    xi = jax.random.normal(key, shape, jnp.result_type(self.mean, self.scale))  # `sample`'s draw
    if isinstance(c, (int, float)) and not c:
      return xi, last
    noise = correlated_noise(last, xi, c)
    return noise, noise

  def noise_log_prob(self, noise: jax.Array) -> jax.Array:
    """`log_prob` of the draw mean + scale noise, from its noise [..., A]: [...]. Exact where
    the draw itself is not (a scale far below |mean| loses the noise to rounding in x - mean)."""
    return jnp.sum(-0.5 * jnp.square(noise) - jnp.log(self.scale) - _HALF_LOG_2PI, axis=-1)

  def log_prob(self, x: jax.Array) -> jax.Array:
    """Log density of `x` [..., A], summed over the action axis: [...]."""
    z = (x - self.mean) / self.scale
    return jnp.sum(-0.5 * jnp.square(z) - jnp.log(self.scale) - _HALF_LOG_2PI, axis=-1)

  def entropy(self) -> jax.Array:
    """Differential entropy, [...]."""
    log_scale = jnp.log(self.scale) + jnp.zeros_like(self.mean)
    return jnp.sum(0.5 + _HALF_LOG_2PI + log_scale, axis=-1)

  def kl_divergence(self, other: DiagonalGaussian, per_dim: bool = False) -> jax.Array:
    """KL(self || other): [..., A] with `per_dim`, else summed over the action axis, [...].

    Per dimension 0.5 ((m1 - m2) / s2)^2 + 0.5 (expm1(2u) - 2u) with u = log(s1 / s2), which
    equals log(s2 / s1) + (s1^2 + (m1 - m2)^2) / (2 s2^2) - 1/2 but keeps its precision for
    nearly equal scales (the scale constraint is ~1e-5) and is exactly 0 for equal inputs.
    """
    u = jnp.log(self.scale) - jnp.log(other.scale)
    kl = 0.5 * jnp.square((self.mean - other.mean) / other.scale)
    kl = kl + 0.5 * (jnp.expm1(2.0 * u) - 2.0 * u)
    return kl if per_dim else jnp.sum(kl, axis=-1)

  def mode(self) -> jax.Array:
    """The most likely action (the mean), [..., A]."""
    return self.mean


class GaussianMixture(NamedTuple):
  """A mixture of K diagonal Gaussians over the last axis (FORM's effect-model head).

  logits [..., K] (unnormalised mixture weights), mean and scale [..., K, D].
  """

  logits: jax.Array
  mean: jax.Array
  scale: jax.Array

  def component_log_probs(self, x: jax.Array) -> jax.Array:
    """log w_k + log N(x; mean_k, diag(scale_k^2)) for x [..., D]: [..., K]."""
    z = (x[..., None, :] - self.mean) / self.scale
    log_normal = jnp.sum(-0.5 * jnp.square(z) - jnp.log(self.scale) - _HALF_LOG_2PI, axis=-1)
    return jax.nn.log_softmax(self.logits, axis=-1) + log_normal

  def log_prob(self, x: jax.Array) -> jax.Array:
    """Log density of x [..., D]: [...]."""
    return jax.nn.logsumexp(self.component_log_probs(x), axis=-1)

  def sample(self, key: jax.Array) -> jax.Array:
    """One draw per batch element, [..., D]: a component by its weight, then its Gaussian."""
    component_key, normal_key = jax.random.split(key)
    k = jax.random.categorical(component_key, self.logits, axis=-1)  # [...]
    pick = lambda a: jnp.take_along_axis(a, k[..., None, None], axis=-2)[..., 0, :]
    mean, scale = pick(self.mean), pick(self.scale)
    return mean + scale * jax.random.normal(normal_key, mean.shape, mean.dtype)


def correlated_noise(last: jax.Array, xi: jax.Array, c: float) -> jax.Array:
  """The actors' noise of this step from the last step's `last` and fresh standard normal draws
  `xi` (same shape): c last + sqrt(1 - c^2) xi, a stationary AR(1) with unit variance; xi
  itself where `last` is NaN (an episode's first step)."""
  return jnp.where(jnp.isnan(last), xi, c * last + jnp.sqrt(1.0 - c * c) * xi)
