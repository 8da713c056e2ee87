"""Populations: several runs in one compiled program, each member the run its seed and its own
settings give alone (reacher_easy, small sizes, a population of 2 over the 2 forced host
devices)."""

import csv
import dataclasses
import json
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import load_script
from test_train import CONFIG, _cli_args, run_iterations

from mjx_form import cpu
from mjx_form import mesh as mesh_lib
from mjx_form.files import checkpoint, policy_io, results
from mjx_form.rl import train as train_lib
from mjx_form.rl.train import Trainer

pytestmark = pytest.mark.xdist_group("train")  # the single runs' programs are test_train's

SEEDS = (0, 1)
# Member 1 has its own learner and actor settings (mjx_form.rl.grid; `--grid NAME=...` gives
# them): it copies its targets every 2 updates where CONFIG (and member 0) copy every 3, learns
# 10x faster, penalises actions outside the bounds and fits its mean to the clipped samples
# (`clip_mean_targets`), and its actors' noise is correlated in time
# where member 0's is independent (as a single run's at 0, though the population keeps a noise
# state and the penalty's dual for both), its envs scale their noise from 0.5 to 1 where
# member 0's act with the policy (as a single run's at 1, though its multipliers are computed),
# and it wraps reacher's shoulder angle where member 0 sees it raw (as a single run without the
# wrap, though its normaliser has a period of zeros).
OVERRIDES = ({"target_update_period": CONFIG.learner.target_update_period,
              "learning_rate": CONFIG.learner.learning_rate, "action_noise_correlation": 0.0,
              "noise_scale_min": 1.0, "action_penalty": False, "wrap_angles": False,
              "clip_mean_targets": False},
             {"target_update_period": 2, "learning_rate": 1e-3, "action_noise_correlation": 0.9,
              "noise_scale_min": 0.5, "action_penalty": True, "wrap_angles": True,
              "clip_mean_targets": True})
MEMBER_CONFIGS = (CONFIG, dataclasses.replace(
    CONFIG, seed=1, action_noise_correlation=0.9, noise_scale_min=0.5, wrap_angles=True,
    learner=dataclasses.replace(
        CONFIG.learner, target_update_period=2, learning_rate=1e-3,
        mpo=dataclasses.replace(CONFIG.learner.mpo, action_penalty=True,
                                clip_mean_targets=True))))


# Member 1's settings on the command line, and the directory name of a member with them.
GRID = ("--grid", "target_update_period=2", "--grid", "learning_rate=0.001",
        "--grid", "action_noise_correlation=0.9", "--grid", "action_penalty=1",
        "--grid", "noise_scale_min=0.5",
        "--grid", "wrap_angles=1", "--grid", "clip_mean_targets=1")
MEMBER_1_DIR = ("action_noise_correlation0.9_action_penalty1_clip_mean_targets1"
                "_learning_rate0.001_noise_scale_min0.5"
                "_target_update_period2_wrap_angles1")


@pytest.fixture(scope="module")
def population():
  trainer = Trainer(CONFIG, mesh_lib.make_mesh(), seeds=SEEDS, overrides=OVERRIDES)
  assert trainer.members == 2 and trainer.mesh.devices.size == 2
  assert [trainer.member_config(i) for i in range(2)] == list(MEMBER_CONFIGS)
  return trainer


def _members_of(trainer, state, i):
  """Member i's learner, normaliser and replay."""
  return trainer.member((state.learner, state.normalizer, state.replay), i)


