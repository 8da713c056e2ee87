"""The tables of README.md and benchmarks/NOTES.md are generated from benchmarks/results/ and
tasks/experts/, never typed by hand."""

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import report  # noqa: E402

from mjx_form.files import results  # noqa: E402


def test_readme_tables_are_generated_from_results():
  result = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "report.py"), "--check"],
                          capture_output=True, text=True, timeout=60)
  assert result.returncode == 0, result.stderr


def test_report_detects_a_hand_edited_table():
  records = report.read_records()
  for path, marker in ((report.README, "parity_summary"), (report.NOTES, "throughput")):
    with open(path) as f:
      text = f.read()
    begin = f"<!-- {marker}:begin -->\n"
    assert begin in text, (path, marker)
    edited = text.replace(begin, begin + "| typed |\n")
    assert report.render(edited, records, path) != edited
    assert report.render(text, records, path) == text


def test_report_refuses_a_file_without_its_markers():
  with open(report.NOTES) as f:
    notes = f.read()
  removed = notes.replace("<!-- learning:begin -->", "")
  try:
    report.render(removed, report.read_records(), report.NOTES)
  except ValueError as e:
    assert "learning" in str(e)
  else:
    raise AssertionError("a missing table went unnoticed")


def _final_return(seed, value, policy="final", **fields):
  return {"kind": "final_return", "task": "cheetah_run", "method": "form", "physics": "fast",
          "num_envs": 512, "seed": seed, "learner_preset": "paper", "policy": policy,
          "final_return": value, "final_return_std": 40.0, "episodes": 256,
          "env_steps": 20_000_000, "wall_s": 600.0, "settings": {}, "device": "gpu:X",
          "time": "2026-12-01T00:00:00+00:00", **fields}


def test_form_table_averages_the_final_policy_over_seeds():
  assert report.form_table([]).startswith("No FORM results yet")
  records = [
      _final_return(0, 800.0), _final_return(1, 700.0, wall_s=700.0),
      _final_return(2, 600.0, wall_s=800.0),
      # the final policy with its actions sampled has its own column
      _final_return(0, 810.0, policy="final_sampled"),
      _final_return(1, 790.0, policy="final_sampled"),
      # best policies are their own column; an older record of a seed gives way to the newer
      _final_return(0, 850.0, policy="best"), _final_return(1, 750.0, policy="best"),
      # and those chosen by the evaluations' log pD theirs
      _final_return(0, 820.0, policy="best_log_pd"), _final_return(2, 640.0, policy="best_log_pd"),
      # and the policies averaged over updates theirs
      _final_return(0, 780.0, policy="average"), _final_return(1, 600.0, policy="average"),
      # and the average's chosen by log pD theirs
      _final_return(1, 610.0, policy="best_log_pd_average"),
      _final_return(2, 100.0, time="2026-11-30T00:00:00+00:00"),
      # another configuration is another row; expert runs are not FORM results
      _final_return(0, 300.0, num_envs=64),
      dict(_final_return(0, 999.0), method="expert")]
  table = report.form_table(records, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={})
  rows = [line for line in table.splitlines() if line.startswith("| cheetah_run")]
  assert len(rows) == 2, table
  # 512 envs: seeds 800, 700, 600 -> 700 +- 81.6 (population std), 700 / 875 = 0.80;
  # sampled: (810 + 790) / 2; best:
  # (850 + 750) / 2; by log pD: (820 + 640) / 2; average: (780 + 600) / 2; its by log pD: 610;
  # paper: 827.9 / 930.5 = 0.89; wall clock: the seeds' mean, 700 s.
  assert ("| cheetah_run | `gpu:X` | fast | 512 | - | raw, T - | 3 | 256 | 20.0M | 11.7 min | "
          "700.0 +- 81.6 | 800.0 | 800.0 | 730.0 | 690.0 | 610.0 | 875.0 | 0.80 | 0.89 |"
          ) in rows, rows
  assert ("| cheetah_run | `gpu:X` | fast | 64 | - | raw, T - | 1 | 256 | 20.0M | 10.0 min | 300.0 | "
          "- | - | - | - | - | 875.0 | 0.34 | 0.89 |") in rows, rows  # one seed: no spread
  # A standardised reward or another target period is another row.
  variant = {"reward": {"standardise_reward": True}, "learner": {"target_update_period": 25}}
  table = report.form_table(records + [_final_return(0, 400.0, settings=variant)],
                            expert_returns={"cheetah_run": 875.0}, demonstration_returns={})
  assert "| 512 | - | standardised, T 25 | 1 | 256 | 20.0M | 10.0 min | 400.0 |" in table, table
  # So are other learner updates per iteration (shown with the replay ratio; '-' where a
  # record does not say, as above).
  ratios = [_final_return(0, v, settings={"updates_per_iteration": u, "replay_ratio": u / 8})
            for v, u in ((450.0, 128), (460.0, 512))]
  table = report.form_table(ratios, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={})
  assert "| 512 | 128 (16) | raw, T - | 1 | 256 | 20.0M | 10.0 min | 450.0 |" in table, table
  assert "| 512 | 512 (64) | raw, T - | 1 | 256 | 20.0M | 10.0 min | 460.0 |" in table, table
  # So are other effect-model regularisers (a demonstrator of another beta_ar or L2).
  models = [_final_return(0, v, settings={"reward": {"effect_model": {"beta_ar": a, "l2": l2}}})
            for v, a, l2 in ((410.0, 1.0, 0.1), (420.0, 0.01, 1.0))]
  table = report.form_table(models, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={})
  assert "| raw, T -, ar 1, L2 0.1 | 1 | 256 | 20.0M | 10.0 min | 410.0 |" in table, table
  assert "| raw, T -, ar 0.01, L2 1 | 1 | 256 | 20.0M | 10.0 min | 420.0 |" in table, table
  clip = _final_return(0, 430.0, settings={"reward": {"standardise_reward": True,
                                                      "reward_clip": 3.0}})
  table = report.form_table([clip], expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={})
  assert "| standardised clipped at 3 sd, T - | 1 |" in table, table
  # A run its time budget stopped (finished: false) says so beside its env steps.
  table = report.form_table([_final_return(0, 440.0, finished=False)],
                            expert_returns={"cheetah_run": 875.0}, demonstration_returns={})
  assert "| 256 | 20.0M stopped | 10.0 min | 440.0 |" in table, table
  unknown = report.form_table([_final_return(0, 500.0)], expert_returns={},
                              demonstration_returns={})
  assert "| 500.0 | - | - | - | - | - | - | - | 0.89 |" in unknown
  # The imitation target: the return of the demonstrations behind the run's demonstrator.
  behind = [_final_return(s, v, settings={"reward": {"demonstrator_sha256": "d1"}})
            for s, v in ((0, 900.0), (1, 850.0))]
  table = report.form_table(behind, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={"d1": 1000.0})
  assert "| 875.0 +- 25.0 | - | - | - | - | - | 1000.0 | 0.88 | 0.89 |" in table, table
  # An ensemble's: the mean over its demonstrators' (the expert's return at export where one
  # is unknown); the variant names the ensemble.
  ensemble = {"reward": {"demonstrator_sha256": "d1+d2", "demonstrators": 2}}
  mixed = [_final_return(s, v, settings=ensemble) for s, v in ((0, 900.0), (1, 850.0))]
  table = report.form_table(mixed, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={"d1": 1000.0, "d2": 950.0})
  assert "ensemble of 2 demonstrators" in table and "mean log pD" not in table
  assert "| 875.0 +- 25.0 | - | - | - | - | - | 975.0 | 0.90 | 0.89 |" in table, table
  averaged = [_final_return(s, v, settings={"reward": {**ensemble["reward"],
                                                            "ensemble_log_pd": "mean"}})
              for s, v in ((0, 900.0), (1, 850.0))]
  assert "| raw, T -, ensemble of 2 demonstrators, mean log pD |" in report.form_table(
      averaged, expert_returns={"cheetah_run": 875.0}, demonstration_returns={})
  table = report.form_table(mixed, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={"d1": 1000.0})
  assert "| 875.0 +- 25.0 | - | - | - | - | - | 875.0 | 1.00 | 0.89 |" in table, table
  # Members with a demonstrator each (a population comparing them): one row per demonstrator,
  # named in the variant, against its own demonstrations' return.
  own = [_final_return(s, v, settings={"reward": {"demonstrator_sha256": d,
                                                  "demonstrator_per_member": True}})
         for s, v, d in ((0, 900.0, "d1aaaaaa"), (1, 850.0, "d2bbbbbb"))]
  table = report.form_table(own, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={"d1aaaaaa": 1000.0, "d2bbbbbb": 950.0})
  assert ("| raw, T -, demonstrator d1aaaa of one per member | 1 | 256 | 20.0M | 10.0 min | "
          "900.0 | - | - | - | - | - | 1000.0 | 0.90 |") in table, table
  assert ("| raw, T -, demonstrator d2bbbb of one per member | 1 | 256 | 20.0M | 10.0 min | "
          "850.0 | - | - | - | - | - | 950.0 | 0.89 |") in table, table


