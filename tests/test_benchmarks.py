"""The benchmark scripts' own logic (their timings are taken on the GPU, never in tests)."""

import argparse
import collections
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import load_script

from mjx_form.rl.train import TrainConfig, Trainer


@pytest.mark.slow
def test_train_throughput_env_only_runs_over_the_loops_devices():
  """The env-only rollout it compares the loop with is split over the same mesh (2 forced host
  devices here): its environments end where they started, on both devices."""
  assert jax.device_count() == 2  # tests/conftest.py forces two host devices
  bench = load_script("train_throughput", folder="benchmarks")
  trainer = Trainer(TrainConfig(task="reacher_easy", num_envs=4, unroll_length=5))
  run, start = bench.env_only_fn(trainer, 3, jax.random.PRNGKey(0))
  assert start.obs.sharding.device_set == set(jax.devices())
  first = np.asarray(start.obs)
  key = jax.random.PRNGKey(1)
  exe = run.lower(start, key).compile()  # compiled once and timed, as benchmarks/common.py does
  end = exe(start, key)  # the start is donated
  assert end.obs.shape == first.shape and end.obs.sharding.device_set == set(jax.devices())
  assert end.obs.sharding.spec == trainer._batch.spec
  assert not np.allclose(np.asarray(end.obs), first)  # it stepped
  # Each timed call is fed the previous output: every leaf (zero-size ones too) must come back
  # with the sharding the executable was compiled for.
  exe(end, key).obs.block_until_ready()


def test_train_throughput_refuses_a_population_that_does_not_split_over_the_devices(tmp_path,
                                                                                  capsys):
  """--layout members with 3 (or 1) members on the 2 devices: exit 2 naming the sizes, before
  any compile (even of the sizes that split), nothing written."""
  bench = load_script("train_throughput", folder="benchmarks")
  out = tmp_path / "out.jsonl"
  assert bench.main(["--tasks", "reacher_easy", "--num_envs", "4", "--members", "2", "3", "1",
                     "--layout", "members", "--out", str(out)]) == 2
  assert "populations of [3, 1] do not split over the 2 devices" in capsys.readouterr().err
  assert not out.exists()


def test_train_throughput_measures_the_learner_settings_it_is_given():
  """--sampled_q_bfloat16 reaches the measured learner (and its records' settings); without
  it the learner is the default one."""
  bench = load_script("train_throughput", folder="benchmarks")
  plain = bench.train_config(bench.parse_args(["--num_envs", "8"]), "cheetah_run", 8)
  assert plain == TrainConfig(task="cheetah_run", num_envs=8)
  bf16 = bench.train_config(bench.parse_args(["--sampled_q_bfloat16"]), "cheetah_run", 8)
  assert bf16.learner.sampled_q_bfloat16 and bf16.to_dict()["learner"]["sampled_q_bfloat16"]


@pytest.mark.slow
def test_scaling_measures_weak_scaling_and_builds_populations_over_the_devices(tmp_path, capsys):
  """benchmarks/scaling.py on the 2 forced host devices, tiny sizes: weak scaling measured (one
  record, amounts per device scaled, each phase printed as it ends); the population it would
  measure (the same `measure`) has its members per device, each member's envs on both. The
  sizes are test_train's CONFIG on two devices, whose programs the persistent cache holds."""
  from test_train import CONFIG
  bench = load_script("scaling", folder="benchmarks")
  out = tmp_path / "scaling.jsonl"
  sizes = ["--envs_per_device", "2", "--members_per_device", "2", "--envs_per_member", "2",
           "--unroll_length", "10", "--batch_size", "2", "--replay_capacity", "6",
           "--updates_per_iteration", "2", "--network_width", "32", "--num_action_samples", "4",
           "--target_update_period", "3"]
  args = argparse.Namespace(
      physics="fast", envs_per_device=2, members_per_device=2, envs_per_member=2,
      unroll_length=10, batch_size=2, replay_capacity=6, updates_per_iteration=2,
      network_width=32, num_action_samples=4, target_update_period=3, sampled_q_bfloat16=False,
      layout=None, per_device_env_steps=False)
  assert bench.trainer_for("weak", "reacher_easy", 2, args).config == CONFIG
  apart = argparse.Namespace(**{**vars(args), "per_device_env_steps": True})
  assert bench.trainer_for("weak", "reacher_easy", 2, apart).per_device_env_steps
  bf16 = argparse.Namespace(**{**vars(args), "sampled_q_bfloat16": True})
  assert bench.trainer_for("weak", "reacher_easy", 2, bf16).config.learner.sampled_q_bfloat16
  assert bench.main(["--tasks", "reacher_easy", "--devices", "2", "--modes", "weak", *sizes,
                     "--repeats", "1", "--per_device_env_steps", "--out", str(out)]) == 0
  printed = capsys.readouterr().out
  assert "reacher_easy weak on 2 device(s): env only, the batch stepped as one:" in printed
  assert "reacher_easy weak on 2 device(s), per device: env only" in printed
  assert "reacher_easy weak on 2 device(s), per device: iteration" in printed
  weak, = [json.loads(line) for line in open(out)]
  assert (weak["kind"], weak["mode"], weak["devices"], weak["members"]) == ("scaling", "weak", 2, 1)
  assert weak["total_envs"] == 4 and weak["settings"]["batch_size"] == 4
  assert weak["settings"]["replay_capacity"] == 12
  assert weak["sps"] > 0 and weak["env_sps"] > 0 and 0 < weak["iteration_s"] < 60
  assert weak["layout"] == "environments" and weak["env_whole_batch_sps"] > 0
  assert weak["per_device_env_steps"] is True
  # By default the batch is stepped as one, and the record says nothing of per-device stepping.
  assert bench.main(["--tasks", "reacher_easy", "--devices", "2", "--modes", "weak", *sizes,
                     "--repeats", "1", "--out", str(out)]) == 0
  assert "per device" not in capsys.readouterr().out
  default = json.loads(open(out).readlines()[-1])
  assert "per_device_env_steps" not in default and "env_whole_batch_sps" not in default
  population = bench.trainer_for("population", "reacher_easy", 2, args)
  assert population.members == 4 and population.config.num_envs == 2
  assert population.mesh.devices.size == 2 and population.config.batch_size == 2
  assert population.layout == "members"  # whole members per device, unless asked otherwise
  split = argparse.Namespace(**{**vars(args), "layout": "environments"})
  assert bench.trainer_for("population", "reacher_easy", 2, split).layout == "environments"
  assert bench.trainer_for("weak", "reacher_easy", 2, split).layout == "environments"
  one = bench.trainer_for("weak", "reacher_easy", 1, args)
  assert one.mesh.devices.size == 1 and one.config.num_envs == 2
  # A device count the host lacks is refused before anything runs.
  with pytest.raises(SystemExit):
    bench.main(["--tasks", "reacher_easy", "--devices", "3", "--out", str(out)])
  assert "has 2 device(s)" in capsys.readouterr().err


@pytest.mark.slow
def test_evaluation_speed_times_policies_evaluated_together(tmp_path, capsys):
  """benchmarks/evaluation_speed.py, tiny sizes: a record per number of policies, the time of
  one call and per policy; bad sizes refused."""
  bench = load_script("evaluation_speed", folder="benchmarks")
  out = tmp_path / "evaluation.jsonl"
  bench.main(["--tasks", "reacher_easy", "--members", "2", "--episodes", "2", "--policies",
              "1", "2", "--repeats", "1", "--out", str(out)])
  records = [json.loads(line) for line in open(out)]
  assert [(r["kind"], r["members"], r["episodes"], r["policies"]) for r in records] == [
      ("evaluation_speed", 2, 2, 1), ("evaluation_speed", 2, 2, 2)]
  for r in records:
    assert r["seconds"] > 0 and r["seconds_per_policy"] == pytest.approx(
        r["seconds"] / r["policies"])
  assert "2 member(s) x 2 policies x 2 episodes" in capsys.readouterr().out
  for bad in (["--policies", "0"], ["--tasks", "nope"]):
    with pytest.raises(SystemExit):
      bench.main(bad)


@pytest.mark.slow
def test_update_speed_times_forms_work_per_learner_update(tmp_path, capsys):
  """benchmarks/update_speed.py's FORM variants, tiny sizes: one record each, with the task's
  effect-model settings and the learner FORM runs with (sampled Q in bf16)."""
  from mjx_form.imitation import settings as form_settings
  bench = load_script("update_speed", folder="benchmarks")
  out = tmp_path / "speed.jsonl"
  assert bench.main(["--tasks", "reacher_easy", "--variants", *bench.FORM_VARIANTS,
                     "--updates", "2", "--batch_size", "3", "--unroll_length", "7",
                     "--repeats", "1", "--profile", "3", "--out", str(out)]) == 0
  records = [json.loads(line) for line in open(out)]
  timed = [r for r in records if r["variant"] in bench.FORM_VARIANTS]
  assert [r["variant"] for r in timed] == list(bench.FORM_VARIANTS)
  expected = form_settings.effect_model_config("reacher_easy").to_dict()
  for r in timed:
    assert r["kind"] == "update_speed" and r["update_ms"] > 0, r
    assert r["settings"]["effect_model"] == expected
    assert r["settings"]["learner"]["sampled_q_bfloat16"] is True
    assert (r["settings"]["batch_size"], r["settings"]["unroll_length"]) == (3, 7)
    assert r["settings"].get("source_update_every", 1) == bench.EVERY.get(r["variant"], 1)
    # --profile 3: the three costliest source lines of the variant's program, per update
    assert 1 <= len(r["profile"]) <= 3 and 0 < sum(p["share"] for p in r["profile"]) <= 1 + 1e-9
    assert all(p["us"] > 0 and p["where"] for p in r["profile"]), r["profile"]
  printed = capsys.readouterr().out
  assert all(f"reacher_easy    {v}" in printed for v in bench.FORM_VARIANTS), printed
  with pytest.raises(SystemExit):
    bench.main(["--profile", "-1"])


