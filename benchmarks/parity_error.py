#!/usr/bin/env python3
"""One-control-step error against dm_control, per task and physics mode, on this device.

Reads the reference transitions written by scripts/make_reference.py and records, per task and
mode, the largest absolute error per transition in qpos, qvel, observation and reward (median,
90th percentile, max over transitions) as `kind: parity` records. The physics runs at full
float32 matmul precision on every device (`mjx_form.sim.physics.full_precision`); the records of
2026-11-21 with `matmul_precision: default` measured it with JAX's GPU default (TF32) before
that was fixed.

  python benchmarks/parity_error.py --reference .ref --out benchmarks/results/X.jsonl
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import numpy as np  # noqa: E402

import tasks  # noqa: E402
from mjx_form.sim import parity  # noqa: E402
from mjx_form.sim.physics import PHYSICS_MODES  # noqa: E402


def load_reference(folder: str, name: str) -> dict[str, np.ndarray]:
  path = os.path.join(folder, f"{name}.npz")
  with np.load(path, allow_pickle=False) as f:
    arrays = {k: f[k] for k in f.files}
  if str(arrays.pop("task")) != name:
    raise ValueError(f"{path} holds transitions of another task")
  return arrays


def errors(ours, theirs) -> dict:
  diff = np.abs(np.asarray(ours, np.float64) - np.asarray(theirs, np.float64))
  per_sample = diff.reshape(len(diff), -1).max(axis=1)
  return {"median": float(np.median(per_sample)), "p90": float(np.quantile(per_sample, 0.9)),
          "max": float(per_sample.max())}


def measure(name: str, physics, ref: dict) -> dict:
  """Errors of one control step from each reference transition, and the solver settings."""
  env = tasks.make(name, physics=physics)
  data = parity.physics_batch(env, ref, ref["action"])
  obs, reward = parity.observe_batch(env, data, parity.reference_task(ref))
  return {"qpos_error": errors(data.qpos, ref["next_qpos"]),
          "qvel_error": errors(data.qvel, ref["next_qvel"]),
          "obs_error": errors(obs, ref["obs"]), "reward_error": errors(reward, ref["reward"]),
          "solver": vars(env.solver_settings)}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--reference", default=".ref")
  parser.add_argument("--out", default=common.default_results_path("parity_error"))
  parser.add_argument("--tasks", nargs="*", default=list(tasks.TASKS), choices=tasks.TASKS,
                      metavar="TASK")
  parser.add_argument("--physics", nargs="*", default=["parity", "fast"], choices=PHYSICS_MODES,
                      help="default: parity and fast (fast_bounded steps to fast's states)")
  args = parser.parse_args(argv)
  writer = common.ResultWriter(args.out)
  print(f"{'task':<16}{'physics':<13}{'qpos med/max':>22}{'qvel med/max':>22}{'obs max':>10}")
  for name in args.tasks:
    ref = load_reference(args.reference, name)
    for physics in args.physics:
      result = measure(name, physics, ref)
      writer.write(kind="parity", task=name, physics=physics, precision="float32",
                   settings={"num_transitions": len(ref["action"]),
                             "solver": result.pop("solver")},
                   **result)
      q, v = result["qpos_error"], result["qvel_error"]
      print(f"{name:<16}{physics:<13}{q['median']:>11.1e}/{q['max']:<10.1e}"
            f"{v['median']:>11.1e}/{v['max']:<10.1e}{result['obs_error']['max']:>10.1e}",
            flush=True)
  return 0


if __name__ == "__main__":
  sys.exit(main())
