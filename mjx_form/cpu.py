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