@pytest.mark.slow
def test_device_profile_names_the_source_line_that_costs_the_most(monkeypatch):
  """benchmarks/device_profile.py on the CPU: a scan whose flax layer dwarfs the rest is
  attributed to the line here that applies the layer (up the call stack from flax's own line),
  not to the loop that encloses it, each operation timed by its least time over three calls;
  older HLO texts name their lines in the metadata; an operation without metadata is named as
  such."""
  import flax.linen as nn
  device_profile = load_script("device_profile", folder="benchmarks")
  layer = nn.Dense(384)
  params = layer.init(jax.random.PRNGKey(0), jnp.ones((1, 384)))

  def program(x):
    def step(h, _):
      return jnp.tanh(layer.apply(params, h)), None  # the costly line
    return jax.lax.scan(step, x, None, length=8)[0].sum() + jnp.log1p(x[0, 0])

  x = jnp.ones((384, 384))
  exe = device_profile.compile_for_profile(jax.jit(program), (x,))  # (as update_speed.py)
  lines = device_profile.top_lines(exe, (x,), 3, calls=3)
  line = program.__code__.co_firstlineno + 2
  assert lines[0]["where"].startswith(f"test_benchmarks.py:{line} "), lines
  assert lines[0]["share"] > 0.5 and lines[0]["us"] > 0, lines
  assert not any(p["where"].endswith("/while") for p in lines), lines
  # each operation's least time over the calls that ran it: a stall in one call does not count
  traces = iter([{"a": 9.0, "b": 2.0}, {"a": 1.0}, {"a": 4.0, "b": 2.5, "c": 0.5}])
  monkeypatch.setattr(device_profile, "_traced_times", lambda *_: collections.Counter(next(traces)))
  assert device_profile.top_lines(exe, (x,), 2, calls=3) == [
      {"where": "(no source) b", "us": 2.0, "share": pytest.approx(2 / 3.5)},
      {"where": "(no source) a", "us": 1.0, "share": pytest.approx(1 / 3.5)}]
  with pytest.raises(ValueError, match="calls"):
    device_profile.top_lines(exe, (x,), 2, calls=0)
  old = ('  %fusion.3 = f32[4]{0} fusion(%p), kind=kLoop, calls=%c, metadata={op_name='
         '"jit(run)/while/body/EffectModel/head/dot_general" source_file="/x/y/linear.py" '
         'source_line=287}\n  %copy.6 = f32[4]{0} copy(%fusion.3)')
  assert device_profile.hlo_instructions(old) == {
      "fusion.3": ("fusion", "linear.py:287 EffectModel/head/dot_general"),
      "copy.6": ("copy", "(no source) copy.6")}


def test_reward_terms_multiply_to_dm_controls_reward(tmp_path, capsys):
  """benchmarks/reward_terms.py: at every step of a short rollout the factors it reads off the
  physics multiply to dm_control's own reward (hopper_stand's shipped expert; humanoid_stand's
  kept policy, whose dont_move factor is humanoid's; humanoid_walk's move factor under random
  actions); the summary is numpy's of the series; commands at a bound are counted as such; with
  `--action_scale 0` no control is paid and the commands counted stay the policy's; the
  per-actuator means are numpy's and average to the overall share; hopper's actuated joints are
  found by name and a joint 0.04 rad from a limit counts as at it, 0.06 rad not; a task
  without a control cost, or without a policy, is refused before any record."""
  bench = load_script("reward_terms", folder="benchmarks")
  import tasks
  from mjx_form.sim import parity
  hopper = parity.load_dm_control_env("hopper_stand", 0).physics
  names, address, ranges = bench.actuated_joints(hopper)
  assert names == ["waist", "hip", "knee", "ankle"]  # hopper.xml's motors, in order
  qpos = hopper.data.qpos[address].copy()
  qpos[2] = ranges[2, 0] + 0.04  # the knee 0.04 rad inside the low end of its range
  qpos[3] = ranges[3, 1] - 0.06  # the ankle 0.06 rad inside the high end
  limit = bench.at_joint_limit(qpos, ranges)
  assert limit[2] and not limit[3]
  assert not bench.at_joint_limit(np.zeros(1), np.array([[-np.inf, np.inf]]))[0]
  root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  kept = os.path.join(root, "benchmarks", "policies", "humanoid_stand_hsh_seed1_12m.npz")
  for task, path in (("hopper_stand", tasks.bundled_expert("hopper_stand")),
                     ("humanoid_stand", kept)):
    expert, env = bench.common.load_expert(task, path)
    series = bench.rollout(task, expert, env.observation_layout, env.action_size, episodes=2,
                           seed=3, steps=25)
    factors = [name for name in series if name not in bench.PER_STEP + bench.PER_ACTUATOR]
    assert factors == (["standing", "small_control"] if task == "hopper_stand" else
                       ["standing", "upright", "small_control", "dont_move"])
    product = np.prod([series[name] for name in factors], axis=0)  # [steps, episodes]
    np.testing.assert_allclose(product, series["reward"], rtol=1e-9, atol=1e-12)
    assert series["reward"].shape == (25, 2) and series["reward"].max() > 0
    assert np.all((series["small_control"] >= 0.8) & (series["small_control"] <= 1.0))
    result = bench.summary(series, late_from=20)
    assert result["return"] == pytest.approx(series["reward"].sum(axis=0).mean())
    assert result["late"]["reward_mean"] == pytest.approx(series["reward"][20:].mean())
    assert result["late"]["terms"]["small_control"] == pytest.approx(
        series["small_control"][20:].mean())
    assert bench.summary(series, late_from=25)["late"] is None
    assert result["return_without_control_cost"] == pytest.approx(
        (series["reward"] / series["small_control"]).sum(axis=0).mean())
    assert 0.0 <= result["at_bound_share"] <= 1.0
    names = bench.actuated_joints(parity.load_dm_control_env(task, 0).physics)[0]
    assert len(names) == env.action_size and series["actions"].shape == (25, 2, len(names))
    each = bench.summary(series, late_from=20, names=names)["late"]["actuators"]
    assert list(each) == names
    first = each[names[0]]
    assert first["mean"] == pytest.approx(series["actions"][20:, :, 0].mean())
    assert first["at_bound"] == pytest.approx(
        np.mean(np.abs(series["actions"][20:, :, 0]) >= 1.0))  # bounds [-1, 1] here
    assert np.mean([a["at_bound"] for a in each.values()]) == pytest.approx(
        result["late"]["at_bound_share"])
    if task == "humanoid_stand":  # no torque: no control cost; the commands stay the policy's
      still = bench.rollout(task, expert, env.observation_layout, env.action_size, episodes=2,
                            seed=3, steps=25, action_scale=0.0)
      np.testing.assert_array_equal(still["small_control"], 1.0)
      assert still["at_bound"][0].tolist() == series["at_bound"][0].tolist()
      assert series["at_bound"].max() > 0 and series["small_control"].min() < 1.0
  walk = parity.load_dm_control_env("humanoid_walk", 0)
  walk.reset()
  rng = np.random.default_rng(0)
  for _ in range(20):
    ts = walk.step(rng.uniform(-1, 1, walk.action_spec().shape))
    terms = bench.reward_terms("humanoid_walk", walk)
    assert set(terms) == {"standing", "upright", "small_control", "move"}
    assert np.prod(list(terms.values())) == pytest.approx(ts.reward, rel=1e-9, abs=1e-12)
  low, high = -np.ones(4), np.array([1.0, 1.0, 0.8, 1.1])
  assert bench.commands(np.array([-1.0, 0.5, 0.8, 1.0]), low, high) == {
      "at_bound": 0.5, "abs_control": pytest.approx(0.825)}  # -1 and 0.8 (not 1.0 of 1.1)
  out = tmp_path / "terms.jsonl"
  assert bench.main(["--tasks", "hopper_stand", "--episodes", "1", "--steps", "5",
                     "--out", str(out)]) == 0
  record, = [json.loads(line) for line in open(out)]
  assert record["kind"] == "reward_terms" and set(record["terms"]) == {"standing",
                                                                        "small_control"}
  assert record["action_scale"] == 1.0
  scaled = tmp_path / "scaled.jsonl"
  assert bench.main(["--tasks", "hopper_stand", "--episodes", "1", "--steps", "5",
                     "--action_scale", "1", "0", "--out", str(scaled)]) == 0
  full, none = [json.loads(line) for line in open(scaled)]
  assert (full["action_scale"], none["action_scale"]) == (1.0, 0.0)
  assert full["return"] == pytest.approx(record["return"])
  assert none["terms"]["small_control"] == 1.0 > full["terms"]["small_control"]
  with pytest.raises(SystemExit):
    bench.main(["--tasks", "hopper_stand", "--action_scale", "1.5", "--out", str(out)])
  assert "--action_scale [1.5]: each factor must lie in [0, 1]" in capsys.readouterr().err
  with pytest.raises(SystemExit):
    bench.main(["--tasks", "walker_walk", "--out", str(out)])
  assert "walker_walk: no control cost" in capsys.readouterr().err
  assert bench.main(["--tasks", "hopper_stand", "humanoid_run", "--out", str(out)]) == 2
  assert "no shipped expert for 'humanoid_run'" in capsys.readouterr().err
  assert len(open(out).readlines()) == 1  # (hopper_stand's record not written either)


def test_dm_control_transfer_runs_the_expert_in_dm_control(tmp_path):
  """benchmarks/dm_control_transfer.py, 2 short episodes of reacher_easy: a record with the
  dm_control return (reacher's reward is in [0, 1] per step); observations flattened in
  dm_control's own order; a task whose declared layout differs from dm_control's is refused."""
  bench = load_script("dm_control_transfer", folder="benchmarks")
  out = tmp_path / "transfer.jsonl"
  args = ["--tasks", "reacher_easy", "--episodes", "2", "--steps", "20", "--out", str(out)]
  assert bench.main(args) == 0
  record, = [json.loads(line) for line in open(out)]
  assert record["kind"] == "expert_transfer" and record["episodes"] == 2
  assert 0 <= record["dm_control_return"] <= 20 and "mjx_return" not in record  # short: no MJX
  assert record["physics"] == "fast"  # the shipped expert's
  # MJX's side runs in the physics the policy was trained in (its metadata's).
  import tasks
  from mjx_form.files import policy_io
  params, meta = policy_io.load_policy(tasks.bundled_expert("reacher_easy"))
  trained = tmp_path / "parity_policy.npz"
  policy_io.save_policy(trained, params, {k: v for k, v in meta.items()
                                         if k not in ("sha256", "format", "version")}
                        | {"physics": "parity"})
  assert bench.main([*args, "--policy", str(trained)]) == 0
  assert json.loads(open(out).readlines()[-1])["physics"] == "parity"
  from mjx_form.sim import parity
  env = parity.load_dm_control_env("reacher_easy", 0)
  ts = env.reset()
  np.testing.assert_array_equal(
      bench.flat_observations([ts, ts])[1],
      parity.flat_observation(ts.observation).astype(np.float32))
  from mjx_form.files import experts
  task = tasks.make("reacher_easy")
  expert = experts.load_expert(tasks.bundled_expert("reacher_easy"), task)
  swapped = dict(reversed(list(task.observation_layout.items())))
  with pytest.raises(bench.LayoutError, match="dm_control observes"):
    bench.dm_control_returns("reacher_easy", expert, swapped, task.action_size, 1, 0, 1)


