"""The learner's losses: what the critic sees of an action (`LearnerConfig.clip_critic_actions`)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from mjx_form.rl import learner
from mjx_form.rl.networks import make_networks

B, T, D, A = 3, 5, 4, 2
CONFIG = learner.LearnerConfig(num_action_samples=4, retrace_lambda=0.0)
NETWORKS = make_networks(A, width=16)


@jax.jit
def _metrics(clip: jax.Array, actions: jax.Array) -> dict:
  """Loss metrics of one batch with `clip_critic_actions` = clip, a traced bool as a population
  member's value is. retrace_lambda 0: the Retrace targets (r + gamma v) do not depend on the
  taken actions' importance ratios, only the critic's values of them do."""
  config = dataclasses.replace(CONFIG, clip_critic_actions=clip)
  state = learner.init(NETWORKS, CONFIG, jax.random.PRNGKey(0), D, A)
  keys = jax.random.split(jax.random.PRNGKey(1), 3)
  obs = jax.random.normal(keys[0], (B, T + 1, D))
  batch = {"action": actions, "behaviour_log_prob": jnp.zeros((B, T)),
           "discount": jnp.ones((B, T))}
  rewards = jax.random.normal(keys[1], (B, T))
  online = (state.policy, state.critic, state.duals)
  return learner.losses(NETWORKS, config, online, state, obs, batch, rewards, keys[2])[1]


def test_critic_sees_clipped_actions_only_when_asked():
  """Taken actions that the environment applies alike (1.5 and 3, both clipped to 1) get the
  same value from a clipping critic, and different values from the paper's critic (tanh of
  the unclipped action); inside the bounds the two critics agree."""
  inside = jax.random.uniform(jax.random.PRNGKey(2), (B, T, A), minval=-0.9, maxval=0.9)
  near, far = inside.at[..., 0].set(1.5), inside.at[..., 0].set(3.0)
  on, off = jnp.array(True), jnp.array(False)
  for name in ("q_online", "critic_loss"):
    np.testing.assert_allclose(_metrics(on, near)[name], _metrics(on, far)[name], rtol=1e-6)
    assert abs(float(_metrics(off, near)[name] - _metrics(off, far)[name])) > 1e-6, name
  np.testing.assert_allclose(_metrics(on, inside)["q_online"], _metrics(off, inside)["q_online"],
                             rtol=1e-6)
