"""Result records: one JSON object per measurement, appended as a line to a `.jsonl` file.

Benchmarks and GPU learning runs write them (under benchmarks/results/); reports and the
README's tables are generated from them. Every record carries `kind`, the device as JAX names
it, the package versions and a UTC time stamp; the caller adds the rest (task, settings and
the measured fields).
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import sys


def versions() -> dict:
  import jax
  import mujoco
  return {"jax": jax.__version__, "mujoco": mujoco.__version__, "python": sys.version.split()[0]}


def device_name() -> str:
  """E.g. 'gpu:NVIDIA H200 x1' (platform, device kind, device count)."""
  import jax
  d = jax.devices()[0]
  return f"{d.platform}:{getattr(d, 'device_kind', d.platform)} x{jax.device_count()}"


def peak_memory_bytes() -> int | None:
  """Largest peak of device memory in use over the local devices (None where the backend,
  e.g. the CPU, does not report it)."""
  import jax
  peaks = []
  for d in jax.local_devices():
    stats = d.memory_stats() if hasattr(d, "memory_stats") else None
    if stats and "peak_bytes_in_use" in stats:
      peaks.append(int(stats["peak_bytes_in_use"]))
  return max(peaks) if peaks else None


@contextlib.contextmanager
def count_persistent_cache_hits():
  """Yields a one-element list counting programs loaded from JAX's persistent compilation
  cache (instead of compiled) inside the block."""
  import jax
  hits = [0]
  def listener(event, **_):
    if event == "/jax/compilation_cache/cache_hits":
      hits[0] += 1
  jax.monitoring.register_event_listener(listener)
  try:
    yield hits
  finally:
    jax.monitoring.unregister_event_listener(listener)


class ResultWriter:
  """Appends one JSON record per measurement to `path`, flushing each line."""

  def __init__(self, path: str):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    self.path = path
    from mjx_form.sim.physics import PHYSICS_MATMUL_PRECISION
    # Records without this field (written before the physics asked for full precision)
    # simulated with JAX's default precision, TF32 on NVIDIA GPUs (see mjx_form/sim/physics.py).
    self._common = {"device": device_name(), "versions": versions(),
                    "physics_matmul_precision": PHYSICS_MATMUL_PRECISION}
    if os.environ.get("XLA_FLAGS"):  # compiler settings that change speed, e.g. command buffers
      self._common["xla_flags"] = os.environ["XLA_FLAGS"]

  def write(self, **record) -> dict:
    record = {**record, **self._common,
              "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    with open(self.path, "a") as f:
      f.write(json.dumps(record) + "\n")
    return record
