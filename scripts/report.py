#!/usr/bin/env python3
"""Writes the generated tables of README.md and benchmarks/NOTES.md from
benchmarks/results/*.jsonl (with their packed curves, *.curve.jsonl.gz) and the shipped experts
in tasks/experts/*.npz. `--check` writes nothing and exits 1 where a table differs; either way
it exits 1 where a result file holds FORM learning-curve rows not packed
(scripts/pack_results.py).

  python scripts/report.py           # rewrite the tables in both files
  python scripts/report.py --check   # exit 1 if either file is not what the results give

Each table sits between `<!-- name:begin -->` and `<!-- name:end -->` markers. The README holds
compact tables (Table 1, FORM results, shipped experts, parity per task, scaling);
benchmarks/NOTES.md holds the full ones (every parity, throughput, solver-sweep, learning-run and
its per-task summary, training-loop, population, scaling, demonstrator and baseline record). The tables are never
typed by hand: each comes from the newest record per (task, mode, size, device) in the result files.
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

from mjx_form.files import effect_models, policy_io, results  # noqa: E402  (no JAX)
from mjx_form import paper  # noqa: E402  (constants only)
from mjx_form.imitation import settings as form_settings  # noqa: E402  (constants; no JAX)
from mjx_form.cpu import CPU_XLA_FLAG  # noqa: E402  (os only)

# = tasks.EXPERTS_DIR (not imported from there: importing tasks starts JAX)
EXPERTS = os.path.join(ROOT, "tasks", "experts")
DEMONSTRATORS = os.path.join(ROOT, "tasks", "demonstrators")
# Demonstrators shipped before (the runs that used them keep their demonstrations' return).
FORMER_DEMONSTRATORS = os.path.join(ROOT, "benchmarks", "demonstrators")
ARCHIVED_DEMONSTRATORS = os.path.join(FORMER_DEMONSTRATORS, "archived.json")  # (in git history)
PAPER_EXPERT, PAPER_FORM = paper.EXPERT, paper.FORM
RESULTS = os.path.join(ROOT, "benchmarks", "results")
README = os.path.join(ROOT, "README.md")
NOTES = os.path.join(ROOT, "benchmarks", "NOTES.md")
TASK_ORDER = ["reacher_easy", "reacher_hard", "cheetah_run", "quadruped_walk", "quadruped_run",
              "hopper_stand", "hopper_hop", "walker_stand", "walker_walk", "walker_run",
              "humanoid_stand", "humanoid_walk", "humanoid_run"]


def read_records(folder: str = RESULTS) -> list[dict]:
  """Every record of the folder's `.jsonl` files and packed curves (`.curve.jsonl.gz`,
  mjx_form/files/results.py), whole (compact rows filled in), each with the name of its run's
  `.jsonl` file as `_file` and of the file it was read from as `_source`."""
  paths = sorted(glob.glob(os.path.join(folder, "*.jsonl"))
                 + glob.glob(os.path.join(folder, "*" + results.CURVE_SUFFIX)))
  return [{**record, "_file": os.path.basename(
               results.run_path(path) if path.endswith(results.CURVE_SUFFIX) else path),
           "_source": os.path.basename(path)}
          for path in paths for record in results.read_records(path)]


def unpacked_files(records: list[dict]) -> list[str]:
  """The `.jsonl` files (of `read_records`' records) that hold rows `scripts/pack_results.py`
  moves to a packed curve."""
  return sorted({r["_source"] for r in records
                 if r["_source"].endswith(".jsonl") and results.is_packed_row(r)})


def _newest(records: list[dict], key) -> dict:
  out = {}
  for r in sorted(records, key=lambda r: r.get("time", "")):
    out[key(r)] = r
  return out


def _order(task: str) -> int:
  return TASK_ORDER.index(task) if task in TASK_ORDER else len(TASK_ORDER)


def _k(x: float) -> str:
  return f"{x / 1e6:.2f}M" if x >= 1e6 else f"{x / 1e3:.0f}k" if x >= 1e3 else f"{x:.0f}"


def _steps(x: float) -> str:
  """Env steps as the baselines table writes them: `10.2M`, or `64k` below a million (BC's CPU
  runs; the other tables keep `0.2M`)."""
  return f"{x / 1e6:.1f}M" if x >= 1e6 else _k(x)


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
              "| task | physics | qpos | qvel | observation | reward |",
              "|---|---|---|---|---|---|"]
    for r in sorted(sel, key=lambda r: (_order(r["task"]), r["physics"] != "parity")):
      cells = [f"{r[f]['median']:.0e} / {r[f]['max']:.0e}"
               for f in ("qpos_error", "qvel_error", "obs_error", "reward_error")]
      lines.append(f"| {r['task']} | {r['physics']} | " + " | ".join(cells) + " |")
    lines.append("")
  return "\n".join(lines).rstrip()


def parity_summary(records: list[dict], physics: str = "parity") -> str:
  """One row per task: the one-step error of `physics` mode on the CPU, and qvel / observation
  on the GPU with full-float32 matmuls (the full tables are `parity_table`)."""
  rows = [r for r in records if r.get("kind") == "parity" and r["physics"] == physics]
  cpu = _newest([r for r in rows if r["device"].startswith("cpu")], lambda r: r["task"])
  gpu = _newest([r for r in rows if r["device"].startswith("gpu") and _matmuls(r) == "float32"],
                lambda r: r["task"])
  if not cpu and not gpu:
    return "No parity results yet."
  cpu_devices = ", ".join(f"`{d}`" for d in sorted({r["device"] for r in cpu.values()})) or "-"
  gpu_devices = ", ".join(f"`{d}`" for d in sorted({r["device"] for r in gpu.values()})) or "-"
  sizes = sorted({r["settings"].get("num_transitions") for r in [*cpu.values(), *gpu.values()]},
                 key=str)
  lines = [f"One control step of `{physics}` physics in float32 from "
           f"{'/'.join(str(n) for n in sizes)} dm_control states under random actions: largest "
           f"absolute error per transition against dm_control's next state, median / max over "
           f"transitions, on the CPU ({cpu_devices}) and on the GPU ({gpu_devices}, matmuls in "
           f"full float32). Both physics modes and TF32 matmuls: `benchmarks/NOTES.md`.", "",
           "| task | qpos | qvel | observation | reward | GPU qvel | GPU observation |",
           "|---|---|---|---|---|---|---|"]
  cell = lambda r, f: f"{r[f]['median']:.0e} / {r[f]['max']:.0e}" if r else "-"
  for task in sorted(set(cpu) | set(gpu), key=_order):
    c, g = cpu.get(task), gpu.get(task)
    lines.append(f"| {task} | " + " | ".join(
        [cell(c, f) for f in ("qpos_error", "qvel_error", "obs_error", "reward_error")]
        + [cell(g, "qvel_error"), cell(g, "obs_error")]) + " |")
  return "\n".join(lines)


def sweep_table(records: list[dict]) -> str:
  """`kind: solver_sweep`: per task and solver settings the raw physics' speed (newest record)
  and its one-step error, a column per set of dm_control states (errors over different states
  are not compared in one column)."""
  rows = [r for r in records if r.get("kind") == "solver_sweep"]
  if not rows:
    return "No solver sweep results yet."
  states = lambda r: r["settings"].get("num_transitions", 0) if r["measured"] == "error" else 0
  newest = _newest(rows, lambda r: (r["task"], _solver(r["settings"]["solver"]), r["measured"],
                                    states(r)))
  speed = {k[:2]: r for k, r in newest.items() if k[2] == "speed"}
  size = lambda r: (r["task"], r["device"], r["settings"]["num_envs"])
  parity = _newest([r for r in rows if r["measured"] == "speed"
                    and _solver(r["settings"]["solver"]) == "100/50"], size)
  error = {(*k[:2], k[3]): r for k, r in newest.items() if k[2] == "error"}
  counts = sorted({k[2] for k in error})
  iterations = lambda solver: [-int(v) for v in solver.split()[0].split("/")]
  keys = sorted(set(speed) | {k[:2] for k in error},  # by task, most iterations, culling last
                key=lambda k: (_order(k[0]), *iterations(k[1]), "cull" in k[1]))
  first = next(iter(speed.values()), None)
  lines = [f"Raw `mjx.step` control steps per second at "
           f"{first['settings']['num_envs'] if first else '-'} envs on "
           f"`{first['device'] if first else '-'}`, and the one-step qvel error against "
           "dm_control's next state (float32, CPU: median / p90 / max over the transitions from "
           "N dm_control states under random actions, a column per set of states):", "",
           "| task | solver (iterations / line search) | raw steps/s | x parity | "
           + " | ".join(f"qvel error, {n} states" for n in counts) + " |",
           "|---|---|---|---|" + "---|" * len(counts)]
  for task, solver in keys:
    s = speed.get((task, solver))
    sps = f"{_k(s['raw_sps'])} | {_over_parity(s, parity.get(size(s)))}" if s else "- | -"
    errors = []
    for n in counts:
      e = error.get((task, solver, n))
      errors.append(f"{e['qvel_error']['median']:.0e} / {e['qvel_error']['p90']:.0e} / "
                    f"{e['qvel_error']['max']:.0e}" if e else "-")
    lines.append("| " + " | ".join([task, solver, sps, *errors]) + " |")
  return "\n".join(lines)


def _over_parity(speed: dict, parity: dict | None) -> str:
  """A sweep record's speed-up over dm_control's settings: its own where its run started from
  them (`speedup_over_parity`, older records), else against `parity`, the newest parity record
  of the same task, device and size ('-' where there is none)."""
  if "speedup_over_parity" in speed:
    return f"{speed['speedup_over_parity']:.2f}"
  return "-" if parity is None else f"{speed['raw_sps'] / parity['raw_sps']:.2f}"


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


def _member(record: dict) -> str:
  """The settings a population's members may differ in besides the seed (mjx_form/rl/grid.py):
  with the result file, task and seed it names one run."""
  settings = record.get("settings", {})
  reward = settings.get("reward", {})
  learner = settings.get("learner")
  if learner is not None:  # settings added later, at the value that ran before them (a run
    # resumed across one keeps one key): sampled_q_float32_head (2026-11-29), cloning_loss
    # (2026-12-01), mpo.clip_mean_targets (2026-12-07)
    learner = {k: v for k, v in learner.items()
               if (k, v) not in (("sampled_q_float32_head", False), ("cloning_loss", "likelihood"))}
    if learner.get("mpo", {}).get("clip_mean_targets") is False:
      learner["mpo"] = {k: v for k, v in learner["mpo"].items() if k != "clip_mean_targets"}
  return json.dumps([learner, reward.get("standardise_reward"),
                     reward.get("reward_clip", 0.0), settings.get("action_noise_correlation", 0.0),
                     settings.get("wrap_angles", False), settings.get("init_policy"),
                     *([True] if settings.get("angle_features") else []),
                     *([low] if (low := settings.get("noise_scale_min", 1.0)) != 1.0 else []),
                     # (records leave out the default, the mixture)
                     *([mean] if (mean := reward.get("ensemble_log_pd", "mixture")) != "mixture"
                       else [])],
                    sort_keys=True)


def _learner_notes(record: dict, with_period: bool = True,
                   with_penalty: bool = True) -> list[str]:
  """A run's learner settings that differ from the paper's: e.g. ['T 25', 'critic clips
  actions', 'acme policy head']; [] for the paper's."""
  settings = record.get("settings", {})
  learner = settings.get("learner", {})
  notes = []
  if with_period and learner.get("target_update_period", 200) != 200:
    notes.append(f"T {learner['target_update_period']}")
  if learner.get("clip_critic_actions"):
    notes.append("critic clips actions")
  if learner.get("sampled_q_bfloat16"):
    notes.append("sampled Q in " + results.sampled_q_precision(learner))
  if with_penalty and learner.get("mpo", {}).get("action_penalty"):
    notes.append("action penalty")
  if learner.get("mpo", {}).get("clip_mean_targets"):
    notes.append("mean fitted to clipped actions")
  if (epsilon_scale := learner.get("mpo", {}).get("epsilon_scale", 1e-5)) != 1e-5:
    notes.append(f"epsilon_scale {epsilon_scale:g}")
  if settings.get("network_width", 256) != 256:
    notes.append(f"networks {settings['network_width']} wide")
  head = settings.get("policy_head", "paper")
  if head != "paper":
    notes.append(f"{head} policy head")
  correlation = settings.get("action_noise_correlation", 0.0)
  if correlation:
    notes.append(f"actor noise correlated {correlation:g}")
  if (low := settings.get("noise_scale_min", 1.0)) < 1.0:
    notes.append(f"envs' noise scaled {low:g} to 1")
  if settings.get("wrap_angles"):
    notes.append("angles wrapped")
  if settings.get("angle_features"):
    notes.append("angles as cos and sin")
  if settings.get("init_policy"):  # "<task> <sha256>": the trained policy it started from
    task, _, digest = settings["init_policy"].partition(" ")
    notes.append(f"started from {task}'s policy {digest[:8]}")
  return notes


def _learner_label(record: dict) -> str:
  """`_learner_notes` as a table cell: e.g. 'sampled Q in bf16', '-' for the paper's."""
  return ", ".join(_learner_notes(record)) or "-"


def _expert_runs(records: list[dict]) -> dict[tuple, list[dict]]:
  """{(result file, task, seed, member settings): its learning-curve records} of the expert
  runs (task reward; records before FORM existed carry method "expert" or none)."""
  runs: dict[tuple, list[dict]] = {}
  for r in records:
    if r.get("kind") == "learning_curve" and r.get("method", "expert") == "expert":
      runs.setdefault((r["_file"], r["task"], r["seed"], _member(r)), []).append(r)
  return runs


def _eval_episodes(runs: dict[tuple, list[dict]]) -> str:
  """The runs' evaluation sizes, e.g. '16 or 32'."""
  sizes = sorted({curve[0]["settings"]["eval_episodes"] for curve in runs.values()})
  return " or ".join(map(str, sizes))


def _from_scratch(curve: list[dict]) -> bool:
  """Whether a run started from its networks' initialisation, not from a trained policy
  (`--init_policy`, whose clock does not include that policy's training)."""
  return not curve[0].get("settings", {}).get("init_policy")


def _resumed(curve: list[dict]) -> bool:
  """Whether a run's curve (in iteration order) is the part of a run after a `--resume` in a
  result file of its own: its records say it started past iteration 0 (`start_iteration`,
  recorded since 2026-11-29), or, in older records, its first evaluation lies more than one
  evaluation interval past iteration 0."""
  if "start_iteration" in curve[0]:
    return curve[0]["start_iteration"] > 0
  # (Three rows at least: the first two then are regular evaluations, not a run's last row,
  # logged where a time budget stopped it. Fewer, or rows without iterations: a whole run.)
  if len(curve) < 3 or "iteration" not in curve[0] or "iteration" not in curve[1]:
    return False
  first, second = curve[0]["iteration"], curve[1]["iteration"]
  return first > second - first


def _fastest_to(curves: list[list[dict]], threshold: float, task: str) -> str:
  """Wall clock (env steps, run) of the fastest of `curves` to a first evaluation at or above
  `threshold`, or "not reached". A resumed part that starts at or above it passed it before
  (in another part), so it is not a first evaluation there."""
  reached = [next((r for r in c if r["eval_return"] >= threshold), None) for c in curves]
  reached = [r for r, c in zip(reached, curves)
             if r is not None and not (_resumed(c) and r is c[0])]
  if not reached:
    return "not reached"
  fastest = min(reached, key=lambda r: r["wall_s"])
  return (f"{_duration(fastest['wall_s'])} ({fastest['env_steps'] / 1e6:.1f}M, "
          f"{_run_label(fastest['_file'], task)})")


# The reference of issue 17's cheetah_run target: Brax's PPO on the same GPU model, measured
# once outside this repository (benchmarks/NOTES.md, "Targets of issue 3").
BRAX_PPO_CHEETAH_800 = {"return": 800.0, "seconds": 161, "device": "an H200",
                        "date": "2026-11-22"}


def learning_summary(records: list[dict], threshold: float = 800.0) -> str:
  """One row per task: how many expert runs, the highest evaluation of any of them, and the
  fastest run to a first evaluation at or above `threshold` and at or above the experts bar
  (0.95x the paper's expert: the time to expert)."""
  runs = _expert_runs(records)
  if not runs:
    return "No learning results yet."
  lines = [f"Expert runs (`--method expert`) per task; the full table, one row per run with its "
           f"settings, follows. Evaluation: mean task return of "
           f"{_eval_episodes(runs)} episodes (a run's `--eval_envs`) with the "
           f"policy's mean action; wall clock includes start-up (compiling, or loading from "
           f"JAX's persistent compilation cache; a run resumed from its checkpoint, `--resume`, "
           f"continues from the wall clock logged at the checkpoint, each start-up included). "
           f"Runs: the runs started (a resumed run's later part in another result file is not "
           f"counted again). Time to expert: the fastest run to a first evaluation at or above "
           f"{paper.EXPERT_BAR}x the paper's expert return (runs that started from a trained "
           f"policy, `--init_policy`, count for the highest evaluation, not for the times from "
           f"scratch: where one reached the bar, its time follows apart, `from a trained "
           f"policy`, a clock that leaves out that policy's own training; a "
           f"resumed part whose first evaluation is already above a threshold counts not for "
           f"that threshold, first passed before it):", "",
           f"| task | runs | highest evaluation (env steps, run) | first evaluation >= "
           f"{threshold:.0f}, fastest run: wall clock (env steps, run) | {paper.EXPERT_BAR}x "
           f"paper's expert | time to expert: wall clock (env steps, run) |",
           "|---|---|---|---|---|---|"]
  curves_of = {task: [sorted(c, key=lambda r: r["env_steps"]) for key, c in runs.items()
                      if key[1] == task] for task in TASK_ORDER}
  for task, curves in curves_of.items():
    bar = paper.EXPERT_BAR * PAPER_EXPERT[task]
    if not curves:
      lines.append(f"| {task} | 0 | - | - | {bar:.1f} | no runs yet |")
      continue
    best = max((r for c in curves for r in c), key=lambda r: r["eval_return"])
    scratch = [c for c in curves if _from_scratch(c)]
    started = sum(not _resumed(c) for c in curves)
    to_expert = _fastest_to(scratch, bar, task)
    trained = _fastest_to([c for c in curves if not _from_scratch(c)], bar, task)
    if trained != "not reached":
      to_expert += f"; from a trained policy: {trained}"
    lines.append(f"| {task} | {started} | {best['eval_return']:.1f} "
                 f"({best['env_steps'] / 1e6:.1f}M, {_run_label(best['_file'], task)}) | "
                 f"{_fastest_to(scratch, threshold, task)} | {bar:.1f} | {to_expert} |")
  cheetah = [c for c in curves_of["cheetah_run"] if _from_scratch(c)]
  cold = [c for c in cheetah if c[0].get("persistent_cache_hits") == 0]
  if cheetah and threshold == BRAX_PPO_CHEETAH_800["return"]:
    lines += ["", f"cheetah_run against Brax PPO: Brax's PPO reached "
              f"{BRAX_PPO_CHEETAH_800['return']:.0f} in {BRAX_PPO_CHEETAH_800['seconds']} s on "
              f"{BRAX_PPO_CHEETAH_800['device']}, compilation included (measured "
              f"{BRAX_PPO_CHEETAH_800['date']}, `benchmarks/NOTES.md`); the fastest run here: "
              f"{_fastest_to(cheetah, threshold, 'cheetah_run')}; the fastest that compiled "
              f"every program (no persistent-cache hits recorded): "
              f"{_fastest_to(cold, threshold, 'cheetah_run') if cold else 'none recorded'}."]
  return "\n".join(lines)


def learning_table(records: list[dict], threshold: float = 800.0) -> str:
  """One row per learning run (a result file's records of one task and seed)."""
  runs = _expert_runs(records)
  if not runs:
    return "No learning results yet."
  lines = [f"Expert runs (MPO + Retrace on the task reward, one seed each). Evaluation: mean "
           f"task return of {_eval_episodes(runs)} full episodes (a run's `--eval_envs`) "
           f"with the "
           f"policy's mean action. Wall clock includes compilation (and each restart's "
           f"compilation where a run was continued with --resume; a resumed run's part in a "
           f"result file of its own says when it passed the threshold \"in this part\", which "
           f"an earlier part may have passed before); start-up: its part before the "
           f"first iteration (building, tracing, compiling; `cached`: programs loaded from JAX's "
           f"persistent compilation cache), recorded since 2026-11-22. First episodes: `lockstep` "
           f"= all environments started together, `staggered` = at random phases (see "
           f"above). Action penalty: MPO's penalty on actions outside [-1, 1] and its KL "
           f"bound (`--action_penalty`), `-` = off.", "",
           "| task | device | physics matmuls | envs | updates / iteration (replay ratio) | "
           "first episodes | action penalty | env steps | wall clock | start-up | final eval | "
           f"best eval | first eval >= {threshold:.0f}: wall clock (env steps) | result file |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for (_, task, _, _), curve in sorted(runs.items(), key=lambda kv: (
      _order(kv[0][1]), kv[1][0]["num_envs"], kv[0][0], kv[0][2], kv[0][3])):
    curve = sorted(curve, key=lambda r: r["env_steps"])
    last, best = curve[-1], max(curve, key=lambda r: r["eval_return"])
    reached = next((r for r in curve if r["eval_return"] >= threshold), None)
    first = (f"{_duration(reached['wall_s'])} ({reached['env_steps'] / 1e6:.1f}M)" if reached
             else "not reached")
    if reached is not None and _resumed(curve):  # (an earlier part may have passed it)
      first = "before this part" if reached is curve[0] else f"in this part: {first}"
    settings = last["settings"]
    physics = [f"{last['physics']} physics"] if last.get("physics", "fast") != "fast" else []
    notes = ", ".join(physics + _learner_notes(last, with_penalty=False))  # (its own column)
    lines.append(f"| {task} | `{last['device']}` | {_matmuls(last)} | {last['num_envs']} | "
                 f"{settings['updates_per_iteration']} ({settings['replay_ratio']:g}) | "
                 f"{_episodes(last)} | {_action_penalty(last)} | "
                 f"{last['env_steps'] / 1e6:.1f}M | {_duration(last['wall_s'])} | "
                 f"{_startup(curve[0])} | "
                 f"{last['eval_return']:.1f} | {best['eval_return']:.1f} | {first} | "
                 f"{_run_label(last['_file'], task)}{f' ({notes})' if notes else ''} |")
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
  newest = _newest(rows, lambda r: (r["task"], r["num_envs"], r["device"], r["physics"],
                                    _matmuls(r), r["settings"]["updates_per_iteration"],
                                    _episodes(r), _xla_flags(r), _learner_label(r)))
  lines = ["Environment steps per second of one whole training iteration (collect 100-step "
           "unrolls, normaliser, replay insert, MPO/Retrace updates) beside env-only "
           "`AutoReset(task).step` with random actions, in the same process; peak device memory "
           "of that process (replay of 10,000 unrolls included); learner: its settings that "
           "differ from the paper's:", "",
           "| task | device | physics | physics matmuls | envs | updates / iteration | "
           "learner | first episodes | loop | env only | loop/env | ms / update | peak memory | "
           "other XLA flags |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for r in sorted(newest.values(),
                  key=lambda r: (_order(r["task"]), r["num_envs"], r["physics"], _matmuls(r),
                                 _xla_flags(r), _learner_label(r))):
    memory = r.get("peak_memory_bytes")
    lines.append(f"| {r['task']} | `{r['device']}` | {r['physics']} | {_matmuls(r)} | "
                 f"{r['num_envs']} | {r['settings']['updates_per_iteration']} | "
                 f"{_learner_label(r)} | {_episodes(r)} | {_k(r['sps'])} | "
                 f"{_k(r['env_sps'])} | {r['ratio_to_env']:.2f} | {r['update_ms']:.1f} | "
                 f"{'-' if memory is None else f'{memory / 2**30:.1f} GiB'} | "
                 f"{_xla_flags(r)} |")
  return "\n".join(lines)


def _shipped_experts(folder: str = EXPERTS) -> list[tuple[dict, str]]:
  """(metadata, file name) of each shipped expert file (its checksum is verified)."""
  rows = []
  for path in sorted(glob.glob(os.path.join(folder, "*.npz"))):
    _, meta = policy_io.load_policy(path)
    rows.append((meta, os.path.basename(path)))
  return sorted(rows, key=lambda r: _order(r[0]["task"]))


def _shipped_expert_returns() -> dict[str, float]:
  """{task: the shipped expert's return at export}: what a table compares with by default."""
  return {meta["task"]: meta["eval_return"] for meta, _ in _shipped_experts()}


def _final_as_fresh(record: dict) -> dict:
  """A run's final evaluation of one policy file (`kind: final_return`) in the fields of a
  `kind: expert_eval` record: that file evaluated afresh, by its mean action."""
  std, n = record.get("final_return_std"), record["episodes"]
  return {"policy_sha256": record["policy_sha256"], "episodes": n,
          "mean_return": record["final_return"],
          "stderr_return": None if std is None else std / n ** 0.5,
          "device": record["device"], "time": record.get("time", "")}


def _fresh_evaluations(records: list[dict]) -> dict[str, dict]:
  """{policy sha256: its fresh evaluation of the most episodes (then the newest)}, policy mean
  action only: `kind: expert_eval` records, and runs' final evaluations of a policy file
  (`kind: final_return`, not those with sampled actions)."""
  evals = [r for r in records if r.get("kind") == "expert_eval" and not r.get("stochastic")]
  evals += [_final_as_fresh(r) for r in records
            if r.get("kind") == "final_return" and "policy_sha256" in r and "episodes" in r
            and r.get("policy") != "final_sampled"]
  best = {}
  for r in sorted(evals, key=lambda r: (r["episodes"], r.get("time", ""))):
    best[r["policy_sha256"]] = r
  return best


def experts_table(records: list[dict] = (), folder: str = EXPERTS) -> str:
  """One row per shipped expert file, from its metadata, with its fresh evaluation of the most
  episodes (`kind: expert_eval`, benchmarks/expert_eval.py) and its newest evaluation in
  dm_control (`kind: expert_transfer`, full episodes) where there are."""
  rows = _shipped_experts(folder)
  if not rows:
    return "No shipped experts yet."
  fresh = _fresh_evaluations(records)
  transfer = _newest([r for r in records if r.get("kind") == "expert_transfer"
                      and "mjx_return" in r], lambda r: r["policy_sha256"])
  bar = paper.EXPERT_BAR
  lines = ["Expert policies shipped in `tasks/experts/` (`scripts/make_demos.py --task <name>` "
           "records demonstrations from them), policy mean action. At export: the best of the "
           "run's periodic evaluations (16-32 episodes; biased upwards); fresh: a later "
           "evaluation of the file over the most episodes measured "
           "(`benchmarks/expert_eval.py`, `kind: "
           "expert_eval`, or the final evaluation of the run that wrote it), mean +- standard "
           "error; dm_control: the same policy in dm_control's "
           "own environment against as many MJX episodes on the CPU "
           f"(`benchmarks/dm_control_transfer.py`), and their ratio; bar: {bar}x the paper's "
           "expert, judged on the fresh evaluation:",
           "", "| task | file | at export | fresh (episodes, device) | dm_control / MJX "
           "(episodes) | ratio | paper's expert | bar | env steps | envs | updates / "
           "iteration | physics | sha256 |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for meta, name in rows:
    config = meta.get("train_config", {})
    expected = PAPER_EXPERT.get(meta["task"])
    ev = fresh.get(meta["sha256"])
    fresh_text, bar_text = "-", "-"
    if ev:
      err = ev.get("stderr_return")
      fresh_text = (f"{ev['mean_return']:.1f}{'' if err is None else f' +- {err:.1f}'} "
                    f"({ev['episodes']}, {ev['device'].split(':')[0]})")
      if expected is not None:
        bar_text = "met" if ev["mean_return"] >= bar * expected else (
            f"below ({bar * expected:.1f})")
    moved = transfer.get(meta["sha256"])
    moved_text = (f"{moved['dm_control_return']:.1f} / {moved['mjx_return']:.1f} "
                  f"({moved['episodes']}) | {moved['ratio']:.3f}" if moved else "- | -")
    lines.append(f"| {meta['task']} | `{name}` | {meta['eval_return']:.1f} | {fresh_text} | "
                 f"{moved_text} | "
                 f"{'-' if expected is None else f'{expected:.1f}'} | {bar_text} | "
                 f"{meta['env_steps'] / 1e6:.1f}M | "
                 f"{config.get('num_envs', '-')} | {config.get('updates_per_iteration', '-')} | "
                 f"{meta.get('physics', '-')} | `{meta['sha256'][:12]}` |")
  return "\n".join(lines)


def _mean_std(values: list[float]) -> tuple[float, float]:
  """Mean and population standard deviation (0 for one value)."""
  mean = sum(values) / len(values)
  return mean, (sum((v - mean) ** 2 for v in values) / len(values)) ** 0.5


def _demonstrator_metadata(folders: tuple[str, ...]) -> list[dict]:
  """Metadata of the demonstrator files in `folders` (checksums verified)."""
  return [effect_models.load_effect_model(path).metadata
          for path in sorted(p for f in folders for p in glob.glob(os.path.join(f, "*.npz")))]


def _demonstration_returns(folders: tuple[str, ...] = (DEMONSTRATORS, FORMER_DEMONSTRATORS),
                           archived: str = ARCHIVED_DEMONSTRATORS) -> dict[str, float]:
  """{demonstrator sha256: mean return of the demonstrations it was trained on} of the shipped
  demonstrators, the former ones kept in benchmarks/demonstrators/ (checksums verified) and
  those archived in git history (`archived`, scripts/archive_demonstrators.py)."""
  out = {}
  for meta in _demonstrator_metadata(folders):
    expert = meta["demonstrations"].get("expert", {})
    if "mean_return" in expert:
      out[meta["sha256"]] = expert["mean_return"]
  if os.path.exists(archived):
    with open(archived) as f:
      for entry in json.load(f):
        if entry.get("demonstrations_mean_return") is not None:
          out[entry["sha256"]] = entry["demonstrations_mean_return"]
  return out


def _demonstration_return(sha256: str | None, returns: dict[str, float]) -> float | None:
  """The mean return of the demonstrations a run's demonstrator learned (`returns` by the
  demonstrator's sha256); an ensemble's ('+'-joined sha256s): the mean over its models, None
  where one is unknown."""
  parts = [returns.get(sha) for sha in (sha256 or "").split("+")]
  return None if None in parts else sum(parts) / len(parts)


def _form_variant(record: dict) -> str:
  """How a FORM run used its reward, its learner's target period and its effect models'
  regularisers: e.g. `raw, T 200, ar 1, L2 0.1`."""
  settings = record.get("settings", {})
  reward = "standardised" if settings.get("reward", {}).get("standardise_reward") else "raw"
  if settings.get("reward", {}).get("reward_clip", 0.0) > 0:
    reward += f" clipped at {settings['reward']['reward_clip']:g} sd"
  period = settings.get("learner", {}).get("target_update_period", "-")
  model = settings.get("reward", {}).get("effect_model", {})
  regularisers = ([f"ar {model['beta_ar']:g}, L2 {model['l2']:g}"]
                  if "beta_ar" in model and "l2" in model else [])
  # (a record's models carry their period; `_default_form_variant`'s the task's setting, read
  # without building the task, which would need JAX)
  if any(model.get("period") or ()) or model.get("turn_invariant"):
    regularisers.append("turn-invariant")
  if model.get("angle_increments"):
    regularisers.append("angle increments")
  if model.get("angle_inputs"):
    regularisers.append("angle inputs")
  if model.get("max_scale"):
    regularisers.append(f"scales below {model['max_scale']:g} sd")
  if settings.get("source_update_every", 1) != 1:  # (`--imitator_every`; records before it: 1)
    regularisers.append(f"imitator on 1 batch in {settings['source_update_every']}")
  if settings.get("reward", {}).get("demonstrators"):
    mean = settings["reward"].get("ensemble_log_pd") == "mean"  # (else their mixture)
    regularisers.append(f"ensemble of {settings['reward']['demonstrators']} demonstrators"
                        + (", mean log pD" if mean else ""))
  if settings.get("reward", {}).get("demonstrator_per_member"):  # (one row per demonstrator)
    regularisers.append(f"demonstrator {settings['reward']['demonstrator_sha256'][:6]} of one "
                        "per member")
  return ", ".join([reward, f"T {period}", *regularisers,
                    *_learner_notes(record, with_period=False)])


def _default_form_variant(task: str) -> str:
  """The `_form_variant` of a FORM run of `task` with every default of
  mjx_form/imitation/settings.py (what `--method form` runs unless told otherwise)."""
  run = form_settings.run_settings(task)
  return _form_variant({"settings": {
      "reward": {"standardise_reward": run["standardise_reward"],
                 "reward_clip": run["reward_clip"],
                 "effect_model": form_settings.effect_model_settings(task)},
      "learner": {"target_update_period": run["target_update_period"],
                  "sampled_q_bfloat16": run["sampled_q_bfloat16"],
                  "clip_critic_actions": run.get("clip_critic_actions", False),
                  "mpo": {"epsilon_scale": run.get("epsilon_scale", 1e-5)}},
      **{k: run[k] for k in form_settings.ACTOR_KEYS if k in run}}})


def form_runs_table(records: list[dict]) -> str:
  """One row per FORM learning run (result file and seed): its settings, where its periodic
  evaluations got, and its fresh final evaluation where it finished."""
  runs: dict[tuple, list[dict]] = {}
  finals: dict[tuple, float] = {}
  for r in records:
    if r.get("method") != "form":
      continue
    if r.get("kind") == "learning_curve" and r.get("eval_return") is not None:
      runs.setdefault((r["_file"], r["task"], r["seed"], _member(r)), []).append(r)
    elif r.get("kind") == "final_return" and r.get("policy") == "final":
      finals[(r["_file"], r["task"], r["seed"], _member(r))] = r["final_return"]
  if not runs:
    return "No FORM learning runs yet."
  lines = ["FORM learning runs, one row per run and seed (periodic evaluations: mean task "
           "return of the run's `--eval_envs` episodes; fresh: the final policy over "
           "`--final_eval_envs` episodes after training or where `--max_seconds` stopped it, "
           "`-` where a run has none (`scripts/evaluate_run.py` adds them); learner updates: "
           "MPO/Retrace updates per member at the last evaluation, the paper's Figure 1 shows "
           "an agent after 5M). Wall clock: from the start of training, compiling included "
           "(recording demonstrations and training a demonstrator come before it; records "
           "since 2026-11-27 keep those seconds as `pre_training_s`):", "",
           "| task | device | reward, T, effect models | envs | updates / iteration | seed | "
           "env steps | learner updates | wall clock | last eval | best eval | fresh eval | "
           "log pD at the end | result file |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for key, curve in sorted(runs.items(), key=lambda kv: (_order(kv[0][1]), kv[0][0],
                                                         kv[0][2], kv[0][3])):
    curve = sorted(curve, key=lambda r: r["env_steps"])
    last, best = curve[-1], max(curve, key=lambda r: r["eval_return"])
    fresh = finals.get(key)
    lines.append(f"| {key[1]} | `{last['device']}` | {_form_variant(last)} | "
                 f"{last['num_envs']} | {last['settings']['updates_per_iteration']} | "
                 f"{key[2]} | {last['env_steps'] / 1e6:.1f}M | {last['updates']:,} | "
                 f"{_duration(last['wall_s'])} | "
                 f"{last['eval_return']:.1f} | {best['eval_return']:.1f} | "
                 f"{'-' if fresh is None else f'{fresh:.1f}'} | "
                 f"{last['demonstrator_log_prob']:.1f} | {_run_label(key[0], key[1])} |")
  return "\n".join(lines)


def population_table(records: list[dict]) -> str:
  """`kind: population_throughput`: P runs in one program against one run, per task, device
  and environments per member; the speed-up against P = 1 of the same result file (one
  invocation of the benchmark, one version of the code), else, marked, of another file."""
  rows = [r for r in records if r.get("kind") == "population_throughput"]
  if not rows:
    return "No population throughput results yet."
  key = lambda r, p: (r.get("_file", ""), r["task"], r["device"], r["physics"], r["num_envs"],
                      p, r["settings"]["updates_per_iteration"], _learner_label(r), _layout(r))
  newest = _newest(rows, lambda r: key(r, r["members"]))
  # The same population on one device of the same model (the newest such record; from the
  # same result file where it has one), for rows measured over several devices.
  one_device = lambda r: (r["task"], _device_model(r["device"]) + " x1", r["physics"],
                          r["num_envs"], r["members"], r["settings"]["updates_per_iteration"],
                          _learner_label(r))
  alone = {}
  for r in sorted(newest.values(), key=lambda r: r.get("time", "")):
    if r.get("devices", 1) == 1:
      alone[one_device(r)] = alone[(r.get("_file", ""), *one_device(r))] = r
  lines = ["Populations (`Trainer(..., seeds=range(P))`, `benchmarks/train_throughput.py "
           "--members`): total env steps per second of the whole training iteration over all "
           "P members, its speed-up over P = 1 measured in the same result file, and the "
           "iteration's split into collection (all members' environments and policies) and "
           "updates (each member's `updates_per_iteration` MPO/Retrace updates, side by side); "
           "peak device memory of the process (each member's replay of 10,000 unrolls "
           "included); learner: its settings that differ from the paper's. Over several "
           "devices, the layout (whole members per device, or each member's environments, "
           "replay and batches split over the devices; ', per device' where each device "
           "stepped its own environments, `--per_device_env_steps`, else the batch was stepped "
           "as one) and the speed-up over the same population on one device of the same "
           "model:", "",
           "| task | device | physics | envs / member | updates / iteration | learner | P | "
           "total steps/s | speed-up over P = 1 | layout | over one device | iteration | "
           "collection | updates | ms / update / member | peak memory | result file |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  ordered = sorted(newest.values(), key=lambda r: (_order(r["task"]), r["device"],
                                                   r["physics"], r["num_envs"],
                                                   r.get("_file", ""),
                                                   r["members"], _layout(r)))
  # Where a result file has no P = 1, the newest P = 1 of the same task, device and settings
  # from another file stands in, marked with an asterisk.
  elsewhere = {k[1:]: r for k, r in sorted(newest.items(), key=lambda kr: kr[1].get("time", ""))
               if r["members"] == 1}
  starred = False
  for r in ordered:
    # P = 1 on several devices splits its environments (stepped per device as this row was).
    split = _layout(dict(r, layout="environments"))
    one = newest.get(key(r, 1)) or (newest.get(key(r, 1)[:-1] + (split,))
                                    if r.get("devices", 1) > 1 else None)
    speedup = f"{r['sps'] / one['sps']:.2f}x" if one else "-"
    over_one = "-"
    if r.get("devices", 1) > 1:
      same = alone.get((r.get("_file", ""), *one_device(r))) or alone.get(one_device(r))
      over_one = f"{r['sps'] / same['sps']:.2f}x" if same else "-"
    if one is None and key(r, 1)[1:] in elsewhere:
      speedup = f"{r['sps'] / elsewhere[key(r, 1)[1:]]['sps']:.2f}x*"
      starred = True
    updates_s = r["iteration_s"] - r["collect_s"]
    per_member = r["update_ms"] / r["members"]  # update_ms: all members' update, side by side
    memory = r.get("peak_memory_bytes")
    label = _run_label(r["_file"], "population_throughput") if "_file" in r else "-"
    lines.append(f"| {r['task']} | `{r['device']}` | {r['physics']} | {r['num_envs']} | "
                 f"{r['settings']['updates_per_iteration']} | {_learner_label(r)} | "
                 f"{r['members']} | {_k(r['sps'])} | "
                 f"{speedup} | {_layout(r)} | {over_one} | {r['iteration_s']:.2f} s | "
                 f"{r['collect_s']:.2f} s | "
                 f"{updates_s:.2f} s | {per_member:.2f} | "
                 f"{'-' if memory is None else f'{memory / 2**30:.1f} GiB'} | {label} |")
  if starred:
    lines += ["", "\\* over P = 1 of another result file (same task, device, physics, "
              "environments, updates and learner settings)."]
  return "\n".join(lines)


