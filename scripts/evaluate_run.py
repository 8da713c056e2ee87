#!/usr/bin/env python3
"""Fresh evaluation of a training run's final and best policies, after the run: `kind:
final_return` records, as the run writes them itself with `--final_eval_envs`.

For a run that ended without them (its machine taken back before its end, or stopped by
`--max_seconds` before runs evaluated there too): each member's `policy.npz` and
`best_policy.npz` (and `best_log_pd_policy.npz`, `average_policy.npz` and
`best_log_pd_average_policy.npz` where the run kept them) are evaluated over
`--episodes` fresh episodes (policy mean action, as the run's own evaluation; the final policy
also with actions drawn from it, `final_sampled`), here, e.g. on the CPU; `--policies` picks
some of them. Each record copies the member's learning-curve
record where its final policy was exported, the run's end (task, method, seed, settings, the
training device, env steps, wall clock), adds the returns, `policy_env_steps` (where the
policy was exported: the best one's is earlier), `finished` (whether the run reached its env
steps) and `eval_device` (where this evaluation ran), and is appended to the run's curve file.

  python scripts/evaluate_run.py --run_dir runs/rh_form --episodes 1024
  python scripts/evaluate_run.py --run_dir runs/rh_form --curve benchmarks/results/X.jsonl
  python scripts/evaluate_run.py --run_dir runs/ws --policies final,final_sampled

A member is matched to its learning-curve records by its policy file's settings (seed and the
member's own overrides, its reward settings from the run's config.json) and env steps; a member
without a match is an error (exit 2), and nothing is written.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402
import numpy as np  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import experts, results  # noqa: E402
from mjx_form.rl import grid, runner  # noqa: E402


class RunFilesError(ValueError):
  """A run directory or curve file that cannot be evaluated as asked."""


def _read_json_lines(path: str) -> list[dict]:
  """The file's records, whole (compact rows filled in), with its packed curve's where it has
  one (mjx_form/files/results.py)."""
  try:
    out = results.run_records(path)
  except results.ResultFileError as e:
    raise RunFilesError(str(e)) from None
  for number, record in enumerate(out, 1):
    if not isinstance(record.get("settings", {}), dict):
      raise RunFilesError(f"{path}: record {number}'s settings are not an object")
  return out


def member_record(records: list[dict], policy_meta: dict, path: str,
                  reward_overrides: dict) -> dict:
  """The learning-curve record of the member whose exported policy has `policy_meta`, at the
  policy's env steps: every setting of its train config equal to the record's, and its own
  reward settings (`reward_overrides`, a population's grid of them) too; the last such record
  where a resumed run wrote one twice. Where there is none, the run's own `final_return`
  record of the same file (its sha256)."""
  config = policy_meta.get("train_config") or {}
  # (a setting with named values is left out of records at its default, the first of them)
  recorded = lambda reward, k: reward.get(k, grid.CHOICES.get(k, (None,))[0])
  same = lambda r: (r.get("env_steps") == policy_meta.get("env_steps")
                    and all(r.get("settings", {}).get(k) == v for k, v in config.items())
                    and all(recorded(r.get("settings", {}).get("reward") or {}, k) == v
                            for k, v in reward_overrides.items()))
  matches = [r for r in records if r.get("kind") == "learning_curve" and same(r)]
  # (a run stopped by --max_seconds that evaluated on the host has no learning-curve record
  # at its end: its own fresh evaluation of the same file places it)
  matches = matches or [r for r in records if r.get("kind") == "final_return" and same(r)
                        and r.get("policy_sha256") == policy_meta.get("sha256")]
  if not matches:
    raise RunFilesError(f"{path}: no learning-curve records of the curve file match this "
                        f"policy (seed {config.get('seed')}, {policy_meta.get('env_steps')} env "
                        f"steps)")
  return matches[-1]


POLICIES = ("final", "final_sampled", *(n for n, _, _ in runner.BEST), "average",
            *(n for n, _, _ in runner.AVERAGE_BEST))


def evaluate(path: str, env, episodes: int, chunk: int, seed: int, sampled: bool = False
             ) -> tuple[np.ndarray, dict]:
  """Returns [episodes] of the policy file at `path` (mean action, or with `sampled` actions
  drawn from it afresh each step) in `env`, the run's task (one task object for every file: its
  compiled rollout serves them all), and its metadata."""
  policy = experts.load_expert(path, env)  # refuses a file of another task, by name
  _, _, returns = experts.record_demonstrations(env, policy, jax.random.PRNGKey(seed), episodes,
                                                chunk, stochastic=sampled,
                                                print_fn=lambda line: None)
  return returns, policy.metadata


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--run_dir", required=True, help="a run directory of scripts/run.py")
  parser.add_argument("--curve", default=None, help="the run's learning-curve file, where the "
                      "records are appended (default: <run_dir>/learning_curve.jsonl)")
  parser.add_argument("--episodes", type=int, default=256)
  parser.add_argument("--chunk", type=int, default=512, help="episodes run at once")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--policies", default=",".join(POLICIES),
                      help=f"which, comma-separated (default all: {','.join(POLICIES)})")
  args = parser.parse_args(argv)
  if args.episodes <= 0 or args.chunk <= 0:
    parser.error("--episodes and --chunk must be positive")
  chosen = [p.strip() for p in args.policies.split(",") if p.strip()]
  if not chosen or set(chosen) - set(POLICIES):
    parser.error(f"--policies: expected some of {','.join(POLICIES)}, got {args.policies!r}")
  curve = args.curve or os.path.join(args.run_dir, "learning_curve.jsonl")
  try:
    with open(os.path.join(args.run_dir, "config.json")) as f:
      config = json.load(f)
    seeds = tuple(config.get("seeds") or (config["seed"],))
    overrides = tuple(config.get("overrides") or ({} for _ in seeds))
    if len(overrides) != len(seeds):
      raise RunFilesError(f"{args.run_dir}/config.json: {len(seeds)} seeds but "
                          f"{len(overrides)} members' overrides")
    dirs = runner.member_dirs(args.run_dir, seeds, overrides)
    if config.get("task") not in tasks.TASKS:
      raise RunFilesError(f"{args.run_dir}/config.json: unknown task {config.get('task')!r}")
    env = tasks.make(config["task"], physics=config.get("physics", "fast"))
    records = _read_json_lines(curve)
    out = []
    for d, own_settings in zip(dirs, overrides):
      reward_overrides = grid.split(own_settings)[2]
      end = None  # the final policy's record: where the run ended, every record is placed
      for name, file in (("final", "policy.npz"), ("final_sampled", "policy.npz"),
                         *((n, f) for n, _, f in runner.BEST), ("average", runner.AVERAGE_FILE),
                         *((n, f) for n, _, f in runner.AVERAGE_BEST)):
        path = os.path.join(d, file)
        if name not in ("final", "final_sampled") and not os.path.exists(path):
          continue  # (by log pD: FORM runs; average: runs with --policy_average_decay)
        if name not in chosen:
          # (the final policy's record still places every record: where the run ended)
          end = end or (member_record(records, experts.load_expert(path, env).metadata, path,
                                      reward_overrides) if name == "final" else None)
          continue
        returns, meta = evaluate(path, env, args.episodes, args.chunk, args.seed,
                                 sampled=name == "final_sampled")
        own = member_record(records, meta, path, reward_overrides)  # the policy's point
        end = end or own
        total = end.get("settings", {}).get("total_env_steps")
        out.append({
            **{k: end[k] for k in ("task", "method", "physics", "num_envs", "seed",
                                  "learner_preset", "population", "device", "versions",
                                  "physics_matmul_precision") if k in end},
            "kind": "final_return", "policy": name, "final_return": float(returns.mean()),
            "final_return_std": float(returns.std()), "episodes": int(returns.size),
            "env_steps": end["env_steps"], "wall_s": end["wall_s"],
            "finished": total is not None and end["env_steps"] >= total,
            "settings": end["settings"], "policy_env_steps": own["env_steps"],
            "eval_device": results.device_name(), "policy_sha256": meta["sha256"],
            "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")})
        print(f"{os.path.relpath(path, args.run_dir)}"
              + (" (actions sampled)" if name == "final_sampled" else "")
              + f": {returns.mean():.1f} +- {returns.std():.1f}"
              f" over {returns.size} episodes (policy of {own['env_steps']:,} env steps)",
              flush=True)
  except (OSError, KeyError, ValueError) as e:  # RunFilesError, policy and task checks
    print(f"error: {e}", file=sys.stderr)
    return 2
  with open(curve, "a") as f:  # all members evaluated before anything is written
    for record in out:
      f.write(json.dumps(record) + "\n")
  print(f"{len(out)} final_return records appended to {curve}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
