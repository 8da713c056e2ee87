"""GAIfO: the discriminator's reward, objective and gradient penalty against numpy and finite
differences, its inputs drawn from the demonstrations and the batches, and the reward source in
the compiled loop (reacher_easy, small sizes, over the 2 forced host devices), which never
stores the task reward."""

import dataclasses

import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import pytest

import tasks
from mjx_form import mesh as mesh_lib
from mjx_form.imitation import discriminator as disc
from mjx_form.imitation.gaifo import GaifoReward
from mjx_form.rl import normalizer
from mjx_form.rl.learner import LearnerConfig
from mjx_form.rl.train import TrainConfig, Trainer
from test_form import _iterate

SMALL = disc.DiscriminatorConfig(width=16)


def _params(config=SMALL, features=3, seed=0):
  return disc.Discriminator(config.width).init(jax.random.PRNGKey(seed),
                                               jnp.zeros((1, features)))


def test_reward_is_log_one_plus_the_expert_probability():
  logit = np.array([-60.0, -3.0, -0.5, 0.0, 0.7, 4.0, 60.0], np.float32)
  expected = np.log1p(1.0 / (1.0 + np.exp(-logit.astype(np.float64))))
  got = np.asarray(disc.reward(jnp.asarray(logit)))
  np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-7)
  assert got[0] >= 0 and got[-1] == pytest.approx(np.log(2))


def test_gradient_norms_match_finite_differences():
  params = _params(features=3)
  model = disc.Discriminator(SMALL.width)
  z = jax.random.normal(jax.random.PRNGKey(1), (4, SMALL.width))
  decode = lambda h: np.asarray(model.apply(params, jnp.asarray(h, jnp.float32),
                                            method=disc.Discriminator.decode), np.float64)
  eps = 1e-3
  for row in range(z.shape[0]):
    grad = np.zeros(SMALL.width)
    for i in range(SMALL.width):
      up, down = np.array(z[row]), np.array(z[row])
      up[i] += eps
      down[i] -= eps
      grad[i] = (decode(up[None]) - decode(down[None]))[0] / (2 * eps)
    assert float(disc.gradient_norms(model, params, z)[row]) == pytest.approx(
        np.linalg.norm(grad), rel=2e-2)


def test_loss_is_cross_entropy_plus_the_penalty_and_ignores_invalid_rows():
  """Against numpy from the network's own logits; the penalty adds beta * mean norm / width
  over the valid rows; invalid imitator rows change nothing."""
  params = _params(features=3)
  model = disc.Discriminator(SMALL.width)
  rng = np.random.default_rng(0)
  expert = jnp.asarray(rng.normal(size=(6, 3)), jnp.float32)
  imitator = jnp.asarray(rng.normal(size=(6, 3)), jnp.float32)
  valid = jnp.array([True, True, False, True, False, True])
  key = jax.random.PRNGKey(3)
  le = np.asarray(model.apply(params, expert), np.float64)
  li = np.asarray(model.apply(params, imitator), np.float64)
  v = np.asarray(valid)
  bce = -(np.mean(np.log(1 / (1 + np.exp(-le))))
          + np.mean(np.log(1 / (1 + np.exp(li[v])))))
  plain, _ = disc.loss(SMALL, params, expert, imitator, valid, key)
  assert float(plain) == pytest.approx(bce, rel=1e-5)
  gp = dataclasses.replace(SMALL, gradient_penalty=10.0)
  penalised, metrics = disc.loss(gp, params, expert, imitator, valid, key)
  # the same interpolations (same key): the norms at them, independently of `loss`
  u = jax.random.uniform(jax.random.split(key)[0], (6, 1))
  h = lambda x: model.apply(params, x, method=disc.Discriminator.encode)
  norms = np.asarray(disc.gradient_norms(model, params, u * h(expert) + (1 - u) * h(imitator)))
  assert float(penalised) == pytest.approx(bce + 10.0 * norms[v].mean() / SMALL.width, rel=1e-5)
  assert float(metrics["gradient_norm"]) == pytest.approx(norms[v].mean(), rel=1e-5)
  moved = imitator.at[2].set(100.0).at[4].set(-100.0)
  again, _ = disc.loss(gp, params, expert, moved, valid, key)
  assert float(again) == pytest.approx(float(penalised), rel=1e-6)


