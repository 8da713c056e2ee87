"""BC: the cloning loss against scipy, one update against optax's step, the pairs drawn from the
demonstrations, and BC in the compiled loop (reacher_easy, small sizes, over the 2 forced host
devices)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from scipy import stats

import tasks
from mjx_form import mesh as mesh_lib
from mjx_form.imitation.bc import BehaviourCloning
from mjx_form.imitation.bco import BcoSource
from mjx_form.rl import cloning, normalizer
from mjx_form.rl import learner as learner_lib
from mjx_form.rl.distributions import DiagonalGaussian
from mjx_form.rl.learner import LearnerConfig
from mjx_form.rl.networks import make_networks
from mjx_form.rl.train import TrainConfig, Trainer


def test_loss_is_the_gaussian_negative_log_likelihood():
  """-mean log pi(a|x) equals scipy's normal log-density summed over the action's dimensions;
  the metrics are numpy's of the same policy outputs."""
  networks = make_networks(3, width=16)
  params = networks.policy.init(jax.random.PRNGKey(0), jnp.zeros((1, 5)))
  rng = np.random.default_rng(0)
  obs = jnp.asarray(rng.normal(size=(7, 5)), jnp.float32)
  actions = jnp.asarray(rng.normal(size=(7, 3)), jnp.float32)
  loss, metrics = cloning.loss(networks, params, obs, actions)
  pi = networks.policy.apply(params, obs)
  mean, scale = np.asarray(pi.mean, np.float64), np.asarray(pi.scale, np.float64)
  log_prob = stats.norm.logpdf(np.asarray(actions, np.float64), mean, scale).sum(-1)
  np.testing.assert_allclose(float(loss), -log_prob.mean(), rtol=1e-5)
  np.testing.assert_allclose(float(metrics["bc_log_prob"]), log_prob.mean(), rtol=1e-5)
  np.testing.assert_allclose(float(metrics["bc_action_error"]),
                             np.mean((mean - np.asarray(actions)) ** 2), rtol=1e-5)
  np.testing.assert_allclose(float(metrics["scale_mean"]), scale.mean(), rtol=1e-5)
  np.testing.assert_allclose(float(metrics["entropy"]),
                             stats.norm.entropy(0.0, scale).sum(-1).mean(), rtol=1e-5)


