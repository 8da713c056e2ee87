"""FORM's effect model: pair alignment, the change of variables, the autoregressive term, the
objective's parts and demonstrator training, against numpy / scipy references."""

import dataclasses
import functools
import json
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from mjx_form.imitation import demonstrator, effect_model as em
from mjx_form.rl import normalizer

pytestmark = pytest.mark.xdist_group("effect_model")

CONFIG = em.EffectModelConfig(width=16, num_components=3, max_offset=4, beta_ar=0.5, l2=0.1)
D = 3


def _model_and_params(seed=0):
  model = em.make_model(CONFIG, D)
  return model, model.init(jax.random.PRNGKey(seed), jnp.zeros((1, D)))


def _norm(rng):
  return normalizer.NormalizerState(jnp.asarray(rng.normal(size=D), jnp.float32),
                                    jnp.asarray(rng.uniform(0.1, 4.0, size=D), jnp.float32),
                                    jnp.asarray(3, jnp.int32))


def _brute_force_masks(discount, max_offset):
  b, t = discount.shape
  out = np.zeros((max_offset, b, t))
  for d in range(1, max_offset + 1):
    for i in range(b):
      for s in range(t):
        out[d - 1, i, s] = s + d <= t and all(discount[i, s:s + d] > 0)
  return out


def test_offset_masks_keep_pairs_inside_one_episode():
  rng = np.random.default_rng(0)
  discount = (rng.uniform(size=(6, 12)) > 0.25).astype(np.float32)
  discount[0] = 1.0  # a whole unroll inside one episode
  masks = np.asarray(em.offset_masks(jnp.asarray(discount), 5))
  np.testing.assert_array_equal(masks, _brute_force_masks(discount, 5))
  # An unroll without episode ends: T + 1 - delta pairs at offset delta.
  np.testing.assert_array_equal(masks[:, 0].sum(-1), [12, 11, 10, 9, 8])


def test_raw_density_is_the_standardised_one_with_the_change_of_variables():
  """log p(x' | x) in raw space against scipy: the model's mixture over sigma(x'), mapped back
  through x' = mean + sqrt(var + eps) * sigma(x'), is a mixture with scaled components."""
  rng = np.random.default_rng(1)
  model, params = _model_and_params()
  norm = _norm(rng)
  x, x_next = (rng.normal(size=(5, D)).astype(np.float32) * 2 for _ in range(2))
  got = np.asarray(em.transition_log_prob(model, params, norm, x, x_next))
  mix = jax.tree.map(np.asarray, model.apply(params, em.standardise(norm, x), 1))
  std = np.sqrt(np.asarray(norm.var, np.float64) + em.NORMALIZER_EPS)
  mean = np.asarray(norm.mean, np.float64)
  weights = np.exp(mix.logits - np.logaddexp.reduce(mix.logits.astype(np.float64), -1,
                                                    keepdims=True))
  expected = [np.log(sum(weights[b, k] * np.prod(stats.norm(
      mean + std * mix.mean[b, k], std * mix.scale[b, k]).pdf(x_next[b]))
      for k in range(CONFIG.num_components))) for b in range(5)]
  np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)


def test_autoregressive_term_conditions_on_a_sample_of_the_model():
  rng = np.random.default_rng(2)
  model, params = _model_and_params()
  x = jnp.asarray(rng.normal(size=(2, 9, D)), jnp.float32)  # standardised sequences
  discount = jnp.ones((2, 8))
  key = jax.random.PRNGKey(7)
  _, metrics = em.loss(model, CONFIG, params, x, discount, key)
  sampled = model.apply(params, x[:, :-2], 1).sample(key)  # x~_{t+1} ~ p(. | x_t)
  expected = jnp.mean(model.apply(params, sampled, 1).log_prob(x[:, 2:]))
  np.testing.assert_allclose(metrics["log_prob_autoregressive"], expected, rtol=1e-6)
  teacher_forced = jnp.mean(model.apply(params, x[:, 1:-1], 1).log_prob(x[:, 2:]))
  assert abs(float(expected - teacher_forced)) > 1e-3  # the data itself is not the input
  # Another key draws another sample; the other terms do not change.
  _, other = em.loss(model, CONFIG, params, x, discount, jax.random.PRNGKey(8))
  assert other["log_prob_autoregressive"] != metrics["log_prob_autoregressive"]
  assert other["log_prob_offset1"] == metrics["log_prob_offset1"]


def test_loss_is_the_stated_objective():
  """-(mean over offsets of the masked mean log p + beta_ar * AR - l2/2 * sum kernel^2), each
  part computed here pair by pair, with an episode end inside the batch."""
  rng = np.random.default_rng(3)
  model, params = _model_and_params()
  x = jnp.asarray(rng.normal(size=(2, 8, D)), jnp.float32)
  discount = np.ones((2, 7), np.float32)
  discount[1, 3] = 0.0  # x[1, 4] starts a new episode
  key = jax.random.PRNGKey(0)
  value, metrics = em.loss(model, CONFIG, params, x, jnp.asarray(discount), key)
  per_offset = []
  for d in range(1, CONFIG.max_offset + 1):
    terms = [float(model.apply(params, x[b, t], d).log_prob(x[b, t + d]))
             for b in range(2) for t in range(8 - d) if discount[b, t:t + d].all()]
    per_offset.append(np.mean(terms))
  sampled = model.apply(params, x[:, :-2], 1).sample(key)
  ar = [float(model.apply(params, sampled[b, t], 1).log_prob(x[b, t + 2]))
        for b in range(2) for t in range(6) if discount[b, t:t + 2].all()]
  kernels = [np.sum(np.square(np.asarray(leaf)))
             for path, leaf in jax.tree_util.tree_leaves_with_path(params)
             if path[-1].key == "kernel"]
  assert len(kernels) == 4  # encoder 2, hidden, head; LayerNorm and biases not decayed
  expected = -(np.mean(per_offset) + CONFIG.beta_ar * np.mean(ar) - 0.5 * CONFIG.l2 * sum(kernels))
  np.testing.assert_allclose(value, expected, rtol=1e-5)
  np.testing.assert_allclose([metrics[f"log_prob_offset{d}"] for d in range(1, 5)], per_offset,
                             rtol=1e-5)


def test_update_standardises_then_steps():
  """One update folds the batch into the EMA statistics (a fresh model takes them exactly) and
  moves the parameters; the raw-space batch likelihood is reported."""
  rng = np.random.default_rng(4)
  model = em.make_model(CONFIG, D)
  state = em.init(model, CONFIG, jax.random.PRNGKey(0))
  obs = jnp.asarray(rng.normal(size=(4, 6, D)) * [1.0, 10.0, 0.1] + [0.0, 5.0, -2.0],
                    jnp.float32)
  update = jax.jit(functools.partial(em.update, model, CONFIG))  # (one compile, not op by op)
  new, metrics = update(state, obs, jnp.ones((4, 5)), jax.random.PRNGKey(1))
  np.testing.assert_allclose(new.normalizer.mean, np.asarray(obs).reshape(-1, D).mean(0),
                             rtol=1e-5, atol=1e-5)
  np.testing.assert_allclose(new.normalizer.var, np.asarray(obs).reshape(-1, D).var(0),
                             rtol=1e-4)
  assert int(new.steps) == 1
  assert not np.allclose(jax.tree.leaves(new.params)[0], jax.tree.leaves(state.params)[0])
  np.testing.assert_allclose(metrics["log_prob"], metrics["log_prob_offset1"]
                             + em.log_jacobian(new.normalizer), rtol=1e-6)


