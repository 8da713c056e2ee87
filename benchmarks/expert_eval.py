"""A fresh evaluation of expert policies over many episodes.

The return stored in an expert file is the best of its training evaluations (32 episodes): the
maximum of noisy estimates, biased upwards. This script evaluates each policy afresh, with its
mean action (clipped to the task's control range, as the simulator clamps it: [-1, 1] but
for quadruped's lift actuators, to 1.1, and its extenders, to 0.8; until 2026-11-29 it
clipped to [-1, 1], below the range quadruped's policies train and act in) over `--episodes`
full episodes (default 1000, the number of demonstrations FORM records), and appends one
`kind: expert_eval` record per task: mean, standard deviation, standard error, min and max
return, the paper's expert return and whether the mean reaches the experts issue's bar (0.95x,
`mjx_form.paper`).

  python benchmarks/expert_eval.py                              # every shipped expert
  python benchmarks/expert_eval.py --tasks walker_walk --policy runs/ww/seed0/best_policy.npz

`--by_start NAME` also splits the returns by the value of one dimension of each episode's first
observation (`--bins` equal-width bins between its smallest and largest value; names as the
task's observation layout gives them, e.g. `position[1]`, hopper's initial pitch rooty): which
starts the policy does well from, and how much it explores there (its Gaussian's mean scale
along those episodes, the share of actions whose mean lies 2 scales beyond [-1, 1], and the
chance that a sample leaves [-1, 1]: of [-1, 1], the policy's nominal range and every task's
control range but quadruped's, as the learner's saturation shares are).

  python benchmarks/expert_eval.py --tasks hopper_stand --policy runs/hs/policy.npz \
    --episodes 1024 --by_start "position[1]" --bins 8

The split also gives the share of each bin's episodes with any reward (`rewarded`). With
`--stochastic` the actions are sampled from the policy's Gaussian (clipped to the control
range, as MuJoCo clamps the actors' actions) instead of its mean: how often the policy's
exploration finds reward, and from where; `--action_noise_correlation C` samples them as a run
with that setting does.

`--by_turn` splits the returns by whether one of the task's raw unbounded angles
(`Task.periodic_observations`: reacher's shoulder, hopper's and cheetah's pitch) leaves
[-pi, pi) during the episode, in the observations the environment gives (before any wrap of the
agent's): how a policy does in the episodes where it turns past pi, and how far it turns there.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402
import numpy as np  # noqa: E402
from scipy import special  # noqa: E402

import tasks  # noqa: E402
from mjx_form import paper as paper_lib  # noqa: E402
from mjx_form.files import experts  # noqa: E402
from mjx_form.rl import normalizer  # noqa: E402
from mjx_form.sim import env as env_lib  # noqa: E402


def summary(returns: np.ndarray, task: str) -> dict:
  """The record's numbers for `returns` [K] of `task`."""
  paper = paper_lib.EXPERT.get(task)
  mean = float(returns.mean())
  return {"episodes": int(returns.size), "mean_return": mean,
          "std_return": float(returns.std()),
          "stderr_return": float(returns.std(ddof=1) / np.sqrt(returns.size))
          if returns.size > 1 else float("nan"),
          "min_return": float(returns.min()), "max_return": float(returns.max()),
          "paper_expert_return": paper,
          "reaches_bar": None if paper is None else bool(mean >= paper_lib.EXPERT_BAR * paper)}


def start_dimension(layout: dict[str, int], name: str) -> int:
  """The index of observation dimension `name` ('position[1]', or 'height' for a size-1 entry)
  in `layout` ({'position': 6, ...}); a clear error naming the valid ones."""
  names = env_lib.observation_names(layout)
  if name not in names:
    raise ValueError(f"unknown observation dimension {name!r} (valid: {', '.join(names)})")
  return names.index(name)


def returns_by_start(values: np.ndarray, returns: np.ndarray, bins: int,
                     **per_episode: np.ndarray) -> dict:
  """Returns [K] split by `values` [K] (one per episode) into `bins` equal-width bins between
  their min and max (the last bin closed): edges [bins + 1], episodes and mean return per bin
  (None where a bin is empty), and the per-bin mean of each other `per_episode` quantity [K]."""
  edges = np.linspace(values.min(), values.max(), bins + 1)
  which = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, bins - 1)
  counts = np.bincount(which, minlength=bins)

  def means(x):
    sums = np.bincount(which, weights=x, minlength=bins)
    return [float(s / c) if c else None for s, c in zip(sums, counts)]

  return {"edges": edges.tolist(), "episodes": counts.tolist(), "mean_return": means(returns),
          **{name: means(x) for name, x in per_episode.items()}}