def test_training_tells_the_expert_apart_and_pays_its_observations_more():
  """Expert frames around +1, imitator frames around -1 (3 features): after 200 steps most of
  each side is classified right, and the reward of expert-like transitions is the higher."""
  config = disc.DiscriminatorConfig(width=32, learning_rate=1e-3)
  state = disc.init(config, 3, jax.random.PRNGKey(0))
  step = jax.jit(lambda s, e, i, k: disc.update(config, s, e, i, jnp.ones(64, bool), k))
  rng = np.random.default_rng(1)
  for n in range(200):
    expert = jnp.asarray(rng.normal(1.0, 0.5, size=(64, 1, 3)), jnp.float32)
    imitator = jnp.asarray(rng.normal(-1.0, 0.5, size=(64, 1, 3)), jnp.float32)
    state, metrics = step(state, expert, imitator, jax.random.PRNGKey(n))
  assert metrics["expert_accuracy"] > 0.9 and metrics["imitator_accuracy"] > 0.9
  assert int(state.steps) == 200
  np.testing.assert_allclose(np.asarray(state.normalizer.mean), 0.0, atol=0.2)  # both sides
  sequences = jnp.asarray(np.stack([np.full((3, 3), 1.0), np.full((3, 3), -1.0)]), jnp.float32)
  rewards = np.asarray(disc.reward(disc.logits(config, state, sequences)))  # [2, 2]
  assert rewards.shape == (2, 2) and rewards[0].min() > rewards[1].max()


def test_kl_to_a_standard_normal_matches_its_closed_form():
  rng = np.random.default_rng(0)
  mean, scale = rng.normal(size=(5, 7)), rng.uniform(0.1, 3.0, size=(5, 7))
  expected = np.sum(np.log(1 / scale) + (scale ** 2 + mean ** 2) / 2 - 0.5, axis=-1)
  np.testing.assert_allclose(np.asarray(disc.kl_to_standard_normal(jnp.asarray(mean),
                                                                   jnp.asarray(scale))),
                             expected, rtol=1e-5)


def test_the_bottleneck_holds_its_bound_with_a_learned_multiplier():
  """VAIfO: the multiplier grows while the encodings' KL exceeds the bound and shrinks below
  it; training under a bound of 1 brings the KL down; the reward reads the mean encoding (the
  same every call), and the classifier still tells the two sides apart."""
  rng = np.random.default_rng(1)
  batch = lambda: (jnp.asarray(rng.normal(1.0, 0.5, size=(64, 1, 3)), jnp.float32),
                   jnp.asarray(rng.normal(-1.0, 0.5, size=(64, 1, 3)), jnp.float32))
  for bound, sign in ((0.0, 1), (1e6, -1)):
    config = disc.DiscriminatorConfig(width=16, kl_bound=bound)
    state = disc.init(config, 3, jax.random.PRNGKey(0))
    state, metrics = disc.update(config, state, *batch(), jnp.ones(64, bool),
                                 jax.random.PRNGKey(1))
    assert np.sign(float(state.log_beta)) == sign and "kl" in metrics
  config = disc.DiscriminatorConfig(width=16, kl_bound=1.0, learning_rate=1e-3)
  state = disc.init(config, 3, jax.random.PRNGKey(0))
  step = jax.jit(lambda s, e, i, k: disc.update(config, s, e, i, jnp.ones(64, bool), k))
  kls = []
  for n in range(300):
    state, metrics = step(state, *batch(), jax.random.PRNGKey(n))
    kls.append(float(metrics["kl"]))
  assert kls[0] > 4.0 and np.mean(kls[-20:]) < 0.5 * kls[0], (kls[0], kls[-20:])
  assert metrics["expert_accuracy"] > 0.8 and metrics["imitator_accuracy"] > 0.8
  sequences = jnp.asarray(rng.normal(size=(2, 4, 3)), jnp.float32)
  once, twice = disc.logits(config, state, sequences), disc.logits(config, state, sequences)
  np.testing.assert_array_equal(np.asarray(once), np.asarray(twice))
  model = disc.make_model(config)
  x = disc.inputs(config, state.normalizer, sequences)
  h = model.apply(state.params, x, method=disc.Discriminator.encode)
  mean = model.apply(state.params, h, method=disc.Discriminator.posterior)[0]
  np.testing.assert_allclose(
      np.asarray(once),
      np.asarray(model.apply(state.params, mean, method=disc.Discriminator.decode)), rtol=1e-5)
  assert disc.make_model(disc.DiscriminatorConfig(width=16)).bottleneck is False


