"""BCO: the inverse model's likelihood against scipy and its training on known dynamics, the
source's labels of the demonstrations, and BCO in the compiled loop (reacher_easy, small sizes,
over the 2 forced host devices), which never stores the task reward."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from mjx_form import mesh as mesh_lib
from mjx_form.imitation import inverse_model as im
from mjx_form.imitation.bco import BcoSource
from mjx_form.rl.learner import LearnerConfig
from mjx_form.rl.train import TrainConfig, Trainer
from test_form import _iterate

SMALL = im.InverseModelConfig(width=32, learning_rate=3e-3)
BOUNDS = (np.full(2, -1.0), np.full(2, 1.0))


def test_loss_is_the_gaussian_negative_log_likelihood_of_the_valid_rows():
  model = im.InverseModel(2, 16)
  params = model.init(jax.random.PRNGKey(0), jnp.zeros((1, 6)))
  rng = np.random.default_rng(0)
  pair = jnp.asarray(rng.normal(size=(9, 6)), jnp.float32)
  actions = jnp.asarray(rng.normal(size=(9, 2)), jnp.float32)
  valid = jnp.asarray([1, 1, 0, 1, 1, 1, 0, 1, 1], bool)
  loss, metrics = im.loss(model, params, pair, actions, valid)
  dist = model.apply(params, pair)
  log_prob = stats.norm.logpdf(np.asarray(actions, np.float64), np.asarray(dist.mean, np.float64),
                               np.asarray(dist.scale, np.float64)).sum(-1)
  keep = np.asarray(valid)
  np.testing.assert_allclose(float(loss), -log_prob[keep].mean(), rtol=1e-5)
  np.testing.assert_allclose(float(metrics["action_error"]), np.mean(
      (np.asarray(dist.mean) - np.asarray(actions))[keep] ** 2), rtol=1e-5)


def test_training_recovers_the_action_of_known_dynamics():
  """x' = x + B a: the model learns a from (x, x') on valid rows alone (the invalid rows'
  actions and observations are garbage) and its standardisation follows the valid rows'
  observations."""
  rng = np.random.default_rng(1)
  b = rng.normal(size=(2, 4)).astype(np.float32)
  state = im.init(SMALL, 4, 2, jax.random.PRNGKey(1))
  step = jax.jit(lambda s, x, y, a, v: im.update(SMALL, s, x, y, a, v))
  errors = []
  for i in range(300):
    x = rng.normal(size=(64, 4)).astype(np.float32) * 2 + 1
    a = rng.uniform(-1, 1, size=(64, 2)).astype(np.float32)
    valid = rng.uniform(size=64) > 0.25
    a_seen = np.where(valid[:, None], a, 50.0).astype(np.float32)
    x_seen = np.where(valid[:, None], x, 100.0).astype(np.float32)
    state, metrics = step(state, x_seen, x_seen + a @ b, a_seen, valid)
    errors.append(float(metrics["action_error"]))
  x = rng.normal(size=(256, 4)).astype(np.float32) * 2 + 1
  a = rng.uniform(-1, 1, size=(256, 2)).astype(np.float32)
  predicted = np.asarray(im.predict(SMALL, state, x, x + a @ b, 2))
  assert np.mean((predicted - a) ** 2) < 0.02, (errors[0], errors[-1])
  assert int(state.steps) == 300
  assert np.all(np.abs(np.asarray(state.normalizer.mean) - 1.0) < 0.5)
  assert np.all(np.abs(np.sqrt(np.asarray(state.normalizer.var)) - 2.0) < 0.5)


def test_source_clips_the_imitators_actions_and_labels_demonstrated_transitions():
  """The inverse model trains on the batch's actions clipped to the bounds, on transitions
  with a successor; the policy's targets are demonstrated x_t with the model's action for
  x_t -> x_{t+1}."""
  rng = np.random.default_rng(2)
  demos = rng.normal(size=(3, 8, 4)).astype(np.float32)
  source = BcoSource(SMALL, demos, (np.array([-1.0, -0.5]), np.array([1.0, 0.8])), "sha")
  state = source.init(jax.random.PRNGKey(0), 4, 2)
  obs = jnp.asarray(rng.normal(size=(2, 6, 4)), jnp.float32)
  action = jnp.asarray(rng.normal(size=(2, 5, 2)) * 3, jnp.float32)
  discount = jnp.ones((2, 5)).at[0, 3].set(0.0)
  new, metrics = source.update(state, {"observation": obs, "action": action,
                                       "discount": discount}, jax.random.PRNGKey(1))
  clipped = np.clip(np.asarray(action), [-1.0, -0.5], [1.0, 0.8]).reshape(-1, 2)
  valid = (np.asarray(discount) > 0).reshape(-1)
  expected, expected_metrics = im.update(
      SMALL, state, obs[:, :-1].reshape(-1, 4), obs[:, 1:].reshape(-1, 4), clipped, valid)
  for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(expected)):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)
  assert float(metrics["inverse_model_log_prob"]) == float(expected_metrics["log_prob"])
  x, labels, _ = source.policy_targets(new, jax.random.PRNGKey(3), 500)
  x, labels = np.asarray(x), np.asarray(labels)
  flat = demos[:, :-1].reshape(-1, 4)
  rows = [np.flatnonzero(np.all(flat == row, axis=1)) for row in x]
  assert all(len(r) == 1 for r in rows)  # every x_t is a demonstrated one, never a last frame
  k, t = np.divmod(np.concatenate(rows), 7)
  np.testing.assert_allclose(labels, np.asarray(im.predict(SMALL, new, demos[k, t],
                                                           demos[k, t + 1], 2)), rtol=1e-5)
  assert len(set(np.concatenate(rows))) == 21  # all 3 x 7 transitions drawn


def test_source_refuses_what_does_not_fit():
  with pytest.raises(ValueError, match="at least 2 frames"):
    BcoSource(SMALL, np.zeros((2, 1, 4)), BOUNDS)
  with pytest.raises(ValueError, match="finite"):
    BcoSource(SMALL, np.full((2, 3, 4), np.nan), BOUNDS)
  with pytest.raises(ValueError, match="low < high"):
    BcoSource(SMALL, np.zeros((2, 3, 4)), (np.ones(2), np.ones(2)))
  with pytest.raises(ValueError, match="inverse model width"):
    BcoSource(im.InverseModelConfig(width=0), np.zeros((2, 3, 4)), BOUNDS)
  with pytest.raises(ValueError, match="4-dimensional observations and the bounds 2 actions"):
    BcoSource(SMALL, np.zeros((2, 3, 4)), BOUNDS).init(jax.random.PRNGKey(0), 4, 3)


CONFIG = TrainConfig(task="reacher_easy", reward_source="bco", num_envs=4, unroll_length=50,
                     batch_size=4, replay_capacity=12, updates_per_iteration=2,
                     network_width=32, eval_envs=2,
                     learner=LearnerConfig(learning_rate=3e-3, num_action_samples=4))


def _bco_source():
  rng = np.random.default_rng(5)
  demos = rng.normal(size=(4, 51, 6)).astype(np.float32)  # stand in for recorded ones
  return BcoSource(SMALL, demos, BOUNDS, "sha")


def test_bco_trains_in_the_compiled_loop_without_the_task_reward():
  """BCO in the compiled loop over the mesh: the inverse model steps once per update on the
  imitator's transitions and the policy takes a cloning step per update, the critic is never
  trained, and the task reward is not even stored (test_form and test_gaifo run the loop with
  a garbage reward for the sources that relabel; a cloning source has no relabel)."""
  trainer = Trainer(CONFIG, mesh_lib.make_mesh(), _bco_source())
  fresh = trainer.init(jax.random.PRNGKey(0)[None])
  state, metrics = _iterate(trainer, 3)
  assert int(np.asarray(state.source.steps)[0]) == 6
  assert int(np.asarray(state.learner.updates)[0]) == 6
  assert np.isfinite(metrics[-1]["inverse_model_log_prob"][0])
  assert np.isfinite(metrics[-1]["bc_log_prob"][0])
  for a, b in zip(jax.tree.leaves(state.learner.critic), jax.tree.leaves(fresh.learner.critic)):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
  assert not trainer.source.needs_task_reward and "reward" not in state.replay.data
  assert set(state.replay.data) == {"observation", "action", "behaviour_log_prob", "discount"}
