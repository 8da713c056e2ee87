"""Where the learner's reward comes from.

The learner never reads the task reward itself: it asks a reward source for the rewards of each
sampled batch of unrolls. The task reward (experts) is one source; FORM and the imitation
baselines are others (they train their own models from the replay and relabel). A source
declares whether the replay must keep the task reward at all: when it does not, the task reward
is never written to the replay, so no learner code can read it.

A source is an object with:
  needs_task_reward: bool
  init(key, observation_size, action_size) -> source state (a pytree, replicated)
  update(state, batch, key) -> (state, metrics): called before relabel on every learner
      update's batch, or with `TrainConfig.source_update_every` k on the first of every k
  relabel(state, batch) -> (rewards [B, T], metrics)
  settings() -> dict: what the source's results depend on beyond the TrainConfig (its model
      settings, the checksum of a demonstrator), JSON; stored with checkpoints and records
  fresh_metrics(state, unrolls) -> metrics (optional): diagnostics of each iteration's newly
      collected unrolls (same keys as a batch, [N, ...]), under the state before the
      iteration's updates; nothing in training depends on them
  member_states(states, P) -> states (optional): a population's source states [P, ...] from
      the vmapped `init` (which cannot tell the members apart), given what each member has of
      its own (FORM's demonstrators per member)
  as_member(i) -> source (optional): the source as member i's records describe it
  evaluation_log_prob(state, x, x_next) -> [N] (optional): a score of the evaluation
      episodes' transitions x -> x_next ([N, D] raw observations, the policy's mean action),
      e.g. FORM's log pD: a measure of imitation that needs no task reward; reported beside
      the evaluation return, nothing in training depends on it
  export_file: str and export(state, path, info) (optional): writes what one member's source
      learned online (`state`: that member's), e.g. FORM's imitator model, to `path` (the
      member's directory and `export_file`); the runner calls it beside each member's exported
      policy, `info` naming the task, its observations, the env steps and the policy file
  data() -> pytree of arrays, and with_data(data) -> source (optional, together): constant
      arrays the source reads while training (GAIfO's demonstrations); the Trainer puts them
      on the devices once and passes them into each compiled iteration as an argument, where
      `with_data` gives the source that reads them (not compiled in as constants, not in the
      state that checkpoints save)
  policy_targets(state, key, n) -> (observations [n, D] raw, actions [n, A], metrics)
      (optional): makes the source a cloning source (BC, BCO): the learner fits the policy to
      these pairs (mjx_form.rl.cloning) instead of MPO on rewards, and the
      observation normaliser follows these observations; it needs no `relabel`
where `batch` is a dict of unrolls: observation [B, T+1, D] (raw, not standardised), action
[B, T, A], discount [B, T], and reward [B, T] only when needs_task_reward is set.
"""

from __future__ import annotations

import jax


class TaskReward:
  """The environment's own reward (dm_control's), for experts."""

  name = "task"
  needs_task_reward = True

  def init(self, key: jax.Array, observation_size: int, action_size: int) -> dict:
    del key, observation_size, action_size
    return {}

  def update(self, state: dict, batch: dict, key: jax.Array) -> tuple[dict, dict]:
    del batch, key
    return state, {}

  def relabel(self, state: dict, batch: dict) -> tuple[jax.Array, dict]:
    del state
    return batch["reward"], {}

  def settings(self) -> dict:
    return {}


def make_reward_source(name: str):
  """The reward source called `name` that needs no more than its name ('task'). Imitation
  sources are built from their artefacts (e.g. mjx_form.imitation.form.FormReward) and passed
  to the Trainer."""
  sources = {"task": TaskReward}
  if name not in sources:
    raise ValueError(f"reward source {name!r} is not built by name (valid: "
                     f"{', '.join(sources)}); pass it to the Trainer")
  return sources[name]()
