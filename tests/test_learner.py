"""The learner's losses: what the critic sees of an action (`LearnerConfig.clip_critic_actions`)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_form.rl import learner
from mjx_form.rl.networks import make_networks

B, T, D, A = 3, 5, 4, 2


def _losses(clip: bool, actions: jax.Array) -> dict:
  """Loss metrics of one batch; retrace_lambda 0, so the Retrace targets (r + gamma v) do not
  depend on the taken actions' importance ratios, only the critic's values of them do."""
  config = learner.LearnerConfig(num_action_samples=4, retrace_lambda=0.0,
                                 clip_critic_actions=clip)
  networks = make_networks(A, width=16)
  state = learner.init(networks, config, jax.random.PRNGKey(0), D, A)
  keys = jax.random.split(jax.random.PRNGKey(1), 3)
  obs = jax.random.normal(keys[0], (B, T + 1, D))
  batch = {"action": actions, "behaviour_log_prob": jnp.zeros((B, T)),
           "discount": jnp.ones((B, T))}
  rewards = jax.random.normal(keys[1], (B, T))
  online = (state.policy, state.critic, state.duals)
  _, metrics = learner.losses(networks, config, online, state, obs, batch, rewards, keys[2])
  return metrics


@pytest.mark.parametrize("clip", [False, True])
def test_critic_sees_clipped_actions_only_when_asked(clip):
  """Taken actions that the environment applies alike (1.5 and 3, both clipped to 1) get the
  same value from a clipping critic, and different values from the paper's critic (tanh of
  the unclipped action)."""
  inside = jax.random.uniform(jax.random.PRNGKey(2), (B, T, A), minval=-0.9, maxval=0.9)
  near = inside.at[..., 0].set(1.5)
  far = inside.at[..., 0].set(3.0)
  a, b = _losses(clip, near), _losses(clip, far)
  for name in ("q_online", "critic_loss"):
    if clip:
      np.testing.assert_allclose(a[name], b[name], rtol=1e-6)
    else:
      assert abs(float(a[name]) - float(b[name])) > 1e-6, name
  # Inside the bounds clipping changes nothing.
  np.testing.assert_allclose(_losses(clip, inside)["q_online"],
                             _losses(not clip, inside)["q_online"], rtol=1e-6)


def test_clip_setting_may_be_a_traced_member_value():
  """A population member's value arrives as a traced bool inside the vmapped update."""
  actions = jnp.full((B, T, A), 2.0)
  config = learner.LearnerConfig(num_action_samples=4, retrace_lambda=0.0)
  networks = make_networks(A, width=16)
  state = learner.init(networks, config, jax.random.PRNGKey(0), D, A)
  obs = jnp.ones((B, T + 1, D))
  batch = {"action": actions, "behaviour_log_prob": jnp.zeros((B, T)),
           "discount": jnp.ones((B, T))}

  def q(flag):
    member = dataclasses.replace(config, clip_critic_actions=flag)
    online = (state.policy, state.critic, state.duals)
    return learner.losses(networks, member, online, state, obs, batch, jnp.zeros((B, T)),
                          jax.random.PRNGKey(3))[1]["q_online"]

  traced = jax.vmap(q)(jnp.array([False, True]))
  np.testing.assert_allclose(traced, [q(False), q(True)], rtol=1e-6)
  assert abs(float(traced[0] - traced[1])) > 1e-6
