#!/usr/bin/env python3
"""Where a locomotion policy loses its return: too slow, or not upright?

walker's, quadruped's and hopper_hop's rewards are products of a posture factor and a speed
factor (dm_control: walker `stand_reward * (5 * move_reward + 1) / 6`, quadruped `upright *
move_reward`, hopper `standing * hopping`, standing: the torso 0.6-2 m above the foot; the
speed factor is 1 at the task's speed or faster and falls linearly below it). This rolls out
policies (mean action, clipped) on the CPU and reports, per policy, the mean return, the
torso's forward speed (the task's own sensor: walker's and hopper's subtree linear velocity,
quadruped's velocimeter), the share of steps at the task's speed, and both factors' means, each
over the second half of the episodes (the gait, not the start). It also checks that the factors'
product is the environment's reward, step by step. Appends `kind: locomotion_speed` records.

  python benchmarks/locomotion_speed.py --task walker_run --policy runs/wr/seed0/policy.npz
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402
from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402
import numpy as np  # noqa: E402

from mjx_form.sim.rewards import tolerance  # noqa: E402

TASKS = ("walker_walk", "walker_run", "quadruped_walk", "quadruped_run", "hopper_hop")


def target_speed(env) -> float:
  """The forward speed at which the task's speed factor reaches 1."""
  if env.domain == "walker":
    return env.move_speed
  if env.domain == "hopper":
    return env.hop_speed
  return env.desired_speed


def factors(env, data):
  """(forward speed, posture factor, speed factor, the reward from them) of one state, as the
  task's `get_reward` combines them (tasks/walker.py, tasks/quadruped.py, tasks/hopper.py)."""
  target = target_speed(env)
  if env.domain == "hopper":
    speed = env.speed(data)
    posture = tolerance(env.height(data), (0.6, 2))
    move = tolerance(speed, bounds=(target, float("inf")), margin=target / 2,
                     value_at_margin=0.5, sigmoid="linear")
    return speed, posture, move, posture * move
  if env.domain == "walker":
    speed = env.horizontal_velocity(data)
    standing = tolerance(env.torso_height(data), bounds=(1.2, float("inf")), margin=0.6)
    posture = (3 * standing + (1 + env.torso_upright(data)) / 2) / 4
    move = tolerance(speed, bounds=(target, float("inf")), margin=target / 2,
                     value_at_margin=0.5, sigmoid="linear")
    return speed, posture, move, posture * (5 * move + 1) / 6
  speed = env.torso_velocity(data)[0]
  posture = tolerance(env.torso_upright(data), bounds=(1.0, float("inf")), sigmoid="linear",
                      margin=2.0, value_at_margin=0)
  move = tolerance(speed, bounds=(target, float("inf")), margin=target, value_at_margin=0.5,
                   sigmoid="linear")
  return speed, posture, move, posture * move


def rollout(env, agent, key, episodes):
  """Per step [T, K]: the environment's reward, and `factors` of the state it led to."""
  probe = lambda nxt: (nxt.reward, *jax.vmap(lambda d: factors(env, d))(nxt.data))
  return [np.asarray(x) for x in common.mean_action_rollout(env, agent, key, episodes, probe)]


def summary(env, reward, speed, posture, move, product) -> dict:
  half = reward.shape[0] // 2
  target = target_speed(env)
  return {"mean_return": float(reward.sum(0).mean()),
          "return_std": float(reward.sum(0).std()),
          "target_speed": float(target),
          "speed_mean": float(speed[half:].mean()),
          "speed_p10_p50_p90": [float(v) for v in np.percentile(speed[half:], (10, 50, 90))],
          "share_at_target_speed": float((speed[half:] >= target).mean()),
          "posture_factor_mean": float(posture[half:].mean()),
          "speed_factor_mean": float(move[half:].mean()),
          "reward_mean_second_half": float(reward[half:].mean()),
          "max_factor_error": float(np.abs(product - reward).max())}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", required=True, choices=TASKS)
  parser.add_argument("--policy", action="append", required=True,
                      help="a policy file of the task (repeatable)")
  parser.add_argument("--episodes", type=int, default=32)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--out", default=common.default_results_path("locomotion_speed_cpu"))
  args = parser.parse_args(argv)
  if args.episodes <= 0:
    parser.error("--episodes must be positive")
  loaded = []
  for path in args.policy:  # every file checked before anything runs or is written
    try:
      loaded.append((path, *common.load_expert(args.task, path)))
    except (OSError, ValueError, KeyError) as e:
      print(f"error: {e}", file=sys.stderr)
      return 2
  writer = common.ResultWriter(args.out)
  for path, agent, env in loaded:
    reward, speed, posture, move, product = rollout(env, agent, jax.random.PRNGKey(args.seed),
                                                    args.episodes)
    row = summary(env, reward, speed, posture, move, product)
    if row["max_factor_error"] > 1e-4:
      print(f"error: {path}: the factors' product differs from the reward by "
            f"{row['max_factor_error']:.2g}; the task's reward is not what this script assumes",
            file=sys.stderr)
      return 1
    print(f"{args.task} {path}: return {row['mean_return']:.1f} +- {row['return_std']:.1f}; "
          f"second half: speed {row['speed_mean']:.2f} m/s (p10/50/90 "
          + "/".join(f"{v:.2f}" for v in row["speed_p10_p50_p90"])
          + f"; target {row['target_speed']:g}, reached in {100 * row['share_at_target_speed']:.1f}%"
          f" of steps), posture factor {row['posture_factor_mean']:.3f}, speed factor "
          f"{row['speed_factor_mean']:.3f}, reward per step {row['reward_mean_second_half']:.3f}")
    writer.write(kind="locomotion_speed", task=args.task, physics=env.physics,
                 policy_file=path, policy_sha256=agent.metadata.get("sha256"),
                 policy_env_steps=agent.metadata.get("env_steps"), episodes=args.episodes,
                 seed=args.seed, **row)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
