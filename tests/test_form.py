"""FORM in the compiled loop: the reward, episode boundaries in the replay's unrolls, training
that never sees the task reward, and `scripts/run.py --method form` through every stage, from
the README's main command on (reacher_easy, small sizes; the loop runs over the 2 forced host
devices)."""

import csv
import dataclasses
import json
import os
import re
import subprocess
import sys
import time
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import load_script
from test_readme_commands import run_commands

import tasks
from mjx_form import cpu
from mjx_form import mesh as mesh_lib
from mjx_form.files import checkpoint, demos, effect_models, experts, policy_io, results
from mjx_form.imitation import effect_model as em
from mjx_form.imitation import settings
from mjx_form.imitation.form import ENSEMBLE_LOG_PD, Demonstrator, FormReward
from mjx_form.rl import normalizer
from mjx_form.rl.learner import LearnerConfig
from mjx_form.rl.train import TrainConfig, Trainer
from mjx_form.sim import env as env_lib
from tasks import reacher

pytestmark = pytest.mark.xdist_group("form")

CONFIG = TrainConfig(task="reacher_easy", reward_source="form", num_envs=4, unroll_length=50,
                     batch_size=4, replay_capacity=12, updates_per_iteration=2,
                     network_width=32, eval_envs=2,
                     learner=LearnerConfig(num_action_samples=4, target_update_period=3))
EFFECT = em.EffectModelConfig(width=32)
D = 6  # reacher's observation size


def _demonstrator(seed=0) -> Demonstrator:
  """An untrained demonstrator with its own standardisation (stands in for a trained one)."""
  params = em.make_model(EFFECT, D).init(jax.random.PRNGKey(seed), jnp.zeros((1, D)))
  rng = np.random.default_rng(seed)
  norm = normalizer.NormalizerState(jnp.asarray(rng.normal(size=D), jnp.float32),
                                    jnp.asarray(rng.uniform(0.2, 3.0, size=D), jnp.float32),
                                    jnp.asarray(1, jnp.int32))
  return Demonstrator(params, norm)


class GarbageRewardReacher(reacher.Reacher):
  """reacher_easy with a reward that has nothing to do with the task (finite, so no episode
  ends differently)."""

  def get_reward(self, data, task):
    return 1e3 * jnp.sin(1e4 * jnp.sum(data.qpos) + task["target"][0])


@pytest.fixture(scope="module")
def form_trainer():
  return Trainer(CONFIG, mesh_lib.make_mesh(), FormReward(EFFECT, _demonstrator()))


def _iterate(trainer, n, key=0):
  state, metrics = trainer.init(jax.random.PRNGKey(key)[None]), []
  for _ in range(n):
    state, m = trainer.iteration(state)
    metrics.append(jax.device_get(m))
  return state, metrics


def test_relabel_is_the_difference_of_the_two_log_densities():
  source = FormReward(EFFECT, _demonstrator(0))
  state = source.init(jax.random.PRNGKey(1), D, 2)
  rng = np.random.default_rng(2)
  obs = jnp.asarray(rng.normal(size=(3, 5, D)), jnp.float32)
  discount = jnp.ones((3, 4)).at[1, 2].set(0.0)
  rewards, metrics = source.relabel(state, {"observation": obs, "discount": discount})
  model = em.make_model(EFFECT, D)
  log_d = em.transition_log_prob(model, state.demonstrator.params,
                                 state.demonstrator.normalizer, obs[:, :-1], obs[:, 1:])
  log_i = em.transition_log_prob(model, state.imitator.params, state.imitator.normalizer,
                                 obs[:, :-1], obs[:, 1:])
  expected = np.where(np.asarray(discount) > 0, log_d - log_i, 0.0)
  np.testing.assert_allclose(rewards, expected, rtol=1e-5, atol=1e-5)
  assert float(rewards[1, 2]) == 0.0  # no successor in this episode: no reward
  np.testing.assert_allclose(metrics["form_reward"], expected.sum() / 11, rtol=1e-5)
  # An imitator model equal to the demonstrator gives reward 0 everywhere.
  same = state._replace(imitator=state.imitator._replace(
      params=state.demonstrator.params, normalizer=state.demonstrator.normalizer))
  np.testing.assert_array_equal(source.relabel(same, {"observation": obs,
                                                      "discount": discount})[0], 0.0)


@pytest.mark.slow
def test_an_ensemble_of_demonstrators_scores_with_their_mixture():
  """Several demonstrators: log pD is the log of the mean of their densities (numpy, float64,
  from each model's own log pD); the same model twice is that model; one is no ensemble; models
  of other shapes and an empty list are refused; the reward is log pD - log pI as before."""
  model = em.make_model(EFFECT, D)
  members = [_demonstrator(0), _demonstrator(3), _demonstrator(5)]
  source = FormReward(EFFECT, members, "a+b+c")
  assert source.ensemble == 3 and source.settings()["demonstrators"] == 3
  state = source.init(jax.random.PRNGKey(1), D, 2)
  assert state.demonstrator.normalizer.mean.shape == (3, D)
  obs = jnp.asarray(np.random.default_rng(2).normal(size=(3, 5, D)), jnp.float32)
  discount = jnp.ones((3, 4))
  log_d, log_i = source.log_probs(state, obs)
  each = np.stack([np.asarray(em.transition_log_prob(model, d.params, d.normalizer,
                                                     obs[:, :-1], obs[:, 1:]), np.float64)
                   for d in members])
  mixture = np.logaddexp.reduce(each, axis=0) - np.log(3)
  np.testing.assert_allclose(log_d, mixture, rtol=1e-5, atol=1e-4)
  assert np.all(np.asarray(log_d) >= each.max(axis=0) - np.log(3) - 1e-4)
  assert np.ptp(each, axis=0).max() > 1.0  # (the members differ: the test could fail)
  rewards, _ = source.relabel(state, {"observation": obs, "discount": discount})
  np.testing.assert_allclose(rewards, np.asarray(log_d) - np.asarray(log_i), rtol=1e-5,
                             atol=1e-4)
  twice = FormReward(EFFECT, [members[1], members[1]])
  single = FormReward(EFFECT, members[1])
  np.testing.assert_allclose(twice.log_probs(twice.init(jax.random.PRNGKey(1), D, 2), obs)[0],
                             single.log_probs(single.init(jax.random.PRNGKey(1), D, 2), obs)[0],
                             rtol=1e-5, atol=1e-4)
  one = FormReward(EFFECT, [members[0]])
  assert one.ensemble == 0 and "demonstrators" not in one.settings()
  assert one.demonstrator.normalizer.mean.shape == (D,)
  wider = em.make_model(em.EffectModelConfig(width=16), D).init(jax.random.PRNGKey(0),
                                                               jnp.zeros((1, D)))
  with pytest.raises(ValueError):
    FormReward(EFFECT, [members[0], members[0]._replace(params=wider)])
  for bad in ([], tuple(members[0]), [members[0], tuple(members[1])]):  # (a plain tuple is
    with pytest.raises(TypeError, match="a Demonstrator or a list"):      # no Demonstrator)
      FormReward(EFFECT, bad)


@pytest.mark.slow
def test_an_ensemble_can_score_with_the_mean_of_its_log_densities():
  """`ensemble_log_pd="mean"`: log pD is the mean of the models' own log pD (numpy, float64),
  below the mixture's wherever they differ (Jensen), and the reward is log pD - log pI; the
  setting is recorded only where it is not the mixture. Refused: an unknown name, and the mean
  without an ensemble (one model, or models per member)."""
  model = em.make_model(EFFECT, D)
  members = [_demonstrator(0), _demonstrator(3), _demonstrator(5)]
  mean = FormReward(EFFECT, members, "a+b+c", ensemble_log_pd="mean")
  mixture = FormReward(EFFECT, members, "a+b+c")
  assert mean.settings()["ensemble_log_pd"] == "mean" and mean.settings()["demonstrators"] == 3
  assert "ensemble_log_pd" not in mixture.settings()
  state = mean.init(jax.random.PRNGKey(1), D, 2)
  obs = jnp.asarray(np.random.default_rng(2).normal(size=(3, 5, D)), jnp.float32)
  each = np.stack([np.asarray(em.transition_log_prob(model, d.params, d.normalizer,
                                                     obs[:, :-1], obs[:, 1:]), np.float64)
                   for d in members])
  assert np.ptp(each, axis=0).min() > 0.1  # (the members differ everywhere: the test can fail)
  log_d, log_i = mean.log_probs(state, obs)
  np.testing.assert_allclose(log_d, each.mean(axis=0), rtol=1e-5, atol=1e-4)
  mixed = np.asarray(mixture.log_probs(state, obs)[0])
  assert np.all(np.asarray(log_d) < mixed)
  rewards, _ = mean.relabel(state, {"observation": obs, "discount": jnp.ones((3, 4))})
  np.testing.assert_allclose(rewards, np.asarray(log_d) - np.asarray(log_i), rtol=1e-5,
                             atol=1e-4)
  with pytest.raises(ValueError, match="ensemble_log_pd must be one of"):
    FormReward(EFFECT, members, ensemble_log_pd="product")
  with pytest.raises(ValueError, match="needs an ensemble of 2 demonstrators or more .*got one"):
    FormReward(EFFECT, members[0], ensemble_log_pd="mean")
  with pytest.raises(ValueError, match="got 3 per member"):
    FormReward(EFFECT, members, ["a", "b", "c"], member_demonstrators=True,
               ensemble_log_pd="mean")
  # Population members may differ in it (`--grid ensemble_log_pd=...`): traced per member as its
  # index in ENSEMBLE_LOG_PD, each member gets what its own source gives; as a Python value the
  # member's source records it.
  index = jnp.array([ENSEMBLE_LOG_PD.index(v) for v in ("mixture", "mean")], jnp.int32)
  traced = np.asarray(jax.vmap(lambda v: mixture.specialise({"ensemble_log_pd": v}).log_probs(
      state, obs)[0])(index))
  np.testing.assert_allclose(traced[0], mixed, rtol=1e-6, atol=1e-6)
  np.testing.assert_allclose(traced[1], np.asarray(log_d), rtol=1e-6, atol=1e-6)
  assert mixture.specialise({"ensemble_log_pd": "mean"}).settings()["ensemble_log_pd"] == "mean"
  assert "ensemble_log_pd" not in mean.specialise({"ensemble_log_pd": "mixture"}).settings()
  for source, value, message in ((mixture, "product", "must be one of"),
                                 (FormReward(EFFECT, members[0]), "mean", "got one")):
    with pytest.raises(ValueError, match=message):
      source.specialise({"ensemble_log_pd": value})


def _evaluation_reference(trainer, state, demonstrators: list[Demonstrator]):
  """What `Trainer.evaluate` should give (member i seeded by `keys(1)[i]`, its own policy's
  mean action, one whole episode per environment), computed here on its own: the task returns
  [P, n] and member i's demonstrator's mean log pD per transition of each episode [P, n]."""
  x, x_next, reward = _evaluation_episodes(trainer, state)
  model = em.make_model(EFFECT, D)
  log_pd = [np.asarray(em.transition_log_prob(model, d.params, d.normalizer, x[i], x_next[i]))
            for i, d in enumerate(demonstrators)]
  return reward.sum(axis=-1), np.mean(log_pd, axis=-1)


def _evaluation_episodes(trainer, state):
  """The episodes `Trainer.evaluate` should roll out, rolled out here on their own: x, x_next
  [P, n, T, D] and rewards [P, n, T]."""
  p, n = trainer.members, trainer.config.eval_envs
  keys = jax.vmap(lambda k: jax.random.split(k, n))(trainer.keys(1)).reshape(-1, 2)
  apply = jax.vmap(lambda params, norm, obs: trainer.networks.policy.apply(
      params, normalizer.normalize(norm, obs)).mode())

  @jax.jit
  def episodes(env_state, policy, norm):
    def step(s, _):
      action = apply(policy, norm, s.obs.reshape(p, n, -1)).reshape(p * n, -1)
      after = jax.vmap(trainer.env.step)(s, action)
      return after, (s.obs, after.obs, after.reward)
    return jax.lax.scan(step, env_state, None, length=env_lib.EPISODE_LENGTH)[1]

  x, x_next, reward = jax.device_get(episodes(trainer.auto_reset.reset_from_keys(keys),
                                              state.learner.policy, state.normalizer))
  by_member = lambda v: np.moveaxis(v.reshape(v.shape[0], p, n, *v.shape[2:]), 0, 2)
  return by_member(x), by_member(x_next), by_member(reward)  # [P, n, T, ...]


def test_evaluation_scores_episodes_with_the_demonstrator(form_trainer):
  """FORM's evaluation also gives each episode's mean log pD per transition (the policy's mean
  action; no task reward needed): what a rollout of the same episodes scored by the
  demonstrator gives, next to the same returns."""
  state, _ = _iterate(form_trainer, 1)
  inputs = form_trainer.evaluation_inputs(state)
  assert set(inputs) == {"source", "source_settings"} and inputs["source_settings"] == {}
  returns, scores = form_trainer.evaluate((state.learner.policy,), (state.normalizer,),
                                          form_trainer.keys(1), **inputs)
  returns, scores = returns[0], scores[0]  # (the one policy's)
  assert np.asarray(scores).shape == (1, CONFIG.eval_envs)
  want_returns, want_scores = _evaluation_reference(form_trainer, state, [_demonstrator()])
  np.testing.assert_allclose(np.asarray(returns), want_returns, rtol=1e-4, atol=1e-3)
  np.testing.assert_allclose(np.asarray(scores), want_scores, rtol=1e-4, atol=1e-3)
  assert np.ptp(want_scores) > 0 or abs(want_scores[0, 0]) > 1.0  # (not a constant of nothing)