def _device_model(device: str) -> str:
  """'gpu:NVIDIA H200 x2' -> 'gpu:NVIDIA H200' (the count a record's device string ends with)."""
  model, _, count = device.rpartition(" x")
  return model if model and count.isdigit() else device


def _layout(record: dict) -> str:
  """How a record's members lay on its devices, and ', per device' where each device stepped
  its own environments (`per_device_env_steps`; else the batch was stepped as one): '-' on one
  device (where it makes no difference); records from before layouts existed split
  environments."""
  if record.get("devices", 1) == 1:
    return "-"
  per_device = ", per device" if record.get("per_device_env_steps") else ""
  return record.get("layout", "environments") + per_device


def scaling_table(records: list[dict]) -> str:
  """`kind: scaling` (benchmarks/scaling.py): steps/s on N devices of one host and the
  efficiency against N x one device of the same host, per task and mode."""
  rows = [r for r in records if r.get("kind") == "scaling"]
  if not rows:
    return ("No scaling results yet (`benchmarks/scaling.py`; measured on the GPU machines "
            "only).")
  per_device = lambda r: (r["total_envs"] // r["devices"], r["members"] // r["devices"]
                          if r["mode"] == "population" else r["members"])
  # The host: the device model without the count ("gpu:NVIDIA H200 x2" -> "gpu:NVIDIA H200"),
  # so that N devices compare with one of the same model.
  host = lambda r: _device_model(r["device"])
  key = lambda r, n, layout: (r["task"], r["mode"], host(r), r.get("physics", "fast"),
                              *per_device(r), r["settings"]["updates_per_iteration"],
                              _learner_label(r), n, layout)
  newest = _newest(rows, lambda r: key(r, r["devices"], _layout(r)))
  lines = ["Scaling over the devices of one host (`benchmarks/scaling.py`): total env steps per "
           "second of the whole training iteration (and of env-only stepping) on N devices; "
           "efficiency = steps/s on N devices / (N x steps/s on one device of the same host, "
           "same amounts per device). weak: one run, its environments, learner batch and "
           "replay per device fixed; population: members per device fixed, laid out whole "
           "members per device (members) or each member's environments, replay and batches "
           "split over the devices (environments), and ', per device' where each device stepped "
           "its own environments (`--per_device_env_steps`; else the batch was stepped as one "
           "program-wide batch); env-only stepping as the iteration steps, and beside a per "
           "device row the batch stepped as one:", "",
           "| task | mode | device | physics | learner | envs / device | updates / iteration | "
           "members | N | layout | iteration steps/s | efficiency | env-only steps/s | "
           "efficiency | env-only, batch as one | iteration | peak memory |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  ordered = sorted(newest.values(), key=lambda r: (_order(r["task"]), r["mode"], host(r),
                                                   r.get("physics", "fast"),
                                                   _learner_label(r), r["devices"],
                                                   _layout(r)))
  for r in ordered:
    one = newest.get(key(r, 1, "-"))
    n = r["devices"]
    eff = lambda field: f"{r[field] / (n * one[field]):.2f}" if one else "-"
    memory = r.get("peak_memory_bytes")
    lines.append(f"| {r['task']} | {r['mode']} | `{r['device']}` | {r.get('physics', 'fast')} | "
                 f"{_learner_label(r)} | "
                 f"{r['total_envs'] // n} | {r['settings']['updates_per_iteration']} | "
                 f"{r['members']} | {n} | {_layout(r)} | {_k(r['sps'])} | "
                 f"{eff('sps')} | {_k(r['env_sps'])} | {eff('env_sps')} | "
                 f"{_k(r['env_whole_batch_sps']) if r.get('env_whole_batch_sps') else '-'} | "
                 f"{r['iteration_s']:.2f} s | "
                 f"{'-' if memory is None else f'{memory / 2**30:.1f} GiB'} |")
  return "\n".join(lines)


