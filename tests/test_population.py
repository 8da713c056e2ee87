"""Populations: several runs in one compiled program, each member the run its seed gives alone
(reacher_easy, small sizes, a population of 2 over the 2 forced host devices)."""

import csv
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import load_script
from test_train import CONFIG, _cli_args, run_iterations

from mjx_form import mesh as mesh_lib
from mjx_form.files import checkpoint, policy_io
from mjx_form.rl import train as train_lib
from mjx_form.rl.train import Trainer

pytestmark = pytest.mark.xdist_group("train")  # the single runs' programs are test_train's

SEEDS = (0, 1)


@pytest.fixture(scope="module")
def population():
  trainer = Trainer(CONFIG, mesh_lib.make_mesh(), seeds=SEEDS)
  assert trainer.members == 2 and trainer.mesh.devices.size == 2
  return trainer


def _members_of(trainer, state, i):
  """Member i's learner, normaliser and replay."""
  return trainer.member((state.learner, state.normalizer, state.replay), i)


def test_members_are_the_runs_their_seeds_give_alone(population):
  pop_state, pop_metrics = run_iterations(population, population.init(population.keys()), 3)
  pop_returns = np.asarray(population.evaluate(pop_state.learner.policy,
                                               pop_state.normalizer, population.keys(1)))
  assert pop_returns.shape == (2, CONFIG.eval_envs)
  # The population's environments and replay are split over both devices.
  assert len(pop_state.env.obs.sharding.device_set) == 2
  assert len(pop_state.replay.data["observation"].sharding.device_set) == 2
  single = Trainer(CONFIG, mesh_lib.make_mesh())  # one program for both seeds
  for i, seed in enumerate(SEEDS):
    key = jax.random.PRNGKey(seed)[None]
    state, metrics = run_iterations(single, single.init(key), 3)
    returns = np.asarray(single.evaluate(state.learner.policy, state.normalizer,
                                         jax.random.PRNGKey(seed + 1)[None]))
    ours = _members_of(population, pop_state, i)
    theirs = _members_of(single, state, 0)
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(ours), jax.tree.leaves(theirs)):
      np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=2e-4, atol=2e-5,
                                 err_msg=f"seed {seed}{jax.tree_util.keystr(path)}")
    n = CONFIG.num_envs
    np.testing.assert_allclose(pop_state.env.obs[i * n:(i + 1) * n], state.env.obs,
                               rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(pop_returns[i], returns[0], rtol=1e-4, atol=1e-3)
    for m_pop, m in zip(pop_metrics, metrics):
      np.testing.assert_allclose(m_pop["critic_loss"][i], m["critic_loss"][0], rtol=1e-3)
      assert m_pop["episodes"][i] == m["episodes"][0]
  # The members differ from each other (their seeds do).
  assert not np.allclose(pop_state.env.obs[:CONFIG.num_envs],
                         pop_state.env.obs[CONFIG.num_envs:2 * CONFIG.num_envs])


def test_a_failing_member_leaves_the_others_alone(population):
  """Member 1's policy parameters are NaN: its actions end its episodes by physics errors and
  its learner stays NaN, while member 0 computes exactly what it computes beside a healthy
  member 1."""
  start = population.init(population.keys())
  healthy, _ = run_iterations(population, start, 2)
  start = population.init(population.keys())
  poisoned_policy = jax.tree.map(lambda x: x.at[1].set(np.nan), start.learner.policy)
  poisoned = start._replace(learner=start.learner._replace(policy=poisoned_policy))
  sick, metrics = run_iterations(population, poisoned, 2)
  for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(
      _members_of(population, healthy, 0)), jax.tree.leaves(_members_of(population, sick, 0))):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b),
                                  err_msg=f"member 0{jax.tree_util.keystr(path)}")
  assert metrics[0]["physics_errors"][1] > 0 and metrics[0]["physics_errors"][0] == 0
  assert np.isnan(np.asarray(jax.tree.leaves(sick.learner.policy)[0][1])).all()


def test_population_from_the_command_line_writes_each_member(tmp_path, capsys):
  cli = load_script("run")
  run_dir, curve = tmp_path / "pop", tmp_path / "curve.jsonl"
  args = _cli_args(run_dir, "--seeds", "0,1", "--env_steps", "80", "--results", str(curve))
  assert cli.train_config(cli.parse_args(args)) == CONFIG  # the fixture's programs
  assert cli.main(args) == 0
  out = capsys.readouterr().out
  assert "a population of 2 (seeds 0, 1)" in out and "seed 1: iter 1/2" in out
  assert "seed 1: fresh evaluation of the best policy" in out
  assert json.load(open(run_dir / "config.json"))["seeds"] == [0, 1]
  assert checkpoint.latest_step(str(run_dir / "checkpoints")) == 2  # one for all members
  records = [json.loads(line) for line in open(curve)]
  for seed in SEEDS:
    member = run_dir / f"seed{seed}"
    with open(member / "progress.csv") as f:
      assert [int(r["iteration"]) for r in csv.DictReader(f)] == [1, 2]
    _, meta = policy_io.load_policy(member / "policy.npz", task="reacher_easy")
    assert meta["env_steps"] == 80 and meta["train_config"]["seed"] == seed
    assert policy_io.load_policy(member / "best_policy.npz")[1]["train_config"]["seed"] == seed
    mine = [r for r in records if r["seed"] == seed]
    assert [r["kind"] for r in mine] == ["learning_curve", "final_return", "final_return"]
    assert all(r["population"] == 2 and r["settings"]["seed"] == seed for r in mine)
  # The members' policies are their own.
  policies = [policy_io.load_policy(run_dir / f"seed{s}" / "policy.npz")[1]["sha256"]
              for s in SEEDS]
  assert len(set(policies)) == 2
  # Another set of seeds does not resume this population.
  assert cli.main(_cli_args(run_dir, "--seeds", "0,2", "--env_steps", "120", "--resume")) == 2
  assert "seeds" in capsys.readouterr().err


def test_memory_check_refuses_a_program_larger_than_the_device():
  """compile_ahead's check: XLA's memory analysis of the compiled program against the device's
  memory (here a given limit; the CPU reports none, and then nothing is refused)."""
  compiled = jax.jit(lambda x: x * 2).lower(jnp.ones((1000,))).compile()
  needed = train_lib.program_bytes(compiled)
  assert needed >= 4000  # its 1000 float32 argument at least
  with pytest.raises(ValueError, match="population of 3: one training iteration needs"):
    train_lib.check_memory(compiled, mesh_lib.make_mesh(), "population of 3", limit=needed - 1)
  train_lib.check_memory(compiled, mesh_lib.make_mesh(), "population of 3", limit=needed)
  train_lib.check_memory(compiled, mesh_lib.make_mesh(), "population of 3")
