"""What a policy's return is made of, on the tasks whose reward charges for control: the
factors of dm_control's reward (humanoid: standing x upright x small_control x move or
dont_move; hopper_stand: standing x small_control), step by step in dm_control itself.

small_control = (4 + mean over actuators of tolerance(u, margin 1, quadratic)) / 5 costs up to
a fifth of every step's reward: an actuator held at its bound scores 0 there, one at rest 1. A
policy whose mean action sits outside the control range (clipped: the bound) pays it whatever
it stands like. Per policy (its mean action, clipped to the action spec, in `--episodes`
episodes from dm_control's resets, seeds `--seed`, `--seed` + 1, ...): the return, each factor's
mean over steps, the share of actuator commands at their bound and the mean |u|, and the return
with small_control taken as 1 (what the same motion would score without the control cost);
the same means from `--late_from` on, once a humanoid has got up; and per actuator (by
dm_control's name): its commands' share at the bound, their mean and mean |u|, and the share
of steps its joint lies within `JOINT_LIMIT_RAD` of a limit of its range (torque pressed into a
limit pays the control cost and moves nothing).
Appends a `kind: reward_terms` record per policy and `--action_scale`.

`--action_scale 1 0.9 0.8` also applies the clipped mean action scaled by each factor: does the
policy still stand with less torque, and what would it score? (The commands' share at the bound
and mean |u| stay the policy's own, before scaling.)

  python benchmarks/reward_terms.py --tasks humanoid_stand \\
      --policy benchmarks/policies/humanoid_stand_hsh_seed1_12m.npz --episodes 16
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
from dm_control.suite import hopper as dm_hopper  # noqa: E402
from dm_control.suite import humanoid as dm_humanoid  # noqa: E402
from dm_control.utils import rewards  # noqa: E402

import dm_control_transfer as transfer  # noqa: E402
import tasks  # noqa: E402
from mjx_form.sim import env as env_lib  # noqa: E402
from mjx_form.sim import parity  # noqa: E402

TASKS = ("hopper_stand", "humanoid_stand", "humanoid_walk", "humanoid_run")


def small_control(physics) -> float:
  """dm_control's control factor of hopper_stand's and humanoid's reward, in [0.8, 1]."""
  u = rewards.tolerance(physics.control(), margin=1, value_at_margin=0, sigmoid="quadratic")
  return (4 + float(u.mean())) / 5


def reward_terms(task: str, dm_env) -> dict[str, float]:
  """The factors of `task`'s reward at the environment's current state (their product is
  dm_control's reward for the step that led there), as dm_control's suite defines them."""
  physics = dm_env.physics
  if task == "hopper_stand":
    return {"standing": float(rewards.tolerance(physics.height(),
                                                (dm_hopper._STAND_HEIGHT, 2))),
            "small_control": small_control(physics)}
  height = dm_humanoid._STAND_HEIGHT
  terms = {"standing": float(rewards.tolerance(physics.head_height(), (height, float("inf")),
                                               margin=height / 4)),
           "upright": float(rewards.tolerance(physics.torso_upright(), (0.9, float("inf")),
                                              sigmoid="linear", margin=1.9, value_at_margin=0)),
           "small_control": small_control(physics)}
  velocity = physics.center_of_mass_velocity()[[0, 1]]
  speed = dm_env.task._move_speed
  if speed == 0:
    terms["dont_move"] = float(rewards.tolerance(velocity, margin=2).mean())
  else:
    move = float(rewards.tolerance(np.linalg.norm(velocity), (speed, float("inf")),
                                   margin=speed, value_at_margin=0, sigmoid="linear"))
    terms["move"] = (5 * move + 1) / 6
  return terms


JOINT_LIMIT_RAD = 0.05  # a joint this close to an end of its range counts as at its limit


def actuated_joints(physics) -> tuple[list[str], np.ndarray, np.ndarray]:
  """The actuators' names [A], their joints' qpos addresses [A] and ranges [A, 2] (a joint
  without limits gets (-inf, inf))."""
  model = physics.model
  joint = model.actuator_trnid[:, 0]
  ranges = np.where(model.jnt_limited[joint][:, None].astype(bool), model.jnt_range[joint],
                    np.array([-np.inf, np.inf]))
  names = [model.id2name(i, "actuator") for i in range(model.nu)]
  return names, model.jnt_qposadr[joint], ranges


