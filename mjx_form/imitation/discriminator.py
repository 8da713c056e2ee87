"""GAIfO's discriminator p(expert | x) and its training objective (paper, appendix "GAIfO";
../shared/DESIGN.md).

Network: observations enter standardised with the discriminator's own EMA statistics (as the
effect models', decay 0.99 per batch, over the expert's and the imitator's frames together);
the shared encoder without LayerNorm or hidden layers (linear `width`, tanh) encodes them; a
decoder of two hidden layers of `width` (ELU) gives the log odds that the input is the
expert's. The input is one frame, the observation a transition leads to (the paper's main
table), or with `frames` 2 the pair (x_t, x_{t+1}) concatenated.

Objective, maximised on a batch of expert inputs E and imitator inputs I:
  mean_E log D(e) + mean_I log(1 - D(i)) - beta_gp * mean ||grad_z decoder(z)||_2 / width,
z = u * encoder(e) + (1 - u) * encoder(i) with u ~ U(0, 1) drawn per pair each update (the
paper's gradient penalty "on the decoder MLP" at random interpolations of the two encodings,
"beta_gp about 10, divided by 256", the width; written there with a plus sign in the maximised
objective, a penalty here). z is held fixed (stop_gradient): the penalty regularises the
decoder, not the encoder. beta_gp 0 is GAIfO (the norm then only a metric), > 0 GAIfO+GP. Adam,
learning rate 1e-4.

Variational bottleneck (VAIfO, `kl_bound` epsilon; the paper's 1.0): the encoding is the mean
of a diagonal Gaussian q(z | x) (a linear layer on the encoder's output gives its mean and, by
softplus + 1e-4, its scale), the decoder sees a sample z ~ q(z | x) in training and the mean
in the reward, and the objective adds - beta * (KL - epsilon), KL the mean of KL(q(z | x) ||
N(0, I)) over both sides' inputs, with beta >= 0 a learned multiplier that holds the
constraint hard: log beta takes Adam steps (the discriminator's learning rate) up the same
term, so beta grows while KL > epsilon and shrinks below it (starting at 1). The penalty of
VAIfO+GP interpolates the two sides' samples.

Reward of a transition: log(1 + D(x_{t+1})) (the paper: "a softplus transform: log(1 +
p(expert | x_t))", i.e. softplus of log D), in [0, log 2].
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from mjx_form.rl import normalizer
from mjx_form.rl.networks import Encoder


@dataclasses.dataclass(frozen=True)
class DiscriminatorConfig:
  """The paper's settings; `gradient_penalty` (beta_gp) is tuned per task there (~10)."""

  width: int = 256
  frames: int = 1  # 1: x_{t+1}; 2: (x_t, x_{t+1})
  gradient_penalty: float = 0.0  # beta_gp; 0: GAIfO, > 0: GAIfO+GP
  kl_bound: float | None = None  # VAIfO's epsilon (module docstring); None: no bottleneck
  learning_rate: float = 1e-4
  normalizer_decay: float = 0.99

  def to_dict(self) -> dict:
    return dataclasses.asdict(self)

  def check(self) -> None:
    if isinstance(self.width, bool) or not isinstance(self.width, int) or self.width < 1:
      raise ValueError(f"discriminator width must be a positive integer, got {self.width!r}")
    if self.frames not in (1, 2):
      raise ValueError(f"discriminator frames must be 1 or 2, got {self.frames!r}")
    if not 0 <= self.gradient_penalty < float("inf"):
      raise ValueError(f"discriminator gradient_penalty must be >= 0 and finite, got "
                       f"{self.gradient_penalty}")
    if self.kl_bound is not None and (isinstance(self.kl_bound, bool)
                                      or not 0 <= self.kl_bound < float("inf")):
      raise ValueError(f"discriminator kl_bound must be >= 0 and finite, or none; got "
                       f"{self.kl_bound!r}")
    if not self.learning_rate > 0:
      raise ValueError(f"discriminator learning_rate must be positive, got "
                       f"{self.learning_rate}")
    if not 0.0 <= self.normalizer_decay < 1.0:
      raise ValueError(f"discriminator normalizer_decay must be in [0, 1), got "
                       f"{self.normalizer_decay}")