def test_decoupled_loss_divides_no_gradient_by_the_variance():
  """The decoupled fit's gradient for the mean is (mean - a), the likelihood's (mean - a) /
  scale^2 (finite differences of scipy's log-density); for the scale both are the likelihood's;
  its value is the squared error plus the likelihood at the held mean."""
  rng = np.random.default_rng(2)
  mean = rng.normal(size=(5, 3))
  scale = rng.uniform(0.05, 1.5, size=(5, 3))
  actions = rng.normal(size=(5, 3))
  f32 = lambda x: jnp.asarray(x, jnp.float32)
  def total(kind, m, s):
    return jnp.sum(cloning.fit_loss(DiagonalGaussian(m, s), f32(actions), kind))
  g_mean = {k: np.asarray(jax.grad(total, 1)(k, f32(mean), f32(scale)), np.float64)
            for k in cloning.CLONING_LOSSES}
  g_scale = {k: np.asarray(jax.grad(total, 2)(k, f32(mean), f32(scale)), np.float64)
             for k in cloning.CLONING_LOSSES}
  value = float(total("decoupled", f32(mean), f32(scale)))
  nll = lambda m, s: -stats.norm.logpdf(actions, m, s).sum()
  h = 1e-6
  fd_mean = np.zeros_like(mean)
  fd_scale = np.zeros_like(scale)
  for idx in np.ndindex(mean.shape):
    e = np.zeros_like(mean)
    e[idx] = h
    fd_mean[idx] = (nll(mean + e, scale) - nll(mean - e, scale)) / (2 * h)
    fd_scale[idx] = (nll(mean, scale + e) - nll(mean, scale - e)) / (2 * h)
  np.testing.assert_allclose(g_mean["likelihood"], fd_mean, rtol=1e-4, atol=1e-4)
  np.testing.assert_allclose(g_mean["decoupled"], mean - actions, rtol=1e-5, atol=1e-6)
  for kind in cloning.CLONING_LOSSES:
    np.testing.assert_allclose(g_scale[kind], fd_scale, rtol=1e-4, atol=1e-4)
  np.testing.assert_allclose(value, 0.5 * np.sum((mean - actions) ** 2) + nll(mean, scale),
                             rtol=1e-5)
  # The scale's term weighted (cloning_fit's variants): the scale's gradient scales with it,
  # the mean's does not change.
  weighted = lambda m, s: jnp.sum(cloning.fit_loss(DiagonalGaussian(m, s), f32(actions),
                                                   "decoupled", 0.01))
  np.testing.assert_allclose(jax.grad(weighted, 0)(f32(mean), f32(scale)), mean - actions,
                             rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(jax.grad(weighted, 1)(f32(mean), f32(scale)), 0.01 * fd_scale,
                             rtol=1e-4, atol=1e-5)
  np.testing.assert_allclose(float(weighted(f32(mean), f32(scale))),
                             0.5 * np.sum((mean - actions) ** 2) + 0.01 * nll(mean, scale),
                             rtol=1e-5)
  with pytest.raises(ValueError, match="unknown cloning loss 'mse'; valid: likelihood"):
    cloning.fit_loss(DiagonalGaussian(jnp.zeros(2), jnp.ones(2)), jnp.zeros(2), "mse")


def test_squared_loss_trains_the_shared_layers_on_the_mean_alone():
  """"squared" through the policy network: the layers below the last get the gradient of the
  mean's squared error alone (the scale's likelihood leaves them untouched), the last layer
  the decoupled fit's gradient; with the features held, the policy's outputs are unchanged."""
  networks = make_networks(3, width=16)
  rng = np.random.default_rng(4)
  x = jnp.asarray(rng.normal(size=(12, 5)), jnp.float32)
  actions = jnp.asarray(rng.uniform(-1, 1, size=(12, 3)), jnp.float32)
  params = networks.policy.init(jax.random.PRNGKey(3), x[:1])
  params = jax.tree.map(lambda p: p + 0.3 * jax.random.normal(jax.random.PRNGKey(5), p.shape),
                        params)  # (the last layer's initial weights are ~0)
  held = networks.policy.apply(params, x, hold_features=True)
  plain = networks.policy.apply(params, x)
  np.testing.assert_array_equal(np.asarray(held.mean), np.asarray(plain.mean))
  np.testing.assert_array_equal(np.asarray(held.scale), np.asarray(plain.scale))
  grad = lambda f: jax.grad(f)(params)["params"]
  squared = grad(lambda p: cloning.loss(networks, p, x, actions, "squared")[0])
  decoupled = grad(lambda p: cloning.loss(networks, p, x, actions, "decoupled")[0])
  mean_only = grad(lambda p: 0.5 * jnp.mean(jnp.sum(jnp.square(
      networks.policy.apply(p, x).mean - actions), -1)))
  last = [k for k in squared if k.startswith("Dense")]
  assert last == ["Dense_0"] and set(squared) == {"Encoder_0", "Dense_0"}
  for a, b in zip(jax.tree.leaves(squared["Encoder_0"]), jax.tree.leaves(mean_only["Encoder_0"])):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-7)
  for a, b in zip(jax.tree.leaves(squared["Dense_0"]), jax.tree.leaves(decoupled["Dense_0"])):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-7)
  # (and the decoupled fit's scale term does reach the shared layers: the difference is real)
  assert not all(np.allclose(a, b, rtol=1e-3, atol=1e-6) for a, b in zip(
      jax.tree.leaves(decoupled["Encoder_0"]), jax.tree.leaves(mean_only["Encoder_0"])))
  value = float(cloning.loss(networks, params, x, actions, "squared")[0])
  np.testing.assert_allclose(value, float(cloning.loss(networks, params, x, actions,
                                                       "decoupled")[0]), rtol=1e-6)