def scaling_summary(records: list[dict]) -> str:
  """The README's view of `kind: scaling`: one row per task, mode, card, learner and layout
  with the iteration's env steps/s on one device and, on 2, 4 and 8, steps/s and efficiency
  (the newest record of each; the full table, env-only stepping included, is NOTES')."""
  rows = [r for r in records if r.get("kind") == "scaling"]
  if not rows:
    return "No scaling results yet (`benchmarks/scaling.py`)."
  group = lambda r: (r["task"], r["mode"], _device_model(r["device"]), _learner_label(r),
                     r.get("physics", "fast"), r["total_envs"] // r["devices"],
                     r["members"] // r["devices"] if r["mode"] == "population" else 1,
                     r["settings"]["updates_per_iteration"])
  newest = _newest(rows, lambda r: (*group(r), r["devices"], _layout(r)))
  counts = (2, 4, 8)
  lines = ["Scaling over the GPUs of one host (`benchmarks/scaling.py`; the batch stepped as one "
           "unless the mode says per device): total env steps/s of the training iteration on "
           "one GPU, and on N GPUs with its efficiency = steps/s / (N x steps/s on one GPU of the "
           "same model); weak: one run with the environments per GPU given; population: the "
           "members per GPU given (whole members per GPU, unless the mode says each member's "
           "environments are split over the GPUs); updates: the learner updates per iteration. "
           "Full table, env-only stepping too: `benchmarks/NOTES.md`.", "",
           "| task | mode | card | learner | updates | 1 GPU | "
           + " | ".join(f"{n} GPUs (efficiency)" for n in counts) + " |",
           "|---|---|---|---|---|---|" + "---|" * len(counts)]
  multi = sorted({(*group(r), _layout(r)) for r in newest.values() if r["devices"] > 1},
                 key=lambda g: (_order(g[0]), *g[1:]))
  for *g, layout in multi:
    one = newest.get((*g, 1, "-"))
    cells = []
    for n in counts:
      r = newest.get((*g, n, layout))
      cells.append("-" if r is None else _k(r["sps"]) + (
          f" ({r['sps'] / (n * one['sps']):.2f})" if one else ""))
    envs, members = g[5], g[6]
    size = (f"{members} x {envs // members} envs" if g[1] == "population" else f"{envs} envs")
    split = g[1] == "population" and layout.startswith("environments")
    mode = (f"{g[1]}, {size}/GPU" + (", environments split" if split else "")
            + ("" if g[4] == "fast" else f", physics {g[4]}")
            + (", per device" if layout.endswith("per device") else ""))
    lines.append(f"| {g[0]} | {mode} | {g[2].removeprefix('gpu:NVIDIA ')} | {g[3]} | {g[7]} | "
                 f"{_k(one['sps']) if one else '-'} | " + " | ".join(cells) + " |")
  return "\n".join(lines)


