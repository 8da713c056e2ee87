"""Observation standardisation by exponential moving averages, as pure functions.

`update` keeps bias-corrected EMAs of the batch mean and of the batch second moment, stored as
`mean` and `var` (= EMA second moment - mean**2). With a constant `decay` d, after t updates

  mean_t = sum_i w_i * batch_mean_i,   E[x^2]_t = sum_i w_i * batch_second_moment_i,
  w_i = (1 - d) * d**(t - i) / (1 - d**t)              (the weights sum to 1)

i.e. Adam-style bias correction: the first update sets the statistics from the batch exactly
and early batches are not over-weighted. Each update is the convex combination with rate
a_t = (1 - d) / (1 - d**t); the variance is combined as
(1 - a) var + a batch_var + a (1 - a) (batch_mean - mean)**2, which equals the EMA second
moment minus the squared mean without its cancellation. Batch statistics are plain `jnp`
reductions over all leading axes, so they are global when the batch is sharded over devices.

Periodic features (`period` [D], 0 where a feature is not periodic; e.g. 2 pi for an unbounded
hinge angle that an observation gives raw) are wrapped into [-period/2, period/2) before
anything else, by `update` and `normalize` alike: states that differ by whole turns then look
the same to the agent.

Angle features (`angles` [K, D], row j one-hot at the j-th unbounded angle, or all zeros where a
member does not encode it): each encoded angle reaches the agent as its cos and sin instead of
its raw value, so that the same pose is one input whatever the turns and there is no jump at
+-pi either. `features` maps raw observations [..., D] to [..., D + 2K]: the raw features with the
encoded ones zeroed, then the K cosines, then the K sines (zeros where a row is zero); `update`
and `normalize` take raw observations and keep the statistics of those features ([D + 2K]).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class NormalizerState(NamedTuple):
  mean: jax.Array   # [F] (F = D, or D + 2K with angle features)
  var: jax.Array    # [F], population variance (ddof=0)
  count: jax.Array  # int32 []: number of updates so far
  period: jax.Array | None = None  # [D]: each feature's period, 0 if none; None: no periodic one
  angles: jax.Array | None = None  # [K, D]: the angles seen as cos and sin (module docstring)


def init(size: int, dtype=jnp.float32, period=None, angles=None) -> NormalizerState:
  """Statistics of observations of `size` features before any update: mean 0, var 1 (normalize
  is identity-ish); `period` [size] (0 where a feature is not periodic) or None; `angles`
  [K, size] (rows one-hot or zero: module docstring) or None."""
  if isinstance(size, bool) or not isinstance(size, int) or size < 1:
    raise ValueError(f"size must be a positive integer, got {size!r}")
  if period is not None:
    period = np.asarray(period, np.float64)  # a constant of the run, checked before tracing
    if period.shape != (size,) or np.any(period < 0):
      raise ValueError(f"period must be [{size}] values >= 0, got {period}")
    period = jnp.asarray(period, dtype)
  width = size
  if angles is not None:
    check_angles(angles, size)
    width = size + 2 * np.shape(angles)[0]
    angles = jnp.asarray(angles, dtype)
  return NormalizerState(jnp.zeros((width,), dtype), jnp.ones((width,), dtype),
                         jnp.zeros((), jnp.int32), period, angles)


def check_angles(angles, size: int) -> None:
  """ValueError unless `angles` is [K >= 1, size] rows, each one-hot or zero, no feature in two
  rows (the normaliser's `angles`)."""
  angles = np.asarray(angles, np.float64)
  if (angles.ndim != 2 or angles.shape[1] != size or not angles.shape[0]
      or not np.all((angles == 0) | (angles == 1)) or np.any(angles.sum(1) > 1)
      or np.any(angles.sum(0) > 1)):
    raise ValueError(f"angles must be [K >= 1, {size}] rows, each one-hot or zero, no feature "
                     f"in two rows; got {angles.tolist()}")


def wrap(state: NormalizerState, x: jax.Array) -> jax.Array:
  """x [..., D] with each periodic feature wrapped into [-period/2, period/2)."""
  if state.period is None:
    return x
  p = state.period
  periodic = p > 0
  safe = jnp.where(periodic, p, 1.0)
  wrapped = x - safe * jnp.floor((x + safe / 2) / safe)
  return jnp.where(periodic, wrapped, x)


def angle_rows(period) -> np.ndarray:
  """`angles` [K, D] encoding every feature with a period (> 0) in `period` [D]: K = their
  number, one one-hot row each, in order."""
  period = np.asarray(period)
  return np.eye(period.shape[-1], dtype=np.float32)[np.flatnonzero(period > 0)]


def input_size(state: NormalizerState) -> int:
  """D, the raw observations' size (the statistics' is D + 2K with angle features)."""
  return state.mean.shape[-1] - (0 if state.angles is None else 2 * state.angles.shape[-2])


def features(state: NormalizerState, x: jax.Array) -> jax.Array:
  """Raw observations x [..., D] (periodic features wrapped) as the agent's features
  [..., D + 2K] (module docstring); x itself without `angles`."""
  x = wrap(state, x)
  if state.angles is None:
    return x
  rows = state.angles                                        # [K, D]
  theta = jnp.sum(jnp.where(rows > 0, x[..., None, :], 0), axis=-1)  # [..., K] (exact)
  on = jnp.sum(rows, axis=-1)                                # [K]
  raw = x * (1 - jnp.sum(rows, axis=-2))                     # [..., D]
  return jnp.concatenate([raw, on * jnp.cos(theta), on * jnp.sin(theta)], axis=-1)


def _check(state: NormalizerState, x: jax.Array, what: str) -> None:
  size = input_size(state)
  if jnp.ndim(x) < 1 or jnp.shape(x)[-1] != size:
    raise ValueError(f"{what} has shape {jnp.shape(x)}; expected (..., {size})")


def update(state: NormalizerState, batch: jax.Array, decay: float = 0.99,
           mask: jax.Array | None = None) -> NormalizerState:
  """Folds the statistics of `batch` [..., D] (all leading axes pooled) into the EMAs.

  `mask` [...] (the leading axes of `batch`): only the rows where it is true count; a batch
  with no such row leaves the state as it is.
  """
  _check(state, batch, "batch")
  if isinstance(decay, (int, float)) and not 0.0 <= decay < 1.0:
    raise ValueError(f"decay must be in [0, 1), got {decay}")
  batch = features(state, jnp.asarray(batch, state.mean.dtype))
  axes = tuple(range(batch.ndim - 1))
  if mask is None:
    batch_mean = jnp.mean(batch, axis=axes)                                # [F]
    batch_var = jnp.mean(jnp.square(batch - batch_mean), axis=axes)        # [F]
  else:
    if jnp.shape(mask) != batch.shape[:-1]:
      raise ValueError(f"mask has shape {jnp.shape(mask)}; expected {batch.shape[:-1]}")
    weights = jnp.asarray(mask, batch.dtype)[..., None]                    # [..., 1]
    rows = jnp.sum(weights)
    share = weights / jnp.maximum(rows, 1)
    batch_mean = jnp.sum(share * batch, axis=axes)                         # [F]
    batch_var = jnp.sum(share * jnp.square(batch - batch_mean), axis=axes)  # [F]
  count = state.count + 1
  decay = jnp.asarray(decay, state.mean.dtype)
  rate = (1 - decay) / (1 - decay ** count.astype(state.mean.dtype))       # 1 at the first update
  delta = batch_mean - state.mean
  mean = state.mean + rate * delta
  var = (1 - rate) * state.var + rate * batch_var + rate * (1 - rate) * jnp.square(delta)
  updated = NormalizerState(mean, jnp.maximum(var, 0), count, state.period, state.angles)
  if mask is None:
    return updated
  return jax.tree.map(lambda new, old: jnp.where(rows > 0, new, old), updated, state)


def normalize(state: NormalizerState, x: jax.Array, clip: float | None = None,
              eps: float = 1e-6) -> jax.Array:
  """(features(x) - mean) / sqrt(var + eps) for raw observations x [..., D] (periodic features
  wrapped, angle features made), optionally clipped to [-clip, clip]."""
  _check(state, x, "x")
  out = (features(state, x) - state.mean) / jnp.sqrt(state.var + eps)
  return out if clip is None else jnp.clip(out, -clip, clip)
