"""The MPO networks of the paper (../shared/DESIGN.md, "Algorithms"), in flax.

Encoder: linear 256, optional LayerNorm, tanh, then optional hidden layers of 256 with ELU.
Policy:  encoder (LayerNorm, one hidden layer) -> diagonal Gaussian; its head (`POLICY_HEADS`)
         is the paper's (mean unbounded, scale softplus + 1e-4) or Acme's control-suite MPO
         head (mean tanh-bounded to (-1, 1), scale at least 0.3; Acme rescales each task's
         action spec to [-1, 1] first, this repository does not: quadruped's lift actuators,
         whose range goes to 1.1, stay below 1 with it).
Critic:  encoder (LayerNorm, one hidden layer) of the observation, concatenated with
         tanh(action) -> linear 256, LayerNorm, tanh -> 3 layers of 256 with ELU -> scalar.
         The linear layer on the concatenation runs split (`ConcatDense`), so that with N
         sampled actions per state the observation's half is computed once, not N times.
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


@dataclasses.dataclass(frozen=True)
class PolicyHead:
  """How the policy's last layer becomes a Gaussian: mean = tanh(raw) if `tanh_mean` else raw;
  scale = softplus(raw) * init_scale / softplus(0) + min_scale (init_scale None: factor 1)."""

  tanh_mean: bool = False
  min_scale: float = 1e-4
  init_scale: float | None = None


POLICY_HEADS = {
    # The paper's: the mean may leave [-1, 1] (the environment clamps the action to its control
    # range), the scale may shrink to 1e-4.
    "paper": PolicyHead(),
    # Acme's control-suite MPO/DMPO head (`MultivariateNormalDiagHead(tanh_mean=True,
    # min_scale=0.3, init_scale=0.7)`): the mean stays in the bounds, the scale at 0.3 or more
    # (1.0 at initialisation), so every action dimension keeps exploring.
    "acme": PolicyHead(tanh_mean=True, min_scale=0.3, init_scale=0.7),
}


def policy_head(name: str) -> PolicyHead:
  """The head called `name`; ValueError naming the valid ones."""
  if name not in POLICY_HEADS:
    raise ValueError(f"unknown policy head {name!r}; valid heads: {', '.join(POLICY_HEADS)}")
  return POLICY_HEADS[name]


class GaussianPolicy(nn.Module):
  """Observation [..., D] -> DiagonalGaussian with mean and scale [..., A]."""

  action_size: int
  width: int = 256
  head: PolicyHead = PolicyHead()

  @nn.compact
  def __call__(self, obs: jax.Array, hold_features: bool = False) -> DiagonalGaussian:
    """hold_features: no gradient reaches the layers below the last (BC's "squared" fit trains
    the scale through the last layer alone, mjx_form/rl/cloning.py)."""
    h = Encoder(self.width)(obs)
    if hold_features:
      h = jax.lax.stop_gradient(h)
    out = nn.Dense(2 * self.action_size, kernel_init=nn.initializers.variance_scaling(
        1e-4, "fan_in", "truncated_normal"))(h)  # small initial means: actions near 0
    mean, raw_scale = jnp.split(out, 2, axis=-1)
    if self.head.tanh_mean:
      mean = jnp.tanh(mean)
    if self.head.init_scale is not None:  # rescaled: raw = 0 gives init_scale + min_scale
      scale = (jax.nn.softplus(raw_scale) * (self.head.init_scale / jax.nn.softplus(0.0))
               + self.head.min_scale)
    else:
      scale = scale_from_raw(raw_scale, self.head.min_scale)
    return DiagonalGaussian(mean, scale)


class ConcatDense(nn.Module):
  """nn.Dense of concat([x, y], -1), its kernel [X + Y, F] applied in two parts:
  x @ kernel[:X] + y @ kernel[X:] + bias. `x`'s batch shape may be a suffix of `y`'s (one x
  for N y's): x's part is then computed once and broadcast. Same parameters, names and
  initialisation as nn.Dense on the concatenation."""

  features: int

  @nn.compact
  def __call__(self, x: jax.Array, y: jax.Array) -> jax.Array:  # [..., X], [..., Y] -> [..., F]
    kernel = self.param("kernel", nn.initializers.lecun_normal(),
                        (x.shape[-1] + y.shape[-1], self.features))
    bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
    return (x @ kernel[:x.shape[-1]] + bias) + y @ kernel[x.shape[-1]:]


class Critic(nn.Module):
  """(observation [..., D], action [..., A]) -> Q [...].

  The observation's batch shape may be a suffix of the action's: Q of N sampled actions per
  state takes obs [B, D] with actions [N, B, A]; the encoder, and the observation's half of the
  first layer after it, run once per state, not N times. `tiled=True` computes the same
  function plainly, nn.Dense on the concatenation with the encoding tiled over the actions
  (same parameters): the reference of the tests and of `benchmarks/update_speed.py`.
  """

  width: int = 256
  layers: Sequence[int] = (256, 256, 256)
  tiled: bool = False

  @property
  def head_name(self) -> str:
    """The last layer's name in the parameter tree (width -> 1, Q)."""
    return f"Dense_{len(self.layers) + 1}"

  @nn.compact
  def __call__(self, obs: jax.Array, action: jax.Array, features_only: bool = False
               ) -> jax.Array:
    """Q [...], or with `features_only` the last layer's input h [..., layers[-1]]."""
    encoded = Encoder(self.width)(obs)  # [..., width], batch shape of obs
    # Explicit names: both forms have the parameter tree of nn.Dense layers.
    if self.tiled:
      encoded = jnp.broadcast_to(encoded, action.shape[:-1] + encoded.shape[-1:])
      h = nn.Dense(self.width, name="Dense_0")(
          jnp.concatenate([encoded, jnp.tanh(action)], axis=-1))
    else:
      h = ConcatDense(self.width, name="Dense_0")(encoded, jnp.tanh(action))  # [..., width]
    h = jnp.tanh(nn.LayerNorm()(h))
    for i, size in enumerate(self.layers):
      h = nn.elu(nn.Dense(size, name=f"Dense_{i + 1}")(h))
    if features_only:
      return h
    return nn.Dense(1, name=self.head_name)(h)[..., 0]


@dataclasses.dataclass(frozen=True)
class Networks:
  """The policy and critic modules of one run (stateless; parameters live in the train state)."""

  policy: GaussianPolicy
  critic: Critic


def make_networks(action_size: int, width: int = 256, head: str = "paper") -> Networks:
  return Networks(GaussianPolicy(action_size, width, policy_head(head)),
                  Critic(width, (width,) * 3))
