"""How many iterations the constraint solver and its line search take, per environment and
per batch.

On a batch (`vmap`), MJX's solve runs its `while_loop` until the slowest environment of the
batch has converged, so a batch pays for its maximum count at every substep; `--physics
fast_bounded` always runs `opt.iterations` passes (mjx_form/sim/partitionable.py). Inside each
iteration MJX's line search is a scan of `opt.ls_iterations` passes, all of which a batch
computes (a `lax.cond` under `vmap` computes both branches) though an environment needs only
its own count. This script rolls out `--num_envs` environments of each task for `--steps`
control steps (the shipped expert's mean action where one exists and `--policy expert`, else
uniform random actions), and at every control step counts the solve that starts it
(`partitionable.solve_iterations`). It records per task: the iterations' mean and quantiles
over environments and steps, the share at the cap, the mean over steps of the batch maximum
for batches of 1, 8, 64, ... environments (disjoint groups of the rollout's batch); the line
search's mean passes per iteration; and, per substep of the whole batch, the line-search
passes computed now (`ls_iterations` x the batch's iterations) against those a line search
that stopped once the batch's slowest search had would compute (the sum over iterations of
the batch's largest count). Counts, not timings: the same on any device (float32 physics).

  python benchmarks/solver_iterations.py --tasks cheetah_run walker_walk humanoid_run
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from mujoco import mjx  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import experts  # noqa: E402
from mjx_form.rl import normalizer  # noqa: E402
from mjx_form.sim import partitionable  # noqa: E402
from mjx_form.sim.physics import full_precision  # noqa: E402
from mjx_form.sim.wrappers import AutoReset  # noqa: E402

DEFAULT_TASKS = ("cheetah_run", "hopper_stand", "walker_walk", "quadruped_walk", "humanoid_run")


@full_precision
def iterations_at(m: mjx.Model, d: mjx.Data) -> tuple[jax.Array, jax.Array]:
  """The solver iterations and line-search passes per iteration ([opt.iterations]) of the
  substep that starts at `d` (ctrl set), as `physics_step` reaches the solve (zeros where the
  model has no constraint rows)."""
  d = mjx.fwd_acceleration(m, mjx.fwd_actuation(m, d))
  if d._impl.efc_J.size == 0:
    return jnp.zeros((), jnp.int32), jnp.zeros(int(m.opt.iterations), jnp.int32)
  return partitionable.solve_iterations(m, d)


def rollout_counts(env, policy_fn, num_envs: int, steps: int, key: jax.Array
                   ) -> tuple[np.ndarray, np.ndarray]:
  """Iterations [steps, num_envs] and line-search passes [steps, num_envs, opt.iterations]
  along an auto-reset rollout; `policy_fn(obs, key)` gives actions in the control range."""
  auto = AutoReset(env)

  @jax.jit
  def run(key):
    reset_key, action_key = jax.random.split(key)

    def step(state, key):
      action = policy_fn(state.obs, key)
      data = state.data.replace(ctrl=action)
      counts = jax.vmap(lambda d: iterations_at(env.mjx_model, d))(data)
      return auto.step(state, action), counts

    return jax.lax.scan(step, auto.reset(reset_key, num_envs),
                        jax.random.split(action_key, steps))[1]

  counts, passes = run(key)
  return np.asarray(counts), np.asarray(passes)


def policy_for(env, use_expert: bool):
  """(`policy_fn`, name): the shipped expert's clipped mean action, or uniform random."""
  if use_expert and env.name in tasks.bundled_experts():
    expert = experts.load_expert(tasks.bundled_expert(env.name), env)
    net = experts.policy_network(expert.metadata, env.action_size)
    return (lambda obs, key: env.clip_action(net.apply(
        expert.params, normalizer.normalize(expert.normalizer, obs)).mode()), "expert")
  return (lambda obs, key: jax.random.uniform(key, (obs.shape[0], env.action_size),
                                              minval=-1.0, maxval=1.0), "random")


