"""Expert recipes (mjx_form/rl/recipes.py) and how run.py applies them."""

import pytest
from conftest import load_script

from mjx_form.imitation import settings

import tasks
from mjx_form.rl import recipes
from mjx_form.rl.learner import LearnerConfig
from mjx_form.rl.networks import POLICY_HEADS
from mjx_form.rl.train import TrainConfig


def test_paper_preset_is_the_paper_learner_and_actor():
  paper = recipes.expert_settings("hopper_stand", "paper")
  assert paper == {"policy_head": "paper", "action_noise_correlation": 0.0,
                   "target_update_period": 200, "sampled_q_bfloat16": False,
                   "clip_critic_actions": False, "action_penalty": False,
                   "epsilon_scale": 1e-5}
  assert paper["target_update_period"] == LearnerConfig().target_update_period
  assert paper["epsilon_scale"] == LearnerConfig().mpo.epsilon_scale
  assert paper["action_penalty"] == LearnerConfig().mpo.action_penalty
  assert paper["clip_critic_actions"] == LearnerConfig().clip_critic_actions
  assert paper["policy_head"] == TrainConfig().policy_head


def test_recipes_name_real_tasks_and_valid_settings():
  for task, recipe in recipes.PER_TASK.items():
    assert task in tasks.TASKS
    assert set(recipe) <= set(recipes.KEYS), task
    assert recipe.get("policy_head", "paper") in POLICY_HEADS
    assert 0.0 <= recipe.get("action_noise_correlation", 0.0) < 1.0
    assert recipe.get("target_update_period", 1) >= 1
    assert 0.0 < recipe.get("epsilon_scale", 1e-5) < 1.0, task
    assert all(isinstance(recipe.get(k, False), bool)
               for k in ("clip_critic_actions", "sampled_q_bfloat16", "action_penalty")), task


def test_expert_and_form_presets_share_names():
  """run.py offers one --preset for both methods (its choices are settings.PRESETS)."""
  assert recipes.PRESETS == settings.PRESETS


def test_default_preset_is_the_task_recipe_else_the_paper():
  assert recipes.expert_settings("hopper_stand") == {
      "policy_head": "acme", "action_noise_correlation": 0.9, "target_update_period": 100,
      "sampled_q_bfloat16": True, "clip_critic_actions": False, "action_penalty": False,
      "epsilon_scale": 1e-5}
  assert recipes.expert_settings("walker_run") == {
      "policy_head": "paper", "action_noise_correlation": 0.0, "target_update_period": 25,
      "sampled_q_bfloat16": True, "clip_critic_actions": True, "action_penalty": False,
      "epsilon_scale": 1e-6}
  assert recipes.expert_settings("reacher_hard") == {
      "policy_head": "paper", "action_noise_correlation": 0.0, "target_update_period": 25,
      "sampled_q_bfloat16": True, "clip_critic_actions": False, "action_penalty": True,
      "epsilon_scale": 1e-5}
  assert recipes.expert_settings("quadruped_run") == {
      "policy_head": "paper", "action_noise_correlation": 0.0, "target_update_period": 25,
      "sampled_q_bfloat16": True, "clip_critic_actions": True, "action_penalty": False,
      "epsilon_scale": 1e-6}
  assert recipes.expert_settings("cheetah_run") == recipes.expert_settings("cheetah_run", "paper")
  with pytest.raises(ValueError, match="unknown preset 'fast'"):
    recipes.expert_settings("hopper_stand", "fast")


