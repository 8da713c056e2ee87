#!/usr/bin/env python3
"""mjx-form's command line.

  --method form (default): imitation from observations with FORM. The expert (shipped, or
      --expert) is recorded on the device, the demonstrator effect model comes from
      tasks/demonstrators/ (or --demonstrator, or is trained on the demonstrations), and MPO
      (Retrace) learns from the FORM reward only, in one compiled loop. Writes progress.csv,
      checkpoints, demonstrator.npz, policy.npz, best_policy.npz (by the task return),
      best_log_pd_policy.npz (by the demonstrator's log pD, no task reward), average_policy.npz
      (the policy averaged over updates, --policy_average_decay) with its best by log pD
      (best_log_pd_average_policy.npz) and imitator.npz (the imitator model beside policy.npz)
      to --run_dir.
  --method gaifo, gaifo_gp, vaifo, vaifo_gp: the paper's GAIfO baselines, imitation from
      observations with a discriminator of the expert's observations (_gp: with its gradient
      penalty, --gradient_penalty; vaifo: with a variational bottleneck, --kl_bound), on FORM's
      learner settings, from the same demonstrations (mjx_form/imitation/gaifo.py).
  --method bc: behavioural cloning, the policy fitted to the expert's actions on the same
      demonstrations (mjx_form/imitation/bc.py; it reads actions, so it is no imitation from
      observations: the paper's calibration of the tasks).
  --method bco: behavioural cloning from observation: the policy fitted to the demonstrations
      with the actions an inverse model, trained online on the imitator's own transitions,
      infers for them (mjx_form/imitation/bco.py). BC and BCO take the paper's policy head and
      actors, and refuse MPO's options (no critic).
  --method expert: the same learner on the task reward (to train experts).
  --method random: uniform random actions in N auto-resetting environments of one task,
      sharded over all devices; reports control steps per second (compile time apart).

  python scripts/run.py --task humanoid_run --num_envs 2048
  python scripts/run.py --task walker_walk --method form --num_envs 2048 --env_steps 20000000
  python scripts/run.py --task cheetah_run --method expert --num_envs 512 --env_steps 40000000
  python scripts/run.py --list
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjx_form.cpu import configure_cpu_xla, one_device_per_core  # noqa: E402  (before JAX starts)

configure_cpu_xla()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import tasks  # noqa: E402
from mjx_form import mesh as mesh_lib  # noqa: E402
from mjx_form.files import checkpoint, experts  # noqa: E402
from mjx_form.files import demos as demos_lib  # noqa: E402
from mjx_form.imitation import bc as bc_lib  # noqa: E402
from mjx_form.imitation import bco as bco_lib  # noqa: E402
from mjx_form.imitation import demonstrator as demonstrator_lib  # noqa: E402
from mjx_form.imitation import discriminator as discriminator_lib  # noqa: E402
from mjx_form.imitation import form as form_lib  # noqa: E402
from mjx_form.imitation import gaifo as gaifo_lib  # noqa: E402
from mjx_form.imitation import inverse_model as inverse_model_lib  # noqa: E402
from mjx_form.imitation import pipeline, settings  # noqa: E402
from mjx_form.rl import cloning, grid, recipes, runner  # noqa: E402
from mjx_form.rl.learner import LearnerConfig  # noqa: E402
from mjx_form.rl.networks import POLICY_HEADS  # noqa: E402
from mjx_form.rl.train import TrainConfig  # noqa: E402
from mjx_form.sim.physics import DEFAULT_PHYSICS, PHYSICS_MODES  # noqa: E402
from mjx_form.sim.wrappers import AutoReset  # noqa: E402


METHODS = ("form", "gaifo", "gaifo_gp", "vaifo", "vaifo_gp", "bco", "bc", "expert", "random")
GAIFO = ("gaifo", "gaifo_gp", "vaifo", "vaifo_gp")  # a discriminator's reward
IMITATION = ("form", *GAIFO, "bco")  # learn from demonstrations' observations alone
FROM_DEMOS = (*IMITATION, "bc")  # learn from demonstrations
LEARNERS = ("expert", *FROM_DEMOS)  # every method that trains a policy
CLONING = ("bco", "bc")  # fit the policy to actions (cloning.py): no reward, no critic, no MPO
GAIFO_GP_DEFAULT = 10.0  # beta_gp: the paper's "typically 10"
KL_BOUND_DEFAULT = 1.0  # VAIfO's epsilon: the paper's throughout
# Options that only the methods that learn from demonstrations read (a user who gives one to
# another method is told so; --reward_scale not BC's or BCO's: no reward), those that only
# --method form reads, and those that only GAIfO's read.
DEMO_OPTIONS = ("expert", "demos", "demo_episodes", "save_demos")
FORM_ONLY = ("demonstrator", "member_demonstrators", "train_demonstrator", "demonstrator_seed",
             "beta_ar", "effect_l2", "turn_invariant", "angle_increments", "angle_inputs",
             "effect_max_scale", "reward_clip", "ensemble_log_pd", "imitator_every")
GAIFO_ONLY = ("gradient_penalty", "discriminator_frames", "kl_bound")
CLONING_ONLY = ("cloning_loss",)
# The learner's options that only MPO reads (BC and BCO fit the policy alone: cloning.py uses
# the learning rate and gradient clip), and --preset (they take the paper's settings).
MPO_ONLY = ("num_action_samples", "target_update_period", "action_penalty", "clip_critic_actions",
            "epsilon_scale", "sampled_q_bfloat16", "sampled_q_float32_head", "clip_mean_targets",
            "preset")

# The environment variable that gives --stop_file its default (scripts/gpu_jobs.py sets it).
STOP_FILE_VARIABLE = "MJX_FORM_STOP_FILE"

DEFAULT_COMPILATION_CACHE = os.path.join(
    os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "mjx_form", "jax")


def use_compilation_cache(directory: str) -> None:
  """Points JAX's persistent compilation cache at `directory` ('' turns it off), unless a
  cache directory is already configured (JAX_COMPILATION_CACHE_DIR, or by the caller)."""
  if not directory:
    jax.config.update("jax_enable_compilation_cache", False)
  elif not jax.config.jax_compilation_cache_dir:
    jax.config.update("jax_compilation_cache_dir", directory)


def _seeds(text: str) -> tuple[int, ...]:
  try:
    seeds = tuple(int(s) for s in text.split(","))
  except ValueError:
    raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
  if len(set(seeds)) != len(seeds):
    raise argparse.ArgumentTypeError(f"seeds must be distinct, got {text!r}")
  return seeds


def _grid(parser, items: list[str], method: str) -> dict[str, tuple]:
  """--grid NAME=V1,V2 ... as {name: values}, refusing unknown names, bad or repeated values."""
  out = {}
  for item in items:
    name, sep, values = item.partition("=")
    if not sep or not values:
      parser.error(f"--grid expects NAME=V1,V2,..., got {item!r}")
    if name in out:
      parser.error(f"--grid {name} given twice")
    try:
      parsed = tuple(grid.parse_value(name, v) for v in values.split(","))
    except ValueError as e:
      parser.error(str(e))
    if len(set(parsed)) != len(parsed):
      parser.error(f"--grid {name}: repeated values in {values!r}")
    if name in grid.SOURCE and method != "form":
      parser.error(f"--grid {name} applies to --method form only")
    out[name] = parsed
  return out


def parse_args(argv=None) -> argparse.Namespace:
  parser = argparse.ArgumentParser(
      description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
      epilog="tasks: " + ", ".join(tasks.TASKS))
  parser.add_argument("--task", default="cheetah_run", help="task name (see --list)")
  parser.add_argument("--num_envs", type=int, default=16, help="parallel environments")
  parser.add_argument("--steps", type=int, default=200, help="control steps per environment")
  parser.add_argument("--log_every", type=int, default=None,
                      help="progress lines every N steps (random, default 50) or N iterations "
                           "(expert, default 1)")
  parser.add_argument("--physics", default=DEFAULT_PHYSICS, choices=PHYSICS_MODES,
                      help="parity: dm_control's solver settings; fast: fewer iterations; fast_bounded: "
                           "fast with the solver's loop as a fixed-length scan (same states); "
                           "fast_ls4: fast with the line search capped at 4 passes (same "
                           "one-step error, 1.3-1.5x faster physics)")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--seeds", type=_seeds, default=None,
                      help="comma-separated seeds: a population of runs, one per seed, in one "
                           "compiled program (every method but random; each writes to "
                           "<run_dir>/seed<s>/); overrides --seed for the learners (--method "
                           "form records demonstrations and trains a demonstrator with "
                           "--demonstrator_seed, default --seed)")
  parser.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2,...",
                      help="members with their own values of a setting (repeatable): the "
                           "population is every combination of the seeds and the values, each "
                           "member in <run_dir>/seed<s>_<name><value>/; the values replace "
                           "--NAME. Settings that may differ: " + ", ".join(grid.NAMES)
                           + " (standardise_reward: 0/1, reward_clip, ensemble_log_pd: --method form)")
  parser.add_argument("--list", action="store_true", help="print the task names and exit")
  parser.add_argument("--method", default="form", choices=METHODS,
                      help="form: imitation from observations (default); gaifo, gaifo_gp, "
                           "vaifo, vaifo_gp: the GAIfO baselines; bco: behavioural cloning from "
                           "observation; bc: of the expert's actions; expert: MPO on the task "
                           "reward; random: a random-action throughput demo")
  parser.add_argument("--compilation_cache", default=DEFAULT_COMPILATION_CACHE,
                      help="directory of JAX's persistent compilation cache: a later run of "
                           "the same settings loads its programs instead of compiling them "
                           "(cheetah_run expert on an H200: start-up 28 s instead of 74 s); "
                           "'' turns it off; JAX_COMPILATION_CACHE_DIR, where set, wins")
  train = parser.add_argument_group("training (every method but random; the learner's "
                                    "defaults: see --preset)")
  defaults = TrainConfig()
  train.add_argument("--run_dir", help="where logs, checkpoints and policy.npz go "
                     "(default runs/<task>_<method>_seed<seed>)")
  train.add_argument("--resume", action="store_true", help="continue the run in --run_dir")
  train.add_argument("--env_steps", type=int, default=1_000_000, help="total environment steps")
  train.add_argument("--unroll_length", type=int, default=defaults.unroll_length)
  train.add_argument("--batch_size", type=int, default=defaults.batch_size,
                     help="unrolls per learner update")
  train.add_argument("--replay_capacity", type=int, default=defaults.replay_capacity,
                     help="unrolls")
  train.add_argument("--updates_per_iteration", type=int,
                     default=defaults.updates_per_iteration,
                     help="learner updates per iteration (num_envs x unroll_length env steps)")
  train.add_argument("--network_width", type=int, default=defaults.network_width,
                     help="width of every network: policy, critic and effect models")
  train.add_argument("--policy_head", default=None,
                     choices=list(POLICY_HEADS),
                     help="the policy's Gaussian: paper (mean unbounded, scale softplus + "
                          "1e-4; the default, but see --preset for expert) or acme (Acme's "
                          "control-suite MPO head: tanh mean, scale >= 0.3)")
  train.add_argument("--noise_scale_min", type=float, default=1.0, metavar="K",
                     help="each member's environments act with the policy's noise scaled by "
                          "multipliers spread evenly from K (its first env) to 1 (its last): "
                          "K 0 gives one env the mean action, so that where the mean action "
                          "leads reaches the replay (default 1: every env acts with the "
                          "policy itself, the paper's)")
  train.add_argument("--action_noise_correlation", type=float,
                     default=None, metavar="C",
                     help="the actors' noise correlated in time: e_t = C e_(t-1) + sqrt(1 - C^2) "
                          "xi_t, action = mean + scale e_t (default 0: independent draws each "
                          "step, the paper's, but see --preset for expert; each action's "
                          "marginal is the policy either way)")
  train.add_argument("--num_action_samples", type=int,
                     default=defaults.learner.num_action_samples)
  train.add_argument("--target_update_period", type=int, default=None,
                     help="learner updates between copies of the online networks to the "
                          "targets (default: see --preset; the paper's is "
                          f"{defaults.learner.target_update_period})")
  train.add_argument("--action_penalty", action=argparse.BooleanOptionalAction, default=None,
                     help="MPO's penalty on sampled actions outside [-1, 1] (multi-objective "
                          "MPO, epsilon 1e-3; on by default in Acme, not stated in the paper): "
                          "keeps the policy's mean from drifting out of the action bounds "
                          "(default: on in an expert recipe that says so, reacher_hard's, "
                          "else off)")
  train.add_argument("--clip_critic_actions", action=argparse.BooleanOptionalAction,
                     default=None,
                     help="the critic sees clip(a, -1, 1), the action the environment applies "
                          "where its control range is [-1, 1] (every task but quadruped's) "
                          "(Acme's control-suite MPO), or tanh of the unclipped sample, as the "
                          "paper (default: see --preset)")
  train.add_argument("--clip_mean_targets", action=argparse.BooleanOptionalAction,
                     default=False,
                     help="MPO's M-step fits the policy's mean to the sampled actions clipped "
                          "to [-1 - s, 1 + s], s the target policy's scale (the scale still to "
                          "the raw samples): a mean beyond a bound, where every sample clips "
                          "alike and the weights cannot tell them apart, returns to within a "
                          "scale of it (default off, the paper's M-step; [-1, 1] on every "
                          "task, as the critic's clip: quadruped's lift actuators go to 1.1, "
                          "its extenders to 0.8)")
  train.add_argument("--epsilon_scale", type=float, default=None, metavar="E",
                     help="MPO's bound on the KL of the policy scale's change per update and "
                          "action dimension (default: see --preset; the paper's "
                          f"{defaults.learner.mpo.epsilon_scale:g}, Acme's 1e-6): smaller "
                          "slows the scale's change, its collapse too")
  train.add_argument("--policy_average_decay", type=float, default=None, metavar="D",
                     help="also keep the policy's parameters averaged over updates (the plain "
                          "mean until update 1/(1-D), then an exponential average with decay "
                          "D; e.g. 0.999), evaluated beside the online policy at each "
                          "evaluation and at the end, and exported as average_policy.npz; "
                          "acting and learning are unchanged (default: FORM 0.9995, "
                          "mjx_form/imitation/settings.py, measured; experts and --preset "
                          "paper 0, none)")
  train.add_argument("--sampled_q_bfloat16", action=argparse.BooleanOptionalAction,
                     default=None,
                     help="the target critic's Q of the sampled actions in bfloat16 (half of an "
                          "update's time on a GPU is that Q; learning measured unchanged) or "
                          "float32, the paper's (default: see --preset)")
  train.add_argument("--sampled_q_float32_head", action=argparse.BooleanOptionalAction,
                     default=False,
                     help="with --sampled_q_bfloat16: the critic's last layer in float32, so "
                          "that Q is not rounded to bfloat16 (spacing 0.5 at Q in [64, 128), "
                          "more than Q's spread over a state's sampled actions at high "
                          "returns; record field sampled_q_bf16_centred_error)")
  train.add_argument("--wrap_angles", action=argparse.BooleanOptionalAction, default=None,
                     help="the agent wraps the task's unbounded raw angles (hopper's and "
                          "cheetah's pitch, reacher's shoulder) into [-pi, pi) before "
                          "standardising them; by default it sees them raw, as the paper's "
                          "(FORM: unless the task's entry in mjx_form/imitation/settings.py "
                          "wraps them)")
  train.add_argument("--angle_features", action=argparse.BooleanOptionalAction, default=None,
                     help="the agent (actor and critic) sees each of those unbounded angles as "
                          "its cos and sin instead of its value: one input per pose, no jump at "
                          "+-pi; not the paper's (default: off, unless the task's entry in "
                          "mjx_form/imitation/settings.py turns it on)")
  train.add_argument("--eval_envs", type=int, default=defaults.eval_envs)
  train.add_argument("--lockstep_episodes", action="store_true",
                     help="start every environment's first episode together (as runs before "
                          "staggered starts did); by default first episodes start at random "
                          "phases so that every iteration collects every phase of an episode")
  train.add_argument("--eval_every", type=int, default=10, help="iterations between evaluations")
  train.add_argument("--eval_on_host", action="store_true",
                     help="run the periodic evaluations on the host's CPU while training goes on "
                          "(their rows are written once done; the final evaluations stay on "
                          "the accelerator; the run's end waits for a running one, and where "
                          "--max_seconds stops it, its last iteration is not evaluated "
                          "periodically): for a GPU, whose evaluation steps its episodes one "
                          "step after another while the CPU is idle")
  train.add_argument("--checkpoint_every", type=int, default=50, help="iterations")
  train.add_argument("--max_seconds", type=float, default=None,
                     help="stop training (checkpointed, policy exported) once this many "
                          "seconds have passed since the command started, demonstrations and "
                          "a demonstrator trained here included (it gets about half of them); "
                          "the final evaluations (--final_eval_envs) come after; --resume "
                          "continues")
  train.add_argument("--stop_file", default=os.environ.get(STOP_FILE_VARIABLE) or None,
                     metavar="PATH",
                     help="once this file exists, training stops at the end of its iteration as "
                          "--max_seconds stops it (checkpointed, policy exported, final "
                          "evaluations); it must not exist at the start (default: $"
                          f"{STOP_FILE_VARIABLE}, which scripts/gpu_jobs.py sets for its jobs)")
  train.add_argument("--init_policy", metavar="FILE",
                     help="--method expert: every member starts from this trained policy (its "
                          "parameters and observation statistics; a policy.npz of this task or "
                          "of another with its observations, e.g. hopper_stand's expert for "
                          "hopper_hop); default: random initialisation, as the paper")
  train.add_argument("--lean_checkpoints", action="store_true",
                     help="checkpoints without replay and environment states (a few MB, to "
                          "carry between machines); a resumed run then starts with an empty "
                          "replay and fresh episodes")
  train.add_argument("--results", default=None,
                     help="append kind=learning_curve records (one per evaluation) to this "
                          ".jsonl file (default <run_dir>/learning_curve.jsonl)")
  form = parser.add_argument_group(
      "FORM (--method form): where the demonstrator comes from, and its settings")
  form.add_argument("--expert", help="the expert's policy.npz to record demonstrations from "
                    "(default: the one shipped in tasks/experts/)")
  form.add_argument("--demos", help="demonstrations saved by scripts/make_demos.py, instead "
                    "of recording them (--method bc: with their actions, --actions)")
  form.add_argument("--demo_episodes", type=int, default=None,
                    help="episodes to record (default: 1000 where a demonstrator is trained, "
                         f"as the paper; {pipeline.DEFAULT_CHECK_EPISODES} to check a ready "
                         "one and measure the expert's return; 0: do not check a ready one, "
                         "~40 s less on a GPU for walker)")
  form.add_argument("--save_demos", help="also write the recorded demonstrations here")
  form.add_argument("--demonstrator", action="append", default=None,
                    help="a demonstrator effect model (.npz) to use (default: "
                    "tasks/demonstrators/<task>.npz where its settings are this run's, else "
                    "one is trained); given several times, an ensemble: log pD is their "
                    "mixture's, or see --ensemble_log_pd (files of one task and one setting)")
  form.add_argument("--ensemble_log_pd", choices=form_lib.ENSEMBLE_LOG_PD, default=None,
                    help="with several --demonstrator files (an ensemble): log pD is their "
                         "mixture's (default) or the mean of their log pD, the mean of their "
                         "FORM rewards, where one model's broad floor weighs 1/K instead of "
                         "setting the mixture's (mjx_form/imitation/form.py)")
  form.add_argument("--member_demonstrators", action="store_true",
                    help="the --demonstrator files go one to each member of the population, in "
                         "the members' order (seeds outermost: seed 0 with each --grid value, then "
                         "seed 1, ...), instead of an ensemble: "
                         "one program compares demonstrators, e.g. draws of one recipe; with "
                         "--train_demonstrator, one draw per member is trained (seeds "
                         "--demonstrator_seed + 0, 1, ...; the draws side by side in one "
                         "program, on the same demonstrations)")
  form.add_argument("--train_demonstrator", action="store_true",
                    help="train a demonstrator even where one is shipped")
  form.add_argument("--demonstrator_seed", type=int, default=None,
                    help="seed of the demonstrations recorded and of the demonstrator trained "
                         "(default: --seed; one for the whole population, whatever --seeds): "
                         "another draw of the same recipe")
  form.add_argument("--beta_ar", type=float, default=None,
                    help="effect models' autoregressive weight (default: per task, "
                         "mjx_form/imitation/settings.py)")
  form.add_argument("--effect_l2", type=float, default=None,
                    help="effect models' L2 weight (default: per task)")
  form.add_argument("--turn_invariant", action=argparse.BooleanOptionalAction, default=None,
                    help="effect models blind to full turns of the raw unbounded angles the "
                         "task observes (reacher's shoulder, cheetah's and hopper's pitch; "
                         "mjx_form/imitation/effect_model.py; default: the task's setting in "
                         "mjx_form/imitation/settings.py: on for reacher_hard, else off, the "
                         "paper's). reacher_hard's plain demonstrator: --no-turn_invariant "
                         "--demonstrator benchmarks/demonstrators/reacher_hard_plain.npz")
  form.add_argument("--angle_increments", action=argparse.BooleanOptionalAction, default=None,
                    help="turn-invariant effect models predict each periodic angle's change "
                         "rather than its value (a residual parameterisation; not the "
                         "paper's; default: the task's setting, off)")
  form.add_argument("--angle_inputs", action=argparse.BooleanOptionalAction, default=None,
                    help="effect models with --angle_increments see each periodic angle as its "
                         "cos and sin rather than its wrapped value, which jumps at +-pi (not "
                         "the paper's; default: the task's setting, off)")
  form.add_argument("--effect_max_scale", type=float, default=None,
                    help="soft cap on the effect models' mixture scales, in standardised units "
                         "(not the paper's; default: none): a demonstrator cannot then pay all "
                         "transitions off the expert's alike through one broad component, "
                         "but FORM on reacher_hard was worse with a cap of 1 "
                         "(mjx_form/imitation/effect_model.py)")
  gaifo = parser.add_argument_group(
      "GAIfO (--method gaifo, gaifo_gp, vaifo, vaifo_gp; demonstrations as for form: --expert, "
      "--demos, --demo_episodes, default 1000, --save_demos; --reward_scale)")
  gaifo.add_argument("--gradient_penalty", type=float, default=None, metavar="BETA",
                     help=f"gaifo_gp's and vaifo_gp's beta_gp (default {GAIFO_GP_DEFAULT:g}, "
                          "the paper's typical value; tuned per task there)")
  gaifo.add_argument("--kl_bound", type=float, default=None, metavar="EPSILON",
                     help=f"vaifo's and vaifo_gp's bound on the bottleneck's KL (default "
                          f"{KL_BOUND_DEFAULT:g}, the paper's)")
  gaifo.add_argument("--discriminator_frames", type=int, default=1, choices=(1, 2),
                     help="the discriminator sees x_{t+1} (1, the paper's main table) or "
                          "(x_t, x_{t+1}) (2)")
  cloning_group = parser.add_argument_group("BC and BCO (--method bc, bco)")
  cloning_group.add_argument(
      "--cloning_loss", default=None, choices=cloning.CLONING_LOSSES,
      help="how the Gaussian policy is fitted to the actions: squared (the default): the mean "
           "by squared error, the scale by likelihood through the last layer alone; decoupled: "
           "the same with the scale's term reaching every layer (it slows the mean's fit); "
           "likelihood: -log pi(a|x), the paper's, whose 1/scale^2 lets the states of small "
           "scale (an expert at rest) drown the mean's gradient elsewhere (mjx_form/rl/cloning.py)")
  train.add_argument("--preset", default=None, choices=settings.PRESETS,
                     help="default: measured settings; paper: the paper's. For form: the "
                          "reward scale, reward clip, target period and sampled-Q precision "
                          "(default: standardised, clipped at 3 sd, 25, bfloat16, and a task's "
                          "own entry, mjx_form/imitation/settings.py; paper: raw, unclipped, "
                          "200, float32). For expert: the policy head, actor noise correlation, "
                          "target period, sampled-Q precision, the critic's view of actions, "
                          "action penalty and epsilon_scale (default: the task's recipe in "
                          "mjx_form/rl/recipes.py where it has one, else the paper's: paper "
                          "head, 0, 200, float32, tanh, off, 1e-5). Single flags win")
  form.add_argument("--standardise_reward", dest="reward_scale", action="store_const",
                    const="standardised", help=argparse.SUPPRESS)  # before --reward_scale
  form.add_argument("--reward_scale", default=None, choices=("standardised", "raw"),
                    help="standardised: the learner gets the FORM reward standardised by its "
                         "running mean and sd (mjx_form/imitation/form.py); raw: log pD - log pI "
                         "as the paper (default: --preset's). GAIfO: raw, log(1 + D), by "
                         "default")
  form.add_argument("--imitator_every", type=int, default=1, metavar="K",
                    help="train the imitator model (and fold a batch into its "
                         "standardisation and the reward's running mean and sd) on the first "
                         "of every K learner batches (a divisor of --updates_per_iteration); "
                         "every batch is still relabelled with the current imitator. 1 "
                         "(default): every batch, as the paper; not measured otherwise")
  form.add_argument("--reward_clip", type=float, default=None,
                    help="bound the FORM reward's tail: clip it to this many running standard "
                         "deviations around its running mean, in the learner's reward and in "
                         "its statistics (mjx_form/imitation/form.py); 0: off, else > 1 "
                         "(default: 3, or the task's entry in mjx_form/imitation/settings.py; "
                         "--preset paper: 0)")
  steps = demonstrator_lib.DemonstratorTraining()
  form.add_argument("--demonstrator_steps", type=int, default=steps.max_steps,
                    help="most gradient steps of demonstrator training (it stops earlier when "
                         "the held-out likelihood stops improving)")
  form.add_argument("--demonstrator_eval_every", type=int, default=steps.eval_every,
                    help="steps between held-out evaluations of the demonstrator")
  form.add_argument("--demonstrator_patience", type=int, default=steps.patience,
                    help="held-out evaluations without improvement before it stops")
  form.add_argument("--demonstrator_smoothing", type=int, default=steps.smoothing,
                    help="evaluations whose mean the patience compares (single ones scatter)")
  train.add_argument("--final_eval_envs", type=int, default=256,
                     help="episodes of the fresh evaluation of the final and the best policy "
                          "once training is finished or stopped by --max_seconds (0: none; "
                          "after the time budget, compiling it included)")
  learner_flags = [action.dest for action in train._group_actions]  # random trains nothing
  args = parser.parse_args(argv)
  if args.list:
    return args
  if args.log_every is None:
    args.log_every = 50 if args.method == "random" else 1
  if args.method == "random":
    given = [f"--{name}" for name in ["seeds", "grid"] + learner_flags
             if getattr(args, name) != parser.get_default(name)]
    if given:
      parser.error(f"{', '.join(given)} apply to --method {', '.join(FROM_DEMOS)} and expert")
  args.grid = _grid(parser, args.grid, args.method)
  if args.init_policy and args.method != "expert":
    parser.error("--init_policy applies to --method expert (a FORM run imitates from "
                 "observations alone; random steps no policy)")
  if args.method not in FROM_DEMOS:
    given = [f"--{name}" for name in DEMO_OPTIONS
             if getattr(args, name) != parser.get_default(name)]
    if given:
      parser.error(f"{', '.join(given)} apply to --method {', '.join(FROM_DEMOS)}")
  if args.method not in ("form", *GAIFO) and args.reward_scale is not None:
    parser.error(f"--reward_scale applies to --method form, {', '.join(GAIFO)}"
                 + (f" (--method {args.method} has no reward: it clones actions)"
                    if args.method in CLONING else ""))
  if args.method in CLONING:
    given = [f"--{name}" for name in MPO_ONLY
             if getattr(args, name) != parser.get_default(name)]
    given += [f"--grid {name}" for name in args.grid
              if name in grid.LEARNER and name not in ("learning_rate", "max_grad_norm",
                                                       "policy_average_decay")]
    if given:
      parser.error(f"{', '.join(given)}: --method {args.method} fits the policy alone to "
                   f"its actions (no critic, no MPO) with the paper's settings")
  if args.method not in CLONING:
    given = [f"--{name}" for name in CLONING_ONLY
             if getattr(args, name) != parser.get_default(name)]
    if given:
      parser.error(f"{', '.join(given)} applies to --method {', '.join(CLONING)}")
  if args.method != "form":
    given = [f"--{name}" for name in FORM_ONLY
             if getattr(args, name) != parser.get_default(name)]
    if given:
      parser.error(f"{', '.join(given)} apply to --method form only")
  if args.method not in GAIFO:
    given = [f"--{name}" for name in GAIFO_ONLY
             if getattr(args, name) != parser.get_default(name)]
    if given:
      parser.error(f"{', '.join(given)} apply to --method {', '.join(GAIFO)}")
  if args.method in ("gaifo", "vaifo") and args.gradient_penalty is not None:
    parser.error(f"--gradient_penalty: --method {args.method} has none (--method "
                 f"{args.method}_gp has one)")
  if args.method in ("gaifo_gp", "vaifo_gp") and args.gradient_penalty is not None and not (
      0 < args.gradient_penalty < float("inf")):
    parser.error(f"--gradient_penalty must be positive and finite, got {args.gradient_penalty}")
  if args.method in ("gaifo", "gaifo_gp") and args.kl_bound is not None:
    parser.error(f"--kl_bound: --method {args.method} has no bottleneck (--method "
                 f"{args.method.replace('gaifo', 'vaifo')} has one)")
  if args.kl_bound is not None and not 0 <= args.kl_bound < float("inf"):
    parser.error(f"--kl_bound must be >= 0 and finite, got {args.kl_bound}")
  if args.method in (*GAIFO, "bco", "bc") and args.demo_episodes == 0:
    parser.error(f"--demo_episodes 0: --method {args.method} needs demonstrations")
  if args.resume and (args.demonstrator or args.train_demonstrator or args.member_demonstrators
                      or args.demonstrator_seed is not None):
    parser.error("--resume uses the demonstrators kept in the run directory: leave out "
                 "--demonstrator, --member_demonstrators, --train_demonstrator and "
                 "--demonstrator_seed")
  if args.member_demonstrators:
    members = population_size(args)
    if args.train_demonstrator and members < 2:
      parser.error(f"--member_demonstrators --train_demonstrator: a draw per member needs a "
                   f"population of 2 or more (--seeds and/or --grid), got {members}")
    if not args.train_demonstrator and (len(args.demonstrator or ()) != members or members < 2):
      parser.error(f"--member_demonstrators: give one --demonstrator per member (the "
                   f"population has {members}), got {len(args.demonstrator or ())}")
  averaged = ([f"--ensemble_log_pd {args.ensemble_log_pd}"]
              if args.ensemble_log_pd not in (None, "mixture") else []) + (
      ["--grid ensemble_log_pd"] if set(args.grid.get("ensemble_log_pd", ())) - {"mixture"}
      else [])
  if averaged and (args.member_demonstrators
                   or (len(args.demonstrator or ()) < 2 and not args.resume)):
    parser.error(f"{' and '.join(averaged)}: an ensemble needs 2 --demonstrator files or more, "
                 "shared by the members (not --member_demonstrators)")
  if args.demonstrator and args.train_demonstrator:
    parser.error("--demonstrator and --train_demonstrator exclude each other (a run trains "
                 "its demonstrator or uses the ones given)")
  if args.task not in tasks.TASKS:
    parser.error(f"unknown task {args.task!r}; valid tasks: {', '.join(tasks.TASKS)}")
  for name in ("num_envs", "steps", "log_every", "env_steps", "eval_every", "checkpoint_every",
               "demonstrator_steps", "demonstrator_eval_every", "demonstrator_patience",
               "demonstrator_smoothing"):
    if getattr(args, name) <= 0:
      parser.error(f"--{name} must be a positive integer, got {getattr(args, name)}")
  if args.max_seconds is not None and args.max_seconds <= 0:
    parser.error(f"--max_seconds must be positive, got {args.max_seconds}")
  if args.method in LEARNERS and args.stop_file is not None and os.path.exists(args.stop_file):
    parser.error(f"--stop_file {args.stop_file} exists already (the run would stop after its "
                 "first iteration): remove it, or name another")
  if args.imitator_every <= 0 or args.updates_per_iteration % args.imitator_every:
    parser.error(f"--imitator_every must be a positive divisor of --updates_per_iteration "
                 f"({args.updates_per_iteration}), got {args.imitator_every}")
  if args.demo_episodes is not None and args.demo_episodes < 0:
    parser.error(f"--demo_episodes must be >= 0, got {args.demo_episodes}")
  if args.demo_episodes == 0 and (args.save_demos or args.demos or args.expert
                                  or args.train_demonstrator):
    parser.error("--demo_episodes 0 (no demonstrations: the ready demonstrator unchecked) "
                 "goes with neither --save_demos, --demos, --expert nor --train_demonstrator")
  if args.final_eval_envs < 0:
    parser.error(f"--final_eval_envs must be >= 0, got {args.final_eval_envs}")
  for name in ("policy_average_decay", "epsilon_scale", "noise_scale_min"):  # (--grid's checks)
    if getattr(args, name) is not None:
      try:
        grid.check_value(name, getattr(args, name))
      except ValueError as e:
        parser.error(f"--{e}")
  return args


def train_config(args: argparse.Namespace) -> TrainConfig:
  """The run's TrainConfig: the method's preset for the task, then the flags."""
  if args.method in CLONING:  # the paper's policy head, actor noise, no average policy
    chosen = dict(recipes.PAPER)
  elif args.method in FROM_DEMOS:  # FORM's learner settings; the paper's head and actor noise
    chosen = {**recipes.PAPER, **form_run_settings(args)}
  else:
    chosen = recipes.expert_settings(args.task, args.preset or "default")
  chosen.update({k: getattr(args, k) for k in recipes.KEYS if getattr(args, k) is not None})
  period, bfloat16 = chosen["target_update_period"], chosen["sampled_q_bfloat16"]
  learner = dataclasses.replace(
      LearnerConfig(), num_action_samples=args.num_action_samples,
      target_update_period=period, clip_critic_actions=chosen["clip_critic_actions"],
      sampled_q_bfloat16=bfloat16, sampled_q_float32_head=args.sampled_q_float32_head,
      policy_average_decay=chosen.get("policy_average_decay", 0.0)
      if args.policy_average_decay is None else args.policy_average_decay,
      cloning_loss=(args.cloning_loss or cloning.DEFAULT_CLONING_LOSS) if args.method in CLONING
      else LearnerConfig().cloning_loss,
      mpo=dataclasses.replace(LearnerConfig().mpo, action_penalty=chosen["action_penalty"],
                              epsilon_scale=chosen["epsilon_scale"],
                              clip_mean_targets=args.clip_mean_targets))
  seed = args.seeds[0] if args.seeds else args.seed
  return TrainConfig(task=args.task, physics=args.physics,
                     reward_source=args.method if args.method in FROM_DEMOS else "task",
                     num_envs=args.num_envs,
                     unroll_length=args.unroll_length, batch_size=args.batch_size,
                     replay_capacity=args.replay_capacity,
                     updates_per_iteration=args.updates_per_iteration,
                     source_update_every=args.imitator_every,
                     network_width=args.network_width, policy_head=chosen["policy_head"],
                     action_noise_correlation=chosen["action_noise_correlation"],
                     noise_scale_min=args.noise_scale_min,
                     eval_envs=args.eval_envs, seed=seed,
                     stagger_episodes=not args.lockstep_episodes,
                     wrap_angles=chosen.get("wrap_angles", False) if args.wrap_angles is None
                     else args.wrap_angles,
                     angle_features=chosen.get("angle_features", False)
                     if args.angle_features is None else args.angle_features, learner=learner)


def recipe_applies(args: argparse.Namespace) -> bool:
  """Whether the run takes its task's own settings: an expert run its recipe
  (mjx_form/rl/recipes.py), a FORM run its entry in mjx_form/imitation/settings.py."""
  own = recipes.PER_TASK if args.method == "expert" else settings.PER_TASK_RUN
  return (args.method in LEARNERS and args.method not in CLONING and args.task in own
          and args.preset != "paper")


def recipe_line(args: argparse.Namespace) -> str:
  """What a run prints when its task's own settings apply (`recipe_applies`): those settings,
  and the flags that override them."""
  if args.method == "expert":
    recipe, where = recipes.PER_TASK[args.task], "expert recipe (mjx_form/rl/recipes.py)"
  else:
    recipe = settings.PER_TASK_RUN[args.task]
    where = "FORM settings (mjx_form/imitation/settings.py)"
  keys = (*recipes.KEYS, "wrap_angles", "angle_features")
  flags = [f"--{'no-' if getattr(args, k) is False else ''}{k}" for k in keys
           if getattr(args, k) is not None]
  flags += [f"--grid {k}" for k in keys if k in (args.grid or {})]
  return (f"{args.task}'s {where}: "
          + ", ".join(f"{k} {v}" for k, v in recipe.items())
          + (f"; overridden by {', '.join(flags)}" if flags else "")
          + "; --preset paper for the paper's settings")


def recipe_hint(args: argparse.Namespace, error: ValueError) -> str:
  """For a resumed expert run refused for another config where the task's recipe applied: runs
  started before the recipe existed ran the paper's settings."""
  if not (args.resume and isinstance(error, checkpoint.CheckpointError) and error.keys):
    return ""
  if "init_policy" in error.keys:  # the run started from a policy file, or this one does
    return (" (a run that started from a policy resumes with --init_policy and that file; one "
            "that did not, without it)")
  if "learner.policy_average_decay" in error.keys:
    return (" (a FORM run started before FORM kept the average policy by default, 2026-11-28, "
            "or with another --policy_average_decay, resumes with the value it was started "
            "with: --policy_average_decay 0 for none)")
  if "learner.cloning_loss" in error.keys:
    return (" (a BC or BCO run resumes with the fit it started with: --cloning_loss likelihood "
            "for one started before the flag existed, 2026-12-01, decoupled for one started "
            "before 2026-12-07 without the flag)")
  if "reward.ensemble_log_pd" in error.keys:
    return (" (a run started with --ensemble_log_pd mean resumes with it; one started without "
            "it, without it)")
  if (args.method == "form" and {"learner.clip_critic_actions", "learner.mpo.epsilon_scale"}
      & set(error.keys) and set(settings.LEARNER_KEYS) & set(settings.run_settings(args.task))
      and args.preset != "paper"):
    return (f" ({args.task}'s FORM runs take the expert recipes' learner since 2026-11-29, "
            "mjx_form/imitation/settings.py; a run started before resumes "
            "with --no-clip_critic_actions --epsilon_scale 1e-5, one started with other flags "
            "with those flags)")
  flags = [key for key in ("learner.mpo.clip_mean_targets", "learner.sampled_q_float32_head")
           if key in error.keys]
  if flags:
    names = " and ".join(f"--[no-]{key.rsplit('.', 1)[1]}" for key in flags)
    return f" (a run resumes with the {names} it was started with)"
  if "source_update_every" in error.keys:
    return (" (a run started with --imitator_every K resumes with it; one started without it, "
            "without it)")
  if args.method == "expert" and recipe_applies(args):
    return (f" ({args.task}'s expert runs take its recipe, mjx_form/rl/recipes.py; a run "
            "started with the paper's settings, or before the recipe had these keys, resumes "
            "with --preset paper and the flags it was started with)")
  return ""


