#!/usr/bin/env python3
"""Does FORM's reward, at a run's end, prefer the expert's behaviour to the imitator's own?

A FORM run's learner maximises log pD - log pI, with pI the imitator model of its own recent
behaviour. Where an imitator fails the task, either that reward prefers what the imitator does
(the reward is wrong there), or it prefers the expert's behaviour and the learner does not find
it (optimisation, exploration). pI is the run's own where it kept one (a member's imitator.npz,
written with its final policy since session 49, with the run's reward statistics); else this
fits one as the run does, on the policy's own behaviour: `--episodes` episodes of the policy
sampling its actions as its actors do, and an effect model of the run's settings trained on
them (`--imitator_steps` steps of `--imitator_batch` windows, the best held-out state kept, as
a demonstrator's; on the CPU this fits far less well than a run's model). Then, on
`--eval_episodes` new starts, the policy (its mean action, as evaluated) and the task's expert
are scored with the member's reward: log pD (the demonstrators kept in its run directory: one,
their mixture, or the member's own) minus log pI, clipped and standardised as its learner gets
it (the member's own grid settings included), with the run's statistics where its imitator
file keeps them, else their fixed point on the raw rewards of the policy's sampled episodes
(`reward_statistics`). The FORM return of an episode is the sum of that reward. For reacher,
also per quadrant of the target's angle a = arctan2(x, y) ([-pi,-pi/2) / [-pi/2,0) / [0,pi/2)
/ [pi/2,pi), as reacher_settling.py).
Appends a `kind: form_reward_of_behaviour` record per policy.

  python benchmarks/form_reward_of_behaviour.py --run_dir runs/rh --member 0 \\
      --results benchmarks/results/<date>_form_reward_of_behaviour_cpu.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402
from mjx_form.cpu import configure_cpu_xla  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import tasks  # noqa: E402
from mjx_form.files import effect_models, experts, results  # noqa: E402
from mjx_form.imitation import demonstrator as demonstrator_lib  # noqa: E402
from mjx_form.imitation import effect_model as em  # noqa: E402
from mjx_form.imitation import form, pipeline  # noqa: E402
from mjx_form.rl import grid, runner  # noqa: E402


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--run_dir", required=True, help="a FORM run's directory (config.json "
                      "and its demonstrators)")
  parser.add_argument("--member", type=int, action="append", default=None,
                      help="the member to score, by its place in the run (0: a single "
                      "run's, or a population's first); repeatable (default: every member)")
  parser.add_argument("--policy_file", default="policy.npz",
                      help="which of the member's policies (default: the final one)")
  parser.add_argument("--episodes", type=int, default=256, help="sampled episodes the imitator "
                      "model trains on")
  parser.add_argument("--imitator_steps", type=int, default=4_000)
  parser.add_argument("--imitator_batch", type=int, default=16, help="windows of 100 "
                      "transitions per step (a run's: 64; a CPU step of 64 takes ~0.2 s)")
  parser.add_argument("--eval_episodes", type=int, default=256)
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--results", default=None)
  args = parser.parse_args(argv)
  try:
    return run(args)
  except (pipeline.PipelineError, ValueError, OSError) as e:
    print(f"error: {e}", file=sys.stderr)
    return 2


def run_settings(run_dir: str) -> dict:
  """The run's config.json, refused unless it is a FORM run's."""
  with open(os.path.join(run_dir, "config.json")) as f:
    config = json.load(f)
  if config.get("reward_source") != "form":
    raise ValueError(f"{run_dir}: not a FORM run (reward_source {config.get('reward_source')})")
  return config


def members(run_dir: str, config: dict) -> list[tuple[str, dict]]:
  """Each member's directory and own settings (a grid's overrides, {} else), in the run's order
  (mjx_form.rl.runner.member_dirs)."""
  seeds = tuple(config.get("seeds") or [config["seed"]])
  overrides = tuple(config.get("overrides") or [{} for _ in seeds])
  return list(zip(runner.member_dirs(run_dir, seeds, overrides), overrides))


def run_reward(run_dir: str, config: dict, env, own: dict) -> form.FormReward:
  """The run's FORM reward source (its kept demonstrators, pipeline.kept_source, and reward
  settings), with a member's own settings (`own`, a grid's overrides)."""
  settings = config["reward"]
  source = pipeline.kept_source(
      run_dir, env, reward={k: settings[k] for k in form.FormReward.variable_settings
                            if k in settings}, what="the run")
  return source.specialise(grid.split(own)[2])


def kept_imitator(path: str, env, config) -> tuple[em.EffectModelState, dict]:
  """A run's exported imitator model (its imitator.npz) as an effect-model state, and its
  `imitator` metadata (the run's reward statistics at its end among them); refused unless it
  is an imitator model of `env`'s task with the run's effect-model settings."""
  file = effect_models.load_effect_model(path, task=env.name,
                                         observation_layout=env.observation_layout)
  if "imitator" not in file.metadata or file.metadata["config"] != config.to_dict():
    raise ValueError(f"{path}: not an imitator model of this run's settings ({config.to_dict()})")
  _, model = pipeline.demonstrator_from_file(file, path)  # (its parameters checked to fit)
  steps = jnp.asarray(file.metadata["training"]["steps"])
  return (em.EffectModelState(model.params, None, model.normalizer, steps),
          file.metadata["imitator"])


def reward_statistics(reference: np.ndarray, clip: float) -> tuple[float, float]:
  """The mean and sd a run's running reward statistics settle at on raw rewards distributed as
  `reference`: where the run clips (`clip` sd > 0) it folds in rewards winsorised at `clip` sd
  around its own statistics, whose fixed point this iterates to."""
  mean, sd = float(np.mean(reference)), float(np.std(reference))
  for _ in range(100 if clip > 0 else 0):
    folded = np.clip(reference, mean - clip * sd, mean + clip * sd)
    mean, sd = float(np.mean(folded)), float(np.std(folded))
  return mean, sd


def learner_rewards(raw: np.ndarray, mean: float, sd: float, clip: float, standardise: bool
                    ) -> np.ndarray:
  """What the learner gets for `raw` rewards under statistics (mean, sd): clipped to `clip` sd
  around the mean (0: not clipped), then standardised where the run standardises."""
  if clip > 0:
    raw = np.clip(raw, mean - clip * sd, mean + clip * sd)
  return (raw - mean) / sd if standardise else raw


def mean_action_episodes(env, agent, key, episodes: int):
  """Observations [K, T+1, D] and task returns [K] of `agent`'s mean action from the starts of
  `key`, and the target positions [K, 2] where the task has one (else None)."""
  probe = lambda nxt: (nxt.obs, nxt.reward, nxt.task.get("target", jnp.zeros(2)))
  obs, rewards, target = common.mean_action_rollout(env, agent, key, episodes, probe)
  first = jax.device_get(jax.vmap(env.reset)(jax.random.split(key, episodes)).obs)
  obs = np.concatenate([np.asarray(first)[None], np.asarray(obs)])  # [T+1, K, D]
  has_target = "target" in jax.eval_shape(env.reset, key).task
  return np.swapaxes(obs, 0, 1), np.asarray(rewards).sum(0), (
      np.asarray(target[0]) if has_target else None)


def summary(groups: np.ndarray | None, **per_episode: np.ndarray) -> dict:
  """Means of per-episode values, overall and per group (where there are groups)."""
  out = {"all": {k: float(np.mean(v)) for k, v in per_episode.items()}}
  if groups is not None:
    out["by_target_quadrant"] = [
        {"episodes": int(np.sum(groups == q)),
         **{k: float(np.mean(v[groups == q])) for k, v in per_episode.items()}}
        for q in range(4)]
  return out


def score_member(args, config: dict, member: int, directory: str, own: dict) -> dict:
  env = tasks.make(config["task"], physics=config["physics"])
  source = run_reward(args.run_dir, config, env, own)
  path = os.path.join(directory, args.policy_file)
  agent = experts.load_expert(path, env)
  expert = experts.load_expert(tasks.bundled_expert(env.name), env)
  name = os.path.basename(directory)
  start = time.perf_counter()
  key_train, key_eval = jax.random.split(jax.random.PRNGKey(args.seed))
  actors = {**{k: config.get(k) for k in grid.ACTOR}, **grid.split(own)[1]}
  sampled, _, sampled_returns = experts.record(
      env, agent, key_train, args.episodes, stochastic=True,
      noise_correlation=actors.get("action_noise_correlation") or 0.0)
  kept = os.path.join(directory, source.export_file)
  stats = None
  if args.policy_file == "policy.npz" and os.path.exists(kept):  # the run's own, at its end
    state, info = kept_imitator(kept, env, source.config)
    stats = info["reward_mean"], info["reward_sd"]
    fit = {"file": kept, "steps": int(state.steps)}
    print(f"{name}: the run's imitator model ({fit['steps']} updates)", flush=True)
  else:
    training = demonstrator_lib.DemonstratorTraining(
        max_steps=args.imitator_steps, batch_size=args.imitator_batch,
        eval_every=max(1, min(2_000, args.imitator_steps // 8)), seed=args.seed)
    state, report = demonstrator_lib.train(sampled, source.config, training,
                                           print_fn=lambda line: None)
    fit = {"max_steps": args.imitator_steps, "batch_size": args.imitator_batch,
           "steps": report["steps"], "best_step": report["best_step"],
           "heldout_log_likelihood": [round(float(x), 3) for x in
                                      report["heldout_log_likelihood"]]}
    print(f"{name}: imitator model on {args.episodes} sampled episodes (return "
          f"{np.mean(sampled_returns):.1f}): held-out offset-1 "
          f"{fit['heldout_log_likelihood'][0]:.2f} at {fit['best_step']} steps, "
          f"{time.perf_counter() - start:.0f}s", flush=True)
  fs = source.init(jax.random.PRNGKey(0), env.observation_size, env.action_size)
  fs = fs._replace(imitator=state)
  if source.per_member:  # (init gives the first member's demonstrator)
    fs = fs._replace(demonstrator=jax.tree.map(lambda x: jnp.asarray(x[member]),
                                               source.demonstrator))
  log_probs = jax.jit(lambda obs: source.log_probs(fs, obs))

  def raw(obs):  # [K, T+1, D] -> log pD, log pI [K, T]
    parts = [jax.device_get(log_probs(jnp.asarray(obs[i:i + 32])))
             for i in range(0, obs.shape[0], 32)]
    return tuple(np.concatenate([p[j] for p in parts]) for j in range(2))

  clip, standardise = source.reward_clip, source.standardise_reward
  if stats is None:  # (the run's own where its imitator file keeps them)
    ref_d, ref_i = raw(sampled)
    stats = reward_statistics((ref_d - ref_i).ravel(), clip)
  mean, sd = stats
  out = {"member": member, "policy_file": path, "own_settings": own,
         "sampled_return": float(np.mean(sampled_returns)), "imitator_model": fit,
         "reward_mean": mean, "reward_sd": sd}
  groups = None
  for who, behaviour in (("policy", agent), ("expert", expert)):
    obs, returns, target = mean_action_episodes(env, behaviour, key_eval, args.eval_episodes)
    log_d, log_i = raw(obs)
    given = learner_rewards(log_d - log_i, mean, sd, clip, standardise)
    if target is not None:  # (the same starts for both)
      groups = common.angle_quadrant(np.arctan2(target[:, 0], target[:, 1]))
    out[who] = {"task_return": returns, "form_return": given.sum(1),
                "log_pd": log_d.mean(1), "log_pi": log_i.mean(1)}
  wins = out["expert"]["form_return"] > out["policy"]["form_return"]
  per_episode = {f"{who}_{k}": v for who in ("policy", "expert")
                 for k, v in out.pop(who).items()}
  out.update(summary(groups, **per_episode, expert_form_return_higher=wins.astype(float)))
  out["seconds"] = round(time.perf_counter() - start, 1)
  return out


def run(args) -> int:
  config = run_settings(args.run_dir)
  dirs = members(args.run_dir, config)
  chosen = args.member if args.member is not None else range(len(dirs))
  for member in chosen:
    if not 0 <= member < len(dirs) or not os.path.isdir(dirs[member][0]):
      raise ValueError(f"--member {member}: the run has members 0-{len(dirs) - 1}"
                       + (f"; {dirs[member][0]} is missing" if 0 <= member < len(dirs) else ""))
  writer = results.ResultWriter(args.results) if args.results else None
  for member in chosen:
    directory, own = dirs[member]
    out = score_member(args, config, member, directory, own)
    a = out["all"]
    print(f"{os.path.basename(directory)}: task return policy {a['policy_task_return']:.1f} "
          f"expert {a['expert_task_return']:.1f}; FORM return policy {a['policy_form_return']:.1f} "
          f"expert {a['expert_form_return']:.1f} (expert higher on "
          f"{a['expert_form_return_higher']:.0%} of starts); log pD {a['policy_log_pd']:.1f} / "
          f"{a['expert_log_pd']:.1f}, log pI {a['policy_log_pi']:.1f} / {a['expert_log_pi']:.1f}")
    for q, g in enumerate(out.get("by_target_quadrant", [])):
      print(f"  quadrant {q} ({g['episodes']} starts): task {g['policy_task_return']:.0f} / "
            f"{g['expert_task_return']:.0f}, FORM {g['policy_form_return']:.0f} / "
            f"{g['expert_form_return']:.0f} (expert higher {g['expert_form_return_higher']:.0%})"
            f", log pD {g['policy_log_pd']:.1f} / {g['expert_log_pd']:.1f}, log pI "
            f"{g['policy_log_pi']:.1f} / {g['expert_log_pi']:.1f}", flush=True)
    if writer:
      writer.write(kind="form_reward_of_behaviour", task=config["task"], method="form",
                   run_dir=args.run_dir, episodes=args.episodes,
                   eval_episodes=args.eval_episodes, seed=args.seed, **out)
  return 0


if __name__ == "__main__":
  sys.exit(main())
