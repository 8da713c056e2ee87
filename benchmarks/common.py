"""What the benchmarks share: result records (JSON Lines under benchmarks/results/) and timing."""

from __future__ import annotations

import datetime
import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS_DIR = os.path.join(ROOT, "benchmarks", "results")
if ROOT not in sys.path:
  sys.path.insert(0, ROOT)


def versions() -> dict:
  import jax
  import mujoco
  return {"jax": jax.__version__, "mujoco": mujoco.__version__, "python": sys.version.split()[0]}


def device_name() -> str:
  import jax
  d = jax.devices()[0]
  return f"{d.platform}:{getattr(d, 'device_kind', d.platform)} x{jax.device_count()}"


class ResultWriter:
  """Appends one JSON record per measurement to `path`, flushing each line."""

  def __init__(self, path: str):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    self.path = path
    self._common = {"device": device_name(), "versions": versions()}

  def write(self, **record) -> dict:
    record = {**record, **self._common,
              "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    with open(self.path, "a") as f:
      f.write(json.dumps(record) + "\n")
    return record


def default_results_path(what: str) -> str:
  day = datetime.date.today().isoformat()
  return os.path.join(RESULTS_DIR, f"{day}_{what}.jsonl")


def best_time(fn, repeats: int) -> float:
  """Smallest wall time of `repeats` calls of `fn` (which must block until done)."""
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    fn()
    times.append(time.perf_counter() - t0)
  return min(times)


def time_compiled(fn, fn_args: tuple, steps: int, num_envs: int, repeats: int):
  """Compiles jitted `fn` for `fn_args`, warms it up and times it: (steps/s, compile seconds).

  `fn(state, key)` donates its first argument, so each timed call is fed the previous output.
  """
  import jax
  t0 = time.perf_counter()
  exe = fn.lower(*fn_args).compile()
  compile_s = time.perf_counter() - t0
  holder = [jax.block_until_ready(exe(*fn_args))]  # warm-up

  def call():
    holder[0] = jax.block_until_ready(exe(holder[0], fn_args[1]))
  return steps * num_envs / best_time(call, repeats), compile_s