def test_the_network_weighs_the_kl_by_the_multiplier_and_the_multiplier_climbs_it():
  """With the same samples, the parameters' gradient is linear in beta (the GAN part plus
  beta times the KL's), and log beta's gradient is -beta (KL - bound)."""
  config = disc.DiscriminatorConfig(width=8, kl_bound=0.5)
  params = disc.init(config, 3, jax.random.PRNGKey(0)).params
  rng = np.random.default_rng(2)
  expert, imitator = (jnp.asarray(rng.normal(size=(16, 3)), jnp.float32) for _ in range(2))
  valid, key = jnp.ones(16, bool), jax.random.PRNGKey(5)
  grad = lambda beta: jax.flatten_util.ravel_pytree(jax.grad(
      lambda p: disc.loss(config, p, expert, imitator, valid, key, jnp.log(beta))[0])(params))[0]
  g0, g1, g3 = (np.asarray(grad(b), np.float64) for b in (1e-12, 1.0, 3.0))
  np.testing.assert_allclose(g3 - g1, 2.0 * (g1 - g0), rtol=1e-3, atol=1e-6)
  assert np.abs(g1 - g0).max() > 1e-4  # the KL does pull on the parameters
  _, metrics = disc.loss(config, params, expert, imitator, valid, key, jnp.log(3.0))
  beta_grad = jax.grad(lambda b: disc.loss(config, params, expert, imitator, valid, key,
                                           b)[0])(jnp.log(3.0))
  assert float(beta_grad) == pytest.approx(-3.0 * (float(metrics["kl"]) - 0.5), rel=1e-4)


def _source(frames=1, episodes=5, steps=7, d=2, penalty=0.0):
  """A source whose demonstrations encode (episode, step) in their two features."""
  k, t = np.meshgrid(np.arange(episodes), np.arange(steps + 1), indexing="ij")
  observations = np.stack([k, t], axis=-1).astype(np.float32)  # [K, T+1, 2]
  config = disc.DiscriminatorConfig(width=8, frames=frames, gradient_penalty=penalty)
  return GaifoReward(config, observations[..., :d], "sha"), observations


@pytest.mark.parametrize("frames", [1, 2])
def test_expert_inputs_are_transitions_of_one_demonstration(frames):
  source, observations = _source(frames)
  drawn = np.asarray(source.expert_frames(jnp.asarray(observations), 500,
                                          jax.random.PRNGKey(0)))  # [500, frames, 2]
  assert drawn.shape == (500, frames, 2)
  last = drawn[:, -1]
  assert last[:, 1].min() == 1 and last[:, 1].max() == 7  # x_{t+1}: never a reset frame
  assert len({tuple(x) for x in last}) == 5 * 7  # every transition can be drawn
  many = np.asarray(source.expert_frames(jnp.asarray(observations), 7000,
                                         jax.random.PRNGKey(1)))[:, -1, 1]
  counts = np.bincount(many.astype(int), minlength=8)[1:]  # x_{t+1} = 1..7, uniformly
  assert counts.max() < 1.3 * counts.mean() and counts.min() > 0.7 * counts.mean(), counts
  if frames == 2:
    np.testing.assert_array_equal(drawn[:, 0, 0], drawn[:, 1, 0])  # one episode
    np.testing.assert_array_equal(drawn[:, 0, 1] + 1, drawn[:, 1, 1])  # consecutive


