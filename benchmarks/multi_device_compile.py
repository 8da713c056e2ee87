#!/usr/bin/env python3
"""Which multi-device stepping programs XLA compiles and runs, each in its own process.

On two H200s (jax 0.11.2, 2026-11-26) XLA's GPU compiler died with a segmentation fault on
every program that stepped environments per device (`mjx_form.mesh.per_device`, a
`jax.shard_map`), which took the whole benchmark down with it. This script builds each
candidate program in a child process on the first `--devices` devices, so a crash names the
program and the others still run, from the smallest to the loop's own:

  whole_step          one `AutoReset.step` of the batch stepped as one (the default, which ran)
  plain_per_device    `vmap(task.step)` per device (no restart branch)
  step_per_device     one `AutoReset(per_device=True).step` (the restart branch inside)
  rollout_per_device  10 such steps with random actions (the benchmarks' env-only rollout)
  iteration_per_device  a training iteration of one member per device (tiny learner) with
                      `Trainer(per_device_env_steps=True)`, as train_throughput's populations
  toy_while_per_device  no MJX: a vmapped `while_loop` whose batched predicate each device
                      decides alone (shard_map), the pattern of MJX's solver loops
  top_k_per_device    no MJX: `lax.top_k` per device (shard_map), MJX's contact culling until
                      2026-11-26 (now a stable sort, mjx_form.sim.partitionable)

On the two H200s of 2026-11-26 every per-device program crashed, even plain_per_device. To see
where: `--xla_flags=F` (repeatable) runs every program once more per F with F added to
XLA_FLAGS (e.g. `--xla_gpu_enable_command_buffer=` to keep loops out of CUDA graphs), and
`--dump_passes DIR` has each child dump its HLO after every compiler pass into DIR/<program>...;
where a child dies, the last passes dumped are printed and recorded (the pass after them is
where it died).

Each child compiles its program, runs it once and checks the states are finite; the parent
prints `ok` with the compile seconds, or how the child ended (e.g. `signal 11`), and writes
one `kind: compile_check` record per program.

  python benchmarks/multi_device_compile.py --task cheetah_run --devices 2 --num_envs 1024
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

PROGRAMS = ("whole_step", "plain_per_device", "step_per_device", "rollout_per_device",
            "iteration_per_device", "toy_while_per_device", "top_k_per_device")


def build(program: str, task: str, devices: int, num_envs: int):
  """(jitted fn, its arguments, fn's output -> its environments' observations) of `program`
  for `num_envs` environments of `task` on the first `devices` devices."""
  import jax

  import tasks
  from env_throughput import ours_fn
  from mjx_form import mesh as mesh_lib
  from mjx_form.rl.learner import LearnerConfig
  from mjx_form.rl.train import TrainConfig, Trainer
  from mjx_form.sim.wrappers import AutoReset
  if jax.device_count() < devices:
    raise SystemExit(f"{devices} devices asked for, {jax.device_count()} here")
  mesh = mesh_lib.make_mesh(jax.devices()[:devices])
  if program == "toy_while_per_device":  # x -> how many halvings bring it below 1
    import jax.numpy as jnp
    batch = mesh_lib.batch_sharding(mesh)

    def halvings(x):
      return jax.lax.while_loop(lambda c: c[0] >= 1.0, lambda c: (c[0] / 2, c[1] + 1.0),
                                (x, jnp.float32(0.0)))[1]
    x = jax.device_put(jnp.exp2(jnp.arange(num_envs, dtype=jnp.float32) % 20), batch)
    return jax.jit(mesh_lib.per_device(jax.vmap(halvings), batch)), (x,), lambda out: out
  if program == "top_k_per_device":  # the 4 smallest of 19 distances per environment
    import jax.numpy as jnp
    batch = mesh_lib.batch_sharding(mesh)
    x = jax.device_put(jax.random.normal(jax.random.PRNGKey(0), (num_envs, 19)), batch)
    smallest = mesh_lib.per_device(jax.vmap(lambda d: jax.lax.top_k(-d, 4)[1]), batch)
    return jax.jit(smallest), (x,), lambda out: out
  if program == "iteration_per_device":
    config = TrainConfig(task=task, num_envs=num_envs // devices, unroll_length=10,
                         batch_size=2 * devices, replay_capacity=num_envs, updates_per_iteration=2,
                         network_width=32, eval_envs=devices,
                         learner=LearnerConfig(num_action_samples=4))
    trainer = Trainer(config, mesh, seeds=tuple(range(devices)), per_device_env_steps=True)
    return trainer.iteration, (trainer.init(trainer.keys()),), lambda out: out[0].env.obs
  env = tasks.make(task)
  batch = mesh_lib.batch_sharding(mesh)
  start = mesh_lib.shard_batch(jax.jit(lambda k: AutoReset(env).reset(k, num_envs))(
      jax.random.PRNGKey(0)), mesh)
  key = jax.random.PRNGKey(1)
  observed = lambda state: state.obs
  if program == "rollout_per_device":
    auto_reset = AutoReset(env, batch, per_device=True)
    return ours_fn(env, num_envs, 10, auto_reset), (start, key), observed
  actions = jax.device_put(jax.random.uniform(key, (num_envs, env.action_size), minval=-1.0,
                                              maxval=1.0), batch)
  if program == "plain_per_device":
    step = mesh_lib.per_device(jax.vmap(env.step), batch)
  else:
    step = AutoReset(env, batch, per_device=program == "step_per_device").step
  return jax.jit(step, out_shardings=batch), (start, actions), observed


def child(program: str, task: str, devices: int, num_envs: int) -> int:
  """Compiles and runs `program` once; 0 where its environments' observations come out
  finite."""
  import jax
  import numpy as np
  fn, args, observed = build(program, task, devices, num_envs)
  t0 = time.perf_counter()
  exe = fn.lower(*args).compile()
  print(f"compiled in {time.perf_counter() - t0:.1f}s", flush=True)
  out = jax.block_until_ready(exe(*args))
  return 0 if np.isfinite(np.asarray(observed(out))).all() else 3


def ended(returncode: int) -> str:
  """How a child ended, in words."""
  if returncode == 0:
    return "ok"
  if returncode < 0:
    name = signal.Signals(-returncode).name if -returncode in signal.valid_signals() else "?"
    return f"signal {-returncode} ({name})"
  return "non-finite states" if returncode == 3 else f"exit status {returncode}"


def last_passes(folder: str, count: int = 3) -> list[str]:
  """The names of the last `count` HLO dumps written under `folder` (oldest first)."""
  if not os.path.isdir(folder):
    return []
  files = [os.path.join(folder, name) for name in os.listdir(folder)]
  files = sorted((f for f in files if os.path.isfile(f)), key=lambda f: (os.path.getmtime(f), f))
  return [os.path.basename(f) for f in files[-count:]]


def dump_folder(root: str, program: str, variant: int) -> str:
  return os.path.join(root, f"{program}_{variant}")


def check(program: str, extra: str, variant: int, args, writer) -> str:
  """Runs `program` in a child with `extra` added to XLA_FLAGS: prints and records how it
  ended."""
  command = [sys.executable, os.path.abspath(__file__), "--child", program, "--task",
             args.task, "--devices", str(args.devices), "--num_envs", str(args.num_envs)]
  flags = extra
  dump = None
  if args.dump_passes:
    dump = dump_folder(args.dump_passes, program, variant)
    flags = f"{extra} --xla_dump_to={dump} --xla_dump_hlo_pass_re=.*".strip()
  env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} {flags}".strip())
  t0 = time.perf_counter()
  output = ""
  try:
    done = subprocess.run(command, capture_output=True, text=True, timeout=args.timeout,
                          env=env)
    outcome, output = ended(done.returncode), done.stdout + done.stderr
  except subprocess.TimeoutExpired:
    outcome = f"timed out after {args.timeout:.0f}s"
  seconds = time.perf_counter() - t0
  compiled = re.search(r"compiled in ([\d.]+)s", output)
  compile_s = float(compiled.group(1)) if compiled else None
  passes = last_passes(dump) if dump and outcome != "ok" else []
  print(f"{args.task} {program} on {args.devices} device(s), {args.num_envs} envs"
        + (f", XLA_FLAGS + {extra!r}" if extra else "") + f": {outcome}"
        + (f" (compile {compile_s:.0f}s)" if compile_s is not None else "")
        + f", {seconds:.0f}s in all", flush=True)
  if outcome != "ok" and output.strip():
    print("  " + output.strip()[-400:].replace("\n", "\n  "), flush=True)
  if passes:
    print("  last passes dumped: " + ", ".join(passes), flush=True)
  writer.write(kind="compile_check", task=args.task, program=program, devices=args.devices,
               num_envs=args.num_envs, outcome=outcome, compile_s=compile_s, seconds=seconds,
               xla_flags_added=extra, last_passes=passes,
               settings={"programs": args.programs, "timeout": args.timeout,
                         "xla_flags": args.xla_flags, "dump_passes": args.dump_passes})
  return outcome


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", default="cheetah_run")
  parser.add_argument("--devices", type=int, default=2)
  parser.add_argument("--num_envs", type=int, default=1024)
  parser.add_argument("--programs", nargs="*", default=list(PROGRAMS), choices=PROGRAMS)
  parser.add_argument("--timeout", type=float, default=300.0, help="seconds per program")
  parser.add_argument("--xla_flags", action="append", default=[], metavar="F",
                      help="also run every program with F added to XLA_FLAGS (repeatable; "
                           "written --xla_flags=F, as F starts with --)")
  parser.add_argument("--dump_passes", default=None, metavar="DIR",
                      help="children dump their HLO after every compiler pass under DIR")
  parser.add_argument("--child", choices=PROGRAMS, help=argparse.SUPPRESS)
  parser.add_argument("--out", default=common.default_results_path("compile_check"))
  args = parser.parse_args(argv)
  configure_cpu_xla()
  if args.child:
    return child(args.child, args.task, args.devices, args.num_envs)
  # The parent only names the devices: it leaves their memory to the children.
  os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
  import jax

  import tasks
  if args.task not in tasks.TASKS:
    parser.error(f"unknown task {args.task!r}; valid tasks: {', '.join(tasks.TASKS)}")
  if not 1 <= args.devices <= jax.device_count() or args.num_envs % args.devices:
    parser.error(f"--devices {args.devices} of {jax.device_count()}, with --num_envs "
                 f"{args.num_envs} a multiple of it")
  variants = list(enumerate([""] + args.xla_flags))
  if args.dump_passes:  # (a dump left from another run would be read as this one's last passes)
    if os.path.exists(args.dump_passes) and not os.path.isdir(args.dump_passes):
      parser.error(f"--dump_passes {args.dump_passes} is not a folder")
    used = [d for d in (dump_folder(args.dump_passes, p, v) for v, _ in variants
                        for p in args.programs) if os.path.isdir(d) and os.listdir(d)]
    if used:
      parser.error(f"--dump_passes: {', '.join(used)} already hold dumps (nothing was run)")
  writer = common.ResultWriter(args.out)
  for variant, extra in variants:
    for program in args.programs:
      check(program, extra, variant, args, writer)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
