#!/usr/bin/env python3
"""Records expert demonstrations: K full episodes of an expert policy, in parallel on the device.

  python scripts/make_demos.py --policy runs/cheetah_run_expert_seed0/policy.npz \\
      --episodes 1000 --out demos/cheetah_run.npz [--actions]
  python scripts/make_demos.py --task cheetah_run --out demos/cheetah_run.npz  # shipped expert

The file format is documented in mjx_form/files/demos.py (observations [K, 1001, D], actions
only with --actions, for BC; task, observation layout, physics, expert and checksum in the
metadata).
Episodes are recorded in chunks of --chunk episodes (one compiled rollout, reused).
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import demos, experts, policy_io  # noqa: E402
from mjx_form.sim.physics import DEFAULT_PHYSICS, PHYSICS_MODES  # noqa: E402


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  source = parser.add_mutually_exclusive_group(required=True)
  source.add_argument("--policy", help="an expert's policy.npz")
  source.add_argument("--task", help="use the expert shipped in tasks/experts/ for this task")
  parser.add_argument("--out", required=True, help="the demonstration file to write")
  parser.add_argument("--episodes", type=int, default=1000)
  parser.add_argument("--chunk", type=int, default=1000, help="episodes recorded at once")
  parser.add_argument("--actions", action="store_true", help="store actions too (for BC)")
  parser.add_argument("--stochastic", action="store_true",
                      help="sample actions from the policy instead of its mean")
  parser.add_argument("--physics", default=None, choices=PHYSICS_MODES,
                      help="default: the mode the expert was trained with")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--overwrite", action="store_true")
  args = parser.parse_args(argv)
  if args.episodes <= 0 or args.chunk <= 0:
    parser.error("--episodes and --chunk must be positive")
  if os.path.exists(args.out) and not args.overwrite:
    print(f"error: {args.out} exists (pass --overwrite to replace it)", file=sys.stderr)
    return 2
  try:
    if args.task is not None:
      args.policy = tasks.bundled_expert(args.task)
    _, metadata = policy_io.load_policy(args.policy)
    physics = args.physics or metadata.get("physics", DEFAULT_PHYSICS)
    env = tasks.make(metadata["task"], physics=physics)
    expert = experts.load_expert(args.policy, env)
  except (ValueError, KeyError) as e:
    print(f"error: {e}", file=sys.stderr)
    return 2

  obs, actions, returns = experts.record_demonstrations(
      env, expert, jax.random.PRNGKey(args.seed), args.episodes, args.chunk,
      stochastic=args.stochastic, print_fn=lambda line: print(line, flush=True))
  info = experts.recording_info(args.policy, metadata, returns, args.seed, args.stochastic)
  os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
  demos.save_demonstrations(
      args.out, obs, actions if args.actions else None, overwrite=args.overwrite,
      metadata={"task": env.name, "observation_layout": env.observation_layout,
                "physics": physics, "expert": info})
  print(f"wrote {args.out}: {args.episodes} episodes, mean return {returns.mean():.1f}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
