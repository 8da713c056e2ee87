"""Result records: one JSON object per measurement, appended as a line to a `.jsonl` file.

Benchmarks and GPU learning runs write them (under benchmarks/results/); reports and the
README's tables are generated from them. Every record carries `kind`, the device as JAX names
it, the package versions and a UTC time stamp; the caller adds the rest (task, settings and
the measured fields).

Compact rows: a run's learning curve repeats its settings, package versions and compiler flags
(SHARED_FIELDS) in every row, about half of its bytes. A row written with `compact=True` whose
shared fields an earlier row of the file has in full leaves them out and names them by their
digest instead, `"shared_sha256": "<16 hex digits>"` (`shared_digest`); `read_records` puts them
back from that earlier row, so readers see every record whole. A digest, not a line number:
rows deleted, files joined or appended by other writers cannot make it point at another row.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import os
import sys

SHARED_FIELDS = ("settings", "versions", "xla_flags", "physics_matmul_precision")
REFERENCE = "shared_sha256"  # a compact row's name for its shared fields


class ResultFileError(ValueError):
  """A result file that cannot be read: a line that is not a JSON object, or a compact row
  whose shared fields no earlier row of the file has."""


def _shared(record: dict) -> dict:
  return {k: record[k] for k in SHARED_FIELDS if k in record}


def shared_digest(record: dict) -> str:
  """The first 16 hex digits of the sha256 of `record`'s shared fields (sorted JSON)."""
  text = json.dumps(_shared(record), sort_keys=True)
  return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _compact(record: dict, digest: str) -> dict:
  return {**{k: v for k, v in record.items() if k not in SHARED_FIELDS}, REFERENCE: digest}


def compact_records(records: list[dict]) -> list[dict]:
  """`records` as lines of one file in the compact form: each record whose shared fields an
  earlier record has in full names them by digest instead. `read_records` inverts it."""
  whole, out = set(), []
  for record in records:
    digest = shared_digest(record)
    if _shared(record) and digest in whole:
      out.append(_compact(record, digest))
      continue
    if _shared(record):
      whole.add(digest)
    out.append(record)
  return out


def read_records(path: str) -> list[dict]:
  """The records of a `.jsonl` result file, compact rows made whole (blank lines skipped)."""
  shared_by_digest: dict[str, dict] = {}
  out = []
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
      if REFERENCE in record:
        digest = record.pop(REFERENCE)
        if digest not in shared_by_digest:
          raise ResultFileError(f"{path}: line {n} takes its settings from an earlier row with "
                                f"{REFERENCE} {digest!r}, and the file has none")
        record.update(shared_by_digest[digest])
      elif _shared(record):
        shared_by_digest.setdefault(shared_digest(record), _shared(record))
      out.append(record)
  return out


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
    self._whole: set[str] = set()  # digests of the shared fields this writer wrote in full
    self._size = 0  # the file's size after this writer's last row

  def write(self, compact: bool = False, **record) -> dict:
    """Appends `record` (with the device, versions and time); with `compact`, as a compact row
    where this writer has written its shared fields in full to the file before (module
    docstring). Returns the whole record."""
    record = {**record, **self._common,
              "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    size = os.path.getsize(self.path) if os.path.exists(self.path) else 0
    if size < self._size:  # the file was replaced or truncated: its rows are not ours
      self._whole = set()
    digest = shared_digest(record)
    written = record
    if compact and digest in self._whole:
      written = _compact(record, digest)
    else:
      self._whole.add(digest)
    with open(self.path, "a") as f:
      f.write(json.dumps(written) + "\n")
    self._size = os.path.getsize(self.path)
    return record