def test_baselines_table_takes_the_fresh_return_else_the_last_evaluation():
  assert report.baselines_table([]).startswith("No result for the baselines yet")
  settings = {"updates_per_iteration": 512, "replay_ratio": 64.0,
              "learner": {"target_update_period": 25},
              "reward": {"discriminator": {"frames": 1, "gradient_penalty": 10.0,
                                           "kl_bound": None}, "standardise_reward": False}}
  def curve(seed, steps, value, **kw):
    return {"kind": "learning_curve", "task": "walker_walk", "method": "gaifo_gp",
            "seed": seed, "device": "gpu:X", "num_envs": 512, "env_steps": steps,
            "wall_s": steps / 1e4, "pre_training_s": 50.0, "eval_return": value,
            "settings": settings, "_file": "2026-12-07_learning_curve_walker_walk_g.jsonl",
            "time": f"2026-12-07T00:{steps // 1000000:02d}:00", **kw}
  records = [curve(0, 1_000_000, 800.0), curve(0, 2_000_000, 950.0), curve(0, 3_000_000, 940.0),
             curve(1, 1_000_000, 500.0), curve(1, 2_000_000, 880.0), curve(1, 3_000_000, 960.0),
             # seed 1's fresh final evaluation replaces its last periodic one
             dict(curve(1, 3_000_000, None), kind="final_return", policy="final",
                  final_return=900.0),
             # GAIfO+GP on the CPU is not a result; FORM's runs are not baselines
             dict(curve(0, 1_000_000, 10.0), device="cpu:cpu x1"),
             dict(curve(0, 1_000_000, 10.0), method="form")]
  table = report.baselines_table(records, expert_returns={"walker_walk": 1000.0})
  rows = [line for line in table.splitlines() if line.startswith("| walker_walk")]
  # seeds 940 (last) and 900 (fresh): 920 +- 20; best (950 + 960) / 2; 0.9x expert = 900: seed 0
  # at 2M (200 s + 50 s), seed 1 at 3M (300 s + 50 s); paper 981.6 / 983.2 = 1.00.
  assert rows == [
      "| walker_walk | GAIfO+GP | 1 frame, GP 10, raw reward | `gpu:X` | 512 | 512 (64) | 25 | "
      "2 | 3.0M | 300 s | 920.0 +- 20.0 (fresh/last) | 955.0 | 350 s (3.0M) | 1000.0 | 0.92 | "
      "981.6 | 1.00 | 2026-12-07 g |"], table
  # a seed that never reaches 0.9x the expert leaves the column empty; BC's setting is its fit
  bc = {"updates_per_iteration": 512, "learner": {"cloning_loss": "squared",
                                                  "learning_rate": 1e-3}}
  table = report.baselines_table([dict(curve(0, 1_000_000, 700.0), method="bc", settings=bc)],
                                 expert_returns={"walker_walk": 1000.0})
  assert "| BC | squared, lr 0.001 |" in table and "| 512 | 512 | - | 1 | 1.0M | " in table
  assert "| 700.0 (last) | 700.0 | - |" in table  # (one seed: no spread; BC has no T)
  # BC on the CPU counts with the paper's 1000 demonstrations (its environments only evaluate),
  # not with fewer (a smoke test); other baselines on the CPU never
  def on_cpu(method, episodes, value):
    return dict(curve(0, 64_000, value), method=method, device="cpu:cpu x1",
                settings=dict(bc, reward={"demonstration_episodes": episodes}))
  table = report.baselines_table([on_cpu("bc", 1000, 610.0),
                                  dict(on_cpu("bc", 100, 620.0), _file="smoke.jsonl"),
                                  dict(on_cpu("bco", 1000, 630.0), _file="bco.jsonl")],
                                 expert_returns={"walker_walk": 1000.0})
  rows = [line for line in table.splitlines() if line.startswith("| walker_walk")]
  assert len(rows) == 1 and "| BC |" in rows[0] and "`cpu:cpu x1`" in rows[0], table
  assert "| 1 | 64k | 6 s | 610.0 (last) |" in rows[0], table  # (under 1M: thousands)
  # a seed with a final evaluation where its time budget or stop file stopped it, and no
  # periodic one, counts; its row says stopped, and has no best evaluation
  stopped = dict(curve(0, 2_000_000, None), kind="final_return", policy="final",
                 final_return=930.0, finished=False)
  table = report.baselines_table([stopped], expert_returns={"walker_walk": 1000.0})
  assert ("| 1 | 2.0M stopped | 200 s | 930.0 (fresh) | - | - | 1000.0 | 0.93 |" in table), table
  assert report.table1([stopped], expert_returns={}).count("930.0 / 981.6") == 1
  # records that carry their demonstrations' mean return are compared with it
  table = report.baselines_table([dict(stopped, demonstrations_return=950.0)],
                                 expert_returns={"walker_walk": 1000.0})
  assert "| 930.0 (fresh) | - | - | 950.0 | 0.98 |" in table, table


def test_table1_sets_ours_beside_the_papers_for_every_task_and_method():
  """FORM's cell is the FORM table's configuration; a baseline's the configuration of most
  seeds (then the higher mean), starred where it is a last periodic evaluation; the rest
  `-`; the paper's numbers from mjx_form/paper.py."""
  def curve(seed, value, file, method="gaifo_gp", **kw):
    return {"kind": "learning_curve", "task": "walker_walk", "method": method, "seed": seed,
            "device": "gpu:X", "num_envs": 512, "env_steps": 1_000_000, "wall_s": 100.0,
            "eval_return": value, "settings": {}, "_file": file, "time": "2026-12-07", **kw}
  records = [_final_return(0, 800.0), _final_return(1, 700.0),  # FORM, cheetah_run: 750
             # GAIfO+GP: two seeds at 900 (last evaluations) beat one seed at 990
             curve(0, 890.0, "a.jsonl"), curve(1, 910.0, "a.jsonl"), curve(0, 990.0, "b.jsonl"),
             # BC: its fresh final return replaces its last evaluation (no star)
             curve(0, 500.0, "c.jsonl", method="bc"),
             dict(curve(0, None, "c.jsonl", method="bc"), kind="final_return", policy="final",
                  final_return=650.0)]
  table = report.table1(records, expert_returns={"walker_walk": 960.0})
  rows = {line.split(" | ")[0][2:]: line for line in table.splitlines()
          if line.startswith("| ") and not line.startswith("| task")}
  assert list(rows) == report.TASK_ORDER
  assert rows["walker_walk"] == ("| walker_walk | 960.0 / 983.2 | 650.0 / 719.5 | - / 61.9 | "
                                 "- / 976.5 | 900.0* / 981.6 | - / 971.2 | - / 975.2 | "
                                 "- / 977.8 |"), rows["walker_walk"]
  assert rows["cheetah_run"].startswith("| cheetah_run | - / 930.5 | - / 227.5 |")
  assert rows["cheetah_run"].endswith("| 750.0 / 827.9 |")


def test_form_table_per_task_keeps_the_best_configuration_of_two_seeds_or_more():
  records = [_final_return(0, 800.0), _final_return(1, 700.0),  # 512 envs: 750 over 2 seeds
             _final_return(0, 900.0, num_envs=64),  # higher, but one seed
             _final_return(0, 760.0, num_envs=256), _final_return(1, 780.0, num_envs=256),
             _final_return(0, 500.0, task="walker_walk")]  # a task with one seed only
  table = report.form_table(records, expert_returns={"cheetah_run": 875.0, "walker_walk": 1.0},
                            demonstration_returns={}, best_per_task=True)
  rows = [line for line in table.splitlines() if line.startswith("| ")][1:]  # past the header
  assert [row.split(" | ")[:4] for row in rows] == [
      ["| cheetah_run", "`gpu:X`", "fast", "256"], ["| walker_walk", "`gpu:X`", "fast", "512"]]
  assert rows[0].endswith("| 770.0 +- 10.0 | - | - | - | - | - | 875.0 | 0.88 | 0.89 | 3 |"), rows
  assert rows[1].endswith("| 1 |"), rows
  # The README's compact view: the same row per task, fewer columns.
  compact = report.form_table(records, expert_returns={"cheetah_run": 875.0, "walker_walk": 1.0},
                              demonstration_returns={}, best_per_task=True, compact=True)
  rows = [line for line in compact.splitlines() if line.startswith("| ")][1:]
  assert [row.split(" | ")[:6] for row in rows] == [
      ["| cheetah_run", "2", "20.0M", "10.0 min", "770.0 +- 10.0", "-"],
      ["| walker_walk", "1", "20.0M", "10.0 min", "500.0", "-"]], rows
  assert rows[0].split(" | ")[6:10] == ["875.0", "0.88", "0.89", "gpu:X, 256 x -"], rows
  assert rows[0].endswith("| 3 |") and rows[1].endswith("| 1 |"), rows
  with pytest.raises(ValueError, match="per-task view"):
    report.form_table(records, compact=True)


