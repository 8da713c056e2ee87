"""FORM's effect model p(x_{t+delta} | x_t) and its training objective (paper, appendix
"FORM effect model training"; ../shared/DESIGN.md).

Network: observations enter standardised, sigma(x) = (x - mean) / sqrt(var + eps), with the
model's own EMA statistics. The shared encoder (linear 256, LayerNorm, tanh, one hidden layer
of 256 with ELU) encodes sigma(x_t); a one-hot of the offset delta in [1, max_offset] is
concatenated; one hidden layer of 256 (ELU); a linear head gives a mixture of K diagonal
Gaussians over sigma(x_{t+delta}) (scale softplus + 1e-4).

Objective, maximised on batches of sequences x_0..x_T with episode-continuation flags:
  (1/max_offset) sum_delta mean_t log p(sigma(x_{t+delta}) | sigma(x_t), delta)
  + beta_ar mean_t log p(sigma(x_{t+1}) | x~_t, 1),   x~_t ~ p(. | sigma(x_{t-1}), 1)
  - (l2 / 2) sum of squared kernel weights,
where the means run over the pairs that lie inside one episode (`offset_masks`) and x~_t is a
sample of the model's own prediction (gradients do not flow through the sample). Adam.

Densities for rewards are in raw observation space: log p(x' | x) = log p(sigma(x') | sigma(x))
- 0.5 sum_d log(var_d + eps) (change of variables), so two models with different
standardisations give comparable numbers.

Turn invariance (`EffectModelConfig.period`, e.g. 2 pi for a raw unbounded hinge angle such as
reacher's shoulder; () for none): every pair (x_t, x_{t+delta}) is moved by the multiple of the
period that brings x_t's periodic features into [-period/2, period/2), x_{t+delta} by the same
multiple. A full turn then changes nothing the model sees, and the move is a translation, so
log p is unchanged (Jacobian 1). The standardisation is taken over the observations so wrapped.

Angle increments (`EffectModelConfig.angle_increments`, turn-invariant models only; not in the
paper): the model predicts each periodic feature's change x_{t+delta} - x_t instead of its
moved value, a residual parameterisation of those features (the mixture's mean no longer has
to reproduce x_t itself; the moved value is continuous in the moved input either way). The
target is moved by x_t (a translation given x_t: log p unchanged, Jacobian 1).

Scale cap (`EffectModelConfig.max_scale`, not in the paper): every component's scale is held
below max_scale standardised units by a soft cap (`distributions.scale_from_raw`). A reacher_hard
demonstrator trained 352k steps explained all transitions off the expert's with one broad
component (~3.3 sd) and so paid them all about the same: FORM's reward had no slope there and
FORM failed (benchmarks/NOTES.md, session 44). Under a cap no component can act as such a floor.
But capped models pay the expert's own fast reaching 100+ nats, and over six reacher_hard draws
with a 1 sd cap FORM fell (mean 355 against 653 for six uncapped draws of the same
demonstrations and seeds; three capped imitators stopped far from the target, session 46):
not a default anywhere.

Angle inputs (`EffectModelConfig.angle_inputs`, with `angle_increments` only; not in the paper):
the encoder sees each periodic feature of x_t as the cosine and sine of its raw angle
theta = 2 pi x / period instead of its standardised wrapped value, which jumps by a turn at
+-period/2 (`encoder_inputs`). The input is then continuous across that seam as the increments
target is, and blind to full turns by construction; the mixture and its target are unchanged.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from mjx_form.rl import normalizer
from mjx_form.rl.distributions import GaussianMixture, scale_from_raw
from mjx_form.rl.networks import Encoder

NORMALIZER_EPS = 1e-6  # = normalizer.normalize's default; the change of variables uses it too


@dataclasses.dataclass(frozen=True)
class EffectModelConfig:
  """The paper's settings; beta_ar and l2 are tuned per task (mjx_form/imitation/settings.py)."""

  width: int = 256
  num_components: int = 4
  max_offset: int = 5  # overshooting: offsets 1..max_offset are predicted during training
  beta_ar: float = 0.1  # weight of the autoregressive (model-sample input) term
  l2: float = 0.1  # L2 weight decay on the kernels
  learning_rate: float = 1e-4
  normalizer_decay: float = 0.99  # EMA decay of the standardisation, per batch
  min_scale: float = 1e-4
  # [D] period of each observation feature (0: not periodic) for a turn-invariant model; ()
  # for none (the paper's). See the module docstring.
  period: tuple[float, ...] = ()
  # A turn-invariant model predicts its periodic features' changes, not their values (module
  # docstring); off: the values (as before this setting existed).
  angle_increments: bool = False
  # The encoder sees the periodic features as cos and sin of their raw angles (module
  # docstring); needs angle_increments. Off: their standardised values (as before it existed).
  angle_inputs: bool = False
  # Soft cap on every component's scale, in standardised units (module docstring); None: none
  # (the paper's, and files before the setting existed).
  max_scale: float | None = None

  def __post_init__(self):  # from a file's JSON list, too
    object.__setattr__(self, "period", tuple(float(p) for p in self.period))
    if isinstance(self.max_scale, int) and not isinstance(self.max_scale, bool):
      object.__setattr__(self, "max_scale", float(self.max_scale))  # one JSON text for 1 and 1.0

  def to_dict(self) -> dict:
    """The settings as files and records keep them (JSON's shapes: `period` a list, and none
    where there is no period, as before turn invariance existed; `angle_increments`,
    `angle_inputs` and `max_scale` only where set, as before they existed)."""
    out = dataclasses.asdict(self)
    if self.period:
      out["period"] = list(self.period)
    else:
      del out["period"]
    for name in ("angle_increments", "angle_inputs", "max_scale"):
      if not out[name]:
        del out[name]
    return out

  def check(self) -> None:
    for name in ("width", "num_components", "max_offset"):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"effect model {name} must be a positive integer, got {value!r}")
    for name in ("beta_ar", "l2"):
      if getattr(self, name) < 0:
        raise ValueError(f"effect model {name} must be >= 0, got {getattr(self, name)}")
    if self.learning_rate <= 0:
      raise ValueError(f"effect model learning_rate must be positive, got {self.learning_rate}")
    if not 0.0 <= self.normalizer_decay < 1.0:
      raise ValueError(f"effect model normalizer_decay must be in [0, 1), "
                       f"got {self.normalizer_decay}")
    if any(not p >= 0 or p == float("inf") for p in self.period) or (
        self.period and not any(self.period)):
      raise ValueError(f"effect model period must be finite values >= 0, one at least > 0 "
                       f"(or none), got {self.period}")
    for name in ("angle_increments", "angle_inputs"):
      if not isinstance(getattr(self, name), bool):
        raise ValueError(f"effect model {name} must be true or false, got "
                         f"{getattr(self, name)!r}")
    if self.angle_increments and not self.period:
      raise ValueError("effect model angle_increments needs a turn-invariant model (a period: "
                       "--turn_invariant)")
    if self.angle_inputs and not self.angle_increments:
      raise ValueError("effect model angle_inputs needs angle increments (--angle_increments, "
                       "on a turn-invariant model)")
    if self.max_scale is not None and (
        isinstance(self.max_scale, bool) or not isinstance(self.max_scale, (int, float))
        or not self.min_scale < self.max_scale < float("inf")):
      raise ValueError(f"effect model max_scale must be a number above min_scale "
                       f"({self.min_scale:g}) and finite, or none; got {self.max_scale!r}")


