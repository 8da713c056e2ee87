"""scripts/gpu_wheels.py: the wheels a GPU sitting carries, without what it never imports."""

import os
import subprocess
import zipfile

import pytest
from conftest import load_script


def test_slim_leaves_out_the_folders_and_their_record_lines_and_keeps_the_rest(tmp_path):
  gpu_wheels = load_script("gpu_wheels")
  source, target = tmp_path / "pkg-1.0-py3-none-any.whl", tmp_path / "slim.whl"
  members = {"pkg/__init__.py": b"x = 1\n", "pkg/big/data.bin": b"\0" * 100,
             "pkg/big/more/model.xml": b"<mujoco/>", "pkg/bigger.py": b"y = 2\n",
             "pkg-1.0.dist-info/RECORD": (b"pkg/__init__.py,sha256=a,6\npkg/big/data.bin,sha256=b,"
                                          b"100\npkg/big/more/model.xml,sha256=c,9\n"
                                          b"pkg/bigger.py,sha256=d,6\n"
                                          b"pkg-1.0.dist-info/RECORD,,\n")}
  with zipfile.ZipFile(source, "w") as z:
    for name, data in members.items():
      z.writestr(name, data)
  assert gpu_wheels.slim(str(source), str(target), ("pkg/big/",)) == (3, 2)
  with zipfile.ZipFile(target) as z:
    assert sorted(z.namelist()) == ["pkg-1.0.dist-info/RECORD", "pkg/__init__.py",
                                    "pkg/bigger.py"]
    assert z.read("pkg/__init__.py") == b"x = 1\n" and z.read("pkg/bigger.py") == b"y = 2\n"
    assert z.read("pkg-1.0.dist-info/RECORD") == (b"pkg/__init__.py,sha256=a,6\n"
                                                  b"pkg/bigger.py,sha256=d,6\n"
                                                  b"pkg-1.0.dist-info/RECORD,,\n")
  # Nothing to leave out: a copy of every member.
  assert gpu_wheels.slim(str(source), str(target), ()) == (5, 0)
  with zipfile.ZipFile(target) as z:
    assert {n: z.read(n) for n in z.namelist()} == members


def test_main_names_a_missing_wheel(tmp_path, capsys):
  gpu_wheels = load_script("gpu_wheels")
  assert gpu_wheels.main(["--source", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
  assert "wheels.sh" in capsys.readouterr().err


def test_the_tree_that_travels_to_the_gpu_leaves_room_for_a_checkpoint():
  """What a GPU call sends (tracked and untracked-not-ignored files: they all travel) plus the
  slim wheels must stay under the device's 64 MiB with room for a population's lean checkpoint
  carried in to resume: session 52's quadruped_run run of three members, slimmed to its
  checkpoint, config.json and progress.csv files, is 19.6 MiB. Packed curves keep the results
  small (scripts/pack_results.py); when this fails, slim the tree before the next sitting."""
  wheels_mib, checkpoint_mib = 9.8, 19.6  # (.whl-gpu: 10,175,805 bytes; the run: 20,495,033)
  root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                          cwd=root, capture_output=True)
  if listed.returncode != 0:
    pytest.skip("not a git checkout")
  paths = [os.path.join(root, p) for p in listed.stdout.decode().split("\0") if p]
  size = sum(os.path.getsize(p) for p in paths if os.path.isfile(p)) / 2**20
  limit = 64 - wheels_mib - checkpoint_mib
  assert size <= limit, (f"the tree that travels is {size:.2f} MiB, over {limit:.1f}: with the "
                         f"wheels it leaves less than {checkpoint_mib} MiB for a checkpoint")