def test_run_applies_the_recipe_to_expert_runs_only_and_flags_win():
  cli = load_script("run")
  config = lambda *argv: cli.train_config(cli.parse_args(list(argv)))
  hop = config("--task", "hopper_stand", "--method", "expert")
  assert (hop.policy_head, hop.action_noise_correlation) == ("acme", 0.9)
  assert (hop.learner.target_update_period, hop.learner.sampled_q_bfloat16) == (100, True)
  paper = config("--task", "hopper_stand", "--method", "expert", "--preset", "paper")
  assert paper.learner == LearnerConfig() and paper.policy_head == "paper"
  assert paper.action_noise_correlation == 0.0
  mixed = config("--task", "hopper_stand", "--method", "expert", "--target_update_period", "25",
                 "--action_noise_correlation", "0", "--no-sampled_q_bfloat16")
  assert (mixed.learner.target_update_period, mixed.action_noise_correlation) == (25, 0.0)
  assert mixed.learner.sampled_q_bfloat16 is False and mixed.policy_head == "acme"
  walker = config("--task", "walker_stand", "--method", "expert")  # no recipe: the paper's
  assert walker.learner == LearnerConfig() and walker.policy_head == "paper"
  walk = config("--task", "walker_walk", "--method", "expert")  # walker_run's recipe
  assert (walk.learner.target_update_period, walk.learner.clip_critic_actions) == (25, True)
  run = config("--task", "walker_run", "--method", "expert")
  assert (run.learner.target_update_period, run.learner.clip_critic_actions) == (25, True)
  unclipped = config("--task", "walker_run", "--method", "expert", "--no-clip_critic_actions")
  assert unclipped.learner.clip_critic_actions is False
  assert unclipped.learner.target_update_period == 25
  assert config("--task", "walker_run", "--method", "expert", "--preset", "paper").learner == (
      LearnerConfig())
  # FORM takes the paper's view of actions, not walker_run's recipe, unless the flag asks.
  form = config("--task", "walker_run", "--method", "form")
  assert form.learner.clip_critic_actions is False
  assert config("--task", "walker_run", "--method", "form",
                "--clip_critic_actions").learner.clip_critic_actions is True
  # reacher_hard's recipe turns MPO's action penalty on; the flag turns it off; FORM, the paper
  # preset and a task without it in its recipe keep it off unless asked.
  reach = config("--task", "reacher_hard", "--method", "expert")
  assert reach.learner.mpo.action_penalty is True
  assert (reach.learner.target_update_period, reach.learner.sampled_q_bfloat16) == (25, True)
  assert config("--task", "reacher_hard", "--method", "expert",
                "--no-action_penalty").learner.mpo.action_penalty is False
  assert config("--task", "reacher_hard", "--method", "expert",
                "--preset", "paper").learner == LearnerConfig()
  assert config("--task", "reacher_hard", "--method", "form").learner.mpo.action_penalty is False
  assert config("--task", "reacher_hard", "--method", "form",
                "--action_penalty").learner.mpo.action_penalty is True
  assert config("--task", "walker_run", "--method", "expert").learner.mpo.action_penalty is False
  # --epsilon_scale sets MPO's scale bound for either method; without it, the preset's.
  assert config("--task", "walker_run", "--method", "expert",
                "--epsilon_scale", "1e-6").learner.mpo.epsilon_scale == 1e-6
  assert config("--task", "walker_run", "--method", "form",
                "--epsilon_scale", "1e-6").learner.mpo.epsilon_scale == 1e-6
  assert config("--task", "walker_run", "--method", "form").learner.mpo.epsilon_scale == 1e-5
  # quadruped_run's recipe sets it; the flag and the paper preset win; FORM's own entry
  # (mjx_form/imitation/settings.py) sets it too, with the critic's clip; --preset paper not.
  assert config("--task", "quadruped_run", "--method", "expert").learner.mpo.epsilon_scale == 1e-6
  assert config("--task", "quadruped_run", "--method", "expert", "--epsilon_scale",
                "1e-5").learner.mpo.epsilon_scale == 1e-5
  assert config("--task", "quadruped_run", "--method", "expert",
                "--preset", "paper").learner == LearnerConfig()
  form = config("--task", "quadruped_run", "--method", "form").learner
  assert (form.mpo.epsilon_scale, form.clip_critic_actions) == (1e-6, True)
  form = config("--task", "quadruped_run", "--method", "form", "--no-clip_critic_actions",
                "--epsilon_scale", "1e-5").learner
  assert (form.mpo.epsilon_scale, form.clip_critic_actions) == (1e-5, False)
  form = config("--task", "quadruped_run", "--method", "form", "--preset", "paper").learner
  assert (form.mpo.epsilon_scale, form.clip_critic_actions) == (1e-5, False)
  form = config("--task", "walker_stand", "--method", "form").learner  # no entry: the paper's
  assert (form.mpo.epsilon_scale, form.clip_critic_actions) == (1e-5, False)
  head = config("--task", "hopper_stand", "--method", "expert", "--policy_head", "paper")
  assert head.policy_head == "paper" and head.action_noise_correlation == 0.9
  # FORM has its own settings: settings.PER_TASK_RUN's entry (hopper_stand's sets the actor),
  # else the paper's actor; the expert recipe never applies to FORM.
  form = config("--task", "hopper_stand", "--method", "form")
  assert (form.policy_head, form.action_noise_correlation, form.wrap_angles) == (
      "acme", 0.9, True)
  assert form.learner.target_update_period == 100
  raw = config("--task", "hopper_stand", "--method", "form", "--no-wrap_angles",
               "--policy_head", "paper")
  assert (raw.policy_head, raw.action_noise_correlation, raw.wrap_angles) == ("paper", 0.9, False)
  paper = config("--task", "hopper_stand", "--method", "form", "--preset", "paper")
  assert (paper.policy_head, paper.action_noise_correlation, paper.wrap_angles) == (
      "paper", 0.0, False)
  assert paper.learner.target_update_period == 200
  walk = config("--task", "walker_walk", "--method", "form")
  assert (walk.policy_head, walk.action_noise_correlation, walk.wrap_angles) == (
      "paper", 0.0, False)
  assert config("--task", "walker_walk", "--method", "expert", "--wrap_angles").wrap_angles
  assert not config("--task", "hopper_stand", "--method", "expert").wrap_angles
  # The bfloat16 sampled Q's float32 head: off unless asked, and only beside bfloat16.
  assert config("--task", "hopper_stand", "--method", "expert").learner.sampled_q_float32_head is (
      False)
  head = config("--task", "humanoid_stand", "--method", "expert", "--sampled_q_bfloat16",
                "--sampled_q_float32_head")
  assert head.learner.sampled_q_float32_head is True and head.learner.sampled_q_bfloat16
  head.check(1)
  with pytest.raises(ValueError, match="sampled_q_float32_head applies to the bfloat16"):
    config("--task", "humanoid_stand", "--method", "expert", "--sampled_q_float32_head").check(1)
  assert config("--task", "walker_stand", "--noise_scale_min", "0").noise_scale_min == 0.0
  assert config("--task", "walker_stand").noise_scale_min == 1.0
  with pytest.raises(SystemExit):
    cli.parse_args(["--task", "walker_stand", "--noise_scale_min", "1.5"])


