#!/usr/bin/env python3
"""Copies a trained policy file with its agent wrapping the task's unbounded raw angles.

A policy trained without `--wrap_angles` saw, for instance, hopper's pitch raw: a hopper that
turns past pi ends up at observations it met rarely in training (a pitch of 4.7 is the same
state as -1.6). The copy keeps the network and its normaliser's statistics and adds the task's
periods (`Task.observation_period`), so every user of the file (evaluation, demonstrations)
wraps those dimensions into [-pi, pi) first. Its metadata says so (`wrap_angles`,
`wrap_angles_added_after_training`); evaluate the copy afresh before using it.

  python scripts/wrap_angles.py --policy runs/hs/seed2/best_policy.npz --out hs_wrapped.npz
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import numpy as np  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import policy_io  # noqa: E402


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--policy", required=True, help="a policy.npz of a training run")
  parser.add_argument("--out", required=True, help="the copy (refused if it exists)")
  args = parser.parse_args(argv)
  try:
    arrays, metadata = policy_io.load_policy(args.policy)
    if metadata.get("task") not in tasks.TASKS:
      raise ValueError(f"{args.policy}: unknown task {metadata.get('task')!r}")
    env = tasks.make(metadata["task"])
    arrays, metadata = policy_io.load_policy(
        args.policy, task=env.name, observation_size=env.observation_size,
        observation_layout=env.observation_layout)
    if not env.periodic_observations:
      raise ValueError(f"{env.name} observes no unbounded angle: nothing to wrap")
    if "period" in arrays["normalizer"]:
      raise ValueError(f"{args.policy}: its agent wraps angles already")
    if np.any(arrays["normalizer"].get("angles", 0)):
      raise ValueError(f"{args.policy}: its agent sees the angles as cos and sin (nothing to "
                       "wrap)")
    arrays["normalizer"]["period"] = env.observation_period()
    metadata = {**metadata, "wrap_angles": list(env.periodic_observations),
                "wrap_angles_added_after_training": True,
                "wrapped_from_sha256": metadata.get("sha256")}
    for key in ("sha256", "format", "version"):  # written by the file writer
      metadata.pop(key, None)
    policy_io.save_policy(args.out, arrays, metadata)
  except (ValueError, FileExistsError, policy_io.PolicyFileError) as e:
    print(f"error: {e}", file=sys.stderr)
    return 2
  print(f"{args.out}: {env.name}'s policy with {', '.join(env.periodic_observations)} wrapped "
        f"into [-pi, pi) (period {np.float32(2 * np.pi):.4f})")
  return 0


if __name__ == "__main__":
  sys.exit(main())
