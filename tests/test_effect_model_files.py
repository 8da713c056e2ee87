"""Demonstrator (effect-model) files: round trip, and refusals that name the file and the
mismatch (numpy only)."""

import json
import zipfile

import numpy as np
import pytest

from mjx_form.files import effect_models, policy_io
from mjx_form.files.effect_models import EffectModelFileError

LAYOUT = [["position", 2], ["to_target", 2], ["velocity", 2]]


def _params(rng):
  return {"params": {"encoder": {"Dense_0": {"kernel": rng.normal(size=(6, 4)).astype(np.float32),
                                             "bias": np.zeros(4, np.float32)}},
                     "head": {"kernel": rng.normal(size=(4, 5)).astype(np.float32)}}}


def _metadata(**change):
  meta = {"task": "reacher_easy", "observation_size": 6, "observation_layout": LAYOUT,
          "distractors": None, "config": {"width": 4, "beta_ar": 0.1},
          "training": {"steps": 10, "best_step": 10, "heldout_log_likelihood": [1.0, 0.5]},
          "demonstrations": {"sha256": "ab", "episodes": 3}}
  meta.update(change)
  return meta


@pytest.fixture
def saved(tmp_path):
  rng = np.random.default_rng(0)
  params, mean, var = _params(rng), rng.normal(size=6), rng.uniform(0.5, 2, size=6)
  path = tmp_path / "demonstrator.npz"
  effect_models.save_effect_model(path, params, mean, var, _metadata())
  return path, params, mean, var


def test_round_trip(saved):
  path, params, mean, var = saved
  loaded = effect_models.load_effect_model(path, task="reacher_easy", observation_layout=LAYOUT,
                                           distractors=None)
  np.testing.assert_array_equal(loaded.params["params"]["head"]["kernel"],
                                params["params"]["head"]["kernel"])
  np.testing.assert_allclose(loaded.mean, mean.astype(np.float32))
  np.testing.assert_allclose(loaded.var, var.astype(np.float32))
  meta = loaded.metadata
  assert meta["format"] == "mjx-form-effect-model" and meta["training"]["steps"] == 10
  assert len(meta["sha256"]) == 64


def test_never_overwrites(saved):
  path, params, mean, var = saved
  before = path.read_bytes()
  with pytest.raises(FileExistsError):
    effect_models.save_effect_model(path, params, mean, var, _metadata())
  assert path.read_bytes() == before


@pytest.mark.parametrize("kwargs, message", [
    (dict(task="cheetah_run"), "the demonstrator is for reacher_easy, this run is cheetah_run"),
    (dict(observation_layout=[["position", 2], ["velocity", 4]]), "observation layout"),
    (dict(distractors={"dims": 8, "pool": 10}), "distractors None, this run has"),
])
def test_refuses_another_run(saved, kwargs, message):
  path = saved[0]
  with pytest.raises(EffectModelFileError, match=message) as e:
    effect_models.load_effect_model(path, **kwargs)
  assert str(path) in str(e.value)


def test_refuses_damaged_and_foreign_files(saved, tmp_path):
  path = saved[0]
  truncated = tmp_path / "truncated.npz"
  truncated.write_bytes(path.read_bytes()[:200])
  with pytest.raises(EffectModelFileError, match="truncated"):
    effect_models.load_effect_model(truncated)
  with pytest.raises(EffectModelFileError, match="no such effect-model file"):
    effect_models.load_effect_model(tmp_path / "missing.npz")
  # A policy file is not a demonstrator.
  policy = tmp_path / "policy.npz"
  policy_io.save_policy(policy, {"w": np.zeros(2)}, {"task": "reacher_easy",
                                                     "observation_size": 6, "action_size": 2})
  with pytest.raises(EffectModelFileError, match="unknown format 'mjx-form-policy'"):
    effect_models.load_effect_model(policy)
  # Arrays changed behind the checksum's back.
  tampered = tmp_path / "tampered.npz"
  with zipfile.ZipFile(path) as src, zipfile.ZipFile(tampered, "w") as dst:
    for item in src.infolist():
      data = src.read(item.filename)
      if item.filename == "normalizer/mean.npy":
        data = data[:-4] + np.float32(9.0).tobytes()
      dst.writestr(item, data)
  with pytest.raises(EffectModelFileError, match="checksum mismatch"):
    effect_models.load_effect_model(tampered)


def test_refuses_incomplete_metadata(tmp_path):
  rng = np.random.default_rng(1)
  meta = _metadata()
  del meta["training"]
  with pytest.raises(ValueError, match="needs 'training'"):
    effect_models.save_effect_model(tmp_path / "x.npz", _params(rng), np.zeros(6), np.ones(6),
                                    meta)
  with pytest.raises(ValueError, match="observation_layout sums to 6"):
    effect_models.save_effect_model(tmp_path / "y.npz", _params(rng), np.zeros(6), np.ones(6),
                                    _metadata(observation_size=7))
  # Metadata is JSON; nothing pickled.
  effect_models.save_effect_model(tmp_path / "z.npz", _params(rng), np.zeros(6), np.ones(6),
                                  _metadata())
  with np.load(tmp_path / "z.npz", allow_pickle=False) as f:
    assert json.loads(bytes(f["metadata"]).decode())["task"] == "reacher_easy"


def test_each_shipped_demonstrator_has_its_tasks_settings():
  """A shipped demonstrator is used only where its settings are the run's (the pipeline trains
  one otherwise): each must match its task's entry in mjx_form/imitation/settings.py."""
  import tasks
  from mjx_form.imitation import settings
  shipped = [t for t in tasks.TASKS if tasks.bundled_demonstrator(t)]
  assert "cheetah_run" in shipped
  for task in shipped:
    file = effect_models.load_effect_model(tasks.bundled_demonstrator(task), task=task)
    expected = settings.effect_model_config(task, width=256).to_dict()
    assert file.metadata["config"] == expected, task
    turned = settings.effect_model_settings(task).get("turn_invariant", False)
    assert ("period" in file.metadata["config"]) == turned, task