def test_heldout_log_likelihood_is_the_mean_over_every_pair():
  rng = np.random.default_rng(5)
  model, params = _model_and_params()
  norm = _norm(rng)
  episodes = jnp.asarray(rng.normal(size=(3, 7, D)), jnp.float32)
  got = np.asarray(demonstrator.heldout_log_likelihood(model, params, norm, episodes, chunk=2))
  for d in range(1, CONFIG.max_offset + 1):
    pairs = [float(np.asarray(model.apply(params, em.standardise(norm, episodes[e, t]), d)
                              .log_prob(em.standardise(norm, episodes[e, t + d])))
                   + em.log_jacobian(norm)) for e in range(3) for t in range(7 - d)]
    np.testing.assert_allclose(got[d - 1], np.mean(pairs), rtol=1e-5)


def test_split_keeps_held_out_episodes_apart():
  train, heldout = demonstrator.split_episodes(100, 0.05)
  assert list(heldout) == list(range(95, 100)) and list(train) == list(range(95))
  train, heldout = demonstrator.split_episodes(2, 0.05)
  assert list(train) == [0] and list(heldout) == [1]
  with pytest.raises(ValueError, match="at least 2"):
    demonstrator.DemonstratorTraining().check(1, 1000)


def test_demonstrator_learns_a_linear_system_and_keeps_its_best_step():
  """Demonstrations of x_{t+1} = A x_t + noise: the held-out likelihood at offset 1 rises far
  above the untrained model's and towards the true conditional density's."""
  rng = np.random.default_rng(6)
  a = np.array([[0.95, 0.2, 0.0], [-0.2, 0.95, 0.0], [0.0, 0.0, 0.8]])
  x = np.zeros((12, 61, D), np.float32)
  x[:, 0] = rng.normal(size=(12, D)) * 2
  for t in range(60):
    x[:, t + 1] = x[:, t] @ a.T + 0.1 * rng.normal(size=(12, D))
  config = dataclasses.replace(CONFIG, width=32, learning_rate=3e-3, l2=1e-4, beta_ar=0.01)
  training = demonstrator.DemonstratorTraining(max_steps=1500, batch_size=16, window=10,
                                               eval_every=250, patience=6, heldout_fraction=0.2)
  lines = []
  state, report = demonstrator.train(x, config, training, print_fn=lines.append)
  model = em.make_model(config, D)
  untrained = em.init(model, config, jax.random.PRNGKey(0))
  heldout = jnp.asarray(x[-report["heldout_episodes"]:])
  before = demonstrator.heldout_log_likelihood(model, untrained.params, state.normalizer,
                                               heldout)
  after = np.asarray(demonstrator.heldout_log_likelihood(model, state.params, state.normalizer,
                                                         heldout))
  true_offset1 = -D / 2 * np.log(2 * np.pi * 0.01) - D / 2  # E log N(x'; Ax, 0.01 I)
  assert after[0] > float(before[0]) + 3 and after[0] > true_offset1 - 2.5, (before, after)
  # The returned state is the best evaluation's, and the report says which one.
  best = max(report["curve"], key=lambda c: np.mean(c["heldout_log_likelihood"]))
  assert report["best_step"] == best["step"]
  np.testing.assert_allclose(report["heldout_log_likelihood"], after, atol=1e-3)
  assert report["heldout_episodes"] == 2 and report["training_episodes"] == 10
  assert any("held-out log p by offset" in line for line in lines)
  # Why it stopped is reported: patience (6 evaluations without a better mean of the last
  # `smoothing` ones) or the step limit.
  assert report["stopped_by"] == ("max_steps" if report["steps"] == 1500 else "patience")
  means = [float(np.mean(c["heldout_log_likelihood"])) for c in report["curve"]]
  if report["stopped_by"] == "patience":
    assert demonstrator.evaluations_since_best(means, training.smoothing) == 6
    assert demonstrator.evaluations_since_best(means[:-1], training.smoothing) == 5
  # A time budget stops it after the evaluation that passes it, and says so.
  lines = []
  _, report = demonstrator.train(x, config, dataclasses.replace(training, max_seconds=1e-9),
                                 print_fn=lines.append)
  assert (report["steps"], report["stopped_by"]) == (250, "max_seconds")
  assert any("out of time" in line for line in lines)


@pytest.mark.slow
def test_demonstrator_draws_side_by_side_are_the_draws_alone():
  """Draws of several seeds trained in one program: each draw's report (its curve, where and
  why it stopped, its best step) and best parameters are those of the draw trained alone, each
  stopping on its own patience (1 evaluation without a new best, unsmoothed: the draws stop
  at different steps here); repeated seeds are refused."""
  rng = np.random.default_rng(7)
  x = rng.normal(size=(6, 41, D)).astype(np.float32).cumsum(axis=1) * 0.1
  config = dataclasses.replace(CONFIG, width=16, learning_rate=3e-3)
  training = demonstrator.DemonstratorTraining(max_steps=400, batch_size=8, window=10,
                                               eval_every=25, patience=1, smoothing=1,
                                               heldout_fraction=0.2)
  together = demonstrator.train_draws(x, config, training, (0, 1), print_fn=lambda _: None)
  for seed, (state, report) in zip((0, 1), together):
    alone_state, alone = demonstrator.train(x, config, dataclasses.replace(training, seed=seed),
                                            print_fn=lambda _: None)
    assert (report["steps"], report["best_step"], report["stopped_by"]) == (
        alone["steps"], alone["best_step"], alone["stopped_by"]), (seed, report, alone)
    np.testing.assert_allclose([c["heldout_log_likelihood"] for c in report["curve"]],
                               [c["heldout_log_likelihood"] for c in alone["curve"]],
                               rtol=1e-4, atol=1e-3)
    for a, b in zip(jax.tree.leaves(state.params), jax.tree.leaves(alone_state.params)):
      np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
  assert together[0][1]["steps"] != together[1][1]["steps"]  # (each its own stop)
  assert all(r["stopped_by"] == "patience" for _, r in together)
  with pytest.raises(ValueError, match="distinct seeds"):
    demonstrator.train_draws(x, config, training, (3, 3))


