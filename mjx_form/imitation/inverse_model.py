"""BCO's inverse model p(a_t | x_t, x_{t+1}) (paper, appendix "Baselines: GAIfO and BCO";
../shared/DESIGN.md).

Network: the effect models' architecture with the policy's distribution class as its head. The
pair (x_t, x_{t+1}) enters standardised by the model's own EMA statistics of single
observations (decay 0.99 per batch, as the effect models'), concatenated [2D]; the shared
encoder (linear `width`, LayerNorm, tanh, one hidden layer of `width` with ELU), one more hidden
layer of `width` (ELU), and a diagonal Gaussian over the action: mean unbounded, scale
softplus + 1e-4.

Objective: the mean log-likelihood of the actions the imitator took at its own transitions
(those whose successor is stored), each action as the environment applied it (clipped to the
task's control range, `bounds`: a sample beyond a bound moves the body as the bound does, so
nothing in (x_t, x_{t+1}) tells them apart). Adam, learning rate 1e-4. (Not the decoupled fit
of BC's policy, mjx_form/rl/cloning.py: on transitions of evenly spread actions the likelihood
fitted the mean faster; NOTES session 69.)
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from mjx_form.rl import normalizer
from mjx_form.rl.distributions import DiagonalGaussian, scale_from_raw
from mjx_form.rl.networks import Encoder


@dataclasses.dataclass(frozen=True)
class InverseModelConfig:
  """The paper's settings."""

  width: int = 256
  learning_rate: float = 1e-4
  normalizer_decay: float = 0.99

  def to_dict(self) -> dict:
    return dataclasses.asdict(self)

  def check(self) -> None:
    if isinstance(self.width, bool) or not isinstance(self.width, int) or self.width < 1:
      raise ValueError(f"inverse model width must be a positive integer, got {self.width!r}")
    if not self.learning_rate > 0:
      raise ValueError(f"inverse model learning_rate must be positive, got "
                       f"{self.learning_rate}")
    if not 0.0 <= self.normalizer_decay < 1.0:
      raise ValueError(f"inverse model normalizer_decay must be in [0, 1), got "
                       f"{self.normalizer_decay}")


class InverseModel(nn.Module):
  """Standardised (x_t, x_{t+1}) concatenated [..., 2D] -> DiagonalGaussian over a_t [..., A]."""

  action_size: int
  width: int = 256

  @nn.compact
  def __call__(self, pair: jax.Array) -> DiagonalGaussian:
    h = nn.elu(nn.Dense(self.width)(Encoder(self.width)(pair)))
    mean, raw = jnp.split(nn.Dense(2 * self.action_size)(h), 2, axis=-1)
    return DiagonalGaussian(mean, scale_from_raw(raw))


class InverseModelState(NamedTuple):
  params: Any
  opt_state: Any
  normalizer: normalizer.NormalizerState  # of one observation [D]
  steps: jax.Array  # int32 [], gradient steps taken


def _optimizer(config: InverseModelConfig) -> optax.GradientTransformation:
  return optax.adam(config.learning_rate)


def init(config: InverseModelConfig, observation_size: int, action_size: int,
         key: jax.Array) -> InverseModelState:
  params = InverseModel(action_size, config.width).init(key, jnp.zeros((1, 2 * observation_size)))
  return InverseModelState(params, _optimizer(config).init(params),
                           normalizer.init(observation_size), jnp.zeros((), jnp.int32))


def pairs(norm: normalizer.NormalizerState, x: jax.Array, x_next: jax.Array) -> jax.Array:
  """The model's input of raw x [..., D] and x_next [..., D]: [..., 2D]."""
  return jnp.concatenate([normalizer.normalize(norm, x), normalizer.normalize(norm, x_next)],
                         axis=-1)


def loss(model: InverseModel, params, pair: jax.Array, actions: jax.Array,
         valid: jax.Array) -> tuple[jax.Array, dict]:
  """-mean log p(a | pair) over the valid rows: pair [N, 2D] standardised, actions [N, A],
  valid [N]; metrics: that mean log-likelihood and the mean squared error of the mean."""
  weights = valid.astype(jnp.float32)
  count = jnp.maximum(jnp.sum(weights), 1.0)
  dist = model.apply(params, pair)
  log_prob = jnp.sum(weights * dist.log_prob(actions)) / count
  error = jnp.sum(weights * jnp.mean(jnp.square(dist.mean - actions), axis=-1)) / count
  return -log_prob, {"log_prob": log_prob, "action_error": error}


def update(config: InverseModelConfig, state: InverseModelState, x: jax.Array,
           x_next: jax.Array, actions: jax.Array, valid: jax.Array
           ) -> tuple[InverseModelState, dict]:
  """One step on transitions x [N, D] -> x_next [N, D] (raw) by actions [N, A] (as applied),
  valid [N]: fold the valid rows' observations into the standardisation, then one Adam step."""
  both = jnp.stack([x, x_next], axis=1)  # [N, 2, D]
  norm = normalizer.update(state.normalizer, both, config.normalizer_decay,
                           mask=jnp.broadcast_to(valid[:, None], both.shape[:2]))
  model = InverseModel(actions.shape[-1], config.width)
  grads, metrics = jax.grad(lambda p: loss(model, p, pairs(norm, x, x_next), actions, valid),
                            has_aux=True)(state.params)
  change, opt_state = _optimizer(config).update(grads, state.opt_state, state.params)
  return InverseModelState(optax.apply_updates(state.params, change), opt_state, norm,
                           state.steps + 1), metrics


def predict(config: InverseModelConfig, state: InverseModelState, x: jax.Array,
            x_next: jax.Array, action_size: int) -> jax.Array:
  """The most likely action (the mean) of each transition x [..., D] -> x_next [..., D] raw:
  [..., A]."""
  return InverseModel(action_size, config.width).apply(
      state.params, pairs(state.normalizer, x, x_next)).mean
