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
from typing import Callable, Sequence

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
  """Trains a demonstrator on observations [K, T+1, D] with `training.seed`; returns (the best
  held-out state, a report: steps, best_step, stopped_by, heldout_log_likelihood per offset,
  curve, seconds, episodes)."""
  return train_draws(observations, config, training, (training.seed,), print_fn)[0]


def train_draws(observations: np.ndarray, config: em.EffectModelConfig,
                training: DemonstratorTraining, seeds: Sequence[int],
                print_fn: Callable[[str], None] = print
                ) -> list[tuple[em.EffectModelState, dict]]:
  """Trains one demonstrator per seed on the same observations and held-out split, side by
  side in one program (vmapped: a draw computes what it computes alone, up to the order of
  floating-point sums, which on a GPU carries into the curves over many steps); each keeps its best
  held-out state and stops on its own patience (the others go on; a stopped draw's further
  steps are discarded). Returns (state, report) per seed, as `train`'s (`seconds`: the
  program's, the same for every draw)."""
  config.check()
  if not seeds or len(set(seeds)) != len(seeds):
    raise ValueError(f"demonstrator draws need distinct seeds, got {list(seeds)}")
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

  def chunk_one(state, key):
    key, sub = jax.random.split(key)
    state, metrics = jax.lax.scan(step, state, jax.random.split(sub, training.eval_every))
    heldout = heldout_log_likelihood(model, state.params, state.normalizer, heldout_obs)
    return state, key, jax.tree.map(jnp.mean, metrics), heldout

  chunk = jax.jit(jax.vmap(chunk_one))  # over the draws: [S, ...] each

  def init_one(key):
    key, init_key = jax.random.split(key)
    return em.init(model, config, init_key), key

  states, keys = jax.vmap(init_one)(jnp.stack([jax.random.PRNGKey(s) for s in seeds]))
  n = len(seeds)
  draws = [{"best_state": None, "best": -np.inf, "best_step": 0, "curve": [], "means": [],
            "steps": 0, "stopped_by": None} for _ in range(n)]
  start = time.perf_counter()
  steps = 0
  print_fn(f"demonstrator{'s' if n > 1 else ''}: {len(train_idx)} training and "
           f"{len(heldout_idx)} held-out episodes, batches of {b} windows of {w} transitions, "
           f"up to {training.max_steps:,} steps"
           + (f", {n} draws side by side (seeds {', '.join(map(str, seeds))})" if n > 1 else ""))
  while steps < training.max_steps and any(r["stopped_by"] is None for r in draws):
    states, keys, metrics, heldouts = chunk(states, keys)
    steps += training.eval_every
    log_probs, heldouts = jax.device_get((metrics["log_prob"], heldouts))  # one transfer
    heldouts = np.asarray(heldouts, np.float64)  # [S, max_offset]
    seconds = time.perf_counter() - start
    if steps == training.eval_every:  # the first chunk compiled; rates count from here
      warm_start, warm_steps = time.perf_counter(), steps
    warm = time.perf_counter() - warm_start
    rate = (steps - warm_steps) / warm if warm > 0 and steps > warm_steps else float("nan")
    shown = f"{rate:,.0f}" if rate > 0 else "-"  # the first chunk compiles: not timed
    left = f"  {(training.max_steps - steps) / rate:.0f}s left at most" if rate > 0 else ""
    notes = []
    for i, r in enumerate(draws):
      if r["stopped_by"] is not None:
        continue
      heldout, log_prob = heldouts[i], float(log_probs[i])
      r["steps"] = steps
      r["curve"].append({"step": steps, "seconds": round(seconds, 2),
                         "heldout_log_likelihood": [round(float(v), 4) for v in heldout],
                         "train_log_prob": round(log_prob, 4)})
      improved = heldout.mean() > r["best"]
      if improved:
        r["best_state"] = jax.tree.map(lambda x, i=i: x[i], states)
        r["best"], r["best_step"] = float(heldout.mean()), steps
      r["means"].append(float(heldout.mean()))
      best = "  (best)" if improved else f"  (best at {r['best_step']:,})"
      if n == 1:
        print_fn(f"demonstrator step {steps:,}  {shown} steps/s  train log p {log_prob:.2f}  "
                 "held-out log p by offset " + " ".join(f"{v:.2f}" for v in heldout)
                 + best + left)
      else:
        notes.append(f"seed {seeds[i]} {heldout[0]:.2f}{'*' if improved else ''}")
      waited = evaluations_since_best(r["means"], training.smoothing)
      who = "demonstrator" + (f" (seed {seeds[i]})" if n > 1 else "")
      if waited >= training.patience:
        print_fn(f"{who}: held-out likelihood (mean of {training.smoothing} evaluations) has "
                 f"not improved for {waited} evaluations; keeping step {r['best_step']:,}")
        r["stopped_by"] = "patience"
      elif training.max_seconds is not None and seconds >= training.max_seconds:
        print_fn(f"{who}: out of time after {seconds:.0f}s; keeping step {r['best_step']:,}")
        r["stopped_by"] = "max_seconds"
    if notes:
      print_fn(f"demonstrators step {steps:,}  {shown} steps/s each  held-out log p at offset "
               "1 (* new best of the mean over offsets): " + ", ".join(notes) + left)
  failed = [s for s, r in zip(seeds, draws) if r["best_state"] is None]
  if failed:  # (a held-out likelihood that was never a number)
    raise ValueError(f"demonstrator draws of seeds {failed}: no finite held-out "
                     "log-likelihood at any evaluation")
  out = []
  for seed, r in zip(seeds, draws):
    best_heldout = next(c["heldout_log_likelihood"] for c in r["curve"]
                        if c["step"] == r["best_step"])
    # stopped_by: "patience", "max_seconds" or "max_steps" (a run cut by time depends on the
    # machine's speed: the file and its record say so)
    out.append((r["best_state"], {
        "seed": int(seed), "steps": r["steps"], "best_step": r["best_step"],
        "stopped_by": r["stopped_by"] or "max_steps", "batch_size": b, "window": w,
        "seconds": round(time.perf_counter() - start, 2),
        "heldout_log_likelihood": best_heldout, "curve": r["curve"],
        "training_episodes": int(len(train_idx)), "heldout_episodes": int(len(heldout_idx))}))
  return out