def test_evaluations_since_best_smooths_the_held_out_curve():
  """Counted on the running mean of the last `smoothing` evaluations (fewer at the start):
  by hand, [1, 3, 2, 2.5, 2.2] has running means [1, 3, 2, 2.5, 2.2] (1), [1, 2, 2.5, 2.25,
  2.35] (2) and [1, 2, 2, 2.5, 2.2333] (3): last new maxima at evaluations 1, 2 and 3 (an equal
  mean is not a new one)."""
  means = [1.0, 3.0, 2.0, 2.5, 2.2]
  assert [demonstrator.evaluations_since_best(means, s) for s in (1, 2, 3)] == [3, 2, 1]
  assert demonstrator.evaluations_since_best(means[:1], 10) == 0
  # A curve rising by 0.2 per evaluation with +-1 of scatter: the single evaluations' best is
  # a lucky one for long stretches; the mean of 10 keeps finding new bests.
  rising = [0.2 * i + (1.0 if i % 7 == 0 else -1.0 if i % 7 == 3 else 0.0) for i in range(60)]
  waits = [demonstrator.evaluations_since_best(rising[:n], 1) for n in range(1, 61)]
  smoothed = [demonstrator.evaluations_since_best(rising[:n], 10) for n in range(1, 61)]
  assert max(waits) == 5 and max(smoothed[10:]) <= 1, (waits, smoothed)
  with pytest.raises(ValueError, match="smoothing"):
    demonstrator.DemonstratorTraining(smoothing=0).check(4, 100)


# --- turn invariance ----------------------------------------------------------------------

TURNING = dataclasses.replace(CONFIG, period=(2 * np.pi, 0.0, 0.0))  # feature 0 is an angle


def _turned(x, k):
  """x [..., D] with feature 0 moved by k full turns (k broadcast over the leading axes)."""
  return np.asarray(x, np.float64) + np.stack(
      [2 * np.pi * np.asarray(k, np.float64), np.zeros_like(k, np.float64),
       np.zeros_like(k, np.float64)], -1)


def test_a_turn_invariant_density_moves_each_pair_by_x_ts_turns():
  """log p(x' | x) of a turn-invariant model is the plain model's (same parameters) at the pair
  moved by the whole turns that bring x's angle into [-pi, pi), computed here with numpy; so
  full turns of both change nothing, while a shift of a non-periodic feature does."""
  rng = np.random.default_rng(6)
  model, params = _model_and_params()
  turning = em.make_model(TURNING, D)
  norm = _norm(rng)
  x = rng.normal(size=(6, D)) * 3
  x[:, 0] = rng.uniform(-12, 12, size=6)  # several turns either way
  x_next = x + rng.normal(size=(6, D)) * 0.3
  k = np.floor((x[:, 0] + np.pi) / (2 * np.pi))
  assert len(set(k)) > 2
  f32 = lambda a: jnp.asarray(a, jnp.float32)
  got = np.asarray(em.transition_log_prob(turning, params, norm, f32(x), f32(x_next)))
  expected = np.asarray(em.transition_log_prob(model, params, norm, f32(_turned(x, -k)),
                                               f32(_turned(x_next, -k))))
  np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-3)
  turns = rng.integers(-3, 4, size=6)
  moved = np.asarray(em.transition_log_prob(turning, params, norm, f32(_turned(x, turns)),
                                            f32(_turned(x_next, turns))))
  np.testing.assert_allclose(moved, got, rtol=1e-4, atol=1e-3)
  plain = np.asarray(em.transition_log_prob(model, params, norm, f32(_turned(x, turns)),
                                            f32(_turned(x_next, turns))))
  assert np.abs(plain - np.asarray(em.transition_log_prob(model, params, norm, f32(x),
                                                          f32(x_next)))).max() > 0.1
  other = x + [0.0, 2 * np.pi, 0.0]
  assert np.abs(np.asarray(em.transition_log_prob(turning, params, norm, f32(other),
                                                  f32(x_next + [0.0, 2 * np.pi, 0.0])))
                - got).max() > 0.1


def test_turn_invariant_held_out_likelihood_moves_every_pair_by_its_first_observation():
  rng = np.random.default_rng(7)
  model, params = _model_and_params()
  turning = em.make_model(TURNING, D)
  norm = _norm(rng)
  episodes = rng.normal(size=(3, 7, D)) * 0.5
  episodes[..., 0] = np.cumsum(rng.normal(size=(3, 7)) * 2.0, axis=1)  # wanders past pi
  got = np.asarray(demonstrator.heldout_log_likelihood(
      turning, params, norm, jnp.asarray(episodes, jnp.float32), chunk=2))
  for d in range(1, CONFIG.max_offset + 1):
    pairs = []
    for e in range(3):
      for t in range(7 - d):
        k = np.floor((episodes[e, t, 0] + np.pi) / (2 * np.pi))
        pairs.append(float(em.transition_log_prob(
            model, params, norm, jnp.asarray(_turned(episodes[e, t], -k), jnp.float32),
            jnp.asarray(_turned(episodes[e, t + d], -k), jnp.float32)))
            if d == 1 else float(model.apply(params, em.standardise(
                norm, jnp.asarray(_turned(episodes[e, t], -k), jnp.float32)), d).log_prob(
                em.standardise(norm, jnp.asarray(_turned(episodes[e, t + d], -k),
                                                 jnp.float32))) + em.log_jacobian(norm)))
    np.testing.assert_allclose(got[d - 1], np.mean(pairs), rtol=1e-4)


@pytest.mark.parametrize("increments", [False, True])
def test_a_turn_invariant_update_does_not_see_full_turns(increments):
  """The same sequences, each moved by its own number of full turns: the same standardisation
  (taken over wrapped angles), objective (the autoregressive term included) and step; for a
  model of the angle's values and of its changes alike."""
  rng = np.random.default_rng(8)
  turning = dataclasses.replace(TURNING, angle_increments=increments)
  model = em.make_model(turning, D)
  state = em.init(model, turning, jax.random.PRNGKey(0))
  obs = rng.normal(size=(4, 9, D)) * [1.0, 3.0, 0.5]
  obs[..., 0] = rng.uniform(-np.pi, np.pi, size=(4, 1)) + np.cumsum(
      rng.normal(size=(4, 9)) * 0.8, axis=1)
  turns = rng.integers(-3, 4, size=(4, 1)) * np.ones((4, 9), int)
  discount = jnp.ones((4, 8))
  steps = [em.update(model, turning, state, jnp.asarray(o, jnp.float32), discount,
                     jax.random.PRNGKey(1)) for o in (obs, _turned(obs, turns))]
  (a, ma), (b, mb) = steps
  for name in ("log_prob", "log_prob_offset1", "log_prob_offset4", "log_prob_autoregressive"):
    np.testing.assert_allclose(ma[name], mb[name], rtol=1e-4, atol=1e-4, err_msg=name)
  np.testing.assert_allclose(a.normalizer.mean, b.normalizer.mean, atol=1e-5)
  for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params)):
    np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-5)
  # The standardisation is over the wrapped angle; a plain model's is over the raw one.
  wrapped = np.mod(obs[..., 0] + np.pi, 2 * np.pi) - np.pi
  np.testing.assert_allclose(a.normalizer.mean[0], wrapped.mean(), atol=1e-5)
  plain, _ = em.update(em.make_model(CONFIG, D), CONFIG, em.init(em.make_model(CONFIG, D),
                       CONFIG, jax.random.PRNGKey(0)), jnp.asarray(_turned(obs, turns),
                       jnp.float32), discount, jax.random.PRNGKey(1))
  assert abs(float(plain.normalizer.mean[0]) - wrapped.mean()) > 0.1