@pytest.mark.parametrize("frames", [1, 2])
def test_batch_inputs_are_scored_as_the_relabelled_transitions(frames):
  """The rows the discriminator trains on from a batch are, in order, the transitions that
  `relabel` rewards; invalid transitions get reward 0."""
  source, _ = _source(frames)
  state = source.init(jax.random.PRNGKey(0), 2, 1)
  state = state._replace(discriminator=state.discriminator._replace(
      normalizer=normalizer.NormalizerState(jnp.array([0.5, 2.0]), jnp.array([2.0, 9.0]),
                                            jnp.asarray(1, jnp.int32))))
  rng = np.random.default_rng(0)
  batch = {"observation": jnp.asarray(rng.normal(size=(3, 5, 2)), jnp.float32),
           "discount": jnp.asarray(rng.uniform(size=(3, 4)) > 0.3, jnp.float32)}
  rows = source.imitator_frames(batch["observation"])  # [12, frames, 2]
  norm = state.discriminator.normalizer
  flat = normalizer.normalize(norm, rows).reshape(rows.shape[0], -1)
  # transition t's input, from the observations themselves: x_{t+1} (and x_t before it)
  x = (np.asarray(batch["observation"]) - np.array([0.5, 2.0])) / np.sqrt(
      np.array([2.0, 9.0]) + 1e-6)
  own = x[:, 1:] if frames == 1 else np.concatenate([x[:, :-1], x[:, 1:]], axis=-1)
  np.testing.assert_allclose(np.asarray(flat), own.reshape(12, -1), rtol=1e-5, atol=1e-6)
  logits = disc.Discriminator(8).apply(state.discriminator.params, flat)
  rewards, metrics = source.relabel(state, batch)
  valid = np.asarray(batch["discount"]).reshape(-1) > 0
  expected = np.asarray(disc.reward(logits))
  np.testing.assert_allclose(np.asarray(rewards).reshape(-1)[valid], expected[valid], rtol=1e-6)
  assert np.all(np.asarray(rewards).reshape(-1)[~valid] == 0)
  assert float(metrics["gaifo_reward"]) == pytest.approx(float(expected[valid].mean()), rel=1e-5)
  # standardised: by the running mean and sd of the raw reward
  stats = normalizer.NormalizerState(jnp.array([0.3]), jnp.array([0.04]),
                                     jnp.asarray(1, jnp.int32))
  scaled = source.specialise({"standardise_reward": True})
  standardised, _ = scaled.relabel(state._replace(reward=stats), batch)
  np.testing.assert_allclose(np.asarray(standardised).reshape(-1)[valid],
                             (expected[valid] - 0.3) / np.sqrt(0.04 + 1e-6), rtol=1e-4)


@pytest.mark.parametrize("bottleneck", [None, 1.0])
def test_transitions_without_a_successor_neither_train_nor_score(bottleneck):
  """The observations only a discount-0 transition leads to (1 frame) change neither the
  discriminator's step (with a bottleneck: nor its KL or multiplier), its standardisation, the
  reward's statistics nor any valid reward."""
  source, _ = _source(frames=1)
  source = GaifoReward(dataclasses.replace(source.config, kl_bound=bottleneck), source.expert)
  state = source.init(jax.random.PRNGKey(0), 2, 1)
  rng = np.random.default_rng(0)
  observation = rng.normal(size=(3, 5, 2)).astype(np.float32)
  discount = np.ones((3, 4), np.float32)
  discount[0, 1] = discount[2, 3] = 0.0
  batch = lambda obs: {"observation": jnp.asarray(obs), "discount": jnp.asarray(discount)}
  moved = observation.copy()
  moved[0, 2] = 1e3  # x_{t+1} of transition (0, 1)
  moved[2, 4] = -1e3  # x_{t+1} of transition (2, 3)
  key = jax.random.PRNGKey(4)
  one, _ = source.update(state, batch(observation), key)
  two, _ = source.update(state, batch(moved), key)
  for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(two)):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
  r1, r2 = source.relabel(one, batch(observation))[0], source.relabel(two, batch(moved))[0]
  np.testing.assert_array_equal(np.asarray(r1), np.asarray(r2))
  other = observation.copy()
  other[1, 2] = 1e3  # a valid transition's x_{t+1}: it does train (the test can fail)
  three, _ = source.update(state, batch(other), key)
  assert not np.array_equal(np.asarray(three.discriminator.normalizer.mean),
                            np.asarray(one.discriminator.normalizer.mean))