def form_run_settings(args: argparse.Namespace) -> dict:
  """The FORM run's reward scale, reward clip, target period, sampled-Q precision and average
  policy's decay, and the actor and learner settings of the task's entry
  (`settings.run_settings`): --preset's for the task, then the flags of the first five (the
  others' flags apply in `train_config`)."""
  chosen = settings.run_settings(args.task, args.preset or "default")
  if args.reward_scale is not None:
    chosen["standardise_reward"] = args.reward_scale == "standardised"
  if args.reward_clip is not None:
    try:
      grid.check_value("reward_clip", args.reward_clip)
    except ValueError as e:
      raise ValueError(f"--{e}") from None
    chosen["reward_clip"] = args.reward_clip
  if args.target_update_period is not None:
    chosen["target_update_period"] = args.target_update_period
  if args.sampled_q_bfloat16 is not None:
    chosen["sampled_q_bfloat16"] = args.sampled_q_bfloat16
  if args.policy_average_decay is not None:
    chosen["policy_average_decay"] = args.policy_average_decay
  return chosen


def effect_model_settings(args: argparse.Namespace, env):
  """The effect-model settings the user set (`explicit`) and those of this run (`config`).
  ValueError for --turn_invariant on a task without unbounded angles."""
  explicit = {"beta_ar": args.beta_ar, "l2": args.effect_l2,
              "period": settings.turn_period(env, args.turn_invariant),
              "angle_increments": args.angle_increments, "angle_inputs": args.angle_inputs,
              "max_scale": args.effect_max_scale}
  # Effect models share the width of the other networks, and a demonstrator trains on batches
  # shaped like the learner's (batch_size windows of unroll_length transitions).
  config = settings.effect_model_config(args.task, env, width=args.network_width, **explicit)
  return explicit, config