def test_turn_settings_are_checked():
  assert em.EffectModelConfig(period=[6.0, 0, 0]).period == (6.0, 0.0, 0.0)  # a file's list
  with pytest.raises(ValueError, match="period has 3 entries, the observations have 4"):
    em.make_model(TURNING, 4)
  for bad in ((-1.0, 0.0, 0.0), (0.0, 0.0, 0.0), (float("inf"), 0.0, 0.0)):
    with pytest.raises(ValueError, match="period must be finite values >= 0"):
      em.EffectModelConfig(period=bad).check()


def test_reacher_hards_effect_models_are_turn_invariant_unless_told_otherwise():
  """settings.PER_TASK makes reacher_hard's models turn-invariant at its shoulder's raw angle
  (the period read off the task, built here where the caller does not pass it);
  --no-turn_invariant gives the plain model; reacher_easy stays plain."""
  import tasks
  from mjx_form.imitation import settings
  env = tasks.make("reacher_hard")
  config = settings.effect_model_config("reacher_hard", env)
  assert env.periodic_observations == ("position[0]",)
  np.testing.assert_allclose(config.period, [2 * np.pi, 0, 0, 0, 0, 0], rtol=1e-6)
  assert settings.effect_model_config("reacher_hard") == config
  plain = settings.effect_model_config("reacher_hard", env, period=settings.turn_period(env, False))
  assert plain.period == () and plain == dataclasses.replace(config, period=())
  assert settings.effect_model_config("reacher_easy").period == ()


def test_a_files_turn_settings_read_back_as_the_runs(tmp_path):
  """A demonstrator file keeps its periods as a JSON list; read back, its settings are the
  run's `to_dict()` (what the pipeline compares a shipped demonstrator with) and rebuild the
  run's settings (a tuple), so a ready turn-invariant demonstrator is used, not retrained."""
  from mjx_form.files import effect_models
  config = dataclasses.replace(TURNING, width=4)
  meta = {"task": "reacher_easy", "observation_size": D, "observation_layout": [["x", D]],
          "distractors": None, "config": config.to_dict(), "training": {},
          "demonstrations": {}}
  path = tmp_path / "turning.npz"
  effect_models.save_effect_model(path, {"w": np.zeros(2, np.float32)}, np.zeros(D),
                                  np.ones(D), meta)
  file = effect_models.load_effect_model(path)
  assert isinstance(file.metadata["config"]["period"], list)
  assert file.metadata["config"] == config.to_dict()
  assert em.EffectModelConfig(**file.metadata["config"]) == config
  assert file.metadata["config"] != dataclasses.replace(config, period=()).to_dict()
  assert "period" not in dataclasses.replace(config, period=()).to_dict()


def test_train_demonstrator_script_trains_a_grid_and_refuses_bad_input(tmp_path, capsys):
  """scripts/train_demonstrator.py on saved demonstrations (random walks shaped like
  reacher_easy's, tiny sizes): a grid of two turn-invariant models, each file named after its
  settings and recorded; existing files are never overwritten; a task without unbounded angles
  is refused for --turn_invariant."""
  from conftest import load_script

  from mjx_form.files import demos, effect_models
  script = load_script("train_demonstrator")
  rng = np.random.default_rng(9)
  obs = np.cumsum(rng.normal(size=(4, 21, 6)) * 0.3, axis=1).astype(np.float32)
  saved = tmp_path / "demos.npz"
  demos.save_demonstrations(saved, obs, metadata={
      "task": "reacher_easy", "physics": "fast",
      "observation_layout": [["position", 2], ["to_target", 2], ["velocity", 2]]})
  grid, records = tmp_path / "grid", tmp_path / "em.jsonl"
  args = ["--task", "reacher_easy", "--demos", str(saved), "--width", "8", "--max_steps", "4",
          "--batch_size", "2", "--window", "5", "--eval_every", "2", "--turn_invariant"]
  assert script.main([*args, "--beta_ar", "0.1,1", "--out", str(grid),
                      "--results", str(records)]) == 0
  names = sorted(p.name for p in grid.iterdir())
  assert names == ["reacher_easy_ar0.1_l20.1_turn.npz", "reacher_easy_ar1_l20.1_turn.npz"]
  for name, beta_ar in zip(names, (0.1, 1.0)):
    meta = effect_models.load_effect_model(grid / name, task="reacher_easy").metadata
    assert meta["config"]["beta_ar"] == beta_ar and meta["training"]["steps"] == 4
    np.testing.assert_allclose(meta["config"]["period"], [2 * np.pi, 0, 0, 0, 0, 0])
  written = [json.loads(line) for line in open(records)]
  assert [r["kind"] for r in written] == ["effect_model"] * 2
  assert written[0]["demonstrations"]["sha256"] == meta["demonstrations"]["sha256"] is not None
  before = (grid / names[0]).read_bytes()
  assert script.main([*args, "--beta_ar", "0.1,1", "--out", str(grid)]) == 2
  assert "exist (nothing was overwritten)" in capsys.readouterr().err
  assert (grid / names[0]).read_bytes() == before
  with pytest.raises(SystemExit) as exit_:
    script.main(["--task", "walker_walk", "--turn_invariant", "--out", str(tmp_path / "w.npz")])
  assert exit_.value.code == 2
  assert "walker_walk observes no unbounded angle" in capsys.readouterr().err
  # reacher_hard's models are turn-invariant without the flag (settings.PER_TASK), plain with
  # --no-turn_invariant.
  hard = tmp_path / "hard_demos.npz"
  demos.save_demonstrations(hard, obs, metadata={
      "task": "reacher_hard", "physics": "fast",
      "observation_layout": [["position", 2], ["to_target", 2], ["velocity", 2]]})
  plain = [a for a in args if a != "--turn_invariant"]
  plain[plain.index("reacher_easy")], plain[plain.index(str(saved))] = "reacher_hard", str(hard)
  assert script.main([*plain, "--beta_ar", "0.1,1", "--out", str(tmp_path / "hard")]) == 0
  assert sorted(p.name for p in (tmp_path / "hard").iterdir()) == [
      "reacher_hard_ar0.1_l20.1_turn.npz", "reacher_hard_ar1_l20.1_turn.npz"]
  assert script.main([*plain, "--no-turn_invariant", "--out", str(tmp_path / "plain.npz")]) == 0
  config = effect_models.load_effect_model(tmp_path / "plain.npz",
                                           task="reacher_hard").metadata["config"]
  assert "period" not in config
  # --seeds: draws of one setting side by side, one file and one record each, named by seed
  draws, records = tmp_path / "draws", tmp_path / "draws.jsonl"
  assert script.main([*args, "--seeds", "3,7", "--out", str(draws),
                      "--results", str(records)]) == 0
  assert sorted(p.name for p in draws.iterdir()) == ["reacher_easy_seed3.npz",
                                                      "reacher_easy_seed7.npz"]
  metas = [effect_models.load_effect_model(draws / f"reacher_easy_seed{s}.npz").metadata
           for s in (3, 7)]
  assert [m["training"]["seed"] for m in metas] == [3, 7]
  assert metas[0]["sha256"] != metas[1]["sha256"]
  assert [json.loads(line)["seed"] for line in open(records)] == [3, 7]
  (tmp_path / "taken.npz").write_bytes(b"x")
  for bad, out, said in ((["--seeds", "3,3"], "bad", "must be distinct"),
                         (["--seeds", "3,x"], "bad", "comma-separated integers"),
                         (["--seeds", "3,7", "--beta_ar", "0.1,1"], "bad", "one setting"),
                         (["--seeds", "3,7", "--seed", "1"], "bad", "exclude each other"),
                         (["--seeds", "3,7"], "taken.npz", "is a file"),
                         (["--max_seconds", "0"], "bad", "--max_seconds must be positive")):
    with pytest.raises(SystemExit):
      script.main([*args, *bad, "--out", str(tmp_path / out)])
    assert said in capsys.readouterr().err
  assert not (tmp_path / "bad").exists() and (tmp_path / "taken.npz").read_bytes() == b"x"
  # One seed (by --seeds or --seed): one file, its record and its training of that seed.
  for flag in ("--seeds", "--seed"):
    one, records = tmp_path / f"one{flag}.npz", tmp_path / f"one{flag}.jsonl"
    assert script.main([*args, flag, "5", "--out", str(one), "--results", str(records)]) == 0
    record = json.loads(open(records).readline())
    assert (record["seed"], record["settings"]["seed"]) == (5, 5)
    assert effect_models.load_effect_model(one).metadata["training"]["seed"] == 5