def test_both_cloning_losses_reach_the_actions_mean_and_deviation():
  """Fitting one state's free mean and scale to its actions by gradient descent, both losses
  end at numpy's mean and standard deviation of them (the same maximum-likelihood fit)."""
  actions = jnp.asarray(np.random.default_rng(3).normal([0.3, -0.5], [0.2, 0.05], (400, 2)),
                        jnp.float32)
  for kind in cloning.CLONING_LOSSES:
    def objective(p):
      pi = DiagonalGaussian(jnp.broadcast_to(p[0], actions.shape),
                            jnp.broadcast_to(jnp.exp(p[1]), actions.shape))
      return jnp.mean(cloning.fit_loss(pi, actions, kind))
    opt = optax.adam(1e-2)
    params = jnp.zeros((2, 2))
    state = opt.init(params)
    @jax.jit
    def step(p, s):
      change, s = opt.update(jax.grad(objective)(p), s, p)
      return optax.apply_updates(p, change), s
    for _ in range(4000):
      params, state = step(params, state)
    np.testing.assert_allclose(params[0], np.mean(np.asarray(actions), 0), atol=2e-3,
                               err_msg=kind)
    np.testing.assert_allclose(np.exp(params[1]), np.std(np.asarray(actions), 0), rtol=2e-2,
                               err_msg=kind)


def test_update_steps_the_policy_alone_on_standardised_observations():
  """One update is optax's step of the policy's optimiser on the loss's gradient at the
  observations standardised by the given normaliser; critic, targets and duals stay; the
  count and the average policy advance; repeated updates fit the actions."""
  config = LearnerConfig(learning_rate=1e-2, policy_average_decay=0.5)
  networks = make_networks(2, width=16)
  state = learner_lib.init(networks, config, jax.random.PRNGKey(1), 4, 2)
  rng = np.random.default_rng(1)
  norm = normalizer.NormalizerState(jnp.asarray(rng.normal(size=4), jnp.float32),
                                    jnp.asarray(rng.uniform(0.5, 2.0, size=4), jnp.float32),
                                    jnp.ones((), jnp.int32))
  obs = jnp.asarray(rng.normal(size=(32, 4)) * 3 + 1, jnp.float32)
  actions = jnp.tanh(obs[:, :2] - obs[:, 2:])
  new, metrics = cloning.update(networks, config, state, norm, obs, actions)
  x = (np.asarray(obs) - np.asarray(norm.mean)) / np.sqrt(np.asarray(norm.var) + 1e-6)
  pi = networks.policy.apply(state.policy, jnp.asarray(x, jnp.float32))  # (before the step)
  np.testing.assert_allclose(float(metrics["bc_log_prob"]), stats.norm.logpdf(
      np.asarray(actions, np.float64), np.asarray(pi.mean, np.float64),
      np.asarray(pi.scale, np.float64)).sum(-1).mean(), rtol=1e-5)
  grad = jax.grad(lambda p: cloning.loss(networks, p, jnp.asarray(x, jnp.float32),
                                         actions)[0])(state.policy)
  tx = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(1e-2))
  change, _ = tx.update(grad, tx.init(state.policy), state.policy)
  expected = optax.apply_updates(state.policy, change)
  for a, b in zip(jax.tree.leaves(new.policy), jax.tree.leaves(expected)):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
  decoupled = dataclasses.replace(config, cloning_loss="decoupled")  # its own loss's step
  new_d, _ = cloning.update(networks, decoupled, state, norm, obs, actions)
  grad_d = jax.grad(lambda p: cloning.loss(networks, p, jnp.asarray(x, jnp.float32), actions,
                                           "decoupled")[0])(state.policy)
  change_d, _ = tx.update(grad_d, tx.init(state.policy), state.policy)
  for a, b, c in zip(jax.tree.leaves(new_d.policy),
                     jax.tree.leaves(optax.apply_updates(state.policy, change_d)),
                     jax.tree.leaves(new.policy)):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
  assert any(not np.allclose(a, c) for a, c in zip(jax.tree.leaves(new_d.policy),
                                                   jax.tree.leaves(new.policy)))
  for part in ("critic", "target_critic", "target_policy", "duals", "critic_opt", "dual_opt"):
    for a, b in zip(jax.tree.leaves(getattr(new, part)), jax.tree.leaves(getattr(state, part))):
      np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=part)
  assert int(new.updates) == 1
  for a, b in zip(jax.tree.leaves(new.average_policy), jax.tree.leaves(new.policy)):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # the mean of one update
  assert float(metrics["policy_grad_norm"]) > 0
  step = jax.jit(lambda s: cloning.update(networks, config, s, norm, obs, actions))
  errors = []
  for _ in range(200):
    new, metrics = step(new)
    errors.append(float(metrics["bc_action_error"]))
  assert errors[-1] < 0.2 * errors[0], errors[::40]