def returns_by_turn(observations: np.ndarray, period: np.ndarray,
                    returns: np.ndarray) -> dict:
  """Returns [K] split by whether a periodic dimension (`period` [D] > 0) of the episode's
  observations [K, T, D] leaves [-period / 2, period / 2): per group ("turned", "stayed") the
  episodes, the mean return and the share rewarded (None where empty), and the turned episodes'
  median largest |angle| over their periodic dimensions."""
  turned = common.turned_past(observations, period).any(axis=1)  # [K]
  angles = np.abs(observations[..., period > 0])  # [K, T, P]

  def group(mask):
    n = int(mask.sum())
    return {"episodes": n, "mean_return": float(returns[mask].mean()) if n else None,
            "rewarded": float((returns[mask] > 0).mean()) if n else None}

  return {"turned": group(turned), "stayed": group(~turned),
          "turned_median_max_angle": (float(np.median(angles[turned].max(axis=(1, 2))))
                                      if turned.any() else None)}


def exploration(mean: np.ndarray, scale: np.ndarray) -> dict[str, np.ndarray]:
  """How much the policy explores along each episode, from its Gaussian's mean and scale
  [K, T, A] at the visited states: `policy_scale` [K], the mean scale; `beyond_bounds` [K],
  the share of steps and action dimensions whose mean lies more than 2 scales outside [-1, 1]
  (there 98% of the samples clip to the same bound: that dimension explores next to nothing);
  `clipped` [K], the probability that a sample leaves [-1, 1] (the control range but for
  quadruped's),
  averaged over steps and dimensions: comparable between policy heads, where a tanh-bounded
  mean is never beyond the bounds."""
  beyond = (np.abs(mean) - 1.0) > 2.0 * scale
  outside = special.ndtr((-1.0 - mean) / scale) + special.ndtr((mean - 1.0) / scale)
  return {"policy_scale": scale.mean(axis=(1, 2)), "beyond_bounds": beyond.mean(axis=(1, 2)),
          "clipped": outside.mean(axis=(1, 2))}