def test_form_table_per_task_prefers_the_shipped_demonstrator():
  shipped = {"reward": {"demonstrator_sha256": "a" * 64}}
  former = {"reward": {"demonstrator_sha256": "b" * 64}}
  records = [_final_return(0, 900.0, settings=former), _final_return(1, 880.0, settings=former),
             _final_return(0, 600.0, num_envs=256, settings=shipped),
             _final_return(1, 640.0, num_envs=256, settings=shipped)]
  table = report.form_table(records, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={}, best_per_task=True,
                            shipped_demonstrators={"a" * 64})
  row, = [line for line in table.splitlines() if line.startswith("| cheetah_run")]
  assert "| 256 |" in row and "| 620.0 +- 20.0 |" in row, row
  # without a shipped demonstrator among them, the higher mean wins as before
  table = report.form_table(records, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={}, best_per_task=True,
                            shipped_demonstrators=set())
  row, = [line for line in table.splitlines() if line.startswith("| cheetah_run")]
  assert "| 890.0 +- 10.0 |" in row, row


def test_form_table_keeps_the_halves_of_an_action_penalty_grid_apart():
  # one result file, one seed, the grid's two halves: two configurations, not one
  penalty = lambda on: {"learner": {"mpo": {"action_penalty": on}}}
  records = [_final_return(0, 700.0, settings=penalty(False)),
             _final_return(0, 900.0, settings=penalty(True))]
  table = report.form_table(records, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={})
  rows = [line for line in table.splitlines() if line.startswith("| cheetah_run")]
  assert len(rows) == 2 and sum("action penalty" in row for row in rows) == 1, rows
  assert report._learner_notes({"settings": {"network_width": 512}}) == ["networks 512 wide"]
  # (the expert runs' table has a column of its own for the penalty)
  assert report._learner_notes({"settings": penalty(True)}, with_penalty=False) == []
  # MPO's scale bound is named where it is not the paper's 1e-5 (records without it had 1e-5)
  scale = lambda e: {"learner": {"mpo": {"epsilon_scale": e}}}
  assert report._learner_notes({"settings": scale(1e-6)}) == ["epsilon_scale 1e-06"]
  assert report._learner_notes({"settings": scale(1e-5)}) == []


def _default_settings(task):
  """A FORM record's settings with every default of mjx_form/imitation/settings.py."""
  from mjx_form.imitation import settings
  run = settings.run_settings(task)
  return {"reward": {"standardise_reward": run["standardise_reward"],
                     "reward_clip": run["reward_clip"],
                     "effect_model": settings.effect_model_settings(task)},
          "learner": {"target_update_period": run["target_update_period"],
                      "sampled_q_bfloat16": run["sampled_q_bfloat16"],
                      **({"clip_critic_actions": True} if run.get("clip_critic_actions") else {}),
                      "mpo": {"epsilon_scale": run.get("epsilon_scale", 1e-5)}},
          **{k: run[k] for k in settings.ACTOR_KEYS if k in run}}  # e.g. reacher's angles


def test_default_form_variant_is_what_a_default_run_records():
  assert report._default_form_variant("cheetah_run") == (
      "standardised clipped at 3 sd, T 25, ar 0.01, L2 1, sampled Q in bf16")
  # a committed record of a run with the defaults (H200, seeds 0-2, 2026-11-24)
  name = ("2026-11-24_learning_curve_h200_cheetah_run_form_std_t25_reward_clip3_bf16_sampled_q"
          "_seeds012_41m")
  record = results.run_records(os.path.join(report.RESULTS, name + ".jsonl"))[0]  # (packed)
  assert report._form_variant(record) == report._default_form_variant("cheetah_run")
  # a task whose entry sets the actor: hopper_stand's T-100 members of its first FORM run
  name = "2026-11-26_learning_curve_h100_hopper_stand_form_acme_noise09_wrap_t25_t100_seeds01"
  runs = results.run_records(os.path.join(report.RESULTS, name + ".jsonl"))
  variants = {report._form_variant(r) for r in runs if r["kind"] == "learning_curve"}
  assert report._default_form_variant("hopper_stand") in variants and len(variants) == 2
  assert "acme policy head, actor noise correlated 0.9, angles wrapped" in (
      report._default_form_variant("hopper_stand"))
  # a task whose entry sets the learner: walker_walk's runs with the expert recipes' learner
  name = "2026-11-29_learning_curve_h200_walker_walk_form_recipe_seeds012_5m"
  runs = results.run_records(os.path.join(report.RESULTS, name + ".jsonl"))
  assert {report._form_variant(r) for r in runs if r["kind"] == "learning_curve"} == {
      report._default_form_variant("walker_walk")}
  assert "critic clips actions, sampled Q in bf16, epsilon_scale 1e-06" in (
      report._default_form_variant("walker_walk"))
  assert "critic clips" not in report._default_form_variant("walker_stand")
  # a run whose imitator trained on 1 batch in k says so (records before the setting: every)
  sparse = json.loads(json.dumps(record))
  sparse["settings"]["source_update_every"] = 4
  assert report._form_variant(sparse) == (
      "standardised clipped at 3 sd, T 25, ar 0.01, L2 1, imitator on 1 batch in 4, sampled Q in "
      "bf16")
  sparse["settings"]["source_update_every"] = 1
  assert report._form_variant(sparse) == report._default_form_variant("cheetah_run")
  # a turn-invariant run's effect models say so (a period of zeros is none)
  turned = json.loads(json.dumps(record))
  turned["settings"]["reward"]["effect_model"]["period"] = [0.0, 6.28] + [0.0] * 15
  assert report._form_variant(turned) == (
      "standardised clipped at 3 sd, T 25, ar 0.01, L2 1, turn-invariant, sampled Q in bf16")


def test_form_table_per_task_prefers_the_default_configuration():
  """The default FORM settings run with 2 seeds or more on a GPU are the task's row even where
  another configuration scored higher (of two such, the one of more seeds); one seed, or a CPU
  run, is not enough; with one seed everywhere the default is still preferred."""
  default = _default_settings
  records = [_final_return(0, 800.0), _final_return(1, 700.0),  # 750 over 2 seeds, not default
             _final_return(0, 600.0, num_envs=128, settings=default("cheetah_run")),
             _final_return(1, 650.0, num_envs=128, settings=default("cheetah_run")),
             _final_return(2, 640.0, num_envs=128, settings=default("cheetah_run")),
             # the default with fewer seeds and a higher mean; the default on the CPU
             _final_return(0, 700.0, num_envs=256, settings=default("cheetah_run")),
             _final_return(1, 710.0, num_envs=256, settings=default("cheetah_run")),
             *[_final_return(s, 990.0, num_envs=4, device="cpu:cpu x1",
                             settings=default("cheetah_run")) for s in range(4)],
             _final_return(0, 500.0, task="walker_walk"),
             _final_return(1, 520.0, task="walker_walk"),
             _final_return(0, 990.0, task="walker_walk", settings=default("walker_walk")),
             _final_return(0, 900.0, task="reacher_easy"),
             _final_return(0, 100.0, task="reacher_easy", settings=default("reacher_easy"))]
  table = report.form_table(records, expert_returns={"cheetah_run": 875.0, "walker_walk": 1.0,
                                                     "reacher_easy": 1.0},
                            demonstration_returns={}, best_per_task=True)
  rows = [line for line in table.splitlines() if line.startswith("| ")][1:]
  assert [row.split(" | ")[:4] for row in rows] == [
      ["| reacher_easy", "`gpu:X`", "fast", "512"], ["| cheetah_run", "`gpu:X`", "fast", "128"],
      ["| walker_walk", "`gpu:X`", "fast", "512"]], rows
  assert "| 100.0 | - |" in rows[0], rows
  assert "| 630.0 +- 21.6 |" in rows[1] and rows[1].endswith("| 4 |"), rows
  assert "| 510.0 +- 10.0 |" in rows[2] and rows[2].endswith("| 2 |"), rows


def test_form_table_keeps_runs_of_one_seed_in_two_files_apart():
  """Two runs of seed 0 with the same settings in two result files are two runs (two rows),
  whichever was recorded last; within a file, the newer record of a seed wins."""
  a = "d/2026-12-01_learning_curve_a.jsonl"
  b = "d/2026-12-02_learning_curve_b.jsonl"
  records = [_final_return(0, 800.0, _file=a), _final_return(0, 600.0, _file=b),
             _final_return(1, 700.0, _file=b),
             _final_return(1, 500.0, _file=b, time="2026-11-01T00:00:00+00:00")]
  table = report.form_table(records, expert_returns={"cheetah_run": 875.0},
                            demonstration_returns={})
  rows = [line for line in table.splitlines() if line.startswith("| cheetah_run")]
  assert len(rows) == 2, rows
  assert any("| 1 | 256 | 20.0M | 10.0 min | 800.0 |" in row for row in rows), rows
  assert any("| 2 | 256 | 20.0M | 10.0 min | 650.0 +- 50.0 |" in row for row in rows), rows