@pytest.mark.slow
@pytest.mark.xdist_group("reacher")
def test_same_starts_replays_one_start_in_dm_control_and_mjx(tmp_path):
  """benchmarks/same_starts.py, 3 reacher_easy episodes of 100 steps: dm_control put at each MJX start
  (its target included) scores what MJX with dm_control's solver settings scores, step for step
  (reacher's reward is 0 or 1 per step); failures are counted per simulator; a start range that
  no draw falls in is refused."""
  bench = load_script("same_starts", folder="benchmarks")
  out = tmp_path / "same.jsonl"
  assert bench.main(["--tasks", "reacher_easy", "--episodes", "3", "--steps", "100",
                     "--fail_below", "1", "--out", str(out)]) == 0
  record, = [json.loads(line) for line in open(out)]
  returns = {k: np.array(v) for k, v in record["returns"].items()}
  assert set(returns) == {"dm_control", "mjx_fast", "mjx_parity"}
  assert returns["dm_control"].min() > 5  # the expert reaches the target: a real comparison
  np.testing.assert_allclose(returns["dm_control"], returns["mjx_parity"], atol=1.0)
  assert record["failed"] == {k: int((v < 1).sum()) for k, v in returns.items()}
  counts = bench.failures({"a": np.array([0., 9., 0., 9.]), "b": np.array([0., 0., 9., 9.])}, 1)
  assert counts == {"failed": {"a": 2, "b": 2}, "failed_in_all": 1, "failed_in_a_only": 1,
                    "failed_not_in_a": 1}
  import tasks
  with pytest.raises(ValueError, match="only 0 of"):
    bench.draw_starts(tasks.make("reacher_easy"), jax.random.PRNGKey(0), 2, 0, 5.0, 6.0)


def test_expert_eval_summarises_returns_and_refuses_another_tasks_policy(tmp_path, capsys):
  """benchmarks/expert_eval.py: mean, sd and standard error as numpy computes them, the bar at
  0.95x the paper's expert; a policy of another task is refused by name, with nothing written."""
  bench = load_script("expert_eval", folder="benchmarks")
  returns = np.array([900.0, 950.0, 980.0, 10.0])
  numbers = bench.summary(returns, "reacher_easy")
  assert numbers["mean_return"] == pytest.approx(710.0)
  assert numbers["std_return"] == pytest.approx(np.std(returns))
  assert numbers["stderr_return"] == pytest.approx(np.std(returns, ddof=1) / 2.0)
  assert numbers["min_return"] == 10.0 and numbers["episodes"] == 4
  assert numbers["paper_expert_return"] == 974.6 and numbers["reaches_bar"] is False
  assert bench.summary(np.array([926.0]), "reacher_easy")["reaches_bar"] is True  # 925.87
  assert bench.summary(np.array([925.8]), "reacher_easy")["reaches_bar"] is False
  out = tmp_path / "eval.jsonl"
  import tasks
  args = ["--tasks", "reacher_hard", "--policy", tasks.bundled_expert("cheetah_run"),
          "--episodes", "2", "--out", str(out)]
  assert bench.main(args) == 2
  assert "cheetah_run" in capsys.readouterr().err and not out.exists()
  # --by_start: an unknown observation dimension is refused by name before any rollout.
  args = ["--tasks", "reacher_easy", "--episodes", "2", "--by_start", "position[9]",
          "--out", str(out)]
  assert bench.main(args) == 2
  assert "position[9]" in capsys.readouterr().err and not out.exists()


def test_expert_eval_splits_returns_by_the_start():
  """--by_start's split against a direct numpy computation: equal-width bins between the
  values' min and max, the max in the last bin, an empty bin's mean None; names resolve as the
  layout orders them."""
  bench = load_script("expert_eval", folder="benchmarks")
  layout = {"position": 6, "height": 1, "velocity": 7}
  assert bench.start_dimension(layout, "position[1]") == 1
  assert bench.start_dimension(layout, "height") == 6
  assert bench.start_dimension(layout, "velocity[0]") == 7
  with pytest.raises(ValueError, match="height"):
    bench.start_dimension(layout, "height[0]")
  rng = np.random.default_rng(0)
  values = rng.uniform(-np.pi, np.pi, 200)
  returns = np.where(np.abs(values) < 1.0, 900.0, 50.0) + rng.normal(0, 5, 200)
  split = bench.returns_by_start(values, returns, 4)
  edges = np.linspace(values.min(), values.max(), 5)
  np.testing.assert_allclose(split["edges"], edges)
  for i in range(4):
    inside = (values >= edges[i]) & ((values < edges[i + 1]) if i < 3 else True)
    assert split["episodes"][i] == inside.sum()
    assert split["mean_return"][i] == pytest.approx(returns[inside].mean())
  assert sum(split["episodes"]) == 200
  gap = bench.returns_by_start(np.array([0.0, 0.1, 3.9, 4.0]), np.arange(4.0), 4,
                               other=np.array([1.0, 2.0, 3.0, 5.0]))
  assert gap["episodes"] == [2, 0, 0, 2] and gap["mean_return"] == [0.5, None, None, 2.5]
  assert gap["other"] == [1.5, None, None, 4.0]


def test_expert_eval_splits_returns_by_turns_past_pi(tmp_path, capsys):
  """--by_turn: an episode turned if a periodic dimension leaves [-pi, pi) at any step (pi
  itself is outside, -pi inside; other dimensions never count); a task without unbounded
  angles is refused before any rollout."""
  bench = load_script("expert_eval", folder="benchmarks")
  period = np.array([2 * np.pi, 0.0], np.float32)
  obs = np.zeros((5, 3, 2), np.float32)  # [K, T, D]
  obs[0, 1, 0] = 3.2          # past pi: turned
  obs[1, 2, 0] = -np.pi       # -pi is inside: stayed
  obs[2, 0, 0] = np.pi        # pi is outside: turned
  obs[3, :, 1] = 100.0        # a non-periodic dimension: stayed
  obs[4, :, 0] = [-1.0, -7.5, -4.0]  # turned, largest |angle| 7.5
  returns = np.array([10.0, 20.0, 0.0, 40.0, 30.0])
  split = bench.returns_by_turn(obs, period, returns)
  turned = np.array([True, False, True, False, True])
  assert split["turned"] == {"episodes": 3, "mean_return": pytest.approx(returns[turned].mean()),
                             "rewarded": pytest.approx(2 / 3)}
  assert split["stayed"] == {"episodes": 2, "mean_return": 30.0, "rewarded": 1.0}
  assert split["turned_median_max_angle"] == pytest.approx(3.2)  # median of 3.2, pi, 7.5
  none = bench.returns_by_turn(obs[[1, 3]], period, returns[[1, 3]])
  assert none["turned"] == {"episodes": 0, "mean_return": None, "rewarded": None}
  assert none["turned_median_max_angle"] is None
  out = tmp_path / "turn.jsonl"
  assert bench.main(["--tasks", "reacher_easy", "walker_stand", "--episodes", "2", "--by_turn",
                     "--out", str(out)]) == 2  # refused before reacher_easy's record
  assert "walker_stand observe(s) no unbounded angle" in capsys.readouterr().err
  assert not out.exists()


def test_form_reward_landscape_splits_log_pd_by_the_next_observations_turn():
  """log_pd_by_turn: a transition counts as turned when its next observation has a periodic
  dimension outside [-pi, pi) (pi outside, -pi inside; the first observation and other
  dimensions never count), against a direct computation."""
  bench = load_script("form_reward_landscape", folder="benchmarks")
  period = np.array([0.0, 2 * np.pi], np.float32)
  obs = np.zeros((2, 4, 2), np.float32)  # [K, T+1, D]
  obs[0, 0, 1] = 5.0      # the first observation: no transition ends there
  obs[0, 2, 1] = np.pi    # transition (0, 1) turned
  obs[1, 3, 1] = -np.pi   # inside
  obs[1, 1, 0] = 50.0     # not periodic
  obs[1, 2, 1] = -3.5     # transition (1, 1) turned
  log_d = np.arange(6.0).reshape(2, 3)
  split = bench.log_pd_by_turn(obs, period, log_d)
  turned = np.array([[False, True, False], [False, True, False]])
  assert split == {"within": pytest.approx(log_d[~turned].mean()),
                   "turned": pytest.approx(log_d[turned].mean()), "turned_share": 2 / 6}
  calm = bench.log_pd_by_turn(np.zeros((1, 3, 2), np.float32), period, np.ones((1, 2)))
  assert calm == {"within": 1.0, "turned": None, "turned_share": 0.0}


