"""FORM's per-task settings, in one place: the effect models' regularisers, and the reward
scale, actor and learner of an imitation run.

The paper tunes two regularisers per task and shares them between the demonstrator and the
imitator model: the autoregressive weight beta_ar and the L2 weight, each over the grid
{0.01, 0.1, 1} (its appendix; humanoid_run and quadruped_run did best with beta_ar 1 and
L2 0.1 there). Everything else is the paper's and the same for every task
(`EffectModelConfig`), except that a task may have turn-invariant effect models
(`turn_invariant`: blind to full turns of its raw unbounded angles; not in the paper). A task
not listed uses DEFAULT. Each entry says which measurement chose it (benchmarks/results/); an
entry without one is not tuned yet.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

if TYPE_CHECKING:
  from mjx_form.imitation.effect_model import EffectModelConfig

GRID = (0.01, 0.1, 1.0)  # the paper's search space for beta_ar and l2

# Untuned tasks: the paper's best pair on its two ablated tasks.
DEFAULT = {"beta_ar": 1.0, "l2": 0.1}

PER_TASK: dict[str, dict[str, float | bool]] = {
    # cheetah_run, measured 2026-11-23 (benchmarks/NOTES.md, sessions 14-15): of the grid
    # {0.01, 0.1} x {0.1, 1}, the L2-1 models give the stalled imitators' behaviour a log pD
    # well above random actions' (the L2-0.1 ones: the same as random), and FORM with the
    # (0.01, 1) demonstrator evaluated 265 (3 seeds) at 15.4M steps against 114 with (1, 0.1)
    # (2 seeds), 242-353 by 35M; with the reward clipped (DEFAULT_RUN below) it imitates.
    "cheetah_run": {"beta_ar": 0.01, "l2": 1.0},
    # reacher_hard, turn-invariant (the shoulder's raw angle, effect_model.py), measured
    # 2026-11-25/26 (benchmarks/NOTES.md, sessions 28-29). The demonstrator's held-out
    # log-likelihood at offset 1: 18.51 against the plain model's 15.06 (the same expert's 1000
    # demonstrations, 64 x 100 batches, H200s; higher at every offset; on the CPU at 16 x 50:
    # 14.28 against 13.22). FORM with it (every other default; seeds 0-1 x wrap_angles 0-1 in
    # one population, 67.4M steps, one H200): fresh finals 591.9 / 817.2 (no wrap) and 680.9 /
    # 785.1 (wrapped), best policies 800.2 / 843.1 and 786.9 / 887.4, over 1024 episodes each;
    # with the plain demonstrator (seeds 0-2, 64.4M, 2026-11-25): finals 576.1 / 553.6 / 666.3,
    # best 663.6 / 680.3 / 767.8. Seed for seed the turn-invariant runs are ahead.
    # Predicting the shoulder's change instead (`angle_increments`, session 42: seeds 0-5, own
    # demonstrators, 50M steps) is worse: 660.1 against 822.8 with values, so it stays off.
    "reacher_hard": {"turn_invariant": True},
}


def effect_model_settings(task: str) -> dict:
  """`task`'s tuned effect-model settings: beta_ar and l2 (its PER_TASK entry, else DEFAULT),
  and turn_invariant where its entry says so."""
  return {**DEFAULT, **PER_TASK.get(task, {})}


def turn_period(env, turn_invariant: bool | None) -> tuple[float, ...] | None:
  """The effect models' `period` that --turn_invariant / --no-turn_invariant ask for: the task
  `env`'s observation periods (raw unbounded angles), () for none, None where neither was
  given (the task's setting then applies: `effect_model_config`). ValueError for a task that
  observes no unbounded angle."""
  if turn_invariant is None:
    return None
  if not turn_invariant:
    return ()
  if not env.periodic_observations:
    raise ValueError(f"--turn_invariant: {env.name} observes no unbounded angle (nothing to "
                     "turn)")
  return tuple(float(p) for p in env.observation_period())


def effect_model_config(task: str, env=None, **overrides) -> EffectModelConfig:
  """The effect-model settings of `task`, with `overrides` (e.g. beta_ar=0.1, period=()) that
  are not None applied; `env`: the task, built, where the caller has it (a turn-invariant
  task's periods are read off it; else it is built here)."""
  # Imported here: the constants of this module load without JAX (scripts/report.py).
  from mjx_form.imitation.effect_model import EffectModelConfig
  chosen = effect_model_settings(task)
  if chosen.pop("turn_invariant", False) and overrides.get("period") is None:
    if env is None:
      import tasks
      env = tasks.make(task)
    chosen["period"] = turn_period(env, True)
  chosen.update({k: v for k, v in overrides.items() if v is not None})
  config = dataclasses.replace(EffectModelConfig(), **chosen)
  config.check()
  return config


# The imitation run's learner and reward settings. The paper's: raw reward log pD - log pI,
# targets copied every 200 updates (`--preset paper`). The default, measured on the GPU
# (benchmarks/NOTES.md, the FORM sections of 2026-11-23): the FORM reward standardised by its
# running mean and sd (form.py) and targets copied every 25 updates. walker_walk, raw and 200:
# 101 at 7.7M steps; standardised and 25: 486 at 5.9M, then 3 seeds with best policies of
# 918.7 / 942.7 / 940.6 at 13.4M (the demonstrations: 878.8); walker_stand at 2M steps: 274
# against 91; cheetah_run fails either way unclipped (~110 against ~70).
# `reward_clip` (bounding the reward's tail at c running sd, form.py) is 3 for every task: it
# decides cheetah_run and changes nothing measurable where the reward has no tail. Measured on
# GPUs (benchmarks/NOTES.md, sessions 18-19), fresh final returns unless said otherwise:
#   cheetah_run (tumbles: the unclipped reward's running sd ~100 against ~6 clipped): seed 0 with
#     c = 0 / 3 / 10 in one population 231.7 / 823.6 / 292.2 at 19.0M steps; c = 3 over 7 runs
#     (seeds 0-2) 631.6-836.5, mean 772.6; c = 2 beside c = 3 (seeds 0-2, one population): 802.6 /
#     818.5 / 745.1 against 631.6 / 778.6 / 810.7, no difference at 3 seeds (medians over training:
#     2 clips 7-9% of transitions, 3 clips 2-3%; 2 also biases the running sd low, form.py);
#   walker_walk seed 2 (unclipped in session 13: best evaluation 942, fresh final 536.3 at 13.4M)
#     with c = 0 / 3 in one population: 915.4 / 936.9 at 11.8M steps (3 clipped a median 0.8%;
#     both curves dipped on the way, the clipped one from 928 at 7.2M to 533 at 9.2M);
#   reacher_hard seed 0 (no tail: running sd median 5.8 either way): c = 3 evaluated 547 at 20.5M
#     steps, where unclipped seeds evaluated 564 and 393 (periodic evaluations; fresh final with
#     c = 3: 541.7 at 20.6M).
# reacher_easy and walker_stand were measured unclipped only (their running sd medians 4-14).
# `sampled_q_bfloat16` (the target critic's Q of the sampled actions in bfloat16, learner.py) is
# on by default: one update 1.27 ms against 1.71 (cheetah_run, H100), a population of 8 at 3.20x
# one run's env steps/s against 2.66x, and learning unchanged where measured (session 20):
#   cheetah_run expert, seeds 0-2, 12.8M steps, one population each: fresh final returns 732.3 /
#     786.7 / 753.9 (mean 757.7) against float32's 735.9 / 728.8 / 779.6 (748.1);
#   cheetah_run FORM with every default here, seeds 0-2 to 41.0M steps on an H200: 840.5 / 836.9
#     / 873.4 (mean 850.3, 0.95 of the demonstrations), cheetah_run's best FORM result so far.
# The paper's learner computes in float32 (`--preset paper`).
# `policy_average_decay` (mjx_form/rl/learner.py: the policy's parameters averaged over updates,
# evaluated beside the online policy; no update changes) is kept by default at 0.9995 (~2000
# updates): FORM's imitators swing from evaluation to evaluation, their average much less.
# Measured on H200s (session 51, one value of the decay), over each run's evaluations of the
# second half of training, the same starts for both policies:
#   reacher_hard, shipped demonstrator, seeds 0-2 x epsilon_scale 1e-5 / 1e-6, 52.8M steps: the
#     average policy +54.5 (higher in 116 of 162 evaluations, every run's mean higher), the
#     median change between neighbouring evaluations 15-53 against 61-114; fresh finals over
#     256 episodes: 865.5 against the final policy's 866.8 (higher in 2 of 6);
#   reacher_easy, a three-draw mixture, seeds 0-5, 50.4M: +32.6 (122 of 156, every run), fresh
#     finals 948.0 against 929.5 (higher in 4 of 6).
# The final policy stays the headline, as the paper's; the average is the tables' own column.
PAPER_RUN = {"standardise_reward": False, "reward_clip": 0.0, "target_update_period": 200,
             "sampled_q_bfloat16": False, "policy_average_decay": 0.0}
DEFAULT_RUN = {"standardise_reward": True, "reward_clip": 3.0, "target_update_period": 25,
               "sampled_q_bfloat16": True, "policy_average_decay": 0.9995}
# A task's measured departures from DEFAULT_RUN. Besides DEFAULT_RUN's keys an entry may set the
# actor (ACTOR_KEYS; the paper's head, independent noise and raw angles otherwise) and more of
# the learner (LEARNER_KEYS; the paper's otherwise: the critic sees tanh of the sampled action,
# MPO's scale bound 1e-5).
ACTOR_KEYS = ("policy_head", "action_noise_correlation", "wrap_angles", "angle_features")
LEARNER_KEYS = ("clip_critic_actions", "epsilon_scale")
# The learner of the expert recipes for walker_run and quadruped_run (mjx_form/rl/recipes.py):
# the critic clips actions, MPO's scale bound at Acme's 1e-6. Measured with 512 envs x 512
# updates per iteration (replay ratio 64; the scale stays on the command line: `--num_envs 512
# --updates_per_iteration 512`), seeds 0-2 as one population on one H200, fresh finals over 256
# episodes, against the FORM rows before it (the defaults above at 512 x 128: not a same-scale
# A/B, the learner's settings and 4x the updates per env step change together):
#   walker_walk (benchmarks/NOTES.md, session 56; 2026-11-29_learning_curve_h200_walker_walk_
#     form_recipe_seeds012_5m): 969.1 / 958.3 / 970.5 (mean 966.0, 1.00 of the demonstrations'
#     963.7; the paper's FORM / expert 0.995) at 5.2M steps, every seed's first evaluation >= 0.95
#     of the demonstrations at 1.5M steps (6.9 min); the defaults at 128 updates: 945.5 +- 22.9
#     at 14.4M, first >= 0.95 at 4.1-7.2M steps (7.2-11.7 min; 2026-11-28_..._form_seeds012_14m);
#   quadruped_run (`--physics fast_ls4`, its expert's; session 55, 2026-11-29_learning_curve_
#     h200_quadruped_run_form_recipe_seeds012_4m): 926.7 / 932.7 / 936.5 (mean 932.0, 0.99 of the
#     demonstrations' 941.5; the paper's 0.985) at 4.1M steps; no FORM run of it before;
#   quadruped_walk (`--physics fast_ls4`; session 68, 2026-12-01_learning_curve_h200_quadruped_
#     walk_form_recipe_seeds012_10m): 919.9 / 919.9 / 890.3 (mean 910.0, 0.97 of the
#     demonstrations' 934.9; the paper's 0.991) at 10.0M steps, cut by the sitting; the critic
#     clipping alone at 128 updates: 857.8 +- 24.8 at 13.7M (0.92; 2026-11-26_..._quadruped_walk_
#     form_fast_ls4_clip_seeds012). Both with the demonstrator then shipped, since archived: it
#     learned demonstrations recorded with the lift clipped at 1 (pipeline.MISFIT_NATS). With
#     the one shipped now, trained in the run on 1000 episodes in the control range (session
#     69, 2026-12-01_..._quadruped_walk_form_recipe_own_demonstrator_seeds012_7m): 901.6 /
#     917.3 / 886.6 at 7.5M steps (mean 901.8, 0.97 of its demonstrations' 932.3), average
#     policies 925.2 / 917.5 / 932.8 (0.99).
RECIPE_LEARNER = {"clip_critic_actions": True, "epsilon_scale": 1e-6}
PER_TASK_RUN: dict[str, dict] = {
    "walker_walk": dict(RECIPE_LEARNER),
    "quadruped_run": dict(RECIPE_LEARNER),
    "quadruped_walk": dict(RECIPE_LEARNER),
    # hopper_stand: the actor of its expert recipe (mjx_form/rl/recipes.py: without the acme head
    # and noise correlated at 0.9 the expert runs never rose; wrapped angles fixed its falls from
    # starts past pi), not A/B'd under FORM. T 100 against 25, measured on one H100 (512 envs x
    # 128 updates, seeds 0-1 x T in one population, 17.5M steps; benchmarks/NOTES.md session 35,
    # 2026-11-26_learning_curve_h100_hopper_stand_form_acme_noise09_wrap_t25_t100_seeds01):
    # fresh finals over 256 episodes 860.3 / 834.1 at T 100 against 646.2 / 602.3 at T 25 (0.92
    # of the demonstrations' 921.1 against 0.68), as the expert runs declined at T 25.
    "hopper_stand": {"target_update_period": 100, "policy_head": "acme",
                     "action_noise_correlation": 0.9, "wrap_angles": True},
    # reacher: the agent sees the shoulder as its cos and sin (`angle_features`). Raw, its
    # imitators failed about twice as often where the arm must end with the shoulder near +-pi
    # (benchmarks/reacher_settling.py, session 40). Measured on H100s, each task one population
    # of seeds 0-2 x angle_features 0/1 with the shipped pair (benchmarks/NOTES.md, session 41),
    # fresh finals over 256 episodes, raw -> cos and sin, seed for seed (the raw members' networks
    # had the two extra inputs, always 0: mjx_form/rl/grid.py):
    #   reacher_hard (58.9M steps): 482.5 / 288.4 / 573.7 (mean 448.2) -> 714.7 / 656.5 / 787.9
    #     (719.7); best policies 748.9 -> 782.9; with an L2-1 demonstrator (49.9M): 228.0 ->
    #     595.4, every seed higher;
    #   reacher_easy (58.1M): 816.3 / 947.3 / 856.5 (873.3) -> 923.7 / 890.1 / 887.1 (900.3);
    #     best policies 936.3 -> 962.3, every seed higher.
    "reacher_hard": {"angle_features": True},
    "reacher_easy": {"angle_features": True},
}
PRESETS = ("default", "paper")


def run_settings(task: str, preset: str = "default") -> dict:
  """`standardise_reward`, `reward_clip`, `target_update_period`, `sampled_q_bfloat16` and
  `policy_average_decay` of a FORM run of `task`, and the actor and learner settings its
  PER_TASK_RUN entry sets."""
  if preset not in PRESETS:
    raise ValueError(f"unknown preset {preset!r} (valid: {', '.join(PRESETS)})")
  if preset == "paper":
    return dict(PAPER_RUN)
  return {**DEFAULT_RUN, **PER_TASK_RUN.get(task, {})}
