#!/usr/bin/env python3
"""Does reacher's demonstrator reward settling on the target over hovering near it? (FORM)

reacher_hard's FORM imitators get within ~3 cm of the target and do not settle, where the task
pays only within 2.5 cm (target 1.5 cm + finger 1 cm; benchmarks/NOTES.md, sessions 36-37).
This scores, with the demonstrator's log pD(x_t | x_{t-1}), the transitions of the shipped
expert where it has settled (fingertip within `--settled` of the target, joints nearly still),
as recorded and with the target moved by d (`--offsets`, metres, a random direction per
transition, in both observations: the arm is as still as before, the target elsewhere). If log pD falls with d, the demonstrator tells
"still at the target" from "still 3 cm away"; if it is flat, FORM's reward cannot pull the last
centimetres. With `--policy` files (e.g. FORM imitators), also their transitions by distance
to the target and joint speed, as they visit them, and (over `--target_episodes` episodes)
where their failed episodes (return under 100) have the target: the failure rate by quartile
of the target's distance from the arm's base and by its angle; and, on `--episodes` episodes
from the expert's own starts, how the policy's failed episodes end (still or shaking in place,
whether they ever came within 5 cm, the policy's scale and out-of-bounds means there), what
the demonstrator pays for their second half against the policy's successful episodes and the
expert's on the same starts, and how often they fail by where the expert's shoulder ends on
the same starts (near +-pi or elsewhere; starts where the expert itself scores 800 or less are
left out of that), how the expert gets there (passing
+-pi or not) and where the failed episodes' shoulder ends; and, for the expert and each policy on
those starts, the demonstrator's log pD by where the shoulder is at x_t (wrapped: near +-pi or
elsewhere) and of the transitions that cross +-pi (`--demonstrator`: another demonstrator file
of the task to score with). Appends `kind: reacher_settling` records.

  python benchmarks/reacher_settling.py --task reacher_hard --episodes 32 \\
      --policy runs/rh/seed0/policy.npz --results benchmarks/results/<date>_reacher_settling.jsonl
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
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import tasks  # noqa: E402
from form_reward_landscape import rollout  # noqa: E402
from mjx_form.files import effect_models, experts, results  # noqa: E402
from mjx_form.imitation import effect_model as em  # noqa: E402
from mjx_form.imitation import pipeline  # noqa: E402
from mjx_form.sim import env as env_lib  # noqa: E402

SPEED_BINS = (0.0, 0.5, 2.0, np.inf)  # joint speed |qvel| (rad/s): still, slow, moving
DISTANCE_BINS = (0.0, 0.01, 0.02, 0.03, 0.05, 0.1, np.inf)  # fingertip to target (m)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--task", default="reacher_hard", choices=("reacher_easy", "reacher_hard"))
  parser.add_argument("--episodes", type=int, default=32)
  parser.add_argument("--settled", type=float, default=0.01, help="metres (default 0.01)")
  parser.add_argument("--offsets", default="0,0.01,0.02,0.03,0.05,0.1")
  parser.add_argument("--policy", action="append", default=[])
  parser.add_argument("--target_episodes", type=int, default=512,
                      help="episodes per policy for the failures by target position")
  parser.add_argument("--demonstrator", default=None,
                      help="the demonstrator to score with (default: the shipped one)")
  parser.add_argument("--results", default=None)
  args = parser.parse_args(argv)
  env = tasks.make(args.task)
  layout = list(env.observation_layout.items())
  start = {name: sum(size for _, size in layout[:i]) for i, (name, _) in enumerate(layout)}
  to_target = slice(start["to_target"], start["to_target"] + 2)
  velocity = slice(start["velocity"], start["velocity"] + 2)
  position = slice(start["position"], start["position"] + 2)
  path = args.demonstrator or tasks.bundled_demonstrator(args.task)
  file = effect_models.load_effect_model(path, task=args.task,
                                         observation_layout=env.observation_layout)
  config, demonstrator = pipeline.demonstrator_from_file(file, path)
  model = em.make_model(config, env.observation_size)
  score = jax.jit(lambda prev, nxt: em.transition_log_prob(
      model, demonstrator.params, demonstrator.normalizer, prev, nxt))
  writer = results.ResultWriter(args.results) if args.results else None
  common_fields = dict(task=args.task, method="form", demonstrator_sha256=file.metadata["sha256"])

  expert = experts.load_expert(tasks.bundled_expert(args.task), env)
  agents = [("expert", expert)] + [(p, experts.load_expert(p, env)) for p in args.policy]

  def transitions(obs):
    """obs [K, T+1, D] -> prev, nxt [K*T, D], fingertip distance and joint speed at nxt [K*T]."""
    prev, nxt = obs[:, :-1].reshape(-1, obs.shape[-1]), obs[:, 1:].reshape(-1, obs.shape[-1])
    return (prev, nxt, np.linalg.norm(nxt[:, to_target], axis=-1),
            np.linalg.norm(nxt[:, velocity], axis=-1))

  obs, returns, _, _ = rollout(env, expert, 0.0, jax.random.PRNGKey(0), args.episodes)
  prev, nxt, distance, speed = transitions(obs)
  settled = ((distance < args.settled) & (np.linalg.norm(prev[:, to_target], axis=-1)
             < args.settled) & (speed < SPEED_BINS[1]))
  print(f"{args.task}: expert return {returns.mean():.1f} over {args.episodes} episodes; "
        f"{settled.sum()} settled transitions ({settled.mean():.0%}); demonstrator {path}")
  if not settled.any():
    print(f"  no settled transitions within {args.settled} m: the target-moved probe is skipped")
  rng = np.random.default_rng(0)
  angle = rng.uniform(0, 2 * np.pi, settled.sum())
  direction = np.stack([np.cos(angle), np.sin(angle)], axis=-1)  # [S, 2]
  for d in (float(x) for x in args.offsets.split(",")) if settled.any() else ():
    p, n = move_target(prev[settled], nxt[settled], to_target, d * direction)
    log_d = np.asarray(score(jnp.asarray(p), jnp.asarray(n)))
    q = np.percentile(log_d, [10, 50, 90])
    print(f"  expert settled, target moved {d * 100:4.1f} cm: log pD mean {log_d.mean():8.2f}  "
          f"p10/p50/p90 {q[0]:8.2f} {q[1]:8.2f} {q[2]:8.2f}")
    if writer:
      writer.write(kind="reacher_settling", probe="expert_settled_target_moved", offset_m=d,
                   transitions=int(settled.sum()), log_pd_mean=float(log_d.mean()),
                   log_pd_percentiles={"p10": q[0], "p50": q[1], "p90": q[2]},
                   expert_return=float(returns.mean()), **common_fields)

  behaviours = [("expert", obs, returns)]
  for i, (name, agent) in enumerate(agents[1:]):
    p_obs, p_returns, _, _ = rollout(env, agent, 0.0, jax.random.PRNGKey(100 + i), args.episodes)
    behaviours.append((name, p_obs, p_returns))
  for name, b_obs, b_returns in behaviours:
    prev, nxt, distance, speed = transitions(b_obs)
    log_d = np.asarray(score(jnp.asarray(prev), jnp.asarray(nxt)))
    print(f"  {name}: return {b_returns.mean():.1f}; mean log pD by distance (cm) x joint speed "
          f"(rad/s), share of transitions in brackets")
    cells = []
    for lo, hi in zip(DISTANCE_BINS[:-1], DISTANCE_BINS[1:]):
      row = []
      for slo, shi in zip(SPEED_BINS[:-1], SPEED_BINS[1:]):
        m = (distance >= lo) & (distance < hi) & (speed >= slo) & (speed < shi)
        cell = {"distance_m": [lo, None if np.isinf(hi) else hi],
                "speed": [slo, None if np.isinf(shi) else shi], "share": float(m.mean()),
                "log_pd_mean": float(log_d[m].mean()) if m.any() else None}
        cells.append(cell)
        row.append("        -        " if not m.any()
                   else f"{cell['log_pd_mean']:8.2f} ({cell['share']:5.1%})")
      print(f"    {lo * 100:4.0f}-{hi * 100:4.0f} cm: " + "  ".join(row))
    if writer:
      writer.write(kind="reacher_settling", probe="visited_by_distance_and_speed",
                   behaviour=name, episodes=args.episodes, task_return=float(b_returns.mean()),
                   cells=cells, **common_fields)
  for name, agent in agents:
    target, returns, late_distance, late_speed, shoulder = targets_and_returns(
        env, agent, args.target_episodes)
    # The task draws target = radius * (sin a, cos a) (tasks/reacher.py): a = arctan2(x, y).
    radius, angle = np.linalg.norm(target, axis=-1), np.arctan2(target[:, 0], target[:, 1])
    failed = returns < 100.0
    edges, by_radius, by_angle = failure_shares(failed, radius, angle)
    print(f"  {name}: return {returns.mean():.1f} over {args.target_episodes} episodes, "
          f"{failed.mean():.1%} under 100; by target radius quartile (edges "
          + "/".join(f"{e * 100:.1f}" for e in edges) + " cm): "
          + " ".join("-" if r is None else f"{r:.1%}" for r in by_radius)
          + "; by target angle quadrant: "
          + " ".join("-" if r is None else f"{r:.1%}" for r in by_angle))
    medians = lambda m: {"distance_m": float(np.median(late_distance[m])) if m.any() else None,
                         "speed": float(np.median(late_speed[m])) if m.any() else None}
    late = {"failed": medians(failed), "over_800": medians(returns > 800)}
    print("    second half of the episodes (medians): "
          + "; ".join(f"{k}: {v['distance_m'] * 100:.1f} cm, {v['speed']:.2f} rad/s"
                      for k, v in late.items() if v["distance_m"] is not None))
    if writer:
      writer.write(kind="reacher_settling", probe="failures_by_target_position", behaviour=name,
                   episodes=args.target_episodes, task_return=float(returns.mean()),
                   share_under_100=float(failed.mean()), radius_quartile_edges_m=edges.tolist(),
                   share_under_100_by_radius_quartile=by_radius,
                   share_under_100_by_angle_quadrant=by_angle, second_half_medians=late,
                   **common_fields)
    paths = paths_by_quadrant(angle, returns, shoulder)
    print("    the shoulder's path by target quadrant (under 100 / raw angle leaves [-pi, pi] / "
          "median path, rad): " + "; ".join(
              "-" if q["episodes"] == 0 else f"{q['share_under_100']:.0%} / "
              f"{q['share_leaving_pi']:.0%} / {q['median_path_rad']:.1f}" for q in paths))
    if writer:
      writer.write(kind="reacher_settling", probe="paths_by_target_quadrant", behaviour=name,
                   episodes=args.target_episodes, task_return=float(returns.mean()),
                   quadrants=paths, **common_fields)
  same_starts = jax.random.PRNGKey(11)  # one key: the same resets (targets, arm) for all
  expert_run = scored_rollout(env, expert, score, same_starts, args.episodes)
  runs = {name: expert_run if name == "expert" else scored_rollout(env, agent, score,
                                                                   same_starts, args.episodes)
          for name, agent in agents}
  for name, run in runs.items():
    by_shoulder = log_pd_by_shoulder(run[0][..., position.start], run[2],
                                     np.linalg.norm(run[0][:, 1:, velocity], axis=-1))
    fmt = lambda g: "-" if g["log_pd"] is None else f"{g['log_pd']:.2f} ({g['transitions']})"
    at = f"{np.pi - by_shoulder['close_rad']:.2f} rad"
    edge = f"{by_shoulder['edge_rad']:g} rad"
    print(f"  {name}: log pD by the shoulder at x_t (8 bins over [-pi, pi)): "
          + " ".join("-" if x is None else f"{x:.1f}" for x in by_shoulder["log_pd_by_bin"])
          + f"; beyond {edge} {fmt(by_shoulder['near_pi'])}, elsewhere "
          + fmt(by_shoulder["elsewhere"]) + f"; crossing +-pi {fmt(by_shoulder['crossing_pi'])}, "
          f"not crossing within {at} of it {fmt(by_shoulder['at_pi'])}; moving (over {SPEED_BINS[2]:g} "
          f"rad/s): crossing {fmt(by_shoulder['crossing_pi_moving'])}, not crossing within "
          f"{at} {fmt(by_shoulder['at_pi_moving'])}, within {edge} of 0 "
          + fmt(by_shoulder["moving_elsewhere"]))
    if writer:
      writer.write(kind="reacher_settling", probe="log_pd_by_shoulder", behaviour=name,
                   episodes=args.episodes, task_return=float(run[1].mean()), **by_shoulder,
                   **common_fields)
  for name, _ in agents[1:]:
    probe = failed_episodes(runs[name], expert_run,
                            dict(position=position, to_target=to_target, velocity=velocity))
    print(f"  {name}: {probe['failed']} of {args.episodes} episodes under 100 (the expert's "
          "starts)")
    for group in ("failed", "over_800"):
      g = probe[group + "_episodes"]
      if g is None:
        continue
      print(f"    {group}: second half median {g['distance_m'] * 100:.1f} cm from the target at "
            f"{g['speed']:.2f} rad/s, joint angles' sd {g['angle_sd']:.3f} rad; within 5 cm at "
            f"some step: {g['reached_5cm']:.0%}; log pD of its second half "
            f"{g['log_pd_second_half']:.2f} (its whole episodes {g['log_pd']:.2f}), the expert's "
            f"on the same starts {g['expert_log_pd_second_half']:.2f}; the policy's scale there "
            f"{g['policy_scale']:.3f}, its mean outside [-1, 1] in {g['mean_out_of_bounds']:.0%}")
    near, elsewhere = (probe[f"failed_share_expert_final_shoulder_{k}"]
                       for k in ("near_pi", "elsewhere"))
    print("    under 100 by where the expert's shoulder ends on the same starts (8 bins over "
          "[-pi, pi)): " + " ".join("-" if x is None else f"{x:.0%}"
                                    for x in probe["failed_share_by_expert_final_shoulder"])
          + f"; beyond {probe['near_pi_edge_rad']:g} rad: "
          + ("-" if near is None else f"{near:.0%}")
          + ", elsewhere: " + ("-" if elsewhere is None else f"{elsewhere:.0%}"))
    endings = endings_by_angle(expert_run[0][..., position.start],
                               runs[name][0][..., position.start], runs[name][1] < 100.0)
    fmt = lambda x, f: "-" if x is None else format(x, f)
    print("    the shoulder by bin of the expert's end: expert passes +-pi / turns positive; "
          "the failed episodes' final angle (circular mean, sd): " + "; ".join(
              f"{fmt(g['expert_passes_pi'], '.0%')} / {fmt(g['expert_turns_positive'], '.0%')}"
              f", {g['failed']} at {fmt(g['failed_end_mean_rad'], '+.2f')} "
              f"({fmt(g['failed_end_circular_sd_rad'], '.2f')})"
              for g in endings["by_expert_final_shoulder"])
          + f"; all failed: {fmt(endings['failed_end_mean_rad'], '+.2f')} "
          f"({fmt(endings['failed_end_circular_sd_rad'], '.2f')})")
    if writer:
      writer.write(kind="reacher_settling", probe="failed_episodes", behaviour=name,
                   episodes=args.episodes, **probe, **common_fields)
      writer.write(kind="reacher_settling", probe="endings_by_angle", behaviour=name,
                   episodes=args.episodes, **endings, **common_fields)
  return 0


def scored_rollout(env, policy, score, key, episodes: int):
  """`policy`'s mean-action episodes from the resets of `key`: observations [K, T+1, D],
  returns [K], the demonstrator's log pD of every transition [K, T], and the policy's mean and
  scale at each x_t [K, T, A]."""
  obs, returns, means, scales = rollout(env, policy, 0.0, key, episodes)
  flat = lambda x: jnp.asarray(x.reshape(-1, x.shape[-1]))
  log_d = np.asarray(score(flat(obs[:, :-1]), flat(obs[:, 1:]))).reshape(episodes, -1)
  return obs, returns, log_d, np.swapaxes(means, 0, 1), np.swapaxes(scales, 0, 1)


def failed_episodes(run, expert_run, parts: dict) -> dict:
  """A policy's and the expert's `scored_rollout`s from the same starts, summarised by
  `episode_groups` and `failures_by_angle`."""
  (obs, returns, log_d, means, scales), (expert_obs, expert_returns, expert_log_d, _, _) = (
      run, expert_run)
  shoulder = expert_obs[:, -1, parts["position"].start]  # raw: may have turned past pi
  reached = expert_returns > 800.0  # starts where the expert's end is where the arm must be
  return {**episode_groups(obs, returns, log_d, expert_log_d, parts, means, scales),
          **failures_by_angle((returns < 100.0)[reached], shoulder[reached]),
          "starts_the_expert_missed": int((~reached).sum())}


def endings_by_angle(expert_shoulder, shoulder, failed, bins: int = 8) -> dict:
  """How the expert and a policy move the shoulder from the same starts: expert_shoulder and
  shoulder [K, T+1] (raw), failed [K] (the policy's episodes under 100). By bin of the expert's
  final wrapped angle (`wrapped_bins`; None where empty): episodes, the share where the expert
  passes +-pi (an odd multiple of pi) at some step and the share where its net turn is
  positive; the policy's failed episodes there and their final angles' circular mean and
  circular standard deviation sqrt(-2 ln R) (rad; 0: all end at one angle). The same for all
  failed episodes together: one angle with a small spread is a pose the policy parks in
  whatever the target."""
  expert_shoulder, shoulder = np.asarray(expert_shoulder), np.asarray(shoulder)
  failed = np.asarray(failed, bool)
  _, index = wrapped_bins(expert_shoulder[:, -1], bins)
  turn = turn_index(expert_shoulder)
  passes = np.any(turn[:, 1:] != turn[:, :-1], axis=1)
  positive = expert_shoulder[:, -1] > expert_shoulder[:, 0]
  end = shoulder[:, -1]

  def circular(m):
    if not m.any():
      return None, None
    z = np.exp(1j * end[m]).mean()
    return float(np.angle(z)), float(np.sqrt(-2 * np.log(np.clip(abs(z), 1e-12, 1.0))) + 0.0)

  share = lambda v, m: float(v[m].mean()) if m.any() else None
  by_bin = []
  for b in range(bins):
    m = index == b
    mean, sd = circular(m & failed)
    by_bin.append({"episodes": int(m.sum()), "expert_passes_pi": share(passes, m),
                   "expert_turns_positive": share(positive, m), "failed": int((m & failed).sum()),
                   "failed_end_mean_rad": mean, "failed_end_circular_sd_rad": sd})
  mean, sd = circular(failed)
  return {"by_expert_final_shoulder": by_bin, "failed": int(failed.sum()),
          "failed_end_mean_rad": mean, "failed_end_circular_sd_rad": sd}


def turn_index(raw):
  """Which turn each raw angle lies in (its count of 2 pi past [-pi, pi)): two angles of one
  episode in different turns have passed an odd multiple of pi between them."""
  return np.floor((np.asarray(raw) + np.pi) / (2 * np.pi))


def wrapped_bins(angle, bins: int):
  """Raw angles wrapped into [-pi, pi), and the index of each among `bins` equal bins there."""
  wrapped = (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi
  return wrapped, np.minimum(((wrapped + np.pi) / (2 * np.pi) * bins).astype(int), bins - 1)


def failures_by_angle(failed, angle, bins: int = 8, edge: float = 2.5) -> dict:
  """The share of `failed` [K] episodes by `angle` [K] (the expert's final shoulder angle on the
  same starts: where the arm has to end up), wrapped into [-pi, pi) and cut into `bins` equal
  bins (None where empty), and the share among episodes whose wrapped angle is beyond `edge`
  (rad: near +-pi, where the raw angle an actor sees jumps by 2 pi between two ways of turning
  there) against the others."""
  wrapped, index = wrapped_bins(angle, bins)
  share = lambda m: float(failed[m].mean()) if m.any() else None
  near = np.abs(wrapped) > edge
  return {"failed_share_by_expert_final_shoulder": [share(index == b) for b in range(bins)],
          "failed_share_expert_final_shoulder_near_pi": share(near),
          "failed_share_expert_final_shoulder_elsewhere": share(~near),
          "near_pi_edge_rad": edge}


def log_pd_by_shoulder(shoulder, log_d, speed, bins: int = 8, edge: float = 2.5,
                       close: float = 3.0) -> dict:
  """The mean log pD of transitions by the shoulder's raw angle at x_t: shoulder [K, T+1] (raw,
  may pass +-pi), log_d [K, T], speed [K, T] (joint speed at x_{t+1}, rad/s). Wrapped into
  [-pi, pi): by `bins` equal bins, beyond `edge` rad (near +-pi) against elsewhere, and the
  transitions that cross +-pi (the raw angle passes an odd multiple of pi, however fast)
  against the others whose x_t is beyond `close` rad, all of them and the moving ones (speed
  over SPEED_BINS[2]) (None: none)."""
  raw = np.asarray(shoulder)
  a, index = wrapped_bins(raw[:, :-1], bins)
  turn = turn_index(raw)
  log_d = np.asarray(log_d)
  mean = lambda m: float(log_d[m].mean()) if m.any() else None
  group = lambda m: {"log_pd": mean(m), "transitions": int(m.sum())}
  crossing = turn[:, 1:] != turn[:, :-1]
  moving = np.asarray(speed) > SPEED_BINS[2]
  at_pi = (np.abs(a) > close) & ~crossing
  return {"log_pd_by_bin": [mean(index == i) for i in range(bins)],
          "near_pi": group(np.abs(a) > edge), "elsewhere": group(np.abs(a) <= edge),
          "crossing_pi": group(crossing), "at_pi": group(at_pi),
          "crossing_pi_moving": group(crossing & moving), "at_pi_moving": group(at_pi & moving),
          "moving_elsewhere": group((np.abs(a) <= edge) & moving),
          "edge_rad": edge, "close_rad": close, "moving_speed": SPEED_BINS[2]}


def episode_groups(obs, returns, log_d, expert_log_d, parts: dict, means=None,
                   scales=None) -> dict:
  """For the failed (return under 100) and successful (over 800) episodes of obs [K, T+1, D]
  and returns [K]: the medians over episodes of the second half's median fingertip distance (m)
  and joint speed (rad/s) and of the joint angles' standard deviation there (rad: ~0 still,
  > 0 shaking or moving), the share that came within 5 cm at some step, and the mean log pD
  (log_d [K, T]) over their second halves and whole episodes, beside the expert's
  (expert_log_d [K, T], from the same starts) over its second halves; with the policy's `means`
  and `scales` at each x_t [K, T, A], also the median over episodes of the second half's median
  scale (mean over action dimensions: a policy unsure there is wide) and the share of its means
  outside [-1, 1] there. None for an empty group."""
  half = log_d.shape[1] // 2
  distance = np.linalg.norm(obs[:, 1:, parts["to_target"]], axis=-1)  # [K, T]
  speed = np.linalg.norm(obs[:, 1:, parts["velocity"]], axis=-1)
  angle_sd = np.linalg.norm(obs[:, 1 + half:, parts["position"]].std(axis=1), axis=-1)  # [K]

  def group(m):
    if not m.any():
      return None
    return {"episodes": int(m.sum()),
            "distance_m": float(np.median(np.median(distance[m, half:], axis=1))),
            "speed": float(np.median(np.median(speed[m, half:], axis=1))),
            "angle_sd": float(np.median(angle_sd[m])),
            "reached_5cm": float((distance[m] < 0.05).any(axis=1).mean()),
            "log_pd": float(log_d[m].mean()),
            "log_pd_second_half": float(log_d[m, half:].mean()),
            "expert_log_pd_second_half": float(expert_log_d[m, half:].mean()),
            **({} if scales is None else {
                "policy_scale": float(np.median(np.median(scales[m, half:].mean(axis=-1),
                                                          axis=1))),
                "mean_out_of_bounds": float((np.abs(means[m, half:]) > 1.0).mean())})}

  return {"failed": int((returns < 100.0).sum()), "task_return": float(returns.mean()),
          "failed_episodes": group(returns < 100.0), "over_800_episodes": group(returns > 800.0)}


def move_target(prev, nxt, to_target: slice, shift):
  """Copies of the transitions' observations prev, nxt [S, D] with the target moved by shift
  [S, 2] (metres): the finger-to-target vector grows by shift in both, nothing else changes."""
  prev, nxt = prev.copy(), nxt.copy()
  prev[:, to_target] += shift
  nxt[:, to_target] += shift
  return prev, nxt


def failure_shares(failed, radius, angle):
  """The quartile edges of radius [K], the share of `failed` [K] episodes in each radius
  quartile (each episode in one: bins closed on the right) and in each quadrant of angle (in
  [-pi, pi]); None for an empty bin."""
  edges = np.quantile(radius, [0, 0.25, 0.5, 0.75, 1])
  quartile = np.digitize(radius, edges[1:-1], right=True)  # 0..3
  quadrant = common.angle_quadrant(angle)

  def shares(bins):
    return [float(failed[bins == b].mean()) if (bins == b).any() else None for b in range(4)]

  return edges, shares(quartile), shares(quadrant)


def paths_by_quadrant(angle, returns, shoulder) -> list[dict]:
  """Per quadrant of the target angle [K] (in [-pi, pi], as `failure_shares`): its episodes,
  their share under 100 (returns [K]), the share whose raw shoulder angle (after every step,
  [T, K]) leaves [-pi, pi] (it crossed the seam of the range it starts in), and the median
  length of the shoulder's path, sum |theta_{t+1} - theta_t| (rad; a spinning arm's grows with
  every turn)."""
  quadrant = common.angle_quadrant(angle)
  leaves = (np.abs(shoulder) > np.pi).any(axis=0)
  path = np.abs(np.diff(shoulder, axis=0)).sum(axis=0)
  out = []
  for q in range(4):
    m = quadrant == q
    out.append({"episodes": int(m.sum()),
                **({"share_under_100": float((returns[m] < 100.0).mean()),
                    "share_leaving_pi": float(leaves[m].mean()),
                    "median_path_rad": float(np.median(path[m]))} if m.any() else {})})
  return out


def targets_and_returns(env, agent, episodes: int, seed: int = 7):
  """The target positions [K, 2], returns [K], median fingertip distance (m) and joint speed
  (rad/s) over the second half [K], and the raw shoulder angle after every step [T, K] of
  `episodes` episodes of `agent`'s mean action."""
  probe = lambda nxt: (nxt.task["target"], nxt.reward,
                       jnp.linalg.norm(nxt.obs_parts["to_target"], axis=-1),
                       jnp.linalg.norm(nxt.obs_parts["velocity"], axis=-1),
                       nxt.obs_parts["position"][..., 0])
  target, rewards, distance, speed, shoulder = common.mean_action_rollout(
      env, agent, jax.random.PRNGKey(seed), episodes, probe)
  half = env_lib.EPISODE_LENGTH // 2  # the second half of each episode: where it ended up
  return tuple(np.asarray(x) for x in (  # (an episode's target stays where its reset put it)
      target[0], rewards.sum(0), jnp.median(distance[half:], axis=0),
      jnp.median(speed[half:], axis=0), shoulder))


if __name__ == "__main__":
  sys.exit(main())