def at_joint_limit(qpos: np.ndarray, ranges: np.ndarray) -> np.ndarray:
  """Whether each actuated joint's position [A] lies within JOINT_LIMIT_RAD of its range's
  ends [A, 2]."""
  return np.min(np.abs(qpos[:, None] - ranges), axis=1) <= JOINT_LIMIT_RAD


def commands(actions: np.ndarray, low: np.ndarray, high: np.ndarray) -> dict[str, float]:
  """Of one step's commands [A] (clipped to [low, high] [A]): the share at a bound and the
  mean |u|."""
  return {"at_bound": float(np.mean((actions <= low) | (actions >= high))),
          "abs_control": float(np.mean(np.abs(actions)))}


def rollout(task: str, expert, layout: dict, action_size: int, episodes: int, seed: int,
            steps: int, action_scale: float = 1.0) -> dict[str, np.ndarray]:
  """The policy's mean action (clipped, then times `action_scale`) in `episodes` dm_control
  episodes, stepped together: per step [steps, episodes] the reward, each factor, and the share
  of the policy's clipped commands at their bound and their mean |u| (before the scale); per
  step and actuator [steps, episodes, A] those commands, whether each is at its bound, and
  whether its joint is at a limit."""
  envs = [parity.load_dm_control_env(task, seed + i) for i in range(episodes)]
  theirs = transfer.dm_control_layout(envs[0])
  if list(theirs.items()) != list(dict(layout).items()):
    raise ValueError(f"{task}: dm_control observes {theirs}, our task declares {dict(layout)}")
  spec = envs[0].action_spec()
  if spec.shape != (action_size,):
    raise ValueError(f"{task}: dm_control's actions have shape {spec.shape}, ours "
                     f"({action_size},)")
  low, high = (np.asarray(b, np.float32) for b in (spec.minimum, spec.maximum))
  act = transfer.mean_action_fn(expert, low, high)
  _, qpos_address, ranges = actuated_joints(envs[0].physics)
  time_steps = [env.reset() for env in envs]
  out: dict[str, list] = {}
  for _ in range(steps):
    actions = np.asarray(act(transfer.flat_observations(time_steps)), np.float64)
    time_steps = [env.step(action_scale * a) for env, a in zip(envs, actions)]
    rows = [{"reward": ts.reward or 0.0, **reward_terms(task, env), **commands(a, low, high)}
            for env, ts, a in zip(envs, time_steps, actions)]
    for name in rows[0]:
      out.setdefault(name, []).append([row[name] for row in rows])
    out.setdefault("actions", []).append(actions)
    out.setdefault("actuator_at_bound", []).append((actions <= low) | (actions >= high))
    out.setdefault("at_joint_limit", []).append(
        [at_joint_limit(env.physics.data.qpos[qpos_address], ranges) for env in envs])
  return {name: np.asarray(values) for name, values in out.items()}


PER_STEP = ("reward", "at_bound", "abs_control")  # series that are not reward factors
PER_ACTUATOR = ("actions", "actuator_at_bound", "at_joint_limit")  # [steps, episodes, A]


def _means(series: dict[str, np.ndarray], names: list[str] | None = None) -> dict:
  out = {"terms": {name: float(values.mean()) for name, values in series.items()
                   if name not in PER_STEP + PER_ACTUATOR},
         "at_bound_share": float(series["at_bound"].mean()),
         "abs_control_mean": float(series["abs_control"].mean())}
  if names is not None:
    u, bound, limit = (series[k] for k in PER_ACTUATOR)
    out["actuators"] = {name: {"at_bound": float(bound[..., i].mean()),
                               "mean": float(u[..., i].mean()),
                               "abs_mean": float(np.abs(u[..., i]).mean()),
                               "joint_at_limit": float(limit[..., i].mean())}
                        for i, name in enumerate(names)}
  return out


