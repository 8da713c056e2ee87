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

Packed curves: a FORM run's learning curve is most of the committed results' bytes (two thirds
in 2026-11), and the tree that travels to the GPU machine has a size limit. `pack_curve` moves a
result file's FORM `learning_curve` rows into a gzip-compressed companion, `<name>.curve.jsonl.gz`
(JSON Lines, compact rows, read with `read_records`), and leaves its other rows (final returns,
effect models) in `<name>.jsonl`; `run_records` reads both back as one file.
"""

from __future__ import annotations

import contextlib
import datetime
import gzip
import hashlib
import io
import json
import os
import sys

SHARED_FIELDS = ("settings", "versions", "xla_flags", "physics_matmul_precision")
REFERENCE = "shared_sha256"  # a compact row's name for its shared fields
CURVE_SUFFIX = ".curve.jsonl.gz"  # a result file's packed FORM learning curve


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
  """The records of a `.jsonl` result file (or a gzip-compressed one, `.gz`), compact rows made
  whole (blank lines skipped)."""
  shared_by_digest: dict[str, dict] = {}
  out = []
  with (gzip.open(path, "rt") if path.endswith(".gz") else open(path)) as f:
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


def curve_path(path: str) -> str:
  """The packed curve beside the result file `path` (`X.jsonl` -> `X.curve.jsonl.gz`)."""
  return path.removesuffix(".jsonl") + CURVE_SUFFIX


def run_path(curve: str) -> str:
  """The result file of the packed curve `curve` (`X.curve.jsonl.gz` -> `X.jsonl`)."""
  return curve.removesuffix(CURVE_SUFFIX) + ".jsonl"


def run_records(path: str) -> list[dict]:
  """The records of the result file `path` and of its packed curve, where it has one, in the
  order they were written (by time stamp; a curve's rows first among equal ones)."""
  curve = curve_path(path)
  parts = [p for p in (curve, path) if os.path.exists(p)]
  if not parts:
    raise FileNotFoundError(f"{path}: no such result file (nor {os.path.basename(curve)})")
  rows = [r for p in parts for r in read_records(p)]
  return sorted(rows, key=lambda r: r.get("time", ""))


def is_packed_row(record: dict) -> bool:
  """A row that `pack_curve` moves to a packed curve: a FORM run's learning-curve row."""
  return record.get("kind") == "learning_curve" and record.get("method") == "form"


def _write_lines(path: str, records: list[dict]) -> None:
  """`records` (compact rows) to `path` through a temporary file: gzip without a time stamp or
  name where `path` ends in `.gz` (the same rows give the same bytes), else plain text."""
  text = "".join(json.dumps(r) + "\n" for r in compact_records(records)).encode("utf-8")
  if path.endswith(".gz"):
    buffer = io.BytesIO()
    with gzip.GzipFile(filename="", mode="wb", fileobj=buffer, mtime=0) as f:
      f.write(text)
    text = buffer.getvalue()
  with open(path + ".tmp", "wb") as f:
    f.write(text)
  os.replace(path + ".tmp", path)


def pack_curve(path: str) -> int:
  """Moves the FORM learning-curve rows of the result file `path` (`.jsonl`) to its packed
  curve (after the rows it holds already; a row it holds already, e.g. from a sitting's file
  copied in again, is not added twice), keeps its other rows in `path` (removed where none are
  left); returns how many rows it took out of `path`. Each file is written whole before it
  replaces the old one, the curve read back first: nothing is lost where it fails."""
  if not path.endswith(".jsonl"):
    raise ResultFileError(f"{path}: not a .jsonl result file")
  records = read_records(path)
  moving = [r for r in records if is_packed_row(r)]
  if not moving:
    return 0
  curve = curve_path(path)
  packed = read_records(curve) if os.path.exists(curve) else []
  held = {json.dumps(r, sort_keys=True) for r in packed}
  packed += [r for r in moving if json.dumps(r, sort_keys=True) not in held]
  kept = [r for r in records if not is_packed_row(r)]
  _write_lines(curve, packed)
  if read_records(curve) != packed:  # (before the rows leave `path`)
    raise ResultFileError(f"{curve}: the packed curve does not read back as written")
  if kept:
    _write_lines(path, kept)
  else:
    os.remove(path)
  return len(moving)


def sampled_q_precision(learner: dict) -> str:
  """'float32', 'bf16' or 'bf16 (float32 head)': how a run computed the target critic's Q of
  the sampled actions, from its learner settings (a record's `settings['learner']`)."""
  if not learner.get("sampled_q_bfloat16"):
    return "float32"
  return "bf16 (float32 head)" if learner.get("sampled_q_float32_head") else "bf16"


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
