"""The expert policies shipped in tasks/experts/: each loads for its task only, and the
reacher_easy one, recorded through scripts/make_demos.py --task, does reach its targets."""

import numpy as np
import pytest
from conftest import load_script

import tasks
from mjx_form.files import demos, experts, policy_io

SHIPPED = tasks.bundled_experts()


def test_the_readme_experts_are_shipped():
  assert {"reacher_easy", "reacher_hard", "cheetah_run", "walker_stand",
          "walker_walk"} <= set(SHIPPED)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_expert_loads_for_its_task_only(name):
  expert = experts.load_expert(SHIPPED[name], tasks.make(name))  # checksum, sizes, layout
  assert expert.metadata["task"] == name
  assert expert.metadata["eval_return"] > 800  # what the table calls an expert
  other = "walker_walk" if name == "cheetah_run" else "cheetah_run"
  with pytest.raises(policy_io.PolicyFileError, match=name):
    experts.load_expert(SHIPPED[name], tasks.make(other))


def test_unknown_or_unshipped_task_is_a_clear_error(tmp_path, capsys):
  with pytest.raises(ValueError, match="valid tasks"):
    tasks.bundled_expert("cheetah_walk")
  with pytest.raises(ValueError, match="no shipped expert for 'humanoid_run'.*reacher_easy"):
    tasks.bundled_expert("humanoid_run")
  out = tmp_path / "demos.npz"
  assert load_script("make_demos").main(["--task", "humanoid_run", "--out", str(out)]) == 2
  assert "no shipped expert" in capsys.readouterr().err and not out.exists()


def test_demonstrations_from_the_shipped_reacher_expert(tmp_path):
  """16 full episodes on the CPU: the expert reaches its targets (random actions score ~0-50)."""
  out = tmp_path / "demos.npz"
  assert load_script("make_demos").main(["--task", "reacher_easy", "--episodes", "16",
                                 "--out", str(out)]) == 0
  loaded = demos.load_demonstrations(out, task="reacher_easy", observation_size=6)
  assert loaded.observations.shape == (16, 1001, 6) and loaded.actions is None
  _, shipped = policy_io.load_policy(SHIPPED["reacher_easy"])
  assert loaded.metadata["expert"]["policy_sha256"] == shipped["sha256"]
  assert loaded.metadata["expert"]["mean_return"] > 700, loaded.metadata["expert"]
  # The arm moves towards the target: finger-to-target distance shrinks over the episode.
  to_target = np.linalg.norm(loaded.observations[:, :, 2:4], axis=-1)  # obs 'to_target'
  assert to_target[:, -100:].mean() < 0.5 * to_target[:, 0].mean()


def test_the_shipped_hopper_expert_wraps_its_pitch():
  """hopper_stand's expert (a network trained on raw pitches, wrapped afterwards by
  scripts/wrap_angles.py; benchmarks/NOTES.md, session 25) wraps position[1] only."""
  expert = experts.load_expert(SHIPPED["hopper_stand"], tasks.make("hopper_stand"))
  period = np.zeros(15, np.float32)
  period[1] = 2 * np.pi
  np.testing.assert_allclose(expert.normalizer.period, period)
  assert expert.metadata["wrap_angles"] == ["position[1]"]
  assert expert.metadata["wrap_angles_added_after_training"] is True