def _updates(record: dict) -> str:
  """A run's learner updates per iteration and its replay ratio (updates x batch / envs):
  e.g. '512 (64)'; '-' where its record does not say."""
  settings = record.get("settings", {})
  if "updates_per_iteration" not in settings:
    return "-"
  ratio = settings.get("replay_ratio")
  return f"{settings['updates_per_iteration']}" + ("" if ratio is None else f" ({ratio:g})")


def _form_groups(records: list[dict], best_per_task: bool,
                 shipped_demonstrators: set[str] | None = None
                 ) -> tuple[dict[tuple, dict[str, list[dict]]], dict[str, int]]:
  """FORM's configurations {key: {policy: the seeds' newest final_return records}} (only those
  with a final policy's) and how many each task has; with `best_per_task`, one per task
  (`form_table`'s rule)."""
  rows = [r for r in records if r.get("kind") == "final_return" and r.get("method") == "form"]
  if shipped_demonstrators is None:
    shipped_demonstrators = {meta["sha256"] for meta in _demonstrator_metadata((DEMONSTRATORS,))}
  newest = _newest(rows, lambda r: (r["task"], r["physics"], r["num_envs"], _updates(r),
                                    r["env_steps"], r.get("learner_preset"), r["device"],
                                    _form_variant(r), r.get("_file", ""), r["seed"],
                                    r["policy"]))
  groups: dict[tuple, dict[str, list[dict]]] = {}
  for key, r in newest.items():
    groups.setdefault(key[:9], {}).setdefault(r["policy"], []).append(r)
  groups = {key: g for key, g in groups.items() if g.get("final")}
  configurations = {task: sum(key[0] == task for key in groups) for task, *_ in groups}
  if best_per_task:
    def rank(key):
      final = groups[key]["final"]
      default = key[7] == _default_form_variant(key[0])
      shipped = all(r.get("settings", {}).get("reward", {}).get("demonstrator_sha256")
                    in shipped_demonstrators for r in final)
      return (len(final) >= 2, key[6].startswith("gpu"), shipped, default,
              len(final) if default else 0,
              _mean_std([r["final_return"] for r in final])[0])
    groups = {key: groups[key] for key in (max((k for k in groups if k[0] == task), key=rank)
                                           for task in configurations)}
  return groups, configurations