def test_train_demonstrator_budget_counts_from_the_scripts_start(tmp_path, monkeypatch, capsys):
  """--max_seconds covers the whole script: the time spent before a training (recording the
  demonstrations) comes off it, and a grid's trainings share what is left (a clock the test
  sets; the trainings themselves stubbed, only the budget each is given is looked at)."""
  from conftest import load_script

  from mjx_form.files import demos
  script = load_script("train_demonstrator")
  assert script.training_budget(None, 50.0, 2) is None
  assert script.training_budget(100.0, 30.0, 2) == 35.0
  assert script.training_budget(100.0, 130.0, 1) == 0.0  # out of time: stop at the first check
  obs = np.zeros((4, 21, 6), np.float32)
  saved = tmp_path / "demos.npz"
  demos.save_demonstrations(saved, obs, metadata={
      "task": "reacher_easy", "physics": "fast",
      "observation_layout": [["position", 2], ["to_target", 2], ["velocity", 2]]})
  given, file = [], types.SimpleNamespace(metadata={"training": {"heldout_log_likelihood": [0]}})

  def train(env, config, obs, info, training, *rest):
    given.append(training.max_seconds)
    return file

  def train_draws(env, config, obs, info, training, physics, seeds, *rest):
    given.append(training.max_seconds)
    return [file] * len(seeds)

  monkeypatch.setattr(script.pipeline, "train_demonstrator", train)
  monkeypatch.setattr(script.pipeline, "train_demonstrators", train_draws)
  args = ["--task", "reacher_easy", "--demos", str(saved), "--window", "5", "--max_seconds",
          "100"]
  # the script's start, the budget's line, then before each of its two trainings
  clock = iter([0.0, 30.0, 30.0, 70.0])
  monkeypatch.setattr(script, "time", types.SimpleNamespace(perf_counter=lambda: next(clock)))
  assert script.main([*args, "--beta_ar", "0.1,1", "--out", str(tmp_path / "grid")]) == 0
  assert given == [35.0, 30.0]  # (100 - 30) / 2, then (100 - 70) / 1
  assert "--max_seconds 100: 30s spent before training, 70s left for it" in (
      capsys.readouterr().out)
  # draws side by side (--seeds): one training, all that is left
  given.clear()
  clock = iter([0.0, 40.0, 40.0])
  assert script.main([*args, "--seeds", "3,7", "--out", str(tmp_path / "draws")]) == 0
  assert given == [60.0]


# --- angle increments ---------------------------------------------------------------------

INCREMENTS = dataclasses.replace(TURNING, angle_increments=True)


def _standardised_turns(norm):
  """The turn-invariant shift's numbers in standardised units: (period, low) of feature 0."""
  std = np.sqrt(np.asarray(norm.var, np.float64) + em.NORMALIZER_EPS)
  return 2 * np.pi / std[0], (-np.pi - float(norm.mean[0])) / std[0]


def test_angle_increments_predict_the_change_of_the_angle_from_x_t():
  """With `angle_increments`, log p(x' | x) is the model (same parameters) at x moved into
  [-pi, pi) predicting, for the angle, x' - x (standardised) and, for the other features, x'
  itself (computed here with numpy); full turns of both change nothing. A pair that crosses +pi
  and the next pair, whose x_t is on the other side (-pi), have the same angle target, where a
  model of values has targets a turn apart."""
  rng = np.random.default_rng(9)
  model, params = _model_and_params()
  inc = em.make_model(INCREMENTS, D)
  norm = _norm(rng)
  x = rng.normal(size=(6, D)) * 3
  x[:, 0] = rng.uniform(-12, 12, size=6)
  x_next = x + rng.normal(size=(6, D)) * 0.3
  f32 = lambda a: jnp.asarray(a, jnp.float32)
  got = np.asarray(em.transition_log_prob(inc, params, norm, f32(x), f32(x_next)))
  std = np.sqrt(np.asarray(norm.var, np.float64) + em.NORMALIZER_EPS)
  z, z_next = ((np.asarray(a, np.float64) - np.asarray(norm.mean)) / std for a in (x, x_next))
  period, low = _standardised_turns(norm)
  moved = z.copy()
  moved[:, 0] -= period * np.floor((z[:, 0] - low) / period)
  target = z_next.copy()
  target[:, 0] = z_next[:, 0] - z[:, 0]
  expected = (np.asarray(model.apply(params, f32(moved), 1).log_prob(f32(target)))
              + float(em.log_jacobian(norm)))
  np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-3)
  turns = rng.integers(-3, 4, size=6)
  np.testing.assert_allclose(
      em.transition_log_prob(inc, params, norm, f32(_turned(x, turns)),
                             f32(_turned(x_next, turns))), got, rtol=1e-4, atol=1e-3)
  values = np.asarray(em.transition_log_prob(em.make_model(TURNING, D), params, norm, f32(x),
                                             f32(x_next)))
  assert np.abs(values - got).max() > 0.1  # not the model of values
  # Across the edge: x_t = pi - 0.01 -> pi + 0.01 -> pi + 0.03 (the second x_t wraps to -pi).
  path = np.zeros((3, D), np.float32)
  path[:, 0] = np.pi + np.array([-0.01, 0.01, 0.03])
  anchors = em.standardise(norm, f32(path[:2]))
  nexts = np.asarray(em.standardise(norm, f32(path[1:])))
  t = em.turns(inc, norm)
  for m, same in ((inc, True), (em.make_model(TURNING, D), False)):
    _, targets = em.shifts(m, t, anchors)
    angle_targets = nexts[:, 0] - np.asarray(targets)[:, 0]
    assert np.isclose(angle_targets[0], angle_targets[1], atol=1e-4) == same, angle_targets


