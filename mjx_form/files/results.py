"""Result records: one JSON object per measurement, appended as a line to a `.jsonl` file.

Benchmarks and GPU learning runs write them (under benchmarks/results/); reports and the
README's tables are generated from them. Every record carries `kind`, the device as JAX names
it, the package versions and a UTC time stamp; the caller adds the rest (task, settings and
the measured fields).

Compact rows: a run's learning curve repeats its settings, package versions and compiler flags
(SHARED_FIELDS) in every row, about half of its bytes. A row written with `compact=True` whose
shared fields equal an earlier row's of the same file leaves them out and names that row
instead, `"same_as_line": n` (1-based line number in the file); `read_records` puts them back,
so readers see every record whole.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import sys

SHARED_FIELDS = ("settings", "versions", "xla_flags", "physics_matmul_precision")


class ResultFileError(ValueError):
  """A result file that cannot be read: a line that is not a JSON object, or a compact row
  naming a line that is not an earlier record of the file."""


def _shared(record: dict) -> dict:
  return {k: record[k] for k in SHARED_FIELDS if k in record}


def _shared_key(record: dict) -> str:
  return json.dumps(_shared(record), sort_keys=True)


def compact_records(records: list[dict]) -> list[dict]:
  """`records` as lines of one file in the compact form: each record whose shared fields equal
  an earlier (whole) record's gets `same_as_line` instead of them. `read_records` inverts it."""
  first, out = {}, []
  for line, record in enumerate(records, 1):
    key = _shared_key(record)
    if _shared(record) and key in first:
      out.append({**{k: v for k, v in record.items() if k not in SHARED_FIELDS},
                  "same_as_line": first[key]})
    else:
      first.setdefault(key, line)
      out.append(record)
  return out


def read_records(path: str) -> list[dict]:
  """The records of a `.jsonl` result file, compact rows made whole (blank lines skipped)."""
  by_line: dict[int, dict] = {}
  with open(path) as f:
    for n, text in enumerate(f, 1):
      if not text.strip():
        continue
      try:
        record = json.loads(text)
      except json.JSONDecodeError as e:
        raise ResultFileError(f"{path}: line {n} is not JSON ({e.msg})") from None
      if not isinstance(record, dict):
        raise ResultFileError(f"{path}: line {n} is not a result record")
      if "same_as_line" in record:
        ref = record.pop("same_as_line")
        whole = by_line.get(ref) if isinstance(ref, int) and ref < n else None
        if whole is None or not _shared(whole):
          raise ResultFileError(f"{path}: line {n} takes its settings from line {ref!r}, which "
                                "is not an earlier record with settings")
        record.update(_shared(whole))
      by_line[n] = record
  return list(by_line.values())


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
    self._first: dict[str, int] = {}  # shared fields (as JSON) -> line of this writer's row
    self._lines = 0  # the file's lines after this writer's last row

  def write(self, compact: bool = False, **record) -> dict:
    """Appends `record` (with the device, versions and time); with `compact`, as a compact row
    where an earlier row of the file has the same shared fields (module docstring). Returns
    the whole record."""
    record = {**record, **self._common,
              "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    line = self._count_lines() + 1
    key = _shared_key(record)
    written = record
    if compact and _shared(record) and key in self._first:
      written = {**{k: v for k, v in record.items() if k not in SHARED_FIELDS},
                 "same_as_line": self._first[key]}
    else:
      self._first.setdefault(key, line)
    with open(self.path, "a") as f:
      f.write(json.dumps(written) + "\n")
    self._lines = line
    return record

  def _count_lines(self) -> int:
    """Lines in the file now (others may have appended since this writer's last row); a file
    shorter than this writer left it was replaced, and its rows are forgotten."""
    try:
      with open(self.path, "rb") as f:
        lines = sum(1 for _ in f)
    except FileNotFoundError:
      lines = 0
    if lines < self._lines:
      self._first = {}
    return lines
