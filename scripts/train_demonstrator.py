#!/usr/bin/env python3
"""Trains FORM demonstrator effect models (the first stage of `run.py --method form`, alone).

  python scripts/train_demonstrator.py --task cheetah_run --out tasks/demonstrators/cheetah_run.npz
  python scripts/train_demonstrator.py --task walker_walk --demos demos/walker_walk.npz \\
      --beta_ar 0.01,0.1,1 --effect_l2 0.01,0.1,1 --out runs/walker_grid/   # a grid

Demonstrations are recorded from the expert (shipped, or --expert) on the device, or read from
--demos. With several values of --beta_ar / --effect_l2, every combination is trained on the
same demonstrations and written to the folder --out as <task>_ar<beta_ar>_l2<l2>.npz (with
`_turn` before `.npz` for turn-invariant models: reacher_hard's by default). With several
--seeds (one setting), draws of those seeds are trained side by side in one program on the
same demonstrations (recorded with the first seed) and written to the folder --out as
<task>_seed<s>.npz. Each training appends a `kind: effect_model` record (held-out
log-likelihood per offset, steps, the held-out curve) to --results.

  python scripts/train_demonstrator.py --task reacher_hard --seeds 0,1,2,3,4,5 --out runs/draws/

`--max_seconds` is the budget of the script from the start of `main` (after its imports):
recording the demonstrations (on a GPU, 1000 quadruped episodes take ~100 s with compilation)
and every training; a grid's trainings share what is left equally, and each stops at its first
evaluation past its share, then writes its file. Under a hard limit (a GPU call's), leave room
for the imports, one evaluation interval and the writing.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import tasks  # noqa: E402
from mjx_form.imitation import demonstrator, pipeline, settings  # noqa: E402
from mjx_form.sim.physics import DEFAULT_PHYSICS, PHYSICS_MODES  # noqa: E402


def _floats(text: str) -> list[float]:
  try:
    return [float(v) for v in text.split(",")]
  except ValueError:
    raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def training_budget(max_seconds: float | None, elapsed: float, trainings_left: int
                    ) -> float | None:
  """The seconds the next of `trainings_left` trainings may take, when `max_seconds` counts
  from the script's start, `elapsed` seconds ago: an equal share of what is left (0 when none
  is: the training then stops at its first evaluation)."""
  if max_seconds is None:
    return None
  return max(0.0, (max_seconds - elapsed) / trainings_left)


def main(argv=None) -> int:
  started = time.perf_counter()  # --max_seconds counts from here
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", required=True)
  parser.add_argument("--out", required=True,
                      help="the file to write (a folder for a grid or several --seeds)")
  parser.add_argument("--expert", help="policy.npz to record (default: the shipped expert)")
  parser.add_argument("--demos", help="demonstrations to train on instead of recording them")
  parser.add_argument("--episodes", type=int, default=pipeline.DEFAULT_TRAINING_EPISODES,
                      help="episodes to record")
  parser.add_argument("--physics", default=DEFAULT_PHYSICS, choices=PHYSICS_MODES)
  parser.add_argument("--beta_ar", type=_floats, default=None,
                      help="autoregressive weight(s) (default: the task's, settings.py)")
  parser.add_argument("--effect_l2", type=_floats, default=None, help="L2 weight(s)")
  parser.add_argument("--width", type=int, default=256)
  parser.add_argument("--turn_invariant", action=argparse.BooleanOptionalAction, default=None,
                      help="a model blind to full turns of the task's raw unbounded angles "
                           "(mjx_form/imitation/effect_model.py), or not (default: the task's "
                           "setting, mjx_form/imitation/settings.py)")
  parser.add_argument("--angle_increments", action=argparse.BooleanOptionalAction, default=None,
                      help="a turn-invariant model predicts each periodic angle's change, not "
                           "its value (mjx_form/imitation/effect_model.py; default: the task's "
                           "setting, off)")
  parser.add_argument("--angle_inputs", action=argparse.BooleanOptionalAction, default=None,
                      help="a model with --angle_increments sees each periodic angle as its cos "
                           "and sin, not its wrapped value (mjx_form/imitation/effect_model.py; "
                           "default: the task's setting, off)")
  parser.add_argument("--effect_max_scale", type=float, default=None,
                      help="soft cap on the mixture's scales, in standardised units "
                           "(mjx_form/imitation/effect_model.py; default: none, the paper's)")
  defaults = demonstrator.DemonstratorTraining()
  for name in ("max_steps", "batch_size", "window", "eval_every", "patience", "smoothing"):
    parser.add_argument(f"--{name}", type=int, default=getattr(defaults, name))
  parser.add_argument("--max_seconds", type=float, default=None,
                      help="time budget of the whole script, demonstrations' recording "
                           "included; a grid's trainings share what is left")
  parser.add_argument("--seed", type=int, default=None, help="(default 0)")
  parser.add_argument("--seeds", default=None,
                      help="comma-separated seeds: draws trained side by side (one setting; "
                           "the demonstrations recorded with the first)")
  parser.add_argument("--results", default=None, help="append kind=effect_model records here")
  args = parser.parse_args(argv)
  if args.task not in tasks.TASKS:
    parser.error(f"unknown task {args.task!r}; valid tasks: {', '.join(tasks.TASKS)}")
  if args.max_seconds is not None and not args.max_seconds > 0:
    parser.error(f"--max_seconds must be positive, got {args.max_seconds}")
  grid = list(itertools.product(args.beta_ar or [None], args.effect_l2 or [None]))
  if args.seeds is not None and args.seed is not None:
    parser.error("--seed and --seeds exclude each other")
  try:
    seeds = [int(v) for v in args.seeds.split(",")] if args.seeds else [args.seed or 0]
  except ValueError:
    parser.error(f"--seeds: expected comma-separated integers, got {args.seeds!r}")
  if len(set(seeds)) != len(seeds):
    parser.error(f"--seeds must be distinct, got {args.seeds!r}")
  if len(seeds) > 1 and len(grid) > 1:
    parser.error("--seeds trains draws of one setting: give one --beta_ar and one --effect_l2")
  if len(seeds) > 1 and os.path.exists(args.out) and not os.path.isdir(args.out):
    parser.error(f"--out {args.out} is a file; several --seeds write to a folder")
  env = tasks.make(args.task, physics=args.physics)
  try:
    period = settings.turn_period(env, args.turn_invariant)
    configs = [settings.effect_model_config(args.task, env, width=args.width, beta_ar=b, l2=l,
                                            period=period,
                                            angle_increments=args.angle_increments,
                                            angle_inputs=args.angle_inputs,
                                            max_scale=args.effect_max_scale)
               for b, l in grid]
  except ValueError as e:
    parser.error(str(e))
  if len(seeds) > 1:  # draws of one setting, named by seed
    outs = [os.path.join(args.out, f"{args.task}_seed{seed}.npz") for seed in seeds]
  elif len(grid) > 1:  # a grid, named by setting
    outs = [os.path.join(args.out, f"{args.task}_ar{c.beta_ar:g}_l2{c.l2:g}"
                                   f"{'_turn' if c.period else ''}"
                                   f"{'_increments' if c.angle_increments else ''}"
                                   f"{'_angle_inputs' if c.angle_inputs else ''}"
                                   f"{f'_max_scale{c.max_scale:g}' if c.max_scale else ''}.npz")
            for c in configs]
  else:
    outs = [args.out]
  existing = [o for o in outs if os.path.exists(o)]
  if existing:
    print(f"error: {', '.join(existing)} exist (nothing was overwritten)", file=sys.stderr)
    return 2
  say = lambda line: print(line, flush=True)
  try:
    training = demonstrator.DemonstratorTraining(
        max_steps=args.max_steps, batch_size=args.batch_size, window=args.window,
        eval_every=args.eval_every, patience=args.patience, smoothing=args.smoothing,
        seed=seeds[0],
        max_seconds=args.max_seconds)
    artefacts = pipeline.Artefacts(expert=args.expert, demos=args.demos)
    obs, info = pipeline.demonstrations(env, artefacts, args.episodes, args.physics, seeds[0],
                                        say)
    training.check(len(obs), obs.shape[1] - 1)
    if args.max_seconds is not None:
      spent = time.perf_counter() - started
      say(f"--max_seconds {args.max_seconds:g}: {spent:.0f}s spent before training, "
          f"{training_budget(args.max_seconds, spent, 1):.0f}s left for it")
    share = lambda left: dataclasses.replace(training, max_seconds=training_budget(
        args.max_seconds, time.perf_counter() - started, left))
    if len(seeds) > 1:
      os.makedirs(args.out, exist_ok=True)
      files = pipeline.train_demonstrators(env, configs[0], obs, info, share(1), args.physics,
                                           tuple(seeds), args.results, say, outs)
      for seed, file in zip(seeds, files):
        say(f"seed {seed}: held-out log-likelihood by offset: "
            f"{file.metadata['training']['heldout_log_likelihood']}")
      return 0
    for i, (config, out) in enumerate(zip(configs, outs)):
      say(f"training with beta_ar={config.beta_ar}, l2={config.l2} -> {out}")
      os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
      file = pipeline.train_demonstrator(env, config, obs, info, share(len(configs) - i),
                                         args.physics, seeds[0], args.results, say, out)
      heldout = file.metadata["training"]["heldout_log_likelihood"]
      say(f"held-out log-likelihood by offset: {heldout}")
  except ValueError as e:
    print(f"error: {e}", file=sys.stderr)
    return 2
  return 0


if __name__ == "__main__":
  sys.exit(main())