def _form_expert(task: str, final: list[dict], expert_returns: dict[str, float],
                 demonstration_returns: dict[str, float]) -> float | None:
  """The expert return a FORM configuration's seeds (`final`) are compared with: the mean
  return of the demonstrations their demonstrator learned, else the task's expert return."""
  shas = {r.get("settings", {}).get("reward", {}).get("demonstrator_sha256") for r in final}
  targets = {_demonstration_return(sha, demonstration_returns) for sha in shas}
  return (targets.pop() if len(targets) == 1 and None not in targets
          else expert_returns.get(task))


def form_table(records: list[dict], expert_returns: dict[str, float] | None = None,
               demonstration_returns: dict[str, float] | None = None,
               best_per_task: bool = False,
               shipped_demonstrators: set[str] | None = None, compact: bool = False) -> str:
  """FORM's results: one row per task and configuration, over its seeds. Each seed's return is
  its newest `kind: final_return` record of the final policy (a fresh evaluation after
  training). The expert's return it is compared with: the mean return of the demonstrations
  its demonstrator was trained on (`demonstration_returns`, by the demonstrator's sha256;
  default: the shipped demonstrators'), else `expert_returns` (default: the shipped experts'
  returns at export). A configuration is one result file's runs of one setting (two runs of a
  seed in two files are two runs). With `best_per_task`, one row per task, chosen among its
  configurations run with 2 seeds or more (else among all), then on a GPU (else all), then
  with the shipped demonstrator (`shipped_demonstrators`, sha256s; default: those in
  tasks/demonstrators/, so the row is what the shipped expert and demonstrator give): the
  default settings (`_default_form_variant`) with the most seeds, then the highest mean;
  without the default settings, the highest mean return. `compact` (the README's view, with
  `best_per_task`): the return, the policy chosen by log pD, the fractions and the settings;
  the other policies' columns stay in the full table."""
  if compact and not best_per_task:
    raise ValueError("form_table: compact is the per-task view (best_per_task)")
  groups, configurations = _form_groups(records, best_per_task, shipped_demonstrators)
  if not groups:
    return ("No FORM results yet: a run with `--final_eval_envs` > 0 writes `kind: "
            "final_return` records; copied to `benchmarks/results/`, they appear here.")
  if expert_returns is None:
    expert_returns = _shipped_expert_returns()
  if demonstration_returns is None:
    demonstration_returns = _demonstration_returns()
  if compact:
    return _form_compact(groups, configurations, expert_returns, demonstration_returns)
  caption = ("FORM (`--method form`), per task one configuration (one result file's runs of "
             "one setting; all of them: `benchmarks/NOTES.md`), among those run with 2 seeds "
             "or more on a GPU where there are any, with the shipped demonstrator (and so its "
             "expert) where any were: the default settings "
             "(`mjx_form/imitation/settings.py`, what `--method form` runs) with the most "
             "seeds, else the highest mean return: "
             if best_per_task else "FORM (`--method form`): ")
  lines = [caption + "return of the final policy in a fresh evaluation after "
           "training, or where the run's time budget stopped it (`stopped` beside its env "
           "steps; `--final_eval_envs` episodes per seed, policy mean action), mean +- "
           "standard deviation over seeds (each seed: its mean over the episodes); sampled: the "
           "final policy on the same episodes with its actions drawn from it each step (runs "
           "since 2026-11-29); best: the "
           "same for the policy of each run's best periodic evaluation by the task return; by "
           "log pD: by the demonstrator's log pD per transition of the evaluation's episodes, a "
           "choice made without the task reward (`best_log_pd_policy.npz`, runs since 2026-11-28; "
           "`-` before); average: the policy averaged over updates (`--policy_average_decay`, "
           "`average_policy.npz`; `-` where a run kept none), and its evaluation of highest "
           "log pD (`best_log_pd_average_policy.npz`, runs since 2026-11-29). Expert: the mean "
           "return "
           "of the demonstrations the run's demonstrator was trained on (1000 episodes of the "
           "shipped expert), else the shipped expert's return at export; fraction = FORM / "
           "expert; the paper's fraction is its FORM return over its expert's. Reward: `raw` = "
           "log pD - log pI as the paper, `standardised` = `--reward_scale standardised` (the "
           "default), `clipped at c sd` = `--reward_clip c` (the default 3); T = the learner's "
           "target period (the paper's is 200; the default 25); `sampled Q in bf16` = "
           "`--sampled_q_bfloat16` (the default; else float32, the paper's); ar, L2: "
           "the effect models' beta_ar and L2 weight; updates / iteration: the learner's "
           "updates per iteration of envs x unroll length env steps, the replay ratio (updates x "
           "batch / envs) beside it" + (
               "; configurations: how many the task has" if best_per_task else "") + ":",
           "",
           "| task | device | physics | envs | updates / iteration (replay ratio) | "
           "reward, T, effect models | seeds | episodes / seed | env steps "
           "| wall clock (mean) | FORM return | sampled | best policy | by log pD | "
           "average policy | "
           "average by log pD | expert | "
           "fraction | "
           "paper's fraction |" + (" configurations |" if best_per_task else ""),
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
           + ("---|" if best_per_task else "")]
  for key in sorted(groups, key=_form_key_order):
    task, physics, num_envs, updates, _, _, device, variant, _ = key
    c = _form_cells(key, groups[key], expert_returns, demonstration_returns)
    episodes = sorted({r["episodes"] for r in groups[key]["final"]})
    policies = [c[name] for name in FORM_POLICIES]
    lines.append(f"| {task} | `{device}` | {physics} | {num_envs} | {updates} | {variant} | "
                 f"{c['seeds']} | {'/'.join(str(e) for e in episodes)} | {c['env_steps']} | "
                 f"{c['wall']} | {c['return']} | {' | '.join(policies)} | "
                 f"{c['expert']} | {c['fraction']} | {c['paper']} |"
                 + (f" {configurations[task]} |" if best_per_task else ""))
  return "\n".join(lines)


