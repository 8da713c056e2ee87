"""An expert from the same initial states in MJX and in dm_control: does it fail from the same
starts in both simulators, or only in the physics it was trained in?

`dm_control_transfer.py` compares mean returns over independent starts. This script replays the
same starts: it draws `--episodes` initial states from the MJX task's reset (with `--start NAME
LOW HIGH`, only those whose first observation has NAME in [LOW, HIGH], e.g. hopper's pitch
`position[1]`), puts dm_control's physics at each (qpos, qvel, act; reacher's target), and runs
the expert's mean action from them in dm_control, in MJX with the physics the expert was trained
in (`fast` for the shipped experts), and in MJX with dm_control's solver settings (`parity`).
One `kind: same_starts` record per task: each simulator's returns per episode and their mean,
and the episodes each one fails (return below `--fail_below`, default half the paper's expert
return), alone and together.

  python benchmarks/same_starts.py --tasks hopper_stand --episodes 128 \\
    --start "position[1]" 2.35 3.15
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

import dm_control_transfer  # noqa: E402
import expert_eval  # noqa: E402
import tasks  # noqa: E402
from mjx_form import paper as paper_lib  # noqa: E402
from mjx_form.files import experts  # noqa: E402
from mjx_form.sim import env as env_lib  # noqa: E402


def draw_starts(env: env_lib.Task, key: jax.Array, episodes: int, dimension: int | None = None,
                low: float = -np.inf, high: float = np.inf, pool: int = 16) -> dict:
  """`episodes` initial states of `env`'s reset, {'qpos': [K, nq], 'qvel', 'act', 'task':
  {name: [K, ...]}, 'obs': [K, D]}: the first of `pool` x `episodes` draws whose first
  observation's `dimension` lies in [low, high] (all draws count where `dimension` is None)."""
  draws = episodes if dimension is None else episodes * pool
  states = jax.device_get(jax.jit(jax.vmap(env.reset))(jax.random.split(key, draws)))
  keep = np.arange(draws)
  if dimension is not None:
    keep = np.flatnonzero((states.obs[:, dimension] >= low) & (states.obs[:, dimension] <= high))
    if keep.size < episodes:
      raise ValueError(f"only {keep.size} of {draws} starts lie in [{low}, {high}]; ask for "
                       "fewer episodes or a wider range")
    keep = keep[:episodes]
  d = states.data
  return {"qpos": np.asarray(d.qpos)[keep], "qvel": np.asarray(d.qvel)[keep],
          "act": np.asarray(d.act)[keep], "obs": np.asarray(states.obs)[keep],
          "task": {k: np.asarray(v)[keep] for k, v in states.task.items()}}


def mjx_returns(env: env_lib.Task, expert: experts.Expert, starts: dict,
                steps: int = env_lib.EPISODE_LENGTH) -> np.ndarray:
  """[K] returns of the expert's mean action (clipped to the control range) from `starts` in
  `env`."""
  act = dm_control_transfer.mean_action_fn(expert, *env.action_bounds)  # the policy as there

  @jax.jit
  def run(qpos, qvel, actuation, task):
    keys = jax.random.split(jax.random.PRNGKey(0), qpos.shape[0])
    states = jax.vmap(env.reset_to)(qpos, qvel, actuation, task, keys)

    def step(states, _):
      states = jax.vmap(env.step)(states, act(states.obs))
      return states, states.reward

    _, rewards = jax.lax.scan(step, states, None, length=steps)
    return rewards.sum(axis=0)

  return np.asarray(run(starts["qpos"], starts["qvel"], starts["act"], starts["task"]))