def test_source_names_its_method_and_refuses_what_does_not_fit():
  assert _source()[0].name == "gaifo" and _source(penalty=10.0)[0].name == "gaifo_gp"
  from conftest import load_script
  cli = load_script("run")
  for method, penalty, bound in (("gaifo", 0, None), ("gaifo_gp", 10, None),
                                 ("vaifo", 0, 1.0), ("vaifo_gp", 10, 1.0)):
    config = cli.discriminator_config(cli.parse_args(["--method", method]))
    assert (config.gradient_penalty, config.kl_bound) == (penalty, bound)
    assert GaifoReward(config, np.zeros((2, 3, 4))).name == method
  config = cli.discriminator_config(cli.parse_args(["--method", "vaifo_gp", "--kl_bound", "0.1",
                                                    "--gradient_penalty", "3"]))
  assert (config.gradient_penalty, config.kl_bound) == (3, 0.1)
  source = _source()[0]
  assert source.settings()["discriminator"]["gradient_penalty"] == 0.0
  with pytest.raises(ValueError, match="2-dimensional observations, the task has 6"):
    source.init(jax.random.PRNGKey(0), 6, 2)
  with pytest.raises(ValueError, match=r"sequences \[K, T\+1, D\]"):
    GaifoReward(SMALL, np.zeros((4, 3)))
  with pytest.raises(ValueError, match="finite"):
    GaifoReward(SMALL, np.full((2, 3, 4), np.nan))
  for bad in ({"frames": 3}, {"gradient_penalty": -1.0}, {"gradient_penalty": np.inf},
              {"kl_bound": -0.5}, {"kl_bound": np.inf},
              {"width": 0},
              {"learning_rate": 0.0}, {"normalizer_decay": 1.0}):
    with pytest.raises(ValueError, match="discriminator"):
      GaifoReward(dataclasses.replace(SMALL, **bad), np.zeros((2, 3, 4)))


CONFIG = TrainConfig(task="reacher_easy", reward_source="vaifo_gp", num_envs=4,
                     unroll_length=50, batch_size=4, replay_capacity=12,
                     updates_per_iteration=2, network_width=32, eval_envs=2,
                     learner=LearnerConfig(num_action_samples=4, target_update_period=3))


def _gaifo_source(episodes=3):
  """VAIfO+GP (the discriminator with every part: penalty and bottleneck)."""
  rng = np.random.default_rng(episodes)
  demos = rng.normal(size=(episodes, 11, 6)).astype(np.float32)  # stands in for recorded ones
  return GaifoReward(disc.DiscriminatorConfig(width=16, gradient_penalty=10.0, kl_bound=1.0),
                     demos, "sha", standardise_reward=True)


@pytest.mark.slow
def test_vaifo_gp_trains_in_the_compiled_loop_without_the_task_reward():
  """VAIfO+GP runs in the compiled loop over the mesh: the discriminator steps once per
  update, its bottleneck's KL is logged and its multiplier moves, and the task reward is not
  even stored (the replay holds none; test_form runs FORM's loop with a garbage reward, which
  shows that a source without it trains the same whatever the reward; one compile fewer
  here)."""
  trainer = Trainer(CONFIG, mesh_lib.make_mesh(), _gaifo_source())
  state, metrics = _iterate(trainer, 2)
  # the demonstrations enter the iteration as an argument: not in the (checkpointed) state,
  # not compiled in (ten times as many leave the program's text as long)
  assert not any(np.shape(x)[-3:] == (3, 11, 6) for x in jax.tree.leaves(state.source))
  text = lambda t: len(t.iteration.lower(t.abstract_state).as_text())
  more = _gaifo_source(episodes=30)
  assert abs(text(Trainer(CONFIG, mesh_lib.make_mesh(), more)) - text(trainer)) < 2000
  # a trainer that only evaluates (--eval_on_host's) does not place them at all
  assert not hasattr(Trainer(CONFIG, mesh_lib.make_mesh(), more, source_data=False),
                     "source_data") and hasattr(trainer, "source_data")
  assert int(np.asarray(state.source.discriminator.steps).max()) == 4  # 2 x 2 updates
  assert np.isfinite(metrics[-1]["gaifo_reward"][0])
  assert np.isfinite(metrics[-1]["discriminator_gradient_norm"][0])
  assert np.isfinite(metrics[-1]["discriminator_kl"][0])
  assert float(np.asarray(state.source.discriminator.log_beta)[0]) != 0.0
  assert not trainer.source.needs_task_reward
  assert set(state.replay.data) == {"observation", "action", "behaviour_log_prob", "discount"}


SMALL_RUN = ["--task", "reacher_easy", "--num_envs", "4", "--unroll_length", "50",
             "--batch_size", "4", "--replay_capacity", "16", "--updates_per_iteration", "2",
             "--num_action_samples", "4", "--network_width", "32", "--eval_envs", "2",
             "--eval_every", "2", "--final_eval_envs", "0", "--demo_episodes", "2"]