def test_policies_evaluated_together_each_give_their_own_episodes(form_trainer):
  """Several policies evaluated in one call (the online and the average policy at each
  evaluation; the final and the kept ones at the end) give what each gives alone: the same
  starts, each stepped with its own policy and normaliser, its own returns and log pD."""
  state, _ = _iterate(form_trainer, 1)
  other_policy = jax.tree.map(lambda w: 1.5 * w + 0.05, state.learner.policy)
  other_norm = state.normalizer._replace(mean=state.normalizer.mean + 0.3)
  returns, scores = jax.device_get(form_trainer.evaluate(
      (state.learner.policy, other_policy), (state.normalizer, other_norm),
      form_trainer.keys(1), **form_trainer.evaluation_inputs(state)))
  assert returns.shape == scores.shape == (2, 1, CONFIG.eval_envs)
  other = state._replace(learner=state.learner._replace(policy=other_policy),
                         normalizer=other_norm)
  for k, alone in enumerate((state, other)):
    want_returns, want_scores = _evaluation_reference(form_trainer, alone, [_demonstrator()])
    np.testing.assert_allclose(returns[k], want_returns, rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(scores[k], want_scores, rtol=1e-4, atol=1e-3)
  assert np.abs(scores[0] - scores[1]).max() > 0.1  # (the two policies' episodes differ)


def test_a_policy_evaluated_with_sampled_actions_draws_them_at_its_scale(form_trainer):
  """`sampled` [K] evaluates a policy with actions drawn from it each step: the policy beside it
  keeps its mean actions' episodes; the draws differ from the mean actions by the policy's
  scale (at the smallest scale, 1e-4, the episodes are the mean actions' to rounding)."""
  state, _ = _iterate(form_trainer, 1)
  policy, norm, keys = state.learner.policy, state.normalizer, form_trainer.keys(1)
  inputs = form_trainer.evaluation_inputs(state)
  alone = jax.device_get(form_trainer.evaluate((policy,), (norm,), keys, **inputs))
  both = jax.device_get(form_trainer.evaluate((policy, policy), (norm, norm), keys, **inputs,
                                              sampled=np.array([0.0, 1.0], np.float32)))
  for got, want in zip(both, alone):  # (returns, log pD): the mean actions' as alone
    np.testing.assert_allclose(got[0], want[0], rtol=1e-5, atol=1e-4)
  assert np.abs(both[1][1] - both[1][0]).max() > 0.1  # (the draws' episodes differ)
  head = policy["params"]["Dense_0"]  # (mean, raw scale): the raw scale at -30 everywhere
  a = head["bias"].shape[-1] // 2
  narrow = jax.tree.map(lambda x: x, policy)
  narrow["params"]["Dense_0"] = {"kernel": head["kernel"].at[..., a:].set(0.0),
                                 "bias": head["bias"].at[..., a:].set(-30.0)}
  returns, scores = jax.device_get(form_trainer.evaluate(
      (narrow, narrow), (norm, norm), keys, **inputs, sampled=np.array([0.0, 1.0], np.float32)))
  np.testing.assert_allclose(returns[1], returns[0], rtol=1e-3, atol=1e-2)
  np.testing.assert_allclose(scores[1], scores[0], rtol=1e-3, atol=1e-2)


def test_policies_beyond_the_env_limit_go_to_calls_of_one_size(form_trainer, monkeypatch):
  """The runner's evaluations: policies beyond EVALUATION_ENVS environments go to further calls
  of one size (the last padded, one program), each policy's own returns and log pD in order."""
  from mjx_form.rl import runner
  state, _ = _iterate(form_trainer, 1)
  pairs = [(jax.tree.map(lambda w: scale * w, state.learner.policy), state.normalizer)
           for scale in (1.0, 1.5, 2.0)]
  keys = form_trainer.keys(1)
  calls, evaluate = [], form_trainer.evaluate  # (each call: how many policies it evaluates)
  monkeypatch.setattr(form_trainer, "evaluate",
                      lambda *a, **k: calls.append(len(a[0])) or evaluate(*a, **k))
  together = runner._evaluated(form_trainer, state, pairs, keys)
  monkeypatch.setattr(runner, "EVALUATION_ENVS", 2 * CONFIG.eval_envs)  # two policies a call
  split = runner._evaluated(form_trainer, state, pairs, keys)
  assert calls == [3, 2, 2]
  for (returns, scores), (want_returns, want_scores) in zip(split, together):
    np.testing.assert_allclose(returns, want_returns, rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(scores, want_scores, rtol=1e-4, atol=1e-3)
  assert min(np.abs(together[i][1] - together[j][1]).max()
             for i, j in ((0, 1), (0, 2), (1, 2))) > 0.1  # (the three policies differ)


@pytest.mark.slow
def test_evaluations_on_the_host_write_what_evaluations_on_the_accelerator_write(tmp_path,
                                                                                  monkeypatch):
  """`eval_on_host` (run.py --eval_on_host): a FORM population with an average policy, trained
  on one device and evaluated on both, its batch split over them (standing in for a GPU and
  its host's CPU devices), writes the same rows, records and kept policies as evaluating on
  the training's device: evaluations every 2 iterations, a checkpoint every 3 (which waits for
  the evaluation before it), the last iteration's, the final ones, with each evaluation still
  running until it is waited for (the rows behind it held back; evaluations done once ready,
  after a few looks, are test_a_checkpoint_due_while_the_host_evaluates_waits_for_its_rows').
  The rows come in order, each once."""
  from mjx_form.rl import runner
  assert jax.device_count() == 2  # (tests/conftest.py)
  config = dataclasses.replace(CONFIG, learner=dataclasses.replace(
      CONFIG.learner, policy_average_decay=0.5))
  out = {}
  host = {"eval_on_host": True}  # (on both devices: the default, every CPU device)
  for name, more in (("accelerator", {}), ("late", host)):
    if name == "late":  # (done only once waited for)
      monkeypatch.setattr(runner._Evaluation, "done", lambda self: self.results is not None)
    run_dir, curve = tmp_path / name, tmp_path / f"{name}.jsonl"
    runner.run(config, str(run_dir), 7 * config.env_steps_per_iteration, eval_every=2,
               checkpoint_every=3, final_eval_envs=2, results_path=str(curve),
               mesh=mesh_lib.make_mesh(jax.devices()[:1]),
               reward_source=FormReward(EFFECT, _demonstrator()), seeds=(0, 1),
               print_fn=lambda *_: None, **more)
    out[name] = run_dir, results.read_records(str(curve))
  timing = {"wall_s", "eval_s", "steps_per_s", "peak_memory_bytes", "startup_s", "time",
            "persistent_cache_hits", "settings"}
  (run_dir, records) = out["accelerator"]
  _same_run_written(run_dir, records, *out["late"], timing)
  # Everything the host's program holds lies on the host device: its environment's model too
  # (MJX would place it on the first device of the default backend, a GPU).
  trainer = Trainer(config, mesh_lib.make_mesh(jax.devices()[:1]),
                    FormReward(EFFECT, _demonstrator()))
  host = runner._HostEvaluation(trainer, jax.devices()[1:], trainer.keys(1), 1)
  assert {d for leaf in jax.tree.leaves(host.trainer.env.mjx_model)
          if isinstance(leaf, jax.Array) for d in leaf.devices()} == {jax.devices()[1]}
  assert host.keys.devices() == {jax.devices()[1]}
  # By default, the host's CPU devices, as many as divide the evaluation's batch and the
  # environments: here both (2 members x 2 policies x 2 episodes, 4 environments) or one.
  assert runner._HostEvaluation(trainer, None, trainer.keys(1), 1).devices == jax.devices()
  odd = dataclasses.replace(config, num_envs=3, eval_envs=3)
  trainer = Trainer(odd, mesh_lib.make_mesh(jax.devices()[:1]), FormReward(EFFECT,
                                                                         _demonstrator()))
  assert runner._HostEvaluation(trainer, None, trainer.keys(1), 1).devices == jax.devices()[:1]


@pytest.mark.slow
def test_a_run_stopped_by_max_seconds_skips_its_last_host_evaluation(tmp_path, capsys,
                                                                      monkeypatch):
  """With `eval_on_host`, a run that `max_seconds` stops does not start a host evaluation of its
  last iteration (its end would wait for it; the final evaluations on the accelerator come next):
  its last row has no periodic evaluation, and its final_return records are written; one whose
  time runs out while the host evaluates trains on until that evaluation is done. (On the
  accelerator the same stop evaluates the last iteration: test_train's
  test_command_line_trains_resumes_and_refuses_mismatches.)"""
  from mjx_form.rl import runner
  curve = tmp_path / "curve.jsonl"
  rows = runner.run(CONFIG, str(tmp_path / "run"), 50 * CONFIG.env_steps_per_iteration,
                    eval_every=10, max_seconds=1e-3, final_eval_envs=2, results_path=str(curve),
                    mesh=mesh_lib.make_mesh(jax.devices()[:1]),
                    reward_source=FormReward(EFFECT, _demonstrator()), print_fn=lambda *_: None,
                    eval_on_host=True, host_devices=jax.devices()[1:])
  assert rows[0]["iteration"] == 1 and "eval_return" not in rows[0]
  kinds = [r["kind"] for r in results.read_records(str(curve))]
  assert "learning_curve" not in kinds and "final_return" in kinds
  # A run whose time runs out while the host evaluates trains on, starting no evaluation,
  # until that one is done (here: time runs out as iteration 1's starts, and it takes until
  # the 4th look), and writes it.
  clock, looks = [0.0], {}
  real_start, real_done = runner._HostEvaluation.start, runner._Evaluation.done

  def start(self, state, pairs):
    clock[0] = 1e9  # (the budget is spent)
    return real_start(self, state, pairs)

  def done(self):
    looks[id(self)] = looks.get(id(self), 0) + 1
    return looks[id(self)] > 3 and real_done(self)

  monkeypatch.setattr(runner, "time", types.SimpleNamespace(
      perf_counter=lambda: time.perf_counter() + clock[0]))
  monkeypatch.setattr(runner._HostEvaluation, "start", start)
  monkeypatch.setattr(runner._Evaluation, "done", done)
  said = []
  curve = tmp_path / "curve2.jsonl"
  rows = runner.run(CONFIG, str(tmp_path / "run2"), 50 * CONFIG.env_steps_per_iteration,
                    eval_every=1, max_seconds=1e6, final_eval_envs=0, results_path=str(curve),
                    mesh=mesh_lib.make_mesh(jax.devices()[:1]),
                    reward_source=FormReward(EFFECT, _demonstrator()), print_fn=said.append,
                    eval_on_host=True, host_devices=jax.devices()[1:])
  points = [r for r in results.read_records(str(curve)) if r["kind"] == "learning_curve"]
  assert [p["iteration"] for p in points] == [1]
  assert 2 < rows[0]["iteration"] < 50 and "eval_return" not in rows[0]
  assert any(f"training on for {rows[0]['iteration'] - 2} iteration(s) while the host" in line
             for line in said)
  monkeypatch.undo()
  # run.py --eval_on_host asks JAX for a CPU device per core (too late here: JAX has started)
  # and refuses a run that trains on the CPU itself, before anything is written.
  assert not cpu.one_device_per_core()
  cli = load_script("run")
  assert cli.main(["--task", "reacher_easy", "--eval_on_host", "--run_dir",
                   str(tmp_path / "cpu")]) == 2
  assert "--eval_on_host evaluates on the host's CPU beside an accelerator" in (
      capsys.readouterr().err)
  assert not (tmp_path / "cpu").exists()


@pytest.mark.slow
def test_a_checkpoint_due_while_the_host_evaluates_waits_for_its_rows(tmp_path, monkeypatch):
  """With `eval_on_host`, a checkpoint due as an evaluation starts there is saved at the first
  iteration after it with every row written (the accelerator trains on meanwhile), and a run
  resumed from it continues the CSV without a gap.
  (Here each evaluation says it is running the first 3 times it is asked.)"""
  from mjx_form.rl import runner
  looks, saved = {}, []
  real_done, real_save = runner._Evaluation.done, runner.checkpoint.save

  def done(self):
    looks[id(self)] = looks.get(id(self), 0) + 1
    return looks[id(self)] > 3 and real_done(self)

  def save(directory, step, *args, **kwargs):
    saved.append(step)
    return real_save(directory, step, *args, **kwargs)

  monkeypatch.setattr(runner._Evaluation, "done", done)
  monkeypatch.setattr(runner.checkpoint, "save", save)
  more = dict(eval_every=4, checkpoint_every=4, final_eval_envs=0,
              mesh=mesh_lib.make_mesh(jax.devices()[:1]), print_fn=lambda *_: None,
              eval_on_host=True, host_devices=jax.devices()[1:])
  run_dir, steps = str(tmp_path / "run"), CONFIG.env_steps_per_iteration
  runner.run(CONFIG, run_dir, 9 * steps, reward_source=FormReward(EFFECT, _demonstrator()),
             **more)
  assert saved[0] in (6, 7) or saved == [9]  # (without the wait: 4, 8, 9)
  runner.run(CONFIG, run_dir, 13 * steps, resume=True,
             reward_source=FormReward(EFFECT, _demonstrator()), **more)
  with open(os.path.join(run_dir, "progress.csv"), newline="") as f:
    rows = list(csv.DictReader(f))
  assert [int(r["iteration"]) for r in rows] == list(range(1, 14))
  assert [r["eval_return"] != "" for r in rows] == [i % 4 == 0 or i in (9, 13)  # (ends)
                                                  for i in range(1, 14)]
  # A host that is always busy (each evaluation running until waited for): a checkpoint due
  # for checkpoint_every iterations is forced at the first that starts no evaluation (7, not
  # 6, which starts one), waiting for the one running.
  monkeypatch.setattr(runner._Evaluation, "done", lambda self: self.results is not None)
  saved.clear()
  runner.run(CONFIG, str(tmp_path / "busy"), 9 * steps,
             reward_source=FormReward(EFFECT, _demonstrator()),
             **{**more, "eval_every": 3, "checkpoint_every": 2})
  assert saved == [2, 7, 8, 9]


def test_one_cpu_device_per_core_this_process_may_run_on():
  """--eval_on_host's CPU devices count the cores of the process's affinity (gpu_jobs.py pins
  each job to its GPUs' share of the host), not every core of the machine."""
  code = ("import os; os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:1]); "
          "from mjx_form import cpu; assert cpu.one_device_per_core(); "
          "import jax; print(len(jax.devices('cpu')))")
  flags = " ".join(f for f in os.environ["XLA_FLAGS"].split()  # (the tests' 2 CPU devices)
                   if not f.startswith("--xla_force_host_platform_device_count"))
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                       env={**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": flags})
  assert out.stdout.split()[-1] == "1"


def _same(value, want, what: str):
  """`value` is `want`, numbers (and numbers as CSV text) to float rounding: the host's batch,
  split over its devices, is computed in other vector widths (last bits of log pD differ)."""
  if isinstance(want, dict):
    assert value.keys() == want.keys(), what
    for k in want:
      _same(value[k], want[k], f"{what}.{k}")
  elif isinstance(want, float) or (isinstance(want, str) and _number(want)):
    assert float(value) == pytest.approx(float(want), rel=1e-5, abs=1e-4, nan_ok=True), what
  else:
    assert value == want, what


def _number(text: str) -> bool:
  try:
    float(text)
    return True
  except ValueError:
    return False


def _same_run_written(run_dir, records, host_dir, host_records, timing):
  from mjx_form.rl import runner
  assert [r["kind"] for r in host_records] == [r["kind"] for r in records]
  assert sum(r["kind"] == "learning_curve" for r in records) == 2 * 4  # (iterations 2, 4, 6, 7)
  for record, host_record in zip(records, host_records):
    _same({k: v for k, v in host_record.items() if k not in timing},
          {k: v for k, v in record.items() if k not in timing}, record["kind"])
    if record["kind"] == "learning_curve":
      assert host_record["settings"] == {**record["settings"], "eval_on_host": True}
  for seed in ("seed0", "seed1"):
    rows = [{k: v for k, v in r.items() if k not in timing}
            for r in csv.DictReader(open(run_dir / seed / "progress.csv"))]
    host_rows = [{k: v for k, v in r.items() if k not in timing}
                 for r in csv.DictReader(open(host_dir / seed / "progress.csv"))]
    assert [r["iteration"] for r in host_rows] == [str(i) for i in range(1, 8)]
    for host_row, row in zip(host_rows, rows):
      _same(host_row, row, f"{seed} row {row['iteration']}")
    assert sum(r["eval_demonstrator_log_prob_average"] != "" for r in rows) == 4
    for file in ("best_policy.npz", "best_log_pd_policy.npz", runner.AVERAGE_BEST[0][2],
                 "policy.npz", runner.AVERAGE_FILE):  # (the same arrays; their evaluations)
      (arrays, meta), (want_arrays, want_meta) = (
          policy_io.load_policy(str(d / seed / file)) for d in (host_dir, run_dir))
      jax.tree.map(np.testing.assert_array_equal, arrays, want_arrays)
      _same({k: v for k, v in meta.items() if k != "sha256"},
            {k: v for k, v in want_meta.items() if k != "sha256"}, file)


@pytest.mark.slow
def test_an_ensemble_runs_in_the_compiled_loop_on_two_devices(form_trainer):
  """An ensemble's stacked demonstrators go through the compiled loop with the batch sharded
  over two devices: an ensemble of one model twice trains as that model alone (the same log pD
  and rewards, iteration for iteration), and the stacked models stay as given."""
  assert jax.device_count() == 2  # (tests/conftest.py)
  twice = Trainer(CONFIG, mesh_lib.make_mesh(), FormReward(EFFECT, [_demonstrator()] * 2))
  state, metrics = _iterate(twice, 2)
  _, alone = _iterate(form_trainer, 2)  # (the same model, `_demonstrator()`, alone)
  for name in ("demonstrator_log_prob", "form_reward", "imitator_batch_log_prob", "q_online"):
    np.testing.assert_allclose([m[name] for m in metrics], [m[name] for m in alone],
                               rtol=1e-4, atol=1e-3, err_msg=name)
  kept = jax.device_get(state.source.demonstrator)  # [P, K, ...]
  np.testing.assert_array_equal(kept.normalizer.mean[0], np.stack(
      [np.asarray(_demonstrator().normalizer.mean)] * 2))


@pytest.mark.slow
def test_members_may_differ_in_how_an_ensemble_makes_log_pd():
  """A population over the two devices whose members differ only in `ensemble_log_pd` (seed 0
  each, `--grid ensemble_log_pd=mixture,mean`): their first iteration's transitions are the
  same, scored lower by the mean (Jensen) in every place a member's log pD enters; evaluating
  the initial policies (the same episodes) scores each member's with its own, the mean lower in
  every episode. (Each way's arithmetic against numpy: the two tests above.)"""
  members = [_demonstrator(0), _demonstrator(3)]
  population = Trainer(CONFIG, mesh_lib.make_mesh(), FormReward(EFFECT, members, "a+b"),
                       seeds=(0, 0), overrides=({"ensemble_log_pd": "mixture"},
                                                {"ensemble_log_pd": "mean"}))
  assert "ensemble_log_pd" not in population.member_source(0).settings()
  assert population.member_source(1).settings()["ensemble_log_pd"] == "mean"
  start = population.init(population.keys())
  np.testing.assert_array_equal(start.settings["ensemble_log_pd"], [0, 1])
  returns, scores = jax.device_get(population.evaluate(
      (start.learner.policy,), (start.normalizer,), population.keys(1),
      **population.evaluation_inputs(start)))
  returns, scores = returns[0], scores[0]
  np.testing.assert_array_equal(returns[0], returns[1])  # (the same episodes)
  assert np.all(scores[1] < scores[0] - 0.1), scores
  after, m = population.iteration(start)  # (`start` donated)
  # [P]: the same transitions (collected, and the learner's batches), each member's own log pD
  # in the fresh metrics, the rewards and the reward statistics its imitator step folds in
  for name in ("demonstrator_fresh_log_prob", "demonstrator_log_prob"):
    assert m[name][1] < m[name][0] - 0.1, (name, m[name])
  reward_mean = np.asarray(after.source.reward.mean)[:, 0]
  assert reward_mean[1] < reward_mean[0] - 0.1, reward_mean
  with pytest.raises(ValueError, match="needs an ensemble"):
    Trainer(CONFIG, mesh_lib.make_mesh(), FormReward(EFFECT, members[0]), seeds=(0, 0),
            overrides=({}, {"ensemble_log_pd": "mean"}))


def test_evaluate_run_tells_a_mixture_member_from_a_mean_member():
  """scripts/evaluate_run.py matches a member's policy to its records by its own reward
  settings: records leave out the mixture (the default), so a mixture member of `--grid
  ensemble_log_pd=mixture,mean` matches the record without the key, never the mean member's."""
  evaluate_run = load_script("evaluate_run")
  base = {"kind": "learning_curve", "env_steps": 40, "seed": 0}
  mixture = dict(base, settings={"seed": 0, "reward": {"reward_clip": 3.0}}, eval_return=1.0)
  mean = dict(base, settings={"seed": 0, "reward": {"reward_clip": 3.0,
                                                     "ensemble_log_pd": "mean"}}, eval_return=2.0)
  meta = {"train_config": {"seed": 0}, "env_steps": 40}
  for own, want in (("mixture", mixture), ("mean", mean)):
    for records in ([mixture, mean], [mean, mixture]):
      assert evaluate_run.member_record(records, meta, "p.npz",
                                        {"ensemble_log_pd": own}) is want, own
  with pytest.raises(evaluate_run.RunFilesError, match="no learning-curve records"):
    evaluate_run.member_record([mean], meta, "p.npz", {"ensemble_log_pd": "mixture"})


@pytest.mark.slow
def test_demonstrators_per_member_give_each_member_its_own(form_trainer):
  """Demonstrators per member: member i of a population (over the two devices, one member
  each, or each member over both) imitates the i-th, computing what a single run with its seed
  and that demonstrator computes; its state holds its own; its records name its own checksum
  and the run's name all.
  Refused: fewer than 2, a checksum count that differs, a population of another size."""
  demos = [_demonstrator(0), _demonstrator(3)]
  source = FormReward(EFFECT, demos, ["sha-a", "sha-b"], member_demonstrators=True)
  assert source.ensemble == 0 and source.per_member == 2
  population = Trainer(CONFIG, mesh_lib.make_mesh(), source, seeds=(0, 1))
  state, metrics = population.init(population.keys()), []
  for _ in range(2):
    state, m = population.iteration(state)
    metrics.append(jax.device_get(m))
  kept = jax.device_get(state.source.demonstrator)  # [P, ...]: member i's own
  for i, d in enumerate(demos):
    np.testing.assert_array_equal(kept.normalizer.mean[i], np.asarray(d.normalizer.mean))
  other = Trainer(dataclasses.replace(CONFIG, seed=1), mesh_lib.make_mesh(),
                  FormReward(EFFECT, demos[1]))
  alone = [_iterate(form_trainer, 2)[1], _iterate(other, 2, key=1)[1]]  # seed i, demos[i]
  for i in range(2):
    for name in ("demonstrator_log_prob", "form_reward", "imitator_batch_log_prob",
                 "q_online"):
      np.testing.assert_allclose([m[name][i] for m in metrics], [m[name][0] for m in alone[i]],
                                 rtol=1e-3, atol=1e-3, err_msg=f"member {i} {name}")
  # The other layout (each member's environments split over both devices, its state on both)
  # computes the same.
  spread = Trainer(CONFIG, mesh_lib.make_mesh(), source, seeds=(0, 1), layout="environments")
  assert population.layout == "members" and spread.layout == "environments"
  _, first = spread.iteration(spread.init(spread.keys()))
  np.testing.assert_allclose(jax.device_get(first["demonstrator_log_prob"]),
                             metrics[0]["demonstrator_log_prob"], rtol=1e-4, atol=1e-3)
  # Evaluation: member i's episodes scored by its own demonstrator; the other layout's
  # evaluation of the same state scores the same.
  scored = [np.asarray(t.evaluate((state.learner.policy,), (state.normalizer,), t.keys(1),
                                  **t.evaluation_inputs(state))[1][0])
            for t in (population, spread)]
  np.testing.assert_allclose(scored[0], _evaluation_reference(population, state, demos)[1],
                             rtol=1e-4, atol=1e-3)
  np.testing.assert_allclose(scored[1], scored[0], rtol=1e-4, atol=1e-3)
  assert np.abs(scored[0][0] - scored[0][1]).min() > 0.1  # (the members' episodes differ)
  # Two policies per member in one call ([K, P, n]): each member's and each policy's own
  # episodes, in either layout (the batch is [P, K, n], members outermost).
  other = jax.tree.map(lambda w: 1.5 * w + 0.05, state.learner.policy)
  other_norm = state.normalizer._replace(mean=state.normalizer.mean + 0.3)
  for t in (population, spread):
    inputs = t.evaluation_inputs(state)
    together = np.asarray(t.evaluate((state.learner.policy, other), (state.normalizer, other_norm),
                                     t.keys(1), **inputs)[1])
    alone = [np.asarray(t.evaluate((p,), (m,), t.keys(1), **inputs)[1][0])
             for p, m in ((state.learner.policy, state.normalizer), (other, other_norm))]
    assert together.shape == (2, 2, CONFIG.eval_envs)
    np.testing.assert_allclose(together, np.stack(alone), rtol=1e-4, atol=1e-3)
    assert np.abs(alone[0] - alone[1]).min() > 0.1  # (the policies' episodes differ)
  # (the two demonstrators score the same transitions differently, through the members' states)
  obs = jnp.asarray(np.random.default_rng(2).normal(size=(3, 5, D)), jnp.float32)
  scores = [np.asarray(source.log_probs(population.member(state.source, i), obs)[0])
            for i in range(2)]
  assert np.abs(scores[0] - scores[1]).mean() > 1.0
  assert population.source.settings()["member_demonstrators"] == ["sha-a", "sha-b"]
  mine = population.member_source(1).settings()
  assert mine["demonstrator_sha256"] == "sha-b" and mine["demonstrator_per_member"] is True
  assert "member_demonstrators" not in mine
  with pytest.raises(ValueError, match="2 demonstrators per member for a population of 3"):
    Trainer(CONFIG, mesh_lib.make_mesh(), source, seeds=(0, 1, 2))
  for models, shas in (([demos[0]], ["sha-a"]), (demos, ["sha-a"]), (demos, "sha-a+sha-b")):
    with pytest.raises(ValueError, match="demonstrators per member need 2 or more"):
      FormReward(EFFECT, models, shas, member_demonstrators=True)


def test_the_imitator_model_is_exported_as_an_effect_model_file_and_refused_as_a_demonstrator(
    tmp_path):
  """Each member's imitator model is written as it stands (after its online steps), with the
  reward's running statistics: read back, it gives that member's log pI; a run refuses the file
  as a demonstrator, naming it."""
  from types import SimpleNamespace

  from mjx_form.imitation import pipeline
  from mjx_form.rl import runner
  source = FormReward(EFFECT, _demonstrator())
  env = tasks.make("reacher_easy")
  rng = np.random.default_rng(1)
  batch = {"observation": jnp.asarray(rng.normal(size=(3, 8, D)), jnp.float32),
           "discount": jnp.ones((3, 7))}
  states = jax.jit(jax.vmap(lambda k: source.init(k, D, 2)))(
      jax.random.split(jax.random.PRNGKey(0), 2))
  update = jax.jit(jax.vmap(source.update))  # (compiled once; op by op it took CI ~40 s)
  for i in range(3):  # member 1 takes one more step than member 0, on other batches
    keys = jax.random.split(jax.random.PRNGKey(i), 2)
    batches = jax.tree.map(lambda x: jnp.stack([x, x[::-1]]), batch)
    stepped, _ = update(states, batches, keys)
    states = jax.tree.map(lambda new, old: jnp.stack([new[0] if i < 2 else old[0], new[1]]),
                          stepped, states)
  trainer = SimpleNamespace(source=source, env=env, member=lambda tree, i: jax.tree.map(
      lambda x: x[i], tree))
  for i in range(2):
    (tmp_path / f"m{i}").mkdir()
    runner.export_source(trainer, SimpleNamespace(source=states), i, str(tmp_path / f"m{i}"),
                         {"env_steps": 100 + i})
  x, x_next = batch["observation"][:, :-1], batch["observation"][:, 1:]
  logs = []
  for i in range(2):
    member = jax.tree.map(lambda v: v[i], states)
    file = effect_models.load_effect_model(tmp_path / f"m{i}" / "imitator.npz",
                                           task="reacher_easy")
    assert file.metadata["training"]["steps"] == 2 + i
    assert file.metadata["config"] == EFFECT.to_dict()
    info = file.metadata["imitator"]
    assert (info["env_steps"], info["policy_file"]) == (100 + i, "policy.npz")
    np.testing.assert_allclose([info["reward_mean"], info["reward_sd"] ** 2],
                               [member.reward.mean[0], member.reward.var[0]], rtol=1e-6)
    norm = normalizer.NormalizerState(jnp.asarray(file.mean), jnp.asarray(file.var),
                                      jnp.asarray(1, jnp.int32))
    logs.append(em.transition_log_prob(source.model, file.params, norm, x, x_next))
    np.testing.assert_allclose(logs[-1], source.log_probs(member, batch["observation"])[1],
                               rtol=1e-6, atol=1e-5)
  assert not np.allclose(logs[0], logs[1])  # each member's own model
  with pytest.raises(effect_models.EffectModelFileError, match="an imitator model"):
    pipeline.load_demonstrator(str(tmp_path / "m0" / "imitator.npz"), env)
  # A source without a file to export writes nothing.
  runner.export_source(SimpleNamespace(source=object()), None, 0, str(tmp_path / "none"), {})
  assert not (tmp_path / "none").exists()


def test_standardised_reward_uses_the_running_statistics_of_the_raw_reward():
  """With standardise_reward the learner gets (r - m) / s, m and s the bias-corrected EMA
  (decay 0.99 per batch) of the raw reward over the valid transitions of the batches so far,
  each batch's rewards taken under the imitator after that batch's step (numpy reference)."""
  plain = FormReward(EFFECT, _demonstrator(0))
  scaled = FormReward(EFFECT, _demonstrator(0), standardise_reward=True)
  assert plain.settings()["standardise_reward"] is False
  assert scaled.settings()["standardise_reward"] is True
  state = plain.init(jax.random.PRNGKey(1), D, 2)
  update, relabel = jax.jit(plain.update), jax.jit(plain.relabel)
  rng, kept = np.random.default_rng(3), []
  for i in range(5):
    obs = jnp.asarray(rng.normal(size=(3, 6, D)) * (1 + i), jnp.float32)
    discount = jnp.asarray(rng.random((3, 5)) > 0.2, jnp.float32)
    batch = {"observation": obs, "discount": discount}
    state, _ = update(state, batch, jax.random.PRNGKey(10 + i))
    raw, raw_metrics = relabel(state, batch)
    kept.append(np.asarray(raw, np.float64)[np.asarray(discount) > 0])
  decay, t = EFFECT.normalizer_decay, len(kept)
  w = (1 - decay) * decay ** (t - np.arange(1, t + 1)) / (1 - decay ** t)
  mean = sum(wi * k.mean() for wi, k in zip(w, kept))
  var = sum(wi * (k ** 2).mean() for wi, k in zip(w, kept)) - mean ** 2
  rewards, metrics = scaled.relabel(state, batch)
  valid = np.asarray(discount) > 0
  expected = np.where(valid, (np.asarray(raw) - mean) / np.sqrt(var + 1e-6), 0.0)
  np.testing.assert_allclose(rewards, expected, rtol=1e-4, atol=1e-4)
  assert abs(float(np.std(expected[valid])) - 1.0) < 0.8 and float(np.std(raw)) > 2.0
  np.testing.assert_allclose(metrics["form_reward"], raw_metrics["form_reward"], rtol=1e-6)
  np.testing.assert_allclose(metrics["form_reward_std"], np.sqrt(var), rtol=1e-4)
  # Population members may differ in this setting: traced per member, it gives each member
  # what its own source gives.
  members = jax.vmap(lambda on: plain.specialise({"standardise_reward": on}).relabel(
      state, batch)[0])(jnp.array([False, True]))
  np.testing.assert_allclose(members[0], raw, rtol=1e-6, atol=1e-6)
  np.testing.assert_allclose(members[1], rewards, rtol=1e-6, atol=1e-6)
  assert scaled.specialise({"standardise_reward": False}).settings()["standardise_reward"] is False
  with pytest.raises(ValueError, match="beta_ar"):
    plain.specialise({"beta_ar": 0.1})


def test_reward_clip_bounds_the_tail_in_the_reward_and_in_its_statistics():
  """With reward_clip c, each batch's raw rewards are folded into the EMA statistics clipped to
  [m - c s, m + c s] of the statistics before it (the first batch unclipped), and the learner's
  reward is clipped the same way (standardised: to [-c, c]); numpy reference, winsorised EMA."""
  c = 1.5
  raw_source = FormReward(EFFECT, _demonstrator(0))
  clipped = FormReward(EFFECT, _demonstrator(0), reward_clip=c)
  both = FormReward(EFFECT, _demonstrator(0), standardise_reward=True, reward_clip=c)
  assert clipped.settings()["reward_clip"] == c and raw_source.settings()["reward_clip"] == 0.0
  state = clipped.init(jax.random.PRNGKey(1), D, 2)
  update = jax.jit(clipped.update)
  rng, decay = np.random.default_rng(4), EFFECT.normalizer_decay
  mean, var, count, folded_any = 0.0, 1.0, 0, False
  for i in range(4):
    obs = jnp.asarray(rng.normal(size=(3, 6, D)) * (1 + i), jnp.float32)
    discount = jnp.asarray(rng.random((3, 5)) > 0.2, jnp.float32)
    batch = {"observation": obs, "discount": discount}
    state, _ = update(state, batch, jax.random.PRNGKey(10 + i))
    raw, valid = (np.asarray(a, np.float64) for a in clipped.raw_rewards(state, batch))
    x = raw[valid > 0]
    if count > 0:
      lo, hi = mean - c * np.sqrt(var), mean + c * np.sqrt(var)
      folded_any |= bool(np.any((x < lo) | (x > hi)))
      x = np.clip(x, lo, hi)
    count += 1
    rate = (1 - decay) / (1 - decay ** count)
    delta = x.mean() - mean
    var = (1 - rate) * var + rate * x.var() + rate * (1 - rate) * delta ** 2
    mean += rate * delta
  assert folded_any  # the reference did clip: the check below can fail
  np.testing.assert_allclose(state.reward.mean[0], mean, rtol=1e-4)
  np.testing.assert_allclose(state.reward.var[0], var, rtol=1e-4)
  lo, hi, sd = mean - c * np.sqrt(var), mean + c * np.sqrt(var), np.sqrt(var + 1e-6)
  valid = valid > 0
  rewards, _ = clipped.relabel(state, batch)
  np.testing.assert_allclose(rewards, np.where(valid, np.clip(raw, lo, hi), 0.0), rtol=1e-4,
                             atol=1e-4)
  # The share of clipped transitions among the valid ones, on a batch of which only some are
  # outside the bounds and some are not valid.
  for scale in (1.0, 2.0, 3.0):
    mild = {"observation": jnp.asarray(rng.normal(size=(8, 6, D)) * scale, jnp.float32),
            "discount": jnp.asarray(rng.random((8, 5)) > 0.3, jnp.float32)}
    raw_mild = np.asarray(clipped.raw_rewards(state, mild)[0], np.float64)
    mild_valid = np.asarray(mild["discount"]) > 0
    outside = ((raw_mild < lo) | (raw_mild > hi))[mild_valid]
    if 0 < outside.mean() < 1 and outside.mean() != ((raw_mild < lo) | (raw_mild > hi)).mean():
      break
  assert 0 < outside.mean() < 1
  assert outside.mean() != ((raw_mild < lo) | (raw_mild > hi)).mean()  # the mask matters
  np.testing.assert_allclose(clipped.relabel(state, mild)[1]["form_reward_clipped"],
                             outside.mean(), rtol=1e-5)
  assert raw_source.relabel(state, mild)[1]["form_reward_clipped"] == 0.0
  shares = jax.vmap(lambda v: raw_source.specialise({"reward_clip": v}).relabel(
      state, mild)[1]["form_reward_clipped"])(jnp.array([0.0, c]))
  np.testing.assert_allclose(shares, [0.0, outside.mean()], rtol=1e-5)
  # A member's traced value gives what its own source gives; 0 is off.
  members = jax.vmap(lambda v: raw_source.specialise({"reward_clip": v}).relabel(
      state, batch)[0])(jnp.array([0.0, c]))
  np.testing.assert_allclose(members[0], raw_source.relabel(state, batch)[0], rtol=1e-6)
  np.testing.assert_allclose(members[1], rewards, rtol=1e-6, atol=1e-6)
  for refused in (-1.0, 0.5, 1.0, float("inf")):  # at c <= 1 the clipped statistics' sd
    with pytest.raises(ValueError, match="reward_clip"):  # collapses
      FormReward(EFFECT, _demonstrator(0), reward_clip=refused)
  assert FormReward(EFFECT, _demonstrator(0), reward_clip=1.01).reward_clip == 1.01


def test_imitation_requires_unrolls_that_end_with_the_episodes():
  with pytest.raises(ValueError, match="must divide the episode length"):
    TrainConfig(task="reacher_easy", reward_source="form", unroll_length=64).check(1)
  with pytest.raises(ValueError, match="reward source 'task'"):
    Trainer(TrainConfig(task="reacher_easy"), reward_source=FormReward(EFFECT, _demonstrator()))


def test_unrolls_mark_every_episode_end_for_the_effect_models(form_trainer):
  """Pairs (x_t, x_{t+delta}) of a collected unroll are kept only inside one episode: an
  episode ending mid-unroll, a physics error, a staggered first episode ending on the unroll's
  last step (its final observation is kept: no boundary) and an uninterrupted one."""
  trainer = form_trainer
  state = trainer.init(jax.random.PRNGKey(0)[None])
  env = state.env
  steps = jnp.asarray([995, 950, 0, 0], env.info["step"].dtype)
  qvel = env.data.qvel.at[2].set(jnp.nan)  # env 2: a physics error at its first step
  env = env.replace(data=env.data.replace(qvel=qvel), info=dict(env.info, step=steps))
  # (run once: compiled without XLA's backend optimisation, CI time; mjx_form.cpu)
  collect = jax.jit(trainer._collect, compiler_options=cpu.run_once_compiler_options())
  _, _, _, unrolls, stats = collect(state._replace(env=env), jax.random.PRNGKey(1)[None])
  unrolls = trainer.member(unrolls, 0)  # [N, T(+1), ...] of the one member
  assert int(stats["physics_errors"][0]) == 1
  # transitions whose successor starts a new episode (995: after 5 steps; 950: on the last)
  boundaries = {i: [] for i in range(CONFIG.num_envs)} | {0: [4], 2: [0]}
  t = CONFIG.unroll_length
  expected = np.zeros((5, CONFIG.num_envs, t))
  for i, ends in boundaries.items():
    for d in range(1, 6):
      for s in range(t):
        expected[d - 1, i, s] = s + d <= t and not any(s <= b < s + d for b in ends)
  masks = np.asarray(em.offset_masks(unrolls["discount"], 5))
  np.testing.assert_array_equal(masks, expected)
  # reacher starts at rest: a new episode's first observation has zero velocity (its last two
  # elements). The staggered episode's last observation is its own final one, not a reset.
  velocity = np.asarray(unrolls["observation"])[..., 4:]
  assert not velocity[0, 5].any() and not velocity[2, 1].any()
  assert velocity[1, -1].all() and velocity[3, 1:].all()
  assert np.asarray(stats["episodes"])[0] >= 3  # env 0, 1 and 2 at least


def assert_trained_alike(state, other) -> None:
  """Two runs' states agree bit for bit in everything training made (their environments may
  differ in what the task reward logged)."""
  for part in ("learner", "source", "replay", "normalizer", "key"):
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(getattr(state, part)),
                            jax.tree.leaves(getattr(other, part))):
      np.testing.assert_array_equal(np.asarray(a), np.asarray(b),
                                    err_msg=part + jax.tree_util.keystr(path))


def test_training_never_sees_the_task_reward(form_trainer, monkeypatch):
  """The same FORM run with the environment's reward replaced by garbage trains bit for bit
  the same: only the logged task returns differ."""
  state, metrics = _iterate(form_trainer, 3)
  monkeypatch.setitem(tasks._REGISTRY, "reacher_easy",
                      lambda physics: GarbageRewardReacher(reacher._BIG_TARGET, "easy", physics))
  garbage = Trainer(CONFIG, mesh_lib.make_mesh(), FormReward(EFFECT, _demonstrator()))
  assert isinstance(garbage.env, GarbageRewardReacher)
  other, other_metrics = _iterate(garbage, 3)
  assert_trained_alike(state, other)
  np.testing.assert_array_equal(state.env.obs, other.env.obs)
  assert metrics[-1]["train_reward"][0] != other_metrics[-1]["train_reward"][0]  # garbage seen
  assert np.isfinite(metrics[-1]["form_reward"][0]) and metrics[-1]["imitator_log_prob"][0] != 0


@pytest.mark.slow
def test_imitator_every_k_trains_it_on_one_batch_in_k(form_trainer):
  """source_update_every k (`--imitator_every`): the imitator model takes one step per k
  learner updates, the reward statistics fold in one batch per step, the learner takes every
  update, and the iteration reports the same metrics."""
  state, metrics = _iterate(form_trainer, 3)
  every = Trainer(dataclasses.replace(CONFIG, source_update_every=2), mesh_lib.make_mesh(),
                  FormReward(EFFECT, _demonstrator()))
  other, other_metrics = _iterate(every, 3)
  assert int(state.source.imitator.steps[0]) == 6 and int(other.source.imitator.steps[0]) == 3
  assert int(state.source.reward.count[0]) == 6 and int(other.source.reward.count[0]) == 3
  assert int(state.learner.updates[0]) == int(other.learner.updates[0]) == 6
  assert metrics[-1].keys() == other_metrics[-1].keys()
  assert np.isfinite(other_metrics[-1]["form_reward"][0])
  assert not np.allclose(np.asarray(jax.tree.leaves(state.learner.policy)[0]),
                         np.asarray(jax.tree.leaves(other.learner.policy)[0]))


def test_fresh_metrics_score_the_new_transitions_under_the_imitator_before_it_saw_them(
    form_trainer):
  """fresh_metrics: both models' mean log-likelihood over the valid transitions of unrolls; the
  trainer computes them on each iteration's collected unrolls with the source state from
  before the iteration's updates (read back from the replay's first slots here)."""
  source = FormReward(EFFECT, _demonstrator(0))
  state = source.init(jax.random.PRNGKey(1), D, 2)
  rng = np.random.default_rng(3)
  obs = jnp.asarray(rng.normal(size=(3, 5, D)), jnp.float32)
  discount = jnp.ones((3, 4)).at[2, 1].set(0.0)
  fresh = source.fresh_metrics(state, {"observation": obs, "discount": discount})
  log_d, log_i = (np.asarray(x) for x in source.log_probs(state, obs))
  valid = np.asarray(discount) > 0
  np.testing.assert_allclose(fresh["demonstrator_fresh_log_prob"], log_d[valid].mean(), rtol=1e-5)
  np.testing.assert_allclose(fresh["imitator_fresh_log_prob"], log_i[valid].mean(), rtol=1e-5)
  np.testing.assert_allclose(fresh["form_reward_fresh"], (log_d - log_i)[valid].mean(),
                             rtol=1e-5, atol=1e-5)
  # In the loop: the first iteration's unrolls are the replay's first num_envs slots.
  member = lambda tree: jax.tree.map(lambda x: np.asarray(x)[0], tree)
  before = form_trainer.init(jax.random.PRNGKey(0)[None])
  before_source = member(before.source)  # (the iteration donates its state's buffers)
  after, metrics = form_trainer.iteration(before)
  new = jax.tree.map(lambda x: x[:CONFIG.num_envs], member(after.replay.data))
  expected = source.fresh_metrics(before_source, new)
  for key in ("demonstrator_fresh_log_prob", "imitator_fresh_log_prob", "form_reward_fresh"):
    np.testing.assert_allclose(np.asarray(metrics[key])[0], expected[key], rtol=1e-4, err_msg=key)
  # ... and not with the updated imitator model (the check above can tell them apart).
  moved = source.fresh_metrics(member(after.source), new)
  assert abs(moved["imitator_fresh_log_prob"] - expected["imitator_fresh_log_prob"]) > 1e-4


def test_form_run_settings_take_the_task_entry_then_the_preset_then_the_flags(monkeypatch):
  """DEFAULT_RUN's measured reward clip (3 sd) and bfloat16 sampled Q are every task's default;
  a task's entry in settings.PER_TASK_RUN overrides them; --preset paper replaces both; a flag
  overrides either."""
  cli = load_script("run")
  def chosen(*argv):
    return cli.form_run_settings(cli.parse_args(["--method", "form", *argv]))
  default = {"standardise_reward": True, "reward_clip": 3.0, "target_update_period": 25,
             "sampled_q_bfloat16": True, "policy_average_decay": 0.9995}
  assert chosen("--task", "cheetah_run") == default
  assert chosen("--task", "walker_stand") == default
  # walker_walk's entry: the expert recipes' learner (the critic's clip, MPO's scale bound)
  assert chosen("--task", "walker_walk") == {**default, "clip_critic_actions": True,
                                             "epsilon_scale": 1e-6}
  monkeypatch.setitem(settings.PER_TASK_RUN, "walker_walk", {"reward_clip": 2.0})
  assert chosen("--task", "walker_walk")["reward_clip"] == 2.0
  assert chosen("--task", "cheetah_run")["reward_clip"] == 3.0
  assert chosen("--task", "walker_walk", "--reward_clip", "0")["reward_clip"] == 0.0
  assert chosen("--task", "walker_walk", "--preset", "paper") == {
      "standardise_reward": False, "reward_clip": 0.0, "target_update_period": 200,
      "sampled_q_bfloat16": False, "policy_average_decay": 0.0}
  assert chosen("--task", "walker_walk", "--policy_average_decay", "0")[
      "policy_average_decay"] == 0.0
  assert cli.train_config(cli.parse_args(["--method", "form", "--task", "walker_walk"])
                          ).learner.policy_average_decay == 0.9995
  assert cli.train_config(cli.parse_args(["--method", "expert", "--task", "walker_walk"])
                          ).learner.policy_average_decay == 0.0
  assert chosen("--task", "walker_walk", "--no-sampled_q_bfloat16")["sampled_q_bfloat16"] is False
  assert chosen("--task", "walker_walk", "--preset", "paper",
                "--sampled_q_bfloat16")["sampled_q_bfloat16"] is True


def test_angle_increments_flag_reaches_the_effect_models():
  """--angle_increments: a turn-invariant task's (reacher_hard's) models predict angle changes;
  off by default; refused, naming --turn_invariant, for models that are not turn-invariant."""
  import tasks
  cli = load_script("run")
  config = lambda task, *argv: cli.effect_model_settings(
      cli.parse_args(["--task", task, "--method", "form", *argv]), tasks.make(task))[1]
  assert not config("reacher_hard").angle_increments
  on = config("reacher_hard", "--angle_increments")
  assert on.angle_increments and on.period == config("reacher_hard").period
  assert config("reacher_easy", "--turn_invariant", "--angle_increments").angle_increments
  with pytest.raises(ValueError, match="--turn_invariant"):
    config("reacher_easy", "--angle_increments")


def test_angle_inputs_flag_reaches_the_effect_models(capsys):
  """--angle_inputs: with --angle_increments, reacher_hard's models see the shoulder as its cos
  and sin; off by default (absent from the settings); refused, naming --angle_increments,
  without it; --no-angle_inputs is an explicit setting (a demonstrator must agree with it)."""
  import tasks
  cli = load_script("run")
  env = tasks.make("reacher_hard")
  settings_of = lambda *argv: cli.effect_model_settings(
      cli.parse_args(["--task", "reacher_hard", "--method", "form", *argv]), env)
  explicit, default = settings_of()
  assert not default.angle_inputs and "angle_inputs" not in default.to_dict()
  assert explicit["angle_inputs"] is None
  on = settings_of("--angle_increments", "--angle_inputs")[1]
  assert on.angle_inputs and on.angle_increments and on.period == default.period
  explicit, off = settings_of("--angle_increments", "--no-angle_inputs")
  assert explicit["angle_inputs"] is False and not off.angle_inputs
  with pytest.raises(ValueError, match="--angle_increments"):
    settings_of("--angle_inputs")
  with pytest.raises(SystemExit):
    cli.parse_args(["--method", "expert", "--no-angle_inputs"])
  assert "--angle_inputs apply to --method form only" in capsys.readouterr().err


def test_sampled_q_precision_reaches_the_learner_per_method():
  """FORM's learner computes the sampled actions' Q in bfloat16 unless --preset paper or
  --no-sampled_q_bfloat16; an expert run of a task without a recipe (the default task,
  cheetah_run; mjx_form/rl/recipes.py) in float32, the paper's learner, unless asked."""
  cli = load_script("run")
  def bfloat16(*argv):
    return cli.train_config(cli.parse_args(list(argv))).learner.sampled_q_bfloat16
  assert bfloat16("--method", "form") is True
  assert bfloat16() is True  # form is the default method
  assert bfloat16("--method", "form", "--preset", "paper") is False
  assert bfloat16("--method", "form", "--no-sampled_q_bfloat16") is False
  assert bfloat16("--method", "expert") is False
  assert bfloat16("--method", "expert", "--sampled_q_bfloat16") is True
  assert cli.train_config(cli.parse_args(["--method", "expert"])).learner == (
      cli.LearnerConfig())  # an expert run with no flags is the paper's learner


def test_form_flags_are_refused_for_other_methods(capsys, monkeypatch, tmp_path):
  """A FORM flag given to --method expert or random is an error naming it, whichever value it
  was given (--no-turn_invariant included); without them those methods parse."""
  cli = load_script("run")
  for argv, named in ((["--method", "expert", "--no-turn_invariant"], "--turn_invariant"),
                      (["--method", "random", "--turn_invariant"], "--turn_invariant"),
                      (["--method", "expert", "--beta_ar", "0.1"], "--beta_ar"),
                      (["--method", "expert", "--train_demonstrator"], "--train_demonstrator"),
                      (["--method", "random", "--demonstrator_seed", "0"],
                       "--demonstrator_seed"),
                      (["--method", "expert", "--demonstrator", "a.npz"], "--demonstrator"),
                      (["--method", "expert", "--imitator_every", "2"], "--imitator_every")):
    with pytest.raises(SystemExit):
      cli.parse_args(argv)
    assert f"{named} apply to --method form only" in capsys.readouterr().err
  # --imitator_every: a positive divisor of the updates per iteration, into the TrainConfig
  for bad in ("0", "3"):
    with pytest.raises(SystemExit):
      cli.parse_args(["--updates_per_iteration", "8", "--imitator_every", bad])
    assert ("--imitator_every must be a positive divisor of --updates_per_iteration (8), got "
            f"{bad}") in capsys.readouterr().err
  assert cli.train_config(cli.parse_args(["--updates_per_iteration", "8", "--imitator_every",
                                          "4"])).source_update_every == 4
  assert cli.train_config(cli.parse_args([])).source_update_every == 1
  # --member_demonstrators: one --demonstrator per member, 2 members or more
  for argv, given, members in (
      (["--seeds", "0,1,2", "--demonstrator", "a.npz", "--demonstrator", "b.npz"], 2, 3),
      (["--seeds", "0,1", "--grid", "reward_clip=2,3,4", "--demonstrator", "a.npz"], 1, 6),
      (["--demonstrator", "a.npz"], 1, 1), ([], 0, 1)):
    with pytest.raises(SystemExit):
      cli.parse_args(["--method", "form", "--member_demonstrators", *argv])
    assert (f"--member_demonstrators: give one --demonstrator per member (the population has "
            f"{members}), got {given}") in capsys.readouterr().err
  assert cli.parse_args(["--method", "form", "--member_demonstrators", "--seeds", "0,1",
                         "--demonstrator", "a.npz", "--demonstrator", "a.npz"]).demonstrator
  with pytest.raises(SystemExit):  # a draw per member: a population
    cli.parse_args(["--method", "form", "--member_demonstrators", "--train_demonstrator"])
  assert "a draw per member needs a population of 2 or more (--seeds and/or --grid), got 1" in (
      capsys.readouterr().err)
  # a draw per member: seeds --demonstrator_seed + 0, 1, ... (else --seed + ...), one per member
  # of the seeds and the grid's values
  from mjx_form.imitation import pipeline
  monkeypatch.setattr(pipeline, "prepare", lambda *args, **kwargs: args[3])  # the Artefacts
  for argv, seeds in ((["--seeds", "0,1,2", "--demonstrator_seed", "4"], (4, 5, 6)),
                      (["--seeds", "0,1", "--grid", "reward_clip=2,3"], (0, 1, 2, 3)),
                      (["--seed", "7", "--grid", "reward_clip=2,3"], (7, 8))):
    drawn = cli.parse_args(["--method", "form", "--member_demonstrators", "--train_demonstrator",
                            *argv])
    artefacts = cli.form_source(drawn, str(tmp_path), None, print)
    assert artefacts.draw_seeds == seeds and artefacts.train_demonstrator, (argv, artefacts)
  # --ensemble_log_pd reaches the reward source's settings (the mixture where not given)
  monkeypatch.setattr(pipeline, "prepare", lambda *args, **kwargs: kwargs["reward"])
  for argv, asked in (([], "mixture"), (["--ensemble_log_pd", "mean"], "mean")):
    both = cli.parse_args(["--method", "form", "--demonstrator", "a.npz", "--demonstrator",
                           "b.npz", *argv])
    assert cli.form_source(both, str(tmp_path), None, print)["ensemble_log_pd"] == asked
  # --ensemble_log_pd mean: an ensemble shared by the members
  for argv in (["--demonstrator", "a.npz"], [],
               ["--member_demonstrators", "--seeds", "0,1", "--demonstrator", "a.npz",
                "--demonstrator", "b.npz"]):
    with pytest.raises(SystemExit):
      cli.parse_args(["--method", "form", "--ensemble_log_pd", "mean", *argv])
    assert "--ensemble_log_pd mean: an ensemble needs 2 --demonstrator files or more" in (
        capsys.readouterr().err)
  assert cli.parse_args(["--method", "form", "--ensemble_log_pd", "mean", "--demonstrator",
                         "a.npz", "--demonstrator", "b.npz"]).ensemble_log_pd == "mean"
  assert cli.parse_args(["--resume", "--ensemble_log_pd", "mean"]).ensemble_log_pd == "mean"
  # ... and so does a grid in which some member takes the mean (one of the mixture alone is the
  # default, allowed anywhere)
  for argv in (["--demonstrator", "a.npz"], ["--member_demonstrators", "--seeds", "0,1",
                                              "--demonstrator", "a.npz", "--demonstrator",
                                              "b.npz", "--demonstrator", "c.npz",
                                              "--demonstrator", "d.npz"]):
    with pytest.raises(SystemExit):
      cli.parse_args(["--method", "form", "--grid", "ensemble_log_pd=mixture,mean", *argv])
    assert "--grid ensemble_log_pd: an ensemble needs 2 --demonstrator files or more" in (
        capsys.readouterr().err)
  assert cli.parse_args(["--method", "form", "--grid", "ensemble_log_pd=mixture", "--seeds",
                         "0,1"]).grid == {"ensemble_log_pd": ("mixture",)}
  gridded = cli.parse_args(["--method", "form", "--grid", "ensemble_log_pd=mixture,mean",
                            "--demonstrator", "a.npz", "--demonstrator", "b.npz"])
  assert gridded.grid == {"ensemble_log_pd": ("mixture", "mean")}
  assert cli.population_size(gridded) == 2
  with pytest.raises(SystemExit):
    cli.parse_args(["--method", "form", "--grid", "ensemble_log_pd=mixture,product"])
  assert "ensemble_log_pd must be one of mixture, mean, got 'product'" in (
      capsys.readouterr().err)
  # a resume refused for another ensemble_log_pd says how to resume
  refused = checkpoint.CheckpointError("differs", ("reward.ensemble_log_pd",))
  assert "started with --ensemble_log_pd mean resumes with it" in cli.recipe_hint(
      cli.parse_args(["--resume"]), refused)
  assert cli.recipe_hint(cli.parse_args([]), refused) == ""
  # so does one refused for another average-policy decay (FORM's default since 2026-11-28)
  refused = checkpoint.CheckpointError("differs", ("learner.policy_average_decay",))
  assert "--policy_average_decay 0 for none" in cli.recipe_hint(
      cli.parse_args(["--resume"]), refused)
  refused = checkpoint.CheckpointError("differs", ("source_update_every",))
  assert "started with --imitator_every K resumes with it" in cli.recipe_hint(
      cli.parse_args(["--resume"]), refused)
  # the learner flags that no recipe sets: resume with the one the run started with
  refused = checkpoint.CheckpointError("differs", ("learner.mpo.clip_mean_targets",))
  assert cli.recipe_hint(cli.parse_args(["--resume", "--task", "walker_run", "--method",
                                         "expert"]), refused) == (
      " (a run resumes with the --[no-]clip_mean_targets it was started with)")
  # and one refused for the critic's clip or MPO's scale bound (walker_walk's and
  # quadruped_run's FORM entries set them since 2026-11-29)
  refused = checkpoint.CheckpointError("differs", ("learner.mpo.epsilon_scale",))
  assert "resumes with --no-clip_critic_actions --epsilon_scale 1e-5" in cli.recipe_hint(
      cli.parse_args(["--resume", "--task", "walker_walk"]), refused)
  assert "--no-clip_critic_actions" not in cli.recipe_hint(
      cli.parse_args(["--resume", "--task", "walker_walk", "--method", "expert"]), refused)
  assert "--no-clip_critic_actions" not in cli.recipe_hint(  # no entry sets them there
      cli.parse_args(["--resume", "--task", "walker_stand"]), refused)
  # --resume reads the kept demonstrators; a demonstrator flag beside it would be ignored
  for flags in (["--demonstrator", "a.npz"], ["--train_demonstrator"],
                ["--demonstrator_seed", "1"], ["--member_demonstrators"]):
    with pytest.raises(SystemExit):
      cli.parse_args(["--resume", *flags])
    assert "--resume uses the demonstrators kept in the run directory" in (
        capsys.readouterr().err)
  assert cli.parse_args(["--method", "expert"]).turn_invariant is None


def test_policy_head_flag_reaches_the_config():
  """--policy_head picks the policy's head for either method; without it, the paper's (the
  default task has no expert recipe; tests/test_recipes.py covers one that has)."""
  cli = load_script("run")
  head = lambda *argv: cli.train_config(cli.parse_args(list(argv))).policy_head
  assert head() == "paper" and head("--method", "expert") == "paper"
  assert head("--method", "expert", "--policy_head", "acme") == "acme"
  assert head("--method", "form", "--policy_head", "acme") == "acme"


def test_action_noise_correlation_flag_reaches_the_config():
  """--action_noise_correlation sets the actors' noise correlation for either method; 0 without
  (the default task has no expert recipe)."""
  cli = load_script("run")
  c = lambda *argv: cli.train_config(cli.parse_args(list(argv))).action_noise_correlation
  assert c() == 0.0 and c("--method", "expert") == 0.0
  assert c("--method", "expert", "--action_noise_correlation", "0.9") == 0.9
  assert c("--method", "form", "--action_noise_correlation", "0.5") == 0.5


def _readme_args(run_dir, *extra):
  """The README's main command, shortened to one iteration, in `run_dir`."""
  argv = run_commands()[0]
  steps = argv.index("--env_steps") + 1
  args = load_script("run").parse_args(argv)
  one_iteration = str(args.num_envs * args.unroll_length)
  return argv[:steps] + [one_iteration] + argv[steps + 1:] + ["--run_dir", str(run_dir),
                                                              *extra]


@pytest.mark.slow
def test_evaluate_run_scores_every_policy_a_form_run_kept(tmp_path):
  """scripts/evaluate_run.py after the README's main command (one iteration, no final
  evaluations, as a run stopped by its time budget): every policy the run kept is scored
  afresh, the average's too, and the records go to the run's packed curve."""
  cli, run_dir, curve = load_script("run"), tmp_path / "run", tmp_path / "curve.jsonl"
  assert cli.main(_readme_args(run_dir, "--final_eval_envs", "0", "--results", str(curve))) == 0
  assert [r["kind"] for r in results.read_records(str(curve))] == ["learning_curve"]
  results.pack_curve(str(curve))  # (as committed: the curve alone, packed)
  assert load_script("evaluate_run").main(["--run_dir", str(run_dir), "--curve", str(curve),
                                           "--episodes", "2", "--chunk", "2"]) == 0
  assert [r["policy"] for r in results.read_records(str(curve))] == [
      "final", "final_sampled", "best", "best_log_pd", "average", "best_log_pd_average"]


def test_form_command_line_runs_every_stage(tmp_path, capsys):
  """The README's main command (the default method, FORM): the shipped expert's
  demonstrations check the shipped demonstrator, MPO imitates, the policies are evaluated
  afresh; the run resumes; a demonstrator is trained where asked, kept in the run directory;
  each stage starts from saved artefacts; mismatched or damaged artefacts are refused."""
  cli = load_script("run")
  first, curve = tmp_path / "readme", tmp_path / "curve.jsonl"
  saved = tmp_path / "demos.npz"
  readme = cli.parse_args(_readme_args(first))
  k, final_episodes = readme.demo_episodes, readme.final_eval_envs
  assert cli.main(_readme_args(first, "--results", str(curve), "--save_demos", str(saved))) == 0
  out = capsys.readouterr().out
  for expected in (f"recording {k} episodes of the expert",
                   "tasks/demonstrators/reacher_easy.npz",
                   f"its log-likelihood on this run's {k} demonstrations", "form reward",
                   f"fresh evaluation of the final policy over {final_episodes} episodes",
                   "done:"):
    assert expected in out, expected
  shipped = effect_models.load_effect_model(tasks.bundled_demonstrator("reacher_easy"))
  assert (first / "demonstrator.npz").read_bytes() == open(
      tasks.bundled_demonstrator("reacher_easy"), "rb").read()
  records = results.read_records(str(curve))
  assert [r["kind"] for r in records] == ["learning_curve"] + ["final_return"] * 6
  assert all(r["method"] == "form" for r in records)
  assert all(np.isfinite(records[0][k]) for k in ("form_reward", "demonstrator_log_prob",
                                                  "imitator_batch_log_prob", "eval_return",
                                                  "eval_demonstrator_log_prob"))
  # the evaluations' log pD (no task reward) in the records, the progress lines and the CSV
  assert all(np.isfinite(r["eval_demonstrator_log_prob"]) for r in records[1:])
  assert re.search(r"eval -?[0-9.]+ \(log pD -?[0-9.]+\)", out)
  assert "eval_demonstrator_log_prob" in (first / "progress.csv").read_text().splitlines()[0]
  assert 0.0 <= records[0]["form_reward_clipped"] < 0.5  # a share of the batch's transitions
  assert records[0]["settings"]["reward"]["demonstrator_sha256"] == shipped.metadata["sha256"]
  # FORM's default run settings (mjx_form/imitation/settings.py): standardised reward clipped
  # at 3 sd, T 25.
  assert records[0]["settings"]["reward"]["standardise_reward"] is True
  assert records[0]["settings"]["reward"]["reward_clip"] == 3.0
  assert records[0]["settings"]["learner"]["target_update_period"] == 25
  assert records[0]["learner_preset"] == "custom"
  # (and the policy averaged over updates, FORM's default: settings.DEFAULT_RUN, with its own
  # best by log pD)
  assert [r["policy"] for r in records[1:]] == ["final", "final_sampled", "best", "best_log_pd",
                                                "average", "best_log_pd_average"]
  assert re.search(r"eval -?[0-9.]+ \(log pD -?[0-9.]+\)  average policy -?[0-9.]+", out)
  assert records[1]["episodes"] == final_episodes and np.isfinite(records[1]["final_return"])
  assert (records[2]["eval_demonstrator_log_prob"]  # (sampled actions: other episodes)
          != records[1]["eval_demonstrator_log_prob"])
  # One evaluation, at the end: both best policies are the final one (the same arrays), whose
  # fresh evaluation they repeat rather than run again; so is the average's best the average.
  # (The final policy with sampled actions is its own evaluation.)
  assert [r.get("same_policy_as") for r in records[1:]] == [None, None, "final", "final", None,
                                                            "average"]
  chosen = policy_io.load_policy(first / "best_log_pd_average_policy.npz")[1]
  assert chosen["sha256"] == policy_io.load_policy(first / "average_policy.npz")[1]["sha256"]
  assert (chosen["eval_return"], chosen["eval_demonstrator_log_prob"]) == (
      records[0]["eval_return_average"], records[0]["eval_demonstrator_log_prob_average"])
  assert len({(r["final_return"], r["eval_demonstrator_log_prob"])
              for r in (records[1], *records[3:5])}) == 1
  assert re.search(r"the best policy by log pD holds the final policy's arrays: -?[0-9.]+ \+- "
                   r"[0-9.]+ \(log pD -?[0-9.]+\), not evaluated again", out)
  shas = {r["policy_sha256"] for r in records[1:5]}
  assert shas == {policy_io.load_policy(first / "policy.npz")[1]["sha256"]}
  # The imitator model at the run's end, beside the policy (one update per learner step).
  imitator = effect_models.load_effect_model(first / "imitator.npz", task="reacher_easy")
  assert imitator.metadata["training"]["steps"] == records[0]["updates"] > 0
  assert imitator.metadata["imitator"]["env_steps"] == records[0]["env_steps"]
  assert imitator.metadata["config"] == shipped.metadata["config"]
  # Resume: the kept demonstrator is used; the run continues from its checkpoint.
  assert cli.main(_readme_args(first, "--env_steps", str(2 * readme.env_steps), "--resume",
                               "--final_eval_envs", "0", "--results", str(curve))) == 0
  assert "resumed from iteration 1" in capsys.readouterr().out
  assert checkpoint.latest_step(str(first / "checkpoints")) == 2
  # (the average's best by log pD, resumed from its file, is the higher of its two evaluations)
  points = [r for r in results.read_records(str(curve)) if r["kind"] == "learning_curve"]
  assert policy_io.load_policy(first / "best_log_pd_average_policy.npz")[1][
      "eval_demonstrator_log_prob"] == max(r["eval_demonstrator_log_prob_average"] for r in points)
  resumed = effect_models.load_effect_model(first / "imitator.npz", task="reacher_easy")
  assert resumed.metadata["training"]["steps"] == 2 * records[0]["updates"]  # rewritten
  # The best policies over both processes' evaluations: by their task return, and by their
  # log pD (no task reward), each with the value that chose it.
  curve_points = [r for r in results.read_records(str(curve)) if r["kind"] == "learning_curve"]
  assert len(curve_points) == 2
  for file, key in (("best_policy.npz", "eval_return"),
                    ("best_log_pd_policy.npz", "eval_demonstrator_log_prob")):
    kept = policy_io.load_policy(first / file)[1]
    best = max(curve_points, key=lambda r: r[key])
    assert (kept[key], kept["env_steps"]) == (best[key], best["env_steps"]), file
    # what a resume starts from: the kept value; none kept: -inf, except a run that kept a best
    # policy by the return and not this one (started before it existed): +inf, it keeps none
    from mjx_form.rl import runner
    assert runner._resumed_best(str(first / file), key, str(first / "best_policy.npz")) == kept[key]
    assert runner._resumed_best(str(tmp_path / file), key, str(tmp_path / "best_policy.npz")) == (
        -np.inf)
  assert runner._resumed_best(str(tmp_path / "best_log_pd_policy.npz"),
                              "eval_demonstrator_log_prob", str(first / "best_policy.npz")) == np.inf

  # Stages from saved artefacts: the first run's demonstrations train a demonstrator, kept in
  # the run directory.
  run_dir = tmp_path / "trained"
  assert cli.main(_readme_args(run_dir, "--demos", str(saved), "--train_demonstrator",
                               "--demonstrator_steps", "20", "--demonstrator_eval_every", "10",
                               "--demonstrator_seed", "3",
                               "--max_seconds", "1000", "--results", str(curve))) == 0
  out = capsys.readouterr().out
  for expected in (f"demonstrations: {k} episodes from", "demonstrator step 20",
                   "demonstrator written to", "demonstrator step 10  - steps/s",
                   "--max_seconds 1000: "):
    assert expected in out, expected
  assert not re.search(r"\bnan\b", out)  # the first, compiling chunk is not timed
  demonstrator = effect_models.load_effect_model(run_dir / "demonstrator.npz",
                                                 task="reacher_easy")
  meta = demonstrator.metadata
  assert meta["config"] == shipped.metadata["config"] and meta["training"]["steps"] == 20
  assert (meta["training"]["batch_size"], meta["training"]["window"]) == (readme.batch_size,
                                                                          readme.unroll_length)
  assert meta["demonstrations"]["episodes"] == k and meta["demonstrations"]["file"] == "demos.npz"
  assert meta["demonstrations"]["expert"]["policy_file"] == "reacher_easy.npz"
  assert demos.load_demonstrations(saved, task="reacher_easy").actions.shape == (k, 1000, 2)
  records = results.read_records(str(curve))[8:]  # (after the first run's and its resume's)
  kinds = [r["kind"] for r in records]
  assert kinds == ["effect_model", "learning_curve"] + ["final_return"] * 6
  assert len(records[0]["heldout_log_likelihood"]) == 5 and records[0]["steps"] == 20
  assert records[0]["settings"]["max_seconds"] == 500.0  # about half of --max_seconds
  assert records[0]["stopped_by"] == "max_steps"
  # --demonstrator_seed seeds the demonstrator's training (the learner keeps --seed)
  assert records[0]["settings"]["seed"] == records[0]["seed"] == 3
  assert records[1]["seed"] == 0
  # --max_seconds counts from the command's start: the demonstrations and the demonstrator's
  # training came before the runner and count against it (a sitting's job given the seconds
  # left of the sitting ended 274 s past them when they did not).
  assert records[1]["pre_training_s"] >= records[0]["seconds"] > 0
  assert all(r["method"] == "form" for r in records)
  assert all(np.isfinite(records[1][k]) for k in ("form_reward", "demonstrator_log_prob",
                                                  "imitator_batch_log_prob", "eval_return"))
  assert records[1]["settings"]["reward"]["demonstrator_sha256"] == meta["sha256"]
  assert records[1]["settings"]["reward"]["standardise_reward"] is True
  # --preset paper gives the paper's raw reward and target period, to the reward source (its
  # arithmetic: the test above) and the learner; single flags override a preset. (The saved
  # demonstrations check the shipped demonstrator: nothing new to record or compile.)
  args = cli.parse_args(_readme_args(tmp_path / "paper", "--preset", "paper",
                                     "--demos", str(saved), "--reward_clip", "3"))
  source = cli.form_source(args, str(tmp_path / "paper"), None, print)
  assert not source.standardise_reward and source.settings()["standardise_reward"] is False
  assert source.settings()["reward_clip"] == 3.0  # --reward_clip reaches the source
  assert cli.train_config(args).learner.target_update_period == 200
  args = cli.parse_args(_readme_args(tmp_path / "mixed", "--preset", "paper", "--reward_scale",
                                     "standardised", "--target_update_period", "50"))
  assert cli.form_run_settings(args) == {"standardise_reward": True, "reward_clip": 0.0,
                                         "target_update_period": 50,
                                         "sampled_q_bfloat16": False,
                                         "policy_average_decay": 0.0}
  assert cli.train_config(cli.parse_args(["--method", "expert"])).learner.target_update_period == 200
  # --turn_invariant: the shipped demonstrator (no period) does not fit, so one is trained with
  # the task's periods (reacher's shoulder), which the imitator model shares.
  turning = tmp_path / "turning"
  args = cli.parse_args(_readme_args(turning, "--turn_invariant", "--demos", str(saved),
                                     "--demonstrator_steps", "10",
                                     "--demonstrator_eval_every", "10"))
  source = cli.form_source(args, str(turning), None, print)
  period = (2 * np.pi, 0.0, 0.0, 0.0, 0.0, 0.0)
  np.testing.assert_allclose(source.config.period, period)
  assert source.model.period == source.config.period
  kept = effect_models.load_effect_model(turning / "demonstrator.npz", task="reacher_easy")
  np.testing.assert_allclose(kept.metadata["config"]["period"], period)
  assert "trained with other settings" in capsys.readouterr().out
  assert records[1]["learner_preset"] == "custom"
  assert [r["policy"] for r in records[2:]] == ["final", "final_sampled", "best", "best_log_pd",
                                                "average", "best_log_pd_average"]
  assert records[2]["episodes"] == final_episodes and np.isfinite(records[2]["final_return"])

  # Refusals: exit code 2, the file and the mismatch named, nothing written. (A run given a
  # demonstrator checks it on demonstrations first: the saved ones, not 4 recorded episodes.)
  other_task = tmp_path / "cheetah_demonstrator.npz"
  effect_models.save_effect_model(other_task, demonstrator.params, np.zeros(17), np.ones(17), {
      **{k: v for k, v in meta.items() if k not in ("format", "version", "sha256")},
      "task": "cheetah_run", "observation_size": 17,
      "observation_layout": [["position", 8], ["velocity", 9]]})
  truncated = tmp_path / "truncated.npz"
  truncated.write_bytes((run_dir / "demonstrator.npz").read_bytes()[:300])
  other_demos = tmp_path / "cheetah_demos.npz"
  demos.save_demonstrations(other_demos, np.zeros((2, 11, 17)), metadata={
      "task": "cheetah_run", "observation_layout": {"position": 8, "velocity": 9},
      "physics": "fast"})
  checked_on = ["--demos", str(saved)]
  refusals = [
      (["--demonstrator", str(other_task), *checked_on], "the demonstrator is for cheetah_run"),
      (["--demonstrator", str(truncated), *checked_on], "truncated"),
      (["--demonstrator", str(first / "imitator.npz"), *checked_on], "an imitator model"),
      (["--demonstrator", str(run_dir / "demonstrator.npz"), "--beta_ar", "0.5", *checked_on],
       "trained with beta_ar="),
      (["--demonstrator", str(run_dir / "demonstrator.npz"), "--turn_invariant", *checked_on],
       "trained with turn-invariance period (--turn_invariant)=()"),
      (["--task", "walker_walk", "--turn_invariant"],
       "walker_walk observes no unbounded angle"),
      (["--demos", str(other_demos)], "demonstrations are for cheetah_run"),
      (["--expert", str(tmp_path / "missing.npz")], "no such policy file"),
      (["--reward_clip", "1"], "--reward_clip must be 0 (off) or finite and > 1"),
  ]
  for extra, message in refusals:
    target = tmp_path / "refused"
    assert cli.main(_readme_args(target, *extra)) == 2, extra
    err = capsys.readouterr().err
    assert message in err, (extra, err)
    assert not target.exists(), extra
  # A task without a shipped expert says which one is missing and how to train it.
  target = tmp_path / "humanoid"
  assert cli.main(_readme_args(target, "--task", "humanoid_run")) == 2
  err = capsys.readouterr().err
  assert "no shipped expert for 'humanoid_run'" in err and "--method expert" in err
  assert not target.exists()
  # An existing run is not overwritten.
  before = (run_dir / "demonstrator.npz").read_bytes()
  assert cli.main(_readme_args(run_dir)) == 2
  assert "--resume" in capsys.readouterr().err
  assert (run_dir / "demonstrator.npz").read_bytes() == before


def test_a_demonstrator_of_another_expert_is_named():
  """walker_walk's former demonstrator (benchmarks/demonstrators/) was trained on the former
  expert's demonstrations (878.8); demonstrations of the shipped expert get a notice naming
  both policies, those of the same policy none. The shipped demonstrator learned the shipped
  expert's: no notice."""
  from mjx_form.files import policy_io
  from mjx_form.imitation import pipeline
  former = os.path.join(os.path.dirname(__file__), "..", "benchmarks", "demonstrators",
                        "walker_walk_expert_136e17.npz")
  demonstrator = effect_models.load_effect_model(former)
  theirs = demonstrator.metadata["demonstrations"]["expert"]
  path = tasks.bundled_expert("walker_walk")
  _, meta = policy_io.load_policy(path)
  ours = {"expert": experts.recording_info(path, meta, np.array([950.0, 970.0]), 0, False)}
  shipped = effect_models.load_effect_model(tasks.bundled_demonstrator("walker_walk"))
  assert pipeline.another_expert(shipped.metadata, ours) is None
  notice = pipeline.another_expert(demonstrator.metadata, ours)
  assert notice is not None and "another expert policy" in notice, notice
  assert theirs["policy_sha256"][:12] in notice and meta["sha256"][:12] in notice, notice
  assert "mean return 878.8" in notice and "mean return 960.0" in notice, notice
  same = {"expert": dict(ours["expert"], policy_sha256=theirs["policy_sha256"])}
  assert pipeline.another_expert(demonstrator.metadata, same) is None
  assert pipeline.another_expert(demonstrator.metadata, {"expert": {}}) is None  # unknown


def test_a_demonstrator_far_below_its_held_out_fit_on_its_own_experts_episodes_is_named():
  """misfit: a demonstrator whose offset-1 log-likelihood on this run's demonstrations of the
  expert policy it learned lies more than MISFIT_NATS below its own held-out figure learned
  other behaviour of it (quadruped_walk's former one: -325.6 against 27.6, its demonstrations
  recorded with actions clipped inside the control range). Not said of another policy's
  demonstrations (another_expert's notice) or where a policy or the figure is unknown."""
  from mjx_form.imitation import pipeline
  meta = effect_models.load_effect_model(tasks.bundled_demonstrator("reacher_easy")).metadata
  held = meta["training"]["heldout_log_likelihood"][0]
  sha = meta["demonstrations"]["expert"]["policy_sha256"]
  ours = {"episodes": 16, "expert": {"policy_sha256": sha}}
  fit = lambda first: np.array([first, 0.0, 0.0, 0.0, 0.0])
  assert pipeline.misfit(meta, ours, fit(held - pipeline.MISFIT_NATS + 0.01)) is None
  assert pipeline.misfit(meta, ours, fit(held + 5.0)) is None
  low = held - pipeline.MISFIT_NATS - 0.01
  why = pipeline.misfit(meta, ours, fit(low))
  assert why is not None and f"{low:.2f}" in why and f"{held:.2f}" in why, why
  assert sha[:12] in why and "16 demonstrations" in why, why
  other = {"episodes": 16, "expert": {"policy_sha256": "0" * 64}}
  assert pipeline.misfit(meta, other, fit(low)) is None
  assert pipeline.misfit(meta, {"episodes": 16, "expert": {}}, fit(low)) is None
  assert pipeline.misfit(dict(meta, training={}), ours, fit(low)) is None


def _stub_recording_of_the_expert(monkeypatch, pipeline, sha256: str) -> list:
  """Replaces the pipeline's recording by 2 random episodes of reacher's shape said to be the
  expert `sha256`'s (no demonstrator fits them); the list gets the episodes asked for."""
  demo_obs = np.random.default_rng(0).normal(size=(2, 201, D)).astype(np.float32)
  asked = []
  def record(env, artefacts, episodes, *args, **kwargs):
    asked.append(episodes)
    if artefacts.save_demos:  # (as save_demonstrations: never over an existing file)
      with open(artefacts.save_demos, "x") as f:
        f.write(str(episodes))
    return demo_obs, {"episodes": episodes, "expert": {"policy_sha256": sha256}}
  monkeypatch.setattr(pipeline, "demonstrations", record)
  return asked


def test_a_demonstrator_that_misfits_its_experts_episodes_is_refused_or_replaced(tmp_path,
                                                                                   monkeypatch):
  """A --demonstrator file that misfits this run's demonstrations of its own expert (misfit) is
  refused by name before anything is written; --demo_episodes 0 uses it unchecked. The shipped
  one is replaced: the run records the 1000 training episodes and trains one on them."""
  from mjx_form.imitation import pipeline
  env = tasks.make("reacher_easy")
  config = settings.effect_model_config("reacher_easy", env)
  shipped = tasks.bundled_demonstrator("reacher_easy")
  meta = effect_models.load_effect_model(shipped).metadata
  asked = _stub_recording_of_the_expert(monkeypatch, pipeline,
                                        meta["demonstrations"]["expert"]["policy_sha256"])
  prepare = lambda run_dir, artefacts, lines=None: pipeline.prepare(
      env, config, {}, artefacts, str(tmp_path / run_dir), resume=False, physics="fast", seed=0,
      results_path=None, print_fn=(lines if lines is not None else []).append)
  with pytest.raises(pipeline.PipelineError, match=re.escape(shipped) + ": its log-likelihood "
                     "at offset 1 .* below its own held-out .*--train_demonstrator"):
    prepare("given", pipeline.Artefacts(demonstrator=(shipped,)))
  assert asked == [pipeline.DEFAULT_CHECK_EPISODES] and not (tmp_path / "given").exists()
  source = prepare("unchecked", pipeline.Artefacts(demonstrator=(shipped,), demo_episodes=0))
  assert source.demonstrator_sha256 == meta["sha256"] and len(asked) == 1

  class Trains(Exception):
    pass
  def train(env, config, demos_obs, demos_info, *args, **kwargs):
    raise Trains(demos_info["episodes"])
  monkeypatch.setattr(pipeline, "train_demonstrator", train)
  lines, saved = [], tmp_path / "demos.npz"
  with pytest.raises(Trains) as trained:
    prepare("shipped", pipeline.Artefacts(save_demos=str(saved)), lines)
  assert trained.value.args == (pipeline.DEFAULT_TRAINING_EPISODES,)
  assert asked[1:] == [pipeline.DEFAULT_CHECK_EPISODES, pipeline.DEFAULT_TRAINING_EPISODES]
  assert saved.read_text() == str(pipeline.DEFAULT_TRAINING_EPISODES)  # (the 16 gave way)
  assert any(line.startswith(f"the shipped demonstrator {shipped}: its log-likelihood")
             and "training one on this run's demonstrations" in line for line in lines), lines


def test_a_demonstrator_that_does_not_fit_is_refused_before_anything_is_recorded(tmp_path,
                                                                                   monkeypatch):
  """A run given --demonstrator checks the file first: another task's or a damaged one is
  refused before the expert's episodes are recorded (they take minutes on a large task), and
  nothing is written in the run directory."""
  from mjx_form.imitation import pipeline
  def record(*args, **kwargs):
    raise AssertionError("demonstrations were recorded before the demonstrator was checked")
  monkeypatch.setattr(pipeline, "demonstrations", record)
  env = tasks.make("reacher_easy")
  config = settings.effect_model_config("reacher_easy", env)
  truncated = tmp_path / "truncated.npz"
  truncated.write_bytes(open(tasks.bundled_demonstrator("reacher_easy"), "rb").read()[:300])
  for path, message in ((tasks.bundled_demonstrator("cheetah_run"), "cheetah_run"),
                        (str(truncated), "truncated")):
    run_dir = tmp_path / f"run_{len(message)}"
    with pytest.raises(ValueError, match=message):
      pipeline.prepare(env, config, {}, pipeline.Artefacts(demonstrator=(path,)), str(run_dir),
                       resume=False, physics="fast", seed=0, results_path=None,
                       print_fn=lambda line: None)
    assert not run_dir.exists()
  # A file that fits goes on to the check on demonstrations (here: the stand-in's error).
  with pytest.raises(AssertionError, match="were recorded"):
    pipeline.prepare(env, config, {}, pipeline.Artefacts(
        demonstrator=(tasks.bundled_demonstrator("reacher_easy"),)), str(tmp_path / "fits"),
        resume=False, physics="fast", seed=0, results_path=None, print_fn=lambda line: None)


def test_demo_episodes_0_keeps_a_ready_demonstrator_unchecked_and_refuses_training_one(
    tmp_path, monkeypatch, capsys):
  """--demo_episodes 0: the shipped (or given) demonstrator is kept and used without recording
  the expert's episodes to check it (~40 s of a walker job on a GPU); where none is ready (one
  would be trained), the run is refused by name before anything is recorded or written; the
  parser refuses it beside --demos, --save_demos, --expert and --train_demonstrator."""
  from mjx_form.imitation import pipeline
  recorded = _stub_recording(monkeypatch, pipeline, episodes=2)
  env = tasks.make("reacher_easy")
  config = settings.effect_model_config("reacher_easy", env)
  lines = []
  source = pipeline.prepare(env, config, {}, pipeline.Artefacts(demo_episodes=0),
                            str(tmp_path / "run"), resume=False, physics="fast", seed=0,
                            results_path=None, print_fn=lines.append)
  shipped = tasks.bundled_demonstrator("reacher_easy")
  assert not recorded
  assert source.demonstrator_sha256 == effect_models.load_effect_model(shipped).metadata["sha256"]
  assert open(tmp_path / "run" / "demonstrator.npz", "rb").read() == open(shipped, "rb").read()
  assert "--demo_episodes 0: the demonstrator is not checked on demonstrations" in lines
  assert not any("its log-likelihood on this run's" in line for line in lines)
  with pytest.raises(pipeline.PipelineError, match="--demo_episodes 0 .* none is ready for "
                     "reacher_easy"):
    pipeline.prepare(env, config, {}, pipeline.Artefacts(demo_episodes=0, train_demonstrator=True),
                     str(tmp_path / "trains"), resume=False, physics="fast", seed=0,
                     results_path=None, print_fn=lines.append)
  assert not recorded and not (tmp_path / "trains").exists()
  # (with the default, the same ready demonstrator is checked on recorded episodes)
  pipeline.prepare(env, config, {}, pipeline.Artefacts(), str(tmp_path / "checked"),
                   resume=False, physics="fast", seed=0, results_path=None,
                   print_fn=lines.append)
  assert recorded == [1]
  cli = load_script("run")
  for extra in (["--demos", "d.npz"], ["--save_demos", "d.npz"], ["--expert", "e.npz"],
                ["--train_demonstrator"]):
    with pytest.raises(SystemExit):
      cli.parse_args(["--task", "reacher_easy", "--demo_episodes", "0", *extra])
    assert "--demo_episodes 0 (no demonstrations" in capsys.readouterr().err
  with pytest.raises(SystemExit):
    cli.parse_args(["--task", "reacher_easy", "--demo_episodes", "-1"])
  assert "--demo_episodes must be >= 0, got -1" in capsys.readouterr().err
  assert cli.parse_args(["--task", "reacher_easy", "--demo_episodes", "0"]).demo_episodes == 0


def _reacher_easy_demonstrator_files(tmp_path) -> tuple[str, str, str]:
  """(the shipped reacher_easy demonstrator, a former one, the former one's model written as if
  trained at L2 1: a file of other settings)."""
  shipped = tasks.bundled_demonstrator("reacher_easy")
  former = os.path.join("benchmarks", "demonstrators", "reacher_easy_expert_d93ef5.npz")
  file = effect_models.load_effect_model(former)
  other = str(tmp_path / "other.npz")
  meta = {k: v for k, v in file.metadata.items() if k not in ("format", "version", "sha256")}
  effect_models.save_effect_model(other, file.params, file.mean, file.var, dict(
      meta, config=dict(meta["config"], l2=1.0)))
  return shipped, former, other


def _stub_recording(monkeypatch, pipeline, episodes: int) -> list:
  """Replaces the pipeline's recording of demonstrations by `episodes` random ones of
  reacher's shape; the list returned gets an entry per recording."""
  demo_obs = np.random.default_rng(0).normal(size=(episodes, 201, D)).astype(np.float32)
  recorded = []
  def record(*args, **kwargs):
    recorded.append(1)
    return demo_obs, {"episodes": episodes, "expert": {}}
  monkeypatch.setattr(pipeline, "demonstrations", record)
  return recorded


def test_an_ensemble_of_demonstrator_files_is_checked_kept_and_resumed(tmp_path, monkeypatch):
  """Several --demonstrator files: each is checked on the demonstrations and kept in the run
  directory (demonstrator.npz, demonstrator_1.npz), the reward source scores with their mixture
  and is named by their sorted checksums; --resume reads them back. Refused before anything
  is recorded or written: a file given twice, and two trained with other settings."""
  from mjx_form.imitation import pipeline
  env = tasks.make("reacher_easy")
  config = settings.effect_model_config("reacher_easy", env)
  shipped, former, other = _reacher_easy_demonstrator_files(tmp_path)
  recorded = _stub_recording(monkeypatch, pipeline, episodes=2)
  prepare = lambda run_dir, paths, **kw: pipeline.prepare(
      env, config, {}, pipeline.Artefacts(demonstrator=paths), str(run_dir), physics="fast",
      seed=0, results_path=None, print_fn=lines.append, **kw)
  copy = str(tmp_path / "copy.npz")
  with open(copy, "wb") as f:
    f.write(open(shipped, "rb").read())
  for paths, message in (((shipped, shipped), "given twice"),
                         ((shipped, copy), "the same demonstrator as"),
                         ((former, other), r"other effect-model settings than .*\(l2 1.0 "
                                           r"against 0.1\)")):
    lines = []
    with pytest.raises(pipeline.PipelineError, match=message):
      prepare(tmp_path / "refused", paths, resume=False)
    assert not recorded and not (tmp_path / "refused").exists()
  lines = []
  source = prepare(tmp_path / "run", (shipped, former), resume=False)
  shas = sorted(effect_models.load_effect_model(p).metadata["sha256"] for p in (shipped, former))
  assert source.ensemble == 2 and source.demonstrator_sha256 == "+".join(shas)
  assert sum("its log-likelihood on this run's 2 demonstrations" in line for line in lines) == 2
  assert "an ensemble of 2 demonstrators: log pD is their mixture's" in lines
  for name, path in (("demonstrator.npz", shipped), ("demonstrator_1.npz", former)):
    assert open(tmp_path / "run" / name, "rb").read() == open(path, "rb").read()
  (tmp_path / "run" / "config.json").write_text("{}")  # (what the runner writes)
  resumed = prepare(tmp_path / "run", (), resume=True)
  assert resumed.ensemble == 2 and resumed.demonstrator_sha256 == source.demonstrator_sha256
  np.testing.assert_array_equal(resumed.demonstrator.normalizer.mean,
                                source.demonstrator.normalizer.mean)
  with pytest.raises(Exception, match="already holds a run"):  # nothing overwritten
    prepare(tmp_path / "run", (shipped, former), resume=False)
  lines = []  # the mean of their log pD, asked for as run.py asks (its `reward` settings)
  averaged = prepare(tmp_path / "mean", (shipped, former), resume=False,
                     reward={"ensemble_log_pd": "mean"})
  assert averaged.ensemble_log_pd == "mean" and averaged.settings()["ensemble_log_pd"] == "mean"
  assert "an ensemble of 2 demonstrators: log pD is the mean of their log pD" in lines
  prepare(tmp_path / "both", (shipped, former), resume=False, varied=("ensemble_log_pd",))
  assert ("an ensemble of 2 demonstrators: log pD is their mixture's or the mean of their log "
          "pD, as each member's --grid ensemble_log_pd says") in lines
  # A directory holding only an ensemble's second file is a used one too (a later --resume
  # would read it).
  (tmp_path / "leftover").mkdir()
  (tmp_path / "leftover" / "demonstrator_1.npz").write_bytes(b"")
  with pytest.raises(Exception, match="already holds a run .*demonstrator_1.npz"):
    prepare(tmp_path / "leftover", (shipped,), resume=False)


def test_demonstrator_files_per_member_are_checked_kept_and_resumed(tmp_path, monkeypatch):
  """--member_demonstrators' files: refused before anything is recorded or written where two
  were trained with other settings or fewer than 2 are given; else each is checked once on
  the demonstrations (a file may go to several members) and kept once per member in order;
  --resume reads them back as demonstrators per member where the run's config.json says so."""
  from mjx_form.imitation import pipeline
  env = tasks.make("reacher_easy")
  config = settings.effect_model_config("reacher_easy", env)
  shipped, former, other = _reacher_easy_demonstrator_files(tmp_path)
  recorded = _stub_recording(monkeypatch, pipeline, episodes=2)
  prepare = lambda run_dir, paths, **kw: pipeline.prepare(
      env, config, {}, pipeline.Artefacts(demonstrator=paths, member_demonstrators=True),
      str(run_dir), physics="fast", seed=0, results_path=None, print_fn=lines.append, **kw)
  for paths, message in (((former, other, former), r"other effect-model settings than .*"
                                                   r"\(l2 1.0 against 0.1\)"),
                         ((shipped,), "one --demonstrator file per member")):
    lines = []
    with pytest.raises(pipeline.PipelineError, match=message):
      prepare(tmp_path / "refused", paths, resume=False)
    assert not recorded and not (tmp_path / "refused").exists()
  lines = []
  source = prepare(tmp_path / "run", (shipped, former, shipped), resume=False)
  shas = [effect_models.load_effect_model(p).metadata["sha256"] for p in (shipped, former)]
  assert source.per_member == 3 and source.ensemble == 0
  assert source.settings()["member_demonstrators"] == [shas[0], shas[1], shas[0]]
  assert sum("its log-likelihood on this run's 2 demonstrations" in line for line in lines) == 2
  for name, path in (("demonstrator.npz", shipped), ("demonstrator_1.npz", former),
                     ("demonstrator_2.npz", shipped)):
    assert open(tmp_path / "run" / name, "rb").read() == open(path, "rb").read()
  (tmp_path / "run" / "config.json").write_text(json.dumps({"reward": source.settings()}))
  resumed = prepare(tmp_path / "run", (), resume=True)
  assert resumed.per_member == 3 and resumed.settings() == source.settings()
  np.testing.assert_array_equal(resumed.demonstrator.normalizer.mean,
                                source.demonstrator.normalizer.mean)
  # Kept files that are not the ones config.json lists: named, nothing resumed.
  second = (tmp_path / "run" / "demonstrator_1.npz").read_bytes()
  (tmp_path / "run" / "demonstrator_1.npz").write_bytes(open(shipped, "rb").read())
  with pytest.raises(pipeline.PipelineError, match="demonstrator_1.npz is not member 1's"):
    prepare(tmp_path / "run", (), resume=True)
  (tmp_path / "run" / "demonstrator_1.npz").write_bytes(second)
  (tmp_path / "run" / "demonstrator_2.npz").rename(tmp_path / "third.npz")
  with pytest.raises(pipeline.PipelineError, match="demonstrator_2.npz is missing"):
    prepare(tmp_path / "run", (), resume=True)
  (tmp_path / "third.npz").rename(tmp_path / "run" / "demonstrator_2.npz")
  # Where config.json names no demonstrators per member, the kept files are an ensemble
  # (refused here: one file is kept twice).
  (tmp_path / "run" / "config.json").write_text("{}")
  with pytest.raises(pipeline.PipelineError, match="the same demonstrator as"):
    pipeline.prepare(env, config, {}, pipeline.Artefacts(), str(tmp_path / "run"),
                     physics="fast", seed=0, results_path=None, print_fn=lines.append,
                     resume=True)


@pytest.mark.slow
def test_demonstrator_draws_per_member_are_trained_side_by_side_and_kept(tmp_path,
                                                                         monkeypatch):
  """--member_demonstrators --train_demonstrator: one draw per member, of the given seeds, on
  the same demonstrations, trained in one program; each kept in the run directory in order,
  with its record (its seed) and its checksum as its member's; fewer than 2 seeds, or a seed
  twice, refused before anything is recorded or written."""
  from mjx_form.imitation import demonstrator, pipeline
  env = tasks.make("reacher_easy")
  config = em.EffectModelConfig(width=16)
  recorded = _stub_recording(monkeypatch, pipeline, episodes=3)
  training = demonstrator.DemonstratorTraining(max_steps=20, batch_size=4, window=20,
                                               eval_every=10, heldout_fraction=0.34)
  lines, curve = [], str(tmp_path / "curve.jsonl")
  prepare = lambda run_dir, seeds: pipeline.prepare(
      env, config, {}, pipeline.Artefacts(train_demonstrator=True, member_demonstrators=True,
                                          draw_seeds=seeds, training=training),
      str(run_dir), resume=False, physics="fast", seed=0, results_path=curve,
      print_fn=lines.append)
  for seeds in ((4,), (4, 4)):
    with pytest.raises(pipeline.PipelineError, match="2 or more distinct draw seeds"):
      prepare(tmp_path / "refused", seeds)
    assert not recorded and not (tmp_path / "refused").exists()
  source = prepare(tmp_path / "run", (4, 5))
  assert recorded == [1] and source.per_member == 2
  files = [effect_models.load_effect_model(str(tmp_path / "run" / name))
           for name in ("demonstrator.npz", "demonstrator_1.npz")]
  assert [f.metadata["training"]["seed"] for f in files] == [4, 5]
  assert source.settings()["member_demonstrators"] == [f.metadata["sha256"] for f in files]
  assert files[0].metadata["sha256"] != files[1].metadata["sha256"]
  kept = [r for r in results.read_records(curve) if r["kind"] == "effect_model"]
  assert [(r["seed"], r["settings"]["seed"]) for r in kept] == [(4, 4), (5, 5)]
  assert any("2 draws side by side (seeds 4, 5)" in line for line in lines)


def test_effect_max_scale_flag_reaches_the_effect_models(capsys):
  """--effect_max_scale caps the effect models' scales (none by default: absent from the
  settings), refuses a value at or below min_scale, and applies to --method form only."""
  cli = load_script("run")
  env = tasks.make("reacher_easy")
  settings_of = lambda *argv: cli.effect_model_settings(
      cli.parse_args(["--task", "reacher_easy", "--method", "form", *argv]), env)
  explicit, default = settings_of()
  assert default.max_scale is None and "max_scale" not in default.to_dict()
  assert explicit["max_scale"] is None
  explicit, capped = settings_of("--effect_max_scale", "1")
  assert explicit["max_scale"] == 1.0 and capped.max_scale == 1.0
  assert capped.to_dict() == {**default.to_dict(), "max_scale": 1.0}
  with pytest.raises(ValueError, match="max_scale must be a number above min_scale"):
    settings_of("--effect_max_scale", "0")
  with pytest.raises(SystemExit):
    cli.parse_args(["--method", "expert", "--effect_max_scale", "1"])
  assert "--effect_max_scale apply to --method form only" in capsys.readouterr().err


def test_the_averages_best_resumes_from_its_file_and_only_averaging_members_keep_one(tmp_path):
  """best_log_pd_average_policy.npz: a resumed run reads its evaluation's log pD back (the file
  keeps it under the online policy's key); a run started before the file existed keeps none
  (+inf); in a population only the members that average are expected to have one."""
  from mjx_form.rl import runner
  name, key, file = runner.AVERAGE_BEST[0]
  chosen, best, absent = tmp_path / file, tmp_path / "best_policy.npz", tmp_path / "none.npz"
  meta = {"task": "reacher_easy", "observation_size": 6, "action_size": 2}
  assert runner._resumed_best(str(chosen), key, str(best)) == -np.inf  # (a new run)
  policy_io.save_policy(best, {"w": np.zeros(2, np.float32)}, {**meta, "eval_return": 1.0})
  assert runner._resumed_best(str(chosen), key, str(best)) == np.inf  # (started before it)
  policy_io.save_policy(chosen, {"w": np.zeros(2, np.float32)},
                        {**meta, "eval_return": 2.0, "eval_demonstrator_log_prob": 7.5})
  assert runner._resumed_best(str(chosen), key, str(best)) == 7.5
  assert runner._member_files(name, [str(chosen), str(absent)], [True, False]) == (
      [True, False], [])  # (member 1 keeps no average: its file is not missed)
  assert runner._member_files(name, [str(absent), str(chosen)], [True, True]) == ([True, True], [0])
  assert runner._member_files("best_log_pd", [str(chosen), str(absent)], [True, False]) == (
      [True, True], [1])  # (the online policy's bests: every member)
