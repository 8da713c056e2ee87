#!/usr/bin/env python3
"""Does a demonstrator model rank behaviour the way the task does? (FORM diagnostics)

Records episodes of the shipped expert with growing action noise (its mean action plus
N(0, sigma^2), clipped) and of uniform random actions, and scores every transition with the
demonstrator's log pD(x_{t+1} | x_t) (raw observation space, FORM's reward term). Prints, per
behaviour, the task return and the distribution of log pD, and the rank correlation between an
episode's task return and its mean log pD over all episodes; appends `kind:
form_reward_landscape` records.

  python benchmarks/form_reward_landscape.py --task cheetah_run --episodes 8 \\
      --results benchmarks/results/<date>_form_reward_landscape_cpu.jsonl
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import effect_models, experts, results  # noqa: E402
from mjx_form.imitation import effect_model as em  # noqa: E402
from mjx_form.imitation import pipeline  # noqa: E402
from mjx_form.rl import normalizer  # noqa: E402
from mjx_form.rl.networks import make_networks  # noqa: E402
from mjx_form.sim import env as env_lib  # noqa: E402


def rollout(env, expert, noise, key, episodes):
  """Observations [K, T+1, D] and returns [K]: the expert's mean action plus N(0, noise^2)
  (clipped), or uniform random actions where `noise` is None."""
  policy = make_networks(env.action_size, expert.metadata["network_width"]).policy

  @jax.jit
  def run(key):
    reset_key, key = jax.random.split(key)
    states = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))

    def step(states, key):
      if noise is None:
        action = jax.random.uniform(key, (episodes, env.action_size), minval=-1, maxval=1)
      else:
        mean = policy.apply(expert.params, normalizer.normalize(expert.normalizer, states.obs))
        action = mean.mode() + noise * jax.random.normal(key, mean.mode().shape)
      nxt = jax.vmap(env.step)(states, jnp.clip(action, -1.0, 1.0))
      return nxt, (states.obs, nxt.reward)

    final, (obs, rewards) = jax.lax.scan(step, states,
                                         jax.random.split(key, env_lib.EPISODE_LENGTH))
    return jnp.swapaxes(jnp.concatenate([obs, final.obs[None]]), 0, 1), rewards.sum(0)

  return jax.device_get(run(key))


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", required=True)
  parser.add_argument("--demonstrator", help="default: tasks/demonstrators/<task>.npz")
  parser.add_argument("--episodes", type=int, default=8, help="per behaviour")
  parser.add_argument("--noise", default="0,0.3,1", help="action noise scales of the expert")
  parser.add_argument("--results", default=None)
  args = parser.parse_args(argv)
  env = tasks.make(args.task)
  path = args.demonstrator or tasks.bundled_demonstrator(args.task)
  if path is None:
    parser.error(f"no demonstrator shipped for {args.task}; pass --demonstrator")
  file = effect_models.load_effect_model(path, task=args.task,
                                         observation_layout=env.observation_layout)
  config, demonstrator = pipeline.demonstrator_from_file(file, path)
  model = em.make_model(config, env.observation_size)
  score = jax.jit(lambda obs: em.transition_log_prob(
      model, demonstrator.params, demonstrator.normalizer, obs[:, :-1], obs[:, 1:]))
  expert = experts.load_expert(tasks.bundled_expert(args.task), env)
  writer = results.ResultWriter(args.results) if args.results else None
  behaviours = [(f"expert + noise {s}", float(s)) for s in args.noise.split(",")]
  behaviours.append(("uniform random", None))
  all_returns, all_scores = [], []
  print(f"{args.task}: demonstrator {path} (held-out log p at offset 1: "
        f"{file.metadata['training']['heldout_log_likelihood'][0]:.2f})")
  for i, (name, noise) in enumerate(behaviours):
    obs, returns = rollout(env, expert, noise, jax.random.PRNGKey(i), args.episodes)
    log_d = np.asarray(score(jnp.asarray(obs)))  # [K, T]
    per_episode = log_d.mean(axis=1)
    all_returns += list(returns)
    all_scores += list(per_episode)
    q = np.percentile(log_d, [5, 50, 95])
    print(f"  {name:22s} return {returns.mean():7.1f}  log pD per transition: mean "
          f"{log_d.mean():9.2f}  p5/p50/p95 {q[0]:9.2f} {q[1]:8.2f} {q[2]:8.2f}")
    if writer:
      writer.write(kind="form_reward_landscape", task=args.task, method="form",
                   behaviour=name, noise=noise, episodes=args.episodes,
                   task_return=float(returns.mean()), log_pd_mean=float(log_d.mean()),
                   log_pd_percentiles={"p5": q[0], "p50": q[1], "p95": q[2]},
                   demonstrator_sha256=file.metadata["sha256"])
  rho = stats.spearmanr(all_returns, all_scores).statistic
  print(f"  rank correlation of episode return and mean log pD over all episodes: {rho:.2f}")
  if writer:
    writer.write(kind="form_reward_landscape", task=args.task, method="form",
                 behaviour="all", episodes=len(all_returns), spearman_return_log_pd=float(rho),
                 demonstrator_sha256=file.metadata["sha256"])
  return 0


if __name__ == "__main__":
  sys.exit(main())