def test_angle_increments_autoregressive_sample_returns_to_the_observations():
  """The autoregressive term with `angle_increments`: x~_{t+1} = x_t + the model's sampled
  angle change (x_t moved into [-pi, pi) for the input), then log p(x_{t+2} | x~_{t+1}), with
  numpy's shifts."""
  rng = np.random.default_rng(10)
  inc = em.make_model(INCREMENTS, D)
  params = inc.init(jax.random.PRNGKey(0), jnp.zeros((1, D)))
  norm = _norm(rng)
  x = rng.normal(size=(2, 9, D)) * 3  # standardised sequences whose angle crosses turns
  t = em.turns(inc, norm)
  period, low = float(t.period[0]), float(t.low[0])
  x = jnp.asarray(x, jnp.float32)
  key = jax.random.PRNGKey(7)
  _, metrics = em.loss(inc, INCREMENTS, params, x, jnp.ones((2, 8)), key, t)

  def moved(a):  # a [..., D] standardised: its angle brought into the standardised [-pi, pi)
    a = np.asarray(a, np.float64).copy()
    a[..., 0] -= period * np.floor((a[..., 0] - low) / period)
    return jnp.asarray(a, jnp.float32)

  draw = np.asarray(inc.apply(params, moved(x[:, :-2]), 1).sample(key), np.float64)
  sampled = draw.copy()
  sampled[..., 0] += np.asarray(x[:, :-2, 0])  # the angle's change added back to x_t
  target = np.asarray(x[:, 2:], np.float64).copy()
  target[..., 0] -= sampled[..., 0]
  expected = jnp.mean(inc.apply(params, moved(sampled), 1).log_prob(jnp.asarray(target,
                                                                                jnp.float32)))
  np.testing.assert_allclose(metrics["log_prob_autoregressive"], expected, rtol=1e-4, atol=1e-4)


def test_angle_increment_settings_are_checked_and_kept_in_files():
  with pytest.raises(ValueError, match="angle_increments needs a turn-invariant model"):
    dataclasses.replace(CONFIG, angle_increments=True).check()
  with pytest.raises(ValueError, match="angle_increments must be true or false"):
    dataclasses.replace(TURNING, angle_increments=1).check()
  assert "angle_increments" not in TURNING.to_dict()  # as files before the setting existed
  assert INCREMENTS.to_dict()["angle_increments"] is True
  assert em.EffectModelConfig(**json.loads(json.dumps(INCREMENTS.to_dict()))) == INCREMENTS
  assert em.EffectModelConfig(**TURNING.to_dict()) == TURNING


def test_angle_increments_held_out_likelihood_at_every_offset():
  """heldout_log_likelihood of an increments model: per offset d the mean over pairs of the
  model at x_t (moved into [-pi, pi)) predicting x_{t+d} with the angle as x_{t+d} - x_t
  (standardised), computed here with numpy, plus the change of variables."""
  rng = np.random.default_rng(11)
  inc = em.make_model(INCREMENTS, D)
  params = inc.init(jax.random.PRNGKey(0), jnp.zeros((1, D)))
  norm = _norm(rng)
  episodes = rng.normal(size=(3, 7, D)) * 0.5
  episodes[..., 0] = np.cumsum(rng.normal(size=(3, 7)) * 2.0, axis=1)  # wanders past pi
  got = np.asarray(demonstrator.heldout_log_likelihood(
      inc, params, norm, jnp.asarray(episodes, jnp.float32), chunk=2))
  std = np.sqrt(np.asarray(norm.var, np.float64) + em.NORMALIZER_EPS)
  z = (episodes - np.asarray(norm.mean, np.float64)) / std
  period, low = _standardised_turns(norm)
  for d in range(1, INCREMENTS.max_offset + 1):
    moved, target = z[:, :-d].copy(), z[:, d:].copy()
    moved[..., 0] -= period * np.floor((moved[..., 0] - low) / period)
    target[..., 0] = z[:, d:, 0] - z[:, :-d, 0]
    pairs = inc.apply(params, jnp.asarray(moved, jnp.float32), d).log_prob(
        jnp.asarray(target, jnp.float32))
    np.testing.assert_allclose(got[d - 1], float(jnp.mean(pairs) + em.log_jacobian(norm)),
                               rtol=1e-4, atol=1e-4)


# --- angle inputs -------------------------------------------------------------------------

INPUTS = dataclasses.replace(INCREMENTS, angle_inputs=True)


def test_angle_inputs_encoder_sees_the_cos_and_sin_of_the_raw_angle():
  """With `angle_inputs` the encoder's input for the standardised x is [cos theta, x_1, x_2,
  sin theta], theta the raw angle (numpy, from the raw observations), whatever whole turns x
  was moved by (`shifts`); the first layer takes D + 1 inputs. Without it: x itself; without
  the turns: refused."""
  rng = np.random.default_rng(12)
  model = em.make_model(INPUTS, D)
  norm = _norm(rng)
  t = em.turns(model, norm)
  raw = rng.normal(size=(7, D)) * 3
  raw[:, 0] = rng.uniform(-12, 12, size=7)
  x = em.standardise(norm, jnp.asarray(raw, jnp.float32))
  std = np.sqrt(np.asarray(norm.var, np.float64) + em.NORMALIZER_EPS)
  z = (raw - np.asarray(norm.mean, np.float64)) / std
  expected = np.concatenate([np.cos(raw[:, :1]), z[:, 1:], np.sin(raw[:, :1])], axis=-1)
  inputs, _ = em.shifts(model, t, x)
  assert np.abs(np.asarray(inputs)[:, 0]).max() > 1  # (some are moved by whole turns)
  for a in (x, x - inputs):
    np.testing.assert_allclose(em.encoder_inputs(model, t, a), expected, atol=1e-5)
  params = em.init_params(model, jax.random.PRNGKey(0))
  assert params["params"]["encoder"]["Dense_0"]["kernel"].shape == (D + 1, INPUTS.width)
  assert em.encoder_inputs(em.make_model(INCREMENTS, D), t, x) is x
  with pytest.raises(ValueError, match="needs the turns"):
    em.encoder_inputs(model, None, x)


def test_angle_inputs_of_several_periods_in_feature_order_against_numpy():
  """Two periodic features (1 and 3, periods 2 pi and 3): the encoder sees [x_0, cos theta_1,
  x_2, cos theta_3, sin theta_1, sin theta_3], and transition_log_prob is the model on those
  (numpy) predicting x'_0, x'_2 and the angles' changes, plus the change of variables; the
  offset-1 pairs of offset_log_probs are the same density without it."""
  period = np.array([0.0, 2 * np.pi, 0.0, 3.0])
  config = dataclasses.replace(INPUTS, period=tuple(period), max_offset=1)
  model = em.make_model(config, 4)
  params = jax.jit(lambda key: em.init_params(model, key))(jax.random.PRNGKey(1))
  rng = np.random.default_rng(15)
  norm = normalizer.NormalizerState(jnp.asarray(rng.normal(size=4), jnp.float32),
                                    jnp.asarray(rng.uniform(0.1, 4.0, size=4), jnp.float32),
                                    jnp.asarray(3, jnp.int32))
  raw = rng.normal(size=(6, 4)) * 2
  raw[:, [1, 3]] = rng.uniform(-10, 10, size=(6, 2))  # several turns either way
  raw_next = raw + rng.normal(size=(6, 4)) * 0.3
  std = np.sqrt(np.asarray(norm.var, np.float64) + em.NORMALIZER_EPS)
  z, z_next = ((a - np.asarray(norm.mean, np.float64)) / std for a in (raw, raw_next))
  theta = 2 * np.pi * raw[:, [1, 3]] / period[[1, 3]]
  features = np.concatenate([z[:, :1], np.cos(theta[:, :1]), z[:, 2:3], np.cos(theta[:, 1:]),
                             np.sin(theta)], axis=-1)
  x = em.standardise(norm, jnp.asarray(raw, jnp.float32))
  np.testing.assert_allclose(em.encoder_inputs(model, em.turns(model, norm), x), features,
                             atol=1e-5)
  target = z_next.copy()
  target[:, [1, 3]] -= z[:, [1, 3]]
  expected = jax.jit(lambda f, y: model.apply(
      params, f, method=lambda m, f: m.predict(m.encoder(f), 1)).log_prob(y))(
          jnp.asarray(features, jnp.float32), jnp.asarray(target, jnp.float32))

  @jax.jit
  def densities(a, b):  # transition_log_prob, offset_log_probs' offset-1 pairs
    pairs = em.standardise(norm, jnp.stack([a, b], 1))
    return (em.transition_log_prob(model, params, norm, a, b) - em.log_jacobian(norm),
            em.offset_log_probs(model, params, pairs, em.turns(model, norm))[0, :, 0])

  for got in densities(jnp.asarray(raw, jnp.float32), jnp.asarray(raw_next, jnp.float32)):
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-3)


