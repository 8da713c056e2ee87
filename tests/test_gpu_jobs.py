"""scripts/gpu_jobs.py: jobs files, GPUs handed out in order, records copied, runs packed."""

import io
import json
import os
import sys
import tarfile
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import gpu_jobs  # noqa: E402


def sitting(folder):
  for sub in ("logs", "res", "runs"):
    (folder / sub).mkdir(parents=True)
  return folder


def test_jobs_file_parsing_and_its_refusals():
  jobs = gpu_jobs.parse_jobs("# a sitting\n\nwr: python run.py --a 1\npair gpus=2 : echo $LEFT\n",
                             num_gpus=2)
  assert jobs == [{"name": "wr", "gpus": 1, "cmd": "python run.py --a 1"},
                  {"name": "pair", "gpus": 2, "cmd": "echo $LEFT"}]
  for text, words in [("no colon here", "line 1"), ("a: x\na: y", "used twice"),
                      ("big gpus=3: x", "asks for 3 GPUs"), ("# only a comment", "no job"),
                      ("bad name!: x", "line 1")]:
    with pytest.raises(gpu_jobs.JobsError, match=words):
      gpu_jobs.parse_jobs(text, num_gpus=2)


def test_jobs_wait_for_free_gpus_and_get_their_own(tmp_path):
  jobs = gpu_jobs.parse_jobs(
      "a: echo $CUDA_VISIBLE_DEVICES > $RES/a.txt; sleep 0.5\n"
      "b: echo $CUDA_VISIBLE_DEVICES > $RES/b.txt; sleep 1.5\n"
      "c gpus=2: echo $CUDA_VISIBLE_DEVICES $LEFT > $RES/c.txt\n"
      "d: echo d; exit 3\n", num_gpus=2)
  gpu_jobs.schedule(jobs, ["4", "6"], sitting(tmp_path), time.time() + 100, poll_s=0.05)
  res = tmp_path / "res"
  assert (res / "a.txt").read_text().split() == ["4"]
  assert (res / "b.txt").read_text().split() == ["6"]
  gpus, left = (res / "c.txt").read_text().split()
  assert gpus == "4,6" and 90 <= int(left) < 100  # c waited for both a and b
  status = json.loads((tmp_path / "status.json").read_text())
  assert status["c"]["started_s"] >= status["b"]["ended_s"]
  assert status["d"]["started_s"] >= status["c"]["ended_s"]
  assert [status[n]["rc"] for n in "abcd"] == [0, 0, 0, 3]
  assert (tmp_path / "logs" / "d.log").read_text().strip() == "d"
  assert (tmp_path / "all_done").exists()


def test_each_gpu_owns_an_equal_share_of_the_cores_and_its_jobs_run_on_it(tmp_path):
  alone = lambda c: [c]  # (a core per logical CPU)
  assert gpu_jobs.core_shares(["0", "1"], list(range(32)), alone) == {
      "0": list(range(16)), "1": list(range(16, 32))}
  assert gpu_jobs.core_shares(list("abc"), [0, 2, 4, 6, 8], alone) == {"a": [0], "b": [2, 4],
                                                                       "c": [6, 8]}
  assert gpu_jobs.core_shares(list("abc"), [5, 7], alone) == {g: [5, 7] for g in "abc"}
  # Hyperthreads stay with their core: CPUs i and i + 4 share one (as Linux often numbers them).
  pairs = lambda c: [c % 4, c % 4 + 4]
  assert gpu_jobs.core_shares(["0", "1"], list(range(8)), pairs) == {"0": [0, 1, 4, 5],
                                                                     "1": [2, 3, 6, 7]}
  assert gpu_jobs.core_shares(["0", "1"], [0, 4], pairs) == {"0": [0, 4], "1": [0, 4]}
  assert gpu_jobs.thread_siblings(0) and 0 in gpu_jobs.thread_siblings(0)
  cores = sorted(os.sched_getaffinity(0))
  shares = gpu_jobs.core_shares(["0", "1"], cores)
  where = "python3 -c 'import os; print(*sorted(os.sched_getaffinity(0)))' >"
  jobs = gpu_jobs.parse_jobs(f"a: {where} $RES/a.txt; sleep 0.5\nb: {where} $RES/b.txt\n"
                             f"c gpus=2: {where} $RES/c.txt\n", num_gpus=2)
  gpu_jobs.schedule(jobs, ["0", "1"], sitting(tmp_path), time.time() + 100, poll_s=0.05)
  seen = {n: [int(c) for c in (tmp_path / "res" / f"{n}.txt").read_text().split()] for n in "abc"}
  assert seen == {"a": shares["0"], "b": shares["1"], "c": sorted(set(shares["0"] + shares["1"]))}
  status = json.loads((tmp_path / "status.json").read_text())
  assert status["c"]["cores"] == len(seen["c"])