class EffectModel(nn.Module):
  """(standardised x_t [..., D], offset, turns) -> GaussianMixture over standardised
  x_{t+offset} (moved by `shifts`: with `angle_increments`, over the periodic features'
  changes). The turns (`turns`, of the model's own standardisation) are needed only with
  `angle_inputs` (`encoder_inputs`)."""

  observation_size: int
  width: int = 256
  num_components: int = 4
  max_offset: int = 5
  min_scale: float = 1e-4
  period: tuple[float, ...] = ()  # EffectModelConfig.period
  angle_increments: bool = False  # EffectModelConfig.angle_increments
  angle_inputs: bool = False  # EffectModelConfig.angle_inputs
  max_scale: float | None = None  # EffectModelConfig.max_scale

  def setup(self):
    self.encoder = Encoder(self.width)
    self.hidden = nn.Dense(self.width)
    self.head = nn.Dense(self.num_components * (1 + 2 * self.observation_size))

  def encode(self, x: jax.Array, t: Turns | None = None) -> jax.Array:
    """x [..., D] standardised (moved by `shifts`' first value), t: the turns of the model's
    standardisation (None: none; needed with `angle_inputs`) -> [..., width]."""
    return self.encoder(encoder_inputs(self, t, x))

  def predict(self, h: jax.Array, offset) -> GaussianMixture:
    """h [..., width]; offset: an int, or an int array that broadcasts against h's leading
    axes (e.g. [O, 1, 1] for h [O, B, T, width]: offset o's prediction in row o)."""
    onehot = jax.nn.one_hot(offset - 1, self.max_offset, dtype=h.dtype)
    onehot = jnp.broadcast_to(onehot, h.shape[:-1] + (self.max_offset,))
    out = self.head(nn.elu(self.hidden(jnp.concatenate([h, onehot], axis=-1))))
    k, d = self.num_components, self.observation_size
    logits = out[..., :k]
    mean, raw_scale = jnp.split(out[..., k:].reshape(out.shape[:-1] + (k, 2 * d)), 2, axis=-1)
    return GaussianMixture(logits, mean,
                           scale_from_raw(raw_scale, self.min_scale, self.max_scale))

  def __call__(self, x: jax.Array, offset: int = 1, t: Turns | None = None) -> GaussianMixture:
    return self.predict(self.encode(x, t), offset)


