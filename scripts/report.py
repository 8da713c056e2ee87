#!/usr/bin/env python3
"""Writes the README's tables (throughput, parity, solver sweep, learning, loop throughput)
from benchmarks/results/*.jsonl, and the table of shipped experts from tasks/experts/*.npz.

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
sys.path.insert(0, ROOT)

from mjx_form import policy_io  # noqa: E402  (numpy only; no JAX)
from mjx_form.cpu import CPU_XLA_FLAG  # noqa: E402  (os only)

# = tasks.EXPERTS_DIR (not imported from there: importing tasks starts JAX)
EXPERTS = os.path.join(ROOT, "tasks", "experts")
# Expert returns of the paper's Table 1 (mean over 3 seeds), for comparison only.
PAPER_EXPERT = {"reacher_easy": 974.6, "reacher_hard": 981.3, "cheetah_run": 930.5,
                "quadruped_walk": 972.4, "quadruped_run": 962.9, "hopper_stand": 965.8,
                "hopper_hop": 711.5, "walker_stand": 993.6, "walker_walk": 983.2,
                "walker_run": 952.1, "humanoid_stand": 905.9, "humanoid_walk": 809.5,
                "humanoid_run": 736.6}
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


def _matmuls(r: dict) -> str:
  """How the physics' float32 matmuls ran: 'float32', or 'TF32' for GPU records made before the
  physics asked for full precision (they carry no `physics_matmul_precision`; JAX's default on
  NVIDIA GPUs is TF32)."""
  precision = r.get("physics_matmul_precision") or r.get("matmul_precision")
  return "float32" if precision == "highest" or not r["device"].startswith("gpu") else "TF32"


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
              "own settings, unwrapped step); unwrapped = `vmap(task.step)` without auto-reset, "
              "where measured; physics matmuls = how our and raw physics ran its float32 matrix "
              "products:", "",
              "| task | physics | solver | envs | physics matmuls | ours | raw | ours/raw | "
              "unwrapped/raw | peer | ours/peer | peer settings |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(sel, key=lambda r: (_order(r["task"]), r["physics"] != "parity",
                                        r["num_envs"])):
      peer = f"{_k(r['peer_sps'])}" if "peer_sps" in r else "-"
      ratio_peer = f"{r['ratio_to_peer']:.2f}" if "ratio_to_peer" in r else "-"
      p = r["settings"].get("peer")
      peer_settings = (f"dt {p['sim_dt']}, {p['n_substeps']} substeps, {p['iterations']}/"
                       f"{p['ls_iterations']} iterations" if p else "-")
      unwrapped = f"{r['step_ratio_to_raw']:.2f}" if "step_ratio_to_raw" in r else "-"
      lines.append(f"| {r['task']} | {r['physics']} | {_solver(r['settings']['solver'])} | "
                   f"{r['num_envs']} | {_matmuls(r)} | {_k(r['sps'])} | "
                   f"{_k(r['raw_sps'])} | {r['ratio_to_raw']:.2f} | {unwrapped} | {peer} | "
                   f"{ratio_peer} | {peer_settings} |")
    lines.append("")
  return "\n".join(lines).rstrip()


def parity_table(records: list[dict]) -> str:
  rows = [r for r in records if r.get("kind") == "parity"]
  if not rows:
    return "No parity results yet."
  newest = _newest(rows, lambda r: (r["task"], r["physics"], r["device"], _matmuls(r)))
  lines = []
  for device, matmuls in sorted({(r["device"], _matmuls(r)) for r in newest.values()}):
    sel = [r for r in newest.values() if (r["device"], _matmuls(r)) == (device, matmuls)]
    n = sel[0]["settings"].get("num_transitions")
    lines += [f"One control step from {n} dm_control states under random actions, float32 on "
              f"`{device}`, matmuls in {matmuls}: largest absolute error per transition against "
              "dm_control's next state, median / max over transitions:", "",
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


def _duration(seconds: float) -> str:
  return f"{seconds / 60:.1f} min" if seconds >= 600 else f"{seconds:.0f} s"


def _episodes(record: dict) -> str:
  """How a training run started its first episodes (records before staggering: lockstep)."""
  return "staggered" if record["settings"].get("stagger_episodes") else "lockstep"


def _action_penalty(record: dict) -> str:
  """MPO's action penalty of a training run: its KL bound, or '-' when off (records before the
  setting existed ran without it)."""
  mpo = record["settings"].get("learner", {}).get("mpo", {})
  return f"{mpo['epsilon_penalty']:g}" if mpo.get("action_penalty") else "-"


def _startup(record: dict) -> str:
  """The first process's start-up of a run (records before 2026-11-22 lack it)."""
  if "startup_s" not in record:
    return "-"
  return f"{record['startup_s']:.0f} s" + (" cached" if record["persistent_cache_hits"] else "")


def _run_label(path: str, task: str) -> str:
  """A run's result file, shortened: its date and what its name adds to the task's."""
  name = os.path.basename(path).removesuffix(".jsonl")
  suffix = name.split(task, 1)[1].strip("_") if task in name else ""
  return f"{name[:10]}{' ' + suffix if suffix else ''}"