def test_a_job_that_would_start_after_the_deadline_is_skipped(tmp_path):
  jobs = gpu_jobs.parse_jobs("a: sleep 2\nb: touch $RES/b\n", num_gpus=1)
  gpu_jobs.schedule(jobs, ["0"], sitting(tmp_path), time.time() + 1.8, poll_s=0.05)
  status = json.loads((tmp_path / "status.json").read_text())
  assert status["a"]["rc"] == 0 and status["b"]["state"].startswith("skipped")
  assert not (tmp_path / "res" / "b").exists()


def test_poll_stop_makes_the_stop_file_the_jobs_watch_and_skips_waiting_jobs(tmp_path, capsys):
  """Each job is told the sitting's stop file (run.py's --stop_file default); `poll --stop`
  makes it: a running job that watches it ends, a waiting one is skipped."""
  jobs = tmp_path / "jobs.txt"
  jobs.write_text("a: echo $MJX_FORM_STOP_FILE > $RES/a.txt; "
                  "while [ ! -e $MJX_FORM_STOP_FILE ]; do sleep 0.05; done; echo saw it\n"
                  "b: touch $RES/b\n")
  folder = tmp_path / "sitting"
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(folder), "--gpus", "1"]) == 0
  deadline = time.time() + 30
  while not (folder / "res" / "a.txt").exists() and time.time() < deadline:
    time.sleep(0.05)
  assert gpu_jobs.main(["poll", "--dir", str(folder), "--wait", "0"]) == 0
  assert not (folder / "stop").exists() and "jobs still running" in capsys.readouterr().out
  assert gpu_jobs.main(["poll", "--dir", str(folder), "--wait", "30", "--stop"]) == 0
  printed = capsys.readouterr().out
  assert "asked the runs to stop" in printed and "every job has ended" in printed
  assert (folder / "res" / "a.txt").read_text().strip() == str(folder / "stop")
  status = json.loads((folder / "status.json").read_text())
  assert status["a"]["rc"] == 0 and status["b"]["state"] == "skipped (stopped)"
  assert not (folder / "res" / "b").exists()
  assert "saw it" in (folder / "logs" / "a.log").read_text()


def test_start_poll_copy_and_pack(tmp_path, capsys, monkeypatch):
  monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
  jobs = tmp_path / "jobs.txt"
  jobs.write_text("resume_checkpoint: R=$RUNS/resume_checkpoint && mkdir -p $R/checkpoints/step_7"
                  " && echo policy > $R/policy.npz && echo ckpt > $R/checkpoints/step_7/state && "
                  "echo '{\"kind\": \"x\"}' > $RES/one.jsonl"
                  " && echo 'step 1' && echo 'UserWarning: noise' && echo 'step 2'\n")
  folder, out = tmp_path / "sitting", tmp_path / "out"
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(folder), "--gpus", "1"]) == 0
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(folder), "--gpus", "1"]) == 2
  assert "already holds a sitting" in capsys.readouterr().err
  # A folder with an earlier sitting's logs but no status.json (seen on a reused GPU host,
  # 2026-11-29): its records would be packed with this sitting's.
  (tmp_path / "used" / "logs").mkdir(parents=True)
  (tmp_path / "used" / "logs" / "old.log").write_text("old")
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(tmp_path / "used"), "--gpus", "1"]) == 2
  assert "is not empty (logs); pick another --dir" in capsys.readouterr().err
  assert gpu_jobs.main(["poll", "--dir", str(folder), "--wait", "60", "--out", str(out)]) == 0
  printed = capsys.readouterr().out
  assert "every job has ended" in printed and "step 2" in printed and "noise" not in printed
  with tarfile.open(out / "records.tgz") as tar:
    assert json.loads(tar.extractfile("res/one.jsonl").read()) == {"kind": "x"}
    assert json.loads(tar.extractfile("status.json").read())["resume_checkpoint"]["rc"] == 0
    assert "logs/resume_checkpoint.log" in tar.getnames()
  data = b"".join(p.read_bytes() for p in sorted(out.glob("runs.tgz.part*")))
  with tarfile.open(fileobj=io.BytesIO(data)) as tar:
    names = tar.getnames()
  assert names == ["runs/resume_checkpoint/policy.npz"]  # the checkpoints folder left out
  assert sorted(p.name for p in out.iterdir()) == ["records.tgz", "runs.tgz.part00"]


