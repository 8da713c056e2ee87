#!/usr/bin/env python3
"""Control steps per second of our `step`, beside the raw physics and MuJoCo Playground.

For every task, physics mode and batch size it times, on one device, with uniform random
actions drawn on the device:
  - ours: `AutoReset(task).step` (physics, observation, reward, NaN checks, auto-reset);
  - step: with `--unwrapped`, also `vmap(task.step)` without the auto-reset wrapper, to split
          the wrapper's cost from the environment's (field `step_sps`);
  - raw:  a plain `mjx.step` loop (n_substeps per control step) on the same MJX model, solver
          settings and matmul precision (full float32, as our physics), no observation, reward
          or reset: the floor an env step cannot beat
          (measured once per model, settings and size; tasks of a domain share a model);
  - peer: MuJoCo Playground's version of the task (`impl="jax"`, its own settings), where one
          exists (none for quadruped), its unwrapped `step` (JAX's default matmul precision: TF32
          on NVIDIA GPUs).
All three run `--steps` control steps inside one jitted `lax.scan`; the time is the best of
`--repeats` calls after a warm-up call, compile time recorded apart. Tasks go in batches
(`--batch_tasks`) whose functions are compiled in parallel threads (`--compile_threads`); then
the timed calls run one at a time, so no measurement shares the device or the host with a
compile.

  python benchmarks/env_throughput.py --tasks cheetah_run --num_envs 2048 8192
"""

from __future__ import annotations

import argparse
import concurrent.futures
import hashlib
import os
import sys
import threading
import time
import xml.etree.ElementTree as ET

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from mujoco import mjx  # noqa: E402

import tasks  # noqa: E402
from mjx_form.sim import partitionable  # noqa: E402
from mjx_form.sim.physics import PHYSICS_MODES, apply_solver_settings, full_precision  # noqa: E402
from mjx_form.sim.wrappers import AutoReset  # noqa: E402

PEERS = {  # our name -> MuJoCo Playground's name
    "reacher_easy": "ReacherEasy", "reacher_hard": "ReacherHard", "cheetah_run": "CheetahRun",
    "hopper_stand": "HopperStand", "hopper_hop": "HopperHop", "walker_stand": "WalkerStand",
    "walker_walk": "WalkerWalk", "walker_run": "WalkerRun", "humanoid_stand": "HumanoidStand",
    "humanoid_walk": "HumanoidWalk", "humanoid_run": "HumanoidRun",
}


def _tile(tree, times: int):
  """`times` copies of a batched pytree along the batch axis, in new buffers."""
  return copy_tree(jax.tree.map(lambda x: jnp.tile(x, (times,) + (1,) * (x.ndim - 1)), tree))


def copy_tree(tree):
  """Every leaf in a buffer of its own (inputs are donated; no two leaves may share one)."""
  return jax.tree.map(lambda x: jnp.array(x, copy=True), tree)


def _random_actions(key, num_envs, size):
  return jax.random.uniform(key, (num_envs, size), minval=-1.0, maxval=1.0)


def _random_rollout(step, num_envs: int, action_size: int, steps: int):
  """Jitted `run(state, key)`: `steps` calls of batched `step` with uniform random actions
  (state donated)."""
  def run(state, key):
    def body(state, key):
      return step(state, _random_actions(key, num_envs, action_size)), None
    return jax.lax.scan(body, state, jax.random.split(key, steps))[0]
  return jax.jit(run, donate_argnums=0)


def ours_fn(env, num_envs: int, steps: int, auto_reset: AutoReset | None = None):
  """`AutoReset(env).step` (or `auto_reset`'s, e.g. one over a device mesh)."""
  step = (auto_reset or AutoReset(env)).step
  return _random_rollout(step, num_envs, env.action_size, steps)


def step_fn(env, num_envs: int, steps: int):
  """`vmap(env.step)` alone: ours without the auto-reset wrapper."""
  return _random_rollout(jax.vmap(env.step), num_envs, env.action_size, steps)


def raw_fn(env, num_envs: int, steps: int):
  """A plain `mjx.step` loop on `env`'s model (MJX's step with the bounded solve of
  mjx_form.sim.partitionable where `env`'s physics asks for it)."""
  model, n_substeps = env.mjx_model, env.n_substeps
  bounded = env.solver_settings.bounded_solver_loop
  mjx_step = partitionable.step if bounded else mjx.step

  def control_step(data):
    return jax.lax.scan(lambda d, _: (mjx_step(model, d), None), data, None, length=n_substeps)[0]

  @full_precision  # as our step: float32 matmuls at full precision
  def run(data, key):
    def body(data, key):
      data = data.replace(ctrl=_random_actions(key, num_envs, env.action_size))
      return jax.vmap(control_step)(data), None
    return jax.lax.scan(body, data, jax.random.split(key, steps))[0]
  return jax.jit(run, donate_argnums=0)


