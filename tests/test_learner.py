"""The learner's losses: what the critic sees of an action (`LearnerConfig.clip_critic_actions`)
and the precision of the sampled actions' Q (`sampled_q_bfloat16`, `sampled_q_float32_head`)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_form.rl import learner, normalizer
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


def test_sampled_q_in_bfloat16_is_close_to_float32_and_only_when_asked():
  """`sampled_q_bfloat16` computes the sampled actions' Q with bfloat16 parameters and inputs:
  within bfloat16's rounding of float32's Q (relative error ~1e-2 of the Q scale), not equal to
  it; off, it is the critic's float32 Q exactly. The update with it runs and stays finite."""
  networks = make_networks(A, width=64)
  params = networks.critic.init(jax.random.PRNGKey(3), jnp.zeros((1, D)), jnp.zeros((1, A)))
  # Q of a trained critic is far from 0: scale the last layer as Q ~ 50 would.
  params = jax.tree_util.tree_map_with_path(
      lambda path, x: x * 50 if "Dense_4" in jax.tree_util.keystr(path) else x, params)
  obs = jax.random.normal(jax.random.PRNGKey(4), (B, T + 1, D))
  actions = jax.random.normal(jax.random.PRNGKey(5), (4, B, T + 1, A))
  exact = networks.critic.apply(params, obs, actions)
  off = learner.sampled_q(networks, CONFIG, params, obs, actions)
  on = learner.sampled_q(networks, dataclasses.replace(CONFIG, sampled_q_bfloat16=True), params,
                         obs, actions)
  assert on.dtype == jnp.float32 and on.shape == exact.shape == (4, B, T + 1)
  np.testing.assert_array_equal(off, exact)
  scale = float(jnp.max(jnp.abs(exact)))
  error = float(jnp.max(jnp.abs(on - exact)))
  assert 0 < error < 2e-2 * scale, (error, scale)
  batch = {"observation": obs, "action": jnp.clip(actions[0, :, :-1], -1, 1),
           "behaviour_log_prob": jnp.zeros((B, T)), "discount": jnp.ones((B, T))}
  norm = normalizer.init(D)
  for head in (False, True):  # (and with the float32 head)
    config = dataclasses.replace(CONFIG, sampled_q_bfloat16=True, sampled_q_float32_head=head)
    state = learner.init(NETWORKS, config, jax.random.PRNGKey(0), D, A)
    update = jax.jit(lambda s: learner.update(NETWORKS, config, s, norm, batch,
                                              jnp.ones((B, T)), jax.random.PRNGKey(6)))
    state, metrics = update(state)
    assert all(np.isfinite(float(v)) for v in jax.tree.leaves(metrics))


@pytest.mark.slow
def test_sampled_q_float32_head_removes_bfloat16s_rounding_of_high_q():
  """At Q ~80 (humanoid_stand's late runs), bfloat16 rounds Q to a spacing of 0.5, so the
  differences between a state's sampled actions, which the E-step weighs, are off by more than
  their spread; with `sampled_q_float32_head` (features in bfloat16, last layer in float32)
  those differences match float32's within a tenth of their spread. A member's traced flag
  computes what the Python bool does, either way, and off it is the bfloat16 Q as before."""
  networks = make_networks(A, width=64)
  params = networks.critic.init(jax.random.PRNGKey(3), jnp.zeros((1, D)), jnp.zeros((1, A)))
  params["params"][networks.critic.head_name]["bias"] = jnp.full((1,), 80.0)
  obs = jax.random.normal(jax.random.PRNGKey(4), (B, T + 1, D))
  actions = jnp.clip(jax.random.normal(jax.random.PRNGKey(5), (20, B, T + 1, A)), -1, 1)
  exact = networks.critic.apply(params, obs, actions)
  bf16 = dataclasses.replace(CONFIG, sampled_q_bfloat16=True)
  q = {head: learner.sampled_q(networks, dataclasses.replace(bf16, sampled_q_float32_head=head),
                               params, obs, actions) for head in (False, True)}
  centred = lambda x: x - x.mean(axis=0)
  spread = float(jnp.std(exact, axis=0).mean())
  error = {head: float(jnp.sqrt(jnp.mean(jnp.square(centred(q[head]) - centred(exact)))))
           for head in (False, True)}
  assert error[False] > spread / 2, (error, spread)  # the rounding swamps the differences
  assert error[True] < spread / 10, (error, spread)
  # the head on the float32 parameters (a bfloat16-cast head passes the bound above, not this)
  cast = lambda tree: jax.tree.map(lambda x: x.astype(jnp.bfloat16), tree)
  features = networks.critic.apply(cast(params), cast(obs), cast(actions),
                                   features_only=True).astype(np.float64)
  head = jax.tree.map(np.asarray, params["params"][networks.critic.head_name])
  np.testing.assert_allclose(q[True], (features @ head["kernel"] + head["bias"])[..., 0],
                             rtol=1e-6)
  np.testing.assert_array_equal(q[False], networks.critic.apply(
      cast(params), cast(obs), cast(actions)).astype(jnp.float32))
  # (compiled both ways: bfloat16's rounding may differ by one step between a compiled and an
  # op-by-op evaluation)
  compiled = jax.jit(lambda head: learner.sampled_q(
      networks, dataclasses.replace(bf16, sampled_q_float32_head=head), params, obs, actions),
      static_argnums=0)
  traced = jax.jit(lambda head: learner.sampled_q(
      networks, dataclasses.replace(bf16, sampled_q_float32_head=head), params, obs, actions))
  for head in (False, True):
    np.testing.assert_array_equal(traced(jnp.array(head)), compiled(head))


