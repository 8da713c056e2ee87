#!/usr/bin/env python3
"""The speed / fidelity trade-off of the solver settings, one task per domain.

For each candidate (iterations, line-search iterations, contact culling) it measures, on this
device: control steps per second of our step and of the raw `mjx.step` loop at `--num_envs`,
and the one-step error against dm_control's reference transitions
(scripts/make_reference.py). Records `kind: solver_sweep`. The fast mode of each domain is
chosen from these numbers (README, "Physics modes and speed").

  python benchmarks/solver_sweep.py --reference .ref --num_envs 2048
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402

import env_throughput  # noqa: E402
import parity_error  # noqa: E402
import tasks  # noqa: E402
from mjx_form.physics import SolverSettings  # noqa: E402

DOMAIN_TASKS = ["cheetah_run", "hopper_hop", "walker_walk", "quadruped_walk", "humanoid_walk"]
# Contact caps above the most simultaneous contacts seen in 3000 random-action steps of
# dm_control (cheetah 2, hopper 5, walker 6, quadruped 4, humanoid 11 contacts).
CULL = {"cheetah_run": 4, "hopper_hop": 8, "walker_walk": 8, "quadruped_walk": 8,
        "humanoid_walk": 16}


def candidates(name: str) -> list[SolverSettings]:
  cull = CULL[name]
  out = []
  for iterations, ls in ((100, 50), (10, 10), (4, 8)):
    out.append(SolverSettings(iterations, ls))
    out.append(SolverSettings(iterations, ls, max_contact_points=cull, max_geom_pairs=cull))
  return out


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--tasks", nargs="*", default=DOMAIN_TASKS, choices=DOMAIN_TASKS)
  parser.add_argument("--reference", default=".ref")
  parser.add_argument("--num_envs", type=int, default=2048)
  parser.add_argument("--steps", type=int, default=20)
  parser.add_argument("--repeats", type=int, default=2)
  parser.add_argument("--threads", type=int, default=12)
  parser.add_argument("--out", default=common.default_results_path("solver_sweep"))
  args = parser.parse_args(argv)
  writer = common.ResultWriter(args.out)
  key = jax.random.PRNGKey(0)

  configs = [(name, settings) for name in args.tasks for settings in candidates(name)]
  envs = [tasks.make(name, physics=settings) for name, settings in configs]
  t0 = time.perf_counter()
  starts = common.batched_resets(envs, key, args.num_envs, args.threads)
  print(f"{len(envs)} resets compiled and run in {time.perf_counter() - t0:.0f}s", flush=True)
  jobs = []  # (name, settings, kind, fn, fn_args); inputs get their own buffers (donated)
  for (name, settings), env, start in zip(configs, envs, starts):
    jobs.append((name, settings, "sps", env_throughput.ours_fn(env, args.num_envs, args.steps),
                 (env_throughput.copy_tree(start), key)))
    jobs.append((name, settings, "raw_sps",
                 env_throughput.raw_fn(env, args.num_envs, args.steps),
                 (env_throughput.copy_tree(start.data), key)))
  del starts

  t0 = time.perf_counter()
  executables = [exe for exe, _ in common.compile_all([(j[3], j[4]) for j in jobs], args.threads)]
  print(f"compiled {len(jobs)} functions in {time.perf_counter() - t0:.0f}s", flush=True)

  results: dict[tuple, dict] = {}
  for (name, settings, kind, _, fn_args), exe in zip(jobs, executables):
    holder = [jax.block_until_ready(exe(*fn_args))]

    def call():
      holder[0] = jax.block_until_ready(exe(holder[0], key))
    seconds = common.best_time(call, args.repeats)
    results.setdefault((name, settings), {})[kind] = args.steps * args.num_envs / seconds
    del holder

  def error_job(item):
    (name, settings), _ = item
    return parity_error.measure(name, settings,
                                parity_error.load_reference(args.reference, name))

  with concurrent.futures.ThreadPoolExecutor(args.threads) as pool:
    errors = list(pool.map(error_job, results.items()))

  print(f"{'task':<16}{'iters':>6}{'ls':>4}{'cull':>6}{'ours/s':>12}{'raw/s':>12}"
        f"{'qvel med':>10}{'qvel p90':>10}{'qvel max':>10}")
  for ((name, settings), speed), error in zip(results.items(), errors):
    error.pop("solver")
    writer.write(kind="solver_sweep", task=name, settings={**vars(settings),
                 "num_envs": args.num_envs, "steps": args.steps}, **speed, **error)
    v = error["qvel_error"]
    print(f"{name:<16}{settings.iterations:>6}{settings.ls_iterations:>4}"
          f"{settings.max_contact_points or '-':>6}{speed['sps']:>12,.0f}{speed['raw_sps']:>12,.0f}"
          f"{v['median']:>10.1e}{v['p90']:>10.1e}{v['max']:>10.1e}", flush=True)
  return 0


if __name__ == "__main__":
  sys.exit(main())
