"""Result records' helpers."""

import json
import os

import conftest  # noqa: F401  (the session's persistent compilation cache)
import jax
import numpy as np
import pytest

from mjx_form.files import results


def test_persistent_cache_hits_are_counted():
  """A program compiled once and asked for again by a new jit object comes from the cache."""
  previous = jax.config.jax_persistent_cache_min_compile_time_secs
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
  try:
    program = lambda: jax.jit(lambda x: jax.numpy.cos(x) * 2.5 + 1)  # a new function each time
    x = np.arange(7.0, dtype=np.float32)
    with results.count_persistent_cache_hits() as first:
      jax.block_until_ready(program()(x))  # compiled and written (or found)
    with results.count_persistent_cache_hits() as second:
      jax.block_until_ready(program()(x))
    assert first[0] <= 1 and second == [1]
  finally:
    jax.config.update("jax_persistent_cache_min_compile_time_secs", previous)


def test_records_carry_the_xla_flags(tmp_path, monkeypatch):
  """A speed measured under other compiler flags says so in its record."""
  monkeypatch.setenv("XLA_FLAGS", "--xla_gpu_enable_command_buffer=WHILE")
  record = results.ResultWriter(str(tmp_path / "r.jsonl")).write(kind="test")
  assert record["xla_flags"] == "--xla_gpu_enable_command_buffer=WHILE"
  monkeypatch.delenv("XLA_FLAGS")
  assert "xla_flags" not in results.ResultWriter(str(tmp_path / "s.jsonl")).write(kind="test")


def _lines(path):
  return [json.loads(line) for line in open(path)]


def _refs(path):
  """Each line's reference to its shared fields (None: written whole)."""
  return [r.get(results.REFERENCE) for r in _lines(path)]


def test_compact_rows_name_an_earlier_rows_fields_and_read_back_whole(tmp_path):
  """A learning curve's rows after the first of each member leave out the settings, versions
  and flags they share with it and name them by digest; read_records gives every record whole,
  as written."""
  path = str(tmp_path / "curve.jsonl")
  writer = results.ResultWriter(path)
  written = []
  for step in range(3):
    for seed in (0, 1):  # two members, interleaved as a population writes them
      written.append(writer.write(compact=True, kind="learning_curve", seed=seed,
                                  env_steps=step, settings={"seed": seed, "lr": 1e-4}))
  written.append(writer.write(kind="final_return", seed=0, settings={"seed": 0, "lr": 1e-4}))
  raw = _lines(path)
  assert ["settings" in r for r in raw] == [True, True, False, False, False, False, True]
  first, second = results.shared_digest(written[0]), results.shared_digest(written[1])
  assert first != second and _refs(path) == [None, None, first, second, first, second, None]
  assert all("versions" not in r and "device" in r for r in raw[2:6])
  assert results.read_records(path) == written
  # A member whose settings change (e.g. resumed with other ones) writes them again.
  for step in (3, 4):
    written.append(writer.write(compact=True, kind="learning_curve", seed=0, env_steps=step,
                                settings={"seed": 0, "lr": 3e-4}))
  assert _refs(path)[-2:] == [None, results.shared_digest(written[-1])]
  assert results.read_records(path) == written


def test_compact_rows_survive_other_writers_deleted_rows_and_resumes(tmp_path):
  """Another writer appending in between, a new writer on the same file (a resumed run) and
  rows deleted from the file leave every compact row its own fields; a row whose fields are
  gone is refused; a replaced file starts afresh."""
  path = str(tmp_path / "curve.jsonl")
  first, other = results.ResultWriter(path), results.ResultWriter(path)
  expected = [first.write(compact=True, kind="learning_curve", settings={"a": 1}),
              other.write(kind="benchmark", settings={"b": 2}),
              first.write(compact=True, kind="learning_curve", settings={"a": 1})]
  resumed = results.ResultWriter(path)
  expected += [resumed.write(compact=True, kind="learning_curve", settings={"a": 1}),
               resumed.write(compact=True, kind="learning_curve", settings={"a": 1})]
  a = results.shared_digest(expected[0])
  assert _refs(path) == [None, None, a, None, a]
  assert results.read_records(path) == expected
  lines = open(path).readlines()
  with open(path, "w") as f:  # the other writer's row deleted
    f.writelines(lines[:1] + lines[2:])
  assert results.read_records(path) == expected[:1] + expected[2:]
  with open(path, "w") as f:  # the first whole row deleted: its compact row refers to nothing
    f.writelines(lines[1:])
  with pytest.raises(results.ResultFileError, match=f"line 2 takes its settings .*{a}"):
    results.read_records(path)
  os.remove(path)
  again = first.write(compact=True, kind="learning_curve", settings={"a": 1})
  assert "settings" in _lines(path)[0] and results.read_records(path) == [again]


def test_compact_records_inverts_read_records(tmp_path):
  """compact_records (for files written before compact rows) loses nothing."""
  records = [{"kind": "learning_curve", "seed": s, "env_steps": i, "settings": {"s": s},
              "versions": {"jax": "x"}} for i in range(3) for s in (0, 1)]
  records.append({"kind": "other", "value": 1})  # no shared fields: kept as it is
  compact = results.compact_records(records)
  assert ["settings" in r for r in compact] == [True, True] + [False] * 4 + [False]
  assert [r.get(results.REFERENCE) for r in compact][2:4] == [
      results.shared_digest(records[0]), results.shared_digest(records[1])]
  path = tmp_path / "c.jsonl"
  path.write_text("".join(json.dumps(r) + "\n" for r in compact))
  assert results.read_records(str(path)) == records