def population_size(args: argparse.Namespace) -> int:
  """How many members the run's population has (every seed with each --grid combination)."""
  return len(grid.expand(args.seeds or (args.seed,), args.grid)[0])


def demonstrator_seed_of(args: argparse.Namespace) -> int:
  """The seed of a FORM run's recorded demonstrations and trained demonstrator."""
  return args.seed if args.demonstrator_seed is None else args.demonstrator_seed


def form_source(args: argparse.Namespace, run_dir: str, results_path: str, print_fn):
  """Stages 1-2 of --method form: the FORM reward source, its demonstrator in `run_dir`."""
  env = tasks.make(args.task, physics=args.physics)
  explicit, config = effect_model_settings(args, env)
  demonstrator_seed = demonstrator_seed_of(args)
  training = demonstrator_lib.DemonstratorTraining(
      max_steps=args.demonstrator_steps, batch_size=args.batch_size, window=args.unroll_length,
      eval_every=args.demonstrator_eval_every, patience=args.demonstrator_patience,
      smoothing=args.demonstrator_smoothing, seed=demonstrator_seed,
      max_seconds=None if args.max_seconds is None else args.max_seconds / 2)
  artefacts = pipeline.Artefacts(
      expert=args.expert, demos=args.demos, demonstrator=tuple(args.demonstrator or ()),
      member_demonstrators=args.member_demonstrators,
      draw_seeds=(tuple(demonstrator_seed + i for i in range(population_size(args)))
                  if args.member_demonstrators and args.train_demonstrator else ()),
      demo_episodes=args.demo_episodes, train_demonstrator=args.train_demonstrator,
      save_demos=args.save_demos, training=training)
  return pipeline.prepare(env, config, explicit,
                          artefacts, run_dir, resume=args.resume, physics=args.physics,
                          seed=demonstrator_seed, results_path=results_path,
                          reward={**{k: v for k, v in form_run_settings(args).items()
                                     if k in ("standardise_reward", "reward_clip")},
                                  "ensemble_log_pd": args.ensemble_log_pd or "mixture"},
                          varied=tuple(args.grid), print_fn=print_fn)