def batch_maxima(counts: np.ndarray, sizes) -> dict[str, float]:
  """Mean over steps and groups of the largest count among `size` environments (disjoint
  groups of the batch), for each size that fits."""
  steps, n = counts.shape
  out = {}
  for size in sizes:
    if size <= n:
      groups = counts[:, : n - n % size].reshape(steps, -1, size)
      out[str(size)] = float(groups.max(axis=-1).mean())
  return out


def summary(counts: np.ndarray, passes: np.ndarray, cap: int, ls_cap: int,
            num_envs: int) -> dict:
  """The record's numbers for iterations [S, N] and line-search passes [S, N, cap]."""
  sizes = [1] + [8 ** k for k in range(1, 8) if 8 ** k < num_envs] + [num_envs]
  return {"mean": float(counts.mean()),
          "quantiles": {q: float(np.quantile(counts, float(q))) for q in ("0.5", "0.9", "0.99")},
          "at_cap": float(np.mean(counts >= cap)), "cap": cap,
          "mean_batch_max": batch_maxima(counts, sizes),
          "line_search": {
              "mean_per_iteration": float(passes.sum() / max(counts.sum(), 1)),
              "cap": ls_cap,
              "batch_passes_now": float(ls_cap * counts.max(axis=1).mean()),
              "batch_passes_if_stopped": float(passes.max(axis=1).sum(axis=-1).mean())}}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--tasks", nargs="*", default=list(DEFAULT_TASKS), choices=tasks.TASKS,
                      metavar="TASK")
  parser.add_argument("--physics", default="fast", choices=("parity", "fast"))
  parser.add_argument("--ls_iterations", type=int, default=None,
                      help="the line search's cap instead of the mode's (fast: 10)")
  parser.add_argument("--num_envs", type=int, default=256)
  parser.add_argument("--steps", type=int, default=200, help="control steps per environment")
  parser.add_argument("--policy", default="expert", choices=("expert", "random"),
                      help="expert: the shipped expert where one exists, else random")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--out", default=None)
  args = parser.parse_args(argv)
  for name in ("num_envs", "steps", "ls_iterations"):
    if getattr(args, name) is not None and getattr(args, name) < 1:
      parser.error(f"--{name} must be positive, got {getattr(args, name)}")
  writer = common.ResultWriter(args.out or common.default_results_path("solver_iterations"))
  for name in args.tasks:
    env = tasks.make(name, args.physics)
    if args.ls_iterations is not None:  # (the mode's settings, the cap replaced)
      env = tasks.make(name, dataclasses.replace(env.solver_settings,
                                                 ls_iterations=args.ls_iterations))
    policy_fn, policy = policy_for(env, args.policy == "expert")
    counts, passes = rollout_counts(env, policy_fn, args.num_envs, args.steps,
                                    jax.random.PRNGKey(args.seed))
    cap, ls_cap = int(env.mjx_model.opt.iterations), int(env.mjx_model.opt.ls_iterations)
    s = summary(counts, passes, cap, ls_cap, args.num_envs)
    maxima = ", ".join(f"{k}: {v:.2f}" for k, v in s["mean_batch_max"].items())
    ls = s["line_search"]
    print(f"{name} ({policy}): iterations mean {s['mean']:.2f} of cap {cap}, median "
          f"{s['quantiles']['0.5']:g}, 90% {s['quantiles']['0.9']:g}, at cap "
          f"{100 * s['at_cap']:.1f}%; mean batch max by batch size {maxima}; line search "
          f"{ls['mean_per_iteration']:.2f} passes per iteration, per substep of the batch "
          f"{ls['batch_passes_now']:.1f} computed, {ls['batch_passes_if_stopped']:.1f} if it "
          "stopped with the batch's slowest", flush=True)
    writer.write(kind="solver_iterations", task=name, policy=policy, physics=args.physics,
                 settings={"num_envs": args.num_envs, "steps": args.steps, "seed": args.seed,
                           "iterations": cap, "ls_iterations": ls_cap}, **s)
  print(f"results appended to {writer.path}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
