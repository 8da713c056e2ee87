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
  records = [{"kind": "env_throughput", "task": "cheetah_run", "physics": "parity",
              "num_envs": 2048, "device": "gpu:X", "versions": {}, "time": "t", "sps": 1.5e5,
              "raw_sps": 2e5, "ratio_to_raw": 0.75,
              "settings": {"solver": {"iterations": 10, "ls_iterations": 10,
                                      "max_contact_points": 4}}}]
  table = report.throughput_table(records)
  assert "| cheetah_run | parity | 10/10 cull 4 | 2048 | 150k | 200k | 0.75 | - | - | - |" in table