def discriminator_config(args: argparse.Namespace) -> discriminator_lib.DiscriminatorConfig:
  """The discriminator of --method gaifo, gaifo_gp, vaifo or vaifo_gp (its penalty and
  bottleneck by the method, their strengths by the flags or the paper's defaults)."""
  penalty = 0.0 if not args.method.endswith("_gp") else (
      GAIFO_GP_DEFAULT if args.gradient_penalty is None else args.gradient_penalty)
  bound = None if not args.method.startswith("vaifo") else (
      KL_BOUND_DEFAULT if args.kl_bound is None else args.kl_bound)
  return discriminator_lib.DiscriminatorConfig(
      width=args.network_width, frames=args.discriminator_frames, gradient_penalty=penalty,
      kl_bound=bound)


def run_demonstrations(args: argparse.Namespace, run_dir: str, print_fn,
                       with_actions: bool = False) -> tuple:
  """(the task, then `pipeline.demonstrations`' results) of the run's demonstrations (recorded,
  or --demos; 1000 episodes by default), once `run_dir` is known to fit (a new run's unused, a
  resumed one's there)."""
  runner.check_run_dir(run_dir, args.resume)
  env = tasks.make(args.task, physics=args.physics)
  artefacts = pipeline.Artefacts(expert=args.expert, demos=args.demos,
                                 save_demos=args.save_demos)
  episodes = (pipeline.DEFAULT_TRAINING_EPISODES if args.demo_episodes is None
              else args.demo_episodes)
  return (env, *pipeline.demonstrations(env, artefacts, episodes, args.physics, args.seed,
                                        print_fn, with_actions=with_actions))