def test_run_names_the_recipe_and_its_overrides(capsys):
  cli = load_script("run")
  line = cli.recipe_line(cli.parse_args(["--task", "hopper_stand", "--method", "expert"]))
  assert "hopper_stand's expert recipe" in line and "target_update_period 100" in line
  assert "overridden" not in line
  line = cli.recipe_line(cli.parse_args(["--task", "hopper_stand", "--method", "expert",
                                         "--target_update_period", "25"]))
  assert "overridden by --target_update_period" in line
  line = cli.recipe_line(cli.parse_args(["--task", "walker_run", "--method", "expert",
                                         "--no-clip_critic_actions"]))
  assert "clip_critic_actions True" in line and "overridden by --no-clip_critic_actions;" in line
  line = cli.recipe_line(cli.parse_args(["--task", "walker_run", "--method", "expert",
                                         "--seeds", "0", "--grid", "clip_critic_actions=0,1"]))
  assert "overridden by --grid clip_critic_actions;" in line
  line = cli.recipe_line(cli.parse_args(["--task", "reacher_hard", "--method", "expert",
                                         "--no-action_penalty"]))
  assert "action_penalty True" in line and "overridden by --no-action_penalty;" in line
  line = cli.recipe_line(cli.parse_args(["--task", "hopper_stand", "--method", "form",
                                         "--no-wrap_angles"]))
  assert "hopper_stand's FORM settings" in line and "policy_head acme" in line
  assert "overridden by --no-wrap_angles;" in line
  assert cli.recipe_applies(cli.parse_args(["--task", "hopper_stand", "--method", "form"]))
  assert not cli.recipe_applies(cli.parse_args(["--task", "walker_stand", "--method", "form"]))
  line = cli.recipe_line(cli.parse_args(["--task", "walker_walk", "--method", "form",
                                         "--epsilon_scale", "1e-5"]))
  assert "walker_walk's FORM settings" in line and "clip_critic_actions True" in line
  assert "overridden by --epsilon_scale;" in line
  assert not cli.recipe_applies(cli.parse_args(["--task", "hopper_stand", "--method", "form",
                                                "--preset", "paper"]))
  with pytest.raises(SystemExit):
    cli.parse_args(["--method", "random", "--preset", "paper"])
  assert "--preset apply to --method form, gaifo, gaifo_gp, vaifo, vaifo_gp, bco, bc and expert" in capsys.readouterr().err
  with pytest.raises(SystemExit):  # random trains nothing, so no learner flag has a meaning
    cli.parse_args(["--method", "random", "--policy_average_decay", "0.5", "--resume"])
  assert ("--resume, --policy_average_decay apply to --method form, gaifo, gaifo_gp, vaifo, vaifo_gp, bco, bc and expert"
          in capsys.readouterr().err)
  assert cli.parse_args(["--method", "random", "--physics", "fast"]).method == "random"


@pytest.mark.parametrize("value", ["0", "-1e-6", "inf", "nan"])
def test_run_refuses_an_epsilon_scale_that_is_not_positive_and_finite(value, capsys):
  cli = load_script("run")
  with pytest.raises(SystemExit) as exit_info:
    cli.parse_args(["--method", "expert", f"--epsilon_scale={value}"])
  assert exit_info.value.code == 2
  assert "--epsilon_scale must be positive and finite" in capsys.readouterr().err