def test_angle_inputs_density_ignores_full_turns_and_has_no_seam_at_pi():
  """log p(x' | x) of an angle-inputs model (random parameters) is unchanged by full turns of
  both; x at pi - 1e-4 and at -pi + 1e-4 (nearly the same pose, x' moved with x) score alike,
  where the increments model with standardised wrapped inputs jumps."""
  rng = np.random.default_rng(13)
  norm = _norm(rng)
  f32 = lambda a: jnp.asarray(a, jnp.float32)
  model = em.make_model(INPUTS, D)
  params = em.init_params(model, jax.random.PRNGKey(0))
  x = rng.normal(size=(8, D)) * 3
  x[:, 0] = rng.uniform(-12, 12, size=8)
  x_next = x + rng.normal(size=(8, D)) * 0.3
  got = np.asarray(em.transition_log_prob(model, params, norm, f32(x), f32(x_next)))
  assert np.all(np.isfinite(got))
  turns = rng.integers(-3, 4, size=8)
  np.testing.assert_allclose(
      em.transition_log_prob(model, params, norm, f32(_turned(x, turns)),
                             f32(_turned(x_next, turns))), got, rtol=1e-4, atol=1e-3)
  below = rng.normal(size=(8, D))
  below[:, 0] = np.pi - 1e-4
  above = below.copy()
  above[:, 0] = -np.pi + 1e-4
  step = rng.normal(size=(8, D)) * 0.3
  for config in (INPUTS, INCREMENTS):
    m = em.make_model(config, D)
    p = em.init_params(m, jax.random.PRNGKey(0))
    a, b = (np.asarray(em.transition_log_prob(m, p, norm, f32(s), f32(s + step)))
            for s in (below, above))
    if config.angle_inputs:
      np.testing.assert_allclose(a, b, rtol=0, atol=2e-3)
    else:  # the seam the angle inputs remove
      assert np.abs(a - b).max() > 0.1, np.abs(a - b)


def test_angle_input_settings_are_checked():
  for base in (CONFIG, TURNING):
    with pytest.raises(ValueError, match=r"angle_inputs needs angle increments \(--angle_incr"):
      dataclasses.replace(base, angle_inputs=True).check()
  with pytest.raises(ValueError, match="angle_inputs must be true or false"):
    dataclasses.replace(INCREMENTS, angle_inputs=1).check()
  INPUTS.check()
  assert "angle_inputs" not in INCREMENTS.to_dict()  # as files before the setting existed
  assert INPUTS.to_dict()["angle_inputs"] is True
  assert em.EffectModelConfig(**json.loads(json.dumps(INPUTS.to_dict()))) == INPUTS


def _saved_demonstrator(path, config, params_of=None):
  """(path, loaded file) of a reacher_easy-like demonstrator file saved at `path` with
  `config`'s settings and freshly initialised parameters of `params_of` (default: `config`)."""
  from mjx_form.files import effect_models
  params = em.init_params(em.make_model(params_of or config, D), jax.random.PRNGKey(0))
  meta = {"task": "reacher_easy", "observation_size": D, "observation_layout": [["x", D]],
          "distractors": None, "config": config.to_dict(), "training": {},
          "demonstrations": {}}
  effect_models.save_effect_model(path, jax.device_get(params), np.zeros(D), np.ones(D), meta)
  return str(path), effect_models.load_effect_model(path)


def test_a_files_angle_inputs_are_kept_and_a_run_asking_otherwise_is_refused(tmp_path):
  """A demonstrator file keeps angle_inputs; read back it rebuilds its model. A run asking for
  the other setting is refused naming it, either way, as is an ensemble of both kinds and a
  file whose parameters are not an angle-inputs model's."""
  from mjx_form.imitation import pipeline
  save = lambda name, config, params_of=None: _saved_demonstrator(tmp_path / name, config,
                                                                  params_of)
  path, file = save("inputs.npz", INPUTS)
  assert file.metadata["config"]["angle_inputs"] is True
  assert pipeline.demonstrator_from_file(file, path, {"angle_inputs": True})[0] == INPUTS
  with pytest.raises(pipeline.PipelineError, match="trained with angle_inputs=True, this run "
                                                   "asks for False"):
    pipeline.demonstrator_from_file(file, path, {"angle_inputs": False})
  plain_path, plain = save("increments.npz", INCREMENTS)
  assert "angle_inputs" not in plain.metadata["config"]
  with pytest.raises(pipeline.PipelineError, match="trained with angle_inputs=False, this run "
                                                   "asks for True"):
    pipeline.demonstrator_from_file(plain, plain_path, {"angle_inputs": True})
  with pytest.raises(pipeline.PipelineError, match="angle_inputs"):
    pipeline.ensemble([(path, file), (plain_path, plain)], None)
  wrong_path, wrong = save("wrong.npz", INPUTS, params_of=INCREMENTS)
  with pytest.raises(pipeline.PipelineError, match="do not fit"):
    pipeline.demonstrator_from_file(wrong, wrong_path)


def test_train_demonstrator_script_refuses_angle_inputs_without_increments(tmp_path, capsys):
  from conftest import load_script
  script = load_script("train_demonstrator")
  with pytest.raises(SystemExit) as exit_:
    script.main(["--task", "reacher_hard", "--angle_inputs", "--out", str(tmp_path / "a.npz")])
  assert exit_.value.code == 2
  assert "angle_inputs needs angle increments (--angle_increments" in capsys.readouterr().err
  assert not (tmp_path / "a.npz").exists()


