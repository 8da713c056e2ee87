#!/usr/bin/env python3
"""The speed / fidelity trade-off of the solver settings, one task per contact domain.

For each candidate (solver iterations, line-search iterations, contact culling) it measures
one of two things, chosen by `--measure`:
  speed: control steps per second of the raw `mjx.step` loop at `--num_envs` on this device
         (GPU), from the same reset states for every candidate, and the speed-up over the
         first candidate (`first` in the record; dm_control's settings unless --iterations
         starts otherwise);
  error: the one-control-step error against dm_control's reference transitions
         (scripts/make_reference.py), float32, on this device (CPU is fine).
Records `kind: solver_sweep` with `measured` set to `speed` or `error`. The fast mode of each
domain is chosen from these numbers (README, "Physics modes"). Runs sequentially and writes
each record as soon as it is measured, so a run stopped at a time limit keeps what it had.

  python benchmarks/solver_sweep.py --measure speed --num_envs 2048      # on the GPU
  python benchmarks/solver_sweep.py --measure error --reference .ref     # on the CPU
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402
from mujoco import mjx  # noqa: E402

import env_throughput  # noqa: E402
import parity_error  # noqa: E402
import tasks  # noqa: E402
from mjx_form.sim.physics import SolverSettings  # noqa: E402
from mjx_form.sim.wrappers import AutoReset  # noqa: E402

# Contact caps above the most simultaneous contacts seen in 3000 random-action steps of
# dm_control (cheetah 2, hopper 5, walker 6, quadruped 4, humanoid 11 contacts).
CULL = {"cheetah_run": 4, "hopper_hop": 8, "walker_walk": 8, "quadruped_walk": 8,
        "humanoid_walk": 16}
DOMAIN_TASKS = list(CULL)
ITERATIONS = ((100, 50), (10, 10), (4, 8))  # MuJoCo's defaults (dm_control's) come first


def candidates(name: str, pairs=ITERATIONS) -> list[SolverSettings]:
  """The settings tried for `name`'s domain, each (solver, line-search) iteration pair without
  and with culling; (100, 50) is dm_control's (parity: MuJoCo's defaults)."""
  out = []
  for iterations, ls in pairs:
    default = (iterations, ls) == ITERATIONS[0]
    out.append(SolverSettings() if default else SolverSettings(iterations, ls))
    out.append(SolverSettings(None if default else iterations, None if default else ls,
                              max_contact_points=CULL[name], max_geom_pairs=CULL[name]))
  return out


def _pair(text: str) -> tuple[int, int]:
  """'10/4' -> (10, 4): solver and line-search iterations."""
  try:
    iterations, ls = (int(v) for v in text.split("/"))
  except ValueError:
    raise argparse.ArgumentTypeError(f"expected I/L (e.g. 10/4), got {text!r}") from None
  if iterations < 1 or ls < 1:
    raise argparse.ArgumentTypeError(f"iterations must be positive, got {text!r}")
  return iterations, ls


def start_states(name: str, num_envs: int, key):
  """(qpos, qvel) of `num_envs` fresh resets of the task (parity settings)."""
  state = jax.jit(lambda k: AutoReset(tasks.make(name)).reset(k, num_envs))(key)
  return jax.block_until_ready((state.data.qpos, state.data.qvel))


def describe(settings: SolverSettings) -> str:
  its = f"{settings.iterations or 100}/{settings.ls_iterations or 50}"
  return its + (f" cull {settings.max_contact_points}" if settings.max_contact_points else "")


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--measure", choices=("speed", "error"), required=True)
  parser.add_argument("--tasks", nargs="*", default=DOMAIN_TASKS, choices=DOMAIN_TASKS)
  parser.add_argument("--reference", default=".ref", help="folder of reference transitions")
  parser.add_argument("--num_envs", type=int, default=2048)
  parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
  parser.add_argument("--repeats", type=int, default=2)
  parser.add_argument("--iterations", nargs="*", type=_pair,
                      default=list(ITERATIONS), metavar="I/L",
                      help="solver/line-search iteration pairs to try, e.g. 10/10 10/4 "
                           "(default: 100/50 10/10 4/8; with --measure speed put 100/50 "
                           "first: the speed-ups are over the first)")
  parser.add_argument("--out", default=common.default_results_path("solver_sweep"))
  args = parser.parse_args(argv)
  writer = common.ResultWriter(args.out)
  key = jax.random.PRNGKey(0)

  for name in args.tasks:
    if args.measure == "speed":
      qpos, qvel = start_states(name, args.num_envs, key)
      first_sps = first = None
    else:
      ref = parity_error.load_reference(args.reference, name)
    for settings in candidates(name, args.iterations):
      env = tasks.make(name, physics=settings)
      record = {"kind": "solver_sweep", "task": name, "measured": args.measure,
                "settings": {"solver": vars(settings), "n_substeps": env.n_substeps}}
      if args.measure == "speed":
        data = env_throughput.copy_tree(jax.vmap(  # own buffers: the timed calls donate them
            lambda q, v: mjx.make_data(env.mjx_model).replace(qpos=q, qvel=v))(qpos, qvel))
        raw_sps, compile_s = common.time_compiled(
            env_throughput.raw_fn(env, args.num_envs, args.steps), (data, key), args.steps,
            args.num_envs, args.repeats)
        if first is None:  # the first candidate (dm_control's settings by default)
          first_sps, first = raw_sps, describe(settings)
        record["settings"].update(num_envs=args.num_envs, steps=args.steps,
                                  repeats=args.repeats)
        writer.write(**record, raw_sps=raw_sps, speedup_over_first=raw_sps / first_sps,
                     first=first, compile_s=compile_s)
        print(f"{name:<16}{describe(settings):<16}{raw_sps:>12,.0f} raw steps/s "
              f"({raw_sps / first_sps:.2f}x {first}, compile {compile_s:.0f}s)", flush=True)
        del data
      else:
        result = parity_error.measure(name, settings, ref)
        result.pop("solver")
        record["settings"]["num_transitions"] = len(ref["action"])
        writer.write(**record, precision="float32", **result)
        v = result["qvel_error"]
        print(f"{name:<16}{describe(settings):<16} qvel error median {v['median']:.1e} "
              f"p90 {v['p90']:.1e} max {v['max']:.1e}", flush=True)
  return 0


if __name__ == "__main__":
  sys.exit(main())