def test_broken_files_are_refused_naming_the_line(tmp_path):
  path = tmp_path / "bad.jsonl"
  ref = results.REFERENCE
  for text, message in [('{"kind": "a", "settings": {}}\n{"kind": "b"', "line 2 is not JSON"),
                        ("[1]\n", "line 1 is not a result record"),
                        ('{"kind": "a", "%s": "0123"}\n' % ref, "line 1 takes its settings"),
                        ('{"kind": "a"}\n{"kind": "b", "%s": "0123"}\n' % ref,
                         "line 2 takes its settings from an earlier row with"),
                        ('{"kind": "b", "%s": "%s"}\n{"kind": "a", "settings": {}}\n'
                         % (ref, results.shared_digest({"settings": {}})),
                         "line 1 takes its settings")]:  # the whole row comes after it
    path.write_text(text)
    with pytest.raises(results.ResultFileError, match=message):
      results.read_records(str(path))


def test_pack_curve_moves_form_curves_to_a_gzip_companion_and_reads_back_the_same(tmp_path):
  """pack_curve: a FORM run's learning-curve rows go to <name>.curve.jsonl.gz (gzip, the same
  bytes for the same rows), every other row stays; run_records gives the file as written;
  packing again, or rows appended later, keep every row once; a file of curve rows alone is
  replaced by its packed curve; a file that is not .jsonl is refused."""
  path = str(tmp_path / "run.jsonl")
  settings = {"seed": 0, "lr": 1e-4}
  at = lambda second: f"2026-11-29T00:00:{second:02d}+00:00"
  written = [{"kind": "effect_model", "method": "form", "settings": settings, "time": at(0)},
             *[{"kind": "learning_curve", "method": "form", "env_steps": step,
                "settings": settings, "time": at(1 + step)} for step in range(3)],
             # (an expert's curve stays in the file)
             {"kind": "learning_curve", "method": "expert", "env_steps": 0,
              "settings": settings, "time": at(4)},
             {"kind": "final_return", "method": "form", "settings": settings, "time": at(5)}]
  with open(path, "w") as f:
    f.writelines(json.dumps(r) + "\n" for r in results.compact_records(written))
  writer = results.ResultWriter(path)
  assert results.pack_curve(path) == 3
  curve = tmp_path / "run.curve.jsonl.gz"
  assert curve.read_bytes()[:2] == b"\x1f\x8b" and results.curve_path(path) == str(curve)
  assert [r["kind"] for r in results.read_records(path)] == [
      "effect_model", "learning_curve", "final_return"]
  assert [r["env_steps"] for r in results.read_records(str(curve))] == [0, 1, 2]
  assert results.run_records(path) == written  # (whole: compact rows refilled in each file)
  first_bytes = curve.read_bytes()
  assert results.pack_curve(path) == 0 and curve.read_bytes() == first_bytes
  # The sitting's whole file copied in again: its curve rows are packed already, not twice.
  original = "".join(json.dumps(r) + "\n" for r in results.compact_records(written))
  with open(path, "w") as f:
    f.write(original)
  assert results.pack_curve(path) == 3 and curve.read_bytes() == first_bytes
  assert results.run_records(path) == written
  assert results.run_path(str(curve)) == path
  # Rows a resumed run appends later join the packed ones, after them.
  writer.write(compact=True, kind="learning_curve", method="form", env_steps=3,
               settings=settings)
  written = results.run_records(path)  # (the new row still in the file)
  assert results.pack_curve(path) == 1
  assert [r["env_steps"] for r in results.read_records(str(curve))] == [0, 1, 2, 3]
  assert sorted(map(json.dumps, results.run_records(path))) == sorted(map(json.dumps, written))
  # Rows of the same second: the curve's first (it was written before the final returns).
  tied = str(tmp_path / "tied.jsonl")
  with open(tied, "w") as f:
    f.writelines(json.dumps({**r, "time": at(0)}) + "\n" for r in written)
  results.pack_curve(tied)
  assert [(r["kind"], r["method"]) for r in results.run_records(tied)] == [
      ("learning_curve", "form")] * 4 + [("effect_model", "form"), ("learning_curve", "expert"),
                                         ("final_return", "form")]
  # A stopped run's file (curve rows only) is replaced by its packed curve.
  alone = str(tmp_path / "stopped.jsonl")
  results.ResultWriter(alone).write(kind="learning_curve", method="form", settings=settings)
  assert results.pack_curve(alone) == 1 and not os.path.exists(alone)
  assert [r["kind"] for r in results.run_records(alone)] == ["learning_curve"]
  with pytest.raises(FileNotFoundError, match="no such result file"):
    results.run_records(str(tmp_path / "none.jsonl"))
  with pytest.raises(results.ResultFileError, match="not a .jsonl result file"):
    results.pack_curve(str(curve))