def test_run_py_gaifo_runs_resumes_and_refuses_what_does_not_fit(tmp_path, capsys):
  """`scripts/run.py --method gaifo_gp` end to end on the CPU: demonstrations recorded from the
  shipped expert, records named by the method with the discriminator's settings and metrics,
  and --resume continuing the run from the demonstrations its first part saved (other ones
  refused by their checksum); demonstrations of another task, or none, and the other methods'
  flags are refused with exit status 2 or a usage error, nothing written."""
  import json
  from conftest import load_script
  from mjx_form.files import demos
  cli = load_script("run")
  run_dir, out = tmp_path / "run", tmp_path / "curve.jsonl"
  args = [*SMALL_RUN, "--method", "gaifo_gp", "--gradient_penalty", "5", "--run_dir",
          str(run_dir), "--results", str(out)]
  saved = tmp_path / "demos.npz"
  assert cli.main([*args, "--env_steps", "400", "--save_demos", str(saved)]) == 0
  records = [json.loads(line) for line in open(out)]
  curve = [r for r in records if r["kind"] == "learning_curve"]
  assert curve and {r["method"] for r in records} == {"gaifo_gp"}
  reward = curve[-1]["settings"]["reward"]
  assert reward["discriminator"]["gradient_penalty"] == 5.0
  assert reward["demonstration_episodes"] == 2 and not reward["standardise_reward"]
  assert 0.0 <= curve[-1]["gaifo_reward"] <= np.log(2)
  assert np.isfinite(curve[-1]["discriminator_gradient_norm"])
  assert "gaifo reward" in capsys.readouterr().out
  assert cli.main([*args, "--env_steps", "800", "--resume", "--demos", str(saved)]) == 0
  assert max(json.loads(line)["env_steps"] for line in open(out)) == 800
  # every record carries the demonstrations' mean return (recorded, then read from the file)
  loaded = demos.load_demonstrations(str(saved))
  from mjx_form.files import results
  assert {r["demonstrations_return"] for r in results.read_records(str(out))} == {
      round(float(loaded.metadata["expert"]["mean_return"]), 2)}
  # other demonstrations than the run's: refused on resume, by their checksum
  changed = demos.save_demonstrations(
      tmp_path / "changed.npz", loaded.observations + 1e-3, loaded.actions,
      metadata={k: loaded.metadata[k] for k in ("task", "observation_layout", "physics",
                                                "expert")})
  capsys.readouterr()
  assert cli.main([*args, "--env_steps", "1200", "--resume", "--demos", str(changed)]) == 2
  assert "demonstrations_sha256" in capsys.readouterr().err
  # demonstrations of another task: refused, naming the file, before anything is written
  walker = tasks.make("walker_walk")
  other = demos.save_demonstrations(
      tmp_path / "walker.npz", np.zeros((1, 3, walker.observation_size), np.float32),
      metadata={"task": "walker_walk", "observation_layout": walker.observation_layout,
                "physics": "fast", "expert": {}})
  capsys.readouterr()
  assert cli.main([*SMALL_RUN, "--method", "gaifo", "--demos", str(other), "--run_dir",
                   str(tmp_path / "refused"), "--env_steps", "400"]) == 2
  err = capsys.readouterr().err
  assert "walker.npz" in err and "walker_walk" in err
  assert not (tmp_path / "refused").exists()
  for argv, message in (
      (["--method", "gaifo", "--demo_episodes", "0"], "--method gaifo needs demonstrations"),
      (["--method", "gaifo", "--gradient_penalty", "1"], "--method gaifo has none"),
      (["--method", "gaifo_gp", "--gradient_penalty", "0"], "must be positive and finite, got 0.0"),
      (["--method", "gaifo_gp", "--gradient_penalty", "inf"], "positive and finite, got inf"),
      (["--method", "gaifo", "--beta_ar", "1"], "--beta_ar apply to --method form only"),
      (["--method", "expert", "--discriminator_frames", "2"],
       "--discriminator_frames apply to --method gaifo, gaifo_gp, vaifo, vaifo_gp"),
      (["--method", "vaifo", "--gradient_penalty", "1"], "--method vaifo has none"),
      (["--method", "gaifo_gp", "--kl_bound", "1"],
       "--kl_bound: --method gaifo_gp has no bottleneck (--method vaifo_gp has one)"),
      (["--method", "vaifo", "--kl_bound", "-1"], "--kl_bound must be >= 0 and finite"),
      (["--method", "expert", "--demos", "x.npz"],
       "--demos apply to --method form, gaifo, gaifo_gp")):
    with pytest.raises(SystemExit):
      cli.parse_args(argv)
    assert message in capsys.readouterr().err

