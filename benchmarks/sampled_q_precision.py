#!/usr/bin/env python3
"""How precise the E-step's input was in each run: bfloat16's error in the sampled actions' Q
against their spread over a state's actions, read from the learning-curve records.

MPO weighs a state's sampled actions by exp(Q / temperature), so what matters is Q's
differences between a state's actions. A run is a seed and its settings (a grid's members
apart); its points may lie in several files, a resumed part continuing where the file before
it stopped (a file whose points overlap another's in env steps is another run, a rerun). Per
run with at least `--min_points` evaluations, the mean over its last `--late` share of them of: Q (`q_online`), the
spread (`sampled_q_spread`, the sd of Q over a state's actions), bfloat16's mean |error|
(`sampled_q_bf16_error`, uncentred: it includes any offset common to a state's actions, which
the weights ignore), its centred rms (`sampled_q_bf16_centred_error`, recorded since
2026-11-29: the part the weights see) and the temperature. Then per task, method and precision
(float32, bf16, bf16 with the float32 head: `results.sampled_q_precision`) the runs, the
median and range of error / spread (centred error / spread where recorded) and the medians of
the rest (a run with a NaN in its last evaluations or a spread of 0 has no ratio). Prints
markdown; writes nothing.

  python benchmarks/sampled_q_precision.py                    # every learning-curve record
  python benchmarks/sampled_q_precision.py FILE... --runs     # and one row per run
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.files import results  # noqa: E402

FIELDS = {"q": "q_online", "spread": "sampled_q_spread", "error": "sampled_q_bf16_error",
          "centred": "sampled_q_bf16_centred_error", "temperature": "temperature"}
# settings that say how a run was recorded, not what it ran
_RECORDING = ("eval_episodes", "total_env_steps", "eval_on_host")


def _chains(segments: list[tuple[str, list[dict]]]) -> list[list[tuple[str, list[dict]]]]:
  """One run's (file, points sorted by env steps) joined into runs: a file whose first point
  comes after the last of the run before it continues it (a resumed part), one that overlaps
  it starts another run (a rerun)."""
  chains = []
  for segment in sorted(segments, key=lambda item: item[1][0]["env_steps"]):
    for chain in chains:
      if segment[1][0]["env_steps"] > chain[-1][1][-1]["env_steps"]:
        chain.append(segment)
        break
    else:
      chains.append([segment])
  return chains


def run_rows(records_by_file: dict[str, list[dict]], late: float,
             min_points: int = 1) -> list[dict]:
  """One row per run with at least `min_points` evaluations: task, method, seed, precision,
  its last file, env steps, evaluations and the late means of FIELDS (NaN where the run did not
  record one). ValueError naming the file for a row without its task or env steps."""
  runs = collections.defaultdict(lambda: collections.defaultdict(list))
  for path, records in records_by_file.items():
    for r in records:
      if r.get("kind") != "learning_curve" or "sampled_q_spread" not in r:
        continue
      if missing := [k for k in ("task", "env_steps") if k not in r]:
        raise ValueError(f"{path}: a learning-curve row without {' or '.join(missing)}")
      settings = {k: v for k, v in r.get("settings", {}).items() if k not in _RECORDING}
      runs[(r["task"], r.get("seed"), json.dumps(settings, sort_keys=True))][path].append(r)
  rows = []
  for (task, seed, settings), by_file in runs.items():
    segments = [(path, sorted(points, key=lambda r: r["env_steps"]))
                for path, points in by_file.items()]
    for chain in _chains(segments):
      points = [r for _, segment in chain for r in segment]
      if len(points) < min_points:
        continue
      tail = points[len(points) - max(1, math.ceil(round(late * len(points), 9))):]
      means = {name: float(np.mean([r.get(field, np.nan) for r in tail]))
               for name, field in FIELDS.items()}
      path = chain[-1][0]
      learner = json.loads(settings).get("learner", {})
      rows.append({"task": task, "method": points[0].get("method", "expert"), "seed": seed,
                   "precision": results.sampled_q_precision(learner),
                   "file": os.path.basename(path),
                   "env_steps": points[-1]["env_steps"], "evaluations": len(points), **means})
  return sorted(rows, key=lambda r: (r["task"], r["method"], r["precision"], r["file"],
                                     str(r["seed"])))


def summary(rows: list[dict]) -> list[dict]:
  """Per task, method and precision: runs, error / spread and centred error / spread (median,
  min, max over the runs that recorded them) and the medians of the late means."""
  groups = collections.defaultdict(list)
  for row in rows:
    groups[(row["task"], row["method"], row["precision"])].append(row)
  out = []
  for (task, method, prec), group in sorted(groups.items()):
    entry = {"task": task, "method": method, "precision": prec, "runs": len(group)}
    for name in ("error", "centred"):
      values, spread = (np.array([r[k] for r in group]) for k in (name, "spread"))
      keep = np.isfinite(values) & np.isfinite(spread) & (spread > 0)
      ratio = values[keep] / spread[keep]
      entry[f"{name}_ratio"] = ((float(np.median(ratio)), float(ratio.min()), float(ratio.max()))
                                if ratio.size else None)
    for name in FIELDS:
      values = np.array([r[name] for r in group])
      values = values[np.isfinite(values)]
      entry[name] = float(np.median(values)) if values.size else None
    out.append(entry)
  return out


def _ratio(value) -> str:
  return "-" if value is None else f"{value[0]:.2f} ({value[1]:.2f}-{value[2]:.2f})"


def _number(value, digits: int) -> str:
  return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def _diagnostics(values: dict) -> str:
  """The table cells of the means both tables end with: error, centred, spread, Q, temperature."""
  return " | ".join(_number(values[name], digits) for name, digits in (
      ("error", 3), ("centred", 3), ("spread", 3), ("q", 1), ("temperature", 3))) + " |"


def summary_table(entries: list[dict]) -> str:
  lines = ["| task | method | precision | runs | error / spread | centred / spread | error | "
           "centred | spread | Q | temperature |", "|" + "---|" * 11]
  for e in entries:
    lines.append(f"| {e['task']} | {e['method']} | {e['precision']} | {e['runs']} | "
                 f"{_ratio(e['error_ratio'])} | {_ratio(e['centred_ratio'])} | "
                 + _diagnostics(e))
  return "\n".join(lines)


def runs_table(rows: list[dict]) -> str:
  lines = ["| task | method | precision | last file | seed | env steps | evaluations | error | "
           "centred | spread | Q | temperature |", "|" + "---|" * 12]
  for r in rows:
    lines.append(f"| {r['task']} | {r['method']} | {r['precision']} | {r['file']} | "
                 f"{r['seed']} | {r['env_steps'] / 1e6:.1f}M | {r['evaluations']} | "
                 + _diagnostics(r))
  return "\n".join(lines)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("files", nargs="*", help="record files (default: every learning-curve "
                      "record under benchmarks/results/)")
  parser.add_argument("--late", type=float, default=0.3,
                      help="the share of each run's last evaluations averaged (default 0.3)")
  parser.add_argument("--min_points", type=int, default=5,
                      help="leave out runs with fewer evaluations (smoke tests; default 5)")
  parser.add_argument("--runs", action="store_true", help="also print one row per run")
  args = parser.parse_args(argv)
  if not 0.0 < args.late <= 1.0 or args.min_points < 1:
    parser.error(f"--late must be in (0, 1] and --min_points at least 1, not {args.late} and "
                 f"{args.min_points}")
  root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
  files = args.files or sorted(glob.glob(os.path.join(root, "*learning_curve*")))
  # A FORM run's curve is packed beside its result file (results.pack_curve): either name
  # reads both, once.
  files = list(dict.fromkeys(os.path.normpath(results.run_path(f) if f.endswith(
      results.CURVE_SUFFIX) else f) for f in files))
  records = {}
  try:
    for path in files:
      try:
        records[path] = results.run_records(path)
      except (OSError, EOFError) as e:  # (a truncated .gz: EOFError)
        raise ValueError(f"{path}: {e!r}") from None
    rows = run_rows(records, args.late, args.min_points)
  except ValueError as e:  # (messages name the file)
    print(f"cannot read the records: {e}", file=sys.stderr)
    return 2
  if not rows:
    print("no learning-curve record with the sampled Q's diagnostics in a run of at least "
          f"{args.min_points} evaluations in {len(files)} file(s)", file=sys.stderr)
    return 2
  print(summary_table(summary(rows)))
  if args.runs:
    print()
    print(runs_table(rows))
  return 0


if __name__ == "__main__":
  sys.exit(main())