# The policies beside the final one in the FORM tables, by `_form_groups`' group names: the final
# policy with sampled actions, the best by return, by log pD, the average, and its best by log pD.
FORM_POLICIES = ("final_sampled", "best", "best_log_pd", "average", "best_log_pd_average")


def _form_key_order(key: tuple):
  """The FORM tables' row order: task, then envs, then env steps (`_form_groups`' keys)."""
  return _order(key[0]), key[2], key[4], str(key)


def _form_cells(key: tuple, group: dict, expert_returns: dict,
                demonstration_returns: dict) -> dict[str, str]:
  """The texts both FORM tables show of one configuration (`_form_groups`' key and group):
  seeds, env steps, wall clock, return (mean +- sd over seeds), expert, fraction, the paper's
  fraction, and each other policy's mean return by its group name ('-' where none)."""
  task, env_steps, final = key[0], key[4], group["final"]
  mean, std = _mean_std([r["final_return"] for r in final])
  expert = _form_expert(task, final, expert_returns, demonstration_returns)
  stopped = " stopped" if any(r.get("finished") is False for r in final) else ""
  cells = {"seeds": str(len(final)), "env_steps": f"{env_steps / 1e6:.1f}M{stopped}",
           "wall": _duration(_mean_std([r["wall_s"] for r in final])[0]),
           "return": f"{mean:.1f}" + (f" +- {std:.1f}" if len(final) > 1 else ""),
           "expert": "-" if expert is None else f"{expert:.1f}",
           "fraction": f"{mean / expert:.2f}" if expert else "-",
           "paper": (f"{PAPER_FORM[task] / PAPER_EXPERT[task]:.2f}"
                     if task in PAPER_FORM and task in PAPER_EXPERT else "-")}
  for name in FORM_POLICIES:
    chosen = group.get(name, [])
    cells[name] = f"{_mean_std([r['final_return'] for r in chosen])[0]:.1f}" if chosen else "-"
  return cells