def policy_at(expert: experts.Expert, action_size: int, observations: np.ndarray,
              chunk: int = 128) -> tuple[np.ndarray, np.ndarray]:
  """The policy's mean and scale [K, T, A] at `observations` [K, T, D], `chunk` episodes at a
  time (the network's width and head from the expert's metadata)."""
  policy = experts.policy_network(expert.metadata, action_size)
  apply = jax.jit(lambda obs: policy.apply(expert.params,
                                           normalizer.normalize(expert.normalizer, obs)))
  parts = [apply(observations[i:i + chunk]) for i in range(0, len(observations), chunk)]
  return (np.concatenate([np.asarray(p.mean) for p in parts]),
          np.concatenate([np.asarray(p.scale) for p in parts]))


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  common.add_expert_arguments(parser)
  parser.add_argument("--episodes", type=int, default=1000)
  parser.add_argument("--chunk", type=int, default=1000, help="episodes run at once")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--by_start", default=None, metavar="NAME",
                      help="split the returns by this dimension of the first observation")
  parser.add_argument("--bins", type=int, default=8, help="bins of --by_start")
  parser.add_argument("--by_turn", action="store_true",
                      help="split the returns by whether a raw unbounded angle of the task "
                      "leaves [-pi, pi) during the episode")
  parser.add_argument("--stochastic", action="store_true",
                      help="sample the actions from the policy (as its actors act) instead of "
                      "taking its mean")
  parser.add_argument("--action_noise_correlation", type=float, default=0.0, metavar="C",
                      help="with --stochastic: the noise correlated in time as a training "
                      "run's actors draw it with this setting (default 0: independent)")
  parser.add_argument("--out", default=None, help="default: benchmarks/results/<date>_"
                      "expert_eval_<device>.jsonl")
  args = parser.parse_args(argv)
  names = common.expert_tasks(parser, args)
  if args.episodes <= 0 or args.chunk <= 0 or args.bins <= 0:
    parser.error("--episodes, --chunk and --bins must be positive")
  if not 0.0 <= args.action_noise_correlation < 1.0:
    parser.error("--action_noise_correlation must be in [0, 1)")
  if args.action_noise_correlation and not args.stochastic:
    parser.error("--action_noise_correlation needs --stochastic (it is the sampling noise's)")
  out = args.out or common.default_results_path(f"expert_eval_{jax.default_backend()}")
  if args.by_turn:  # every task checked before any record is written
    flat = [task for task in names if not tasks.make(task).periodic_observations]
    if flat:
      print(f"error: --by_turn: {', '.join(flat)} observe(s) no unbounded angle "
            "(Task.periodic_observations is empty)", file=sys.stderr)
      return 2
  writer = common.ResultWriter(out)
  for task in names:
    try:
      path = args.policy or tasks.bundled_expert(task)
      expert, env = common.load_expert(task, path)  # (in the physics it was trained in)
    except (ValueError, KeyError) as e:
      print(f"error: {e}", file=sys.stderr)
      return 2
    try:
      dimension = (None if args.by_start is None
                   else start_dimension(env.observation_layout, args.by_start))
    except ValueError as e:
      print(f"error: {task}: {e}", file=sys.stderr)
      return 2
    start = time.perf_counter()
    observations, _, returns = experts.record_demonstrations(
        env, expert, jax.random.PRNGKey(args.seed), args.episodes, args.chunk,
        stochastic=args.stochastic, noise_correlation=args.action_noise_correlation,
        print_fn=lambda line: None)
    seconds = time.perf_counter() - start
    numbers = summary(returns, task)
    if dimension is not None:
      loc, scale = policy_at(expert, env.action_size, observations[:, :-1])
      numbers["by_start"] = {"dimension": args.by_start, **returns_by_start(
          observations[:, 0, dimension], returns, args.bins, **exploration(loc, scale),
          rewarded=(returns > 0).astype(np.float64))}
    if args.by_turn:
      numbers["by_turn"] = {"dimensions": list(env.periodic_observations),
                            **returns_by_turn(np.asarray(observations),
                                              np.asarray(env.observation_period()), returns)}
    writer.write(kind="expert_eval", task=task, physics=env.physics,
                 policy_file=args.policy or os.path.basename(path),
                 policy_sha256=expert.metadata["sha256"],
                 policy_env_steps=expert.metadata.get("env_steps"),
                 export_return=expert.metadata.get("eval_return"), stochastic=args.stochastic,
                 action_noise_correlation=args.action_noise_correlation,
                 seed=args.seed, seconds=seconds, **numbers)
    paper = numbers["paper_expert_return"]
    bar = ("" if paper is None else f"; {paper_lib.EXPERT_BAR}x paper "
           f"{paper_lib.EXPERT_BAR * paper:.1f}: "
           f"{'reached' if numbers['reaches_bar'] else 'NOT reached'}")
    print(f"{task}{' (sampled actions)' if args.stochastic else ''}: "
          f"{numbers['mean_return']:.1f} +- {numbers['stderr_return']:.1f} (s.e.) over "
          f"{numbers['episodes']} episodes, min {numbers['min_return']:.1f} (at export "
          f"{expert.metadata.get('eval_return', float('nan')):.1f}{bar}) [{seconds:.0f}s]",
          flush=True)
    if dimension is not None:
      split = numbers["by_start"]
      for i, (count, mean) in enumerate(zip(split["episodes"], split["mean_return"])):
        low, high = split["edges"][i], split["edges"][i + 1]
        extra = ("" if mean is None else f", policy scale {split['policy_scale'][i]:.3f}, "
                 f"{split['beyond_bounds'][i]:.0%} of actions beyond the bounds by 2 scales, "
                 f"{split['clipped'][i]:.0%} of samples clipped, "
                 f"{split['rewarded'][i]:.0%} of episodes rewarded")
        print(f"  {args.by_start} in [{low:.3f}, {high:.3f}]: {count} episodes, mean return "
              f"{'-' if mean is None else f'{mean:.1f}'}{extra}", flush=True)
    if args.by_turn:
      turn = numbers["by_turn"]
      for name in ("turned", "stayed"):
        g = turn[name]
        print(f"  {name} {'past' if name == 'turned' else 'within'} [-pi, pi) "
              f"({', '.join(turn['dimensions'])}): {g['episodes']} episodes"
              + ("" if g["mean_return"] is None else
                 f", mean return {g['mean_return']:.1f}, {g['rewarded']:.0%} rewarded"),
              flush=True)
      if turn["turned_median_max_angle"] is not None:
        print(f"  turned episodes' largest |angle|, median: "
              f"{turn['turned_median_max_angle']:.2f}", flush=True)
  print(f"results appended to {out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