def _curve_point(steps, value, **fields):
  return {"kind": "learning_curve", "task": "walker_walk", "method": "form", "seed": 0,
          "num_envs": 512, "env_steps": steps, "updates": int(steps // 400),
          "wall_s": steps / 1e4, "eval_return": value,
          "demonstrator_log_prob": value / 100, "device": "gpu:X", "_file": "d/2026-12-01_x.jsonl",
          "settings": {"updates_per_iteration": 128, "reward": {"standardise_reward": True},
                       "learner": {"target_update_period": 25}}, **fields}


def test_form_runs_table_has_one_row_per_run_and_seed():
  assert report.form_runs_table([]).startswith("No FORM learning runs")
  settings = _curve_point(0, 0)["settings"]
  clipped = dict(settings, learner={"target_update_period": 25, "clip_critic_actions": True})
  records = [_curve_point(1e6, 100.0), _curve_point(3e6, 300.0), _curve_point(2e6, 350.0),
             _curve_point(1e6, 50.0, seed=1),
             dict(_final_return(1, 77.0, task="walker_walk", settings=settings),
                  _file="d/2026-12-01_x.jsonl"),
             dict(_curve_point(1e6, 999.0), method="expert"),
             # a population member of seed 0 with its own (grid) setting: a run of its own
             _curve_point(1e6, 120.0, settings=clipped)]
  table = report.form_runs_table(records)
  rows = [line for line in table.splitlines() if line.startswith("| walker_walk")]
  # seed 0: last eval 300 at 3M, best 350, no fresh evaluation; seed 1: its final_return.
  # (learner updates: those of the last evaluation)
  assert rows == [
      "| walker_walk | `gpu:X` | standardised, T 25, critic clips actions | 512 | 128 | 0 | 1.0M | "
      "2,500 | 100 s | 120.0 | 120.0 | - | 1.2 | 2026-12-01 |",
      "| walker_walk | `gpu:X` | standardised, T 25 | 512 | 128 | 0 | 3.0M | 7,500 | 300 s | "
      "300.0 | 350.0 | - | 3.0 | 2026-12-01 |",
      "| walker_walk | `gpu:X` | standardised, T 25 | 512 | 128 | 1 | 1.0M | 2,500 | 100 s | "
      "50.0 | 50.0 | 77.0 | 0.5 | 2026-12-01 |"], table


def test_population_table_gives_the_speed_up_over_one_member_of_the_same_file_or_a_marked_other():
  assert report.population_table([]).startswith("No population")

  def record(members, sps, iteration_s, collect_s, file="2026-12-01_population_throughput.jsonl",
             learner=None):
    return {"kind": "population_throughput", "task": "cheetah_run", "device": "gpu:X",
            "physics": "fast", "num_envs": 512, "members": members, "sps": sps, "iteration_s": iteration_s,
            "collect_s": collect_s, "update_ms": 1e3 * (iteration_s - collect_s) / 100,
            "peak_memory_bytes": 2**30 * members,
            "settings": {"updates_per_iteration": 100, "learner": learner or {}}, "_file": file}
  later = "2026-12-02_population_throughput_faster.jsonl"
  bf16 = {"target_update_period": 200, "sampled_q_bfloat16": True}
  table = report.population_table([record(1, 50_000, 1.0, 0.4), record(8, 200_000, 2.0, 0.8),
                                   record(1, 40_000, 1.0, 0.4, later, bf16),
                                   record(4, 100_000, 2.0, 0.8, later, bf16)])
  rows = [line for line in table.splitlines() if line.startswith("| cheetah_run")]
  # P = 8: 4.00x; updates 1.2 s over 100 updates and 8 members = 1.50 ms each.
  assert rows[1] == ("| cheetah_run | `gpu:X` | fast | 512 | 100 | - | 8 | 200k | 4.00x | - | - | "
                     "2.00 s | 0.80 s | 1.20 s | 1.50 | 8.0 GiB | 2026-12-01 |"), rows
  assert "| 1 | 50k | 1.00x | - | - | 1.00 s | 0.40 s | 0.60 s | 6.00 | 1.0 GiB |" in rows[0], rows
  # The later file's P = 4 is against its own P = 1 (40k), not the other file's (50k); its
  # learner's departure from the paper's is named.
  assert rows[3].startswith("| cheetah_run | `gpu:X` | fast | 512 | 100 | sampled Q in bf16 | 4 | "
                            "100k | 2.50x |"), rows
  assert rows[3].endswith("| 2026-12-02 faster |"), rows
  assert "another result file" not in table

  # A file without P = 1 is measured against the newest P = 1 of the same settings elsewhere,
  # marked; with no such P = 1 anywhere (other learner settings) it gets none.
  newer = "2026-12-03_population_throughput_p8.jsonl"
  t25 = {"target_update_period": 25}
  table = report.population_table([record(1, 50_000, 1.0, 0.4, later, bf16) | {"time": "1"},
                                   record(1, 40_000, 1.0, 0.4, later, bf16) | {"time": "2"},
                                   record(8, 200_000, 2.0, 0.8, newer, bf16) | {"time": "3"},
                                   record(8, 100_000, 2.0, 0.8, newer, t25) | {"time": "3"}])
  rows = {line.split(" | ")[5]: line for line in table.splitlines()
          if line.startswith("| cheetah_run") and "| 8 |" in line}
  assert "| 8 | 200k | 5.00x* |" in rows["sampled Q in bf16"], rows
  assert "| 8 | 100k | - |" in rows["T 25"], rows
  assert table.endswith("\\* over P = 1 of another result file (same task, device, physics, "
                        "environments, updates and learner settings)."), table
  # another physics mode is never measured against fast's P = 1, in its file or elsewhere
  bounded = lambda r: r | {"physics": "fast_bounded"}
  table = report.population_table([record(1, 50_000, 1.0, 0.4, later, bf16),
                                   bounded(record(8, 300_000, 2.0, 0.8, later, bf16)),
                                   bounded(record(8, 300_000, 2.0, 0.8, newer, bf16))])
  rows = [line for line in table.splitlines() if "| fast_bounded |" in line]
  assert len(rows) == 2 and all("| 8 | 300k | - |" in row for row in rows), rows

  # Over two devices: each layout's speed-up over the same population on one device of the
  # same model (here from another file) and over P = 1 on the two devices (a single run
  # splits its environments, whatever the population's layout).
  two = "2026-12-04_population_throughput_two_gpus.jsonl"
  on = lambda r, devices, layout: r | {"device": f"gpu:X x{devices}", "devices": devices,
                                       "layout": layout}
  table = report.population_table([
      on(record(8, 200_000, 2.0, 0.8, later), 1, "environments") | {"time": "1"},
      on(record(8, 300_000, 2.0, 0.8, later), 1, "environments") | {"time": "0"},
      on(record(1, 60_000, 1.0, 0.4, two), 2, "environments"),
      on(record(8, 380_000, 2.0, 0.8, two), 2, "members"),
      on(record(8, 250_000, 2.0, 0.8, two), 2, "environments")])
  rows = {tuple(line.split(" | ")[6:11]): line for line in table.splitlines()
          if line.startswith("| cheetah_run")}
  assert ("8", "380k", "6.33x", "members", "1.90x") in rows, rows  # the newest one-device 200k
  assert ("8", "250k", "4.17x", "environments", "1.25x") in rows, rows
  assert ("8", "200k", "-", "-", "-") in rows, rows
  # Stepped per device: a layout of its own, against P = 1 stepped per device (not the 60k).
  apart = {"per_device_env_steps": True}
  table = report.population_table([
      on(record(1, 60_000, 1.0, 0.4, two), 2, "environments"),
      on(record(1, 80_000, 1.0, 0.4, two), 2, "environments") | apart,
      on(record(8, 400_000, 2.0, 0.8, two), 2, "members") | apart])
  row, = [line for line in table.splitlines() if "| members, per device |" in line]
  assert "| 8 | 400k | 5.00x | members, per device |" in row, row


def test_learner_label_names_what_differs_from_the_paper():
  assert report._learner_label({"settings": {"learner": {}}}) == "-"
  record = {"settings": {"policy_head": "acme", "learner": {"target_update_period": 25,
                                                            "sampled_q_bfloat16": True}}}
  assert report._learner_label(record) == "T 25, sampled Q in bf16, acme policy head"
  assert report._learner_label({"settings": {"policy_head": "paper", "learner": {}}}) == "-"
  record = {"settings": {"action_noise_correlation": 0.9, "learner": {}}}
  assert report._learner_label(record) == "actor noise correlated 0.9"
  record = {"settings": {"action_noise_correlation": 0.0, "learner": {}}}
  assert report._learner_label(record) == "-"
  record = {"settings": {"init_policy": "hopper_stand " + "ab12cd34" * 8, "learner": {},
                         "policy_head": "acme", "wrap_angles": True}}
  assert report._learner_label(record) == (
      "acme policy head, angles wrapped, started from hopper_stand's policy ab12cd34")
  record = {"settings": {"init_policy": None, "learner": {}}}
  assert report._learner_label(record) == "-"


def test_scaling_table_gives_the_efficiency_against_one_device():
  assert report.scaling_table([]).startswith("No scaling")

  def record(devices, sps, env_sps, mode="weak", device="gpu:H x8", learner=None):
    return {"kind": "scaling", "task": "humanoid_run", "mode": mode, "device": device,
            "devices": devices, "members": 1, "total_envs": 2048 * devices, "sps": sps,
            "env_sps": env_sps, "iteration_s": 1.5, "peak_memory_bytes": 2**31,
            "settings": {"updates_per_iteration": 128, "learner": learner or {}}}
  bf16 = {"sampled_q_bfloat16": True}
  table = report.scaling_table([record(1, 20_000, 500_000), record(8, 144_000, 3_600_000),
                                record(8, 100_000, 1e6, device="gpu:other x8"),
                                record(1, 25_000, 500_000, learner=bf16),
                                record(8, 150_000, 3_600_000, learner=bf16)])
  rows = [line for line in table.splitlines() if line.startswith("| humanoid_run")]
  assert "| 8 | environments | 144k | 0.90 | 3.60M | 0.90 | - | 1.50 s | 2.0 GiB |" in rows[1], rows
  assert "| 1 | - | 20k | 1.00 | 500k | 1.00 |" in rows[0], rows
  # a bf16 learner's rows keep their own one-device row (25k, not the float32 run's 20k)
  assert rows[3].startswith("| humanoid_run | weak | `gpu:H x8` | fast | sampled Q in bf16 | 2048 "
                            "| 128 | 1 | 8 | environments | 150k | 0.75 |"), rows
  assert "| 8 | environments | 100k | - | 1.00M | - |" in rows[4], rows  # no one-device row there
  # A population over two devices, in each layout, against one device of the same model (its
  # record says x1: measured with one device visible).
  def population(devices, sps, layout=None, device="gpu:H x2"):
    return record(devices, sps, 1e6, mode="population", device=device) | {
        "members": 2 * devices, "total_envs": 1024 * devices, "layout": layout}
  table = report.scaling_table([population(1, 200_000, "environments", "gpu:H x1"),
                                population(2, 380_000, "members") | {
                                    "env_whole_batch_sps": 1.5e6,
                                    "per_device_env_steps": True},
                                population(2, 240_000, "environments")])
  rows = [line for line in table.splitlines() if line.startswith("| humanoid_run")]
  assert "| 2 | 1 | - | 200k | 1.00 |" in rows[0], rows
  assert "| 4 | 2 | environments | 240k | 0.60 |" in rows[1], rows
  assert "| 4 | 2 | members, per device | 380k | 0.95 | 1.00M | 0.50 | 1.50M |" in rows[2], rows


def test_scaling_summary_gives_one_row_per_setting_with_each_device_count():
  assert report.scaling_summary([]).startswith("No scaling")

  def record(devices, sps, device="gpu:NVIDIA H x4", time="2026-01-01", **extra):
    return {"kind": "scaling", "task": "humanoid_run", "mode": "weak", "device": device,
            "devices": devices, "members": 1, "total_envs": 2048 * devices, "sps": sps,
            "env_sps": sps, "iteration_s": 1.0, "time": time,
            "settings": {"updates_per_iteration": 8, "learner": {}}, **extra}
  table = report.scaling_summary([
      record(1, 40_000, "gpu:NVIDIA H x1"),
      record(1, 50_000, "gpu:NVIDIA H x1", time="2026-01-02"),
      record(2, 90_000), record(4, 160_000), record(2, 70_000, "gpu:NVIDIA G x2"),
      record(2, 95_000, layout="environments", per_device_env_steps=True),
      record(1, 30_000, physics="fast_bounded"), record(2, 66_000, physics="fast_bounded")])
  rows = [line for line in table.splitlines() if line.startswith("| humanoid_run")]
  # the newest one-device record of the same card and physics (50k), N = 8 unmeasured
  weak = "| humanoid_run | weak, 2048 envs/GPU"
  assert rows[0] == f"{weak} | G | - | 8 | - | 70k | - | - |", rows
  assert rows[1] == f"{weak} | H | - | 8 | 50k | 90k (0.90) | 160k (0.80) | - |", rows
  assert rows[2] == f"{weak}, per device | H | - | 8 | 50k | 95k (0.95) | - | - |", rows
  assert rows[3] == f"{weak}, physics fast_bounded | H | - | 8 | 30k | 66k (1.10) | - | - |", rows
  assert len(rows) == 4
  # populations of other sizes keep their own rows and one-GPU baselines
  population = lambda devices, sps, members: record(devices, sps) | {
      "mode": "population", "members": members * devices, "total_envs": 512 * members * devices}
  members = lambda r: r | {"layout": "members"}
  table = report.scaling_summary([population(1, 100_000, 2), members(population(2, 180_000, 2)),
                                  population(1, 150_000, 4), members(population(2, 240_000, 4))])
  rows = [line for line in table.splitlines() if line.startswith("| humanoid_run")]
  assert rows == [
      "| humanoid_run | population, 2 x 512 envs/GPU | H | - | 8 | 100k | 180k (0.90) | - | - |",
      "| humanoid_run | population, 4 x 512 envs/GPU | H | - | 8 | 150k | 240k (0.80) | - | - |"
  ], rows
  # each member's environments split over the GPUs, and another update count: rows of their own
  split = population(2, 120_000, 2) | {"layout": "environments"}
  more = lambda r: r | {"settings": {"updates_per_iteration": 128, "learner": {}}}
  table = report.scaling_summary([population(1, 100_000, 2), members(population(2, 180_000, 2)),
                                  split, more(population(1, 50_000, 2)),
                                  more(members(population(2, 95_000, 2)))])
  rows = [line for line in table.splitlines() if line.startswith("| humanoid_run")]
  assert rows == [
      "| humanoid_run | population, 2 x 512 envs/GPU, environments split | H | - | 8 | 100k | "
      "120k (0.60) | - | - |",
      "| humanoid_run | population, 2 x 512 envs/GPU | H | - | 8 | 100k | 180k (0.90) | - | - |",
      "| humanoid_run | population, 2 x 512 envs/GPU | H | - | 128 | 50k | 95k (0.95) | - | - |"
  ], rows


def test_demonstrator_tables_show_the_held_out_likelihood():
  assert report.effect_model_table([]) == "No demonstrator results yet."
  base = {"kind": "effect_model", "task": "walker_walk", "method": "form", "device": "gpu:X",
          "settings": {"beta_ar": 1.0, "l2": 0.1, "width": 256, "demo_episodes": 1000},
          "steps": 90000, "best_step": 80000, "seconds": 150.2,
          "heldout_log_likelihood": [5.0, 4.0, 3.0, 2.0, 1.0], "curve": [],
          "_file": "2026-12-01_effect_models.jsonl", "time": "t"}
  better = dict(base, settings=dict(base["settings"], beta_ar=0.01),
                heldout_log_likelihood=[6.0, 5.0, 4.0, 3.0, 2.0])
  best = report.effect_model_table([base, better], shipped={})
  assert ("| walker_walk | - | - | 2 | `gpu:X` | 1000 | 0.01 | 0.1 | 256 | - | - | 90,000 (80,000) | "
          "150 s | 6.00 / 5.00 / 4.00 / 3.00 / 2.00 | 2026-12-01_effect_models |") in best
  assert best.count("| walker_walk |") == 1
  # Another expert's demonstrations: a row of its own, even with a lower likelihood.
  other = dict(base, demonstrations={"sha256": "d" * 64, "expert_sha256": "a9395d5fd8f0" + "0" * 52,
                                     "expert_return": 963.69})
  both = report.effect_model_table([base, better, other], shipped={})
  assert both.count("| walker_walk |") == 2
  assert "| walker_walk | a9395d5fd8f0 (963.7) | - | 1 | `gpu:X` |" in both
  # Demonstrations without a named expert (a --demos file): a row of their own; an expert
  # without its return.
  hand = dict(base, demonstrations={"sha256": "e" * 64, "expert_sha256": None})
  unscored = dict(base, demonstrations={"sha256": "f" * 64, "expert_sha256": "b" * 64})
  rows = report.effect_model_table([base, hand, unscored], shipped={}).splitlines()
  assert sum(line.startswith("| walker_walk |") for line in rows) == 3
  assert any(line.startswith("| walker_walk | none (demonstrations eeeeeeeeeeee) | - | 1 |")
             for line in rows)
  assert any(line.startswith("| walker_walk | bbbbbbbbbbbb | - | 1 |") for line in rows)
  turning = dict(base, settings=dict(base["settings"], period=[6.28, 0.0], batch_size=16,
                                     window=50))
  every = report.effect_model_table([base, better, turning], best_per_task=False,
                                     shipped={})
  assert every.count("| walker_walk |") == 3 and "| 1 | 0.1 | 256 | - | - |" in every
  assert "| 1 | 0.1 | 256 | invariant | 16 x 50 |" in every
  # The shipped training is its group's row and is marked, even below a better likelihood
  # (cheetah_run ships a strongly regularised model: FORM learned more with it).
  shipped = {"walker_walk": (90000, (5.0, 4.0, 3.0, 2.0, 1.0))}
  marked = report.effect_model_table([base, better], shipped=shipped)
  assert "| walker_walk | - | yes | 2 | `gpu:X` | 1000 | 1 | 0.1 |" in marked, marked
  assert marked.count("| walker_walk |") == 1
  every = report.effect_model_table([base, better], best_per_task=False, shipped=shipped)
  assert "| walker_walk | - | yes |" in every and "| walker_walk | - | - |" in every
  # Where a task's shipped demonstrator is among them, other experts' trainings are left to
  # the full table (benchmarks/NOTES.md).
  elsewhere = dict(other, heldout_log_likelihood=[9.0, 8.0, 7.0, 6.0, 5.0])
  alone = report.effect_model_table([base, better, elsewhere], shipped=shipped)
  assert alone.count("| walker_walk |") == 1 and "| walker_walk | - | yes |" in alone
  assert report.effect_model_table([base, better, elsewhere], best_per_task=False,
                                   shipped=shipped).count("| walker_walk |") == 3
  assert report.effect_model_table([base, better, elsewhere],  # (none shipped: both groups)
                                   shipped={}).count("| walker_walk |") == 2
  # Another task's or another length's training is not the shipped one.
  assert "| yes |" not in report.effect_model_table(
      [base], shipped={"walker_walk": (91000, (5.0, 4.0, 3.0, 2.0, 1.0))})
  assert "| yes |" not in report.effect_model_table(
      [base], shipped={"cheetah_run": (90000, (5.0, 4.0, 3.0, 2.0, 1.0))})


def test_every_shipped_demonstrator_has_its_training_record():
  """Each file in tasks/demonstrators/ is tied to the record of the training that wrote it."""
  records = report.read_records()
  shipped = report._shipped_demonstrators()
  assert set(shipped) >= {"reacher_easy", "reacher_hard", "cheetah_run", "walker_stand",
                          "walker_walk"}
  for task in shipped:
    assert any(r.get("kind") == "effect_model" and r["task"] == task
               and report._is_shipped(r, shipped) for r in records), task


def test_learning_tables_show_expert_runs_only():
  base = {"kind": "learning_curve", "task": "walker_walk", "seed": 0, "num_envs": 512,
          "device": "gpu:X", "physics_matmul_precision": "highest",
          "settings": {"updates_per_iteration": 128, "replay_ratio": 16, "eval_episodes": 32}}
  curve = [dict(base, method="expert", _file="a.jsonl", env_steps=s, wall_s=w, eval_return=v)
           for s, w, v in ((1e6, 100.0, 500.0), (2e6, 200.0, 850.0), (3e6, 300.0, 820.0))]
  fast = dict(base, _file="b.jsonl", env_steps=1e6, wall_s=90.0, eval_return=810.0)  # no method
  form = dict(base, method="form", _file="c.jsonl", env_steps=1e6, wall_s=10.0,
              eval_return=990.0)
  summary = report.learning_summary([*curve, fast, form])
  assert "| walker_walk | 2 | 850.0 (2.0M, a) | 90 s (1.0M, b) |" in summary, summary
  assert "| 934.0 | not reached |" in summary  # walker_walk's bar: 0.95 x 983.2
  assert "| humanoid_run | 0 | - | - | 699.8 | no runs yet |" in summary
  expert = [dict(base, method="expert", _file="d.jsonl", env_steps=s, wall_s=w, eval_return=v)
            for s, w, v in ((4e6, 400.0, 933.9), (5e6, 500.0, 934.1))]
  summary = report.learning_summary([*curve, fast, form, *expert])
  assert "| 934.0 | 500 s (5.0M, d) |" in summary, summary
  assert "990.0" not in report.learning_table([*curve, fast, form])
  capped = [dict(r, physics="fast_ls4", _file="e.jsonl") for r in expert]
  table = report.learning_table([*curve, *capped])
  assert table.count("(fast_ls4 physics)") == 1 and "fast physics" not in table, table
  # A run that started from a trained policy (--init_policy) counts for the highest evaluation,
  # not for the times from scratch: its clock does not include the policy it started from. Its
  # time to expert follows apart, named so.
  started = [dict(r, _file="f.jsonl", wall_s=r["wall_s"] / 100, eval_return=r["eval_return"] + 9,
                  settings=dict(base["settings"], init_policy="walker_stand " + "ab" * 32))
             for r in expert]
  summary = report.learning_summary([*curve, fast, *expert, *started])
  assert "| walker_walk | 4 | 943.1 (5.0M, f) | 90 s (1.0M, b) |" in summary, summary
  assert "| 934.0 | 500 s (5.0M, d); from a trained policy: 4 s (4.0M, f) |" in summary, summary
  # (none from scratch reached it)
  summary = report.learning_summary([*curve, fast, *started])
  assert "| 934.0 | not reached; from a trained policy: 4 s (4.0M, f) |" in summary, summary
  # (one that started from a trained policy and did not reach it adds nothing)
  below = [dict(r, eval_return=900.0) for r in started]
  assert "| 934.0 | 500 s (5.0M, d) |" in report.learning_summary([*curve, *expert, *below])


def test_a_resumed_part_counts_once_and_for_the_thresholds_it_passes():
  """A run resumed (`--resume`) into a result file of its own: the part after the resume is
  not counted as a run again, and a threshold its first evaluation already passes was passed
  in the part before (the run's clock goes on across the resume)."""
  base = {"kind": "learning_curve", "method": "expert", "task": "walker_walk", "seed": 0,
          "num_envs": 512, "device": "gpu:X", "physics_matmul_precision": "highest",
          "settings": {"updates_per_iteration": 128, "replay_ratio": 16, "eval_episodes": 32}}
  part1 = [dict(base, _file="g.jsonl", iteration=i, env_steps=i * 1e5, wall_s=i * 10.0,
                eval_return=v) for i, v in ((10, 500.0), (20, 850.0), (30, 900.0))]
  part2 = [dict(base, _file="h.jsonl", iteration=i, env_steps=i * 1e5, wall_s=i * 10.0,
                eval_return=v) for i, v in ((40, 860.0), (50, 940.0), (60, 930.0))]
  # (a run stopped by its time budget right after its first evaluation: rows 10 and 11)
  stopped = [dict(r, iteration=i) for r, i in zip(part1, (10, 11))]
  assert [report._resumed(c) for c in (part1, part2, part2[:2], stopped)] == [
      False, True, False, False]
  # Records since 2026-11-29 say where their process started; that wins over the rows.
  said = lambda curve, start: [dict(r, start_iteration=start) for r in curve]
  assert [report._resumed(c) for c in (said(part2[:2], 30), said(part2, 0), said(part1, 0))
          ] == [True, False, False]
  # (a run begun before the field, resumed after it into the same file: its first rows decide)
  assert report._resumed([*part1, *said(part2, 30)]) is False
  assert report._resumed([*said(part1, 0)[:1], *part2]) is False
  summary = report.learning_summary([*part1, *part2])
  assert "| walker_walk | 1 | 940.0 (5.0M, h) | 200 s (2.0M, g) | 934.0 | 500 s (5.0M, h) |" in (
      summary), summary
  # (alone, the resumed part passes 800 nowhere that counts)
  assert "| walker_walk | 0 | 940.0 (5.0M, h) | not reached | 934.0 | 500 s (5.0M, h) |" in (
      report.learning_summary(part2))
  rows = [line for line in report.learning_table([*part1, *part2]).splitlines()
          if line.startswith("| walker_walk")]
  assert [("before this part" in line, "200 s (2.0M)" in line) for line in rows] == [
      (False, True), (True, False)], rows
  # A resumed part that dips under a threshold and passes it again: "in this part".
  dipped = [dict(r, eval_return=v) for r, v in zip(part2, (790.0, 820.0, 930.0))]
  row, = [line for line in report.learning_table(dipped).splitlines()
          if line.startswith("| walker_walk")]
  assert "| in this part: 500 s (5.0M) |" in row, row


def test_expert_runs_tell_members_apart_by_every_grid_setting():
  """A population's members share the file, task and seed; _member keeps them apart by the
  learner, the reward settings, the actor noise and the wrap, and a member's records together."""
  settings = {"learner": {"target_update_period": 25}, "reward": {},
              "action_noise_correlation": 0.0, "wrap_angles": False}
  base = {"kind": "learning_curve", "task": "hopper_stand", "seed": 0, "_file": "a.jsonl"}
  variants = [settings, dict(settings, wrap_angles=True),
              dict(settings, init_policy="hopper_stand " + "ab" * 32),
              dict(settings, action_noise_correlation=0.9),
              dict(settings, learner={"target_update_period": 100}),
              dict(settings, reward={"standardise_reward": True}),
              dict(settings, reward={"reward_clip": 3.0}),
              dict(settings, reward={"ensemble_log_pd": "mean"})]
  records = [dict(base, settings=v, env_steps=s) for v in variants for s in (1, 2)]
  runs = report._expert_runs(records)
  assert len(runs) == len(variants)
  assert all([r["env_steps"] for r in curve] == [1, 2] for curve in runs.values())
  # Records written before the noise and the wrap were settings read as their defaults.
  old = dict(base, settings={"learner": {"target_update_period": 25}, "reward": {}})
  assert report._member(old) == report._member(dict(base, settings=settings))
  # Learner settings added later, at the value that ran before them, keep a resumed run whole;
  # another value is another member.
  for key, before, other in (("sampled_q_float32_head", False, True),
                             ("cloning_loss", "likelihood", "decoupled")):
    added = lambda v: dict(base, settings=dict(settings, learner={"target_update_period": 25,
                                                                   key: v}))
    assert report._member(added(before)) == report._member(old), key
    assert report._member(added(other)) != report._member(old), key
  mpo = lambda **kw: dict(base, settings=dict(settings, learner={
      "target_update_period": 25, "mpo": {"epsilon_scale": 1e-6, **kw}}))
  assert report._member(mpo(clip_mean_targets=False)) == report._member(mpo())
  assert report._member(mpo(clip_mean_targets=True)) != report._member(mpo())
  assert "mean fitted to clipped actions" in report._learner_notes(mpo(clip_mean_targets=True))
  assert "mean fitted to clipped actions" not in report._learner_notes(
      mpo(clip_mean_targets=False))


def test_learning_summary_sets_cheetah_against_brax_ppo_cold_and_warm():
  base = {"kind": "learning_curve", "task": "cheetah_run", "seed": 0, "num_envs": 512,
          "method": "expert", "device": "gpu:X", "settings": {"eval_episodes": 32}}
  warm = [dict(base, _file="warm.jsonl", env_steps=1e6, wall_s=w, eval_return=v,
               persistent_cache_hits=4) for w, v in ((100.0, 500.0), (150.0, 805.0))]
  cold = [dict(base, _file="cold.jsonl", env_steps=1e6, wall_s=w, eval_return=v,
               persistent_cache_hits=0) for w, v in ((160.0, 700.0), (210.0, 801.0))]
  old = [dict(base, _file="old.jsonl", env_steps=1e6, wall_s=190.0, eval_return=900.0)]
  line = report.learning_summary([*warm, *cold, *old]).splitlines()[-1]
  assert line.startswith("cheetah_run against Brax PPO: Brax's PPO reached 800 in 161 s"), line
  # fastest of all: the warm run; of the runs that compiled (cache hits recorded as 0): cold.
  assert "the fastest run here: 150 s (1.0M, warm)" in line, line
  assert "no persistent-cache hits recorded): 210 s (1.0M, cold)." in line, line
  line = report.learning_summary([*warm, *old]).splitlines()[-1]
  assert line.endswith("no persistent-cache hits recorded): none recorded."), line
  assert "Brax" not in report.learning_summary([dict(r, task="walker_walk") for r in warm])


def test_throughput_table_lists_each_measurement():
  record = {"kind": "env_throughput", "task": "cheetah_run", "physics": "parity",
            "num_envs": 2048, "device": "gpu:X", "versions": {}, "time": "t", "sps": 1.5e5,
            "raw_sps": 2e5, "ratio_to_raw": 0.75,
            "settings": {"solver": {"iterations": 10, "ls_iterations": 10,
                                    "max_contact_points": 4}}}
  # A GPU record without the precision field predates the full-precision physics: TF32.
  table = report.throughput_table([record])
  assert ("| cheetah_run | parity | 10/10 cull 4 | 2048 | TF32 | 150k | 200k | 0.75 | - | - | - "
          "| - |") in table
  newer = dict(record, physics_matmul_precision="highest", step_sps=1.8e5,
               step_ratio_to_raw=0.9, time="u")
  table = report.throughput_table([record, newer])
  assert ("| cheetah_run | parity | 10/10 cull 4 | 2048 | float32 | 150k | 200k | 0.75 | 0.90 | "
          "- | - | - |") in table
  assert "TF32" not in table.split("\n", 2)[2]  # only the newest record of a row is shown


def test_parity_tables_are_per_device_and_precision():
  error = {"median": 1e-6, "p90": 2e-6, "max": 3e-6}
  base = {"kind": "parity", "task": "walker_walk", "physics": "fast", "time": "t",
          "settings": {"num_transitions": 64}, "qpos_error": error, "qvel_error": error,
          "obs_error": error, "reward_error": error}
  records = [dict(base, device="cpu:cpu x1"),
             dict(base, device="gpu:X", matmul_precision="default"),
             dict(base, device="gpu:X", matmul_precision="highest")]
  table = report.parity_table(records)
  assert table.count("| walker_walk | fast |") == 3
  assert "`gpu:X`, matmuls in TF32" in table and "`gpu:X`, matmuls in float32" in table
  assert "`cpu:cpu x1`, matmuls in float32" in table


def test_train_throughput_rows_differ_by_physics_precision_xla_flags_and_learner():
  """A measurement under another physics mode, other compiler flags, matmul precision or learner
  settings is a row of its own, the learner's departures from the paper named."""
  base = {"kind": "train_throughput", "task": "cheetah_run", "physics": "fast", "num_envs": 512,
          "device": "gpu:X", "versions": {}, "time": "t", "sps": 1.1e5, "env_sps": 2.8e5,
          "ratio_to_env": 0.41, "update_ms": 2.0, "peak_memory_bytes": None,
          "physics_matmul_precision": "highest",
          "xla_flags": "--xla_cpu_enable_concurrency_optimized_scheduler=false",
          "settings": {"updates_per_iteration": 128, "stagger_episodes": False}}
  graphs = dict(base, sps=1.0e5, time="u", xla_flags=base["xla_flags"]
                + " --xla_gpu_enable_command_buffer=WHILE")
  tf32 = dict(base, sps=1.2e5, time="v")
  del tf32["physics_matmul_precision"]
  bf16 = dict(base, sps=1.3e5, time="w", settings=dict(
      base["settings"], learner={"target_update_period": 200, "sampled_q_bfloat16": True}))
  bounded = dict(base, sps=0.9e5, time="x", physics="fast_bounded")
  table = report.train_throughput_table([base, graphs, tf32, bf16, bounded])
  assert "| 110k | 280k | 0.41 | 2.0 | - | - |" in table
  assert "| fast_bounded | float32 | 512 | 128 | - | lockstep | 90k |" in table
  assert "| 100k | 280k | 0.41 | 2.0 | - | `--xla_gpu_enable_command_buffer=WHILE` |" in table
  assert "| TF32 | 512 | 128 | - | lockstep | 120k |" in table
  assert "| float32 | 512 | 128 | sampled Q in bf16 | lockstep | 130k |" in table


def test_learning_rows_show_the_action_penalty():
  base = {"kind": "learning_curve", "task": "hopper_stand", "seed": 0, "num_envs": 256,
          "device": "gpu:X", "env_steps": 1e6, "wall_s": 60.0, "eval_return": 300.0,
          "physics_matmul_precision": "highest", "_file": "2026-11-23_learning_curve_x.jsonl",
          "settings": {"updates_per_iteration": 128, "replay_ratio": 32, "eval_episodes": 32,
                       "stagger_episodes": True,
                       "learner": {"mpo": {"epsilon": 0.1}}}}  # before the setting existed
  penalised = dict(base, _file="2026-11-23_learning_curve_y.jsonl", eval_return=900.0,
                   settings=dict(base["settings"], learner={"mpo": {
                       "action_penalty": True, "epsilon_penalty": 1e-3}}))
  off = dict(base, _file="2026-11-23_learning_curve_z.jsonl", settings=dict(
      base["settings"], learner={"mpo": {"action_penalty": False, "epsilon_penalty": 1e-3}}))
  table = report.learning_table([base, penalised, off])
  rows = [line for line in table.splitlines() if line.startswith("| hopper_stand")]
  assert len(rows) == 3
  assert sum("| staggered | 0.001 | 1.0M |" in row for row in rows) == 1
  assert sum("| staggered | - | 1.0M |" in row for row in rows) == 2
  assert "| staggered | 0.001 | 1.0M | 60 s | - | 900.0 | 900.0 | 60 s (1.0M) |" in table


def test_experts_table_judges_the_bar_on_the_evaluation_of_most_episodes():
  """Of a shipped expert's fresh evaluations the one of most episodes is shown and judged
  against 0.95x the paper's expert (reacher_easy: 925.87); stochastic ones are not used."""
  rows = report._shipped_experts(report.EXPERTS)
  meta = next(m for m, _ in rows if m["task"] == "reacher_easy")

  def evaluation(episodes, mean, time, **extra):
    return dict(kind="expert_eval", task="reacher_easy", policy_sha256=meta["sha256"],
                episodes=episodes, mean_return=mean, stderr_return=1.0, device="gpu:H200",
                time=time, **extra)

  def row(records):
    line, = [l for l in report.experts_table(records).splitlines() if "`reacher_easy.npz`" in l]
    return line

  few = evaluation(16, 990.0, "2026-11-23T02")
  many = evaluation(1000, 925.0, "2026-11-23T01")
  assert "990.0 +- 1.0 (16, gpu)" in row([few]) and "| met |" in row([few])
  line = row([few, many, evaluation(4000, 999.0, "2026-11-23T03", stochastic=True)])
  assert "925.0 +- 1.0 (1000, gpu)" in line and "below (925.9)" in line
  assert "926.0" in row([many, evaluation(1000, 926.0, "2026-11-23T04")])  # newest of a tie
  assert row([]).startswith(f"| reacher_easy | `reacher_easy.npz` | {meta['eval_return']:.1f} | "
                            "- | - | - | 974.6 | - |")
  # A run's final evaluation of the file (its mean action) is a fresh evaluation too; its
  # sampled-action one is not, nor one of another file.
  final = dict(kind="final_return", task="reacher_easy", policy="best", episodes=256,
               policy_sha256=meta["sha256"], final_return=931.0, final_return_std=32.0,
               device="gpu:NVIDIA H200 x1", time="2026-11-23T05")
  sampled = dict(final, policy="final_sampled", episodes=4096, final_return=900.0)
  other = dict(final, policy_sha256="ab" * 32, episodes=4096, final_return=900.0)
  line = row([few, final, sampled, other])
  assert "931.0 +- 2.0 (256, gpu)" in line and "| met |" in line, line
  assert "925.0 +- 1.0 (1000, gpu)" in row([few, final, many])  # (most episodes)


def test_sweep_table_keeps_errors_over_different_states_apart():
  """Errors measured over 64 and over 512 dm_control states go to columns of their own (the
  newest per setting and state set); rows run from most solver then line-search iterations."""
  def error(ls, max_error, states, time="1"):
    return {"kind": "solver_sweep", "task": "walker_walk", "measured": "error", "time": time,
            "settings": {"solver": {"iterations": 10, "ls_iterations": ls},
                         "num_transitions": states},
            "qvel_error": {"median": 1e-5, "p90": 3e-5, "max": max_error}}
  speed = {"kind": "solver_sweep", "task": "walker_walk", "measured": "speed", "time": "1",
           "device": "gpu:X", "raw_sps": 57_000, "speedup_over_parity": 3.71,
           "settings": {"solver": {"iterations": 10, "ls_iterations": 10}, "num_envs": 2048}}
  table = report.sweep_table([speed, error(10, 1e-3, 64), error(10, 2e-3, 512),
                              error(10, 9e-3, 512, time="0"), error(3, 4e-2, 512),
                              error(4, 1.5e-3, 512)])
  rows = [line for line in table.splitlines() if line.startswith("| walker_walk")]
  assert "| qvel error, 64 states | qvel error, 512 states |" in table
  assert rows == ["| walker_walk | 10/10 | 57k | 3.71 | 1e-05 / 3e-05 / 1e-03 | "
                  "1e-05 / 3e-05 / 2e-03 |",
                  "| walker_walk | 10/4 | - | - | - | 1e-05 / 3e-05 / 2e-03 |",
                  "| walker_walk | 10/3 | - | - | - | 1e-05 / 3e-05 / 4e-02 |"], rows


def test_sweep_table_takes_speed_ups_over_parity_not_over_a_runs_first_candidate():
  """A sweep run that started from 10/10 records its speed-ups over 10/10; the table's
  'x parity' divides by the parity record of the same device and size instead."""
  def speed(ls, sps, device="gpu:X", time="2", **extra):
    solver = {"iterations": 10, "ls_iterations": ls} if ls else {}
    return {"kind": "solver_sweep", "task": "walker_walk", "measured": "speed", "time": time,
            "device": device, "raw_sps": sps, "settings": {"solver": solver, "num_envs": 2048},
            **extra}
  parity = speed(None, 20_000, time="1", speedup_over_parity=1.0)
  rows = lambda records: [line for line in report.sweep_table(records).splitlines()
                          if line.startswith("| walker_walk")]
  newer = [speed(10, 60_000, speedup_over_first=1.0, first="10/10"),
           speed(4, 90_000, speedup_over_first=1.5, first="10/10")]
  assert rows([parity] + newer) == ["| walker_walk | 100/50 | 20k | 1.00 |",
                                    "| walker_walk | 10/10 | 60k | 3.00 |",
                                    "| walker_walk | 10/4 | 90k | 4.50 |"]
  other = [speed(4, 90_000, device="gpu:Y", speedup_over_first=1.5, first="10/10")]
  assert rows([parity] + other)[1] == "| walker_walk | 10/4 | 90k | - |"
  # The parity record of the row's device and size, even where another is newer.
  elsewhere = [speed(None, 10_000, device="gpu:Y", time="3", speedup_over_parity=1.0),
               dict(speed(None, 10_000, time="3", speedup_over_parity=1.0),
                    settings={"solver": {}, "num_envs": 64})]
  assert rows([parity, *elsewhere, *newer])[1:] == ["| walker_walk | 10/10 | 60k | 3.00 |",
                                                    "| walker_walk | 10/4 | 90k | 4.50 |"]


def test_packed_curves_are_read_with_their_run_and_unpacked_ones_are_named(tmp_path):
  """report.read_records reads a run's packed curve as rows of the run's file (`_file`);
  unpacked FORM curve rows are named (`--check` fails on them); scripts/pack_results.py packs
  them."""
  import pack_results as pack
  a, b = str(tmp_path / "a.jsonl"), str(tmp_path / "b.jsonl")
  for path in (a, b):
    writer = results.ResultWriter(path)
    writer.write(kind="learning_curve", method="form", settings={"x": 1})
    writer.write(kind="final_return", method="form", settings={"x": 1})
  results.pack_curve(a)
  records = report.read_records(str(tmp_path))
  assert sorted((r["_file"], r["_source"], r["kind"]) for r in records) == [
      ("a.jsonl", "a.curve.jsonl.gz", "learning_curve"), ("a.jsonl", "a.jsonl", "final_return"),
      ("b.jsonl", "b.jsonl", "final_return"), ("b.jsonl", "b.jsonl", "learning_curve")]
  assert report.unpacked_files(records) == ["b.jsonl"]
  assert pack.main([a, b]) == 0
  assert report.unpacked_files(report.read_records(str(tmp_path))) == []


def test_archived_demonstrators_leave_the_tree_and_keep_their_demonstrations_return(tmp_path):
  """scripts/archive_demonstrators.py removes a committed demonstrator from the folder and
  indexes it (checksum, demonstrations' mean return, commit); its restore command brings the
  same bytes back from git; the report still reads its return; a file that differs from the
  commit is refused, nothing removed."""
  import shutil

  import archive_demonstrators as archive
  folder = tmp_path / "benchmarks" / "demonstrators"
  folder.mkdir(parents=True)
  name = "walker_walk_expert_136e17.npz"
  shutil.copy(os.path.join(report.FORMER_DEMONSTRATORS, name), folder / name)
  shutil.copy(os.path.join(report.FORMER_DEMONSTRATORS, name), folder / "changed.npz")
  git = lambda *a: subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *a],
                                  cwd=tmp_path, capture_output=True, check=True)
  git("init", "-q")
  git("add", ".")
  git("commit", "-qm", "demonstrators")
  (folder / "changed.npz").write_bytes((folder / "changed.npz").read_bytes() + b"\0")
  original = (folder / name).read_bytes()
  assert archive.main(["changed.npz"], root=str(tmp_path)) == 2
  assert (folder / "changed.npz").exists() and not (folder / "archived.json").exists()
  assert archive.main([name, name], root=str(tmp_path)) == 0 and not (folder / name).exists()
  [entry] = archive.read_index(str(tmp_path))
  assert archive.main([name], root=str(tmp_path)) == 2  # (archived already)
  meta = report._demonstrator_metadata((report.FORMER_DEMONSTRATORS,))
  kept = next(m for m in meta if m["sha256"] == entry["sha256"])
  assert entry["demonstrations_mean_return"] == kept["demonstrations"]["expert"]["mean_return"]
  subprocess.run(entry["restore"], shell=True, cwd=tmp_path, check=True)
  assert (folder / name).read_bytes() == original
  returns = report._demonstration_returns((), archived=str(folder / "archived.json"))
  assert returns == {entry["sha256"]: entry["demonstrations_mean_return"]}
