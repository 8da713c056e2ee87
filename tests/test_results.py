"""Result records' helpers."""

import conftest  # noqa: F401  (the session's persistent compilation cache)
import jax
import numpy as np

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