def test_members_are_the_runs_their_seeds_and_settings_give_alone(population):
  pop_state, pop_metrics = run_iterations(population, population.init(population.keys()), 3)
  pop_returns = np.asarray(population.evaluate((pop_state.learner.policy,),
                                               (pop_state.normalizer,), population.keys(1)))[0]
  assert pop_returns.shape == (2, CONFIG.eval_envs)
  # The population's environments and replay are split over both devices.
  assert len(pop_state.env.obs.sharding.device_set) == 2
  assert len(pop_state.replay.data["observation"].sharding.device_set) == 2
  for i, (seed, config) in enumerate(zip(SEEDS, MEMBER_CONFIGS)):
    single = Trainer(config, mesh_lib.make_mesh())  # a single run with the member's settings
    key = jax.random.PRNGKey(seed)[None]
    state, metrics = run_iterations(single, single.init(key), 3)
    returns = np.asarray(single.evaluate((state.learner.policy,), (state.normalizer,),
                                         jax.random.PRNGKey(seed + 1)[None]))[0]
    ours = dict(jax.tree_util.tree_leaves_with_path(_members_of(population, pop_state, i)))
    theirs = dict(jax.tree_util.tree_leaves_with_path(_members_of(single, state, 0)))
    for path, b in theirs.items():
      np.testing.assert_allclose(np.asarray(ours[path]), np.asarray(b), rtol=2e-4, atol=2e-5,
                                 err_msg=f"seed {seed}{jax.tree_util.keystr(path)}")
    # What the member holds beyond its single run: member 0's penalty dual (and its optimiser's
    # moments), at their initial values since its flag is off, and its normaliser's period of
    # zeros (it wraps nothing).
    extra = {jax.tree_util.keystr(p): np.asarray(v) for p, v in ours.items() if p not in theirs}
    assert i == 1 or (extra and all("log_penalty_temperature" in p or ".period" in p
                                    for p in extra)
                      and any(".period" in p for p in extra)), extra
    for p, v in extra.items():
      expected = CONFIG.learner.mpo.init_log_temperature if ".duals." in p else 0.0
      np.testing.assert_array_equal(v, expected, err_msg=p)
    if i == 1:  # member 1 wraps the shoulder (reacher's position[0]) as its single run does
      period = np.asarray(ours[next(p for p in ours if ".period" in jax.tree_util.keystr(p))])
      np.testing.assert_array_equal(period, single.env.observation_period())
      assert period[0] == np.float32(2 * np.pi) and not period[1:].any()
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


def _exchanged(compiled) -> dict[str, int]:
  """{collective: largest number of elements one op of it moves} in a compiled program's HLO."""
  largest = {}
  for line in compiled.as_text().splitlines():
    m = re.search(r"= (.+?) (all-reduce|all-gather|all-to-all|collective-permute|"
                  r"reduce-scatter)(?:-start)?\(", line)
    if m:
      sizes = [math.prod(int(d) for d in dims.split(",") if d)
               for dims in re.findall(r"\[([\d,]*)\]", m.group(1))]
      largest[m.group(2)] = max(largest.get(m.group(2), 0), sum(sizes))
  return largest


@pytest.mark.slow
def test_whole_members_per_device_compute_the_same_and_exchange_no_gradients(population):
  """Two members on two devices lie one per device by default ("members"): each member's
  learner, normaliser and replay sit on one device, its updates exchange nothing with the other
  device (only the predicates of the batch's loops and restart branch and the [P] metrics
  cross, where the other layout averages gradients; nothing but the metrics where each device
  steps its own environments), and the iterations compute what the layout that splits each
  member's environments over both devices computes."""
  assert population.layout == "members"
  split = Trainer(CONFIG, mesh_lib.make_mesh(), seeds=SEEDS, overrides=OVERRIDES,
                  layout="environments")
  ours = _exchanged(population.iteration.lower(population.abstract_state).compile())
  theirs = _exchanged(split.iteration.lower(split.abstract_state).compile())
  assert max(ours.values()) <= population.members, ours
  apart = Trainer(CONFIG, mesh_lib.make_mesh(), seeds=SEEDS, overrides=OVERRIDES,
                  per_device_env_steps=True)
  # (never run: compiled without XLA's backend optimisation, CI time; mjx_form.cpu)
  alone = _exchanged(apart.iteration.lower(apart.abstract_state).compile(
      cpu.run_once_compiler_options()))
  assert set(alone) == {"all-gather"} and alone["all-gather"] <= apart.members, alone
  assert max(theirs.values()) > 1000, theirs  # the critic's gradients, for one
  a, _ = run_iterations(population, population.init(population.keys()), 3)
  b, _ = run_iterations(split, split.init(split.keys()), 3)
  weights = jax.tree.leaves(a.learner.policy)[0]
  held = sorted((shard.index[0].start, shard.device.id) for shard in weights.addressable_shards)
  assert held == [(0, 0), (1, 1)] and all(shard.data.shape[0] == 1
                                          for shard in weights.addressable_shards)
  for (path, x), y in zip(jax.tree_util.tree_leaves_with_path(
      (a.learner, a.normalizer, a.replay, a.episode_return)),
      jax.tree.leaves((b.learner, b.normalizer, b.replay, b.episode_return))):
    np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=2e-4, atol=2e-5,
                               err_msg=jax.tree_util.keystr(path))