class Discriminator(nn.Module):
  """Standardised inputs [..., frames * D] -> log odds [...] that they are the expert's (with a
  bottleneck: of the mean encoding)."""

  width: int = 256
  bottleneck: bool = False

  def setup(self):
    self.encoder = Encoder(self.width, layer_norm=False, hidden_layers=0)
    if self.bottleneck:
      self.stats = nn.Dense(2 * self.width)
    self.hidden = [nn.Dense(self.width), nn.Dense(self.width)]
    self.logit = nn.Dense(1)

  def encode(self, x: jax.Array) -> jax.Array:  # [..., F] -> [..., width]
    return self.encoder(x)

  def posterior(self, h: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The bottleneck's q(z | x) from the encoding h [..., width]: mean and scale, each
    [..., width]."""
    mean, raw = jnp.split(self.stats(h), 2, axis=-1)
    return mean, jax.nn.softplus(raw) + 1e-4

  def decode(self, h: jax.Array) -> jax.Array:  # [..., width] -> [...]
    for layer in self.hidden:
      h = nn.elu(layer(h))
    return self.logit(h)[..., 0]

  def __call__(self, x: jax.Array) -> jax.Array:
    h = self.encode(x)
    return self.decode(self.posterior(h)[0] if self.bottleneck else h)


class DiscriminatorState(NamedTuple):
  params: Any
  opt_state: Any
  normalizer: normalizer.NormalizerState  # of one frame [D]
  steps: jax.Array  # int32 [], gradient steps taken
  log_beta: jax.Array  # [] the bottleneck's multiplier, log (0 and unused without one)
  beta_opt_state: Any


def make_model(config: DiscriminatorConfig) -> Discriminator:
  return Discriminator(config.width, config.kl_bound is not None)


def _optimizer(config: DiscriminatorConfig) -> optax.GradientTransformation:
  return optax.adam(config.learning_rate)


def init(config: DiscriminatorConfig, observation_size: int,
         key: jax.Array) -> DiscriminatorState:
  params = make_model(config).init(key, jnp.zeros((1, config.frames * observation_size)))
  log_beta = jnp.zeros(())
  return DiscriminatorState(params, _optimizer(config).init(params),
                            normalizer.init(observation_size), jnp.zeros((), jnp.int32),
                            log_beta, _optimizer(config).init(log_beta))


def inputs(config: DiscriminatorConfig, norm: normalizer.NormalizerState,
           observation: jax.Array) -> jax.Array:
  """The discriminator's standardised inputs of each transition of sequences observation
  [..., T+1, D] raw: [..., T, frames * D] (x_{t+1}, or x_t and x_{t+1} concatenated)."""
  x = normalizer.normalize(norm, observation)
  return x[..., 1:, :] if config.frames == 1 else jnp.concatenate([x[..., :-1, :],
                                                                  x[..., 1:, :]], axis=-1)


def gradient_norms(model: Discriminator, params, z: jax.Array) -> jax.Array:
  """||d decoder / d z||_2 at each encoding z [N, width]: [N]."""
  grads = jax.vmap(jax.grad(lambda h: model.apply(params, h, method=Discriminator.decode)))(z)
  return jnp.sqrt(jnp.sum(jnp.square(grads), axis=-1) + 1e-12)


def kl_to_standard_normal(mean: jax.Array, scale: jax.Array) -> jax.Array:
  """KL(N(mean, scale^2) || N(0, I)) of diagonal Gaussians [..., W]: [...]."""
  return 0.5 * jnp.sum(jnp.square(mean) + jnp.square(scale) - 1.0 - 2.0 * jnp.log(scale),
                       axis=-1)


def loss(config: DiscriminatorConfig, params, expert: jax.Array, imitator: jax.Array,
         imitator_valid: jax.Array, key: jax.Array,
         log_beta: jax.Array | None = None) -> tuple[jax.Array, dict]:
  """The negated objective (module docstring), and with a bottleneck the multiplier's own
  loss -beta * (KL - epsilon) (KL held fixed in it, beta in the other). expert [N, F] and
  imitator [N, F] standardised inputs; imitator_valid [N]: the imitator inputs that count (a
  transition whose successor is stored); each expert input is interpolated with the imitator
  input in the same row; log_beta: the multiplier (a bottleneck's; 0 where None)."""
  model = make_model(config)
  weights = imitator_valid.astype(jnp.float32)
  count = jnp.maximum(jnp.sum(weights), 1.0)
  penalty_key, sample_key = jax.random.split(key)
  h_expert = model.apply(params, expert, method=Discriminator.encode)
  h_imitator = model.apply(params, imitator, method=Discriminator.encode)
  if model.bottleneck:  # samples of q(z | x) for the decoder, and the KL of both sides
    (m_e, s_e), (m_i, s_i) = (model.apply(params, h, method=Discriminator.posterior)
                              for h in (h_expert, h_imitator))
    e_key, i_key = jax.random.split(sample_key)
    h_expert = m_e + s_e * jax.random.normal(e_key, m_e.shape)
    h_imitator = m_i + s_i * jax.random.normal(i_key, m_i.shape)
    kl = (jnp.sum(kl_to_standard_normal(m_e, s_e))
          + jnp.sum(weights * kl_to_standard_normal(m_i, s_i))) / (
              expert.shape[0] + jnp.sum(weights))  # over both sides' inputs that count
  logit_expert = model.apply(params, h_expert, method=Discriminator.decode)
  logit_imitator = model.apply(params, h_imitator, method=Discriminator.decode)
  log_expert = jnp.mean(jax.nn.log_sigmoid(logit_expert))
  log_imitator = jnp.sum(weights * jax.nn.log_sigmoid(-logit_imitator)) / count
  u = jax.random.uniform(penalty_key, (expert.shape[0], 1))
  z = jax.lax.stop_gradient(u * h_expert + (1 - u) * h_imitator)
  norms = gradient_norms(model, params, z)
  if not config.gradient_penalty:  # (a metric only: no second-order pass, no 0 x NaN)
    norms = jax.lax.stop_gradient(norms)
  penalty = jnp.sum(weights * norms) / count / config.width
  objective = log_expert + log_imitator
  if config.gradient_penalty:
    objective = objective - config.gradient_penalty * penalty
  metrics = {"expert_log_prob": log_expert, "imitator_log_prob": log_imitator,
             "gradient_norm": penalty * config.width,
             "expert_accuracy": jnp.mean(logit_expert > 0),
             "imitator_accuracy": jnp.sum(weights * (logit_imitator < 0)) / count}
  if not model.bottleneck:
    return -objective, metrics
  beta = jnp.exp(jnp.zeros(()) if log_beta is None else log_beta)
  excess = kl - config.kl_bound
  objective = objective - jax.lax.stop_gradient(beta) * excess
  beta_loss = -beta * jax.lax.stop_gradient(excess)
  metrics.update(kl=kl, beta=beta)
  return -objective + beta_loss, metrics


def update(config: DiscriminatorConfig, state: DiscriminatorState, expert: jax.Array,
           imitator: jax.Array, imitator_valid: jax.Array,
           key: jax.Array) -> tuple[DiscriminatorState, dict]:
  """One step: fold the raw frames of both sides into the standardisation, then one Adam step
  on `loss`. expert and imitator [N, frames, D] raw frames; imitator_valid [N]."""
  frames = jnp.concatenate([expert, imitator], axis=0)  # [2N, frames, D]
  mask = jnp.concatenate([jnp.ones(expert.shape[:1], bool), imitator_valid])
  norm = normalizer.update(state.normalizer, frames, config.normalizer_decay,
                           mask=jnp.broadcast_to(mask[:, None], frames.shape[:2]))
  flat = lambda x: normalizer.normalize(norm, x).reshape(x.shape[0], -1)
  (grads, beta_grad), metrics = jax.grad(
      lambda p, b: loss(config, p, flat(expert), flat(imitator), imitator_valid, key, b),
      argnums=(0, 1), has_aux=True)(state.params, state.log_beta)
  updates, opt_state = _optimizer(config).update(grads, state.opt_state, state.params)
  params = optax.apply_updates(state.params, updates)
  beta_update, beta_opt_state = _optimizer(config).update(beta_grad, state.beta_opt_state)
  log_beta = optax.apply_updates(state.log_beta, beta_update)
  return DiscriminatorState(params, opt_state, norm, state.steps + 1, log_beta,
                            beta_opt_state), metrics


def logits(config: DiscriminatorConfig, state: DiscriminatorState,
           observation: jax.Array) -> jax.Array:
  """Log odds of each transition of observation [..., T+1, D] raw: [..., T]."""
  return make_model(config).apply(state.params, inputs(config, state.normalizer, observation))


def reward(logit: jax.Array) -> jax.Array:
  """log(1 + D), D = sigmoid(logit): the paper's GAIfO reward, in [0, log 2]."""
  return jax.nn.softplus(jax.nn.log_sigmoid(logit))