def learning_table(records: list[dict], threshold: float = 800.0) -> str:
  """One row per learning run (a result file's records of one task and seed)."""
  rows = [r for r in records if r.get("kind") == "learning_curve"]
  if not rows:
    return "No learning results yet."
  runs: dict[tuple, list[dict]] = {}
  for r in rows:
    runs.setdefault((r["_file"], r["task"], r["seed"]), []).append(r)
  lines = [f"Expert runs (MPO + Retrace on the task reward, one seed each). Evaluation: mean "
           f"task return of {rows[0]['settings']['eval_episodes']} full episodes with the "
           f"policy's mean action. Wall clock includes compilation (and each restart's "
           f"compilation where a run was continued with --resume); start-up: its part before the "
           f"first iteration (building, tracing, compiling; `cached`: programs loaded from JAX's "
           f"persistent compilation cache), recorded since 2026-11-22. First episodes: `lockstep` "
           f"= all environments started together, `staggered` = at random phases (see "
           f"above). Action penalty: MPO's penalty on actions outside [-1, 1] and its KL "
           f"bound (`--action_penalty`), `-` = off.", "",
           "| task | device | physics matmuls | envs | updates / iteration (replay ratio) | "
           "first episodes | action penalty | env steps | wall clock | start-up | final eval | "
           f"best eval | first eval >= {threshold:.0f}: wall clock (env steps) | result file |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for (_, task, _), curve in sorted(runs.items(),
                                    key=lambda kv: (_order(kv[0][1]), kv[1][0]["num_envs"])):
    curve = sorted(curve, key=lambda r: r["env_steps"])
    last, best = curve[-1], max(curve, key=lambda r: r["eval_return"])
    reached = next((r for r in curve if r["eval_return"] >= threshold), None)
    first = (f"{_duration(reached['wall_s'])} ({reached['env_steps'] / 1e6:.1f}M)" if reached
             else "not reached")
    settings = last["settings"]
    lines.append(f"| {task} | `{last['device']}` | {_matmuls(last)} | {last['num_envs']} | "
                 f"{settings['updates_per_iteration']} ({settings['replay_ratio']:g}) | "
                 f"{_episodes(last)} | {_action_penalty(last)} | "
                 f"{last['env_steps'] / 1e6:.1f}M | {_duration(last['wall_s'])} | "
                 f"{_startup(curve[0])} | "
                 f"{last['eval_return']:.1f} | {best['eval_return']:.1f} | {first} | "
                 f"{_run_label(last['_file'], task)} |")
  return "\n".join(lines)


def _xla_flags(r: dict) -> str:
  """The XLA flags a record ran under beyond the CPU one every run sets ('-' for none)."""
  cpu_flag = CPU_XLA_FLAG.split("=")[0]
  flags = [f for f in r.get("xla_flags", "").split() if f.split("=")[0] != cpu_flag]
  return " ".join(f"`{f}`" for f in flags) or "-"


def train_throughput_table(records: list[dict]) -> str:
  rows = [r for r in records if r.get("kind") == "train_throughput"]
  if not rows:
    return "No training-loop throughput results yet."
  newest = _newest(rows, lambda r: (r["task"], r["num_envs"], r["device"], _matmuls(r),
                                    r["settings"]["updates_per_iteration"], _episodes(r),
                                    _xla_flags(r)))
  lines = ["Environment steps per second of one whole training iteration (collect 100-step "
           "unrolls, normaliser, replay insert, MPO/Retrace updates) beside env-only "
           "`AutoReset(task).step` with random actions, in the same process; peak device memory "
           "of that process (replay of 10,000 unrolls included):", "",
           "| task | device | physics | physics matmuls | envs | updates / iteration | "
           "first episodes | loop | env only | loop/env | ms / update | peak memory | "
           "other XLA flags |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for r in sorted(newest.values(),
                  key=lambda r: (_order(r["task"]), r["num_envs"], _matmuls(r), _xla_flags(r))):
    memory = r.get("peak_memory_bytes")
    lines.append(f"| {r['task']} | `{r['device']}` | {r['physics']} | {_matmuls(r)} | "
                 f"{r['num_envs']} | {r['settings']['updates_per_iteration']} | "
                 f"{_episodes(r)} | {_k(r['sps'])} | "
                 f"{_k(r['env_sps'])} | {r['ratio_to_env']:.2f} | {r['update_ms']:.1f} | "
                 f"{'-' if memory is None else f'{memory / 2**30:.1f} GiB'} | "
                 f"{_xla_flags(r)} |")
  return "\n".join(lines)


def experts_table(folder: str = EXPERTS) -> str:
  """One row per shipped expert file, from its metadata (the file's checksum is verified)."""
  rows = []
  for path in sorted(glob.glob(os.path.join(folder, "*.npz"))):
    _, meta = policy_io.load_policy(path)
    rows.append((meta, os.path.basename(path)))
  if not rows:
    return "No shipped experts yet."
  lines = ["Expert policies shipped in `tasks/experts/` (`scripts/make_demos.py --task <name>` "
           "records demonstrations from them). Return: mean of the evaluation episodes at export "
           "(policy mean action), on the device it was trained on:", "",
           "| task | file | return | paper's expert | env steps | envs | updates / iteration | "
           "physics | sha256 |", "|---|---|---|---|---|---|---|---|---|"]
  for meta, name in sorted(rows, key=lambda r: _order(r[0]["task"])):
    config = meta.get("train_config", {})
    paper = PAPER_EXPERT.get(meta["task"])
    lines.append(f"| {meta['task']} | `{name}` | {meta['eval_return']:.1f} | "
                 f"{'-' if paper is None else f'{paper:.1f}'} | {meta['env_steps'] / 1e6:.1f}M | "
                 f"{config.get('num_envs', '-')} | {config.get('updates_per_iteration', '-')} | "
                 f"{meta.get('physics', '-')} | `{meta['sha256'][:12]}` |")
  return "\n".join(lines)


def render(readme: str, records: list[dict]) -> str:
  for name, table in (("experts", experts_table()), ("throughput", throughput_table(records)),
                      ("parity", parity_table(records)), ("sweep", sweep_table(records)),
                      ("learning", learning_table(records)),
                      ("train_throughput", train_throughput_table(records))):
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
