"""BCO's source: behavioural cloning from observation (Torabi et al. 2018, as the paper's
appendix runs it).

A cloning source (mjx_form.rl.reward_sources), trained online in the compiled loop: an inverse
model p(a_t | x_t, x_{t+1}) (mjx_form.imitation.inverse_model) takes one step on every learner
batch of the imitator's own transitions (the replay's: the policy's actions, as applied), and
the policy is fitted (mjx_form.rl.cloning) to the demonstrations' transitions, each labelled
with the inverse model's most likely action, drawn uniformly from the K x T of them. The
labels are the current model's at every update. BCO never reads the expert's actions nor the
task reward.

The demonstrations' observations are the source's `data`, as GAIfO's.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form.imitation import inverse_model as im
from mjx_form.imitation.draws import draw_transitions


class BcoSource:
  """BCO's source (interface: mjx_form.rl.reward_sources, a cloning source)."""

  name = "bco"
  needs_task_reward = False

  def __init__(self, config: im.InverseModelConfig, expert_observations: np.ndarray,
               action_bounds: tuple, demonstrations_sha256: str = ""):
    """`expert_observations` [K, T+1, D]: the demonstrations' observation sequences;
    `action_bounds` ([A], [A]): the task's control range (`Task.action_bounds`), which the
    imitator's actions are clipped to as the environment clips them."""
    config.check()
    obs = np.asarray(expert_observations, np.float32)
    if obs.ndim != 3 or obs.shape[1] < 2 or not np.all(np.isfinite(obs)):
      raise ValueError(f"BCO needs finite observation sequences [K, T+1, D] of at least 2 "
                       f"frames, got shape {obs.shape}")
    low, high = (np.asarray(b, np.float32) for b in action_bounds)
    if low.ndim != 1 or low.shape != high.shape or not np.all(low < high):
      raise ValueError(f"action bounds must be two [A] arrays with low < high, got {low} and "
                       f"{high}")
    self.config = config
    self.observations, self.low, self.high = obs, low, high
    self.demonstrations_sha256 = demonstrations_sha256
    self.bound = None  # the data as the compiled iteration passes it (`with_data`)

  def data(self) -> dict:
    """The constant arrays the source reads: the demonstrations' observations."""
    return {"observations": self.observations}

  def with_data(self, data: dict) -> "BcoSource":
    source = copy.copy(self)
    source.bound = data
    return source

  def init(self, key: jax.Array, observation_size: int, action_size: int) -> im.InverseModelState:
    if (observation_size, action_size) != (self.observations.shape[-1], self.low.shape[0]):
      raise ValueError(f"the demonstrations have {self.observations.shape[-1]}-dimensional "
                       f"observations and the bounds {self.low.shape[0]} actions, the task "
                       f"{observation_size} and {action_size}")
    return im.init(self.config, observation_size, action_size, key)

  def update(self, state: im.InverseModelState, batch: dict, key: jax.Array
             ) -> tuple[im.InverseModelState, dict]:
    """One inverse-model step on the batch's transitions whose successor is stored."""
    del key
    obs = batch["observation"]  # [B, T+1, D]
    flat = lambda x: x.reshape((-1,) + x.shape[2:])
    actions = jnp.clip(batch["action"], self.low, self.high)  # as the environment applied
    state, metrics = im.update(self.config, state, flat(obs[:, :-1]), flat(obs[:, 1:]),
                               flat(actions), flat(batch["discount"] > 0))
    return state, {f"inverse_model_{k}": v for k, v in metrics.items()}

  def policy_targets(self, state: im.InverseModelState, key: jax.Array, n: int
                     ) -> tuple[jax.Array, jax.Array, dict]:
    """n demonstrated transitions drawn uniformly: raw observations x_t [n, D] and the inverse
    model's most likely action for x_t -> x_{t+1} [n, A] (no gradient into the model)."""
    expert = self.bound["observations"] if self.bound is not None else jnp.asarray(
        self.observations)
    k, t = draw_transitions(expert.shape[1] - 1, expert.shape[0], n, key)
    x, x_next = expert[k, t], expert[k, t + 1]
    labels = im.predict(self.config, state, x, x_next, self.low.shape[0])
    return x, jax.lax.stop_gradient(labels), {}

  def settings(self) -> dict:
    return {"inverse_model": self.config.to_dict(),
            "demonstrations_sha256": self.demonstrations_sha256,
            "demonstration_episodes": int(self.observations.shape[0])}