def test_expert_eval_measures_exploration_along_episodes():
  """`exploration` against a direct count: an action explores next to nothing where its mean
  lies more than 2 scales beyond [-1, 1] (on either side); `policy_at` gives, chunk by chunk,
  what the policy network gives at once."""
  bench = load_script("expert_eval", folder="benchmarks")
  loc = np.array([[[0.0, 1.5], [-3.0, 1.0]], [[2.0, -2.0], [0.5, 0.5]]])  # [K 2, T 2, A 2]
  scale = np.array([[[1.0, 0.2], [0.9, 0.1]], [[0.6, 0.4], [0.1, 0.1]]])
  numbers = bench.exploration(loc, scale)
  # beyond by more than 2 scales: 1.5 (0.5 > 0.4), -3.0 (2 > 1.8), -2.0 (1 > 0.8); not 2.0
  # (1 < 1.2), not 1.0 (0 < 0.2)
  np.testing.assert_allclose(numbers["beyond_bounds"], [2 / 4, 1 / 4])
  np.testing.assert_allclose(numbers["policy_scale"], [0.55, 0.3])
  # The chance that a sample clips, against tabulated normal probabilities: mean 0, scale 1:
  # P(|x| > 1) = 0.317311; mean 1.5, scale 0.2: P(x > 1) = Phi(2.5) = 0.993790.
  one = bench.exploration(np.array([[[0.0, 1.5]]]), np.array([[[1.0, 0.2]]]))["clipped"]
  np.testing.assert_allclose(one, [(0.317311 + 0.993790) / 2], atol=1e-6)
  assert 0.0 < numbers["clipped"][1] < numbers["clipped"][0] < 1.0
  import jax
  import tasks
  from mjx_form.files import experts
  from mjx_form.rl import normalizer
  from mjx_form.rl.networks import make_networks
  env = tasks.make("reacher_easy")
  expert = experts.load_expert(tasks.bundled_expert("reacher_easy"), env)
  width = expert.metadata["network_width"]
  obs = np.random.default_rng(0).normal(size=(5, 3, env.observation_size)).astype(np.float32)
  loc, scale = bench.policy_at(expert, env.action_size, obs, chunk=2)
  direct = make_networks(env.action_size, width).policy.apply(
      expert.params, normalizer.normalize(expert.normalizer, jax.numpy.asarray(obs)))
  assert loc.shape == scale.shape == (5, 3, env.action_size)
  np.testing.assert_allclose(loc, direct.mean, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(scale, direct.scale, rtol=1e-5, atol=1e-6)


def test_expert_eval_samples_actions_when_stochastic_and_counts_rewarded_episodes(
    tmp_path, monkeypatch):
  """--stochastic reaches the rollout and the record (default: the mean action); the split's
  `rewarded` is each bin's share of episodes with a positive return, against numpy."""
  bench = load_script("expert_eval", folder="benchmarks")
  import tasks
  env = tasks.make("reacher_easy")
  rng = np.random.default_rng(0)
  obs = rng.normal(size=(6, 4, env.observation_size)).astype(np.float32)  # [K, T+1, D]
  returns = np.array([0.0, 3.0, 0.0, 0.0, 5.0, 1.0])
  calls = []

  def fake_record(env, expert, key, episodes, chunk, stochastic=False, print_fn=print,
                  noise_correlation=0.0):
    calls.append((stochastic, noise_correlation))
    return obs, np.zeros((6, 3, env.action_size), np.float32), returns

  monkeypatch.setattr(bench.experts, "record_demonstrations", fake_record)
  for flag, c in (([], 0.0), (["--stochastic"], 0.0),
                  (["--stochastic", "--action_noise_correlation", "0.9"], 0.9)):
    out = tmp_path / f"eval{len(flag)}.jsonl"
    args = ["--tasks", "reacher_easy", "--episodes", "6", "--by_start", "position[0]",
            "--bins", "2", "--out", str(out), *flag]
    assert bench.main(args) == 0
    record, = [json.loads(line) for line in open(out)]
    assert record["stochastic"] is bool(flag) and calls[-1] == (bool(flag), c)
    assert record["action_noise_correlation"] == c
    split = record["by_start"]
    first = obs[:, 0, 0]
    low = first < (first.min() + first.max()) / 2
    assert split["rewarded"] == pytest.approx([(returns[low] > 0).mean(),
                                               (returns[~low] > 0).mean()])
  # A correlation without sampling, or out of [0, 1), is refused before any rollout.
  for bad in (["--action_noise_correlation", "0.9"],
              ["--stochastic", "--action_noise_correlation", "1.0"]):
    with pytest.raises(SystemExit) as exit_info:
      bench.main(["--tasks", "reacher_easy", "--out", str(tmp_path / "bad.jsonl"), *bad])
    assert exit_info.value.code == 2 and not (tmp_path / "bad.jsonl").exists()
  assert len(calls) == 3


@pytest.mark.slow
def test_recorded_actions_follow_the_actors_correlated_noise():
  """experts.record with noise_correlation samples as a run's actors do: the first step's
  actions equal independent sampling's (a fresh start takes the draw itself), later ones
  differ; the correlation without sampling is refused."""
  import jax
  import tasks
  from mjx_form.files import experts
  env = tasks.make("reacher_easy")
  expert = experts.load_expert(tasks.bundled_expert("reacher_easy"), env)
  key = jax.random.PRNGKey(3)
  _, independent, _ = experts.record(env, expert, key, 2, stochastic=True)
  _, correlated, _ = experts.record(env, expert, key, 2, stochastic=True, noise_correlation=0.9)
  np.testing.assert_array_equal(correlated[:, 0], independent[:, 0])
  assert not np.allclose(correlated[:, 1:], independent[:, 1:])
  assert np.abs(correlated).max() <= 1.0
  with pytest.raises(ValueError, match="sampled actions only"):
    experts.record(env, expert, key, 2, noise_correlation=0.9)


def test_recorded_actions_are_the_mean_clipped_to_the_control_range(monkeypatch):
  """experts.record applies and records the mean action clipped to the task's control range
  (`Task.action_bounds`: MuJoCo clamps to it, and a run's actors and evaluations act in it),
  not to [-1, 1] (quadruped's lift actuators go to 1.1). Here the range is narrowed so that
  the expert's means leave it on both sides."""
  import jax
  import tasks
  from mjx_form.files import experts
  from mjx_form.rl import normalizer
  env = tasks.make("reacher_easy")
  low, high = np.array([-0.05, -0.03], np.float32), np.array([0.02, 0.04], np.float32)
  monkeypatch.setattr(type(env), "action_bounds", property(lambda self: (low, high)))
  expert = experts.load_expert(tasks.bundled_expert("reacher_easy"), env)
  obs, actions, _ = experts.record(env, expert, jax.random.PRNGKey(5), 3)
  mean = np.asarray(experts.policy_network(expert.metadata, env.action_size).apply(
      expert.params, normalizer.normalize(expert.normalizer, obs[:, :-1])).mode())
  np.testing.assert_allclose(actions, np.clip(mean, low, high), atol=1e-5)
  assert (actions == low).any() and (actions == high).any()  # (clipped on both sides)
  # The benchmarks' rollouts act in the same range: what they write to the simulator's ctrl,
  # and dm_control_transfer's (and same_starts') policy for the bounds it is given.
  common = load_script("common", folder="benchmarks")
  ctrl = common.mean_action_rollout(env, expert, jax.random.PRNGKey(5), 3,
                                    lambda state: state.data.ctrl)  # [T, K, A]
  assert (ctrl >= low).all() and (ctrl <= high).all()
  assert (ctrl == low).any() and (ctrl == high).any()
  act = load_script("dm_control_transfer", folder="benchmarks").mean_action_fn(expert, low, high)
  np.testing.assert_allclose(act(obs[:, 0]), np.clip(mean[:, 0], low, high), atol=1e-5)


@pytest.mark.slow
def test_multi_device_compile_checks_each_program_in_its_own_process(tmp_path, capsys):
  """benchmarks/multi_device_compile.py on 2 forced host devices: each program compiled and
  run in a child process, one line and one record each; a child's death by a signal is named
  (a child that segfaults is what the script is for)."""
  bench = load_script("multi_device_compile", folder="benchmarks")
  out = tmp_path / "compile.jsonl"
  # (CI time: each child imports JAX and compiles anew; the rollout and the step are parts of
  # the iteration)
  programs = ["iteration_per_device", "top_k_per_device"]
  assert bench.main(["--task", "reacher_easy", "--devices", "2", "--num_envs", "4",
                     "--programs", *programs, "--out", str(out)]) == 0
  printed = capsys.readouterr().out
  for program in programs:
    assert f"reacher_easy {program} on 2 device(s), 4 envs: ok (compile " in printed, printed
  records = [json.loads(line) for line in open(out)]
  assert [(r["kind"], r["program"], r["outcome"], r["devices"]) for r in records] == [
      ("compile_check", p, "ok", 2) for p in programs]
  assert all(0 <= r["compile_s"] < r["seconds"] for r in records)  # (top_k: ~0.0 s)
  assert bench.ended(-11) == "signal 11 (SIGSEGV)" and bench.ended(3) == "non-finite states"
  assert bench.ended(1) == "exit status 1"
  with pytest.raises(SystemExit):
    bench.main(["--task", "reacher_easy", "--devices", "3", "--out", str(out)])


@pytest.mark.slow
def test_multi_device_compile_runs_flag_variants_and_names_the_last_passes(tmp_path, capsys):
  """The MJX-free per-device loop, once as is and once with a flag added to XLA_FLAGS, with
  its passes dumped; the last passes of a dump are read off the files' order."""
  bench = load_script("multi_device_compile", folder="benchmarks")
  out = tmp_path / "compile.jsonl"
  assert bench.main(["--task", "reacher_easy", "--devices", "2", "--num_envs", "8",
                     "--programs", "toy_while_per_device",
                     "--xla_flags=--xla_backend_optimization_level=1", "--dump_passes", str(tmp_path / "d"),
                     "--out", str(out)]) == 0
  printed = capsys.readouterr().out
  assert "toy_while_per_device on 2 device(s), 8 envs: ok" in printed, printed
  assert "XLA_FLAGS + '--xla_backend_optimization_level=1': ok" in printed, printed
  records = [json.loads(line) for line in open(out)]
  assert [r["xla_flags_added"] for r in records] == ["", "--xla_backend_optimization_level=1"]
  assert all(r["outcome"] == "ok" and r["last_passes"] == [] for r in records)
  dumped = os.listdir(tmp_path / "d" / "toy_while_per_device_0")
  assert any("after" in name or "before" in name for name in dumped), dumped[:5]
  # a folder holding dumps already, or a file, is refused before anything runs
  (tmp_path / "f").write_text("")
  for root, message in ((tmp_path / "d", "already hold dumps"), (tmp_path / "f", "not a folder")):
    with pytest.raises(SystemExit) as exit_info:
      bench.main(["--task", "reacher_easy", "--devices", "2", "--num_envs", "8", "--programs",
                  "toy_while_per_device", "--dump_passes", str(root), "--out", str(out)])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
  assert len(open(out).readlines()) == 2
  for i, name in enumerate(["a.txt", "b.txt", "c.txt", "d.txt"]):
    (tmp_path / "p" / name).parent.mkdir(exist_ok=True)
    (tmp_path / "p" / name).write_text(name)
    os.utime(tmp_path / "p" / name, (1000 + i, 1000 + i))
  assert bench.last_passes(str(tmp_path / "p")) == ["b.txt", "c.txt", "d.txt"]
  assert bench.last_passes(str(tmp_path / "missing")) == []


def test_env_throughput_shares_a_raw_loop_only_between_the_same_physics():
  """Tasks of one domain share the raw mjx.step loop's measurement; fast_bounded (same XML,
  another solver loop) gets its own, as parity does."""
  import tasks
  bench = load_script("env_throughput", folder="benchmarks")
  key = lambda name, physics: bench.raw_key(tasks.make(name, physics), 2048, 50)
  assert key("walker_walk", "fast") == key("walker_run", "fast")
  assert key("walker_walk", "fast") != key("walker_walk", "fast_bounded")
  assert key("walker_walk", "fast") != key("walker_walk", "parity")
  assert key("walker_walk", "fast_bounded") == key("walker_stand", "fast_bounded")


@pytest.mark.slow
def test_solver_iterations_summarises_what_a_batch_computes(tmp_path):
  """Two steps of four environments: batch maxima over disjoint groups, and the line-search
  passes a batch computes (10 per iteration of its slowest environment) against those a
  search stopping with the batch's slowest would (the largest count of each iteration)."""
  bench = load_script("solver_iterations", folder="benchmarks")
  counts = np.array([[1, 2, 3, 4], [2, 2, 2, 5]])
  passes = np.zeros((2, 4, 10), np.int32)
  passes[0, :, 0] = [1, 1, 2, 1]
  passes[0, 3, 1:4] = [3, 1, 1]
  passes[1, :, :2] = 2
  passes[1, 3, 2:5] = [4, 4, 1]
  s = bench.summary(counts, passes, cap=10, ls_cap=10, num_envs=4)
  assert s["mean"] == 2.625 and s["at_cap"] == 0.0
  assert s["mean_batch_max"] == {"1": 2.625, "4": 4.5}  # (8 does not fit in 4)
  ls = s["line_search"]
  assert ls["mean_per_iteration"] == passes.sum() / counts.sum()
  assert ls["batch_passes_now"] == 45.0  # 10 x (4 + 5) / 2
  assert ls["batch_passes_if_stopped"] == ((2 + 3 + 1 + 1) + (2 + 2 + 4 + 4 + 1)) / 2
  out = tmp_path / "si.jsonl"  # (reacher: only its finger's joint limit to solve)
  assert bench.main(["--tasks", "reacher_easy", "--num_envs", "4", "--steps", "3", "--out",
                     str(out)]) == 0
  record = json.loads(open(out).read())
  assert record["kind"] == "solver_iterations" and record["policy"] == "expert"
  settings = record["settings"]  # (reacher keeps dm_control's 100/50 in every mode)
  assert (settings["num_envs"], settings["steps"], settings["iterations"]) == (4, 3, 100)
  ls = record["line_search"]
  assert 0 <= record["mean"] <= 100 and ls["batch_passes_if_stopped"] <= ls["batch_passes_now"]
  assert bench.main(["--tasks", "reacher_easy", "--num_envs", "4", "--steps", "3",
                     "--ls_iterations", "4", "--out", str(out)]) == 0
  capped = json.loads(open(out).readlines()[-1])
  assert capped["settings"]["ls_iterations"] == capped["line_search"]["cap"] == 4


def test_solver_sweep_tries_the_iteration_pairs_it_is_given():
  bench = load_script("solver_sweep", folder="benchmarks")
  pairs = [bench._pair("10/4"), bench._pair("10/10")]
  assert pairs == [(10, 4), (10, 10)]
  settings = bench.candidates("walker_walk", pairs)
  assert [(s.iterations, s.ls_iterations, s.max_contact_points) for s in settings] == [
      (10, 4, None), (10, 4, 8), (10, 10, None), (10, 10, 8)]
  assert bench.candidates("cheetah_run")[0] == bench.SolverSettings()  # parity comes first
  for bad in ("10", "10/x", "0/4"):
    with pytest.raises(argparse.ArgumentTypeError):
      bench._pair(bad)


def test_reacher_settling_moves_only_the_target_and_splits_failures_by_its_place():
  """benchmarks/reacher_settling.py: a moved target changes to_target in both observations and
  nothing else; failures are shared out by radius quartile and angle quadrant."""
  bench = load_script("reacher_settling", folder="benchmarks")
  rng = np.random.default_rng(0)
  prev, nxt = rng.normal(size=(5, 6)), rng.normal(size=(5, 6))
  shift = rng.normal(size=(5, 2))
  p, n = bench.move_target(prev, nxt, slice(2, 4), shift)
  np.testing.assert_allclose(p[:, 2:4] - prev[:, 2:4], shift, rtol=1e-12, atol=1e-12)
  np.testing.assert_allclose(n[:, 2:4] - nxt[:, 2:4], shift, rtol=1e-12, atol=1e-12)
  np.testing.assert_array_equal(np.delete(p, [2, 3], 1), np.delete(prev, [2, 3], 1))
  np.testing.assert_array_equal(np.delete(n, [2, 3], 1), np.delete(nxt, [2, 3], 1))
  radius = np.arange(1.0, 9.0)  # quartiles {1,2} {3,4} {5,6} {7,8}
  angle = np.array([-3.0, -1.0, 0.5, 2.0, np.pi, -2.0, 1.0, 3.0])
  failed = np.array([1, 1, 0, 0, 0, 1, 0, 1], bool)
  edges, by_radius, by_angle = bench.failure_shares(failed, radius, angle)
  np.testing.assert_allclose(edges, [1, 2.75, 4.5, 6.25, 8])
  assert by_radius == [1.0, 0.0, 0.5, 0.5]
  # quadrants [-pi,-pi/2): -3, -2 -> 1, 1; [-pi/2,0): -1 -> 1; [0,pi/2): 0.5, 1 -> 0, 0;
  # [pi/2, pi]: 2, pi, 3 -> 0, 0, 1
  np.testing.assert_allclose(by_angle, [1.0, 1.0, 0.0, 1 / 3])
  # Five episodes: the quantiles fall on data points; each episode counts in one quartile only,
  # and a quadrant without episodes is None.
  edges, by_radius, by_angle = bench.failure_shares(
      np.array([1, 0, 0, 0, 1], bool), np.arange(1.0, 6.0), np.full(5, 0.1))
  np.testing.assert_allclose(edges, [1, 2, 3, 4, 5])
  assert by_radius == [0.5, 0.0, 0.0, 1.0]  # {1, 2}, {3}, {4}, {5}
  assert by_angle == [None, None, 0.4, None]


def test_reacher_settling_follows_the_shoulder_by_target_quadrant():
  """benchmarks/reacher_settling.py: per target quadrant, the share of episodes under 100, of
  those whose raw shoulder leaves [-pi, pi], and the median length of the shoulder's path."""
  bench = load_script("reacher_settling", folder="benchmarks")
  angle = np.array([-3.0, -2.0, -1.0, 0.5, 1.0, np.pi])  # quadrants 0, 0, 1, 2, 2, 3
  returns = np.array([50.0, 900.0, 20.0, 950.0, 960.0, 99.0])
  shoulder = np.zeros((4, 6))
  shoulder[:, 0] = [3.0, 3.2, 3.4, 9.0]  # leaves [-pi, pi]; path 0.2 + 0.2 + 5.6 = 6
  shoulder[:, 1] = [-3.0, -2.0, -3.0, -2.0]  # stays; path 3
  shoulder[:, 2] = [0.0, -3.5, -3.0, -3.0]  # leaves; path 4
  shoulder[:, 5] = [1.0, 1.5, 1.0, 1.0]  # path 1
  paths = bench.paths_by_quadrant(angle, returns, shoulder)
  assert [q["episodes"] for q in paths] == [2, 1, 2, 1]
  assert [q["share_under_100"] for q in paths] == [0.5, 1.0, 0.0, 1.0]
  assert [q["share_leaving_pi"] for q in paths] == [0.5, 1.0, 0.0, 0.0]
  np.testing.assert_allclose([q["median_path_rad"] for q in paths], [4.5, 4.0, 0.0, 1.0])
  assert bench.paths_by_quadrant(np.full(2, 0.1), returns[:2], shoulder[:, :2])[0] == {
      "episodes": 0}


def test_reacher_settling_summarises_failed_episodes_apart_from_successful_ones():
  """benchmarks/reacher_settling.py: episode_groups splits episodes by return and summarises
  each group's second half (distance, speed, shaking, log pD) beside the expert's."""
  bench = load_script("reacher_settling", folder="benchmarks")
  parts = dict(position=slice(0, 2), to_target=slice(2, 4), velocity=slice(4, 6))
  k, t = 3, 12
  obs = np.zeros((k, t + 1, 6))
  obs[0, :, 2] = 0.12  # episode 0 fails: still, 12 cm away throughout
  obs[1, :, 2] = np.linspace(0.2, 0.0, t + 1)  # episode 1 succeeds: reaches the target
  obs[1, :, 4] = 1.0  # ... moving at 1 rad/s
  obs[2, 1 + t // 2:, 0] = np.tile([0.1, -0.1], t // 2 // 2 + 1)[:t // 2]  # shaking in place
  obs[2, :, 2] = 0.3
  returns = np.array([5.0, 900.0, 50.0])
  log_d = np.arange(k * t, dtype=float).reshape(k, t)
  expert = log_d + 100.0
  out = bench.episode_groups(obs, returns, log_d, expert, parts)
  assert out["failed"] == 2 and out["task_return"] == pytest.approx(955.0 / 3)
  failed, ok = out["failed_episodes"], out["over_800_episodes"]
  assert failed["episodes"] == 2 and ok["episodes"] == 1
  assert failed["distance_m"] == pytest.approx(0.21)  # median of 0.12 and 0.3
  assert failed["speed"] == 0.0 and failed["reached_5cm"] == 0.0
  assert failed["angle_sd"] == pytest.approx(0.05)  # median of 0 (still) and 0.1 (shaking)
  assert ok["reached_5cm"] == 1.0 and ok["speed"] == pytest.approx(1.0)
  assert failed["log_pd_second_half"] == pytest.approx(np.mean(log_d[[0, 2], 6:]))
  assert failed["log_pd"] == pytest.approx(np.mean(log_d[[0, 2]]))
  assert failed["expert_log_pd_second_half"] == pytest.approx(failed["log_pd_second_half"] + 100)
  assert "policy_scale" not in failed  # (no policy statistics given)
  means = np.zeros((k, t, 2))
  means[0, t // 2:, 0] = 3.0  # episode 0's first mean outside the bounds in its second half
  scales = np.full((k, t, 2), 0.1)
  scales[0, t // 2:] = [1.0, 2.0]  # wide where it fails: 1.5 over the two dimensions
  scales[2, t // 2:] = 0.5
  policy = bench.episode_groups(obs, returns, log_d, expert, parts, means, scales)
  assert policy["failed_episodes"]["policy_scale"] == pytest.approx(1.0)  # median of 1.5, 0.5
  assert policy["over_800_episodes"]["policy_scale"] == pytest.approx(0.1)
  assert policy["failed_episodes"]["mean_out_of_bounds"] == pytest.approx(0.25)  # 6 of 24
  assert policy["over_800_episodes"]["mean_out_of_bounds"] == 0.0
  none = bench.episode_groups(obs, np.full(3, 500.0), log_d, expert, parts)
  assert none["failed_episodes"] is None and none["over_800_episodes"] is None


def test_reacher_settling_shares_failures_by_the_final_shoulder_angle():
  bench = load_script("reacher_settling", folder="benchmarks")
  # raw angles: 3.5 wraps to 3.5 - 2 pi = -2.78 (bin 0 of 8, near -pi), -0.1 -> bin 3,
  # 0.1 -> bin 4, 3.0 -> bin 7 (near pi), 2 pi + 0.1 -> 0.1 (bin 4)
  angle = np.array([3.5, -0.1, 0.1, 3.0, 2 * np.pi + 0.1])
  failed = np.array([1, 0, 1, 1, 0], bool)
  out = bench.failures_by_angle(failed, angle)
  assert out["failed_share_by_expert_final_shoulder"] == [1.0, None, None, 0.0, 0.5, None,
                                                          None, 1.0]
  assert out["failed_share_expert_final_shoulder_near_pi"] == 1.0  # 3.5 and 3.0
  assert out["failed_share_expert_final_shoulder_elsewhere"] == pytest.approx(1 / 3)
  assert bench.failures_by_angle(failed, np.zeros(5))["failed_share_expert_final_shoulder_near_pi"] is None


def test_reacher_settling_splits_endings_by_the_experts_final_shoulder():
  """endings_by_angle, checked by hand: the expert's passes of +-pi and net turns by the bin of
  its final angle; the failed episodes' final angles as a circular mean and sd."""
  bench = load_script("reacher_settling", folder="benchmarks")
  # expert: ends at 3.0 (bin 7) passing pi from 2.0; at 3.0 turning down from 3.2 (passes pi:
  # 3.2 is past it); at -0.1 (bin 3) from 0.5; at -3.0 (bin 0) from -2.0, not passing.
  expert = np.array([[2.0, 3.5, 3.0 + 2 * np.pi], [3.2, 3.1, 3.0], [0.5, 0.2, -0.1],
                     [-2.0, -2.5, -3.0]])
  # the policy: failed episodes end at pi - 0.1 and -pi + 0.1 (circular mean pi, sd 0.1) and
  # at 4 pi - 2.3 (= -2.3); the third episode succeeds
  policy = np.array([[0.0, np.pi - 0.1], [0.0, -np.pi + 0.1], [0.0, 1.0],
                     [0.0, 4 * np.pi - 2.3]])
  out = bench.endings_by_angle(expert, policy, np.array([1, 1, 0, 1], bool))
  bins = out["by_expert_final_shoulder"]
  assert [g["episodes"] for g in bins] == [1, 0, 0, 1, 0, 0, 0, 2]
  assert bins[7]["expert_passes_pi"] == 1.0 and bins[7]["expert_turns_positive"] == 0.5
  assert bins[0]["expert_passes_pi"] == 0.0 and bins[0]["expert_turns_positive"] == 0.0
  assert bins[1]["expert_passes_pi"] is None and bins[1]["failed_end_mean_rad"] is None
  assert bins[7]["failed"] == 2 and abs(abs(bins[7]["failed_end_mean_rad"]) - np.pi) < 1e-9
  assert bins[7]["failed_end_circular_sd_rad"] == pytest.approx(
      np.sqrt(-2 * np.log(np.cos(0.1))))
  assert bins[0]["failed_end_mean_rad"] == pytest.approx(-2.3)
  assert bins[0]["failed_end_circular_sd_rad"] == pytest.approx(0.0, abs=1e-6)
  assert str(bins[0]["failed_end_circular_sd_rad"])[0] != "-"  # (one episode: 0, not -0)
  assert bins[3]["failed"] == 0 and out["failed"] == 3


def test_reacher_settling_scores_the_shoulder_by_place_and_the_crossings_of_pi():
  """log_pd_by_shoulder: bins, near +-pi / elsewhere and the transitions crossing +-pi are
  taken at x_t's wrapped shoulder (whole turns change nothing), checked by hand."""
  bench = load_script("reacher_settling", folder="benchmarks")
  # one episode: 3.1 (bin 7, near) crosses to 3.2 (= -3.08); -3.08 stays (bin 0, near, not
  # crossing), then swings back through pi to 0.1 (a crossing too), then -0.1 (x_t in bin 4),
  # then stays (bin 3); one more turned by 2 pi.
  shoulder = np.array([[3.1, 3.2, 3.2, 0.1, -0.1, -0.1]])
  shoulder = np.concatenate([shoulder, shoulder + 2 * np.pi])
  log_d = np.array([[-40.0, 30.0, 10.0, 12.0, 14.0]] * 2)
  speed = np.array([[3.0, 0.0, 5.0, 4.0, 0.1]] * 2)  # moving: the crossing, 3.2 -> 0.1, 0.1 -> -0.1
  out = bench.log_pd_by_shoulder(shoulder, log_d, speed)
  assert out["log_pd_by_bin"] == [20.0, None, None, 14.0, 12.0, None, None, -40.0]
  assert out["crossing_pi"] == {"log_pd": -15.0, "transitions": 4}
  assert out["at_pi"] == {"log_pd": 30.0, "transitions": 2}
  assert out["near_pi"] == {"log_pd": 0.0, "transitions": 6}
  assert out["elsewhere"] == {"log_pd": 13.0, "transitions": 4}
  assert out["crossing_pi_moving"] == {"log_pd": -15.0, "transitions": 4}
  assert out["at_pi_moving"] == {"log_pd": None, "transitions": 0}
  assert out["moving_elsewhere"] == {"log_pd": 12.0, "transitions": 2}
  assert bench.log_pd_by_shoulder(np.zeros((1, 3)), np.ones((1, 2)), np.ones((1, 2)))[
      "crossing_pi"] == {"log_pd": None, "transitions": 0}
  # Fast crossings count (3.05 -> 3.45 wraps to -2.83; -3.1 -> -3.5 the other way); a move up
  # to pi that does not pass it does not (2.9 -> 3.1).
  fast = bench.log_pd_by_shoulder(np.array([[3.05, 3.45], [-3.1, -3.5], [2.9, 3.1]]),
                                  np.array([[1.0], [3.0], [7.0]]), np.full((3, 1), 20.0))
  assert fast["crossing_pi"] == {"log_pd": 2.0, "transitions": 2}
  assert fast["at_pi"] == {"log_pd": None, "transitions": 0}  # 2.9 is not within 0.14 rad


@pytest.mark.slow
def test_locomotion_speed_factors_are_the_tasks_reward(tmp_path, capsys):
  """benchmarks/locomotion_speed.py: its posture and speed factors multiply to the reward the
  environment gives at every step (the script refuses to report otherwise), its summary is
  numpy's over the second half, and a policy of another task is refused, nothing written."""
  bench = load_script("locomotion_speed", folder="benchmarks")
  import tasks
  out = tmp_path / "speed.jsonl"
  assert bench.main(["--task", "walker_run", "--policy", tasks.bundled_expert("cheetah_run"),
                     "--out", str(out)]) == 2
  assert "cheetah_run" in capsys.readouterr().err and not out.exists()
  assert bench.main(["--task", "walker_walk", "--policy", tasks.bundled_expert("walker_walk"),
                     "--episodes", "2", "--out", str(out)]) == 0
  record = json.loads(out.read_text())
  assert record["kind"] == "locomotion_speed" and record["max_factor_error"] <= 1e-4
  assert record["target_speed"] == 1.0 and record["speed_mean"] > 1.0  # the expert walks
  assert record["mean_return"] > 900 and record["posture_factor_mean"] > 0.9
  # the summary against numpy on made-up steps [T=4, K=2]
  env = tasks.make("walker_run")
  speed = np.array([[0.0, 1.0], [2.0, 3.0], [7.0, 8.0], [9.0, 4.0]])
  posture, move = np.full((4, 2), 0.5), np.full((4, 2), 0.25)
  reward = posture * (5 * move + 1) / 6
  product = reward.copy()
  product[1, 0] += 0.25  # a step where the factors would not give the reward
  row = bench.summary(env, reward, speed, posture, move, product)
  assert row["speed_mean"] == pytest.approx(7.0) and row["share_at_target_speed"] == 0.5
  assert row["mean_return"] == pytest.approx(reward.sum(0).mean())
  assert row["speed_p10_p50_p90"][1] == pytest.approx(7.5)
  assert row["max_factor_error"] == pytest.approx(0.25)


@pytest.mark.slow
def test_demonstrator_heldout_scores_each_episode_as_the_training_record_scores_them_all():
  """per_episode: each episode's mean log-likelihood per offset; over episodes of one length
  their mean is demonstrator.heldout_log_likelihood of them all (what a training record
  reports), for a turn-invariant model with its own standardisation; episodes differ."""
  from mjx_form.imitation import demonstrator
  from mjx_form.imitation import effect_model as em
  from mjx_form.rl import normalizer
  bench = load_script("demonstrator_heldout", folder="benchmarks")
  config = em.EffectModelConfig(width=16, num_components=2, max_offset=3,
                                period=(2 * np.pi, 0.0, 0.0))
  model = em.make_model(config, 3)
  params = em.init_params(model, jax.random.PRNGKey(3))
  rng = np.random.default_rng(0)
  episodes = np.cumsum(rng.normal(size=(4, 9, 3)) * [0.8, 0.3, 0.1], axis=1).astype(np.float32)
  norm = normalizer.NormalizerState(np.array([0.5, -0.2, 0.1], np.float32),
                                    np.array([2.0, 0.5, 0.3], np.float32), np.int32(1))
  scores = bench.per_episode(model, params, norm, episodes)  # [K, max_offset]
  assert scores.shape == (4, 3) and np.ptp(scores[:, 0]) > 0.1
  whole = demonstrator.heldout_log_likelihood(model, params, norm, episodes)
  np.testing.assert_allclose(scores.mean(axis=0), whole, rtol=1e-5, atol=1e-4)
  one = demonstrator.heldout_log_likelihood(model, params, norm, episodes[2:3])
  np.testing.assert_allclose(scores[2], one, rtol=1e-5, atol=1e-4)
  # Per transition at offset 1 (FORM's reward term, another code path): the same means.
  steps = bench.transition_log_probs(model, params, norm, episodes)  # [K, T]
  assert steps.shape == (4, 8)
  np.testing.assert_allclose(steps.mean(axis=1), scores[:, 0], rtol=1e-5, atol=1e-4)


def test_demonstrator_heldout_marks_the_transitions_that_change_the_observation_most():
  """moving_mask: the share of transitions with the largest change after each dimension is
  divided by its standard deviation (a dimension of large units does not decide alone)."""
  bench = load_script("demonstrator_heldout", folder="benchmarks")
  episodes = np.zeros((2, 6, 2), np.float32)  # [K, T+1, D]: 10 transitions
  episodes[:, :, 1] = 100.0 * np.arange(6)  # large units, the same change everywhere
  episodes[0, 3:, 0] = 1.0  # one jump in dimension 0: transition (0, 2)
  episodes[1, 5, 0] = 3.0   # and a larger one: transition (1, 4)
  mask = bench.moving_mask(episodes, 0.2)
  expected = np.zeros((2, 5), bool)
  expected[0, 2] = expected[1, 4] = True
  np.testing.assert_array_equal(mask, expected)
  assert bench.moving_mask(episodes, 0.1).sum() == 1 and bench.moving_mask(episodes, 0.1)[1, 4]


def test_form_reward_landscape_names_the_component_that_explains_each_transition():
  """responsible_component: the component of largest weighted density per transition, its
  weight and the geometric mean of its scales, against a numpy computation on random mixtures
  (one target placed on a chosen component's mean, so the argmax is known there)."""
  bench = load_script("form_reward_landscape", folder="benchmarks")
  from mjx_form.rl.distributions import GaussianMixture
  rng = np.random.default_rng(3)
  n, k, d = 50, 4, 3
  logits = rng.normal(size=(n, k)).astype(np.float32)
  mean = rng.normal(size=(n, k, d)).astype(np.float32)
  scale = np.exp(rng.normal(size=(n, k, d))).astype(np.float32)
  target = rng.normal(size=(n, d)).astype(np.float32)
  target[0] = mean[0, 2]
  scale[0, 2] = 1e-3  # a sharp component at the first target: it explains it
  mixture = GaussianMixture(jnp.asarray(logits), jnp.asarray(mean), jnp.asarray(scale))
  got = bench.responsible_component(mixture, target)
  w = np.exp(logits - logits.max(-1, keepdims=True))
  w /= w.sum(-1, keepdims=True)
  z = (target[:, None] - mean) / scale
  joint = np.log(w) + (-0.5 * z**2 - np.log(scale) - 0.5 * np.log(2 * np.pi)).sum(-1)
  top = joint.argmax(-1)
  assert top[0] == 2
  rows = np.arange(n)
  assert got["weight_median"] == pytest.approx(np.median(w[rows, top]), rel=1e-5)
  geo = np.exp(np.log(scale).mean(-1))
  assert got["scale_median"] == pytest.approx(np.median(geo[rows, top]), rel=1e-5)
  assert got["share"] == pytest.approx([np.mean(top == i) for i in range(k)])


@pytest.mark.slow
def test_locomotion_speed_factors_are_hopper_hops_reward():
  """hopper_hop: standing (torso 0.6-2 m above the foot) times the speed factor (1 at 2 m/s,
  0.5 at 1 m/s) is the environment's reward at every step, for hopper_stand's expert rolled out
  on hop (it stands, so the speed factor is low); target speed 2."""
  bench = load_script("locomotion_speed", folder="benchmarks")
  import tasks
  from mjx_form.files import experts
  env = tasks.make("hopper_hop")
  agent = experts.load_expert(tasks.bundled_expert("hopper_stand"), env, any_task=True)
  reward, speed, posture, move, product = bench.rollout(env, agent, jax.random.PRNGKey(0), 2)
  row = bench.summary(env, reward, speed, posture, move, product)
  assert row["max_factor_error"] <= 1e-5 and row["target_speed"] == 2.0
  assert row["posture_factor_mean"] > 0.9 and row["speed_factor_mean"] < 0.5


@pytest.mark.slow
def test_form_reward_of_behaviour_settles_where_the_runs_reward_statistics_do():
  """benchmarks/form_reward_of_behaviour.py: the reward statistics' fixed point is where a run's
  EMA statistics, folding in rewards clipped by FormReward.clip_tail, settle; the learner's
  reward is clipped to c sd and standardised with them."""
  bench = load_script("form_reward_of_behaviour", folder="benchmarks")
  rng = np.random.default_rng(0)
  reference = rng.standard_t(3, size=200_000) * 4.0 + 2.0  # heavy tails: clipping matters
  mean, sd = bench.reward_statistics(reference, 0.0)
  np.testing.assert_allclose([mean, sd], [reference.mean(), reference.std()])
  from mjx_form.imitation import effect_model as em
  from mjx_form.imitation import form
  from mjx_form.rl import normalizer
  config = em.EffectModelConfig(width=8)
  params = em.make_model(config, 2).init(jax.random.PRNGKey(0), jnp.zeros((1, 2)))
  source = form.FormReward(config, form.Demonstrator(params, normalizer.init(2)), reward_clip=2.0)
  stats = normalizer.init(1)
  for i in range(3000):  # the run's folding, batch by batch (decay 0.99)
    batch = jnp.asarray(rng.standard_t(3, size=512) * 4.0 + 2.0, jnp.float32)
    folded = source.clip_tail(stats, batch) if i else batch
    stats = normalizer.update(stats, folded[:, None], 0.99)
  mean, sd = bench.reward_statistics(reference, 2.0)
  np.testing.assert_allclose([mean, sd], [float(stats.mean[0]), float(np.sqrt(stats.var[0]))],
                             rtol=0.03, atol=0.03)
  assert sd < 0.8 * reference.std()  # the fixed point differs from the plain statistics
  given = bench.learner_rewards(np.array([mean, mean + 10 * sd, mean - sd]), mean, sd, 2.0, True)
  np.testing.assert_allclose(given, [0.0, 2.0, -1.0], atol=1e-12)
  np.testing.assert_allclose(bench.learner_rewards(np.array([5.0]), 1.0, 2.0, 0.0, False), [5.0])


@pytest.mark.slow
def test_form_reward_of_behaviour_reads_a_runs_imitator_model(tmp_path):
  """benchmarks/form_reward_of_behaviour.py: a run's exported imitator.npz is read back as the
  imitator state it was (same log pI); a demonstrator file or other settings are refused."""
  bench = load_script("form_reward_of_behaviour", folder="benchmarks")
  import tasks
  from mjx_form.imitation import effect_model as em
  from mjx_form.imitation import form
  from mjx_form.rl import normalizer
  env = tasks.make("reacher_easy")
  d = env.observation_size
  config = em.EffectModelConfig(width=8)
  params = em.make_model(config, d).init(jax.random.PRNGKey(0), jnp.zeros((1, d)))
  source = form.FormReward(config, form.Demonstrator(params, normalizer.init(d)))
  state = source.init(jax.random.PRNGKey(1), d, env.action_size)
  obs = jnp.asarray(np.random.default_rng(0).normal(size=(2, 6, d)), jnp.float32)
  state, _ = source.update(state, {"observation": obs, "discount": jnp.ones((2, 5))},
                           jax.random.PRNGKey(2))
  path = str(tmp_path / "imitator.npz")
  layout = [[k, v] for k, v in env.observation_layout.items()]
  source.export(state, path, {"task": env.name, "observation_size": d,
                              "observation_layout": layout, "env_steps": 10,
                              "policy_file": "policy.npz"})
  kept, info = bench.kept_imitator(path, env, config)
  assert int(kept.steps) == 1 and info["env_steps"] == 10
  np.testing.assert_allclose(info["reward_mean"], state.reward.mean[0], rtol=1e-6)
  np.testing.assert_allclose(source.log_probs(state._replace(imitator=kept), obs)[1],
                             source.log_probs(state, obs)[1], rtol=1e-6, atol=1e-5)
  with pytest.raises(ValueError, match="not an imitator model"):
    bench.kept_imitator(path, env, em.EffectModelConfig(width=16))
  # members by their place in the run: a single run's directory, a population's seed folders
  assert bench.members("r", {"seed": 3}) == [("r", {})]
  grid_run = {"seeds": [3, 4], "overrides": [{"reward_clip": 2.0}, {"reward_clip": 3.0}]}
  assert bench.members("r", grid_run) == [(os.path.join("r", "seed3_reward_clip2"),
                                            {"reward_clip": 2.0}),
                                           (os.path.join("r", "seed4_reward_clip3"),
                                            {"reward_clip": 3.0})]
  # a demonstrator of the same settings is not an imitator model
  from mjx_form.files import effect_models
  shipped = tasks.bundled_demonstrator("reacher_easy")
  shipped_config = effect_models.load_effect_model(shipped).metadata["config"]
  with pytest.raises(ValueError, match="not an imitator model"):
    bench.kept_imitator(shipped, env, em.EffectModelConfig(**shipped_config))


def test_sampled_q_precision_counts_a_grids_members_apart_and_averages_their_last_evaluations(
    tmp_path, capsys):
  """benchmarks/sampled_q_precision.py: members of one grid with the same seed (bf16 with and
  without the float32 head) are separate runs, each the mean of its last 30% of evaluations
  (numpy's, on made-up rows); a resumed part in another file continues its run, a rerun that
  overlaps it is another run; the summary is the median and range over runs; a float32 run
  has no error, a row without the diagnostics counts for nothing, runs with too few
  evaluations are left out, and an unreadable file is refused by name with exit 2."""
  bench = load_script("sampled_q_precision", folder="benchmarks")
  rng = np.random.default_rng(0)

  def curve(seed, head, steps, error, spread):
    learner = {"sampled_q_bfloat16": True, "sampled_q_float32_head": head}
    return [{"kind": "learning_curve", "task": "walker_run", "method": "expert", "seed": seed,
             "env_steps": int(t), "q_online": float(t) / 1000, "temperature": 0.1,
             "sampled_q_spread": float(p), "sampled_q_bf16_error": float(e),
             "sampled_q_bf16_centred_error": float(e) / 2,
             "settings": {"learner": learner, "eval_episodes": 64 + i}}
            for i, (t, e, p) in enumerate(zip(steps, error, spread))]

  error, spread = rng.uniform(0.1, 1.0, (4, 10)), rng.uniform(0.1, 1.0, (4, 10))
  steps = 1000 * np.arange(1, 11)
  rows = [r for seed in (0, 1, 2) for r in curve(seed, False, steps, error[seed], spread[seed])]
  rows += curve(0, True, steps[:6], error[3, :6], spread[3, :6])  # first part, resumed below
  rows.append({"kind": "learning_curve", "task": "walker_run", "seed": 0, "env_steps": 1})
  rows.append({"kind": "final_return", "task": "walker_run", "seed": 0, "final_return": 1.0})
  grid_file, resumed, rerun = (tmp_path / f"{n}.jsonl" for n in ("grid", "resumed", "rerun"))
  write = lambda path, rs: path.write_text("".join(json.dumps(r) + "\n" for r in rs))
  write(grid_file, reversed(rows))  # in any order
  write(resumed, curve(0, True, steps[6:], error[3, 6:], spread[3, 6:]))
  write(rerun, curve(1, False, steps[:4], error[0, :4], spread[0, :4]))  # overlaps seed 1's
  plain = tmp_path / "plain.jsonl"
  write(plain, [{"kind": "learning_curve", "task": "walker_run", "seed": 0, "env_steps": 5 * i,
                 "q_online": 1.0, "sampled_q_spread": 0.5, "temperature": 0.2,
                 "settings": {"learner": {"sampled_q_bfloat16": False}}} for i in range(1, 6)])
  records = {str(f): bench.results.read_records(str(f))
             for f in (grid_file, resumed, rerun, plain)}
  runs = bench.run_rows(records, late=0.3, min_points=5)  # (the 4-point rerun left out)
  assert [(r["precision"], r["seed"], r["file"], r["evaluations"]) for r in runs] == [
      ("bf16", 0, "grid.jsonl", 10), ("bf16", 1, "grid.jsonl", 10), ("bf16", 2, "grid.jsonl", 10),
      ("bf16 (float32 head)", 0, "resumed.jsonl", 10), ("float32", 0, "plain.jsonl", 5)]
  late = lambda x: x[:, 7:].mean(axis=1)  # [runs]
  np.testing.assert_allclose([r["error"] for r in runs[:4]], late(error), rtol=1e-12)
  np.testing.assert_allclose([r["spread"] for r in runs[:4]], late(spread), rtol=1e-12)
  assert [r["q"] for r in runs[:4]] == [9.0] * 4 and runs[4]["spread"] == 0.5
  assert np.isnan(runs[4]["error"])
  assert len(bench.run_rows(records, late=0.3)) == 6  # the rerun, counted apart
  groups = bench.summary(runs)
  assert [(g["precision"], g["runs"]) for g in groups] == [
      ("bf16", 3), ("bf16 (float32 head)", 1), ("float32", 1)]
  ratio = late(error)[:3] / late(spread)[:3]
  assert groups[0]["error_ratio"] == pytest.approx(
      (np.median(ratio), ratio.min(), ratio.max()))
  assert groups[0]["centred_ratio"] == pytest.approx(
      (np.median(ratio) / 2, ratio.min() / 2, ratio.max() / 2))
  assert groups[2]["error_ratio"] is None and groups[2]["spread"] == 0.5
  assert bench.main([str(grid_file), str(resumed), str(plain), "--runs"]) == 0
  out = capsys.readouterr().out
  assert "| walker_run | expert | float32 | 1 | - | - |" in out and "plain.jsonl" in out
  broken = tmp_path / "broken.jsonl"
  broken.write_text("{not json\n")
  assert bench.main([str(grid_file), str(broken)]) == 2
  assert "broken.jsonl" in capsys.readouterr().err
  stepless = tmp_path / "stepless.jsonl"
  write(stepless, [{"kind": "learning_curve", "task": "walker_run", "sampled_q_spread": 0.1}])
  assert bench.main([str(grid_file), str(stepless)]) == 2
  assert "stepless.jsonl: a learning-curve row without env_steps" in capsys.readouterr().err
  assert bench.main([str(tmp_path / "absent.jsonl")]) == 2
  assert "absent.jsonl" in capsys.readouterr().err
  assert bench.main([str(tmp_path / "rerun.jsonl"), "--min_points", "5"]) == 2  # none left
  assert "no learning-curve record" in capsys.readouterr().err
  # a FORM run's packed curve is read with its result file, by either name, once
  form = tmp_path / "form.jsonl"
  write(form, [{**r, "method": "form"} for r in curve(0, False, steps, error[0], spread[0])]
        + [{"kind": "final_return", "task": "walker_run", "method": "form", "seed": 0}])
  bench.results.pack_curve(str(form))
  assert "learning_curve" not in form.read_text()
  packed = bench.results.curve_path(str(form))
  for given in ([str(form)], [packed], [str(form), packed],
                [str(form), str(tmp_path / "." / "form.jsonl")]):
    assert bench.main([*given, "--runs"]) == 0, given
    out = capsys.readouterr().out
    assert "| walker_run | form | bf16 | 1 |" in out and out.count("form.jsonl") == 1, out


def _linear_demos(path, episodes: int, steps: int, seed: int = 0, actions: bool = True,
                  task: str = "reacher_easy"):
  """Demonstrations of `task`'s layout whose actions are a fixed function of the observation."""
  import tasks
  from mjx_form.files import demos
  env = tasks.make(task)
  rng = np.random.default_rng(seed)
  obs = rng.normal(size=(episodes, steps + 1, env.observation_size)).astype(np.float32)
  w = rng.normal(size=(env.observation_size, env.action_size)) / np.sqrt(env.observation_size)
  act = np.tanh(obs[:, :-1] @ w).astype(np.float32)
  demos.save_demonstrations(path, obs, act if actions else None, metadata={
      "task": task, "observation_layout": env.observation_layout, "physics": env.physics})
  return obs, act


@pytest.mark.slow
def test_cloning_fit_holds_out_whole_episodes_and_measures_each_loss(tmp_path, capsys):
  """cloning_fit: the held-out pairs are the file's last episodes, whole; fitting actions that
  are a function of the observation lowers the mean action's error on held-out episodes, for
  the mean alone and the weighted decoupled loss, and writes one record per loss and rate with
  its measurements over the updates; `--loss` and the file are checked."""
  bench = load_script("cloning_fit", folder="benchmarks")
  obs, act = _linear_demos(tmp_path / "d.npz", episodes=10, steps=20)
  (x, a), (hx, ha) = bench.split_pairs(obs, act, 0.2)
  np.testing.assert_array_equal(hx, obs[8:, :-1].reshape(-1, obs.shape[-1]))
  np.testing.assert_array_equal(ha, act[8:].reshape(-1, act.shape[-1]))
  assert x.shape == (8 * 20, obs.shape[-1]) and a.shape == (8 * 20, act.shape[-1])
  with pytest.raises(ValueError, match="leave none to train on"):
    bench.split_pairs(obs[:1], act[:1], 0.2)
  assert bench.parse_loss("decoupled:0.01") == ("decoupled", 0.01)
  assert bench.parse_loss("likelihood") == ("likelihood", 1.0)
  for bad, message in (("mse", "unknown loss 'mse'"), ("likelihood:0.1", "only the decoupled"),
                       ("decoupled:x", "not a number"), ("decoupled:0", "must be positive")):
    with pytest.raises(ValueError, match=message):
      bench.parse_loss(bad)
  out = tmp_path / "fit.jsonl"
  args = ["--task", "reacher_easy", "--demos", str(tmp_path / "d.npz"), "--loss", "mean",
          "--loss", "decoupled:0.01", "--learning_rate", "1e-3", "--updates", "300",
          "--every", "150", "--batch", "64", "--width", "32", "--heldout", "0.2"]
  assert bench.main(args + ["--results", str(out)]) == 0
  rows = [json.loads(line) for line in out.read_text().splitlines()]
  assert [(r["kind"], r["loss"], r["scale_weight"]) for r in rows] == [
      ("cloning_fit", "mean", 1.0), ("cloning_fit", "decoupled", 0.01)]
  for r in rows:
    assert r["updates"] == [0, 150, 300] and r["demonstrations"]["heldout_episodes"] == 2
    errors = r["heldout_action_error"]
    assert errors[-1] < 0.5 * errors[0], errors
  # the mean alone leaves the scale near where it starts (only the shared layers move it); the
  # decoupled loss fits it
  assert rows[0]["heldout_scale"][-1] == pytest.approx(rows[0]["heldout_scale"][0], rel=0.02)
  assert rows[1]["heldout_scale"][-1] < 0.5 * rows[1]["heldout_scale"][0]
  # bad input: a file without actions, another task's, --updates not a multiple of --every
  _linear_demos(tmp_path / "obs_only.npz", episodes=4, steps=5, actions=False)
  _linear_demos(tmp_path / "walker.npz", episodes=4, steps=5, task="walker_walk")
  for name in ("obs_only.npz", "walker.npz"):
    capsys.readouterr()
    assert bench.main(["--task", "reacher_easy", "--demos", str(tmp_path / name),
                       "--loss", "mean"]) == 2
    assert "error:" in capsys.readouterr().err
  with pytest.raises(SystemExit) as exit_:
    bench.main(args[:-4] + ["--updates", "100"])
  assert exit_.value.code == 2
  assert len(out.read_text().splitlines()) == 2  # nothing more written


@pytest.mark.slow
def test_saturation_bandit_keeps_the_clipped_fits_mean_near_the_bound(tmp_path, capsys):
  """Small sizes: with the best action beyond the bound, the paper's M-step drives every mean
  far out of [-1, 1] (the samples beyond it are all best); the clipped-target fit keeps the
  means within about a scale of the bound, still applying the bound, and so brings the applied
  action back sooner once the best action lies inside."""
  bench = load_script("saturation_bandit", folder="benchmarks")
  out = tmp_path / "r.jsonl"
  assert bench.main(["--states", "8", "--actions", "2", "--updates", "4000", "--phase1", "2000",
                     "--seeds", "0", "--results", str(out)]) == 0
  rows = {r["arm"]: r for r in json.loads(out.read_text())["rows"]}
  paper, clipped = rows["paper M-step"], rows["clip_mean_targets"]
  assert paper["beyond_at_phase1"] > 0.9 and paper["abs_mean_at_phase1"] > 1.5
  assert 1.0 < clipped["abs_mean_at_phase1"] < 1.0 + 2 * clipped["scale_at_phase1"]
  assert clipped["error_at_phase1"] < 0.01  # the bound is applied
  assert clipped["updates_back"] is not None
  assert clipped["updates_back"] < (2000 if paper["updates_back"] is None
                                    else paper["updates_back"])
  with pytest.raises(SystemExit):
    bench.main(["--updates", "10", "--phase1", "10"])
