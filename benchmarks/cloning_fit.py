#!/usr/bin/env python3
"""BC's fit of the expert's actions, offline: how fast each cloning loss fits the policy's mean.

BC (mjx_form.rl.cloning) fits the learner's Gaussian policy network to the demonstrations'
(observation, action) pairs. Its evaluations use the policy's mean action, so what decides its
return is how closely that mean follows the expert's. This fits the same network, initialised
and optimised as a run's (the learner's init, Adam at the given learning rate, gradients clipped
at the learner's `max_grad_norm`, batches of `--batch` pairs drawn uniformly), to the training
episodes of a demonstration file with actions, once per cloning loss and learning rate, and
every `--every` updates measures on the training pairs and on held-out episodes (the file's
last `--heldout` share of episodes): the mean action's squared error (per action dimension, as
the runs' `bc_action_error`), the mean log-likelihood of the actions, and the mean scale.
Observations are standardised by the training observations' mean and variance (a run's EMA
of the pairs it draws settles there). No environment is stepped. Appends one `kind:
cloning_fit` record per loss and learning rate (its measurements as lists over `updates`).

  python scripts/make_demos.py --task reacher_easy --episodes 200 --actions --out /tmp/re.npz
  python benchmarks/cloning_fit.py --task reacher_easy --demos /tmp/re.npz \\
      --loss likelihood --loss decoupled --loss decoupled:0.01 --learning_rate 1e-4 \\
      --updates 2000 --results benchmarks/results/<date>_cloning_fit_cpu_reacher_easy.jsonl

`--loss KIND[:W]`: a cloning loss of `cloning.CLONING_LOSSES`; for "decoupled", W weights its
scale term (`cloning.fit_loss`'s `scale_weight`, default 1); "mean" fits the mean alone by
squared error (the scale is not trained: a reference for how fast the mean can be fitted).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # noqa: E402  (puts the repository on sys.path)
from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import demos as demos_lib  # noqa: E402
from mjx_form.files import experts  # noqa: E402
from mjx_form.files import results  # noqa: E402
from mjx_form.rl import cloning  # noqa: E402
from mjx_form.rl import learner as learner_lib  # noqa: E402
from mjx_form.rl import normalizer  # noqa: E402
from mjx_form.rl.networks import make_networks  # noqa: E402


def parse_loss(text: str) -> tuple[str, float]:
  """"KIND[:W]" -> (kind, scale weight); a kind of `cloning.CLONING_LOSSES` or "mean"."""
  kind, _, weight = text.partition(":")
  if kind not in (*cloning.CLONING_LOSSES, "mean"):
    raise ValueError(f"unknown loss {kind!r}; valid: "
                     f"{', '.join((*cloning.CLONING_LOSSES, 'mean'))}")
  if weight and kind != "decoupled":
    raise ValueError(f"only the decoupled loss takes a scale weight, got {text!r}")
  try:
    w = float(weight) if weight else 1.0
  except ValueError:
    raise ValueError(f"the scale weight in {text!r} is not a number") from None
  if not w > 0:
    raise ValueError(f"the scale weight must be positive, got {text!r}")
  return kind, w


def split_pairs(observations: np.ndarray, actions: np.ndarray, heldout: float
                ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
  """Training and held-out pairs (x [N, D], a [N, A]) of episodes [K, T+1, D] / [K, T, A]: the
  last `heldout` share of the episodes (at least one) held out whole."""
  k = len(actions)
  held = max(1, int(round(k * heldout)))
  if held >= k:
    raise ValueError(f"{k} episodes leave none to train on with --heldout {heldout}")
  pairs = lambda o, a: (o[:, :-1].reshape(-1, o.shape[-1]), a.reshape(-1, a.shape[-1]))
  return (pairs(observations[:k - held], actions[:k - held]),
          pairs(observations[k - held:], actions[k - held:]))


def measures(networks, params, norm, x: jax.Array, a: jax.Array) -> dict:
  """The mean action's squared error (mean over pairs and dimensions), the actions' mean
  log-likelihood and the mean scale of the policy on pairs x [N, D], a [N, A]."""
  pi = networks.policy.apply(params, normalizer.normalize(norm, x))
  return {"action_error": jnp.mean(jnp.square(pi.mean - a)),
          "log_prob": jnp.mean(pi.log_prob(a)), "scale": jnp.mean(pi.scale)}


def fit(networks, config: learner_lib.LearnerConfig, kind: str, scale_weight: float, norm,
        train: tuple, heldout: tuple, updates: int, batch: int, every: int, key: jax.Array
        ) -> tuple[dict[str, list[float]], dict]:
  """Fits a fresh policy (the learner's init from `key`) for `updates` steps; returns lists of
  the measures on the training and held-out pairs at update 0, `every`, 2 `every`, ..., and
  the fitted policy's parameters."""
  init_key, draw_key = jax.random.split(key)
  policy = learner_lib.init(networks, config, init_key, train[0].shape[-1],
                            train[1].shape[-1]).policy
  tx = learner_lib.policy_optimizer(config)
  x_train, a_train = jnp.asarray(train[0]), jnp.asarray(train[1])
  x_held, a_held = jnp.asarray(heldout[0]), jnp.asarray(heldout[1])

  def loss(p, x, a):
    x = normalizer.normalize(norm, x)
    if kind == "mean":
      return jnp.mean(jnp.sum(jnp.square(networks.policy.apply(p, x).mean - a), axis=-1))
    return cloning.loss(networks, p, x, a, kind, scale_weight)[0]

  def step(carry, k):
    p, opt = carry
    i = jax.random.randint(k, (batch,), 0, x_train.shape[0])
    change, opt = tx.update(jax.grad(loss)(p, x_train[i], a_train[i]), opt, p)
    return (optax.apply_updates(p, change), opt), None

  @jax.jit
  def chunk(p, opt, keys):  # `every` updates in one program
    return jax.lax.scan(step, (p, opt), keys)[0]

  score = jax.jit(lambda p: (measures(networks, p, norm, x_train, a_train),
                             measures(networks, p, norm, x_held, a_held)))
  out: dict[str, list[float]] = {"updates": []}
  opt = tx.init(policy)
  keys = jax.random.split(draw_key, updates).reshape(-1, every, 2)
  for n in range(len(keys) + 1):
    if n:
      policy, opt = chunk(policy, opt, keys[n - 1])
    on_train, on_held = score(policy)
    out["updates"].append(n * every)
    for prefix, m in (("train_", on_train), ("heldout_", on_held)):
      for name, value in m.items():
        out.setdefault(prefix + name, []).append(round(float(value), 6))
  return out, policy


def returns(env, params, norm, width: int, episodes: int, key: jax.Array) -> np.ndarray:
  """The task returns [episodes] of the policy's mean action (clipped to the control range),
  one episode per environment from `key`'s starts, as a run's evaluation."""
  agent = experts.Expert(params, norm, {"network_width": width})
  rewards = common.mean_action_rollout(env, agent, key, episodes, lambda s: s.reward)  # [T, K]
  return np.asarray(rewards).sum(axis=0)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", required=True)
  parser.add_argument("--demos", required=True, help="demonstrations with actions "
                      "(scripts/make_demos.py --actions)")
  parser.add_argument("--loss", action="append", required=True,
                      help="KIND[:W] (module docstring); repeat to compare")
  parser.add_argument("--learning_rate", type=float, action="append", default=None,
                      help="repeat to compare (default: the learner's, 1e-4)")
  parser.add_argument("--updates", type=int, default=2000)
  parser.add_argument("--every", type=int, default=250, help="updates between measurements")
  parser.add_argument("--batch", type=int, default=6400,
                      help="pairs per update (a run's: batch_size x unroll_length, 64 x 100)")
  parser.add_argument("--heldout", type=float, default=0.1, help="share of episodes held out")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--eval_episodes", type=int, default=0,
                      help="evaluate each fitted policy's mean action over this many episodes")
  parser.add_argument("--width", type=int, default=256)
  parser.add_argument("--results", default=None)
  args = parser.parse_args(argv)
  if args.task not in tasks.TASKS:
    parser.error(f"unknown task {args.task!r}; valid tasks: {', '.join(tasks.TASKS)}")
  for name in ("updates", "every", "batch", "width"):
    if getattr(args, name) < 1:
      parser.error(f"--{name} must be positive, got {getattr(args, name)}")
  if args.eval_episodes < 0:
    parser.error(f"--eval_episodes must be >= 0, got {args.eval_episodes}")
  if args.updates % args.every:
    parser.error(f"--updates ({args.updates}) must be a multiple of --every ({args.every})")
  if not 0.0 < args.heldout < 1.0:
    parser.error(f"--heldout must be in (0, 1), got {args.heldout}")
  rates = args.learning_rate or [learner_lib.LearnerConfig().learning_rate]
  if not all(r > 0 for r in rates):
    parser.error(f"--learning_rate must be positive, got {rates}")
  try:
    losses = [parse_loss(text) for text in args.loss]
  except ValueError as e:
    parser.error(str(e))
  env = tasks.make(args.task)
  try:
    demos = demos_lib.load_demonstrations(args.demos, task=args.task,
                                          observation_layout=env.observation_layout,
                                          need_actions=True)
    train, heldout = split_pairs(np.asarray(demos.observations, np.float32),
                                 np.asarray(demos.actions, np.float32), args.heldout)
  except (ValueError, OSError) as e:
    print(f"error: {e}", file=sys.stderr)
    return 2
  norm = normalizer.update(normalizer.init(train[0].shape[-1]), jnp.asarray(train[0]))
  networks = make_networks(train[1].shape[-1], args.width)
  writer = results.ResultWriter(args.results) if args.results else None
  print(f"{len(demos.actions)} episodes: {len(train[0])} training pairs, {len(heldout[0])} "
        f"held out")
  for rate in rates:
    config = learner_lib.LearnerConfig(learning_rate=rate)
    for (kind, weight), text in zip(losses, args.loss):
      start = time.perf_counter()
      out, policy = fit(networks, config, kind, weight, norm, train, heldout, args.updates,
                        args.batch, args.every, jax.random.PRNGKey(args.seed))
      seconds = time.perf_counter() - start
      line = (f"{text:>16} lr {rate:g}: action error train {out['train_action_error'][-1]:.4f} "
              f"held-out {out['heldout_action_error'][-1]:.4f}, held-out log-likelihood "
              f"{out['heldout_log_prob'][-1]:.2f}, scale {out['heldout_scale'][-1]:.3f} after "
              f"{args.updates} updates ({seconds:.0f} s)")
      if args.eval_episodes:
        got = returns(env, policy, norm, args.width, args.eval_episodes,
                      jax.random.PRNGKey(10_000 + args.seed))
        out["eval_return"], out["eval_return_std"] = (round(float(got.mean()), 2),
                                                      round(float(got.std()), 2))
        out["eval_episodes"] = args.eval_episodes
        line += f"; return {got.mean():.1f} +- {got.std():.1f} over {args.eval_episodes}"
      print(line)
      if writer:
        writer.write(kind="cloning_fit", task=args.task, method="bc", loss=kind,
                     scale_weight=weight, learning_rate=rate, batch=args.batch,
                     width=args.width, seed=args.seed,
                     demonstrations={"path": args.demos, "sha256": demos.metadata.get("sha256"),
                                     "episodes": len(demos.actions),
                                     "heldout_episodes": len(demos.actions)
                                     - len(train[0]) // demos.actions.shape[1]},
                     seconds=round(seconds, 1), **out)
  return 0


if __name__ == "__main__":
  sys.exit(main())