def test_angle_inputs_model_trains_and_sees_its_samples_angle():
  """An update of an angle-inputs model (no weight decay): finite metrics, and every parameter
  moves, the first layer's cos and sin rows included (the gradient reaches them). Its
  autoregressive term's second input is the sample put back into observation space (x_t + the
  sampled angle change), as cos and sin (numpy)."""
  rng = np.random.default_rng(14)
  model = em.make_model(INPUTS, D)
  no_l2 = dataclasses.replace(INPUTS, l2=0.0)  # (the weight decay alone would move each kernel)
  state = em.init(model, no_l2, jax.random.PRNGKey(0))
  obs = rng.normal(size=(2, 9, D)) * [1.0, 3.0, 0.5]
  obs[..., 0] = np.cumsum(rng.normal(size=(2, 9)) * 2.0, axis=1)  # wanders past pi
  key = jax.random.PRNGKey(7)
  new, metrics = jax.jit(lambda s, o: em.update(model, no_l2, s, o, jnp.ones((2, 8)), key))(
      state, jnp.asarray(obs, jnp.float32))
  assert all(np.isfinite(float(v)) for v in metrics.values()), metrics
  for a, b in zip(jax.tree.leaves(state.params), jax.tree.leaves(new.params)):
    assert not np.array_equal(a, b)
  first = [np.asarray(p["params"]["encoder"]["Dense_0"]["kernel"])  # [D + 1, W]
           for p in (state.params, new.params)]
  assert np.all(first[0][[0, D]] != first[1][[0, D]])
  # The autoregressive term, at the parameters before the step and the batch's standardisation.
  params, norm = state.params, new.normalizer
  x = np.asarray(em.standardise(norm, jnp.asarray(obs, jnp.float32)), np.float64)
  std = np.sqrt(np.asarray(norm.var, np.float64) + em.NORMALIZER_EPS)
  mean = np.asarray(norm.mean, np.float64)

  def mixture(a):  # the model on standardised a [..., D], its encoder input made with numpy
    theta = a[..., :1] * std[0] + mean[0]
    f = jnp.asarray(np.concatenate([np.cos(theta), a[..., 1:], np.sin(theta)], -1), jnp.float32)
    return model.apply(params, f, method=lambda m, f: m.predict(m.encoder(f), 1))

  sampled = np.asarray(mixture(x[:, :-2]).sample(key), np.float64)
  sampled[..., 0] += x[:, :-2, 0]  # the angle's change added back to x_t
  target = x[:, 2:].copy()
  target[..., 0] -= sampled[..., 0]
  expected = jnp.mean(mixture(sampled).log_prob(jnp.asarray(target, jnp.float32)))
  np.testing.assert_allclose(metrics["log_prob_autoregressive"], expected, rtol=1e-4, atol=1e-4)


CAPPED = dataclasses.replace(CONFIG, max_scale=1.0)


def test_scale_cap_against_numpy():
  """scale_from_raw with max_scale m: s m / (s + m) for s = softplus(raw) + min_scale, against
  numpy over raw in [-30, 30]: below m everywhere, non-decreasing, m at raw 1e38 and inf (no
  overflow); without a cap exactly softplus + min_scale."""
  from mjx_form.rl.distributions import scale_from_raw
  raw = np.linspace(-30.0, 30.0, 601)
  s = np.logaddexp(0.0, raw) + 1e-4
  capped = np.asarray(scale_from_raw(jnp.asarray(raw), 1e-4, 2.0), np.float64)
  np.testing.assert_allclose(capped, s * 2.0 / (s + 2.0), rtol=1e-5)
  assert capped.max() < 2.0 and np.all(np.diff(capped) >= 0)
  assert np.all(np.diff(capped[raw > -5]) > 0)  # (below, softplus is under float32's step)
  huge = np.asarray(scale_from_raw(jnp.asarray([1e38, np.inf], jnp.float32), 1e-4, 2.0))
  np.testing.assert_array_equal(huge, [2.0, 2.0])  # no product overflows
  np.testing.assert_allclose(np.asarray(scale_from_raw(jnp.asarray(raw), 1e-4)), s, rtol=1e-5)


def test_capped_model_keeps_every_scale_below_max_scale():
  """A capped effect model's components stay below max_scale even where the head pushes the raw
  scales far up (its bias +50); the same parameters uncapped give scales of ~50."""
  uncapped, capped = em.make_model(CONFIG, D), em.make_model(CAPPED, D)
  params = em.init_params(capped, jax.random.PRNGKey(0))
  head = params["params"]["head"]
  k = CONFIG.num_components
  bias = head["bias"].at[k:].add(50.0)  # every component's means and raw scales
  pushed = {"params": {**params["params"], "head": {**head, "bias": bias}}}
  x = jnp.asarray(np.random.default_rng(0).normal(size=(5, D)), jnp.float32)
  big = uncapped.apply(pushed, x, 1).scale
  small = capped.apply(pushed, x, 1).scale
  assert float(big.min()) > 40.0
  assert float(small.max()) < 1.0 and float(small.min()) > 0.95
  normal = capped.apply(params, x, 1).scale
  np.testing.assert_array_less(np.asarray(normal), 1.0)


def test_max_scale_settings_are_checked_and_kept_in_files(tmp_path):
  """max_scale: none or a finite number above min_scale; absent from to_dict where none (as
  files before it existed; an int is kept as a float); a file keeps it; a run asking for another
  cap, or for one against an uncapped file, is refused naming it (a run that sets none takes
  the file's), as is an ensemble of a capped and an uncapped file; the imitator model of a FORM
  reward shares the cap."""
  from mjx_form.imitation import form
  from mjx_form.imitation import pipeline
  for bad in (0.0, 1e-4, float("inf"), float("nan"), True, "1"):
    with pytest.raises(ValueError, match="max_scale must be a number above min_scale"):
      dataclasses.replace(CONFIG, max_scale=bad).check()
  CAPPED.check()
  assert dataclasses.replace(CONFIG, max_scale=1) == CAPPED
  assert json.dumps(dataclasses.replace(CONFIG, max_scale=1).to_dict()) == json.dumps(
      CAPPED.to_dict())
  assert "max_scale" not in CONFIG.to_dict() and CAPPED.to_dict()["max_scale"] == 1.0
  assert em.EffectModelConfig(**json.loads(json.dumps(CAPPED.to_dict()))) == CAPPED
  save = lambda name, config: _saved_demonstrator(tmp_path / name, config)
  path, file = save("c.npz", CAPPED)
  assert pipeline.demonstrator_from_file(file, path, {"max_scale": 1.0})[0] == CAPPED
  assert pipeline.demonstrator_from_file(file, path, {"max_scale": None})[0] == CAPPED
  with pytest.raises(pipeline.PipelineError, match=r"trained with max_scale \(--effect_max_sc"
                                                   r"ale\)=1.0, this run asks for 2.0"):
    pipeline.demonstrator_from_file(file, path, {"max_scale": 2.0})
  plain_path, plain = save("plain.npz", CONFIG)
  with pytest.raises(pipeline.PipelineError, match=r"trained with max_scale \(--effect_max_sc"
                                                   r"ale\)=None, this run asks for 1.0"):
    pipeline.demonstrator_from_file(plain, plain_path, {"max_scale": 1.0})
  with pytest.raises(pipeline.PipelineError, match="max_scale"):
    pipeline.ensemble([(path, file), (plain_path, plain)], None)
  config, demonstrator = pipeline.demonstrator_from_file(file, path)
  reward = form.FormReward(config, demonstrator)
  assert reward.model.max_scale == 1.0
  assert reward.settings()["effect_model"]["max_scale"] == 1.0