def failures(returns: dict[str, np.ndarray], fail_below: float) -> dict:
  """Per simulator ({name: [K] returns}) the episodes it fails (return < fail_below), and the
  episodes failed in the first simulator named only, in the others only, and in all."""
  failed = {name: r < fail_below for name, r in returns.items()}
  (name, first), *others = failed.items()
  others = [f for _, f in others]
  others_all = np.logical_and.reduce(others) if others else np.ones_like(first)
  others_any = np.logical_or.reduce(others) if others else np.zeros_like(first)
  return {"failed": {n: int(f.sum()) for n, f in failed.items()},
          "failed_in_all": int((first & others_all).sum()),
          f"failed_in_{name}_only": int((first & ~others_any).sum()),
          f"failed_not_in_{name}": int((~first & others_any).sum())}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  common.add_expert_arguments(parser)
  parser.add_argument("--episodes", type=int, default=64)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--start", nargs=3, default=None, metavar=("NAME", "LOW", "HIGH"),
                      help="only starts whose first observation has NAME in [LOW, HIGH]")
  parser.add_argument("--fail_below", type=float, default=None,
                      help="an episode fails below this return (default: half the paper's "
                           "expert return)")
  parser.add_argument("--steps", type=int, default=env_lib.EPISODE_LENGTH,
                      help="steps per episode (fewer only to try the script)")
  parser.add_argument("--out", default=common.default_results_path("same_starts_cpu"))
  args = parser.parse_args(argv)
  names = common.expert_tasks(parser, args)
  if args.episodes <= 0 or not 0 < args.steps <= env_lib.EPISODE_LENGTH:
    parser.error(f"--episodes must be positive and --steps in 1..{env_lib.EPISODE_LENGTH}")
  try:
    low, high = (-np.inf, np.inf) if args.start is None else map(float, args.start[1:])
  except ValueError:
    parser.error(f"--start: LOW and HIGH must be numbers, got {args.start[1:]}")
  writer = common.ResultWriter(args.out)
  for task in names:
    try:
      path = args.policy or tasks.bundled_expert(task)
      expert, trained = common.load_expert(task, path)
      dimension = (None if args.start is None
                   else expert_eval.start_dimension(trained.observation_layout, args.start[0]))
      starts = draw_starts(trained, jax.random.PRNGKey(args.seed), args.episodes, dimension,
                           low, high)
      start = time.perf_counter()
      returns = {"dm_control": dm_control_transfer.dm_control_returns(
          task, expert, trained.observation_layout, trained.action_size, args.episodes,
          args.seed, args.steps, starts=starts)}
    except (ValueError, KeyError) as e:
      print(f"error: {e}", file=sys.stderr)
      return 2
    dm_s = time.perf_counter() - start
    returns[f"mjx_{trained.physics}"] = mjx_returns(trained, expert, starts, args.steps)
    other = "parity" if trained.physics != "parity" else "fast"
    returns[f"mjx_{other}"] = mjx_returns(tasks.make(task, physics=other), expert, starts,
                                          args.steps)
    paper = paper_lib.EXPERT.get(task)
    fail_below = args.fail_below if args.fail_below is not None else 0.5 * (paper or 0.0)
    counts = failures(returns, fail_below)
    writer.write(kind="same_starts", task=task, policy_file=os.path.basename(path),
                 policy_sha256=expert.metadata["sha256"], trained_physics=trained.physics,
                 episodes=args.episodes, steps=args.steps, seed=args.seed,
                 start_dimension=None if args.start is None else args.start[0],
                 start_range=None if args.start is None else [low, high],
                 start_values=None if dimension is None
                 else starts["obs"][:, dimension].round(4).tolist(),
                 fail_below=fail_below, dm_control_s=dm_s,
                 mean_return={k: float(v.mean()) for k, v in returns.items()},
                 returns={k: v.round(2).tolist() for k, v in returns.items()}, **counts)
    print(f"{task} ({args.episodes} starts"
          f"{'' if args.start is None else f' with {args.start[0]} in [{low}, {high}]'}): "
          + ", ".join(f"{k} {v.mean():.1f} ({counts['failed'][k]} below {fail_below:.0f})"
                      for k, v in returns.items())
          + f"; failed in all three {counts['failed_in_all']}, in dm_control only "
          f"{counts['failed_in_dm_control_only']}, not in dm_control "
          f"{counts['failed_not_in_dm_control']}", flush=True)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
