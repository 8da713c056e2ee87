"""Offline training of FORM's demonstrator effect model on demonstration observations.

Episodes are split into training and held-out ones (the last `heldout_fraction`, at least
one). Each step samples `batch_size` windows of `window` transitions from random training
episodes and positions (every pair inside a window lies in one episode) and takes one
`effect_model.update`. Every `eval_every` steps the raw-space log-likelihood per offset is
measured on every pair of the held-out episodes; the parameters of the best held-out mean over
offsets are kept. Training stops at `max_steps`, once `max_seconds` have passed, or after
`patience` evaluations in which the held-out mean, averaged over the last `smoothing`
evaluations, has not reached a new best (`evaluations_since_best`): single evaluations scatter
by ~1 nat while the curve still rises by a fraction of that per evaluation. Chunks of
`eval_every` steps run as one compiled scan on the device.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form.imitation import effect_model as em


@dataclasses.dataclass(frozen=True)
class DemonstratorTraining:
  # The paper trains 2M steps. Longer is not better for FORM here: on reacher_hard's shipped
  # demonstrations and seed, 200k steps (627d0d, held-out 29.09 nats at offset 1) gave FORM
  # 822.8 over six seeds, 352k steps (97809d, 30.67 nats, still rising) gave 11.9, every seed
  # failing (NOTES, sessions 43-44). 200k is the length every measured FORM result used.
  max_steps: int = 200_000
  batch_size: int = 64  # windows per step (the learner's 64 unrolls)
  window: int = 100  # transitions per window
  eval_every: int = 2_000
  # Evaluations without a new best of the smoothed held-out curve before stopping. Single
  # evaluations scatter by ~1 nat: patience 15 on them alone stopped a reacher_hard draw at
  # 128k steps while it still rose (26.75 nats at offset 1 against 28.3-29.1 for draws trained
  # to 200k; FORM with it 374.0, with theirs 720-823; NOTES, session 43). The mean of the last 10
  # (over offsets) stopped none of the recorded curves before 200k; past it, one at 228k where
  # offset 1 still rose and the mean over offsets had dipped and recovered (session 44).
  patience: int = 15
  smoothing: int = 10
  heldout_fraction: float = 0.05
  seed: int = 0
  max_seconds: float | None = None  # stop after the evaluation that passes this time budget

  def check(self, episodes: int, steps: int) -> None:
    for name in ("max_steps", "batch_size", "window", "eval_every", "patience", "smoothing"):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"demonstrator training {name} must be a positive integer, "
                         f"got {value!r}")
    if not 0.0 < self.heldout_fraction < 1.0:
      raise ValueError(f"heldout_fraction must be in (0, 1), got {self.heldout_fraction}")
    if episodes < 2:
      raise ValueError(f"training a demonstrator needs at least 2 demonstration episodes (one "
                       f"held out), got {episodes}")
    if self.window > steps:
      raise ValueError(f"window={self.window} is longer than the episodes ({steps} steps)")


def split_episodes(episodes: int, heldout_fraction: float) -> tuple[np.ndarray, np.ndarray]:
  """(training, held-out) episode indices: the last max(1, round(fraction * K)) are held out."""
  heldout = min(max(1, round(heldout_fraction * episodes)), episodes - 1)
  return np.arange(episodes - heldout), np.arange(episodes - heldout, episodes)


def evaluations_since_best(means: list[float], smoothing: int) -> int:
  """How many evaluations ago the running mean of the last `smoothing` held-out means (fewer at
  the start) last reached a new maximum: 0 when the newest one did."""
  best, since = -np.inf, 0
  for i in range(len(means)):
    recent = float(np.mean(means[max(0, i + 1 - smoothing):i + 1]))
    since = 0 if recent > best else since + 1
    best = max(best, recent)
  return since


def heldout_log_likelihood(model: em.EffectModel, params, norm, episodes: jax.Array,
                           chunk: int = 8) -> jax.Array:
  """Raw-space mean log p(x_{t+delta} | x_t) over every pair of `episodes` [H, T+1, D] (no
  episode ends inside): [max_offset]. Episodes are evaluated `chunk` at a time."""
  h, t = episodes.shape[0], episodes.shape[1] - 1
  max_offset = model.max_offset

  def one(episode):  # [T+1, D] -> sums of log-likelihoods per offset [max_offset]
    log_probs = em.offset_log_probs(model, params, em.standardise(norm, episode[None]),
                                    em.turns(model, norm))
    masks = em.offset_masks(jnp.ones((1, t)), max_offset)
    return jnp.sum(log_probs * masks, axis=(1, 2))

  sums = jnp.sum(jax.lax.map(one, episodes, batch_size=chunk), axis=0)
  pairs = h * (t - jnp.arange(max_offset))  # pairs per offset
  return sums / pairs + em.log_jacobian(norm)


def train(observations: np.ndarray, config: em.EffectModelConfig,
          training: DemonstratorTraining = DemonstratorTraining(),
          print_fn: Callable[[str], None] = print) -> tuple[em.EffectModelState, dict]:
  """Trains a demonstrator on observations [K, T+1, D]; returns (the best held-out state, a
  report: steps, best_step, heldout_log_likelihood per offset, curve, seconds, episodes)."""
  config.check()
  k, t1, d = observations.shape
  training.check(k, t1 - 1)
  train_idx, heldout_idx = split_episodes(k, training.heldout_fraction)
  train_obs = jnp.asarray(observations[train_idx])
  heldout_obs = jnp.asarray(observations[heldout_idx])
  model = em.make_model(config, d)
  b, w = training.batch_size, training.window
  ones = jnp.ones((b, w))

  def step(state, key):
    episode_key, start_key, update_key = jax.random.split(key, 3)
    episode = jax.random.randint(episode_key, (b,), 0, train_obs.shape[0])
    start = jax.random.randint(start_key, (b,), 0, t1 - w)
    windows = jax.vmap(lambda e, s: jax.lax.dynamic_slice(train_obs[e], (s, 0), (w + 1, d)))(
        episode, start)  # [B, W+1, D]
    state, metrics = em.update(model, config, state, windows, ones, update_key)
    return state, metrics

  @jax.jit
  def chunk(state, key):
    state, metrics = jax.lax.scan(step, state, jax.random.split(key, training.eval_every))
    return state, jax.tree.map(jnp.mean, metrics)

  evaluate = jax.jit(lambda params, norm: heldout_log_likelihood(model, params, norm,
                                                                 heldout_obs))
  key = jax.random.PRNGKey(training.seed)
  key, init_key = jax.random.split(key)
  state = em.init(model, config, init_key)
  best_state, best, best_step, curve, means = state, -np.inf, 0, [], []
  start = time.perf_counter()
  steps, stopped_by = 0, "max_steps"
  print_fn(f"demonstrator: {len(train_idx)} training and {len(heldout_idx)} held-out episodes, "
           f"batches of {b} windows of {w} transitions, up to {training.max_steps:,} steps")
  while steps < training.max_steps:
    key, sub = jax.random.split(key)
    state, metrics = chunk(state, sub)
    steps += training.eval_every
    heldout = np.asarray(evaluate(state.params, state.normalizer), np.float64)
    seconds = time.perf_counter() - start
    if steps == training.eval_every:  # the first chunk compiled; rates count from here
      warm_start, warm_steps = time.perf_counter(), steps
    curve.append({"step": steps, "seconds": round(seconds, 2),
                  "heldout_log_likelihood": [round(float(v), 4) for v in heldout],
                  "train_log_prob": round(float(metrics["log_prob"]), 4)})
    improved = heldout.mean() > best
    if improved:
      best_state, best, best_step = state, float(heldout.mean()), steps
    means.append(float(heldout.mean()))
    waited = evaluations_since_best(means, training.smoothing)
    warm = time.perf_counter() - warm_start
    rate = (steps - warm_steps) / warm if warm > 0 and steps > warm_steps else float("nan")
    left = f"  {(training.max_steps - steps) / rate:.0f}s left at most" if rate > 0 else ""
    shown = f"{rate:,.0f}" if rate > 0 else "-"  # the first chunk compiles: not timed
    print_fn(f"demonstrator step {steps:,}  {shown} steps/s  train log p "
             f"{float(metrics['log_prob']):.2f}  held-out log p by offset "
             + " ".join(f"{v:.2f}" for v in heldout)
             + ("  (best)" if improved else f"  (best at {best_step:,})") + left)
    if waited >= training.patience:
      print_fn(f"demonstrator: held-out likelihood (mean of {training.smoothing} evaluations) "
               f"has not improved for {waited} evaluations; keeping step {best_step:,}")
      stopped_by = "patience"
      break
    if training.max_seconds is not None and seconds >= training.max_seconds:
      print_fn(f"demonstrator: out of time after {seconds:.0f}s; keeping step {best_step:,}")
      stopped_by = "max_seconds"
      break
  best_heldout = next(c["heldout_log_likelihood"] for c in curve if c["step"] == best_step)
  # stopped_by: "patience", "max_seconds" or "max_steps" (a run cut by time depends on the
  # machine's speed: the file and its record say so)
  report = {"steps": steps, "best_step": best_step, "stopped_by": stopped_by,
            "batch_size": b, "window": w,
            "seconds": round(time.perf_counter() - start, 2),
            "heldout_log_likelihood": best_heldout, "curve": curve,
            "training_episodes": int(len(train_idx)), "heldout_episodes": int(len(heldout_idx))}
  return best_state, report