@pytest.mark.slow
def test_sampled_q_diagnostics_measure_the_spread_and_bfloat16s_error():
  """`sampled_q_spread` is the sd of the sampled actions' Q over the N samples, averaged over
  states (numpy's, on the Q the E-step gets); `sampled_q_bf16_error`, only with bfloat16, is
  the mean |bfloat16 - float32| of the first unroll's sampled Q, recomputed here with both
  precisions from the same sampled actions (the key the loss draws them with)."""
  config = dataclasses.replace(CONFIG, sampled_q_bfloat16=True)
  state = learner.init(NETWORKS, CONFIG, jax.random.PRNGKey(0), D, A)
  keys = jax.random.split(jax.random.PRNGKey(1), 3)
  obs = jax.random.normal(keys[0], (B, T + 1, D))
  batch = {"action": jnp.zeros((B, T, A)), "behaviour_log_prob": jnp.zeros((B, T)),
           "discount": jnp.ones((B, T))}
  online = (state.policy, state.critic, state.duals)
  metrics = {bf16: learner.losses(NETWORKS, c, online, state, obs, batch, jnp.ones((B, T)),
                                  keys[2])[1]
             for bf16, c in ((False, CONFIG), (True, config))}
  assert "sampled_q_bf16_error" not in metrics[False]
  sampled = NETWORKS.policy.apply(state.target_policy, obs).sample(
      keys[2], (CONFIG.num_action_samples,))
  q = {bf16: np.asarray(learner.sampled_q(NETWORKS, c, state.target_critic, obs, sampled))
       for bf16, c in ((False, CONFIG), (True, config))}
  for bf16 in (False, True):
    np.testing.assert_allclose(metrics[bf16]["sampled_q_spread"], q[bf16].std(axis=0).mean(),
                               rtol=1e-5)
  error = q[True][:, :1] - q[False][:, :1]
  assert np.abs(error).mean() > 0
  np.testing.assert_allclose(metrics[True]["sampled_q_bf16_error"], np.abs(error).mean(),
                             rtol=1e-5)
  centred = error - error.mean(axis=0)
  np.testing.assert_allclose(metrics[True]["sampled_q_bf16_centred_error"],
                             np.sqrt(np.mean(centred ** 2)), rtol=1e-4)


def test_sampled_all_beyond_counts_dimensions_whose_samples_all_clip_to_one_bound():
  """`sampled_all_beyond`: the share of (state, dimension) pairs whose N sampled actions all
  exceed 1 or all fall below -1 (numpy's, on the same samples); a target policy whose means sit
  at +3 and -3 in two of its dimensions has most of those pairs there, none elsewhere."""
  state = learner.init(NETWORKS, CONFIG, jax.random.PRNGKey(0), D, A)
  bias = state.target_policy["params"]["Dense_0"]["bias"]
  shifted = jax.tree.map(lambda x: x, state.target_policy)
  shifted["params"]["Dense_0"]["bias"] = bias.at[:2].set(jnp.array([3.0, -3.0]))
  state = state._replace(target_policy=shifted)
  keys = jax.random.split(jax.random.PRNGKey(1), 3)
  obs = jax.random.normal(keys[0], (B, T + 1, D))
  batch = {"action": jnp.zeros((B, T, A)), "behaviour_log_prob": jnp.zeros((B, T)),
           "discount": jnp.ones((B, T))}
  online = (state.policy, state.critic, state.duals)
  metrics = learner.losses(NETWORKS, CONFIG, online, state, obs, batch, jnp.ones((B, T)),
                           keys[2])[1]
  sampled = np.asarray(NETWORKS.policy.apply(state.target_policy, obs).sample(
      keys[2], (CONFIG.num_action_samples,)))  # [N, B, T+1, A]
  sampled = sampled[:, :, :-1]  # (the states MPO's E-step weighs, as sampled_out_of_bounds)
  beyond = (sampled > 1).all(axis=0) | (sampled < -1).all(axis=0)  # [B, T, A]
  np.testing.assert_allclose(float(metrics["sampled_all_beyond"]), beyond.mean(), rtol=1e-6)
  assert beyond[..., :2].mean() > 0.5 and not beyond[..., 2:].any()


