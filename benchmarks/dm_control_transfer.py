"""Shipped experts in dm_control itself: does a policy trained on our MJX tasks score the same
in the simulator the tasks were ported from?

For each task, the expert (`tasks/experts/<task>.npz`, or `--policy`) acts with its mean
action (clipped to the action spec's bounds, what MuJoCo clamps it to; until 2026-11-29 to
[-1, 1]) in `--episodes` episodes of dm_control's own environment (seeds `--seed`, `--seed` +
1, ...; its observation dict flattened in the task's declared layout,
checked against dm_control's spec), and in as many of our MJX episodes on this machine, same
policy and episode length. One `kind: expert_transfer` record per task: both returns, their
ratio, and the expert's return at export. The target (issue: experts on all tasks): dm_control
within 5% of MJX.

  python benchmarks/dm_control_transfer.py                       # every shipped expert, CPU
  python benchmarks/dm_control_transfer.py --tasks cheetah_run --episodes 32
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import experts  # noqa: E402
from mjx_form.rl import normalizer  # noqa: E402
from mjx_form.sim import env as env_lib  # noqa: E402
from mjx_form.sim import parity  # noqa: E402


class LayoutError(ValueError):
  """dm_control's observations are not laid out as our task declares."""


def dm_control_layout(dm_env) -> dict[str, int]:
  """{observation name: flat size} of a dm_control environment, in its order."""
  return {name: int(np.prod(spec.shape)) for name, spec in dm_env.observation_spec().items()}


def flat_observations(time_steps) -> np.ndarray:
  """[K, D] float32: each time step's observation dict flattened in dm_control's order (the
  task's layout, checked by `dm_control_returns`)."""
  return np.stack([parity.flat_observation(ts.observation) for ts in time_steps]
                  ).astype(np.float32)


def mean_action_fn(expert: experts.Expert, low: np.ndarray, high: np.ndarray):
  """Jitted [K, D] raw observations -> [K, A] mean actions of the expert's policy, clipped to
  [low, high] [A] (the action spec's bounds)."""
  policy = experts.policy_network(expert.metadata, len(low))
  return jax.jit(lambda obs: jnp.clip(
      policy.apply(expert.params, normalizer.normalize(expert.normalizer, obs)).mode(),
      low, high))


def set_start(dm_env, qpos: np.ndarray, qvel: np.ndarray, act: np.ndarray, task: dict):
  """Puts a reset dm_control environment at this start (qpos, qvel, act and our task's
  variables: reacher's target) as its reset would have, and returns the first observation."""
  physics = dm_env.physics
  with physics.reset_context():
    physics.data.qpos[:], physics.data.qvel[:], physics.data.act[:] = qpos, qvel, act
    if "target" in task:
      physics.named.model.geom_pos["target", :2] = task["target"]
  return dm_env.task.get_observation(physics)


def dm_control_returns(task: str, expert: experts.Expert, layout: dict[str, int],
                       action_size: int, episodes: int, seed: int, steps: int,
                       starts: dict | None = None) -> np.ndarray:
  """[episodes] returns of the expert in dm_control, all episodes stepped together, from
  dm_control's own resets or, with `starts` ({'qpos': [K, nq], 'qvel', 'act', 'task': {name:
  [K, ...]}}), from those initial states."""
  envs = [parity.load_dm_control_env(task, seed + i) for i in range(episodes)]
  theirs = dm_control_layout(envs[0])
  if list(theirs.items()) != list(dict(layout).items()):  # order matters
    raise LayoutError(f"{task}: dm_control observes {theirs}, our task declares {dict(layout)}")
  spec = envs[0].action_spec()
  if spec.shape != (action_size,):
    raise LayoutError(f"{task}: dm_control's actions have shape {spec.shape}, ours "
                      f"({action_size},)")
  act = mean_action_fn(expert, *(np.asarray(b, np.float32) for b in (spec.minimum, spec.maximum)))
  time_steps = [env.reset() for env in envs]
  if starts is not None:
    time_steps = [ts._replace(observation=set_start(
        env, starts["qpos"][i], starts["qvel"][i], starts["act"][i],
        {k: v[i] for k, v in starts["task"].items()})) for i, (env, ts) in
                  enumerate(zip(envs, time_steps))]
  returns = np.zeros(episodes)
  for _ in range(steps):
    actions = np.asarray(act(flat_observations(time_steps)), np.float64)
    time_steps = [env.step(a) for env, a in zip(envs, actions)]
    returns += [ts.reward or 0.0 for ts in time_steps]
  return returns


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  common.add_expert_arguments(parser)
  parser.add_argument("--episodes", type=int, default=16)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--steps", type=int, default=env_lib.EPISODE_LENGTH,
                      help="steps per episode (fewer only to try the script; the MJX side then "
                           "is skipped)")
  parser.add_argument("--out", default=common.default_results_path("dm_control_transfer_cpu"))
  args = parser.parse_args(argv)
  names = common.expert_tasks(parser, args)
  if args.episodes <= 0 or not 0 < args.steps <= env_lib.EPISODE_LENGTH:
    parser.error(f"--episodes must be positive and --steps in 1..{env_lib.EPISODE_LENGTH}")
  writer = common.ResultWriter(args.out)
  for task in names:
    try:
      path = args.policy or tasks.bundled_expert(task)
      expert, env = common.load_expert(task, path)  # (MJX: the physics it was trained in)
      start = time.perf_counter()
      theirs = dm_control_returns(task, expert, env.observation_layout, env.action_size,
                                  args.episodes, args.seed, args.steps)
    except (ValueError, KeyError) as e:
      print(f"error: {e}", file=sys.stderr)
      return 2
    dm_s = time.perf_counter() - start
    ours = None
    if args.steps == env_lib.EPISODE_LENGTH:
      _, _, ours = experts.record(env, expert, jax.random.PRNGKey(args.seed), args.episodes)
    record = {"kind": "expert_transfer", "task": task, "policy_sha256": expert.metadata["sha256"],
              "policy_env_steps": expert.metadata.get("env_steps"),
              "export_return": expert.metadata.get("eval_return"), "episodes": args.episodes,
              "steps": args.steps, "seed": args.seed, "physics": env.physics,
              "dm_control_return": float(theirs.mean()),
              "dm_control_return_std": float(theirs.std()), "dm_control_s": dm_s}
    line = f"{task}: dm_control {theirs.mean():.1f} +- {theirs.std():.1f}"
    if ours is not None:
      record.update(mjx_return=float(ours.mean()), mjx_return_std=float(ours.std()),
                    ratio=float(theirs.mean() / ours.mean()))
      line += (f", MJX {ours.mean():.1f} +- {ours.std():.1f} (ratio {record['ratio']:.3f}; "
               f"at export {record['export_return']:.1f})")
    writer.write(**record)
    print(line + f"  [{args.episodes} episodes each, dm_control {dm_s:.0f}s]", flush=True)
  print(f"results appended to {args.out}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