def _form_compact(groups: dict, configurations: dict, expert_returns: dict,
                  demonstration_returns: dict) -> str:
  """form_table's README view of `groups` (one per task, `_form_groups` with best_per_task)."""
  lines = ["FORM (`--method form`) per task, one configuration: among those run with 2 seeds "
           "or more, on a GPU, with the shipped demonstrator (each where there are any), the "
           "default settings (`mjx_form/imitation/settings.py`, what `--method form` runs) "
           "with the most seeds, else the highest mean. Return: the final policy's fresh "
           "evaluation after training "
           "(`stopped`: ended by its time budget), `--final_eval_envs` episodes per seed, "
           "mean action, mean +- sd over seeds; by log pD: the policy of the evaluation with "
           "the highest demonstrator log pD, chosen without the task reward (`-`: runs before "
           "2026-11-28). Expert: the mean "
           "return of the demonstrations its demonstrator learned, else the shipped expert's "
           "at export; configurations: how many the task has. The full table (sampled "
           "actions, best and average policies, every configuration): `benchmarks/NOTES.md`.",
           "",
           "| task | seeds | env steps | wall clock | return | by log pD | expert | fraction | "
           "paper's fraction | device, envs x updates / iteration | settings | configurations |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for key in sorted(groups, key=_form_key_order):
    task, physics, num_envs, updates, _, _, device, variant, _ = key
    c = _form_cells(key, groups[key], expert_returns, demonstration_returns)
    card = device.removeprefix("gpu:NVIDIA ").removesuffix(" x1")
    lines.append(f"| {task} | {c['seeds']} | {c['env_steps']} | {c['wall']} | {c['return']} | "
                 f"{c['best_log_pd']} | {c['expert']} | {c['fraction']} | {c['paper']} | "
                 f"{card}, {num_envs} x {updates.split(' ')[0]} | {physics}, {variant} | "
                 f"{configurations[task]} |")
  return "\n".join(lines)


def _g(value) -> str:
  return "-" if value is None else f"{value:g}"


def _heldout_mean(record: dict) -> float:
  values = record["heldout_log_likelihood"]
  return sum(values) / len(values)


def _shipped_demonstrators(folder: str = DEMONSTRATORS) -> dict[str, tuple]:
  """{task: (training steps, held-out log-likelihood by offset)} of the demonstrators shipped
  in `folder`: what ties a training's record to the file it wrote (records do not carry the
  file's checksum)."""
  return {meta["task"]: (meta["training"]["steps"],
                        tuple(meta["training"]["heldout_log_likelihood"]))
          for meta in _demonstrator_metadata((folder,))}


def _is_shipped(record: dict, shipped: dict[str, tuple]) -> bool:
  steps, heldout = shipped.get(record["task"], (None, ()))
  return (record["steps"] == steps and len(heldout) == len(record["heldout_log_likelihood"])
          and all(abs(a - b) < 1e-3 for a, b in zip(heldout, record["heldout_log_likelihood"])))


def effect_model_table(records: list[dict], best_per_task: bool = True,
                       shipped: dict[str, tuple] | None = None) -> str:
  """Demonstrator trainings (`kind: effect_model` records): with `best_per_task`, one row per
  task and expert, the shipped training where it is among them, else the one with the highest
  mean held-out log-likelihood over offsets; else every record. `shipped`: as
  `_shipped_demonstrators()` (the default)."""
  rows = [r for r in records if r.get("kind") == "effect_model"]
  if not rows:
    return "No demonstrator results yet."
  shipped = _shipped_demonstrators() if shipped is None else shipped
  # Likelihoods compare only over the same demonstrations: records name their expert policy, or
  # the demonstrations themselves where no expert is named (older records name neither: one
  # group per task).
  def group(r):
    demos = r.get("demonstrations")
    if not demos:
      return r["task"], None
    return r["task"], demos.get("expert_sha256") or f"demos {demos.get('sha256')}"
  count = {g: sum(group(r) == g for r in rows) for g in {group(r) for r in rows}}
  if best_per_task:
    chosen = [max((r for r in rows if group(r) == g),
                  key=lambda r: (_is_shipped(r, shipped), _heldout_mean(r))) for g in count]
    with_shipped = {r["task"] for r in chosen if _is_shipped(r, shipped)}
    chosen = [r for r in chosen if _is_shipped(r, shipped) or r["task"] not in with_shipped]
    caption = ("Demonstrator effect models (`kind: effect_model` records of "
               "`scripts/train_demonstrator.py` and of `--method form` runs that trained one), "
               "per task the shipped one (`tasks/demonstrators/<task>.npz`; shipped: yes) where "
               "it is among them, else per expert the training with the highest mean held-out "
               "log-likelihood (all of them in `benchmarks/NOTES.md`). Expert: the policy whose "
               "demonstrations it learned (sha256, mean return; '-' in records before they "
               "named it). Held-out log-likelihood: of the held-out demonstration "
               "episodes, raw observation space, nats per transition, one value per offset "
               "1, 2, ..., at the step kept (best step):")
  else:
    chosen = rows
    caption = ("Every demonstrator training (`kind: effect_model` records). Held-out "
               "log-likelihood: of the held-out demonstration episodes, raw observation space, "
               "nats per transition, one value per offset, at the step kept (best step):")
  lines = [caption, "",
           "| task | expert | shipped | trainings | device | demo episodes | beta_ar | L2 | width | "
           "turns | batch | steps (best) | time | held-out log-likelihood by offset | "
           "result file |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for r in sorted(chosen, key=lambda r: (_order(r["task"]), r.get("time", ""))):
    s = r.get("settings", {})
    heldout = " / ".join(f"{v:.2f}" for v in r["heldout_log_likelihood"])
    turns = "invariant" if any(s.get("period") or ()) else "-"  # (EffectModelConfig.period)
    if s.get("angle_increments"):
      turns += ", increments"
    if s.get("angle_inputs"):
      turns += ", angle inputs"
    if s.get("max_scale"):
      turns += f", scales below {s['max_scale']:g} sd"
    batch = (f"{s['batch_size']} x {s['window']}" if "batch_size" in s and "window" in s
             else "-")  # windows x transitions per training step
    demos = r.get("demonstrations") or {}
    expert = "-"
    if demos.get("expert_sha256"):
      ret = demos.get("expert_return")
      expert = demos["expert_sha256"][:12] + (f" ({ret:.1f})" if ret is not None else "")
    elif demos:
      expert = f"none (demonstrations {str(demos.get('sha256'))[:12]})"
    mark = "yes" if _is_shipped(r, shipped) else "-"
    lines.append(f"| {r['task']} | {expert} | {mark} | {count[group(r)]} | `{r['device']}` | "
                 f"{s.get('demo_episodes', '-')} | {_g(s.get('beta_ar'))} | "
                 f"{_g(s.get('l2'))} | {s.get('width', '-')} | {turns} | {batch} | "
                 f"{r['steps']:,} ({r['best_step']:,}) | {_duration(r['seconds'])} | {heldout} | "
                 f"{r['_file'].removesuffix('.jsonl')} |")
  return "\n".join(lines)


BASELINES = tuple(paper.BASELINES)  # run.py's baseline methods
CLONING = ("bc", "bco")  # those that fit the policy to actions: no reward, no critic (cloning.py)


def _baseline_admitted(record: dict) -> bool:
  """A baseline's result: a GPU run's, or BC's on the CPU with the paper's 1000 demonstrations
  (BC learns from the demonstrations alone: its environments only evaluate, so the device sets
  its wall clock, not its return; shorter CPU runs with fewer are smoke tests)."""
  if record.get("method") not in BASELINES:
    return False
  if record.get("device", "").startswith("gpu"):
    return True
  episodes = record.get("settings", {}).get("reward", {}).get("demonstration_episodes", 0)
  return record["method"] == "bc" and episodes >= paper.DEMONSTRATIONS


def _baseline_variant(record: dict) -> str:
  """What a baseline run varied beyond the learner: the discriminator (GAIfO's family) or the
  cloning fit (BC, BCO); e.g. `1 frame, GP 10, raw reward` or `squared, lr 0.001`."""
  settings = record.get("settings", {})
  reward = settings.get("reward", {})
  if record["method"] in CLONING:
    learner = settings.get("learner", {})
    return f"{learner.get('cloning_loss', 'likelihood')}, lr {learner.get('learning_rate', 1e-4):g}"
  d = reward.get("discriminator", {})
  return (f"{d.get('frames', 1)} frame{'s' if d.get('frames', 1) > 1 else ''}, "
          f"GP {d.get('gradient_penalty', 0):g}"
          + ("" if d.get("kl_bound") is None else f", KL <= {d['kl_bound']:g}")
          + f", {'standardised' if reward.get('standardise_reward') else 'raw'} reward")


def _baseline_groups(records: list[dict]) -> dict[tuple, dict[int, tuple[list[dict], dict | None]]]:
  """The baselines' configurations (`_baseline_admitted`), keyed (task, method, result file,
  member, setting):
  per seed, its periodic evaluations in order of env steps and its newest fresh final
  evaluation (policy "final"; None where the run wrote none)."""
  curves: dict[tuple, dict[int, list[dict]]] = {}
  finals: dict[tuple, dict[int, dict]] = {}
  for r in sorted(records, key=lambda r: r.get("time", "")):
    if not _baseline_admitted(r):
      continue
    key = (r["task"], r["method"], r["_file"], _member(r), _baseline_variant(r))
    if r.get("kind") == "learning_curve" and r.get("eval_return") is not None:
      curves.setdefault(key, {}).setdefault(r["seed"], []).append(r)
    elif r.get("kind") == "final_return" and r.get("policy") == "final":
      finals.setdefault(key, {})[r["seed"]] = r
  return {key: {seed: (sorted(curves.get(key, {}).get(seed, []), key=lambda r: r["env_steps"]),
                       finals.get(key, {}).get(seed))
                for seed in sorted({*curves.get(key, {}), *finals.get(key, {})})}
          for key in {*curves, *finals}}


def _baseline_return(seeds: dict[int, tuple[list[dict], dict | None]]
                     ) -> tuple[float, float, set[str]]:
  """Mean and sd over seeds of each seed's fresh final return, else its last periodic
  evaluation, and which of the two ("fresh", "last") they are."""
  returns = [final["final_return"] if final else curve[-1]["eval_return"]
             for curve, final in seeds.values()]
  return (*_mean_std(returns), {"fresh" if final else "last" for _, final in seeds.values()})


def baselines_table(records: list[dict], expert_returns: dict[str, float] | None = None,
                    fraction: float = 0.9) -> str:
  """The baselines' runs (BC, BCO, GAIfO, GAIfO+GP, VAIfO, VAIfO+GP; `_baseline_admitted`), one
  row per task, method and configuration (one result file's runs of one setting) over its
  seeds. Each seed's return: its fresh final evaluation (`kind: final_return`, policy "final")
  where the run wrote one, else its last periodic evaluation (a run stopped before it). Expert:
  the records' `demonstrations_return` where every one of the configuration's says the same,
  else `expert_returns` (default: the shipped experts' returns at export)."""
  groups = _baseline_groups(records)
  if not groups:
    return ("No result for the baselines yet: the result file of a GPU run of `--method "
            "gaifo`, `gaifo_gp`, `vaifo`, `vaifo_gp`, `bco` or `bc` (BC's also on the CPU with "
            f"the paper's {paper.DEMONSTRATIONS} demonstrations), copied to "
            "`benchmarks/results/`, appears here.")
  if expert_returns is None:
    expert_returns = _shipped_expert_returns()
  lines = [
      "The baselines on a GPU (BC, which learns from its demonstrations alone, also on the "
      f"CPU with the paper's {paper.DEMONSTRATIONS} demonstrations), one row per task, method "
      "and configuration (one result file's "
      "runs of one setting), mean +- standard deviation over its seeds of each seed's return: "
      "the final policy's fresh evaluation after training, or where the run's time budget "
      "or stop file stopped it (`fresh`, `--final_eval_envs` episodes; `stopped` beside the "
      "env steps), else, where the run ended before it, its last periodic evaluation (`last`, "
      "`--eval_envs` episodes); policy mean action. Best: the mean over seeds of each seed's "
      f"best periodic evaluation. {fraction:g}x expert: the wall clock (env steps) by which "
      f"every seed had a periodic evaluation at or above {fraction:g}x the expert, compilation "
      "and recording the demonstrations included. Expert: the mean return of the "
      "demonstrations the runs imitate (records since 2026-12-07), else the shipped expert's "
      "return at export; fraction = return / expert; paper: the "
      "method's return in the paper's Table 1, and its fraction of the paper's expert. "
      "Setting: the discriminator's input frames, gradient penalty, bottleneck and reward "
      "(GAIfO's family), or the cloning fit and learning rate (BC, BCO); every run uses FORM's "
      "learner (T: its target period):", "",
      "| task | method | setting | device | envs | updates / iteration (replay ratio) | T | "
      "seeds | env steps | wall clock | return | best | "
      f"{fraction:g}x expert | expert | fraction | paper | paper's fraction | result file |",
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
  for key in sorted(groups, key=lambda k: (_order(k[0]), BASELINES.index(k[1]), k[2], k[3])):
    task, method, seeds = key[0], key[1], groups[key]
    mean, sd, kinds = _baseline_return(seeds)
    curves = [curve for curve, _ in seeds.values()]
    best = (f"{_mean_std([max(r['eval_return'] for r in c) for c in curves])[0]:.1f}"
            if all(curves) else "-")
    last = max([c[-1] for c in curves if c] + [f for _, f in seeds.values() if f],
               key=lambda r: r["env_steps"])
    stopped = any(f is not None and f.get("finished") is False for _, f in seeds.values())
    recorded = {r.get("demonstrations_return") for c, f in seeds.values() for r in (*c, f) if r}
    expert = (recorded.pop() if len(recorded) == 1 and None not in recorded
              else expert_returns.get(task))
    reached = ([next((r for r in c if r["eval_return"] >= fraction * expert), None)
                for c in curves] if expert else [None])
    at = ("-" if None in reached else
          f"{_duration(max(r['wall_s'] + r.get('pre_training_s', 0.0) for r in reached))} "
          f"({_steps(max(r['env_steps'] for r in reached))})")
    period = ("-" if method in CLONING
              else last["settings"].get("learner", {}).get("target_update_period", "-"))
    ours = paper.BASELINES[method].get(task)
    lines.append(
        f"| {task} | {paper.BASELINE_NAMES[method]} | {key[4]} | `{last['device']}` | "
        f"{last['num_envs']} | {_updates(last)} | {period} | {len(seeds)} | "
        f"{_steps(last['env_steps'])}{' stopped' if stopped else ''} | "
        f"{_duration(last['wall_s'])} | "
        f"{mean:.1f}{f' +- {sd:.1f}' if len(seeds) > 1 else ''} ({'/'.join(sorted(kinds))}) | "
        f"{best} | {at} | "
        + (f"{expert:.1f} | {mean / expert:.2f}" if expert else "- | -")
        + f" | {ours} | {ours / paper.EXPERT[task]:.2f} | {_run_label(key[2], task)} |")
  return "\n".join(lines)


def table1(records: list[dict], expert_returns: dict[str, float] | None = None) -> str:
  """The paper's Table 1 with ours beside it: per task and method, ours / the paper's return.
  FORM's: the configuration `form_table(best_per_task=True)` shows; a baseline's: among its
  configurations (`baselines_table`), the one with the most seeds, then the highest mean;
  the expert's: `expert_returns` (default: the shipped experts' at export)."""
  if expert_returns is None:
    expert_returns = _shipped_expert_returns()
  ours: dict[tuple[str, str], str] = {}
  groups, _ = _form_groups(records, best_per_task=True)
  for key, group in groups.items():
    ours[(key[0], "form")] = f"{_mean_std([r['final_return'] for r in group['final']])[0]:.1f}"
  best: dict[tuple[str, str], tuple] = {}
  for key, seeds in _baseline_groups(records).items():
    mean, _, kinds = _baseline_return(seeds)
    rank = (len(seeds), mean)
    if (key[0], key[1]) not in best or rank > best[(key[0], key[1])][0]:
      best[(key[0], key[1])] = (rank, mean, kinds)
  for pair, (_, mean, kinds) in best.items():
    ours[pair] = f"{mean:.1f}" + ("*" if "last" in kinds else "")
  methods = list(paper.BASELINES) + ["form"]
  lines = ["The paper's Table 1 beside ours, each cell ours / the paper's return (mean over "
           "seeds). Ours: FORM's configuration in the FORM table below, a baseline's among its "
           "configurations in the baselines table of `benchmarks/NOTES.md` the one with the "
           "most seeds, then the highest mean; `*`: its last periodic evaluation (the run "
           "stopped before its final one); `-`: no result yet. Expert: the shipped expert's "
           "return at export. Our experts are not the paper's: those two tables give each "
           "method's fraction of its own expert.", "",
           "| task | expert | " + " | ".join(paper.BASELINE_NAMES[m] for m in methods[:-1])
           + " | FORM |",
           "|---|---|" + "---|" * len(methods)]
  for task in TASK_ORDER:
    expert = expert_returns.get(task)
    cells = [f"{'-' if expert is None else f'{expert:.1f}'} / {paper.EXPERT[task]}"]
    for method in methods:
      theirs = paper.FORM[task] if method == "form" else paper.BASELINES[method][task]
      cells.append(f"{ours.get((task, method), '-')} / {theirs}")
    lines.append(f"| {task} | " + " | ".join(cells) + " |")
  return "\n".join(lines)


# The generated tables of each file: {marker name: table}.
def readme_tables(records: list[dict]) -> dict[str, str]:
  return {"table1": table1(records),
          "form": form_table(records, best_per_task=True, compact=True),
          "experts": experts_table(records), "parity_summary": parity_summary(records),
          "scaling_summary": scaling_summary(records)}


def notes_tables(records: list[dict]) -> dict[str, str]:
  return {"parity": parity_table(records), "sweep": sweep_table(records),
          "throughput": throughput_table(records),
          "learning_summary": learning_summary(records), "learning": learning_table(records),
          "train_throughput": train_throughput_table(records),
          "demonstrators": effect_model_table(records),
          "effect_models": effect_model_table(records, best_per_task=False),
          "form": form_table(records), "form_runs": form_runs_table(records),
          "baselines": baselines_table(records),
          "populations": population_table(records), "scaling": scaling_table(records)}


TABLES = {README: readme_tables, NOTES: notes_tables}


def render(text: str, records: list[dict], path: str = README) -> str:
  """`text` (the content of README.md or NOTES.md, as `path` says) with its tables generated."""
  for name, table in TABLES[path](records).items():
    pattern = re.compile(rf"(<!-- {name}:begin -->\n).*?(<!-- {name}:end -->)", re.S)
    if not pattern.search(text):
      raise ValueError(f"{os.path.relpath(path, ROOT)} has no <!-- {name}:begin/end --> markers")
    text = pattern.sub(lambda m: m.group(1) + table + "\n" + m.group(2), text)
  return text


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--check", action="store_true")
  args = parser.parse_args(argv)
  records = read_records()
  stale = []
  for path in TABLES:
    with open(path) as f:
      current = f.read()
    updated = render(current, records, path)
    if updated == current:
      continue
    if args.check:
      stale.append(os.path.relpath(path, ROOT))
    else:
      with open(path, "w") as f:
        f.write(updated)
      print(f"{os.path.relpath(path, ROOT)}: tables written")
  if stale:
    print(f"{', '.join(stale)}: tables differ from benchmarks/results/: run scripts/report.py",
          file=sys.stderr)
  unpacked = unpacked_files(records)
  if unpacked:  # (they travel to the GPU machine at five times the size)
    print(f"{', '.join(unpacked)}: FORM learning-curve rows not packed: run "
          "scripts/pack_results.py", file=sys.stderr)
  return 1 if stale or unpacked else 0


if __name__ == "__main__":
  sys.exit(main())