def test_layouts_are_checked():
  three = Trainer(CONFIG, mesh_lib.make_mesh(), seeds=(0, 1, 2))
  assert three.layout == "environments"  # 3 members do not split over 2 devices
  with pytest.raises(ValueError, match=r"'members' needs the members \(3\) to be a multiple"):
    Trainer(CONFIG, mesh_lib.make_mesh(), seeds=(0, 1, 2), layout="members")
  with pytest.raises(ValueError, match="unknown layout 'rows'; valid layouts: environments, "
                                       "members"):
    Trainer(CONFIG, mesh_lib.make_mesh(), seeds=(0, 1), layout="rows")
  assert Trainer(CONFIG, mesh_lib.make_mesh()).layout == "environments"  # a single run


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
  # Both seeds with member 1's settings, all six (the fixture's programs: the members' values
  # are data, so other values of the same settings compile nothing new; CI time).
  grid = GRID
  args = _cli_args(run_dir, "--seeds", "0,1", *grid, "--env_steps", "80",
                   "--results", str(curve), "--eval_every", "1")  # a curve row per iteration
  assert cli.train_config(cli.parse_args(args)) == CONFIG
  assert cli.main(args) == 0
  out = capsys.readouterr().out
  names = [f"seed{s}_{MEMBER_1_DIR}" for s in SEEDS]
  own = ("action_noise_correlation 0.9, action_penalty 1, clip_mean_targets 1, "
         "learning_rate 0.001, "
         "noise_scale_min 0.5, target_update_period 2, wrap_angles 1")
  assert f"a population of 2 (seed 0, {own}; seed 1, {own})" in out
  assert "2 cpu device(s) (whole members per device)" in out
  assert f"seed 1, {own}: iter 1/2" in out
  # (the best policy is evaluated afresh, or is the final one's arrays and says so)
  assert re.search(rf"seed 1, {re.escape(own)}: (fresh evaluation of the best policy over|the "
                   r"best policy holds the final policy's arrays)", out)
  stored = json.load(open(run_dir / "config.json"))
  assert stored["seeds"] == [0, 1] and stored["overrides"] == [
      {"action_noise_correlation": 0.9, "action_penalty": True, "clip_mean_targets": True,
       "learning_rate": 1e-3,
       "noise_scale_min": 0.5, "target_update_period": 2, "wrap_angles": True}] * 2
  assert checkpoint.latest_step(str(run_dir / "checkpoints")) == 2  # one for all members
  records = results.read_records(str(curve))
  for seed, name in zip(SEEDS, names):
    member = run_dir / name
    with open(member / "progress.csv") as f:
      assert [int(r["iteration"]) for r in csv.DictReader(f)] == [1, 2]
    _, meta = policy_io.load_policy(member / "policy.npz", task="reacher_easy")
    assert meta["env_steps"] == 80 and meta["train_config"]["seed"] == seed
    assert meta["train_config"]["learner"]["target_update_period"] == 2
    assert meta["train_config"]["action_noise_correlation"] == 0.9
    assert meta["train_config"]["learner"]["mpo"]["action_penalty"] is True
    assert meta["train_config"]["wrap_angles"] is True
    assert policy_io.load_policy(member / "best_policy.npz")[1]["train_config"]["seed"] == seed
    mine = [r for r in records if r["seed"] == seed]
    assert [r["kind"] for r in mine] == ["learning_curve"] * 2 + ["final_return"] * 3
    assert [r["iteration"] for r in mine[:2]] == [1, 2]
    assert all(r["population"] == 2 and r["settings"]["seed"] == seed
               and r["settings"]["learner"]["learning_rate"] == 1e-3
               and r["settings"]["action_noise_correlation"] == 0.9
               and r["learner_preset"] == "custom" for r in mine)
  # Each member's second curve row names its first row's settings instead of repeating them
  # (mjx_form/files/results.py; read_records above gave them back whole).
  raw = [json.loads(line) for line in open(curve)]
  assert [("settings" in r, r.get(results.REFERENCE)) for r in raw[:4]] == [
      (True, None), (True, None), (False, results.shared_digest(records[0])),
      (False, results.shared_digest(records[1]))]
  # The members' policies are their own.
  policies = [policy_io.load_policy(run_dir / n / "policy.npz")[1]["sha256"] for n in names]
  assert len(set(policies)) == 2
  # Another set of seeds, or other values, does not resume this population.
  assert cli.main(_cli_args(run_dir, "--seeds", "0,2", *grid, "--env_steps", "120",
                            "--resume")) == 2
  assert "seeds" in capsys.readouterr().err
  assert cli.main(_cli_args(run_dir, "--seeds", "0,1", "--grid", "target_update_period=4",
                            "--grid", "learning_rate=0.001", "--env_steps", "120",
                            "--resume")) == 2
  assert "overrides" in capsys.readouterr().err
  # Settings that must be shared are refused as grid entries, naming what may vary.
  with pytest.raises(SystemExit):
    cli.parse_args(_cli_args(run_dir, "--grid", "num_envs=4,8"))
  assert "target_update_period" in capsys.readouterr().err


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


