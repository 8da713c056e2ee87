"""BC's source: the policy clones the expert's actions on the demonstrations' observations.

A cloning source (mjx_form.rl.reward_sources): instead of rewards for MPO it gives the learner
pairs (x, a) to fit the policy to (`policy_targets`, mjx_form.rl.cloning), drawn
uniformly from the demonstrations' K x T transitions, observation x_t with the action a_t the
expert took there. BC reads the expert's actions, so, unlike the imitation from observations
methods, it is not comparable with them (the paper includes it to calibrate the tasks'
difficulty). The environments still run: they give the evaluation returns and nothing else
(no reward is stored, none is read).

The demonstrations are the source's `data`, as GAIfO's: put on the devices once and passed into
each compiled iteration, not compiled in and not in the checkpointed state.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form.imitation.draws import draw_transitions


class BehaviourCloning:
  """BC's source (interface: mjx_form.rl.reward_sources, a cloning source)."""

  name = "bc"
  needs_task_reward = False

  def __init__(self, observations: np.ndarray, actions: np.ndarray,
               demonstrations_sha256: str = ""):
    """`observations` [K, T+1, D] and `actions` [K, T, A] of K demonstrated episodes
    (actions[k, t] taken at observations[k, t]); `demonstrations_sha256` identifies their file
    (kept with checkpoints and records)."""
    obs = np.asarray(observations, np.float32)
    act = np.asarray(actions, np.float32)
    if (obs.ndim != 3 or act.ndim != 3 or obs.shape[0] != act.shape[0]
        or obs.shape[1] != act.shape[1] + 1 or act.shape[1] < 1):
      raise ValueError(f"BC needs observations [K, T+1, D] and actions [K, T, A] of the same "
                       f"episodes, got {obs.shape} and {act.shape}")
    if not (np.all(np.isfinite(obs)) and np.all(np.isfinite(act))):
      raise ValueError("BC's demonstrations must be finite")
    self.observations, self.actions = obs, act
    self.demonstrations_sha256 = demonstrations_sha256
    self.bound = None  # the data as the compiled iteration passes it (`with_data`)

  def data(self) -> dict:
    """The constant arrays the source reads: the demonstrations' observations and actions."""
    return {"observations": self.observations, "actions": self.actions}

  def with_data(self, data: dict) -> "BehaviourCloning":
    source = copy.copy(self)
    source.bound = data
    return source

  def _data(self) -> dict:
    return self.bound if self.bound is not None else jax.tree.map(jnp.asarray, self.data())

  def init(self, key: jax.Array, observation_size: int, action_size: int) -> dict:
    del key
    if (observation_size, action_size) != (self.observations.shape[-1],
                                           self.actions.shape[-1]):
      raise ValueError(f"the demonstrations have {self.observations.shape[-1]}-dimensional "
                       f"observations and {self.actions.shape[-1]}-dimensional actions, the "
                       f"task {observation_size} and {action_size}")
    return {}

  def update(self, state: dict, batch: dict, key: jax.Array) -> tuple[dict, dict]:
    del batch, key
    return state, {}

  def policy_targets(self, state: dict, key: jax.Array, n: int
                     ) -> tuple[jax.Array, jax.Array, dict]:
    """n pairs to clone, drawn uniformly from the demonstrations' transitions: raw
    observations [n, D], the expert's actions [n, A], and metrics (none)."""
    del state
    data = self._data()
    k, t = draw_transitions(data["actions"].shape[1], data["actions"].shape[0], n, key)
    return data["observations"][k, t], data["actions"][k, t], {}

  def settings(self) -> dict:
    return {"demonstrations_sha256": self.demonstrations_sha256,
            "demonstration_episodes": int(self.observations.shape[0])}
