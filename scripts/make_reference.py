#!/usr/bin/env python3
"""Records dm_control reference transitions for parity measurements away from dm_control.

  python scripts/make_reference.py --out .ref --num_states 64

writes one `<task>.npz` per task (numpy arrays only, no pickle): states before and after one
control step under random actions (some outside the control range), with dm_control's
observation and reward. benchmarks/parity_error.py reads them, e.g. on the GPU machine where
dm-control is not installed.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import tasks  # noqa: E402
from mjx_form.sim import parity  # noqa: E402


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--out", default=".ref", help="output folder")
  parser.add_argument("--num_states", type=int, default=64)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--tasks", nargs="*", default=list(tasks.TASKS), choices=tasks.TASKS,
                      metavar="TASK")
  args = parser.parse_args(argv)
  if args.num_states <= 0:
    parser.error("--num_states must be positive")
  os.makedirs(args.out, exist_ok=True)
  for name in args.tasks:
    ref = parity.collect_reference(name, args.num_states, seed=args.seed)
    path = os.path.join(args.out, f"{name}.npz")
    np.savez_compressed(path, task=np.array(name), **ref)
    print(f"{name}: {args.num_states} transitions -> {path}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
