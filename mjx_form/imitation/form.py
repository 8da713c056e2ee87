"""FORM's reward source: r_t = log pD(x_{t+1} | x_t) - log pI(x_{t+1} | x_t).

pD is the demonstrator effect model, trained offline on demonstration observations
(mjx_form.imitation.demonstrator) and frozen here; pI is the imitator effect model, trained
online by one gradient step on every learner batch (the same unrolls the learner consumes,
`EffectModelConfig` shared with the demonstrator). Rewards are relabelled on every batch with
the current imitator model, after its step; only offset 1 enters the reward (the other offsets
and the autoregressive term only regularise training).

Both densities are in raw observation space (each model's own standardisation undone by its
change of variables, mjx_form.imitation.effect_model), so their difference does not depend on
the two sets of statistics. A transition whose successor is not in the unroll (discount 0: an
episode cut short by a physics error, or one that ended mid-unroll) gets reward 0, like the
task reward's 0 at a physics error; the imitation runs keep time-limit ends on unroll ends
(`unroll_length` divides the episode), where the final observation is stored.

With `standardise_reward` the learner gets (r - m) / s instead of r, with m and s the EMA mean
and standard deviation of r over the valid transitions of the batches so far (decay 0.99 per
batch, as the observations). A constant shift and a positive scale leave the best policy of
these tasks unchanged (no episode ends early, time-limit ends are bootstrapped), and they keep
the critic's targets near the scale its learning rate was set for: raw FORM rewards reach -200
per step where the imitator strays from the demonstrations (benchmarks/NOTES.md). The raw r is
what the logs report either way.

With `reward_clip` c > 0 the reward's tail is bounded: the learner's reward is clipped to
c running standard deviations around the running mean (the standardised reward to [-c, c]),
and the statistics fold in the raw reward clipped the same way (winsorised; the first batch,
which sets them, is not clipped). A single transition far off the demonstrations (cheetah's
tumbles score log pD below -400 where the batch's median is ~-25, benchmarks/NOTES.md) then
weighs as c sd and does not inflate the scale of the others. 0 (as the paper, `--preset
paper`, and this class's default; a run's default is 3, `settings.DEFAULT_RUN`): no clipping.
Folding clipped rewards in biases the sd low, more so for small c: on Gaussian rewards the
running sd settles at 1.00 / 0.95 / 0.79 of the true one for c = 3 / 2 / 1.5 and falls towards
0 for c <= 1, which is therefore refused.

An ensemble of demonstrators (several files of one task and one setting: draws of one recipe,
or models of several experts' demonstrations, which the pipeline notes) gives pD as their
mixture, log pD = logsumexp_k log pD_k - log K: a density (so the reward keeps
its meaning), at least the best model's density / K wherever one model has a spurious hole.
Nine draws of one recipe (200k steps) gave reacher_hard's FORM 389-903 (mean 696, 0.72 of the
expert), and one trained longer 12 (benchmarks/NOTES.md, sessions 42-46).

With `ensemble_log_pd="mean"` log pD is instead the mean of the models' log pD (not a density:
their normalised geometric mean would subtract a normaliser of x_t), so the reward is the mean
of the K FORM rewards log pD_k - log pI, whose expectation is minus the mean of the K
divergences the paper's derivation gives. A mixture pays a transition at least what the most
lenient model pays it, less log K: one model's floor (a broad component that pays all
behaviour off the expert's alike, sessions 44-46) becomes the mixture's. The mean pays each
model's floor with weight 1/K. A population's members may differ in it (`--grid
ensemble_log_pd=mixture,mean`: one program compares both on the same models and seeds). A
single demonstrator's parameters are kept as they are; an ensemble's are stacked along a
leading axis of size K.

Demonstrators per member (`member_demonstrators`): a population's member i imitates the i-th
of P demonstrators (one each, not a mixture), so one program compares demonstrators, e.g. draws
of one recipe, which set reacher_hard's FORM level far more than its seeds do (NOTES, sessions
43-45). Every member's source state starts with the first one (`init` runs vmapped, blind to
the member); `member_states` then puts each member's own in its state, where the reward reads
it. `as_member(i)` is the source as member i's records describe it (its demonstrator's sha256).

The source never sees the task reward (`needs_task_reward = False`: it is not even stored).
"""

from __future__ import annotations

import copy
import math
from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form.files import effect_models
from mjx_form.imitation import effect_model as em
from mjx_form.rl import grid, normalizer


ENSEMBLE_LOG_PD = grid.CHOICES["ensemble_log_pd"]  # how an ensemble's models make log pD


class Demonstrator(NamedTuple):
  """A frozen effect model: parameters and the standardisation it was trained with."""

  params: Any
  normalizer: normalizer.NormalizerState


