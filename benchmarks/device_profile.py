"""Where a compiled program's device time goes, by the source line each operation came from.

`top_lines(exe, args, n)` runs compiled `exe` once under `jax.profiler.trace` (a Perfetto trace
in a temporary folder), sums the duration of every operation the device ran for that program
(the trace's `hlo_op` of its `hlo_module`; on a GPU the kernels, on the CPU the runtime's thunks),
maps each operation to the metadata XLA kept for it (the JAX operation and the Python file and
line that made it, from the optimised HLO text), and returns the `n` lines with the most time.
A fusion is attributed to its root operation's line. (JAX keeps one frame per operation: for
a flax layer that is flax's own line, so the operation's name says which layer.) Used by
`update_speed.py --profile N`.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import os
import re
import tempfile

_INSTRUCTION = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=.*?metadata=\{([^}]*)\}")
_FIELD = {name: re.compile(rf'{name}=(?:"([^"]*)"|(\d+))')
          for name in ("op_name", "source_file", "source_line", "stack_frame_id")}
_TABLE_ROW = re.compile(r'^(\d+) (?:"(.*)"|\{(.*)\})$')
_OURS = (f"{os.sep}mjx_form{os.sep}", f"{os.sep}benchmarks{os.sep}", f"{os.sep}tasks{os.sep}")


def _tables(hlo_text: str) -> dict[str, dict[int, object]]:
  """The module's FileNames, FunctionNames, FileLocations and StackFrames tables: {table: {id:
  the quoted name, or {field: int} of the braces}}."""
  tables, current = {}, None
  for line in hlo_text.splitlines():
    if line in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
      current = tables.setdefault(line, {})
      continue
    m = _TABLE_ROW.match(line) if current is not None else None
    if not m:
      current = None if not line.strip() or line.startswith("%") else current
      continue
    current[int(m.group(1))] = (m.group(2) if m.group(2) is not None else
                                {k: int(v) for k, v in re.findall(r"(\w+)=(-?\d+)", m.group(3))})
  return tables


def _frame_line(tables: dict, frame: int) -> str | None:
  """'file.py:line' of a stack frame: the innermost of its frames in this repository's code
  (mjx_form/, benchmarks/, tasks/), else the innermost one."""
  frames, locations = tables.get("StackFrames", {}), tables.get("FileLocations", {})
  files = tables.get("FileNames", {})
  chain, seen = [], set()
  while frame in frames and frame not in seen:
    seen.add(frame)
    location = locations.get(frames[frame].get("file_location_id"), {})
    path = files.get(location.get("file_name_id"), "?")
    chain.append((path, location.get("line", "?")))
    frame = frames[frame].get("parent_frame_id")
  if not chain:
    return None
  path, line = next((c for c in chain if any(part in c[0] for part in _OURS)), chain[0])
  return f"{os.path.basename(path)}:{line}"


def hlo_sources(hlo_text: str) -> dict[str, str]:
  """{instruction name: 'file.py:line op'} of every instruction of an optimised HLO module's
  text that carries metadata ('op' the last three parts of its JAX op_name, which name a flax
  module's layer; the line from its stack frame, or from source_file and source_line in older
  texts)."""
  tables, sources = _tables(hlo_text), {}
  for line in hlo_text.splitlines():
    m = _INSTRUCTION.match(line)
    if not m:
      continue
    fields = {}
    for name, pattern in _FIELD.items():
      found = pattern.search(m.group(2))
      if found:
        fields[name] = found.group(1) if found.group(1) is not None else found.group(2)
    op = "/".join(fields.get("op_name", "").split("/")[-3:])  # (flax: module/layer/op)
    where = (_frame_line(tables, int(fields["stack_frame_id"])) if "stack_frame_id" in fields
             else f"{os.path.basename(fields['source_file'])}:{fields.get('source_line', '?')}"
             if "source_file" in fields else None)
    sources[m.group(1)] = f"{where or '?'} {op}".strip()
  return sources


def operation_times(trace: dict, module: str) -> collections.Counter:
  """{hlo_op: microseconds} of a Perfetto trace's complete events for HLO module `module`, on
  the device where the trace has device processes ('/device:...'), else wherever they are."""
  events = trace["traceEvents"] if isinstance(trace, dict) else trace
  names = {e["pid"]: e.get("args", {}).get("name", "") for e in events
           if e.get("ph") == "M" and e.get("name") == "process_name"}
  devices = {pid for pid, name in names.items() if name.startswith("/device:")}
  times = collections.Counter()
  for e in events:
    args = e.get("args") or {}
    if (e.get("ph") != "X" or "hlo_op" not in args or args.get("hlo_module") != module
        or (devices and e.get("pid") not in devices)):
      continue
    times[args["hlo_op"]] += float(e.get("dur", 0.0))
  return times


def top_lines(exe, args: tuple, n: int) -> list[dict]:
  """Runs compiled `exe(*args)` once under the profiler: the `n` source lines with the most
  device time, [{'where': 'file.py:line op', 'us': microseconds, 'share': of the program's
  traced device time}], most first (empty where the trace held no operation of `exe`)."""
  import jax
  text = exe.as_text()
  module = re.match(r"\s*HloModule\s+([\w.\-]+)", text)
  module = module.group(1) if module else ""
  with tempfile.TemporaryDirectory() as folder:
    with jax.profiler.trace(folder, create_perfetto_trace=True):
      jax.block_until_ready(exe(*args))
    files = glob.glob(os.path.join(folder, "**", "*.trace.json.gz"), recursive=True)
    if not files:
      return []
    with gzip.open(files[0]) as f:
      times = operation_times(json.load(f), module)
  sources = hlo_sources(text)
  by_line = collections.Counter()
  for op, us in times.items():
    by_line[sources.get(op, op)] += us
  total = sum(by_line.values())
  return [{"where": where, "us": us, "share": us / total}
          for where, us in by_line.most_common(n)] if total else []