def _demos(episodes=3, steps=5):
  """Observations [K, T+1, 6] whose first two features name their episode and step; actions
  [K, T, 2] the same two: a drawn pair shows where it came from."""
  k, t = np.meshgrid(np.arange(episodes), np.arange(steps + 1), indexing="ij")
  obs = np.zeros((episodes, steps + 1, 6), np.float32)
  obs[..., 0], obs[..., 1] = k, t
  obs[..., 2:] = np.random.default_rng(0).normal(size=(episodes, steps + 1, 4))
  return obs, obs[:, :-1, :2].copy()


def test_pairs_are_the_demonstrations_transitions_drawn_uniformly():
  """Each drawn observation comes with the action taken at it; the final observations of the
  episodes (no action) are never drawn; every transition is drawn about as often."""
  obs, actions = _demos()
  source = BehaviourCloning(obs, actions, "sha")
  state = source.init(jax.random.PRNGKey(0), 6, 2)
  x, a, metrics = jax.jit(lambda k: source.policy_targets(state, k, 30000))(
      jax.random.PRNGKey(3))
  x, a = np.asarray(x), np.asarray(a)
  np.testing.assert_array_equal(x[:, :2], a)
  k, t = a[:, 0].astype(int), a[:, 1].astype(int)
  np.testing.assert_array_equal(x, obs[k, t])
  counts = np.bincount(k * 5 + t, minlength=15)
  assert counts.min() > 0 and t.max() == 4
  assert stats.chisquare(counts).pvalue > 1e-3, counts
  # the same draws from the data as the compiled iteration passes it
  bound = source.with_data(jax.tree.map(jnp.asarray, source.data()))
  np.testing.assert_array_equal(np.asarray(bound.policy_targets(
      state, jax.random.PRNGKey(3), 30000)[0]), x)
  assert metrics == {}


def test_source_refuses_demonstrations_that_do_not_fit():
  obs, actions = _demos()
  for bad_obs, bad_actions in ((obs, actions[:2]), (obs, actions[:, :4]), (obs[0], actions),
                               (obs[:, :1], actions[:, :0])):
    with pytest.raises(ValueError, match="observations \\[K, T\\+1, D\\] and actions"):
      BehaviourCloning(bad_obs, bad_actions)
  with pytest.raises(ValueError, match="finite"):
    BehaviourCloning(obs, np.full_like(actions, np.nan))
  source = BehaviourCloning(obs, actions)
  with pytest.raises(ValueError, match="6-dimensional observations and 2-dimensional actions"):
    source.init(jax.random.PRNGKey(0), 6, 3)
  assert source.settings() == {"demonstrations_sha256": "", "demonstration_episodes": 3}


CONFIG = TrainConfig(task="reacher_easy", reward_source="bc", num_envs=4, unroll_length=50,
                     batch_size=4, replay_capacity=12, updates_per_iteration=2,
                     network_width=32, eval_envs=2,
                     learner=LearnerConfig(learning_rate=3e-3, num_action_samples=4,
                                           cloning_loss="squared"))  # (run.py's default)