def test_start_hands_out_an_inherited_cuda_visible_devices(tmp_path, capsys, monkeypatch):
  monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")
  jobs = tmp_path / "jobs.txt"
  jobs.write_text("a: echo $CUDA_VISIBLE_DEVICES > $RES/a\n")
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(tmp_path / "s1"), "--gpus", "3"]) == 2
  assert "this machine has 2 GPU(s) (3,5)" in capsys.readouterr().err
  assert not (tmp_path / "s1").exists()
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(tmp_path / "s2"), "--gpus", "1"]) == 0
  assert gpu_jobs.main(["poll", "--dir", str(tmp_path / "s2"), "--wait", "60"]) == 0
  assert (tmp_path / "s2" / "res" / "a").read_text().strip() == "3"  # the first of those given


def test_poll_says_when_the_scheduler_died_and_refuses_no_sitting(tmp_path, capsys):
  folder = sitting(tmp_path / "s")
  gpu_jobs.write_status(folder, {"a": {"state": "running"}})
  (folder / "scheduler.pid").write_text("999999999")
  assert gpu_jobs.main(["poll", "--dir", str(folder), "--lines", "0"]) == 0
  assert "scheduler is not running" in capsys.readouterr().out
  assert gpu_jobs.main(["poll", "--dir", str(tmp_path / "none")]) == 2
  assert "no status.json" in capsys.readouterr().err


def test_pack_splits_into_parts_that_join_again(tmp_path, monkeypatch):
  sitting(tmp_path)
  (tmp_path / "runs" / "big.npz").write_bytes(os.urandom(5000))
  monkeypatch.setattr(gpu_jobs, "PART_BYTES", 1000)
  out = tmp_path / "out"
  out.mkdir()
  parts = gpu_jobs.pack(tmp_path, out)
  assert len(parts) >= 5
  with tarfile.open(fileobj=io.BytesIO(b"".join(p.read_bytes() for p in parts))) as tar:
    assert tar.extractfile("runs/big.npz").read() == (tmp_path / "runs" / "big.npz").read_bytes()
  monkeypatch.setattr(gpu_jobs, "PACK_LIMIT", 3000)  # the runs alone pass it
  with pytest.raises(gpu_jobs.JobsError, match="not packed"):
    gpu_jobs.pack(tmp_path, out)


def _packed(tmp_path, **kwargs) -> set[str]:
  """The files gpu_jobs.pack packs of the sitting folder tmp_path, into a fresh out folder."""
  out = tmp_path / f"out{len(list(tmp_path.glob('out*')))}"
  out.mkdir()
  data = b"".join(p.read_bytes() for p in gpu_jobs.pack(tmp_path, out, **kwargs))
  with tarfile.open(fileobj=io.BytesIO(data)) as tar:
    return {n for n in tar.getnames() if tar.getmember(n).isfile()}


def test_pack_keeps_only_each_runs_newest_checkpoint_and_only_if_it_fits(tmp_path, monkeypatch,
                                                                        capsys):
  sitting(tmp_path)
  for step in ("step_5", "step_10", "step_10.orbax-checkpoint-tmp-3"):
    state = tmp_path / "runs" / "wr" / "checkpoints" / step / "state"
    state.mkdir(parents=True)
    (state / "data").write_bytes(os.urandom(3000))
  (tmp_path / "runs" / "wr" / "policy.npz").write_text("policy")
  (tmp_path / "runs" / "other").mkdir()
  (tmp_path / "runs" / "other" / "checkpoints").write_text("a file, not a folder")

  assert _packed(tmp_path) == {"runs/wr/policy.npz"}
  assert _packed(tmp_path, checkpoints=True) == {"runs/wr/policy.npz",
                                      "runs/wr/checkpoints/step_10/state/data"}
  monkeypatch.setattr(gpu_jobs, "PACK_LIMIT", 2000)
  assert _packed(tmp_path, checkpoints=True) == {"runs/wr/policy.npz"}
  assert "left out runs/wr/checkpoints/step_10" in capsys.readouterr().out