def make_model(config: EffectModelConfig, observation_size: int) -> EffectModel:
  if config.period and len(config.period) != observation_size:
    raise ValueError(f"effect model period has {len(config.period)} entries, the observations "
                     f"have {observation_size}")
  return EffectModel(observation_size, config.width, config.num_components, config.max_offset,
                     config.min_scale, config.period, config.angle_increments,
                     config.angle_inputs, config.max_scale)


class EffectModelState(NamedTuple):
  params: Any
  opt_state: Any
  normalizer: normalizer.NormalizerState
  steps: jax.Array  # int32 [], gradient steps taken


def _optimizer(config: EffectModelConfig) -> optax.GradientTransformation:
  return optax.adam(config.learning_rate)


def init_params(model: EffectModel, key: jax.Array):
  """Fresh parameters of `model` (the encoder's first layer takes `encoder_inputs`' size)."""
  d = model.observation_size
  return model.init(key, jnp.zeros((1, d)), 1, turns(model, normalizer.init(d)))


def init(model: EffectModel, config: EffectModelConfig, key: jax.Array) -> EffectModelState:
  params = init_params(model, key)
  return EffectModelState(params, _optimizer(config).init(params),
                          normalizer.init(model.observation_size), jnp.zeros((), jnp.int32))


# --- data alignment -----------------------------------------------------------------------

def offset_masks(discount: jax.Array, max_offset: int) -> jax.Array:
  """Which (x_t, x_{t+delta}) pairs of a batch of sequences lie inside one episode.

  discount [B, T]: > 0 where x_{t+1} continues x_t's episode (0 at a transition into a new
  episode or a physics error, as the training loop stores it). Returns [max_offset, B, T]
  floats: mask[delta - 1, b, t] = 1 iff t + delta <= T and transitions t .. t+delta-1 all
  continue the episode.
  """
  cont = (discount > 0).astype(jnp.float32)
  masks, mask = [], cont
  for delta in range(1, max_offset + 1):
    if delta > 1:  # extend by transition t+delta-1; pairs running past x_T are invalid
      shifted = jnp.pad(cont[:, delta - 1:], ((0, 0), (0, delta - 1)))
      mask = mask * shifted
    masks.append(mask)
  return jnp.stack(masks)


def log_jacobian(norm: normalizer.NormalizerState) -> jax.Array:
  """log |d sigma(x) / dx| = -0.5 sum_d log(var_d + eps): raw log p = standardised log p + it."""
  return -0.5 * jnp.sum(jnp.log(norm.var + NORMALIZER_EPS))


def standardise(norm: normalizer.NormalizerState, x: jax.Array) -> jax.Array:
  return normalizer.normalize(norm, x, eps=NORMALIZER_EPS)


# --- turn invariance ----------------------------------------------------------------------

class Turns(NamedTuple):
  """A turn-invariant model's periods in standardised coordinates."""

  period: jax.Array  # [D] period_d / sqrt(var_d + eps); 0 where not periodic
  low: jax.Array  # [D] the standardised value of -period_d / 2


def turns(model: EffectModel, norm: normalizer.NormalizerState) -> Turns | None:
  """`model`'s periods under the standardisation `norm`; None for a model without any."""
  if not model.period:
    return None
  period = jnp.asarray(model.period, norm.mean.dtype)
  std = jnp.sqrt(norm.var + NORMALIZER_EPS)
  return Turns(period / std, (-period / 2 - norm.mean) / std)


def turn_shift(t: Turns | None, anchor: jax.Array) -> jax.Array:
  """The multiple of the (standardised) period that brings each periodic feature of the
  standardised `anchor` [..., D] into the standardised [-period/2, period/2): subtracting it
  from x_t and from x_{t+delta} makes a pair turn-invariant. 0 without turns."""
  if t is None:
    return jnp.zeros_like(anchor)
  periodic = t.period > 0
  safe = jnp.where(periodic, t.period, 1.0)
  return jnp.where(periodic, safe * jnp.floor((anchor - t.low) / safe), 0.0)


