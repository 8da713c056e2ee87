#!/usr/bin/env python3
"""MPO's M-step on a known Q whose best action moves from beyond a bound to inside it: how
far the policy's mean drifts out of [-1, 1] while the best action is the bound, and how fast
it comes back once the best action lies inside, with the paper's M-step, with
`--clip_mean_targets` (the mean fitted to the clipped samples) and with the action penalty.

No network, no critic, no environment: S states, each with its own policy mean and scale
(free parameters), Q(s, a) = -q_scale * sum_d (clip(a_d, -1, 1) - b_d)^2 known exactly, the
target policy copied every `--target_period` updates, N samples per state from the target,
`mpo.mpo_loss` with Adam on the policy and the duals, as the learner does. Phase 1 (b = 1.5:
every action at or beyond 1 is best) lets the mean drift; phase 2 (b = 0.5) asks it back.
Q values the clipped action, as a critic with `--clip_critic_actions` does (the recipes'); the
paper's critic sees the raw action, and can tell apart samples beyond a bound.

  python benchmarks/saturation_bandit.py            # prints a table, writes a record
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

from mjx_form.rl import mpo  # noqa: E402
from mjx_form.rl.distributions import DiagonalGaussian  # noqa: E402

ARMS = {"paper M-step": {}, "clip_mean_targets": {"clip_mean_targets": True},
        "action penalty": {"action_penalty": True}}


def run_arm(config: mpo.MPOConfig, args, key) -> dict[str, np.ndarray]:
  """Per update: share of means beyond the bounds, mean |mean|, mean |clip(mean) - clip(b)|
  (the applied mean action's distance from the best applied action), mean scale; [updates]
  arrays."""
  S, A, N = args.states, args.actions, args.samples
  params = {"mean": jnp.zeros((S, A)), "log_scale": jnp.full((S, A), jnp.log(args.init_scale))}
  duals = mpo.init_duals(config, A)
  policy_opt, dual_opt = optax.adam(args.learning_rate), optax.adam(args.dual_learning_rate)
  state = (params, params, duals, policy_opt.init(params), dual_opt.init(duals))
  best = jnp.where(jnp.arange(args.updates) < args.phase1, args.best_beyond, args.best_inside)

  def update(state, xs):
    step, b, key = xs
    params, target_params, duals, popt, dopt = state
    target = DiagonalGaussian(target_params["mean"], jnp.exp(target_params["log_scale"]))
    actions = target.sample(key, (N,))  # [N, S, A]
    q = -args.q_scale * jnp.sum(jnp.square(jnp.clip(actions, -1.0, 1.0) - b), axis=-1)

    def loss(p, d):
      online = DiagonalGaussian(p["mean"], jnp.exp(p["log_scale"]))
      return mpo.mpo_loss(d, online, target, actions, q, config)[0]

    g_params, g_duals = jax.grad(loss, argnums=(0, 1))(params, duals)
    u, popt = policy_opt.update(g_params, popt)
    params = optax.apply_updates(params, u)
    u, dopt = dual_opt.update(g_duals, dopt)
    duals = mpo.clip_duals(optax.apply_updates(duals, u))
    target_params = jax.tree.map(lambda t, o: jnp.where((step + 1) % args.target_period == 0, o, t),
                                 target_params, params)
    out = (jnp.mean(jnp.abs(params["mean"]) > 1.0), jnp.mean(jnp.abs(params["mean"])),
           jnp.mean(jnp.abs(jnp.clip(params["mean"], -1.0, 1.0) - jnp.clip(b, -1.0, 1.0))),
           jnp.mean(jnp.exp(params["log_scale"])))
    return (params, target_params, duals, popt, dopt), out

  keys = jax.random.split(key, args.updates)
  _, (beyond, size, error, scale) = jax.jit(lambda s: jax.lax.scan(
      update, s, (jnp.arange(args.updates), best, keys)))(state)
  return {"beyond": np.asarray(beyond), "size": np.asarray(size), "error": np.asarray(error),
          "scale": np.asarray(scale)}


def first_below(values: np.ndarray, threshold: float) -> int | None:
  hits = np.nonzero(values < threshold)[0]
  return int(hits[0]) if hits.size else None


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--states", type=int, default=256)
  parser.add_argument("--actions", type=int, default=6)
  parser.add_argument("--samples", type=int, default=20)
  parser.add_argument("--updates", type=int, default=6000)
  parser.add_argument("--phase1", type=int, default=3000)
  parser.add_argument("--best_beyond", type=float, default=1.5)
  parser.add_argument("--best_inside", type=float, default=0.5)
  parser.add_argument("--q_scale", type=float, default=10.0)
  parser.add_argument("--init_scale", type=float, default=0.5)
  parser.add_argument("--target_period", type=int, default=25)
  parser.add_argument("--learning_rate", type=float, default=3e-3,
                      help="Adam's on the free means and scales (the learner's 1e-4 moves a "
                           "network's outputs much faster than one free parameter each)")
  parser.add_argument("--dual_learning_rate", type=float, default=1e-3)
  parser.add_argument("--epsilon_scale", type=float, default=1e-6)
  parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
  parser.add_argument("--tolerance", type=float, default=0.1,
                      help="phase 2 counts as done when |clip(mean) - clip(b)| < this on "
                           "average")
  parser.add_argument("--results", default=None, help="a JSON Lines file (default: no record)")
  args = parser.parse_args(argv)
  if not 0 < args.phase1 < args.updates:
    parser.error("--phase1 must lie strictly between 0 and --updates")
  rows = []
  print(f"{'arm':<18} seed  beyond@phase1  |mean|@phase1  error@phase1  scale@phase1  "
        f"updates back (< {args.tolerance})  error@end  beyond@end")
  for name, overrides in ARMS.items():
    config = dataclasses.replace(mpo.MPOConfig(epsilon_scale=args.epsilon_scale), **overrides)
    for seed in args.seeds:
      out = run_arm(config, args, jax.random.key(seed))
      back = first_below(out["error"][args.phase1:], args.tolerance)
      row = {"arm": name, "seed": seed,
             "beyond_at_phase1": float(out["beyond"][args.phase1 - 1]),
             "abs_mean_at_phase1": float(out["size"][args.phase1 - 1]),
             "error_at_phase1": float(out["error"][args.phase1 - 1]),
             "scale_at_phase1": float(out["scale"][args.phase1 - 1]),
             "updates_back": back, "error_at_end": float(out["error"][-1]),
             "beyond_at_end": float(out["beyond"][-1])}
      rows.append(row)
      print(f"{name:<18} {seed:>4}  {row['beyond_at_phase1']:>13.2f}  "
            f"{row['abs_mean_at_phase1']:>13.2f}  {row['error_at_phase1']:>12.3f}  "
            f"{row['scale_at_phase1']:>12.3f}  {str(back):>26}  {row['error_at_end']:>9.3f}  "
            f"{row['beyond_at_end']:>10.2f}")
  if args.results:
    settings = {k: v for k, v in vars(args).items() if k != "results"}
    common.ResultWriter(args.results).write(kind="saturation_bandit", settings=settings,
                                            rows=rows)
  return 0


if __name__ == "__main__":
  sys.exit(main())