def _bc_source():
  """Demonstrations whose actions are a fixed function of their observations (stand in for
  an expert's)."""
  rng = np.random.default_rng(5)
  obs = (rng.normal(size=(4, 51, 6)) * [1, 2, 3, 0.5, 1, 4] + [0, 1, -2, 0, 3, 0]).astype(
      np.float32)
  actions = np.tanh(obs[:, :-1, :2] - 0.5 * obs[:, :-1, 2:4]).astype(np.float32)
  return BehaviourCloning(obs, actions, "sha"), obs


def test_bc_trains_the_policy_in_the_compiled_loop():
  """BC in the compiled loop over the mesh, two members (seeds): each member's policy fits the
  actions (its error falls) on its own draws, the critic and the duals are never trained, and
  the normaliser follows the demonstrations' observations (not the imitator's). (That the
  cloning learner trains blind to the task reward is test_bco's compiled-loop test: one program
  fewer to compile here.)"""
  source, obs = _bc_source()
  trainer = Trainer(CONFIG, mesh_lib.make_mesh(), source, seeds=(0, 1))
  assert trainer.clones
  state = fresh = trainer.init(trainer.keys())
  fresh = jax.device_get(fresh.learner)
  metrics = []
  for _ in range(6):
    state, m = trainer.iteration(state)
    metrics.append(jax.device_get(m))
  for member in (0, 1):
    errors = [float(m["bc_action_error"][member]) for m in metrics]
    assert errors[-1] < 0.5 * errors[0], (member, errors)
  assert metrics[-1]["bc_action_error"][0] != metrics[-1]["bc_action_error"][1]
  np.testing.assert_array_equal(np.asarray(state.learner.updates), [12, 12])
  for part in ("critic", "target_critic", "duals"):
    for a, b in zip(jax.tree.leaves(getattr(state.learner, part)),
                    jax.tree.leaves(getattr(fresh, part))):
      np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=part)
  flat = obs[:, :-1].reshape(-1, 6)  # the observations pairs are drawn from
  for member in (0, 1):
    np.testing.assert_allclose(np.asarray(state.normalizer.mean)[member], flat.mean(0),
                               atol=0.15 * flat.std(0).max())
    np.testing.assert_allclose(np.sqrt(np.asarray(state.normalizer.var)[member]), flat.std(0),
                               rtol=0.15)
  assert "q_mean" not in metrics[-1] and np.isfinite(metrics[-1]["bc_log_prob"][0])


def test_bc_config_names_its_source():
  with pytest.raises(ValueError, match="names reward source 'form'"):
    Trainer(dataclasses.replace(CONFIG, reward_source="form"), mesh_lib.make_mesh(),
            _bc_source()[0])


