"""Trained effect models on disk (FORM's demonstrator model): one small `.npz`, no pickle.

File format ("mjx-form-effect-model", version 1)
------------------------------------------------
The container of `mjx_form.files.policy_io` (compressed `.npz`, one array per '/'-joined leaf
path, a UTF-8 JSON `metadata` entry, sha256 over the arrays in sorted name order). Entries:

  params/...          the flax parameters of `mjx_form.imitation.effect_model.EffectModel`
  normalizer/mean     [D] the standardisation the model was trained with (frozen)
  normalizer/var      [D]

Metadata keys (besides format, version, sha256):

  task                the task name, e.g. "walker_walk"
  observation_size    D
  observation_layout  [[name, size], ...] summing to D
  distractors         null, or the distractor setting of the observations it was trained on
  config              the EffectModelConfig it was trained with (width, num_components,
                      max_offset, beta_ar, l2, learning_rate, normalizer_decay, min_scale;
                      period, angle_increments, angle_inputs and max_scale where set; a run
                      refuses a file whose settings differ from those it asks for, naming them:
                      mjx_form.imitation.pipeline.demonstrator_from_file)
  training            steps, best_step, batch_size, window, seconds, heldout_log_likelihood
                      (raw observation space, nats per transition, one value per offset
                      1..max_offset), the held-out curve, episodes used for training/held out
  demonstrations      what it was trained on: the demonstration file's sha256, episodes,
                      physics and expert (policy file, its sha256, mean return)
  imitator            only in a FORM run's imitator model (its imitator.npz, written online,
                      mjx_form.imitation.form.FormReward.export): the run's env steps, its
                      policy file and the running mean and sd of its raw reward; `training`
                      then holds its steps only, and a run refuses the file as a demonstrator

`load_effect_model` refuses a file of another task, observation layout or distractor setting,
another format (e.g. a policy file), and damaged files, naming the file and the mismatch.
"""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np

from mjx_form.files import npz_files

FORMAT = "mjx-form-effect-model"
VERSION = 1
_SIZES = ("observation_size",)
_NO_CHECK = object()


class EffectModelFileError(ValueError):
  """An effect-model file is missing, corrupt, or does not fit this run."""


class EffectModelFile(NamedTuple):
  params: dict[str, Any]  # nested dict of numpy arrays
  mean: np.ndarray  # [D] standardisation
  var: np.ndarray  # [D]
  metadata: dict[str, Any]


def save_effect_model(path, params, mean, var, metadata: dict, overwrite: bool = False) -> str:
  """Writes an effect model with its standardisation; `metadata` as in the module docstring
  (task, observation_size, observation_layout, distractors, config, training, demonstrations)."""
  for key in ("observation_layout", "distractors", "config", "training", "demonstrations"):
    if key not in metadata:
      raise ValueError(f"metadata needs {key!r}")
  tree = {"params": params, "normalizer": {"mean": np.asarray(mean, np.float32),
                                           "var": np.asarray(var, np.float32)}}
  return npz_files.save_tree(path, tree, metadata, FORMAT, VERSION, _SIZES, overwrite=overwrite)


def load_effect_model(path, *, task: str | None = None, observation_layout=None,
                      distractors=_NO_CHECK) -> EffectModelFile:
  """Reads and validates an effect-model file; `task`, `observation_layout` and `distractors`
  (None for none), when given, must match the file's. Raises `EffectModelFileError`."""
  path = os.fspath(path)
  fail = lambda problem: EffectModelFileError(f"{path}: {problem}")
  arrays, meta = npz_files.read_tree(path, "effect-model file", FORMAT, VERSION, _SIZES, fail)
  for key, kind in (("config", dict), ("training", dict), ("demonstrations", dict),
                    ("observation_layout", list)):
    if not isinstance(meta.get(key), kind):
      raise fail(f"metadata {key!r} is {meta.get(key)!r}, expected a {kind.__name__}")
  npz_files.check_fits(meta, "demonstrator", fail, task=task,
                       observation_layout=observation_layout)
  if distractors is not _NO_CHECK and meta.get("distractors") != distractors:
    raise fail(f"the demonstrator was trained with distractors {meta.get('distractors')}, "
               f"this run has {distractors}")
  tree = npz_files.unflatten_tree(arrays, fail)
  d = meta["observation_size"]
  norm = tree.get("normalizer", {})
  if set(tree) != {"params", "normalizer"} or set(norm) != {"mean", "var"}:
    raise fail(f"entries {sorted(arrays)}; expected params/... and normalizer/mean, "
               "normalizer/var")
  for name in ("mean", "var"):
    if norm[name].shape != (d,) or not np.all(np.isfinite(norm[name])):
      raise fail(f"normalizer/{name} has shape {norm[name].shape} or non-finite values; "
                 f"expected finite [{d}]")
  return EffectModelFile(tree["params"], norm["mean"], norm["var"], meta)