def _updates(config: learner.LearnerConfig, n: int):
  """The states after each of n updates from one init, on random batches."""
  state = learner.init(NETWORKS, config, jax.random.PRNGKey(0), D, A)
  norm = normalizer.init(D)
  step = jax.jit(lambda s, batch, rewards, key: learner.update(NETWORKS, config, s, norm, batch,
                                                               rewards, key)[0])
  states = []
  for k in jax.random.split(jax.random.PRNGKey(3), n):
    keys = jax.random.split(k, 4)
    batch = {"observation": jax.random.normal(keys[0], (B, T + 1, D)),
             "action": jax.random.normal(keys[1], (B, T, A)),
             "behaviour_log_prob": jnp.zeros((B, T)), "discount": jnp.ones((B, T))}
    state = step(state, batch, jax.random.normal(keys[2], (B, T)), keys[3])
    states.append(state)
  return states


def test_average_policy_is_the_mean_then_an_exponential_average_and_changes_no_update():
  """`policy_average_decay` d: after update n the average is the mean of the policies of updates
  1..n while n <= 1/(1-d) (here 4), then a <- d a + (1 - d) theta_n; the online networks follow
  the same path as without the average, and without it the state keeps none."""
  d, n = 0.75, 7
  plain = _updates(CONFIG, n)
  averaging = _updates(dataclasses.replace(CONFIG, policy_average_decay=d), n)
  assert plain[0].average_policy is None
  assert learner.init(NETWORKS, dataclasses.replace(CONFIG, policy_average_decay=d),
                      jax.random.PRNGKey(0), D, A).average_policy is not None
  flat = lambda tree: np.concatenate([np.ravel(x) for x in jax.tree.leaves(tree)])
  for a, b in zip(plain, averaging):
    np.testing.assert_array_equal(flat(a.policy), flat(b.policy))
    np.testing.assert_array_equal(flat(a.critic), flat(b.critic))
  thetas = [flat(s.policy).astype(np.float64) for s in plain]
  for m in range(1, 5):  # the plain mean
    np.testing.assert_allclose(flat(averaging[m - 1].average_policy),
                               np.mean(thetas[:m], axis=0), rtol=1e-5, atol=1e-6)
  expected = np.mean(thetas[:4], axis=0)
  for m in range(5, n + 1):  # the exponential average
    expected = d * expected + (1 - d) * thetas[m - 1]
    np.testing.assert_allclose(flat(averaging[m - 1].average_policy), expected, rtol=1e-5,
                               atol=1e-6)
  assert not np.allclose(expected, thetas[-1], atol=1e-4)  # (the average is not the policy)


def test_a_member_at_decay_zero_keeps_a_copy_of_its_policy():
  """In a population where another member averages, a member at 0 (its traced value) keeps its
  policy in the average's place."""
  config = dataclasses.replace(CONFIG, policy_average_decay=0.9)
  state = learner.init(NETWORKS, config, jax.random.PRNGKey(0), D, A)
  keys = jax.random.split(jax.random.PRNGKey(5), 4)
  batch = {"observation": jax.random.normal(keys[0], (B, T + 1, D)),
           "action": jax.random.normal(keys[1], (B, T, A)),
           "behaviour_log_prob": jnp.zeros((B, T)), "discount": jnp.ones((B, T))}
  rewards = jax.random.normal(keys[2], (B, T))
  step = jax.jit(lambda s, decay: learner.update(
      NETWORKS, dataclasses.replace(config, policy_average_decay=decay), s, normalizer.init(D),
      batch, rewards, keys[3])[0])
  zero, kept = state, state
  for _ in range(3):
    zero, kept = step(zero, jnp.float32(0.0)), step(kept, jnp.float32(0.9))
  for a, p in zip(jax.tree.leaves(zero.average_policy), jax.tree.leaves(zero.policy)):
    np.testing.assert_array_equal(a, p)
  assert not all(np.allclose(a, p) for a, p in zip(jax.tree.leaves(kept.average_policy),
                                                    jax.tree.leaves(kept.policy)))
