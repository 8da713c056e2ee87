"""scripts/gpu_wheels.py: the wheels a GPU sitting carries, without what it never imports."""

import zipfile

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