def gaifo_source(args: argparse.Namespace, run_dir: str, print_fn
                 ) -> tuple[gaifo_lib.GaifoReward, dict]:
  """The discriminator's reward source of --method gaifo, gaifo_gp, vaifo or vaifo_gp and what
  its demonstrations are (`pipeline.demonstrations`' info), once `run_dir` is known to fit (a
  new run's unused, a resumed one's there). A resumed run records its demonstrations again (the
  same seed: the same episodes) or reads --demos; the checkpoint's settings name their
  observations' checksum (the same for a recording and the file --save_demos wrote of it), so
  other ones are refused."""
  _, observations, info = run_demonstrations(args, run_dir, print_fn)
  config = discriminator_config(args)
  # The reward as the paper's, log(1 + D) in [0, log 2], unless --reward_scale standardised:
  # early on D is nearly constant, and its running sd ~0 would blow the standardised one up.
  return gaifo_lib.GaifoReward(config, observations,
                               demos_lib.checksum({"observations": observations}),
                               standardise_reward=args.reward_scale == "standardised"), info


def cloning_source(args: argparse.Namespace, run_dir: str, print_fn) -> tuple:
  """The cloning source of --method bc (with the expert's actions; the checksum covers them
  too) or bco (observations only) and what its demonstrations are, once `run_dir` is known to
  fit (as `gaifo_source`)."""
  if args.method == "bc":
    _, observations, actions, info = run_demonstrations(args, run_dir, print_fn,
                                                        with_actions=True)
    return bc_lib.BehaviourCloning(observations, actions, info["sha256"]), info
  env, observations, info = run_demonstrations(args, run_dir, print_fn)
  return bco_lib.BcoSource(inverse_model_lib.InverseModelConfig(width=args.network_width),
                           observations, env.action_bounds,
                           demos_lib.checksum({"observations": observations})), info