def stack(demonstrators: Sequence[Demonstrator]) -> Demonstrator:
  """K >= 2 demonstrators of one architecture as one, each leaf stacked on a leading axis [K]."""
  if len(demonstrators) < 2:
    raise ValueError(f"an ensemble needs 2 demonstrators or more, got {len(demonstrators)}")
  return jax.tree.map(lambda *leaves: jnp.stack([jnp.asarray(x) for x in leaves]),
                      *demonstrators)


class FormState(NamedTuple):
  demonstrator: Demonstrator  # constant through the run
  imitator: em.EffectModelState
  reward: normalizer.NormalizerState  # EMA mean and variance of the raw reward, [1]


class FormReward:
  """The reward source of `--method form` (interface: mjx_form.rl.reward_sources)."""

  name = "form"
  needs_task_reward = False
  export_file = "imitator.npz"  # `export`'s, beside each member's policy.npz
  # may differ between a population's members
  variable_settings = ("standardise_reward", "reward_clip", "ensemble_log_pd")

  def __init__(self, config: em.EffectModelConfig,
               demonstrator: Demonstrator | Sequence[Demonstrator],
               demonstrator_sha256: str | Sequence[str] = "", standardise_reward: bool = False,
               reward_clip: float = 0.0, member_demonstrators: bool = False,
               ensemble_log_pd: str = "mixture"):
    """`demonstrator`: one, or a sequence of them (an ensemble where there are 2 or more: their
    mixture, or see `ensemble_log_pd`); `demonstrator_sha256` identifies the demonstrator file
    (an ensemble's: its files' sorted and joined by '+'; kept with checkpoints, so a run resumes
    only with the same ones); `standardise_reward`, `reward_clip` (in running standard
    deviations, 0: off): see the module docstring. `member_demonstrators`: the sequence gives a population's members one
    each, in order (2 or more; `demonstrator_sha256` then one checksum per member).
    `ensemble_log_pd`: an ensemble's log pD, "mixture" (their mixture's) or "mean" (the mean
    of their log pD; see the module docstring)."""
    config.check()
    grid.check_value("reward_clip", reward_clip)
    models = [demonstrator] if isinstance(demonstrator, Demonstrator) else list(demonstrator)
    if not models or not all(isinstance(m, Demonstrator) for m in models):
      raise TypeError(f"FormReward takes a Demonstrator or a list of them, got {demonstrator!r}")
    self.per_member = len(models) if member_demonstrators else 0  # 0: members share them
    if member_demonstrators and (len(models) < 2 or isinstance(demonstrator_sha256, str)
                                 or len(demonstrator_sha256) != len(models)):
      raise ValueError("demonstrators per member need 2 or more, and one sha256 each; got "
                       f"{len(models)} and {demonstrator_sha256!r}")
    self.ensemble = len(models) if len(models) > 1 and not self.per_member else 0  # 0: none
    self._check_ensemble_log_pd(ensemble_log_pd)
    self.ensemble_log_pd = ensemble_log_pd  # (a population member's: maybe its traced index)
    demonstrator = stack(models) if len(models) > 1 else models[0]  # (refuses other shapes)
    self.config = config
    self.standardise_reward = bool(standardise_reward)
    self.reward_clip = float(reward_clip)
    self.demonstrator = demonstrator  # an ensemble's or the members' leaves [K, ...]
    self.demonstrator_sha256 = (tuple(demonstrator_sha256) if self.per_member
                                else demonstrator_sha256)
    self.member_index = None  # `as_member(i)`: whose records these settings describe
    self.observation_size = int(demonstrator.normalizer.mean.shape[-1])
    self.model = em.make_model(config, self.observation_size)

  def specialise(self, values: dict) -> "FormReward":
    """This source with some `variable_settings` replaced (Python values, or a population
    member's traced ones)."""
    unknown = set(values) - set(self.variable_settings)
    if unknown:
      raise ValueError(f"FORM settings {sorted(unknown)} cannot differ between members")
    if isinstance(values.get("ensemble_log_pd"), str):  # (a traced one is an index, checked)
      self._check_ensemble_log_pd(values["ensemble_log_pd"])
    source = copy.copy(self)
    for name, value in values.items():
      setattr(source, name, value)
    return source

  def _check_ensemble_log_pd(self, value: str) -> None:
    if value not in ENSEMBLE_LOG_PD:
      raise ValueError(f"ensemble_log_pd must be one of {ENSEMBLE_LOG_PD}, got {value!r}")
    if value != "mixture" and not self.ensemble:
      raise ValueError(f"ensemble_log_pd {value!r} needs an ensemble of 2 demonstrators or "
                       "more shared by the members, got "
                       + (f"{self.per_member} per member" if self.per_member else "one"))

  def as_member(self, i: int) -> "FormReward":
    """The source as member i of a population describes it (with demonstrators per member:
    its own demonstrator's sha256; else this source)."""
    if not self.per_member:
      return self
    if not 0 <= i < self.per_member:
      raise IndexError(f"member {i} of {self.per_member} with demonstrators per member")
    source = copy.copy(self)
    source.member_index = i
    return source

  def init(self, key: jax.Array, observation_size: int, action_size: int) -> FormState:
    del action_size
    if observation_size != self.observation_size:
      raise ValueError(f"the demonstrator models {self.observation_size}-dimensional "
                       f"observations, the task has {observation_size}")
    demonstrator = jax.tree.map(jnp.asarray, self.demonstrator)
    if self.per_member:  # the first member's, until `member_states`
      demonstrator = jax.tree.map(lambda x: x[0], demonstrator)
    return FormState(demonstrator, em.init(self.model, self.config, key), normalizer.init(1))

  def member_states(self, states: FormState, members: int) -> FormState:
    """A population's source states [P, ...] (from `init`, vmapped) with each member's own
    demonstrator (unchanged where the members share them)."""
    if not self.per_member:
      return states
    if members != self.per_member:
      raise ValueError(f"{self.per_member} demonstrators per member for a population of "
                       f"{members} members")
    return states._replace(demonstrator=jax.tree.map(jnp.asarray, self.demonstrator))

  def update(self, state: FormState, batch: dict, key: jax.Array) -> tuple[FormState, dict]:
    """One imitator step on the batch, then the batch's rewards (under the new imitator) are
    folded into the reward statistics."""
    imitator, metrics = em.update(self.model, self.config, state.imitator,
                                  batch["observation"], batch["discount"], key)
    metrics = {f"imitator_{k}": v for k, v in metrics.items()}
    state = state._replace(imitator=imitator)
    raw, valid = self.raw_rewards(state, batch)
    folded = jnp.where(state.reward.count > 0, self.clip_tail(state.reward, raw), raw)
    reward = normalizer.update(state.reward, folded[..., None], self.config.normalizer_decay,
                               mask=valid)
    return state._replace(reward=reward), metrics

  def export(self, state: FormState, path: str, info: dict) -> None:
    """Writes one member's imitator model (`state`: that member's, no member axis) as an
    effect-model file (mjx_form.files.effect_models), so that what a run's reward subtracted
    at its end can be read after the run, whose checkpoints may not come back from the GPU.
    `info`: task, observation_size, observation_layout, and env_steps and policy_file (the
    behaviour it modelled); the file's `imitator` entry (those two and the running mean and sd
    of the raw reward) makes a run refuse it as a demonstrator (mjx_form.imitation.pipeline)."""
    params, norm, steps, reward = jax.device_get((state.imitator.params,
                                                  state.imitator.normalizer,
                                                  state.imitator.steps, state.reward))
    metadata = {"task": info["task"], "observation_size": info["observation_size"],
                "observation_layout": info["observation_layout"], "distractors": None,
                "config": self.config.to_dict(),
                "training": {"steps": int(steps), "online": True},
                "demonstrations": {"episodes": None, "source": "the run's own replay"},
                "imitator": {"env_steps": info["env_steps"], "policy_file": info["policy_file"],
                             "reward_mean": float(reward.mean[0]),
                             "reward_sd": float(np.sqrt(reward.var[0]))}}
    effect_models.save_effect_model(path, params, norm.mean, norm.var, metadata, overwrite=True)

  def settings(self) -> dict:
    if not self.per_member:
      demonstrators = {"demonstrator_sha256": self.demonstrator_sha256,
                       **({"demonstrators": self.ensemble} if self.ensemble else {}),
                       # (only where not the mixture: earlier runs' settings stay as they were)
                       **({"ensemble_log_pd": self.ensemble_log_pd}
                          if self.ensemble_log_pd != "mixture" else {})}
    elif self.member_index is None:  # the run's: every member's
      demonstrators = {"member_demonstrators": list(self.demonstrator_sha256)}
    else:  # member i's records: its own, and that the members had their own
      demonstrators = {"demonstrator_sha256": self.demonstrator_sha256[self.member_index],
                       "demonstrator_per_member": True}
    return {"effect_model": self.config.to_dict(), **demonstrators,
            "standardise_reward": self.standardise_reward, "reward_clip": self.reward_clip}

  def clip_tail(self, stats: normalizer.NormalizerState, raw: jax.Array) -> jax.Array:
    """`raw` rewards clipped to `reward_clip` sd of `stats` around its mean (unchanged at 0)."""
    return jnp.where(self.reward_clip > 0, jnp.clip(raw, *self._bounds(stats)), raw)

  def clipped(self, stats: normalizer.NormalizerState, raw: jax.Array) -> jax.Array:
    """Where `clip_tail` bounds `raw` (bool, raw's shape; False everywhere at 0)."""
    low, high = self._bounds(stats)
    return (self.reward_clip > 0) & ((raw < low) | (raw > high))

  def _bounds(self, stats: normalizer.NormalizerState) -> tuple[jax.Array, jax.Array]:
    width = self.reward_clip * jnp.sqrt(stats.var[0])
    return stats.mean[0] - width, stats.mean[0] + width

  def log_probs(self, state: FormState, observation: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Raw-space log pD and log pI of each transition of observation [B, T+1, D]: [B, T] each."""
    x, x_next = observation[:, :-1], observation[:, 1:]
    demo, imitator = state.demonstrator, state.imitator
    log_d_of = lambda d: em.transition_log_prob(self.model, d.params, d.normalizer, x, x_next)
    log_d = self._ensemble_log_prob(jax.vmap(log_d_of)(demo)) if self.ensemble else log_d_of(demo)
    log_i = em.transition_log_prob(self.model, imitator.params, imitator.normalizer, x, x_next)
    return log_d, log_i

  def _ensemble_log_prob(self, each: jax.Array) -> jax.Array:
    """An ensemble's log pD from its models' own, each [K, ...]: their mixture's (the mean of
    their densities) or the mean of their log pD, as `ensemble_log_pd` says (a population
    member's traced index into ENSEMBLE_LOG_PD: both computed, its own kept)."""
    mixture = jax.nn.logsumexp(each, axis=0) - math.log(self.ensemble)
    mean = jnp.mean(each, axis=0)
    how = self.ensemble_log_pd
    if isinstance(how, str):
      return mean if how == "mean" else mixture
    return jnp.where(how == ENSEMBLE_LOG_PD.index("mean"), mean, mixture)

  def evaluation_log_prob(self, state: FormState, x: jax.Array, x_next: jax.Array) -> jax.Array:
    """log pD(x_next | x) of evaluation transitions, x and x_next [N, D] raw: [N]. Their mean
    over an episode measures the imitation without the task reward. (`log_probs`' log pI,
    unused here, is dropped by the compiler.)"""
    return self.log_probs(state, jnp.stack([x, x_next], axis=1))[0][:, 0]

  def raw_rewards(self, state: FormState, batch: dict) -> tuple[jax.Array, jax.Array]:
    """log pD - log pI of each transition [B, T], and where it is defined (successor stored)."""
    log_d, log_i = self.log_probs(state, batch["observation"])
    return log_d - log_i, batch["discount"] > 0

  def fresh_metrics(self, state: FormState, unrolls: dict) -> dict:
    """Both models' mean log-likelihood of one iteration's new transitions (`unrolls` as
    collected: observation [N, T+1, D], discount [N, T]), under the imitator model from before
    it trained on them. The batches' `imitator_batch_log_prob` is over the replay, older
    behaviour included, which the imitator model trains on: where `imitator_fresh_log_prob`
    falls below it, the imitator model lags the policy (its replay staleness), and the reward
    of what the policy does now is overestimated by the difference."""
    log_d, log_i = self.log_probs(state, unrolls["observation"])
    mean = lambda v: _valid_mean(v, unrolls["discount"] > 0)
    return {"demonstrator_fresh_log_prob": mean(log_d), "imitator_fresh_log_prob": mean(log_i),
            "form_reward_fresh": mean(log_d - log_i)}

  def relabel(self, state: FormState, batch: dict) -> tuple[jax.Array, dict]:
    log_d, log_i = self.log_probs(state, batch["observation"])
    raw, valid = log_d - log_i, batch["discount"] > 0
    bounded = self.clip_tail(state.reward, raw)
    given = jnp.where(self.standardise_reward,
                      normalizer.normalize(state.reward, bounded[..., None])[..., 0], bounded)
    rewards = jnp.where(valid, given, 0.0)
    mean = lambda v: _valid_mean(v, valid)
    metrics = {"form_reward": mean(raw), "demonstrator_log_prob": mean(log_d),
               "imitator_batch_log_prob": mean(log_i),
               "form_reward_std": jnp.sqrt(state.reward.var[0]),
               # share of the batch's transitions whose reward the clip bounded (0 when off)
               "form_reward_clipped": mean(self.clipped(state.reward, raw).astype(jnp.float32))}
    return rewards, metrics


def _valid_mean(values: jax.Array, valid: jax.Array) -> jax.Array:
  """The mean of `values` where `valid` (0 where none is)."""
  return jnp.sum(jnp.where(valid, values, 0.0)) / jnp.maximum(jnp.sum(valid), 1)
