"""Where a compiled program's device time goes, by the source line each operation came from.

`top_lines(exe, args, n)` runs compiled `exe` under `jax.profiler.trace` (its trace, the
`*.trace.json.gz` written to a temporary folder), sums the duration of every operation the
device ran for that program (the trace's `hlo_op` of its `hlo_module`; on a GPU the kernels, on
the CPU the runtime's thunks, less the loops, conditionals and calls, whose events enclose
their bodies'), maps each operation to the metadata XLA kept for it (the JAX operation, and the
innermost line of this repository's code in the call stack that made it, from the optimised
HLO text), and returns the `n` lines with the most time. A fusion is attributed to its root
operation. With `calls` > 1 it traces that many calls, each its own trace, and keeps each
operation's least time over them (a busy CPU only adds time: on CI's two cores a reduction of a
384x384 array once took half the program's time in a single trace). Used by
`update_speed.py --profile N`.

Compile the program to profile with `PROFILE_OPTIONS` (`compile_for_profile`): on a GPU, XLA
otherwise records the program's kernels as CUDA graphs ("command buffers"), and the trace then
holds one event per graph, `command_buffer_N` with no source (seen on an H200, 2026-11-29:
100% of quadruped_run's FORM step in one such event), not the operations inside.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import os
import re
import tempfile

_INSTRUCTION = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*(.*)$")
_OPCODE = re.compile(r"\s([a-z][\w\-]*)\(")  # the first `word(` after the shape
_METADATA = re.compile(r"metadata=\{([^}]*)\}")
_FIELD = {name: re.compile(rf'{name}=(?:"([^"]*)"|(\d+))')
          for name in ("op_name", "source_file", "source_line", "stack_frame_id")}
_TABLE_ROW = re.compile(r'^(\d+) (?:"(.*)"|\{(.*)\})$')
# Operations whose events enclose other operations' events (counted through those).
ENCLOSING = ("while", "conditional", "call")
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep


def _ours(path: str) -> bool:
  """Whether `path` is this repository's code (not an installed package's)."""
  return (path.startswith(_ROOT) and "site-packages" not in path
          and f"{os.sep}.venv{os.sep}" not in path)


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
      current = None
      continue
    current[int(m.group(1))] = (m.group(2) if m.group(2) is not None else
                                {k: int(v) for k, v in re.findall(r"(\w+)=(-?\d+)", m.group(3))})
  return tables


def _frame_line(tables: dict, frame: int) -> str | None:
  """'file.py:line' of a stack frame: the innermost frame of its call stack in this
  repository's code, else the innermost one. (The text prints a frame's parent as its id + 1:
  1 is none.)"""
  frames, locations = tables.get("StackFrames", {}), tables.get("FileLocations", {})
  files = tables.get("FileNames", {})
  chain, seen = [], set()
  while frame in frames and frame not in seen:
    seen.add(frame)
    location = locations.get(frames[frame].get("file_location_id"), {})
    chain.append((files.get(location.get("file_name_id"), "?"), location.get("line", "?")))
    frame = frames[frame].get("parent_frame_id", 1) - 1
  if not chain:
    return None
  path, line = next((c for c in chain if _ours(c[0])), chain[0])
  return f"{os.path.basename(path)}:{line}"


def hlo_instructions(hlo_text: str) -> dict[str, tuple[str, str]]:
  """{instruction name: (opcode, 'file.py:line op')} of an optimised HLO module's text: 'op'
  the last three parts of its JAX op_name (for flax: module/layer/operation), the line from
  its stack frame (`_frame_line`), or from source_file and source_line in older texts;
  '(no source) <name>' where it has no metadata."""
  tables, found = _tables(hlo_text), {}
  for line in hlo_text.splitlines():
    m = _INSTRUCTION.match(line)
    if not m:
      continue
    opcode = _OPCODE.search(" " + m.group(2))
    metadata = _METADATA.search(m.group(2))
    fields = {}
    for name, pattern in _FIELD.items():
      value = pattern.search(metadata.group(1)) if metadata else None
      if value:
        fields[name] = value.group(1) if value.group(1) is not None else value.group(2)
    op = "/".join(fields.get("op_name", "").split("/")[-3:])
    where = (_frame_line(tables, int(fields["stack_frame_id"])) if "stack_frame_id" in fields
             else f"{os.path.basename(fields['source_file'])}:{fields.get('source_line', '?')}"
             if "source_file" in fields else None)
    label = (f"{where or '?'} {op}".strip() if op or where else f"(no source) {m.group(1)}")
    found[m.group(1)] = (opcode.group(1) if opcode else "", label)
  return found


def operation_times(trace: dict, module: str) -> collections.Counter:
  """{hlo_op: microseconds} of a trace's complete events for HLO module `module`, on the
  device where the trace has device processes ('/device:...'), else wherever they are."""
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


# XLA's option that lists what runs as command buffers; empty: nothing (every backend takes it).
PROFILE_OPTIONS = {"xla_gpu_enable_command_buffer": ""}


def compile_for_profile(fn, args: tuple):
  """jitted `fn` compiled for `args` as `top_lines` can attribute it: each kernel its own
  event (no command buffers)."""
  return fn.lower(*args).compile(compiler_options=PROFILE_OPTIONS)


def _traced_times(exe, args: tuple, module: str) -> collections.Counter | None:
  """{hlo_op: microseconds} of one call of `exe(*args)` under the profiler (None: no trace)."""
  import jax
  with tempfile.TemporaryDirectory() as folder:
    with jax.profiler.trace(folder):
      jax.block_until_ready(exe(*args))
    files = glob.glob(os.path.join(folder, "**", "*.trace.json.gz"), recursive=True)
    if not files:
      return None
    with gzip.open(files[0]) as f:
      return operation_times(json.load(f), module)


def top_lines(exe, args: tuple, n: int, calls: int = 1) -> list[dict]:
  """Runs compiled `exe(*args)` `calls` times under the profiler (args must survive a call:
  nothing donated where calls > 1): the `n` source lines with the most device time, each
  operation timed by its least time over the calls, [{'where': 'file.py:line op' (or
  '(no source) <operation>'), 'us': microseconds, 'share': of the program's traced operation
  time}], most first; empty where the trace held no operation of `exe` (no device tracing)."""
  if calls < 1:
    raise ValueError(f"calls must be at least 1, got {calls}")
  text = exe.as_text()
  module = re.match(r"\s*HloModule\s+([\w.\-]+)", text)
  module = module.group(1) if module else ""
  traced = [_traced_times(exe, args, module) for _ in range(calls)]
  if any(t is None for t in traced):
    return []
  ops = set().union(*traced)  # each operation's least time over the traces that hold it
  times = collections.Counter({op: min(t[op] for t in traced if op in t) for op in ops})
  instructions = hlo_instructions(text)
  by_line = collections.Counter()
  for op, us in times.items():
    opcode, label = instructions.get(op, ("", f"(no source) {op}"))
    if opcode not in ENCLOSING:
      by_line[label] += us
  total = sum(by_line.values())
  return [{"where": where, "us": us, "share": us / total}
          for where, us in by_line.most_common(n)] if total else []