def demonstrations_fields(info: dict) -> dict:
  """What a baseline's records say of its demonstrations: the mean task return of the episodes
  (the expert's level it imitates; absent where a demonstrations file did not record it)."""
  mean = (info.get("expert") or {}).get("mean_return")
  return {} if mean is None else {"demonstrations_return": round(float(mean), 2)}


def random_rollout(args: argparse.Namespace, mesh) -> dict:
  """Random-action rollout with the batch sharded over `mesh`; returns the measured numbers."""
  env = AutoReset(tasks.make(args.task, physics=args.physics))
  num_actions = env.env.action_size
  print(f"{args.task}: obs {env.env.observation_size}, actions {num_actions}, "
        f"physics {args.physics}, {args.num_envs} envs on {mesh.devices.size} "
        f"{jax.default_backend()} device(s)", flush=True)

  def chunk(state, key):
    def one_step(state, key):
      action = jax.random.uniform(key, (args.num_envs, num_actions), minval=-1.0, maxval=1.0)
      state = env.step(state, action)
      return state, (state.reward, state.done)
    state, (rewards, dones) = jax.lax.scan(one_step, state, jax.random.split(key, args.log_every))
    return state, rewards.mean(), dones.sum()

  sharding = mesh_lib.batch_sharding(mesh)
  reset = jax.jit(lambda key: env.reset(key, args.num_envs), out_shardings=sharding)
  chunk = jax.jit(chunk, donate_argnums=0,
                  out_shardings=(sharding, mesh_lib.replicated(mesh), mesh_lib.replicated(mesh)))

  key = jax.random.PRNGKey(args.seed)
  t0 = time.perf_counter()
  state = jax.block_until_ready(reset(key))
  reset_s = time.perf_counter() - t0
  # The first chunk compiles; it runs but is not counted in steps/s.
  t0 = time.perf_counter()
  state, _, _ = jax.block_until_ready(chunk(state, key))
  print(f"reset (incl. compile) {reset_s:.1f}s, first {args.log_every} steps (incl. "
        f"compile) {time.perf_counter() - t0:.1f}s", flush=True)

  done_steps, elapsed, episodes = 0, 0.0, 0
  while done_steps < args.steps:
    key, sub = jax.random.split(key)
    t0 = time.perf_counter()
    state, mean_reward, ended = jax.block_until_ready(chunk(state, sub))
    elapsed += time.perf_counter() - t0
    done_steps += args.log_every
    episodes += int(ended)
    sps = done_steps * args.num_envs / elapsed
    print(f"step {done_steps:6d}/{args.steps}  {sps:12,.0f} steps/s  mean reward "
          f"{float(mean_reward):.4f}  episodes ended {episodes}  physics errors "
          f"{int(jnp.sum(state.info['physics_errors']))}", flush=True)
  return {"task": args.task, "num_envs": args.num_envs, "steps": done_steps,
          "steps_per_second": done_steps * args.num_envs / elapsed}