@pytest.mark.slow
def test_evaluate_run_scores_a_stopped_population_afterwards(tmp_path, capsys):
  """scripts/evaluate_run.py: a population stopped by its time budget without fresh
  evaluations gets them afterwards, each member's records placed in its own run."""
  cli, evaluate_run = load_script("run"), load_script("evaluate_run")
  run_dir, curve = tmp_path / "pop", tmp_path / "curve.jsonl"
  grid = GRID  # the CLI test's programs (the population fixture's)
  assert cli.main(_cli_args(run_dir, "--seeds", "0,1", *grid, "--env_steps", "80",
                            "--max_seconds", "0.001", "--final_eval_envs", "0",
                            "--results", str(curve))) == 0  # stops after iteration 1
  capsys.readouterr()
  trained = results.read_records(str(curve))
  assert [r["kind"] for r in trained] == ["learning_curve"] * 2
  # A curve file without seed 1's records is refused before anything is written.
  partial = tmp_path / "partial.jsonl"
  partial.write_text(json.dumps(trained[0]) + "\n")
  assert evaluate_run.main(["--run_dir", str(run_dir), "--curve", str(partial),
                            "--episodes", "2", "--chunk", "2"]) == 2
  assert "no learning-curve records" in capsys.readouterr().err
  assert partial.read_text() == json.dumps(trained[0]) + "\n"
  truncated = tmp_path / "truncated.jsonl"
  truncated.write_text(json.dumps(trained[0])[:50] + "\n")
  assert evaluate_run.main(["--run_dir", str(run_dir), "--curve", str(truncated)]) == 2
  assert "line 1 is not JSON" in capsys.readouterr().err
  truncated.write_text("[1]\n")
  assert evaluate_run.main(["--run_dir", str(run_dir), "--curve", str(truncated)]) == 2
  assert "line 1 is not a result record" in capsys.readouterr().err

  assert evaluate_run.main(["--run_dir", str(run_dir), "--curve", str(curve),
                            "--episodes", "2", "--chunk", "2"]) == 0
  finals = results.read_records(str(curve))[2:]
  assert [(r["kind"], r["seed"], r["policy"]) for r in finals] == [
      ("final_return", s, p) for s in SEEDS for p in ("final", "final_sampled", "best")]
  for r in finals:
    own = next(t for t in trained if t["seed"] == r["seed"])
    assert r["settings"] == own["settings"] and r["device"] == own["device"]
    assert (r["env_steps"], r["policy_env_steps"], r["finished"], r["episodes"]) == (
        40, 40, False, 2)
    assert r["population"] == 2 and r["method"] == "expert" and np.isfinite(r["final_return"])
    member = run_dir / f"seed{r['seed']}_{MEMBER_1_DIR}"
    name = "best_policy.npz" if r["policy"] == "best" else "policy.npz"
    assert r["policy_sha256"] == policy_io.load_policy(member / name)[1]["sha256"]
  # --policies picks some (each record placed where the run ended all the same)
  assert evaluate_run.main(["--run_dir", str(run_dir), "--curve", str(curve), "--episodes", "2",
                            "--chunk", "2", "--policies", "final_sampled"]) == 0
  again = results.read_records(str(curve))[2 + len(finals):]
  assert [(r["seed"], r["policy"], r["env_steps"]) for r in again] == [
      (s, "final_sampled", 40) for s in SEEDS]
  assert [r["final_return"] for r in again] == [
      r["final_return"] for r in finals if r["policy"] == "final_sampled"]  # (same starts)
  # A run with no learning-curve record at its end (stopped by --max_seconds, evaluating on
  # the host) is placed by its own fresh evaluation's record of the same file.
  ended = tmp_path / "ended.jsonl"
  ended.write_text("".join(json.dumps(r) + "\n" for r in finals if r["policy"] == "final"))
  assert evaluate_run.main(["--run_dir", str(run_dir), "--curve", str(ended), "--episodes", "2",
                            "--chunk", "2", "--policies", "final_sampled"]) == 0
  placed = results.read_records(str(ended))[len(SEEDS):]
  assert [(r["seed"], r["policy"], r["env_steps"], r["settings"]) for r in placed] == [
      (r["seed"], "final_sampled", 40, r["settings"]) for r in finals if r["policy"] == "final"]
  ended.write_text("".join(json.dumps({**r, "policy_sha256": "0" * 64}) + "\n"
                           for r in finals if r["policy"] == "final"))  # (another file's)
  assert evaluate_run.main(["--run_dir", str(run_dir), "--curve", str(ended)]) == 2
  assert "no learning-curve records" in capsys.readouterr().err
  with pytest.raises(SystemExit) as e:
    evaluate_run.main(["--run_dir", str(run_dir), "--policies", "final,bogus"])
  assert e.value.code == 2 and "--policies: expected some of" in capsys.readouterr().err


