"""FORM's per-task effect-model settings, in one place.

The paper tunes two regularisers per task and shares them between the demonstrator and the
imitator model: the autoregressive weight beta_ar and the L2 weight, each over the grid
{0.01, 0.1, 1} (its appendix; humanoid_run and quadruped_run did best with beta_ar 1 and
L2 0.1 there). Everything else is the paper's and the same for every task
(`EffectModelConfig`). A task not listed uses DEFAULT. Each entry says which measurement chose
it (benchmarks/results/); an entry without one is not tuned yet.
"""

from __future__ import annotations

import dataclasses

from mjx_form.imitation.effect_model import EffectModelConfig

GRID = (0.01, 0.1, 1.0)  # the paper's search space for beta_ar and l2

# Untuned tasks: the paper's best pair on its two ablated tasks.
DEFAULT = {"beta_ar": 1.0, "l2": 0.1}

PER_TASK: dict[str, dict[str, float]] = {}


def effect_model_config(task: str, **overrides) -> EffectModelConfig:
  """The effect-model settings of `task`, with `overrides` (e.g. beta_ar=0.1) applied."""
  chosen = {**DEFAULT, **PER_TASK.get(task, {})}
  chosen.update({k: v for k, v in overrides.items() if v is not None})
  config = dataclasses.replace(EffectModelConfig(), **chosen)
  config.check()
  return config