def shifts(model: EffectModel, t: Turns | None, anchor: jax.Array
           ) -> tuple[jax.Array, jax.Array]:
  """(what to subtract from x_t, what to subtract from x_{t+delta}) for pairs anchored at the
  standardised x_t `anchor` [..., D]: both x_t's `turn_shift`, or with `angle_increments` the
  target's periodic features x_t itself (the model predicts their change). (With
  `angle_inputs` the encoder sees the periodic features' cos and sin, which no whole turn
  changes: the first then matters for the other features only, where it is 0.)"""
  move = turn_shift(t, anchor)
  if t is None or not model.angle_increments:
    return move, move
  return move, jnp.where(t.period > 0, anchor, move)


def encoder_inputs(model: EffectModel, t: Turns | None, x: jax.Array) -> jax.Array:
  """What the encoder sees of the standardised x [..., D]: x itself, or with `angle_inputs`
  [..., D + P] (P periodic features): x with each periodic feature replaced by cos theta, then
  the P sin theta in feature order, theta = 2 pi x_raw / period its raw angle. The raw value is
  x * sqrt(var + eps) + mean under the standardisation of the turns `t` (`turns`), so
  theta = 2 pi (x - t.low) / t.period - pi (cos and sin: whatever whole turns x was moved by)."""
  if not model.angle_inputs:
    return x
  if t is None:
    raise ValueError("an angle_inputs effect model needs the turns of its standardisation "
                     "(`turns`) to encode")
  periodic = np.flatnonzero(np.asarray(model.period) > 0)  # [P]
  theta = 2 * np.pi * (x[..., periodic] - t.low[periodic]) / t.period[periodic] - np.pi
  return jnp.concatenate([x.at[..., periodic].set(jnp.cos(theta)), jnp.sin(theta)], axis=-1)


def wrap_raw(model: EffectModel, x: jax.Array) -> jax.Array:
  """Raw observations [..., D] with the periodic features wrapped into [-period/2, period/2)
  (what a turn-invariant model's standardisation is taken over); x itself without periods."""
  if not model.period:
    return x
  return normalizer.wrap(normalizer.init(model.observation_size,
                                         period=np.asarray(model.period)), x)

# --- densities ----------------------------------------------------------------------------

def offset_mixtures(model: EffectModel, params, x: jax.Array, t: Turns | None = None
                    ) -> tuple[GaussianMixture, jax.Array]:
  """Every offset's mixture over x_{t+delta} from x_t, x [B, T+1, D] (standardised): mixture
  [max_offset, B, T, K, D] (row delta - 1: offset delta) and what to subtract from its targets
  [B, T, D] (`shifts` of x_t under turns `t`; None: not moved)."""
  inputs, targets = shifts(model, t, x[:, :-1])  # [B, T, D] each
  h = model.apply(params, x[:, :-1] - inputs, t, method=model.encode)  # [B, T, W]
  # Every offset in one pass (one matmul per layer, not one per offset): [O, B, T, ...].
  n = model.max_offset
  offsets = jnp.arange(1, n + 1).reshape(n, 1, 1)
  mixture = model.apply(params, jnp.broadcast_to(h, (n, *h.shape)), offsets,
                        method=model.predict)  # [O, B, T, K, D]
  return mixture, targets


def offset_log_probs(model: EffectModel, params, x: jax.Array,
                     t: Turns | None = None) -> jax.Array:
  """Standardised-space log p(x_{t+delta} | x_t) for every offset: x [B, T+1, D] (standardised)
  -> [max_offset, B, T] (pairs past x_T give values to be masked out); each pair moved by
  x_t's `shifts` under turns `t` (`turns`; None: not moved)."""
  mixture, targets = offset_mixtures(model, params, x, t)
  return _offset_log_probs(mixture, targets, x)


def _offset_log_probs(mixture: GaussianMixture, targets: jax.Array, x: jax.Array) -> jax.Array:
  """`offset_mixtures`' log p of the observations x [B, T+1, D] they predict: [O, B, T]."""
  n = mixture.logits.shape[0]
  later = jnp.stack([jnp.pad(x[:, delta:], ((0, 0), (0, delta - 1), (0, 0)))
                     for delta in range(1, n + 1)])  # [O, B, T, D]: x_{t+delta}
  return mixture.log_prob(later - targets)