def test_pack_leaves_tensorboard_logs_out_before_checkpoints(tmp_path, monkeypatch, capsys):
  """A run's `tb` folder (what progress.csv holds too) comes after every newest checkpoint:
  packed where there is room, left out (named) where a checkpoint would not fit with it."""
  sitting(tmp_path)
  run = tmp_path / "runs" / "hop"
  (run / "checkpoints" / "step_7").mkdir(parents=True)
  (run / "checkpoints" / "step_7" / "data").write_bytes(os.urandom(3000))
  (run / "seed0" / "tb").mkdir(parents=True)
  (run / "seed0" / "tb" / "events").write_bytes(os.urandom(2000))
  (run / "seed0" / "progress.csv").write_text("step\n1\n")

  everything = {"runs/hop/seed0/progress.csv", "runs/hop/seed0/tb/events",
                "runs/hop/checkpoints/step_7/data"}
  assert _packed(tmp_path, checkpoints=True) == everything
  assert _packed(tmp_path) == everything - {"runs/hop/checkpoints/step_7/data"}
  monkeypatch.setattr(gpu_jobs, "PACK_LIMIT", 4000)  # the checkpoint fits, not with the logs
  assert _packed(tmp_path, checkpoints=True) == everything - {"runs/hop/seed0/tb/events"}
  assert "left out runs/hop/seed0/tb (0 MiB)" in capsys.readouterr().out
  monkeypatch.setattr(gpu_jobs, "PACK_LIMIT", 2500)  # the logs fit where the checkpoint does not
  assert (_packed(tmp_path, checkpoints=True)
          == everything - {"runs/hop/checkpoints/step_7/data"})