def test_final_evaluation_of_members_that_differ_in_the_wrap(population, tmp_path, monkeypatch):
  """The fresh evaluation of the best policies stacks the members' files: member 0's has no
  period (it does not wrap), member 1's has one. A best policy whose files hold every member's
  arrays of a policy evaluated before (the final one, or an earlier best) is not evaluated
  again; one member's other arrays make it run."""
  from mjx_form.rl import runner
  state = population.init(population.keys())
  paths = [str(tmp_path / f"best{i}.npz") for i in range(2)]
  for i, path in enumerate(paths):
    runner.export_policy(population, state, i, path, {"env_steps": 0})
  rows = [{"env_steps": 0, "wall_s": 0.0} for _ in paths]
  runs, evaluate = [], population.evaluate  # (each call: how many policies it evaluates)
  monkeypatch.setattr(population, "evaluate",
                      lambda *a, **k: runs.append(len(a[0])) or evaluate(*a, **k))
  lines = []  # (a kind of best policy that a member lacks is left out, and the run says so)
  runner._final_evaluation(population, state,
                           {"best": paths, "best_log_pd": [paths[0], str(tmp_path / "none.npz")]},
                           rows, CONFIG.eval_envs, None, 0, ["seed 0", "seed 1"],
                           print_fn=lines.append)
  # (no final files given: the best policy is evaluated afresh, beside the final one, and the
  # final one with its actions sampled)
  assert runs == [3]
  for row in rows:  # the best policies are the state's own: the same returns as the final ones
    np.testing.assert_allclose(row["best_policy_return"], row["final_policy_return"], rtol=1e-5)
    assert "final_sampled_policy_return" in row
    assert "best_log_pd_policy_return" not in row
  assert ("no none.npz for seed 1: the best policy by log pD is not evaluated afresh"
          in lines), lines
  arrays, meta = policy_io.load_policy(paths[1])  # member 1's policy, changed
  arrays["policy"] = jax.tree.map(lambda x: x + 0.01, arrays["policy"])
  other = str(tmp_path / "other.npz")
  policy_io.save_policy(other, arrays, {k: v for k, v in meta.items()
                                        if k not in ("sha256", "format", "version")})
  sha = lambda path: policy_io.load_policy(path)[1]["sha256"]
  # The final files as the best policy and a best by log pD that differs in member 1: two
  # evaluations. That one as both: two as well, the best by log pD repeating the best's.
  for bests, same in (({"best": paths, "best_log_pd": [paths[0], other]}, ("final", None)),
                      ({"best": [paths[0], other], "best_log_pd": [paths[0], other]},
                       (None, "best"))):
    runs.clear()
    lines.clear()
    finals = tmp_path / f"finals_{same[0]}.jsonl"
    runner._final_evaluation(population, state, bests, rows, CONFIG.eval_envs,
                             results.ResultWriter(str(finals)), 0, ["seed 0", "seed 1"],
                             print_fn=lines.append, final_paths=paths)
    assert runs == [3], bests  # (in one call, the final policy's actions sampled too)
    records = results.read_records(str(finals))
    assert [(r["policy"], r.get("same_policy_as")) for r in records] == [
        ("final", None), ("final", None), ("final_sampled", None), ("final_sampled", None),
        ("best", same[0]), ("best", same[0]), ("best_log_pd", same[1]),
        ("best_log_pd", same[1])], bests
    assert [r["policy_sha256"] for r in records] == [
        sha(p) for p in paths + paths + bests["best"] + bests["best_log_pd"]]
    reused = [r for r in records if "same_policy_as" in r]
    for r in reused:  # (its numbers are those of the policy it repeats, member by member)
      twin = next(t for t in records if t["policy"] == r["same_policy_as"]
                  and t["seed"] == r["seed"])
      assert (r["final_return"], r["final_return_std"]) == (twin["final_return"],
                                                            twin["final_return_std"])
    assert len([line for line in lines if "not evaluated again" in line]) == len(reused) == 2
  assert lines[-1].startswith("seed 1: the best policy by log pD holds the best policy's "
                              f"arrays: {rows[1]['best_policy_return']:.1f} +- "), lines
  np.testing.assert_allclose(rows[0]["best_log_pd_policy_return"],
                             rows[0]["final_policy_return"], rtol=1e-5)