def transition_mixture(model: EffectModel, params, norm: normalizer.NormalizerState,
                       x: jax.Array, x_next: jax.Array) -> tuple[GaussianMixture, jax.Array]:
  """The offset-1 mixture over the standardised (and `shifts`-moved) next observation, and
  x_next in that space: x, x_next [..., D] raw -> (mixture [..., K, D], target [..., D])."""
  x, x_next = standardise(norm, x), standardise(norm, x_next)
  t = turns(model, norm)
  inputs, targets = shifts(model, t, x)
  return model.apply(params, x - inputs, 1, t), x_next - targets


def transition_log_prob(model: EffectModel, params, norm: normalizer.NormalizerState,
                        x: jax.Array, x_next: jax.Array) -> jax.Array:
  """Raw-space log p(x_next | x) at offset 1 (FORM's reward term): x, x_next [..., D] -> [...]."""
  mixture, target = transition_mixture(model, params, norm, x, x_next)
  return mixture.log_prob(target) + log_jacobian(norm)


def _masked_mean(values: jax.Array, mask: jax.Array) -> jax.Array:
  return jnp.sum(values * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def kernel_l2(params) -> jax.Array:
  """Sum of squared kernel (weight matrix) entries; biases and LayerNorm are not decayed."""
  leaves = jax.tree_util.tree_leaves_with_path(params)
  return sum(jnp.sum(jnp.square(leaf)) for path, leaf in leaves
             if getattr(path[-1], "key", None) == "kernel")


def loss(model: EffectModel, config: EffectModelConfig, params, x: jax.Array,
         discount: jax.Array, key: jax.Array,
         t: Turns | None = None) -> tuple[jax.Array, dict]:
  """The negated objective (module docstring) on standardised sequences x [B, T+1, D]; pairs
  moved by their x_t's `shifts` under turns `t` (None: not moved)."""
  masks = offset_masks(discount, config.max_offset)  # [max_offset, B, T]
  mixtures, targets = offset_mixtures(model, params, x, t)  # [max_offset, B, T, K, D], [B, T, D]
  log_probs = _offset_log_probs(mixtures, targets, x)  # [max_offset, B, T]
  per_offset = jax.vmap(_masked_mean)(log_probs, masks)  # [max_offset]
  # Autoregressive term: x~_{t+1} ~ p(. | x_t) for t = 0..T-2, then log p(x_{t+2} | x~_{t+1}).
  # (With turns, x~_{t+1} is drawn in x_t's moved frame, then put back, then x~_{t+1} and
  # x_{t+2} are moved by x~_{t+1}'s own shifts; with angle inputs the encoder then sees the cos
  # and sin of x~_{t+1}'s own angles.) p(. | x_t) is the offset-1 row of the mixtures above.
  first = jax.tree.map(lambda a: a[0, :, :-1], mixtures)  # [B, T-1, K, D]
  sampled = jax.lax.stop_gradient(first.sample(key)) + targets[:, :-1]  # [B, T-1, D]
  inputs, targets = shifts(model, t, sampled)
  ar_log_prob = model.apply(params, sampled - inputs, 1, t).log_prob(
      x[:, 2:] - targets)  # [B, T-1]
  ar_mask = masks[1, :, :-1]  # x_t, x_{t+1}, x_{t+2} in one episode
  ar = _masked_mean(ar_log_prob, ar_mask)
  l2 = kernel_l2(params)
  objective = jnp.mean(per_offset) + config.beta_ar * ar - 0.5 * config.l2 * l2
  metrics = {f"log_prob_offset{d + 1}": per_offset[d] for d in range(config.max_offset)}
  metrics.update(log_prob_autoregressive=ar, kernel_l2=l2)
  return -objective, metrics


def update(model: EffectModel, config: EffectModelConfig, state: EffectModelState,
           observations: jax.Array, discount: jax.Array,
           key: jax.Array) -> tuple[EffectModelState, dict]:
  """One step: fold the batch into the standardisation, then one Adam step on `loss`.

  observations [B, T+1, D] raw; discount [B, T] (see `offset_masks`). Metrics are
  standardised-space log-likelihoods (nats per transition), and `log_prob` the raw-space
  offset-1 log-likelihood of the batch.
  """
  norm = normalizer.update(state.normalizer, wrap_raw(model, observations),
                          config.normalizer_decay)
  x = standardise(norm, observations)
  grads, metrics = jax.grad(lambda p: loss(model, config, p, x, discount, key,
                                           turns(model, norm)), has_aux=True)(state.params)
  updates, opt_state = _optimizer(config).update(grads, state.opt_state, state.params)
  params = optax.apply_updates(state.params, updates)
  metrics["log_prob"] = metrics["log_prob_offset1"] + log_jacobian(norm)
  return EffectModelState(params, opt_state, norm, state.steps + 1), metrics