def test_check_parses_run_jobs_as_run_does_and_names_a_bad_one(tmp_path, capsys):
  """`check` prints the settings a run.py job would train with (the task's recipe, the flags,
  $LEFT filled in), lists other commands unchecked, and names a job whose flags run.py
  refuses."""
  jobs = tmp_path / "jobs.txt"
  jobs.write_text(
      "# a comment\n"
      "rx: python scripts/run.py --task reacher_hard --method expert --seeds 0,1 "
      "--grid target_update_period=25,100 --num_envs 512 --updates_per_iteration 256 "
      "--max_seconds $LEFT --results $RES/rx.jsonl --run_dir $RUNS/rx\n"
      "fx: python scripts/run.py --task reacher_hard --method form --train_demonstrator "
      "--effect_l2 1 --demonstrator_seed 3\n"
      "fc: python scripts/run.py --task cheetah_run --method form\n"
      "fl: python scripts/run.py --task reacher_hard --method form --effect_l2 1 "
      "--no-sampled_q_bfloat16\n"
      "fw: python scripts/run.py --task walker_run --method form\n"
      "fd: python scripts/run.py --task reacher_hard --method form --no-turn_invariant "
      "--demonstrator benchmarks/demonstrators/reacher_hard_plain.npz\n"
      "fe: python scripts/run.py --task reacher_hard --method form --demonstrator "
      "tasks/demonstrators/reacher_hard.npz --demonstrator "
      "benchmarks/demonstrators/reacher_hard_expert_64be96_200k_ee291e.npz\n"
      "fm: python scripts/run.py --task reacher_hard --method form --demonstrator "
      "tasks/demonstrators/reacher_hard.npz --demonstrator elsewhere/d.npz\n"
      "fp: python scripts/run.py --task reacher_hard --method form --seeds 0,1 "
      "--member_demonstrators --demonstrator tasks/demonstrators/reacher_hard.npz "
      "--demonstrator benchmarks/demonstrators/reacher_hard_expert_64be96_200k_ee291e.npz\n"
      "ft: python scripts/run.py --task reacher_hard --method form --seeds 0,1,2 "
      "--member_demonstrators --train_demonstrator --demonstrator_seed 4\n"
      "fn: python scripts/run.py --task reacher_hard --method form --demonstrator "
      "tasks/demonstrators/reacher_hard.npz --demonstrator "
      "benchmarks/demonstrators/reacher_hard_expert_64be96_200k_ee291e.npz "
      "--ensemble_log_pd mean\n"
      "fg: python scripts/run.py --task reacher_hard --method form --demonstrator "
      "tasks/demonstrators/reacher_hard.npz --demonstrator "
      "benchmarks/demonstrators/reacher_hard_expert_64be96_200k_ee291e.npz "
      "--grid ensemble_log_pd=mixture,mean\n"
      "ls: ls -la $RES\n"
      "rr: cp -r runs/rx $RUNS/rx && python scripts/run.py --task reacher_hard --method expert "
      "--sampled_q_float32_head --run_dir $RUNS/rx --resume\n"
      "rl: python scripts/run.py --task reacher_hard --method expert && ls $RES\n"
      "gg: python scripts/run.py --task walker_walk --method gaifo_gp --gradient_penalty 5 "
      "--discriminator_frames 2\n"
      "ga: python scripts/run.py --task walker_walk --method gaifo --reward_scale standardised\n"
      "gv: python scripts/run.py --task walker_walk --method vaifo_gp --kl_bound 0.5\n"
      "bl: python scripts/run.py --task walker_walk --method bc --cloning_loss likelihood\n"
      "bo: python scripts/run.py --task walker_walk --method bco\n")
  assert gpu_jobs.main(["check", str(jobs), "--deadline", "900"]) == 0
  out = [line for line in capsys.readouterr().out.splitlines()  # (not MuJoCo's import notes)
         if line.startswith(("rx:", "fx:", "fc:", "fl:", "fw:", "fd:", "fe:", "fm:", "fp:",
                             "ft:", "fn:", "fg:", "ls:", "rr:", "rl:", "gg:", "ga:", "gv:",
                             "bl:", "bo:"))]
  assert len(out) == 20 and out[0].startswith(
      "rx: reacher_hard expert, seeds 0,1; grid target_update_period=25,100")
  for part in ("512 envs x 256 updates (replay ratio 32)", "T 25", "action penalty True",
               "mean fitted to clipped actions False",
               "average policy decay 0,",
               "max seconds 900.0"):  # reacher_hard's recipe, the flags, $LEFT
    assert part in out[0], part
  # FORM jobs: their effect models' settings (a flag's, else the task's) and where the
  # demonstrator comes from, as run.py decides it
  assert "effect models" not in out[0], out
  assert ("effect models beta_ar 1, L2 1, width 256, turn-invariant; demonstrator trained "
          "(--train_demonstrator), seed 3") in out[1], out
  assert "effect models beta_ar 0.01, L2 1, width 256; demonstrator shipped" in out[2], out
  assert "L2 1, width 256, turn-invariant; demonstrator trained (the shipped one has other " \
         "settings), seed 0" in out[3], out
  # (no walker_run expert either)
  assert "; demonstrator trained (none shipped), seed 0" in out[4], out
  assert ("L2 0.1, width 256; demonstrator given, benchmarks/demonstrators/reacher_hard_plain"
          ".npz") in out[5], out  # its own settings: not turn-invariant
  assert ("turn-invariant; demonstrator given, tasks/demonstrators/reacher_hard.npz + "
          "benchmarks/demonstrators/reacher_hard_expert_64be96_200k_ee291e.npz, their "
          "mixture;") in out[6], out
  assert ("demonstrator given, tasks/demonstrators/reacher_hard.npz + elsewhere/d.npz (not all "
          "here to check)") in out[7], out
  assert ("turn-invariant; demonstrator one per member, tasks/demonstrators/reacher_hard.npz, "
          "benchmarks/demonstrators/reacher_hard_expert_64be96_200k_ee291e.npz") in out[8], out
  assert ("demonstrator trained (--train_demonstrator), one draw per member, seeds 4-6"
          in out[9]), out
  assert ("reacher_hard_expert_64be96_200k_ee291e.npz, the mean of their log pD;"
          in out[10]), out
  assert ("reacher_hard_expert_64be96_200k_ee291e.npz, as each member's --grid ensemble_log_pd "
          "says;" in out[11]), out
  assert out[12] == "ls: not a run.py command, not checked: ls -la $RES"
  assert out[13].startswith("rr: reacher_hard expert, seeds 0;")  # (run.py, after the copy)
  # the sampled Q's precision: the recipe's bf16, float32 by flag, bf16 with the float32 head
  assert "sampled Q bf16, " in out[0] and "sampled Q float32, " in out[3], out
  assert "sampled Q bf16 (float32 head), " in out[13], out
  assert out[14].startswith("rl: not a run.py command, not checked:")  # (run.py not last)
  # GAIfO jobs: the discriminator's settings (gaifo_gp's penalty 10 unless given; raw reward)
  assert out[15].startswith("gg: walker_walk gaifo_gp, seeds 0; discriminator: 2 frame(s), "
                            "gradient penalty 5, reward raw;"), out
  assert out[16].startswith("ga: walker_walk gaifo, seeds 0; discriminator: 1 frame(s), "
                            "gradient penalty 0, reward standardised;"), out
  assert out[17].startswith("gv: walker_walk vaifo_gp, seeds 0; discriminator: 1 frame(s), "
                            "gradient penalty 10, bottleneck KL <= 0.5, reward raw;"), out
  # BC and BCO: how the policy is fitted (the flag's, else the default)
  assert out[18].startswith("bl: walker_walk bc, seeds 0; cloning loss likelihood;"), out
  assert out[19].startswith("bo: walker_walk bco, seeds 0; cloning loss squared;"), out
  for bad, said in (("--task walker_walk --method form --turn_invariant", "unbounded"),
                    ("--task reacher_easy --method form --demonstrator "
                     "tasks/demonstrators/reacher_hard.npz", "reacher_hard"),
                    ("--task reacher_hard --method form --angle_increments --demonstrator "
                     "tasks/demonstrators/reacher_hard.npz", "angle_increments"),
                    ("--task reacher_hard --method form --no-turn_invariant --demonstrator "
                     "benchmarks/demonstrators/reacher_hard_plain.npz --demonstrator "
                     "tasks/demonstrators/reacher_hard.npz", "turn-invariance period"),
                    # (run.py's pipeline refuses it only once JAX has started on the GPU)
                    ("--task walker_run --method form --demo_episodes 0",
                     "--demo_episodes 0 skips the check of a ready demonstrator; this job's "
                     "would be trained (none shipped)")):
    jobs.write_text(f"bad: python scripts/run.py {bad}\n")
    assert gpu_jobs.main(["check", str(jobs)]) == 2
    err = capsys.readouterr().err
    assert "job 'bad'" in err and "run.py would refuse it" in err and said in err, err
  jobs.write_text("bad: python scripts/run.py --task reacher_hard --method form "
                  "--train_demonstrator --demonstrator tasks/demonstrators/reacher_hard.npz\n")
  assert gpu_jobs.main(["check", str(jobs)]) == 2
  err = capsys.readouterr().err
  assert "job 'bad'" in err and "--train_demonstrator exclude each other" in err, err
  jobs.write_text("bad: python scripts/run.py --task reacher_hard --updates_per_iteraton 64\n")
  assert gpu_jobs.main(["check", str(jobs)]) == 2
  err = capsys.readouterr().err
  assert "job 'bad'" in err and "unrecognized arguments: --updates_per_iteraton 64" in err


def test_pack_can_take_only_some_jobs_runs(tmp_path):
  """--runs: a pack of the named jobs' run directories only (a last call bringing back one
  run's checkpoint where the whole would not fit); an unknown name is refused."""
  sitting(tmp_path)
  for name in ("qr", "rh"):
    run = tmp_path / "runs" / name
    (run / "checkpoints" / "step_3").mkdir(parents=True)
    (run / "checkpoints" / "step_3" / "data").write_bytes(os.urandom(100))
    (run / "seed0").mkdir()
    (run / "seed0" / "policy.npz").write_text("policy")
  assert _packed(tmp_path, checkpoints=True, jobs=("qr",)) == {
      "runs/qr/seed0/policy.npz", "runs/qr/checkpoints/step_3/data"}
  assert _packed(tmp_path, jobs=("rh",)) == {"runs/rh/seed0/policy.npz"}
  assert len(_packed(tmp_path, checkpoints=True)) == 4
  with pytest.raises(gpu_jobs.JobsError, match="no run directory for xx"):
    gpu_jobs.pack(tmp_path, tmp_path, jobs=("qr", "xx"))
