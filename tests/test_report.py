"""The README's tables are generated from benchmarks/results/, never typed by hand."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import report  # noqa: E402


def test_readme_tables_are_generated_from_results():
  result = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "report.py"), "--check"],
                          capture_output=True, text=True, timeout=60)
  assert result.returncode == 0, result.stderr


def test_report_detects_a_hand_edited_table():
  with open(report.README) as f:
    readme = f.read()
  records = report.read_records()
  edited = readme.replace("<!-- throughput:begin -->\n", "<!-- throughput:begin -->\n| typed |\n")
  assert report.render(edited, records) != edited
  assert report.render(readme, records) == readme


def test_throughput_table_lists_each_measurement():
  record = {"kind": "env_throughput", "task": "cheetah_run", "physics": "parity",
            "num_envs": 2048, "device": "gpu:X", "versions": {}, "time": "t", "sps": 1.5e5,
            "raw_sps": 2e5, "ratio_to_raw": 0.75,
            "settings": {"solver": {"iterations": 10, "ls_iterations": 10,
                                    "max_contact_points": 4}}}
  # A GPU record without the precision field predates the full-precision physics: TF32.
  table = report.throughput_table([record])
  assert ("| cheetah_run | parity | 10/10 cull 4 | 2048 | TF32 | 150k | 200k | 0.75 | - | - | - "
          "| - |") in table
  newer = dict(record, physics_matmul_precision="highest", step_sps=1.8e5,
               step_ratio_to_raw=0.9, time="u")
  table = report.throughput_table([record, newer])
  assert ("| cheetah_run | parity | 10/10 cull 4 | 2048 | float32 | 150k | 200k | 0.75 | 0.90 | "
          "- | - | - |") in table
  assert "TF32" not in table.split("\n", 2)[2]  # only the newest record of a row is shown


def test_parity_tables_are_per_device_and_precision():
  error = {"median": 1e-6, "p90": 2e-6, "max": 3e-6}
  base = {"kind": "parity", "task": "walker_walk", "physics": "fast", "time": "t",
          "settings": {"num_transitions": 64}, "qpos_error": error, "qvel_error": error,
          "obs_error": error, "reward_error": error}
  records = [dict(base, device="cpu:cpu x1"),
             dict(base, device="gpu:X", matmul_precision="default"),
             dict(base, device="gpu:X", matmul_precision="highest")]
  table = report.parity_table(records)
  assert table.count("| walker_walk | fast |") == 3
  assert "`gpu:X`, matmuls in TF32" in table and "`gpu:X`, matmuls in float32" in table
  assert "`cpu:cpu x1`, matmuls in float32" in table


def test_train_throughput_rows_differ_by_precision_and_xla_flags():
  """A measurement under other compiler flags or matmul precision is a row of its own."""
  base = {"kind": "train_throughput", "task": "cheetah_run", "physics": "fast", "num_envs": 512,
          "device": "gpu:X", "versions": {}, "time": "t", "sps": 1.1e5, "env_sps": 2.8e5,
          "ratio_to_env": 0.41, "update_ms": 2.0, "peak_memory_bytes": None,
          "physics_matmul_precision": "highest",
          "xla_flags": "--xla_cpu_enable_concurrency_optimized_scheduler=false",
          "settings": {"updates_per_iteration": 128, "stagger_episodes": False}}
  graphs = dict(base, sps=1.0e5, time="u", xla_flags=base["xla_flags"]
                + " --xla_gpu_enable_command_buffer=WHILE")
  tf32 = dict(base, sps=1.2e5, time="v")
  del tf32["physics_matmul_precision"]
  table = report.train_throughput_table([base, graphs, tf32])
  assert "| 110k | 280k | 0.41 | 2.0 | - | - |" in table
  assert "| 100k | 280k | 0.41 | 2.0 | - | `--xla_gpu_enable_command_buffer=WHILE` |" in table
  assert "| TF32 | 512 | 128 | lockstep | 120k |" in table


def test_learning_rows_show_the_action_penalty():
  base = {"kind": "learning_curve", "task": "hopper_stand", "seed": 0, "num_envs": 256,
          "device": "gpu:X", "env_steps": 1e6, "wall_s": 60.0, "eval_return": 300.0,
          "physics_matmul_precision": "highest", "_file": "2026-11-23_learning_curve_x.jsonl",
          "settings": {"updates_per_iteration": 128, "replay_ratio": 32, "eval_episodes": 32,
                       "stagger_episodes": True,
                       "learner": {"mpo": {"epsilon": 0.1}}}}  # before the setting existed
  penalised = dict(base, _file="2026-11-23_learning_curve_y.jsonl", eval_return=900.0,
                   settings=dict(base["settings"], learner={"mpo": {
                       "action_penalty": True, "epsilon_penalty": 1e-3}}))
  off = dict(base, _file="2026-11-23_learning_curve_z.jsonl", settings=dict(
      base["settings"], learner={"mpo": {"action_penalty": False, "epsilon_penalty": 1e-3}}))
  table = report.learning_table([base, penalised, off])
  rows = [line for line in table.splitlines() if line.startswith("| hopper_stand")]
  assert len(rows) == 3
  assert sum("| staggered | 0.001 | 1.0M |" in row for row in rows) == 1
  assert sum("| staggered | - | 1.0M |" in row for row in rows) == 2
  assert "| staggered | 0.001 | 1.0M | 60 s | - | 900.0 | 900.0 | 60 s (1.0M) |" in table