def test_run_py_bc_and_bco_take_their_demonstrations_and_refuse_what_does_not_fit(
    tmp_path, capsys):
  """`scripts/run.py --method bc` and `bco`, up to the training (which the compiled-loop tests
  run): demonstrations recorded with actions from the shipped expert carry the checksum of the
  file --save_demos writes of them (a resume compares the two); BC's source takes the
  observations and actions, BCO's the observations and the task's bounds; both take the
  paper's settings (not FORM's per-task ones); BC's progress line reports its fit;
  demonstrations without actions are refused for BC with exit status 2 naming the file,
  nothing written; options BC and BCO have no use for are usage errors."""
  from conftest import load_script
  from mjx_form.files import demos
  from mjx_form.imitation import pipeline
  from mjx_form.rl import runner
  from test_gaifo import SMALL_RUN
  at = SMALL_RUN.index("--num_action_samples")  # (MPO's: BC and BCO refuse it)
  small = SMALL_RUN[:at] + SMALL_RUN[at + 2:]
  cli = load_script("run")
  env = tasks.make("reacher_easy")
  saved = tmp_path / "demos.npz"
  obs, actions, info = pipeline.demonstrations(
      env, pipeline.Artefacts(save_demos=str(saved)), 1, "fast", 0, lambda *_: None,
      with_actions=True)
  assert obs.shape == (1, 1001, env.observation_size) and actions.shape == (1, 1000, 2)
  assert info["sha256"] == demos.load_demonstrations(saved).metadata["sha256"]
  for method, kind in (("bc", BehaviourCloning), ("bco", BcoSource)):
    args = cli.parse_args([*small, "--method", method, "--demos", str(saved)])
    source, seen = cli.cloning_source(args, str(tmp_path / method), lambda *_: None)
    assert isinstance(source, kind) and source.observations.shape == obs.shape
    # the records carry the demonstrations' mean return (the expert's level they imitate)
    assert cli.demonstrations_fields(seen) == {
        "demonstrations_return": round(float(info["expert"]["mean_return"]), 2)}
    assert source.demonstrations_sha256 == (info["sha256"] if method == "bc" else
                                            demos.checksum({"observations": obs}))
    config = cli.train_config(args)
    assert config.reward_source == method and config.policy_head == "paper"
    assert config.learner.policy_average_decay == 0.0 and not config.angle_features
    assert config.learner.cloning_loss == "squared"  # (the default: cloning.py)
    assert cli.train_config(cli.parse_args([*small, "--method", method, "--cloning_loss",
                                            "likelihood"])).learner.cloning_loss == "likelihood"
  assert cli.train_config(cli.parse_args(small)).learner.cloning_loss == "likelihood"  # unused
  np.testing.assert_array_equal(source.low, env.action_bounds[0])  # (BCO's)
  row = {"iteration": 2, "env_steps": 400, "wall_s": 9.0, "steps_per_s": 50.0,
         "train_return": float("nan"), "bc_log_prob": -1.25, "bc_action_error": 0.0312,
         "mean_out_of_bounds": 0.0}
  assert "bc log-likelihood -1.25  action error 0.0312" in runner._progress_line(row, 4, 200)
  assert {"bc_log_prob", "bc_action_error"} <= set(runner._CURVE_FIELDS)
  observations = demos.save_demonstrations(
      tmp_path / "observations.npz", np.zeros((1, 3, env.observation_size), np.float32),
      metadata={"task": "reacher_easy", "observation_layout": env.observation_layout,
                "physics": "fast", "expert": {}})
  capsys.readouterr()
  assert cli.main([*small, "--method", "bc", "--demos", str(observations), "--run_dir",
                   str(tmp_path / "refused"), "--env_steps", "400"]) == 2
  err = capsys.readouterr().err
  assert "observations.npz" in err and "needs actions" in err
  assert not (tmp_path / "refused").exists()
  for method in ("bc", "bco"):
    for argv, message in ((["--reward_scale", "raw"], f"--method {method} has no reward"),
                          (["--demo_episodes", "0"], f"--method {method} needs demonstrations"),
                          (["--gradient_penalty", "1"], "apply to --method gaifo"),
                          (["--beta_ar", "1"], "apply to --method form only"),
                          (["--target_update_period", "5", "--preset", "paper"],
                           f"--target_update_period, --preset: --method {method} fits the "
                           "policy alone"),
                          (["--grid", "epsilon=0.1,0.2"], "--grid epsilon: --method")):
      with pytest.raises(SystemExit):
        cli.parse_args(["--method", method, *argv])
      assert message in capsys.readouterr().err
  assert cli.parse_args(["--method", "bc", "--grid", "learning_rate=1e-4,1e-3"]).grid
  for method in ("form", "gaifo", "expert"):
    with pytest.raises(SystemExit):
      cli.parse_args(["--method", method, "--cloning_loss", "decoupled"])
    assert "--cloning_loss applies to --method bco, bc" in capsys.readouterr().err
  # a BC run from before the flag (fitted by likelihood), refused on resume, is told how
  from mjx_form.files import checkpoint
  refused = checkpoint.CheckpointError("differs", ("learner.cloning_loss",))
  hint = cli.recipe_hint(cli.parse_args(["--method", "bc", "--resume"]), refused)
  assert "--cloning_loss likelihood for one started before" in hint
  assert "decoupled for one started before 2026-12-07" in hint
  with pytest.raises(SystemExit):
    cli.parse_args(["--method", "expert", "--reward_scale", "raw"])
  assert "--reward_scale applies to --method form, gaifo, gaifo_gp, vaifo, vaifo_gp" in (
      capsys.readouterr().err)
