"""The MPO networks of the paper (../shared/DESIGN.md, "Algorithms"), in flax.

Encoder: linear 256, optional LayerNorm, tanh, then optional hidden layers of 256 with ELU.
Policy:  encoder (LayerNorm, one hidden layer) -> diagonal Gaussian, scale softplus + 1e-4.
Critic:  encoder (LayerNorm, one hidden layer) of the observation, concatenated with
         tanh(action) -> linear 256, LayerNorm, tanh -> 3 layers of 256 with ELU -> scalar.
Policy and critic are independent (no shared parameters). Observations enter standardised.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from mjx_form.rl.distributions import DiagonalGaussian, scale_from_raw


class Encoder(nn.Module):
  """Linear `width`, optional LayerNorm, tanh, then `hidden_layers` x (linear `width`, ELU)."""

  width: int = 256
  layer_norm: bool = True
  hidden_layers: int = 1

  @nn.compact
  def __call__(self, x: jax.Array) -> jax.Array:  # [..., D] -> [..., width]
    x = nn.Dense(self.width)(x)
    if self.layer_norm:
      x = nn.LayerNorm()(x)
    x = jnp.tanh(x)
    for _ in range(self.hidden_layers):
      x = nn.elu(nn.Dense(self.width)(x))
    return x


class GaussianPolicy(nn.Module):
  """Observation [..., D] -> DiagonalGaussian with mean and scale [..., A]."""

  action_size: int
  width: int = 256
  min_scale: float = 1e-4

  @nn.compact
  def __call__(self, obs: jax.Array) -> DiagonalGaussian:
    h = Encoder(self.width)(obs)
    out = nn.Dense(2 * self.action_size, kernel_init=nn.initializers.variance_scaling(
        1e-4, "fan_in", "truncated_normal"))(h)  # small initial means: actions near 0
    mean, raw_scale = jnp.split(out, 2, axis=-1)
    return DiagonalGaussian(mean, scale_from_raw(raw_scale, self.min_scale))


class Critic(nn.Module):
  """(observation [..., D], action [..., A]) -> Q [...].

  The observation's batch shape may be a suffix of the action's: Q of N sampled actions per
  state takes obs [B, D] with actions [N, B, A], and the encoder runs once per state, not N times.
  """

  width: int = 256
  layers: Sequence[int] = (256, 256, 256)

  @nn.compact
  def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
    encoded = Encoder(self.width)(obs)  # [..., width], batch shape of obs
    encoded = jnp.broadcast_to(encoded, action.shape[:-1] + encoded.shape[-1:])
    h = jnp.concatenate([encoded, jnp.tanh(action)], axis=-1)
    h = jnp.tanh(nn.LayerNorm()(nn.Dense(self.width)(h)))
    for size in self.layers:
      h = nn.elu(nn.Dense(size)(h))
    return nn.Dense(1)(h)[..., 0]


@dataclasses.dataclass(frozen=True)
class Networks:
  """The policy and critic modules of one run (stateless; parameters live in the train state)."""

  policy: GaussianPolicy
  critic: Critic


def make_networks(action_size: int, width: int = 256) -> Networks:
  return Networks(GaussianPolicy(action_size, width), Critic(width, (width,) * 3))
