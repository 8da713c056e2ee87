#!/usr/bin/env python3
"""Does a demonstrator model rank behaviour the way the task does? (FORM diagnostics)

Records episodes of the shipped expert with growing action noise (its mean action plus
N(0, sigma^2), clipped), of uniform random actions and of any `--policy` file (e.g. a FORM
run's imitator, its mean action), and scores every transition with the demonstrator's
log pD(x_{t+1} | x_t) (raw observation space, FORM's reward term). Prints, per behaviour, the
task return, the distribution of log pD, the rank correlation of an episode's return and its
mean log pD within the behaviour (does the reward prefer its better episodes?), the share of
the policy's mean outside [-1, 1] and its median scale (not for random actions), the
observation dimensions furthest from the noiseless expert's (in its standard deviations: where
a policy's posture differs), which mixture component explains each transition (the one of
largest weighted density: its weight and the geometric mean of its scales, in standardised
units; a demonstrator that explains every transition off the expert's with one broad
component pays them all about the same, and FORM's reward has no slope there), and the same
rank correlation over all episodes; appends
`kind: form_reward_landscape` records. For a task with raw unbounded angles
(`Task.periodic_observations`), log pD is also split by whether the transition's next
observation has them within [-pi, pi) or turned past (`log_pd_by_turn`).

  python benchmarks/form_reward_landscape.py --task cheetah_run --episodes 8 \\
      --policy runs/cheetah_run_form_seed0/policy.npz \\
      --results benchmarks/results/<date>_form_reward_landscape_cpu.jsonl
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402
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
from mjx_form.sim import env as env_lib  # noqa: E402


def rollout(env, agent, noise, key, episodes):
  """Observations [K, T+1, D], returns [K], and the policy's mean and scale [T, K, A] at the
  states visited: `agent`'s (a loaded policy file's) mean action plus N(0, noise^2) (clipped),
  or uniform random actions where `noise` is None."""
  policy = experts.policy_network(agent.metadata, env.action_size)

  @jax.jit
  def run(key):
    reset_key, key = jax.random.split(key)
    states = jax.vmap(env.reset)(jax.random.split(reset_key, episodes))

    def step(states, key):
      pi = policy.apply(agent.params, normalizer.normalize(agent.normalizer, states.obs))
      if noise is None:
        action = jax.random.uniform(key, (episodes, env.action_size), minval=-1, maxval=1)
      else:
        action = pi.mode() + noise * jax.random.normal(key, pi.mode().shape)
      nxt = jax.vmap(env.step)(states, env.clip_action(action))
      return nxt, (states.obs, nxt.reward, pi.mode(), pi.scale)

    final, (obs, rewards, means, scales) = jax.lax.scan(
        step, states, jax.random.split(key, env_lib.EPISODE_LENGTH))
    return (jnp.swapaxes(jnp.concatenate([obs, final.obs[None]]), 0, 1), rewards.sum(0),
            means, scales)

  return jax.device_get(run(key))


def responsible_component(mixture, target: jax.Array | np.ndarray) -> dict:
  """Over transitions, the component with the largest weighted density at `target` [..., D]
  under `mixture` ([..., K, D]): medians of its weight and of the geometric mean of its scales
  (standardised units), and its share of the transitions per component index [K]."""
  joint = np.asarray(mixture.component_log_probs(jnp.asarray(target)))  # [..., K]
  top = joint.argmax(axis=-1)[..., None]  # [..., 1]
  weights = np.asarray(jax.nn.softmax(mixture.logits, axis=-1))
  scales = np.exp(np.asarray(jnp.log(mixture.scale)).mean(axis=-1))  # [..., K]
  k = joint.shape[-1]
  return {"weight_median": float(np.median(np.take_along_axis(weights, top, -1))),
          "scale_median": float(np.median(np.take_along_axis(scales, top, -1))),
          "share": [float(np.mean(top == i)) for i in range(k)]}


def log_pd_by_turn(obs: np.ndarray, period: np.ndarray, log_d: np.ndarray) -> dict:
  """log pD [K, T] of transitions split by whether the next observation (obs [K, T+1, D]) has
  every periodic dimension (`period` [D] > 0) within [-period / 2, period / 2): the mean of
  each group (None where empty) and the share turned past."""
  turned = common.turned_past(obs[:, 1:], period)  # [K, T]
  return {"within": float(log_d[~turned].mean()) if (~turned).any() else None,
          "turned": float(log_d[turned].mean()) if turned.any() else None,
          "turned_share": float(turned.mean())}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", required=True)
  parser.add_argument("--demonstrator", help="default: tasks/demonstrators/<task>.npz")
  parser.add_argument("--episodes", type=int, default=8, help="per behaviour")
  parser.add_argument("--noise", default="0,0.3,1", help="action noise scales of the expert")
  parser.add_argument("--policy", action="append", default=[],
                      help="a policy file of this task to score too (its mean action; "
                           "repeatable), e.g. a FORM run's policy.npz")
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
  mixture_of = jax.jit(lambda obs: em.transition_mixture(
      model, demonstrator.params, demonstrator.normalizer, obs[:, :-1], obs[:, 1:]))
  expert = experts.load_expert(tasks.bundled_expert(args.task), env)
  try:
    others = [(f"policy {p}", experts.load_expert(p, env)) for p in args.policy]
  except ValueError as e:
    parser.error(str(e))
  writer = results.ResultWriter(args.results) if args.results else None
  behaviours = [("expert + noise 0", 0.0, expert)]  # first: the reference posture
  behaviours += [(f"expert + noise {s}", float(s), expert) for s in args.noise.split(",")
                 if float(s) != 0]
  behaviours += [("uniform random", None, expert)] + [(n, 0.0, p) for n, p in others]
  names = env_lib.observation_names(env.observation_layout)
  period = np.asarray(env.observation_period())  # [D]: 2 pi at raw unbounded angles
  reference = None
  all_returns, all_scores = [], []
  print(f"{args.task}: demonstrator {path} (held-out log p at offset 1: "
        f"{file.metadata['training']['heldout_log_likelihood'][0]:.2f})")
  for i, (name, noise, agent) in enumerate(behaviours):
    obs, returns, means, scales = rollout(env, agent, noise, jax.random.PRNGKey(i),
                                          args.episodes)
    # The policy's mean outside [-1, 1] (the control range but for quadruped's), and its scale.
    policy_stats = {} if noise is None else {
        "mean_out_of_bounds": float(np.mean(np.abs(means) > 1.0)),
        "policy_scale_median": float(np.median(scales))}
    log_d = np.asarray(score(jnp.asarray(obs)))  # [K, T]
    per_episode = log_d.mean(axis=1)
    all_returns += list(returns)
    all_scores += list(per_episode)
    q = np.percentile(log_d, [5, 50, 95])
    within = float(stats.spearmanr(returns, per_episode).statistic)  # nan if returns are equal
    flat = obs.reshape(-1, obs.shape[-1])
    if reference is None:
      reference = flat.mean(axis=0), flat.std(axis=0) + 1e-6
    # How far this behaviour's mean observation sits from the noiseless expert's.
    shift = (flat.mean(axis=0) - reference[0]) / reference[1]
    far = np.argsort(-np.abs(shift))[:3]
    turn = log_pd_by_turn(obs, period, log_d) if period.any() else None
    explained = responsible_component(*mixture_of(jnp.asarray(obs)))
    print(f"  {name:22s} return {returns.mean():7.1f}  log pD per transition: mean "
          f"{log_d.mean():9.2f}  p5/p50/p95 {q[0]:9.2f} {q[1]:8.2f} {q[2]:8.2f}  "
          f"rank corr. with return {within:5.2f}  "
          + "".join(f"{k.replace('_', ' ')} {v:.2f}  " for k, v in policy_stats.items())
          + "furthest from the expert: "
          + ", ".join(f"{names[d]} {shift[d]:+.1f} sd" for d in far))
    if turn is not None:
      print(f"  {'':22s} log pD within [-pi, pi): "
            + ("-" if turn["within"] is None else f"{turn['within']:.2f}")
            + f", turned past ({turn['turned_share']:.0%} of transitions): "
            + ("-" if turn["turned"] is None else f"{turn['turned']:.2f}"))
    shares = " / ".join(f"{v:.0%}" for v in explained["share"])
    print(f"  {'':22s} explained by components {shares}, "
          f"the responsible one's weight {explained['weight_median']:.3f} and scale "
          f"{explained['scale_median']:.3f} sd (medians)")
    if writer:
      writer.write(kind="form_reward_landscape", task=args.task, method="form",
                   behaviour=name, noise=noise, episodes=args.episodes,
                   task_return=float(returns.mean()), log_pd_mean=float(log_d.mean()),
                   log_pd_percentiles={"p5": q[0], "p50": q[1], "p95": q[2]},
                   spearman_return_log_pd=None if np.isnan(within) else within,
                   shift_from_expert={names[d]: float(shift[d]) for d in far}, **policy_stats,
                   **({} if turn is None else {"log_pd_by_turn": turn}),
                   responsible_component=explained,
                   demonstrator_sha256=file.metadata["sha256"],
                   demonstrator_settings=config.to_dict())
  rho = stats.spearmanr(all_returns, all_scores).statistic
  print(f"  rank correlation of episode return and mean log pD over all episodes: {rho:.2f}")
  if writer:
    writer.write(kind="form_reward_landscape", task=args.task, method="form",
                 behaviour="all", episodes=len(all_returns), spearman_return_log_pd=float(rho),
                 demonstrator_sha256=file.metadata["sha256"],
                 demonstrator_settings=config.to_dict())
  return 0


if __name__ == "__main__":
  sys.exit(main())
