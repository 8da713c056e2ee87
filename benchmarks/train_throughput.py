#!/usr/bin/env python3
"""End-to-end environment steps per second of the training loop, beside env-only throughput.

For each task and size, in one process over all visible devices (the trainer's mesh: environments
split over devices, parameters replicated; the env-only rollout is split the same way), it times:
  - env:     `AutoReset(task).step` with uniform random actions, `unroll_length` steps per
             jitted call (what env_throughput.py calls "ours");
  - collect: the loop's collection alone (policy network + env step, unrolls out);
  - loop:    one whole `Trainer.iteration`: collect, normaliser, replay insert and
             `updates_per_iteration` MPO/Retrace updates;
and records the peak device memory of the process (run one size per process for a clean
peak: the peak only grows within a process). Each is timed as the best of `--repeats` calls
after a warm-up call; compile times are recorded apart.

  python benchmarks/train_throughput.py --tasks humanoid_run cheetah_run --num_envs 2048

With `--members 1 2 4 8 16` it measures populations (`Trainer(..., seeds=range(P))`: P runs of
`--num_envs` environments each in one program) and writes `kind: population_throughput`
records: total env steps per second of the whole iteration over all members, the env-only
rollout of all P x N environments, and the split into collection and updates. Over several
devices (all visible ones; `CUDA_VISIBLE_DEVICES=0` for one GPU of the same host) the
population takes the trainer's default layout, whole members per device where they split
evenly (`--layout` chooses: mjx_form.rl.train.LAYOUTS); the records say which.
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

import tasks  # noqa: E402
from env_throughput import ours_fn  # noqa: E402
from mjx_form import mesh as mesh_lib  # noqa: E402
from mjx_form.files import results  # noqa: E402
from mjx_form.sim.physics import DEFAULT_PHYSICS, PHYSICS_MODES  # noqa: E402
from mjx_form.rl.learner import LearnerConfig  # noqa: E402
from mjx_form.rl.train import LAYOUTS, Trainer, TrainConfig  # noqa: E402
from mjx_form.sim.wrappers import AutoReset  # noqa: E402


def env_only_fn(trainer: Trainer, steps: int, key, per_device: bool | None = None):
  """(jitted `run(state, key)`, start state): `steps` calls of `AutoReset(task).step` with
  random actions for the trainer's environments (all members'), split over its mesh as the
  loop's are and stepped as the loop steps them (`per_device` None), or with `per_device`
  True / False each device stepping its own part / the whole batch as one
  (mjx_form.sim.wrappers.AutoReset)."""
  if per_device is None:
    per_device = trainer.per_device_env_steps
  num_envs, mesh = trainer.config.num_envs * trainer.members, trainer.mesh
  start = jax.jit(lambda k: AutoReset(trainer.env).reset(k, num_envs))(key)
  auto_reset = AutoReset(trainer.env, mesh_lib.batch_sharding(mesh), per_device=per_device)
  run = jax.jit(ours_fn(trainer.env, num_envs, steps, auto_reset), donate_argnums=0,
                in_shardings=(mesh_lib.batch_sharding(mesh), mesh_lib.replicated(mesh)),
                out_shardings=mesh_lib.batch_sharding(mesh))
  return run, mesh_lib.shard_batch(start, mesh)


def time_iterations(trainer: Trainer, state, repeats: int):
  """(seconds per iteration, compile seconds, state); the state is donated call to call."""
  t0 = time.perf_counter()
  exe = trainer.iteration.lower(state).compile()
  compile_s = time.perf_counter() - t0
  holder = [jax.block_until_ready(exe(state)[0])]  # warm-up

  def call():
    holder[0] = jax.block_until_ready(exe(holder[0]))[0]
  return common.best_time(call, repeats), compile_s, holder[0]


def time_collect(trainer: Trainer, state, repeats: int):
  """(seconds per collection of num_envs x unroll_length steps, compile seconds)."""
  collect = jax.jit(lambda s, k: trainer._collect(s, k)[0])  # env states out only
  key = trainer.keys(1)
  t0 = time.perf_counter()
  exe = collect.lower(state, key).compile()
  compile_s = time.perf_counter() - t0
  jax.block_until_ready(exe(state, key))  # warm-up
  return common.best_time(lambda: jax.block_until_ready(exe(state, key)), repeats), compile_s


def measure(trainer: Trainer, label: str, kind: str, args, writer, key) -> None:
  """Times env-only stepping, collection and the whole iteration of `trainer`; one record."""
  config, members = trainer.config, trainer.members
  steps, per_iteration = config.unroll_length, config.env_steps_per_iteration * members
  env_sps = env_compile_s = None
  if not args.skip_env_only:
    env_only, start = env_only_fn(trainer, steps, key)
    env_sps, env_compile_s = common.time_compiled(env_only, (start, key), steps,
                                                  config.num_envs * members, args.repeats)
    # Each phase is printed as it ends, so a run stopped by a time limit shows how far it got.
    print(f"{label}: env only {env_sps:,.0f} steps/s (compile {env_compile_s:.0f}s)", flush=True)
  state = trainer.init(trainer.keys())
  collect_s, collect_compile_s = time_collect(trainer, state, args.repeats)
  print(f"{label}: collect {per_iteration / collect_s:,.0f} steps/s "
        f"(compile {collect_compile_s:.0f}s)", flush=True)
  iteration_s, loop_compile_s, state = time_iterations(trainer, state, args.repeats)
  result = {
      "sps": per_iteration / iteration_s, "env_sps": env_sps,
      "collect_sps": per_iteration / collect_s,
      "ratio_to_env": None if env_sps is None else per_iteration / iteration_s / env_sps,
      "iteration_s": iteration_s, "collect_s": collect_s,
      "update_ms": 1e3 * max(iteration_s - collect_s, 0.0) / config.updates_per_iteration,
      "peak_memory_bytes": results.peak_memory_bytes(), "compile_s": loop_compile_s,
      "env_compile_s": env_compile_s, "collect_compile_s": collect_compile_s}
  settings = {**config.to_dict(), "updates_per_env_step": config.updates_per_env_step,
              "replay_ratio": config.replay_ratio, "repeats": args.repeats}
  fields = ({"members": members, "devices": trainer.mesh.devices.size,
             "layout": trainer.layout} if kind == "population_throughput" else {})
  if trainer.per_device_env_steps:
    fields["per_device_env_steps"] = True
  writer.write(kind=kind, task=config.task, method="expert", physics=config.physics,
               num_envs=config.num_envs, settings=settings, **fields, **result)
  memory = result["peak_memory_bytes"]
  env = "n/a" if env_sps is None else f"{env_sps:,.0f} (ratio {result['ratio_to_env']:.2f})"
  print(f"{label}: loop {result['sps']:,.0f} steps/s, env only {env}, "
        f"collect {result['collect_sps']:,.0f}, "
        f"{result['update_ms']:.1f} ms/update (all members), peak memory "
        f"{'n/a' if memory is None else f'{memory / 2**30:.1f} GiB'} (compile "
        f"{loop_compile_s:.0f}s)", flush=True)


def train_config(args, task: str, num_envs: int) -> TrainConfig:
  """The measured run's settings: the defaults, with the command line's."""
  return TrainConfig(task=task, physics=args.physics, num_envs=num_envs,
                     updates_per_iteration=args.updates_per_iteration,
                     stagger_episodes=not args.lockstep_episodes,
                     learner=LearnerConfig(sampled_q_bfloat16=args.sampled_q_bfloat16))


def parse_args(argv=None) -> argparse.Namespace:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--tasks", nargs="*", default=["humanoid_run", "cheetah_run"],
                      choices=tasks.TASKS, metavar="TASK")
  parser.add_argument("--num_envs", nargs="*", type=int, default=[2048])
  parser.add_argument("--physics", default=DEFAULT_PHYSICS, choices=PHYSICS_MODES)
  parser.add_argument("--updates_per_iteration", type=int,
                      default=TrainConfig.updates_per_iteration)
  parser.add_argument("--lockstep_episodes", action="store_true",
                      help="start every environment's first episode together (default: staggered "
                      "phases, whose resets then run in every iteration)")
  parser.add_argument("--members", nargs="*", type=int, default=None,
                      help="population sizes to measure (kind population_throughput)")
  parser.add_argument("--layout", default=None, choices=LAYOUTS,
                      help="how a population lies on several devices (default: whole members "
                           "per device where they split evenly)")
  parser.add_argument("--sampled_q_bfloat16", action="store_true",
                      help="the learner's Q of the sampled actions in bfloat16 (LearnerConfig)")
  parser.add_argument("--per_device_env_steps", action="store_true",
                      help="each device steps its own environments (Trainer's "
                           "per_device_env_steps; default: the batch stepped as one)")
  parser.add_argument("--repeats", type=int, default=3)
  parser.add_argument("--skip_env_only", action="store_true",
                      help="skip the env-only rollout (its compile costs ~35 s per size on a GPU)")
  parser.add_argument("--out", default=common.default_results_path("train_throughput"))
  return parser.parse_args(argv)


def main(argv=None) -> int:
  args = parse_args(argv)
  writer = common.ResultWriter(args.out)
  key = jax.random.PRNGKey(0)

  kind = "population_throughput" if args.members else "train_throughput"
  uneven = [p for p in args.members or [] if args.layout == "members" and p % jax.device_count()]
  if uneven:  # refused before anything compiles
    print(f"error: --layout members: populations of {uneven} do not split over the "
          f"{jax.device_count()} devices", file=sys.stderr)
    return 2
  for name in args.tasks:
    for num_envs in args.num_envs:
      for members in args.members or [1]:
        try:
          trainer = Trainer(train_config(args, name, num_envs), seeds=tuple(range(members)),
                            layout=args.layout,
                            per_device_env_steps=args.per_device_env_steps)
        except ValueError as e:  # e.g. members that do not split over the devices
          print(f"error: {name} {num_envs} envs x {members} members: {e}", file=sys.stderr)
          return 2
        label = f"{name} {num_envs} envs" + (
            f" x {members} members ({trainer.layout} over {trainer.mesh.devices.size} "
            "device(s))" if args.members else "")
        measure(trainer, label, kind, args, writer, key)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