def peer_fns(name: str, num_envs: int, steps: int):
  from mujoco_playground import registry
  peer = registry.load(PEERS[name], config_overrides={"impl": "jax"})

  reset = jax.jit(lambda key: jax.vmap(peer.reset)(jax.random.split(key, num_envs)))
  cfg = peer._config
  settings = {"ctrl_dt": float(cfg.ctrl_dt), "sim_dt": float(cfg.sim_dt),
              "n_substeps": int(round(cfg.ctrl_dt / cfg.sim_dt)),
              "iterations": int(peer.mj_model.opt.iterations),
              "ls_iterations": int(peer.mj_model.opt.ls_iterations)}
  return reset, _random_rollout(jax.vmap(peer.step), num_envs, peer.action_size, steps), settings


def model_digest(env) -> str:
  """Identifies the compiled MuJoCo model (XML with solver settings applied)."""
  root = env.model_xml()
  apply_solver_settings(root, env.solver_settings)
  xml = ET.tostring(root, encoding="unicode")
  return hashlib.sha256(xml.encode()).hexdigest()[:16]


def raw_key(env, num_envs: int, steps: int) -> tuple:
  """What a raw loop's measurement depends on: tasks with the same key share one (the tasks of
  a domain, at the same solver settings and loop)."""
  return (model_digest(env), env.solver_settings.bounded_solver_loop, env.n_substeps, num_envs,
          steps)


class Job:
  """One function to time: compiled ahead (possibly in a worker thread), timed later."""

  def __init__(self, label: str, fn, fn_args: tuple, steps: int, num_envs: int):
    self.label, self.fn, self.fn_args, self.steps, self.num_envs = (
        label, fn, fn_args, steps, num_envs)
    self.exe, self.compile_s, self.sps = None, None, None

  def compile(self) -> "Job":
    t0 = time.perf_counter()
    self.exe = self.fn.lower(*self.fn_args).compile()
    self.compile_s = time.perf_counter() - t0
    return self

  def time(self, repeats: int) -> float:
    self.sps = common.time_executable(self.exe, self.fn_args, self.steps, self.num_envs,
                                      repeats)
    print(f"{self.label:<40}{self.sps:>14,.0f} steps/s  (compile {self.compile_s:.0f}s)",
          flush=True)
    self.fn_args = None  # frees the device buffers
    return self.sps


