#!/usr/bin/env python3
"""Several demonstrators' log-likelihood on one common set of demonstrations (FORM diagnostics).

A demonstrator's training record gives its held-out log-likelihood on the last 5% of its own
demonstrations, so two demonstrators trained on other demonstrations (another
`--demonstrator_seed`) are measured on other episodes. This scores every given file on the same
episodes, ones none of them trained on (e.g. `scripts/make_demos.py --seed 1000`): the raw-space
mean log p(x_{t+delta} | x_t) per offset over every pair, per episode at offset 1 (its
spread says how far two files' difference stands above the episodes'), and at offset 1 over the
transitions that change the observation most (`--moving`, the top share by the standardised
size of x_{t+1} - x_t): where an expert settles (reacher: ~92% of its transitions nearly still),
the mean over all transitions weighs the few that FORM's reward must pull an imitator through
little. Appends one `kind: demonstrator_heldout` record per file.

  python scripts/make_demos.py --task reacher_hard --episodes 64 --seed 1000 --out /tmp/rh.npz
  python benchmarks/demonstrator_heldout.py --task reacher_hard --demos /tmp/rh.npz \\
      --demonstrator tasks/demonstrators/reacher_hard.npz --demonstrator other.npz \\
      --results benchmarks/results/<date>_demonstrator_heldout_cpu_reacher_hard.jsonl
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import demos as demos_lib  # noqa: E402
from mjx_form.files import results  # noqa: E402
from mjx_form.imitation import demonstrator as demonstrator_lib  # noqa: E402
from mjx_form.imitation import effect_model as em  # noqa: E402
from mjx_form.imitation import pipeline  # noqa: E402


def per_episode(model: em.EffectModel, params, norm, episodes: np.ndarray) -> np.ndarray:
  """Raw-space mean log p(x_{t+delta} | x_t) of each episode [K, T+1, D] (no episode ends
  inside) per offset, as a training record's held-out log-likelihood of that episode alone
  (`demonstrator.heldout_log_likelihood`): [K, max_offset]."""
  one = jax.jit(lambda episode: demonstrator_lib.heldout_log_likelihood(model, params, norm,
                                                                        episode[None]))
  return np.stack([np.asarray(one(jnp.asarray(e))) for e in episodes])


def transition_log_probs(model: em.EffectModel, params, norm, episodes: np.ndarray
                         ) -> np.ndarray:
  """Raw-space log p(x_{t+1} | x_t) of every transition of episodes [K, T+1, D]: [K, T]."""

  @jax.jit
  def one(episode):  # [T+1, D] -> [T]
    return em.transition_log_prob(model, params, norm, episode[:-1], episode[1:])

  return np.stack([np.asarray(one(jnp.asarray(e))) for e in episodes])


def moving_mask(episodes: np.ndarray, share: float) -> np.ndarray:
  """[K, T] True for the `share` of transitions with the largest |x_{t+1} - x_t| after each
  dimension is divided by its standard deviation over all observations (ties at the threshold
  included)."""
  scale = episodes.reshape(-1, episodes.shape[-1]).std(axis=0)
  change = np.linalg.norm(np.diff(episodes, axis=1) / np.where(scale > 0, scale, 1.0), axis=-1)
  return change >= np.quantile(change, 1.0 - share)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", required=True)
  parser.add_argument("--demos", required=True, help="demonstrations none of the files trained on")
  parser.add_argument("--demonstrator", action="append", required=True,
                      help="a demonstrator file (repeat to compare several)")
  parser.add_argument("--moving", type=float, default=0.1,
                      help="share of transitions with the largest standardised change scored "
                           "apart (default 0.1)")
  parser.add_argument("--results", default=None)
  args = parser.parse_args(argv)
  if not 0.0 < args.moving < 1.0:
    parser.error(f"--moving must be in (0, 1), got {args.moving}")
  if args.task not in tasks.TASKS:
    parser.error(f"unknown task {args.task!r}; valid tasks: {', '.join(tasks.TASKS)}")
  env = tasks.make(args.task)
  try:
    demos = demos_lib.load_demonstrations(args.demos, task=args.task,
                                          observation_layout=env.observation_layout)
    files = [(p, pipeline.load_demonstrator(p, env)) for p in args.demonstrator]
    models = [(p, f, *pipeline.demonstrator_from_file(f, p)) for p, f in files]
  except (ValueError, OSError) as e:
    print(f"error: {e}", file=sys.stderr)
    return 2
  obs = np.asarray(demos.observations, np.float32)  # [K, T+1, D]
  expert = (demos.metadata.get("expert") or {})
  moving = moving_mask(obs, args.moving)  # [K, T]
  writer = results.ResultWriter(args.results) if args.results else None
  print(f"{len(obs)} episodes of {args.demos} (demonstrations sha256 "
        f"{demos.metadata.get('sha256', '')[:12]}, seed {expert.get('seed')}, expert's mean "
        f"return {expert.get('mean_return')})")
  for path, file, config, demonstrator in models:
    model = em.make_model(config, obs.shape[-1])
    scores = per_episode(model, demonstrator.params, demonstrator.normalizer, obs)
    mean = scores.mean(axis=0)
    sem = scores[:, 0].std(ddof=1) / np.sqrt(len(scores)) if len(scores) > 1 else float("nan")
    sha = file.metadata["sha256"]  # what runs and records name a demonstrator by
    steps = transition_log_probs(model, demonstrator.params, demonstrator.normalizer, obs)
    moving_mean, still_mean = float(steps[moving].mean()), float(steps[~moving].mean())
    print(f"{sha[:6]} {os.path.basename(path)}: by offset "
          + " / ".join(f"{v:.2f}" for v in mean) + f"  (offset 1: +- {sem:.2f} s.e. over episodes)"
          + f"; offset 1, moving {args.moving:.0%}: {moving_mean:.2f}, the rest {still_mean:.2f}")
    if writer:
      writer.write(kind="demonstrator_heldout", task=args.task, method="form",
                   demonstrator=path, demonstrator_sha256=sha,
                   demonstrator_settings=config.to_dict(),
                   demonstrations={"path": args.demos, "sha256": demos.metadata.get("sha256"),
                                   "seed": expert.get("seed"), "episodes": len(obs),
                                   "expert_sha256": expert.get("policy_sha256")},
                   log_likelihood=[round(float(v), 4) for v in mean],
                   offset1_sem=round(float(sem), 4), moving_share=args.moving,
                   offset1_moving=round(moving_mean, 4), offset1_rest=round(still_mean, 4),
                   offset1_by_episode=[round(float(v), 3) for v in scores[:, 0]])
  return 0


if __name__ == "__main__":
  sys.exit(main())
