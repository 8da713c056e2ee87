"""XLA settings that MJX needs on the CPU; import before JAX starts."""

from __future__ import annotations

import os

# XLA's concurrency-optimised CPU scheduler deadlocks on MJX steps of the larger models
# (humanoid, quadruped): the process waits at 0% CPU forever. Turning it off fixes that.
CPU_XLA_FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler=false"


def configure_cpu_xla(extra_flags: str = "") -> None:
  """Adds the CPU flag (and `extra_flags`) to XLA_FLAGS unless already there."""
  flags = os.environ.get("XLA_FLAGS", "")
  for flag in (CPU_XLA_FLAG, *extra_flags.split()):
    name = flag.split("=")[0]
    if name not in flags:
      flags = f"{flags} {flag}".strip()
  os.environ["XLA_FLAGS"] = flags


def one_device_per_core() -> bool:
  """Asks JAX for one CPU device per core, for evaluations on the host beside an accelerator
  (`--eval_on_host`: XLA steps a batch on one CPU device with few of its cores; 96 walker
  episodes took 14.6 s split over the 2-core CPU's 2 devices, 23.9 s on one). The cores are
  those this process may run on (`taskset`, or `gpu_jobs.py`'s share of the host per GPU).
  False where JAX has started (too late to ask)."""
  import jax

  try:
    jax.config.update("jax_num_cpu_devices", len(os.sched_getaffinity(0)) or 1)
  except RuntimeError:
    return False
  return True


def run_once_compiler_options() -> dict:
  """XLA options for a program that runs once (a run's init, a parity check's batched step).

  On the CPU: backend optimisation level 0. Measured on the 2-core CPU: a small run's init
  compiles in 6 s instead of 12, quadruped's float64 parity step in 42 s instead of 56, with
  the same results; a program run once gains nothing from the optimisation. Elsewhere: none
  (GPU programs keep XLA's defaults).
  """
  import jax  # (this module is imported before JAX starts; by the time this runs, it has)

  return {"xla_backend_optimization_level": 0} if jax.default_backend() == "cpu" else {}