def main(argv=None) -> int:
  started = time.perf_counter()  # --max_seconds counts from here
  args = parse_args(argv)
  if args.list:
    print("\n".join(tasks.TASKS))
    return 0
  if args.eval_on_host:
    one_device_per_core()  # (before JAX starts; the evaluations' batch is split over them)
  use_compilation_cache(args.compilation_cache)
  mesh = mesh_lib.make_mesh()
  if args.eval_on_host and jax.default_backend() == "cpu":
    print("error: --eval_on_host evaluates on the host's CPU beside an accelerator; this run "
          "trains on the CPU itself (no accelerator found)", file=sys.stderr)
    return 2
  if args.method in LEARNERS:
    seeds, overrides = grid.expand(args.seeds or (args.seed,), args.grid)
    name = (f"seed{seeds[0]}" if len(set(seeds)) == 1 else "seeds" + "_".join(
        map(str, args.seeds))) + "".join(f"_{k}" for k in args.grid)
    run_dir = args.run_dir or os.path.join("runs", f"{args.task}_{args.method}_{name}")
    results_path = args.results or os.path.join(run_dir, "learning_curve.jsonl")
    say = lambda line: print(line, flush=True)
    try:
      config = train_config(args)
      config.check(mesh.devices.size)
      initial = None
      if args.init_policy:  # refuses a file of another layout or a damaged one, by name
        initial = experts.load_expert(args.init_policy, tasks.make(args.task, physics=args.physics),
                                      any_task=True)
        config = dataclasses.replace(config, init_policy=experts.policy_id(initial))
      if recipe_applies(args):
        say(recipe_line(args))
      source, fields = None, {}
      if args.method == "form":
        source = form_source(args, run_dir, results_path, say)
      elif args.method in GAIFO or args.method in CLONING:
        source, info = (gaifo_source if args.method in GAIFO else cloning_source)(args, run_dir,
                                                                                  say)
        fields = demonstrations_fields(info)
      rows = runner.run(config, run_dir, args.env_steps, resume=args.resume,
                        log_every=args.log_every, eval_every=args.eval_every,
                        checkpoint_every=args.checkpoint_every, max_seconds=args.max_seconds,
                        seconds_before=time.perf_counter() - started,
                        checkpoint_replay=not args.lean_checkpoints, results_path=results_path,
                        final_eval_envs=args.final_eval_envs, mesh=mesh, reward_source=source,
                        seeds=seeds, overrides=overrides, initial_policy=initial,
                        eval_on_host=args.eval_on_host, stop_file=args.stop_file,
                        record_fields=fields, print_fn=say)
    except ValueError as e:  # bad settings or artefacts, an existing run, another config
      print(f"error: {e}{recipe_hint(args, e)}", file=sys.stderr)
      return 2
    for seed, own, row, directory in zip(seeds, overrides, rows,
                                         runner.member_dirs(run_dir, seeds, overrides)):
      finished = row["env_steps"] >= args.env_steps
      print(f"{'done' if finished else 'stopped'}"
            + (f" ({grid.label(seed, own)})" if len(seeds) > 1 else "") + ": "
            + "".join(f"{what} {row[key]:.1f}, " for what, key in (
                ("eval return", "eval_return"), ("fresh evaluation", "final_policy_return"))
                      if key in row)
            + f"{row['env_steps']:,} env steps; policy in {os.path.join(directory, 'policy.npz')}"
            f", the best evaluation's in {os.path.join(directory, 'best_policy.npz')}"
            + (", by log pD in best_log_pd_policy.npz"
               if os.path.exists(os.path.join(directory, "best_log_pd_policy.npz")) else "")
            + (f", the average policy in {runner.AVERAGE_FILE}" if os.path.exists(
                os.path.join(directory, runner.AVERAGE_FILE)) else "")
            + "".join(f" (by log pD in {file})" for _, _, file in runner.AVERAGE_BEST
                      if os.path.exists(os.path.join(directory, file)))
            + (f", the imitator model in {form_lib.FormReward.export_file}" if os.path.exists(
                os.path.join(directory, form_lib.FormReward.export_file)) else ""))
    return 0
  try:
    mesh_lib.check_batch_size(args.num_envs, mesh)
  except ValueError as e:
    print(f"error: {e}", file=sys.stderr)
    return 2
  result = random_rollout(args, mesh)
  print(f"done: {result['steps_per_second']:,.0f} control steps/s "
        f"({result['num_envs']} envs x {result['steps']} steps)")
  return 0


if __name__ == "__main__":
  sys.exit(main())