def task_jobs(name: str, args, key, peer_lock: threading.Lock) -> list[dict]:
  """The jobs of one task: for each size, the peer (if any) and, per physics mode, ours and
  raw. Returns one entry per (size, physics) with its jobs; raw jobs may be shared later."""
  base = min(args.num_envs)
  envs = {physics: tasks.make(name, physics=physics) for physics in args.physics}
  reset = jax.jit(lambda k, env: AutoReset(env).reset(k, base), static_argnums=1)
  starts = {physics: jax.block_until_ready(reset(key, env)) for physics, env in envs.items()}
  entries = []
  for num_envs in args.num_envs:
    peer = None
    if not args.no_peer and name in PEERS:
      steps = args.steps or 50
      try:
        with peer_lock:  # Playground's registry is not known to be thread-safe
          peer_reset, peer_run, settings = peer_fns(name, num_envs, steps)
        peer = Job(f"{name} peer {num_envs}", peer_run, (peer_reset(key), key), steps, num_envs)
        peer.settings = {"name": PEERS[name], **settings, "steps": steps}
      except Exception as e:  # e.g. Playground 0.2.0's reacher needs a newer MuJoCo API
        print(f"{name}: peer unavailable ({type(e).__name__}: {e})", flush=True)
    for physics, env in envs.items():
      steps = args.steps or (10 if physics == "parity" else 50)
      times = num_envs // base
      ours = Job(f"{name} {physics} {num_envs} ours", ours_fn(env, num_envs, steps),
                 (_tile(starts[physics], times), key), steps, num_envs)
      raw = Job(f"{name} {physics} {num_envs} raw", raw_fn(env, num_envs, steps),
                (_tile(starts[physics].data, times), key), steps, num_envs)
      unwrapped = None
      if args.unwrapped:
        unwrapped = Job(f"{name} {physics} {num_envs} step", step_fn(env, num_envs, steps),
                        (_tile(starts[physics], times), key), steps, num_envs)
      entries.append({"task": name, "physics": physics, "num_envs": num_envs, "env": env,
                      "steps": steps, "ours": ours, "raw": raw, "step": unwrapped,
                      "raw_key": raw_key(env, num_envs, steps),
                      "peer": peer})
  return entries


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--tasks", nargs="*", default=list(tasks.TASKS), choices=tasks.TASKS,
                      metavar="TASK")
  parser.add_argument("--physics", nargs="*", default=list(PHYSICS_MODES), choices=PHYSICS_MODES)
  parser.add_argument("--num_envs", nargs="*", type=int, default=[2048, 8192])
  parser.add_argument("--steps", type=int, default=0,
                      help="control steps per timed call (0: 10 in parity mode, 50 in fast)")
  parser.add_argument("--repeats", type=int, default=2)
  parser.add_argument("--compile_threads", type=int, default=8,
                      help="jobs compiled in parallel (host CPU threads); the timing itself is "
                           "always sequential")
  parser.add_argument("--batch_tasks", type=int, default=4,
                      help="tasks compiled together before they are timed")
  parser.add_argument("--no_peer", action="store_true")
  parser.add_argument("--unwrapped", action="store_true",
                      help="also time vmap(task.step) without the auto-reset wrapper (step_sps)")
  parser.add_argument("--out", default=common.default_results_path("env_throughput"))
  args = parser.parse_args(argv)
  base = min(args.num_envs)
  if any(n % base for n in args.num_envs):
    parser.error("every --num_envs must be a multiple of the smallest")
  if args.compile_threads <= 0 or args.batch_tasks <= 0:
    parser.error("--compile_threads and --batch_tasks must be positive")
  writer = common.ResultWriter(args.out)
  key = jax.random.PRNGKey(0)
  peer_lock, raw_lock = threading.Lock(), threading.Lock()
  raw_jobs = {}  # tasks that share a model (XML, settings, size) share its raw measurement

  def prepare(name):
    """A task's jobs, not yet compiled; the raw job of a model already seen is reused."""
    entries = task_jobs(name, args, key, peer_lock)
    for entry in entries:
      with raw_lock:
        entry["raw"] = raw_jobs.setdefault(entry["raw_key"], entry["raw"])
    return entries

  def time_entries(entries):
    """Times a task's compiled jobs and writes its records."""
    peers_timed = set()
    for entry in entries:
      peer = entry["peer"]
      if peer is not None and id(peer) not in peers_timed:
        peer.time(args.repeats)
        peers_timed.add(id(peer))
      ours, raw = entry["ours"], entry["raw"]
      ours.time(args.repeats)
      if raw.sps is None:
        raw.time(args.repeats)
      env = entry["env"]
      result = {"sps": ours.sps, "raw_sps": raw.sps, "ratio_to_raw": ours.sps / raw.sps,
                "compile_s": ours.compile_s, "raw_compile_s": raw.compile_s}
      if entry["step"] is not None:
        unwrapped = entry["step"]
        unwrapped.time(args.repeats)
        result.update(step_sps=unwrapped.sps, step_ratio_to_raw=unwrapped.sps / raw.sps)
      settings = {"num_envs": entry["num_envs"], "physics": entry["physics"],
                  "steps": entry["steps"], "repeats": args.repeats,
                  "solver": vars(env.solver_settings), "n_substeps": env.n_substeps,
                  "compile_threads": args.compile_threads, "batch_tasks": args.batch_tasks}
      if peer is not None:
        result.update(peer_sps=peer.sps, ratio_to_peer=ours.sps / peer.sps,
                      peer_compile_s=peer.compile_s)
        settings["peer"] = peer.settings
      writer.write(kind="env_throughput", task=entry["task"], physics=entry["physics"],
                   num_envs=entry["num_envs"], settings=settings, **result)

  # Tasks go in batches of --batch_tasks: a batch's jobs are compiled in parallel threads (XLA
  # compiles outside the GIL), then timed one at a time, so no measurement shares the host with
  # a compile. One record is written per (task, physics, size) as soon as it is measured; a run
  # stopped at its time limit keeps the batches it finished.
  with concurrent.futures.ThreadPoolExecutor(args.compile_threads) as pool:
    for first in range(0, len(args.tasks), args.batch_tasks):
      batch = list(pool.map(prepare, args.tasks[first:first + args.batch_tasks]))
      jobs = {id(job): job for entries in batch for entry in entries
              for job in (entry["peer"], entry["ours"], entry["raw"], entry["step"])
              if job is not None and job.exe is None and job.sps is None}
      list(pool.map(Job.compile, jobs.values()))
      for entries in batch:
        time_entries(entries)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
