#!/usr/bin/env python3
"""Seconds per evaluation: K policies per member in one call against one.

A run evaluates its online and its average policy every `--eval_every` iterations, and at the
end its final, average and kept policies over `--final_eval_envs` episodes. An episode is 1000
control steps one after the other (walker: 10 physics steps each), so on a GPU an evaluation's
time is set by the latency of its steps more than by its batch: `Trainer.evaluate` steps K
policies' episodes as one batch. This times it, for a population of `--members` of FORM (the
task's effect-model settings, an untrained demonstrator scoring the episodes as a run's does),
as the best of `--repeats` calls after a warm-up call, for each K of `--policies` and each
number of episodes of `--episodes`. Records `kind: evaluation_speed` with `seconds` (per call)
and `seconds_per_policy`.

  python benchmarks/evaluation_speed.py --tasks walker_stand --members 3 --episodes 16 256 \
      --policies 1 2 5
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

import tasks  # noqa: E402
import update_speed  # noqa: E402  (its FORM source of an untrained demonstrator)
from mjx_form.rl.train import Trainer, TrainConfig  # noqa: E402


def time_evaluation(trainer: Trainer, state, policies: int, episodes: int, repeats: int
                    ) -> float:
  """Best seconds of `repeats` calls of `trainer.evaluate` with `policies` copies of the
  state's policy per member over `episodes` episodes each (after a warm-up call: compiled)."""
  args = ((state.learner.policy,) * policies, (state.normalizer,) * policies, trainer.keys(1))
  inputs = {**trainer.evaluation_inputs(state), "num_envs": episodes}
  call = lambda: jax.block_until_ready(trainer.evaluate(*args, **inputs))
  call()
  return common.best_time(call, repeats)


def main(argv: list[str] | None = None) -> None:
  parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
  parser.add_argument("--tasks", nargs="+", default=["walker_stand"])
  parser.add_argument("--members", type=int, default=3)
  parser.add_argument("--episodes", type=int, nargs="+", default=[16, 256])
  parser.add_argument("--policies", type=int, nargs="+", default=[1, 2, 5])
  parser.add_argument("--repeats", type=int, default=2)
  parser.add_argument("--physics", default="fast")
  parser.add_argument("--out", default=None, help="JSON lines file for the records")
  args = parser.parse_args(argv)
  for name in args.tasks:
    if name not in tasks.TASKS:
      parser.error(f"unknown task {name!r}; valid tasks: {', '.join(tasks.TASKS)}")
  for label, values in (("--members", [args.members]), ("--episodes", args.episodes),
                        ("--policies", args.policies), ("--repeats", [args.repeats])):
    if min(values) < 1:
      parser.error(f"{label} must be positive, got {min(values)}")
  writer = common.ResultWriter(args.out)
  for name in args.tasks:
    config = TrainConfig(task=name, num_envs=16, physics=args.physics, reward_source="form")
    env = tasks.make(name, physics=args.physics)
    source = update_speed.form_source(name, env, jax.random.PRNGKey(0))
    trainer = Trainer(config, reward_source=source, seeds=tuple(range(args.members)))
    state = trainer.init(trainer.keys())
    for episodes in args.episodes:
      for k in args.policies:
        seconds = time_evaluation(trainer, state, k, episodes, args.repeats)
        print(f"{name}: {args.members} member(s) x {k} policies x {episodes} episodes: "
              f"{seconds:.2f} s per call, {seconds / k:.2f} s per policy", flush=True)
        writer.write(kind="evaluation_speed", task=name, members=args.members,
                     policies=k, episodes=episodes, physics=args.physics, repeats=args.repeats,
                     seconds=seconds, seconds_per_policy=seconds / k)


if __name__ == "__main__":
  main()
