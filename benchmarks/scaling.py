#!/usr/bin/env python3
"""Scaling over the devices of one host: total env steps per second of the whole training
iteration, and of env-only stepping, on the first 1, 2, 4, ... devices.

Modes (`--modes`):
  weak        one run with `--envs_per_device` environments, `--batch_size` unrolls per learner
              batch and `--replay_capacity` unrolls of replay per device: its batches are split
              over the devices (the mesh of mjx_form/mesh.py: parameters replicated, gradients
              reduced over devices);
  population  `--members_per_device` members per device (`Trainer(..., seeds=range(P))`), each
              with `--envs_per_member` environments; by default whole members per device
              (layout "members"), with `--layout environments` each member's environments,
              replay and batches split over the devices (mjx_form.rl.train.LAYOUTS).
Each measurement is the best of `--repeats` calls after a warm-up (compile times apart) and is
printed as it ends, so a run cut off by a time limit still says what it measured; each writes
a `kind: scaling` record: devices, mode, layout, total env steps/s of the iteration and of
env-only stepping (stepped as the loop steps them: the batch as one program-wide batch; with
`--per_device_env_steps` each device stepping its own part, loop and env-only alike, and on
several devices the batch stepped as one measured beside it), peak memory of
the busiest device so far in this process (run one device count per process for a clean
peak). The iteration's split into collection and updates: benchmarks/train_throughput.py.
Efficiency (steps/s on N devices over N x one device's) is computed where the table is made
(scripts/report.py).

  python benchmarks/scaling.py --tasks humanoid_run cheetah_run --devices 1 2 4 8
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402

import tasks  # noqa: E402
from mjx_form import mesh as mesh_lib  # noqa: E402
from mjx_form.files import results  # noqa: E402
from mjx_form.rl.learner import LearnerConfig  # noqa: E402
from mjx_form.rl.train import LAYOUTS, Trainer, TrainConfig  # noqa: E402
from mjx_form.sim.physics import DEFAULT_PHYSICS, PHYSICS_MODES  # noqa: E402
from train_throughput import env_only_fn, time_iterations  # noqa: E402

MODES = ("weak", "population")


def trainer_for(mode: str, task: str, devices: int, args) -> Trainer:
  """The run (weak) or population measured on the first `devices` devices."""
  mesh = mesh_lib.make_mesh(jax.devices()[:devices])
  scale = devices if mode == "weak" else 1  # weak: amounts per device
  config = TrainConfig(task=task, physics=args.physics,
                       num_envs=(args.envs_per_device * devices if mode == "weak"
                                 else args.envs_per_member),
                       unroll_length=args.unroll_length, batch_size=args.batch_size * scale,
                       replay_capacity=args.replay_capacity * scale,
                       updates_per_iteration=args.updates_per_iteration,
                       network_width=args.network_width, eval_envs=devices,
                       learner=dataclasses.replace(
                           LearnerConfig(), num_action_samples=args.num_action_samples,
                           target_update_period=args.target_update_period,
                           sampled_q_bfloat16=args.sampled_q_bfloat16))
  members = args.members_per_device * devices if mode == "population" else 1
  return Trainer(config, mesh, seeds=tuple(range(members)),
                 layout=args.layout if mode == "population" else None,
                 per_device_env_steps=args.per_device_env_steps)


def measure(trainer: Trainer, mode: str, args, writer, key) -> dict:
  """Env-only stepping and the whole iteration of `trainer`: one record, printed by phase."""
  config, members, devices = trainer.config, trainer.members, trainer.mesh.devices.size
  label = f"{config.task} {mode} on {devices} device(s)" + (
      f" ({trainer.layout})" if mode == "population" and devices > 1 else "")
  steps, per_iteration = config.unroll_length, config.env_steps_per_iteration * members
  whole = {}
  if trainer.per_device_env_steps and devices > 1:  # the batch stepped as one beside it, first
    env_only, start = env_only_fn(trainer, steps, key, per_device=False)
    whole["env_whole_batch_sps"], _ = common.time_compiled(
        env_only, (start, key), steps, config.num_envs * members, args.repeats)
    print(f"{label}: env only, the batch stepped as one: {whole['env_whole_batch_sps']:,.0f} "
          "steps/s", flush=True)
    label += ", per device"
  env_only, start = env_only_fn(trainer, steps, key)
  env_sps, env_compile_s = common.time_compiled(env_only, (start, key), steps,
                                                config.num_envs * members, args.repeats)
  print(f"{label}: env only {env_sps:,.0f} steps/s (compile {env_compile_s:.0f}s)", flush=True)
  state = trainer.init(trainer.keys())
  iteration_s, compile_s, _ = time_iterations(trainer, state, args.repeats)
  record = {"mode": mode, "devices": devices, "members": members, "layout": trainer.layout,
            "num_envs": config.num_envs, "total_envs": config.num_envs * members,
            "sps": per_iteration / iteration_s, "env_sps": env_sps,
            "iteration_s": iteration_s,
            "peak_memory_bytes": results.peak_memory_bytes(), "compile_s": compile_s,
            "env_compile_s": env_compile_s, **whole}
  if trainer.per_device_env_steps:
    record["per_device_env_steps"] = True
  settings = {**config.to_dict(), "repeats": args.repeats}
  writer.write(kind="scaling", task=config.task, method="expert", physics=config.physics,
               settings=settings, **record)
  memory = record["peak_memory_bytes"]
  print(f"{label}: iteration {record['sps']:,.0f} steps/s ({iteration_s:.3f} s), "
        f"{record['total_envs']} envs in {members} member(s), peak memory "
        f"{'n/a' if memory is None else f'{memory / 2**30:.1f} GiB'} (compile {compile_s:.0f}s)",
        flush=True)
  return record


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  defaults = TrainConfig()
  parser.add_argument("--tasks", nargs="*", default=["humanoid_run", "cheetah_run"],
                      choices=tasks.TASKS, metavar="TASK")
  parser.add_argument("--devices", nargs="*", type=int, default=None,
                      help="device counts to measure (default: 1, 2, 4, ... up to all)")
  parser.add_argument("--modes", nargs="*", default=list(MODES), choices=MODES)
  parser.add_argument("--envs_per_device", type=int, default=2048, help="weak scaling")
  parser.add_argument("--members_per_device", type=int, default=2, help="population")
  parser.add_argument("--envs_per_member", type=int, default=512, help="population")
  parser.add_argument("--layout", default=None, choices=LAYOUTS,
                      help="population: how its members lie on the devices (default: whole "
                           "members per device)")
  parser.add_argument("--physics", default=DEFAULT_PHYSICS, choices=PHYSICS_MODES)
  parser.add_argument("--unroll_length", type=int, default=defaults.unroll_length)
  parser.add_argument("--batch_size", type=int, default=defaults.batch_size,
                      help="unrolls per learner batch (weak: per device; population: per member)")
  parser.add_argument("--replay_capacity", type=int, default=defaults.replay_capacity,
                      help="unrolls of replay (weak: per device; population: per member)")
  parser.add_argument("--updates_per_iteration", type=int,
                      default=defaults.updates_per_iteration)
  parser.add_argument("--network_width", type=int, default=defaults.network_width)
  parser.add_argument("--num_action_samples", type=int,
                      default=defaults.learner.num_action_samples,
                      help="actions per state the target critic evaluates in an update")
  parser.add_argument("--target_update_period", type=int,
                      default=defaults.learner.target_update_period)
  parser.add_argument("--sampled_q_bfloat16", action="store_true",
                      help="the target critic's Q of the sampled actions in bfloat16 (FORM's "
                           "default learner); by default float32, the paper's")
  parser.add_argument("--per_device_env_steps", action="store_true",
                      help="each device steps its own environments (a shard_map: Trainer's "
                           "per_device_env_steps), and on several devices env-only stepping "
                           "with the batch stepped as one is measured beside it; default: the "
                           "batch stepped as one (every solver iteration and restart branch "
                           "agreed over all devices)")
  parser.add_argument("--repeats", type=int, default=3)
  parser.add_argument("--out", default=common.default_results_path("scaling"))
  args = parser.parse_args(argv)
  available = jax.device_count()
  counts = args.devices or [n for n in (1, 2, 4, 8, 16) if n <= available]
  for n in counts:
    if not 1 <= n <= available:
      parser.error(f"--devices {n}: this host has {available} device(s)")
  writer = common.ResultWriter(args.out)
  key = jax.random.PRNGKey(0)
  for task in args.tasks:
    for mode in args.modes:
      for n in counts:
        try:
          trainer = trainer_for(mode, task, n, args)
        except ValueError as e:  # sizes that do not split over n devices
          parser.error(f"{task} {mode} on {n} device(s): {e}")
        measure(trainer, mode, args, writer, key)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
