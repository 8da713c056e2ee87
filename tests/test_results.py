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


def test_compact_rows_name_an_earlier_row_and_read_back_whole(tmp_path):
  """A learning curve's rows after the first of each member leave out the settings, versions
  and flags they share with it; read_records gives every record whole, as written."""
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
  assert [r.get("same_as_line") for r in raw] == [None, None, 1, 2, 1, 2, None]
  assert all("versions" not in r and "device" in r for r in raw[2:6])
  assert results.read_records(path) == written
  # A member whose settings change (e.g. resumed with other ones) writes them again.
  written.append(writer.write(compact=True, kind="learning_curve", seed=0, env_steps=3,
                              settings={"seed": 0, "lr": 3e-4}))
  written.append(writer.write(compact=True, kind="learning_curve", seed=0, env_steps=4,
                              settings={"seed": 0, "lr": 3e-4}))
  assert [r.get("same_as_line") for r in _lines(path)[-2:]] == [None, 8]
  assert results.read_records(path) == written


def test_compact_rows_survive_other_writers_and_resumes(tmp_path):
  """Line numbers are the file's: another writer appending in between, or a new writer on the
  same file (a resumed run), keeps every reference right; a replaced file starts afresh."""
  path = str(tmp_path / "curve.jsonl")
  first, other = results.ResultWriter(path), results.ResultWriter(path)
  expected = [first.write(compact=True, kind="learning_curve", settings={"a": 1}),
              other.write(kind="benchmark", settings={"b": 2}),
              first.write(compact=True, kind="learning_curve", settings={"a": 1})]
  resumed = results.ResultWriter(path)
  expected += [resumed.write(compact=True, kind="learning_curve", settings={"a": 1}),
               resumed.write(compact=True, kind="learning_curve", settings={"a": 1})]
  assert [r.get("same_as_line") for r in _lines(path)] == [None, None, 1, None, 4]
  assert results.read_records(path) == expected
  os.remove(path)
  again = first.write(compact=True, kind="learning_curve", settings={"a": 1})
  assert "settings" in _lines(path)[0] and results.read_records(path) == [again]


def test_compact_records_inverts_read_records(tmp_path):
  """compact_records (for files written before compact rows) loses nothing."""
  records = [{"kind": "learning_curve", "seed": s, "env_steps": i, "settings": {"s": s},
              "versions": {"jax": "x"}} for i in range(3) for s in (0, 1)]
  records.append({"kind": "other", "value": 1})  # no shared fields: kept as it is
  compact = results.compact_records(records)
  assert [r.get("same_as_line") for r in compact] == [None, None, 1, 2, 1, 2, None]
  path = tmp_path / "c.jsonl"
  path.write_text("".join(json.dumps(r) + "\n" for r in compact))
  assert results.read_records(str(path)) == records


def test_broken_files_are_refused_naming_the_line(tmp_path):
  path = tmp_path / "bad.jsonl"
  for text, message in [('{"kind": "a", "settings": {}}\n{"kind": "b"', "line 2 is not JSON"),
                        ("[1]\n", "line 1 is not a result record"),
                        ('{"kind": "a", "same_as_line": 1}\n', "line 1 takes its settings"),
                        ('{"kind": "a"}\n{"kind": "b", "same_as_line": 1}\n',
                         "line 2 takes its settings from line 1"),
                        ('{"kind": "a", "settings": {}}\n\n{"kind": "b", "same_as_line": 2}\n',
                         "line 3 takes its settings from line 2")]:
    path.write_text(text)
    with pytest.raises(results.ResultFileError, match=message):
      results.read_records(str(path))
