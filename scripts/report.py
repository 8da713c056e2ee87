#!/usr/bin/env python3
"""Writes the README's throughput and parity tables from benchmarks/results/*.jsonl.

  python scripts/report.py           # rewrite the tables in README.md
  python scripts/report.py --check   # exit 1 if README.md is not what the results give

The tables are never typed by hand: each comes from the newest record per (task, mode, size,
device) in the result files.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, "benchmarks", "results")
README = os.path.join(ROOT, "README.md")
TASK_ORDER = ["reacher_easy", "reacher_hard", "cheetah_run", "quadruped_walk", "quadruped_run",
              "hopper_stand", "hopper_hop", "walker_stand", "walker_walk", "walker_run",
              "humanoid_stand", "humanoid_walk", "humanoid_run"]


def read_records(folder: str = RESULTS) -> list[dict]:
  records = []
  for path in sorted(glob.glob(os.path.join(folder, "*.jsonl"))):
    with open(path) as f:
      for line in f:
        if line.strip():
          records.append({**json.loads(line), "_file": os.path.basename(path)})
  return records


def _newest(records: list[dict], key) -> dict:
  out = {}
  for r in sorted(records, key=lambda r: r.get("time", "")):
    out[key(r)] = r
  return out


def _order(task: str) -> int:
  return TASK_ORDER.index(task) if task in TASK_ORDER else len(TASK_ORDER)


def _k(x: float) -> str:
  return f"{x / 1e6:.2f}M" if x >= 1e6 else f"{x / 1e3:.0f}k" if x >= 1e3 else f"{x:.0f}"


def _solver(settings: dict) -> str:
  """'100/50' (iterations / line-search iterations), plus ' cull N' with contact culling."""
  text = f"{settings.get('iterations') or 100}/{settings.get('ls_iterations') or 50}"
  return text + (f" cull {settings['max_contact_points']}"
                 if settings.get("max_contact_points") else "")


def throughput_table(records: list[dict]) -> str:
  rows = [r for r in records if r.get("kind") == "env_throughput"]
  if not rows:
    return "No throughput results yet."
  newest = _newest(rows, lambda r: (r["task"], r["physics"], r["num_envs"], r["device"]))
  lines = []
  for device in sorted({r["device"] for r in newest.values()}):
    sel = [r for r in newest.values() if r["device"] == device]
    versions = sel[0].get("versions", {})
    lines += [f"Control steps per second on `{device}` (jax {versions.get('jax')}, mujoco "
              f"{versions.get('mujoco')}); ours = `AutoReset(task).step`, raw = plain `mjx.step` "
              "loop on the same model and settings, peer = MuJoCo Playground (`impl=\"jax\"`, its "
              "own settings, unwrapped step):", "",
              "| task | physics | solver | envs | ours | raw | ours/raw | peer | ours/peer | "
              "peer settings |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(sel, key=lambda r: (_order(r["task"]), r["physics"] != "parity",
                                        r["num_envs"])):
      peer = f"{_k(r['peer_sps'])}" if "peer_sps" in r else "-"
      ratio_peer = f"{r['ratio_to_peer']:.2f}" if "ratio_to_peer" in r else "-"
      p = r["settings"].get("peer")
      peer_settings = (f"dt {p['sim_dt']}, {p['n_substeps']} substeps, {p['iterations']}/"
                       f"{p['ls_iterations']} iterations" if p else "-")
      lines.append(f"| {r['task']} | {r['physics']} | {_solver(r['settings']['solver'])} | "
                   f"{r['num_envs']} | {_k(r['sps'])} | "
                   f"{_k(r['raw_sps'])} | {r['ratio_to_raw']:.2f} | {peer} | {ratio_peer} | "
                   f"{peer_settings} |")
    lines.append("")
  return "\n".join(lines).rstrip()


def parity_table(records: list[dict]) -> str:
  rows = [r for r in records if r.get("kind") == "parity"]
  if not rows:
    return "No parity results yet."
  newest = _newest(rows, lambda r: (r["task"], r["physics"], r["device"]))
  lines = []
  for device in sorted({r["device"] for r in newest.values()}):
    sel = [r for r in newest.values() if r["device"] == device]
    n = sel[0]["settings"].get("num_transitions")
    lines += [f"One control step from {n} dm_control states under random actions, float32 on "
              f"`{device}`: largest absolute error per transition against dm_control's next "
              "state, median / max over transitions:", "",
              "| task | physics | qpos | qvel | observation | reward |", "|---|---|---|---|---|---|"]
    for r in sorted(sel, key=lambda r: (_order(r["task"]), r["physics"] != "parity")):
      cells = [f"{r[f]['median']:.0e} / {r[f]['max']:.0e}"
               for f in ("qpos_error", "qvel_error", "obs_error", "reward_error")]
      lines.append(f"| {r['task']} | {r['physics']} | " + " | ".join(cells) + " |")
    lines.append("")
  return "\n".join(lines).rstrip()


def sweep_table(records: list[dict]) -> str:
  rows = [r for r in records if r.get("kind") == "solver_sweep"]
  if not rows:
    return "No solver sweep results yet."
  newest = _newest(rows, lambda r: (r["task"], _solver(r["settings"]["solver"]), r["measured"]))
  speed = {k[:2]: r for k, r in newest.items() if k[2] == "speed"}
  error = {k[:2]: r for k, r in newest.items() if k[2] == "error"}
  keys = sorted(set(speed) | set(error),  # by task, then most iterations first, culling second
                key=lambda k: (_order(k[0]), -int(k[1].split("/")[0]), "cull" in k[1]))
  first = next(iter(speed.values()), None)
  lines = [f"Raw `mjx.step` control steps per second at "
           f"{first['settings']['num_envs'] if first else '-'} envs on "
           f"`{first['device'] if first else '-'}`, and the one-step qvel error against "
           "dm_control (float32, CPU, 64 states: median / p90 / max):", "",
           "| task | solver | raw steps/s | x parity | qvel error |", "|---|---|---|---|---|"]
  for task, solver in keys:
    s, e = speed.get((task, solver)), error.get((task, solver))
    sps = f"{_k(s['raw_sps'])} | {s['speedup_over_parity']:.2f}" if s else "- | -"
    err = (f"{e['qvel_error']['median']:.0e} / {e['qvel_error']['p90']:.0e} / "
           f"{e['qvel_error']['max']:.0e}") if e else "-"
    lines.append(f"| {task} | {solver} | {sps} | {err} |")
  return "\n".join(lines)


def render(readme: str, records: list[dict]) -> str:
  for name, table in (("throughput", throughput_table(records)),
                      ("parity", parity_table(records)), ("sweep", sweep_table(records))):
    pattern = re.compile(rf"(<!-- {name}:begin -->\n).*?(\n<!-- {name}:end -->)", re.S)
    if not pattern.search(readme):
      raise ValueError(f"README.md has no <!-- {name}:begin/end --> markers")
    readme = pattern.sub(lambda m: m.group(1) + table + m.group(2), readme)
  return readme


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--check", action="store_true")
  args = parser.parse_args(argv)
  with open(README) as f:
    current = f.read()
  updated = render(current, read_records())
  if args.check:
    if updated != current:
      print("README.md tables differ from benchmarks/results/: run scripts/report.py",
            file=sys.stderr)
      return 1
    return 0
  with open(README, "w") as f:
    f.write(updated)
  print("README.md tables written")
  return 0


if __name__ == "__main__":
  sys.exit(main())
