"""Per-member settings of a population: which settings may differ between its members, and how
a member's own values reach the one compiled program.

Members share everything that fixes the program's shapes and structure: the task, every size
(environments, unrolls, batches, replay, networks, action samples), the policy head, the
reward source and its models (FORM's effect-model settings too: the demonstrator is trained
offline with them, one file for the population). The settings below are numbers inside the
learner update, the actors' draw or the reward source's step, so each member may have its own:
they travel as [P] arrays (a setting with named values, FORM's `ensemble_log_pd`, as the index
of its value in CHOICES), and inside the vmapped update (or draw) each member's config holds
its value where a single run's holds a constant (`learner_config`), so a member computes what a
single run with its settings computes. (The actors' noise correlation is one: a member at 0
draws exactly what a single run's independent draw gives, while the population keeps a noise
state for every member; `noise_scale_min` likewise: each env's multiplier is computed where any
member scales, all 1 in a member at 1. The action penalty is another: its dual is in every
member's state if any member penalises, and stays at its initial value in a member that does
not. And
`wrap_angles`: every member's normaliser has a period if any member wraps, zeros in a member
that does not, which wraps nothing; the policy averaged over updates likewise: every member
keeps one if any member's `policy_average_decay` is above 0, a member at 0 keeps a copy of its
policy (and gets no average's evaluations or files); `angle_features` likewise: every member's
normaliser has `angles` if any member sees cos and sin, zero rows in a member that does not.
That member's networks take the 2K extra inputs, always 0, so it computes what a single run
without angle features computes except for its first layers' initial weights, drawn for the
larger input.)

A member is a seed and its overrides, e.g. (0, {"target_update_period": 25}); a grid
(`expand`) is every combination of the seeds and the listed values.
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import Any

import jax.numpy as jnp

# name (as on the command line) -> (path in LearnerConfig, type)
LEARNER = {
    "target_update_period": (("target_update_period",), int),
    "learning_rate": (("learning_rate",), float),
    "dual_learning_rate": (("dual_learning_rate",), float),
    "discount": (("discount",), float),
    "retrace_lambda": (("retrace_lambda",), float),
    "max_grad_norm": (("max_grad_norm",), float),
    "epsilon": (("mpo", "epsilon"), float),
    "epsilon_mean": (("mpo", "epsilon_mean"), float),
    "epsilon_scale": (("mpo", "epsilon_scale"), float),
    "clip_critic_actions": (("clip_critic_actions",), bool),
    "sampled_q_float32_head": (("sampled_q_float32_head",), bool),
    "action_penalty": (("mpo", "action_penalty"), bool),
    "epsilon_penalty": (("mpo", "epsilon_penalty"), float),
    "clip_mean_targets": (("mpo", "clip_mean_targets"), bool),
    "policy_average_decay": (("policy_average_decay",), float),
}
# MPO's KL bounds: each a dual's target, so 0 or inf makes its dual loss degenerate.
KL_BOUNDS = ("epsilon", "epsilon_mean", "epsilon_scale", "epsilon_penalty")
# name -> type: TrainConfig fields: the actors' draw, and whether the agent wraps the task's raw
# angles (realised as each member's observation-normaliser `period` at init, zeros in a member
# that does not wrap: normalizer.wrap leaves its features as they are).
ACTOR = {"action_noise_correlation": float, "noise_scale_min": float, "wrap_angles": bool,
         "angle_features": bool}
# name -> type: settings a reward source lists in its `variable_settings` (FORM's
# standardise_reward, reward_clip and ensemble_log_pd); the source's `specialise(values)` gives a
# member's source.
SOURCE = {"standardise_reward": bool, "reward_clip": float, "ensemble_log_pd": str}
# name -> the values of a setting of type str, its default first (which a source's settings()
# may leave out of records); a member's value travels as its index here (traced: the source
# compares it with `CHOICES[name].index(value)`).
CHOICES = {"ensemble_log_pd": ("mixture", "mean")}  # how an ensemble's models make log pD
NAMES = (*LEARNER, *ACTOR, *SOURCE)


def _kind(name: str) -> type:
  return LEARNER[name][1] if name in LEARNER else ACTOR.get(name) or SOURCE[name]


def split(values: dict) -> tuple[dict, dict, dict]:
  """(the LEARNER settings of `values`, the ACTOR ones, the reward source's)."""
  return ({k: v for k, v in values.items() if k in LEARNER},
          {k: v for k, v in values.items() if k in ACTOR},
          {k: v for k, v in values.items() if k not in LEARNER and k not in ACTOR})


def parse_value(name: str, text: str):
  """One grid value from the command line, as its setting's type."""
  if name not in NAMES:
    raise ValueError(f"--grid: {name!r} cannot differ between members (it can: "
                     f"{', '.join(NAMES)})")
  kind = _kind(name)
  if kind is str:
    check_value(name, text)
    return text
  if kind is bool:
    if text.lower() not in ("0", "1", "true", "false"):
      raise ValueError(f"--grid {name}: expected 0/1 or true/false, got {text!r}")
    return text.lower() in ("1", "true")
  try:
    value = kind(text)
  except ValueError:
    raise ValueError(f"--grid {name}: expected {kind.__name__} values, got {text!r}") from None
  check_value(name, value)
  return value


def check_value(name: str, value) -> None:
  """Refuses a value its setting cannot take (ValueError naming both)."""
  if name in CHOICES and value not in CHOICES[name]:
    raise ValueError(f"{name} must be one of {', '.join(CHOICES[name])}, got {value!r}")
  if name == "discount" and not 0.0 < value <= 1.0:
    raise ValueError(f"discount must be in (0, 1], got {value}")
  if name == "retrace_lambda" and not 0.0 <= value <= 1.0:
    raise ValueError(f"retrace_lambda must be in [0, 1], got {value}")
  if name == "action_noise_correlation" and not 0.0 <= value < 1.0:
    raise ValueError(f"action_noise_correlation must be in [0, 1), got {value}")
  if name == "noise_scale_min" and not 0.0 <= value <= 1.0:
    raise ValueError(f"noise_scale_min must be in [0, 1], got {value}")
  if name == "reward_clip" and not (value == 0.0 or 1.0 < value < float("inf")):
    # The running statistics fold in the clipped rewards: at c <= 1 their sd shrinks towards 0
    # batch after batch (FORM's module docstring).
    raise ValueError(f"reward_clip must be 0 (off) or finite and > 1 (the clipped "
                     f"statistics' sd collapses at c <= 1), got {value}")
  if name == "policy_average_decay" and not 0.0 <= value < 1.0:
    raise ValueError(f"policy_average_decay must be in [0, 1) (0: no average), got {value}")
  if name in KL_BOUNDS and not 0.0 < value < float("inf"):
    raise ValueError(f"{name} must be positive and finite, got {value}")
  own_range = ("discount", "retrace_lambda", "policy_average_decay")  # (checked above)
  if (name in LEARNER and _kind(name) is not bool and name not in own_range
      and not value > 0):
    raise ValueError(f"{name} must be positive, got {value}")


def expand(seeds: tuple[int, ...], grid: dict[str, tuple]) -> tuple[tuple[int, ...],
                                                                  tuple[dict, ...]]:
  """Every combination of a seed and one value of each grid setting: (seeds, overrides), one
  entry per member, seeds outermost."""
  names = list(grid)
  combos = [dict(zip(names, values)) for values in itertools.product(*grid.values())]
  members = [(s, c) for s in seeds for c in combos]
  return tuple(s for s, _ in members), tuple(c for _, c in members)


def label(seed: int, overrides: dict) -> str:
  """How progress lines name a member: 'seed 0' or 'seed 0, target_update_period 25'."""
  return ", ".join([f"seed {seed}"] + [f"{k} {_show(v)}" for k, v in sorted(overrides.items())])


def dirname(seed: int, overrides: dict) -> str:
  """A member's directory in a population's run directory: seed0, seed0_target_update_period25."""
  return "_".join([f"seed{seed}"] + [f"{k}{_show(v)}" for k, v in sorted(overrides.items())])


def _show(value) -> str:
  return str(int(value)) if isinstance(value, bool) else f"{value:g}" if isinstance(
      value, float) else str(value)


def learner_config(config, values: dict):
  """`config` (a LearnerConfig) with the LEARNER settings in `values` replaced; values may be
  Python numbers or traced scalars (a member's entry of `arrays`)."""
  for name, value in values.items():
    path, _ = LEARNER[name]
    config = _replace(config, path, value)
  return config


def _replace(obj, path: tuple[str, ...], value):
  if len(path) == 1:
    return dataclasses.replace(obj, **{path[0]: value})
  return dataclasses.replace(obj, **{path[0]: _replace(getattr(obj, path[0]), path[1:], value)})


def arrays(values: list[dict], names) -> dict[str, Any]:
  """The members' values of `names` as [P] arrays (int32 for integer settings and for the index
  of a str setting's value in its CHOICES, bool for bool settings, float32 else)."""
  out = {}
  for name in names:
    kind = _kind(name)
    if kind is str:
      out[name] = jnp.asarray([CHOICES[name].index(v[name]) for v in values], jnp.int32)
      continue
    dtype = jnp.int32 if kind is int else jnp.bool_ if kind is bool else jnp.float32
    out[name] = jnp.asarray([v[name] for v in values], dtype)
  return out
