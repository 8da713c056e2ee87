"""scripts/gpu_jobs.py: jobs files, GPUs handed out in order, records copied, runs packed."""

import io
import json
import sys
import tarfile
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import gpu_jobs  # noqa: E402


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
  for sub in ("logs", "res", "runs"):
    (tmp_path / sub).mkdir()
  jobs = gpu_jobs.parse_jobs(
      "a: echo $CUDA_VISIBLE_DEVICES > $RES/a.txt; sleep 0.5\n"
      "b: echo $CUDA_VISIBLE_DEVICES > $RES/b.txt; sleep 1.5\n"
      "c gpus=2: echo $CUDA_VISIBLE_DEVICES $LEFT > $RES/c.txt\n"
      "d: echo d; exit 3\n", num_gpus=2)
  gpu_jobs.schedule(jobs, 2, tmp_path, deadline_s=100, poll_s=0.05)
  res = tmp_path / "res"
  assert (res / "a.txt").read_text().split() == ["0"]
  assert (res / "b.txt").read_text().split() == ["1"]
  gpus, left = (res / "c.txt").read_text().split()
  assert gpus == "0,1" and 90 <= int(left) < 100  # c waited for both a and b
  status = json.loads((tmp_path / "status.json").read_text())
  assert status["c"]["started_s"] >= status["b"]["ended_s"]
  assert status["d"]["started_s"] >= status["c"]["ended_s"]
  assert [status[n]["rc"] for n in "abcd"] == [0, 0, 0, 3]
  assert (tmp_path / "logs" / "d.log").read_text().strip() == "d"
  assert (tmp_path / "all_done").exists()


def test_start_poll_copy_and_pack(tmp_path, capsys):
  jobs = tmp_path / "jobs.txt"
  jobs.write_text("one: mkdir -p $RUNS/one && echo policy > $RUNS/one/policy.npz && "
                  "echo ckpt > $RUNS/one/checkpoint_7 && echo '{\"kind\": \"x\"}' > $RES/one.jsonl"
                  " && echo 'step 1' && echo 'UserWarning: noise' && echo 'step 2'\n")
  folder, out = tmp_path / "sitting", tmp_path / "out"
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(folder), "--gpus", "1"]) == 0
  assert gpu_jobs.main(["start", str(jobs), "--dir", str(folder), "--gpus", "1"]) == 2
  assert "already holds a sitting" in capsys.readouterr().err
  assert gpu_jobs.main(["poll", "--dir", str(folder), "--wait", "60", "--out", str(out)]) == 0
  printed = capsys.readouterr().out
  assert "every job has ended" in printed and "step 2" in printed and "noise" not in printed
  with tarfile.open(out / "records.tgz") as tar:
    assert json.loads(tar.extractfile("res/one.jsonl").read()) == {"kind": "x"}
    assert json.loads(tar.extractfile("status.json").read())["one"]["rc"] == 0
    assert "logs/one.log" in tar.getnames()
  data = b"".join(p.read_bytes() for p in sorted(out.glob("runs.tgz.part*")))
  with tarfile.open(fileobj=io.BytesIO(data)) as tar:
    names = tar.getnames()
  assert "runs/one/policy.npz" in names and not any("checkpoint" in n for n in names)
  assert len(list(out.iterdir())) == 2  # records.tgz and one part: the device's limit is 8


def test_poll_of_no_sitting_is_an_error(tmp_path, capsys):
  assert gpu_jobs.main(["poll", "--dir", str(tmp_path / "none")]) == 2
  assert "no status.json" in capsys.readouterr().err


def test_pack_splits_into_parts_that_join_again(tmp_path, monkeypatch):
  for sub in ("logs", "res", "runs"):
    (tmp_path / sub).mkdir()
  (tmp_path / "runs" / "big.npz").write_bytes(__import__("os").urandom(5000))
  monkeypatch.setattr(gpu_jobs, "PART_BYTES", 1000)
  out = tmp_path / "out"
  out.mkdir()
  parts = gpu_jobs.pack(tmp_path, out)
  assert len(parts) >= 5 and all(p.stat().st_size <= 1000 for p in parts)
  with tarfile.open(fileobj=io.BytesIO(b"".join(p.read_bytes() for p in parts))) as tar:
    assert tar.extractfile("runs/big.npz").read() == (tmp_path / "runs" / "big.npz").read_bytes()


def test_pack_keeps_only_each_runs_newest_checkpoint_and_only_if_it_fits(tmp_path, monkeypatch,
                                                                        capsys):
  for sub in ("logs", "res", "runs"):
    (tmp_path / sub).mkdir()
  for step in ("step_5", "step_10", "step_10.orbax-checkpoint-tmp-3"):
    state = tmp_path / "runs" / "wr" / "checkpoints" / step / "state"
    state.mkdir(parents=True)
    (state / "data").write_bytes(__import__("os").urandom(3000))
  (tmp_path / "runs" / "wr" / "policy.npz").write_text("policy")

  def packed(**kwargs):
    out = tmp_path / f"out{len(list(tmp_path.glob('out*')))}"
    out.mkdir()
    data = b"".join(p.read_bytes() for p in gpu_jobs.pack(tmp_path, out, **kwargs))
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
      return {n for n in tar.getnames() if tar.getmember(n).isfile()}

  assert packed() == {"runs/wr/policy.npz"}
  assert packed(checkpoints=True) == {"runs/wr/policy.npz",
                                      "runs/wr/checkpoints/step_10/state/data"}
  monkeypatch.setattr(gpu_jobs, "PACK_LIMIT", 2000)
  assert packed(checkpoints=True) == {"runs/wr/policy.npz"}
  assert "left out runs/wr/checkpoints/step_10" in capsys.readouterr().out
