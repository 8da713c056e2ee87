"""GAIfO's reward source (and GAIfO+GP's, VAIfO's and VAIfO+GP's: the discriminator's
gradient penalty and bottleneck): r_t = log(1 + D(x_{t+1})), D a discriminator of
the expert's observations from the imitator's (mjx_form.imitation.discriminator), trained
online by one gradient step on every learner batch against as many expert inputs drawn
uniformly from the demonstrations' transitions; rewards are relabelled with the discriminator
after its step.

The demonstrations' observations [K, T+1, D] are the source's `data` (reward_sources.py): put on
the devices once and passed into each compiled iteration (1000 humanoid episodes take 268 MB),
not compiled in and not in the checkpointed state. The imitator's side is the batch's
transitions whose successor is stored (discount > 0); the others get reward 0, as FORM's.
With `standardise_reward` the learner gets the reward standardised by its running mean and sd
over the batches so far (decay 0.99, as FORM's); the logs report the raw reward either way.

The source never sees the task reward (`needs_task_reward = False`: it is not even stored),
nor the demonstrations' actions.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form.imitation import discriminator as disc
from mjx_form.imitation.draws import draw_transitions
from mjx_form.rl import normalizer


class GaifoState(NamedTuple):
  discriminator: disc.DiscriminatorState
  reward: normalizer.NormalizerState  # EMA mean and variance of the raw reward, [1]


class GaifoReward:
  """The reward source of GAIfO; GAIfO+GP where the config's gradient penalty is > 0, VAIfO
  (+GP) where it has a bottleneck (interface: mjx_form.rl.reward_sources)."""

  needs_task_reward = False
  variable_settings = ("standardise_reward",)

  def __init__(self, config: disc.DiscriminatorConfig, expert_observations: np.ndarray,
               demonstrations_sha256: str = "", standardise_reward: bool = False):
    """`expert_observations` [K, T+1, D]: the demonstrations' observation sequences (K
    episodes of T steps); `demonstrations_sha256` identifies their file (kept with checkpoints
    and records)."""
    config.check()
    expert = np.asarray(expert_observations, np.float32)
    if expert.ndim != 3 or expert.shape[1] < config.frames or not np.all(np.isfinite(expert)):
      raise ValueError(f"expert observations must be finite sequences [K, T+1, D] of at least "
                       f"{config.frames} frames, got shape {expert.shape}")
    self.config = config
    self.name = (("vaifo" if config.kl_bound is not None else "gaifo")
                 + ("_gp" if config.gradient_penalty > 0 else ""))
    self.expert = expert
    self.demonstrations_sha256 = demonstrations_sha256
    self.standardise_reward = bool(standardise_reward)
    self.observation_size = int(expert.shape[-1])
    self.bound = None  # the data as the compiled iteration passes it (`with_data`)

  def data(self) -> dict:
    """The constant arrays the source reads: the demonstrations' observations."""
    return {"expert": self.expert}

  def with_data(self, data: dict) -> "GaifoReward":
    """This source reading `data` (`data()`'s arrays as the compiled iteration has them)."""
    source = copy.copy(self)
    source.bound = data["expert"]
    return source

  def specialise(self, values: dict) -> "GaifoReward":
    """This source with `standardise_reward` replaced (a Python value, or a population
    member's traced one)."""
    unknown = set(values) - set(self.variable_settings)
    if unknown:
      raise ValueError(f"GAIfO settings {sorted(unknown)} cannot differ between members")
    source = copy.copy(self)
    for name, value in values.items():
      setattr(source, name, value)
    return source

  def init(self, key: jax.Array, observation_size: int, action_size: int) -> GaifoState:
    del action_size
    if observation_size != self.observation_size:
      raise ValueError(f"the demonstrations have {self.observation_size}-dimensional "
                       f"observations, the task has {observation_size}")
    return GaifoState(disc.init(self.config, observation_size, key), normalizer.init(1))

  def expert_frames(self, expert: jax.Array, n: int, key: jax.Array) -> jax.Array:
    """n inputs drawn uniformly from the demonstrations' transitions: [n, frames, D] raw (the
    observation a transition leads to, after the one it starts from where frames is 2)."""
    k, t = draw_transitions(expert.shape[1] - 1, expert.shape[0], n, key)  # t: x_t -> x_{t+1}
    steps = t[:, None] + jnp.arange(2 - self.config.frames, 2)[None, :]  # [n, frames]
    return expert[k[:, None], steps]

  def imitator_frames(self, observation: jax.Array) -> jax.Array:
    """The batch's transitions as inputs, observation [B, T+1, D] -> [B*T, frames, D]."""
    nxt = observation[:, 1:]
    frames = nxt[:, :, None] if self.config.frames == 1 else jnp.stack(
        [observation[:, :-1], nxt], axis=2)
    return frames.reshape((-1,) + frames.shape[2:])

  def update(self, state: GaifoState, batch: dict, key: jax.Array) -> tuple[GaifoState, dict]:
    """One discriminator step on the batch against as many expert inputs, then the batch's
    raw rewards (under the new discriminator) are folded into the reward statistics."""
    draw_key, step_key = jax.random.split(key)
    imitator = self.imitator_frames(batch["observation"])
    valid = (batch["discount"] > 0).reshape(-1)
    demonstrations = jnp.asarray(self.expert) if self.bound is None else self.bound
    expert = self.expert_frames(demonstrations, imitator.shape[0], draw_key)
    discriminator, metrics = disc.update(self.config, state.discriminator, expert, imitator,
                                         valid, step_key)
    state = state._replace(discriminator=discriminator)
    raw, valid = self.raw_rewards(state, batch)
    reward = normalizer.update(state.reward, raw[..., None], self.config.normalizer_decay,
                               mask=valid)
    return state._replace(reward=reward), {f"discriminator_{k}": v for k, v in metrics.items()}

  def raw_rewards(self, state: GaifoState, batch: dict) -> tuple[jax.Array, jax.Array]:
    """log(1 + D) of each transition [B, T], and where it is defined (successor stored)."""
    logit = disc.logits(self.config, state.discriminator, batch["observation"])
    return disc.reward(logit), batch["discount"] > 0

  def relabel(self, state: GaifoState, batch: dict) -> tuple[jax.Array, dict]:
    raw, valid = self.raw_rewards(state, batch)
    given = jnp.where(self.standardise_reward,
                      normalizer.normalize(state.reward, raw[..., None])[..., 0], raw)
    rewards = jnp.where(valid, given, 0.0)
    count = jnp.maximum(jnp.sum(valid), 1)
    return rewards, {"gaifo_reward": jnp.sum(jnp.where(valid, raw, 0.0)) / count,
                     "gaifo_reward_std": jnp.sqrt(state.reward.var[0])}

  def settings(self) -> dict:
    return {"discriminator": self.config.to_dict(),
            "demonstrations_sha256": self.demonstrations_sha256,
            "demonstration_episodes": int(self.expert.shape[0]),
            "standardise_reward": self.standardise_reward}
