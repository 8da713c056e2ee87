"""Per-member settings of a population (mjx_form.rl.grid): parsing, the grid's members, and a
member's learner config (the compiled program's use of them: tests/test_population.py)."""

import dataclasses

import jax
import jax.numpy as jnp
import pytest

from mjx_form.rl import grid
from mjx_form.rl.learner import LearnerConfig


def test_a_grid_is_every_combination_of_seeds_and_values():
  seeds, overrides = grid.expand((0, 1), {"target_update_period": (25, 200),
                                          "standardise_reward": (False, True)})
  assert seeds == (0,) * 4 + (1,) * 4
  assert overrides[:4] == (
      {"target_update_period": 25, "standardise_reward": False},
      {"target_update_period": 25, "standardise_reward": True},
      {"target_update_period": 200, "standardise_reward": False},
      {"target_update_period": 200, "standardise_reward": True})
  assert overrides[4:] == overrides[:4]
  assert grid.expand((3,), {}) == ((3,), ({},))
  # A member's values split into the learner's, the actors' and the reward source's.
  assert grid.split(overrides[1]) == ({"target_update_period": 25}, {},
                                      {"standardise_reward": True})
  assert grid.split({"action_noise_correlation": 0.9, "reward_clip": 3.0}) == (
      {}, {"action_noise_correlation": 0.9}, {"reward_clip": 3.0})


def test_members_are_named_by_their_seed_and_settings():
  own = {"target_update_period": 25, "standardise_reward": True, "learning_rate": 3e-4}
  assert grid.label(0, {}) == "seed 0" and grid.dirname(2, {}) == "seed2"
  assert grid.label(1, own) == ("seed 1, learning_rate 0.0003, standardise_reward 1, "
                                "target_update_period 25")
  assert grid.dirname(1, own) == "seed1_learning_rate0.0003_standardise_reward1_target_update_period25"


def test_values_are_parsed_as_their_setting_and_checked():
  assert grid.parse_value("target_update_period", "25") == 25
  assert grid.parse_value("epsilon_mean", "5e-3") == 0.005
  assert grid.parse_value("standardise_reward", "true") is True
  assert grid.parse_value("standardise_reward", "0") is False
  assert grid.parse_value("clip_critic_actions", "1") is True  # a learner bool
  assert grid.parse_value("clip_critic_actions", "false") is False
  assert grid.parse_value("reward_clip", "3") == 3.0 and grid.parse_value("reward_clip", "0") == 0
  assert grid.parse_value("action_noise_correlation", "0") == 0.0  # independent: allowed
  assert grid.parse_value("action_noise_correlation", "0.9") == 0.9
  assert grid.parse_value("policy_average_decay", "0") == 0.0  # none kept: allowed
  assert grid.parse_value("policy_average_decay", "0.999") == 0.999
  for name, text, message in (("target_update_period", "2.5", "expected int"),
                              ("target_update_period", "0", "must be positive"),
                              ("discount", "1.5", r"\(0, 1\]"),
                              ("retrace_lambda", "-0.1", r"\[0, 1\]"),
                              ("standardise_reward", "yes", "0/1"),
                              ("clip_critic_actions", "2", "0/1"),
                              ("reward_clip", "-1", "0 \\(off\\) or finite and > 1"),
                              ("reward_clip", "inf", "finite"),
                              ("epsilon_scale", "0", "positive and finite"),
                              ("epsilon_mean", "inf", "positive and finite"),
                              ("reward_clip", "1", "collapses"),
                              ("action_noise_correlation", "1", r"\[0, 1\)"),
                              ("action_noise_correlation", "-0.5", r"\[0, 1\)"),
                              ("policy_average_decay", "1", r"\[0, 1\)"),
                              ("policy_average_decay", "-0.1", r"\[0, 1\)"),
                              ("num_envs", "8", "cannot differ")):
    with pytest.raises(ValueError, match=message):
      grid.parse_value(name, text)


def test_a_member_learner_config_takes_its_values_nested_or_traced():
  base = LearnerConfig()
  config = grid.learner_config(base, {"epsilon_mean": 0.01, "discount": 0.95})
  assert config.mpo.epsilon_mean == 0.01 and config.discount == 0.95
  assert dataclasses.replace(config, discount=base.discount,
                             mpo=base.mpo) == base  # nothing else changed
  # Traced: each member's entry of a [P] array stands where the config holds a number.
  periods = jnp.array([2, 3], jnp.int32)
  copies = jax.vmap(lambda p: grid.learner_config(base, {"target_update_period": p})
                    .target_update_period)(periods)
  assert copies.tolist() == [2, 3]
  arrays = grid.arrays([{"target_update_period": 2, "learning_rate": 1e-3},
                        {"target_update_period": 3, "learning_rate": 1e-4}],
                       ["target_update_period", "learning_rate"])
  assert arrays["target_update_period"].dtype == jnp.int32
  assert arrays["learning_rate"].dtype == jnp.float32 and arrays["learning_rate"].shape == (2,)
  assert grid.arrays([{"clip_critic_actions": True}, {"clip_critic_actions": False}],
                     ["clip_critic_actions"])["clip_critic_actions"].dtype == jnp.bool_


def test_a_setting_with_named_values_travels_as_their_index():
  """FORM's ensemble_log_pd: parsed and checked by name, a member's value in the [P] arrays is
  its index in CHOICES (what the source compares a traced value with)."""
  from mjx_form.imitation import form
  assert grid.CHOICES["ensemble_log_pd"] == form.ENSEMBLE_LOG_PD == ("mixture", "mean")
  assert grid.parse_value("ensemble_log_pd", "mean") == "mean"
  with pytest.raises(ValueError, match="must be one of mixture, mean, got 'Mean'"):
    grid.parse_value("ensemble_log_pd", "Mean")
  values = [{"ensemble_log_pd": "mean"}, {"ensemble_log_pd": "mixture"},
            {"ensemble_log_pd": "mean"}]
  index = grid.arrays(values, ["ensemble_log_pd"])["ensemble_log_pd"]
  assert index.dtype == jnp.int32 and index.tolist() == [1, 0, 1]
  assert grid.split({"ensemble_log_pd": "mean"}) == ({}, {}, {"ensemble_log_pd": "mean"})
  assert grid.dirname(0, {"ensemble_log_pd": "mean"}) == "seed0_ensemble_log_pdmean"
  assert grid.label(2, {"ensemble_log_pd": "mean"}) == "seed 2, ensemble_log_pd mean"