def summary(series: dict[str, np.ndarray], late_from: int,
            names: list[str] | None = None) -> dict:
  """Return (mean over episodes), each factor's and the commands' means over all steps, the
  return with small_control taken as 1, and the same means from step `late_from` on (`late`:
  once the humanoid has got up, what standing or walking itself costs; None past the end);
  with the actuators' `names`, per actuator its commands' share at the bound, their mean and
  mean |u|, and its joint's share of steps at a limit."""
  late = {name: values[late_from:] for name, values in series.items()}
  return {"return": float(series["reward"].sum(axis=0).mean()),
          "return_without_control_cost": float(
              (series["reward"] / series["small_control"]).sum(axis=0).mean()),
          **_means(series, names),
          "late": None if late_from >= len(series["reward"]) else {
              "from_step": late_from, "reward_mean": float(late["reward"].mean()),
              **_means(late, names)}}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--tasks", nargs="+", required=True, metavar="TASK",
                      help=f"of {', '.join(TASKS)}")
  parser.add_argument("--policy", action="append", default=[],
                      help="a policy file (repeatable; default: the task's shipped expert, "
                           "hopper_stand's only: no humanoid expert is shipped)")
  parser.add_argument("--episodes", type=int, default=16)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--steps", type=int, default=env_lib.EPISODE_LENGTH,
                      help="steps per episode (fewer only to try the script)")
  parser.add_argument("--action_scale", type=float, nargs="+", default=[1.0], metavar="K",
                      help="apply the clipped mean action times K, in [0, 1] (default 1; "
                           "several: one record each)")
  parser.add_argument("--late_from", type=int, default=300,
                      help="the step from which the late means are taken (default 300)")
  parser.add_argument("--out", default=common.default_results_path("reward_terms_cpu"))
  args = parser.parse_args(argv)
  unknown = [t for t in args.tasks if t not in TASKS]
  if unknown:
    parser.error(f"{', '.join(unknown)}: no control cost in the reward; this looks at "
                 f"{', '.join(TASKS)}")
  if args.policy and len(args.tasks) != 1:
    parser.error("--policy needs exactly one --tasks")
  if args.episodes <= 0 or not 0 < args.steps <= env_lib.EPISODE_LENGTH or args.late_from < 0:
    parser.error(f"--episodes must be positive, --steps in 1..{env_lib.EPISODE_LENGTH} and "
                 "--late_from not negative")
  if not all(0.0 <= k <= 1.0 for k in args.action_scale):
    parser.error(f"--action_scale {args.action_scale}: each factor must lie in [0, 1]")
  try:  # every policy found and loaded before the first rollout writes a record
    jobs = [(task, path, *common.load_expert(task, path)) for task in args.tasks
            for path in args.policy or [tasks.bundled_expert(task)]]
  except (ValueError, KeyError, OSError) as e:
    print(f"error: {e}", file=sys.stderr)
    return 2
  writer = common.ResultWriter(args.out)
  for (task, path, expert, env), scale in ((job, k) for job in jobs
                                           for k in args.action_scale):
    try:
      series = rollout(task, expert, env.observation_layout, env.action_size, args.episodes,
                       args.seed, args.steps, scale)
    except ValueError as e:  # (dm_control's layout or actions differ from ours)
      print(f"error: {e}", file=sys.stderr)
      return 2
    names = actuated_joints(parity.load_dm_control_env(task, 0).physics)[0]
    result = summary(series, args.late_from, names)
    print(f"{task} {os.path.basename(path)}"
          + (f" x {scale:g}" if scale != 1.0 else "") + f": return {result['return']:.1f} "
          f"({result['return_without_control_cost']:.1f} without the control cost); "
          + ", ".join(f"{k} {v:.3f}" for k, v in result["terms"].items())
          + f"; actuators at their bound {result['at_bound_share']:.0%}, mean |u| "
          f"{result['abs_control_mean']:.2f}")
    if (late := result["late"]) is not None:
      print(f"  from step {late['from_step']}: reward per step {late['reward_mean']:.3f}; "
            + ", ".join(f"{k} {v:.3f}" for k, v in late["terms"].items())
            + f"; at their bound {late['at_bound_share']:.0%}, mean |u| "
            f"{late['abs_control_mean']:.2f}")
      pinned = [f"{name} {a['mean']:+.2f} (joint at a limit {a['joint_at_limit']:.0%})"
                for name, a in late["actuators"].items() if a["at_bound"] >= 0.5]
      if pinned:
        print(f"  at the bound in half its late steps or more: {', '.join(pinned)}")
    writer.write(kind="reward_terms", task=task, policy=os.path.basename(path),
                 policy_sha256=expert.metadata["sha256"],
                 policy_env_steps=expert.metadata.get("env_steps"),
                 episodes=args.episodes, steps=args.steps, seed=args.seed,
                 action_scale=scale, **result)
  print(f"records appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
