"""The MPO networks: shapes, the critic's one-encoding-per-state broadcast, the policy heads."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_form.rl.networks import Critic, make_networks, policy_head


def test_critic_equals_dense_layers_on_the_concatenation():
  """The split first layer has nn.Dense's parameters (names, shapes, initial values) and
  computes what nn.Dense on the concatenation computes, for one or N actions per state."""
  networks = make_networks(action_size=3, width=32)
  obs = jax.random.normal(jax.random.PRNGKey(0), (4, 5, 7))  # [B, T, D]
  actions = 2 * jax.random.normal(jax.random.PRNGKey(1), (6, 4, 5, 3))  # [N, B, T, A]
  params = networks.critic.init(jax.random.PRNGKey(2), obs[:1, 0], actions[0, :1, 0])
  reference = Critic(32, (32,) * 3, tiled=True)  # nn.Dense on the tiled concatenation
  ref_params = reference.init(jax.random.PRNGKey(2), obs[:1, 0], actions[0, :1, 0])
  assert jax.tree.structure(params) == jax.tree.structure(ref_params)
  for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(ref_params)):
    np.testing.assert_array_equal(a, b)
  # Trained-looking parameters: a nonzero first-layer bias, so its single addition is checked.
  params = jax.tree.map(lambda p: p + 0.1 * jax.random.normal(jax.random.PRNGKey(3), p.shape),
                        params)
  for o, a in ((obs, actions), (obs, actions[0])):
    np.testing.assert_allclose(networks.critic.apply(params, o, a), reference.apply(params, o, a),
                               rtol=1e-5, atol=1e-5)


def test_critic_broadcasts_one_state_over_sampled_actions():
  networks = make_networks(action_size=3, width=32)
  obs = jax.random.normal(jax.random.PRNGKey(0), (4, 5, 7))  # [B, T, D]
  actions = jax.random.normal(jax.random.PRNGKey(1), (6, 4, 5, 3))  # [N, B, T, A]
  params = networks.critic.init(jax.random.PRNGKey(2), obs[:1, 0], actions[0, :1, 0])
  q = networks.critic.apply(params, obs, actions)
  q_tiled = networks.critic.apply(params, jnp.broadcast_to(obs, (6, 4, 5, 7)), actions)
  assert q.shape == (6, 4, 5)
  np.testing.assert_allclose(q, q_tiled, rtol=1e-6, atol=1e-6)
  # Each sampled action is scored against its own state, not against another one.
  q_single = networks.critic.apply(params, obs[2, 3], actions[1, 2, 3])
  np.testing.assert_allclose(q[1, 2, 3], q_single, rtol=1e-6, atol=1e-6)
  assert not np.allclose(q[1, 2, 3], q[1, 2, 4])


def test_policy_shapes_and_positive_scale():
  networks = make_networks(action_size=3, width=32)
  obs = jax.random.normal(jax.random.PRNGKey(0), (4, 7))
  params = networks.policy.init(jax.random.PRNGKey(1), obs)
  pi = networks.policy.apply(params, obs)
  assert pi.mean.shape == (4, 3) and pi.scale.shape == (4, 3)
  assert bool(jnp.all(pi.scale > 0))


def test_acme_head_bounds_the_mean_and_floors_the_scale():
  """The acme head on the same parameters as the paper's: mean tanh(paper mean), scale
  softplus(raw) * 0.7 / ln 2 + 0.3 (Acme's MultivariateNormalDiagHead), where the paper's scale
  is softplus(raw) + 1e-4; so the mean stays in (-1, 1) and the scale at 0.3 or more."""
  obs = 3 * jax.random.normal(jax.random.PRNGKey(0), (64, 7))
  paper, acme = (make_networks(3, 32, head).policy for head in ("paper", "acme"))
  params = paper.init(jax.random.PRNGKey(1), obs)
  # Trained-looking outputs: last-layer weights far from their 1e-4 initial scale.
  params = jax.tree.map(lambda p: p + jax.random.normal(jax.random.PRNGKey(2), p.shape), params)
  ref, pi = paper.apply(params, obs), acme.apply(params, obs)
  softplus = np.asarray(ref.scale, np.float64) - 1e-4
  np.testing.assert_allclose(pi.mean, np.tanh(np.asarray(ref.mean, np.float64)), rtol=1e-5,
                             atol=1e-6)
  np.testing.assert_allclose(pi.scale, softplus * 0.7 / np.log(2.0) + 0.3, rtol=1e-5)
  assert np.abs(ref.mean).max() > 1.5  # the paper's mean leaves the bounds here ...
  assert np.abs(pi.mean).max() <= 1.0 and pi.scale.min() >= 0.3  # ... the acme head's cannot
  # A zero last layer: mean 0, scale init_scale + min_scale = 1.0.
  zero = jax.tree.map(jnp.zeros_like, params["params"]["Dense_0"])
  pi0 = acme.apply({"params": {**params["params"], "Dense_0": zero}}, obs)
  np.testing.assert_allclose(pi0.mean, 0.0)
  np.testing.assert_allclose(pi0.scale, 1.0, rtol=1e-6)


def test_unknown_policy_head_is_refused_by_name():
  with pytest.raises(ValueError, match="unknown policy head 'tanh'.*paper, acme"):
    policy_head("tanh")
