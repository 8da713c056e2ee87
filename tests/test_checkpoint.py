"""Training checkpoints: round trips (also onto a 2-device mesh), pruning, atomicity and errors."""

from __future__ import annotations

import json
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_form.files import checkpoint
from mjx_form.files.checkpoint import CheckpointError
from mjx_form.mesh import batch_sharding, make_mesh, replicated

CONFIG = {"task": "walker_walk", "num_envs": 64, "total_steps": 1000, "mpo": {"eta": 0.1}}


class Opt(NamedTuple):
  mu: dict
  count: jax.Array


def make_state(seed=0):
  k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
  return {
      "params": {"w": jax.random.normal(k1, (3, 4)), "b": jnp.zeros(4)},
      "opt": Opt(mu={"w": jax.random.normal(k2, (3, 4))}, count=jnp.asarray(7, jnp.int32)),
      "done": jnp.array([True, False, True, False]),
      "steps": jnp.arange(8, dtype=jnp.int32),
      "lr": jnp.float32(3e-4),
      "key": jax.random.PRNGKey(seed + 42),
  }


def assert_same(restored, expected):
  assert jax.tree.structure(restored) == jax.tree.structure(expected)
  for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(expected)):
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_round_trip(tmp_path):
  state = make_state()
  path = checkpoint.save(tmp_path, 10, state, CONFIG)
  assert path == os.path.join(tmp_path, "step_10") and os.path.isdir(path)
  assert checkpoint.latest_step(tmp_path) == 10
  restored = checkpoint.restore(tmp_path, state, CONFIG)
  assert_same(restored, state)
  assert isinstance(restored["opt"], Opt) and restored["key"].dtype == jnp.uint32
  # an abstract target works too, and the restored key drives the same random stream
  abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), state)
  restored = checkpoint.restore(tmp_path, abstract, CONFIG, step=10)
  assert_same(restored, state)
  default = jax.sharding.SingleDeviceSharding(jax.devices()[0])
  assert all(x.sharding == default for x in jax.tree.leaves(restored))
  np.testing.assert_array_equal(jax.random.normal(restored["key"], (3,)),
                                jax.random.normal(state["key"], (3,)))
  info = checkpoint.read_info(tmp_path)
  assert info["step"] == 10 and info["config"] == json.loads(json.dumps(CONFIG))
  assert info["format"] == checkpoint.FORMAT and info["versions"]["jax"] == jax.__version__


def test_zero_size_leaves_come_back_as_arrays(tmp_path):
  """They are not stored (orbax cannot); an abstract target still gets arrays for them."""
  state = {"act": jnp.zeros((4, 0)), "x": jnp.ones(2)}
  checkpoint.save(tmp_path, 1, state, CONFIG)
  abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), state)
  for target in (state, abstract):
    restored = checkpoint.restore(tmp_path, target, CONFIG)
    assert isinstance(restored["act"], jax.Array) and restored["act"].shape == (4, 0)
    assert_same(restored, state)


def test_typed_prng_key(tmp_path):
  state = {"key": jax.random.key(3), "x": jnp.ones(2)}
  checkpoint.save(tmp_path, 1, state, CONFIG)
  restored = checkpoint.restore(tmp_path, state, CONFIG)
  assert jax.dtypes.issubdtype(restored["key"].dtype, jax.dtypes.prng_key)
  np.testing.assert_array_equal(jax.random.key_data(restored["key"]),
                                jax.random.key_data(state["key"]))


def test_restore_onto_mesh(tmp_path):
  assert jax.device_count() == 2
  mesh = make_mesh()
  state = make_state()
  # saved from one layout (the batch leaves sharded), restored onto another
  saved = dict(state, done=jax.device_put(state["done"], batch_sharding(mesh)),
               steps=jax.device_put(state["steps"], batch_sharding(mesh)))
  checkpoint.save(tmp_path, 5, saved, CONFIG)

  def sharding(path, x):
    name = jax.tree_util.keystr(path)
    return batch_sharding(mesh) if "steps" in name or "params']['b" in name else replicated(mesh)
  shardings = jax.tree_util.tree_map_with_path(sharding, state)
  target = jax.tree.map(lambda x, s: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=s),
                        state, shardings)
  restored = checkpoint.restore(tmp_path, target, CONFIG)
  assert_same(restored, state)
  for x, s in zip(jax.tree.leaves(restored), jax.tree.leaves(shardings)):
    assert x.sharding == s, (x.sharding, s)
  assert restored["steps"].addressable_shards[0].data.shape == (4,)
  assert restored["params"]["w"].sharding.is_fully_replicated


def test_latest_step_and_pruning(tmp_path):
  assert checkpoint.latest_step(tmp_path) is None
  assert checkpoint.latest_step(tmp_path / "absent") is None
  state = make_state()
  for step in (100, 200, 300, 400):
    checkpoint.save(tmp_path, step, state, CONFIG, keep=2)
    assert checkpoint.latest_step(tmp_path) == step
  assert sorted(os.listdir(tmp_path)) == ["step_300", "step_400"]
  assert_same(checkpoint.restore(tmp_path, state, CONFIG, step=300), state)
  with pytest.raises(CheckpointError, match=r"no checkpoint for step 100 \(it has steps \[300, 4"):
    checkpoint.restore(tmp_path, state, CONFIG, step=100)
  with pytest.raises(CheckpointError, match="already holds a checkpoint for step 400 >= 400"):
    checkpoint.save(tmp_path, 400, state, CONFIG)


def test_unfinished_checkpoint_is_ignored(tmp_path):
  state = make_state()
  checkpoint.save(tmp_path, 1, state, CONFIG)
  # what a process killed mid-save leaves: orbax's temporary directories, partly written
  for name in ("step_2.orbax-checkpoint-tmp", "step_3.orbax-checkpoint-tmp-1732000000"):
    os.makedirs(tmp_path / name / "state")
    (tmp_path / name / "state" / "_METADATA").write_text("{")
  assert checkpoint.latest_step(tmp_path) == 1
  assert_same(checkpoint.restore(tmp_path, state, CONFIG), state)
  with pytest.raises(CheckpointError, match="no checkpoint for step 3"):
    checkpoint.restore(tmp_path, state, CONFIG, step=3)
  # the next save of such a step replaces the leftovers
  checkpoint.save(tmp_path, 2, state, CONFIG)
  assert checkpoint.latest_step(tmp_path) == 2


def test_save_failing_midway_leaves_no_checkpoint(tmp_path, monkeypatch):
  state = make_state()
  checkpoint.save(tmp_path, 1, state, CONFIG)
  # the state is written, then the last item fails: the step stays an orbax temporary directory
  monkeypatch.setattr(checkpoint, "package_versions", lambda: {"jax": object()})
  with pytest.raises(TypeError, match="not JSON serializable"):
    checkpoint.save(tmp_path, 2, state, CONFIG)
  assert "step_2" not in os.listdir(tmp_path)
  assert any(name.startswith("step_2.orbax-checkpoint-tmp") for name in os.listdir(tmp_path))
  assert checkpoint.latest_step(tmp_path) == 1
  assert_same(checkpoint.restore(tmp_path, state, CONFIG), state)


def test_config_mismatch(tmp_path):
  state = make_state()
  checkpoint.save(tmp_path, 1, state, CONFIG)
  run = dict(CONFIG, task="cheetah_run", num_envs=128, total_steps=5000)
  with pytest.raises(CheckpointError) as e:
    checkpoint.restore(tmp_path, state, run, ignore=("total_steps",))
  assert str(e.value) == (f"checkpoint in {tmp_path} was written with num_envs=64, "
                          "task=walker_walk; this run has num_envs=128, task=cheetah_run")
  assert e.value.keys == ("num_envs", "task")  # what differs, for callers that explain it
  with pytest.raises(CheckpointError, match="total_steps=1000.*total_steps=5000"):
    checkpoint.restore(tmp_path, state, dict(CONFIG, total_steps=5000))
  # nested keys are named with dots; missing and added keys are reported as unset
  run = {k: v for k, v in CONFIG.items() if k != "num_envs"}
  run.update(mpo={"eta": 0.2}, seed=1)
  message = (r"with mpo\.eta=0\.1, num_envs=64, seed=\(unset\); "
             r"this run has mpo\.eta=0\.2, num_envs=\(unset\), seed=1$")
  with pytest.raises(CheckpointError, match=message):
    checkpoint.restore(tmp_path, state, run)


def test_ignored_keys(tmp_path):
  state = make_state()
  checkpoint.save(tmp_path, 1, state, CONFIG)
  run = dict(CONFIG, total_steps=5000, log_every=10, mpo={"eta": 0.5})
  restored = checkpoint.restore(tmp_path, state, run, ignore=("total_steps", "log_every", "mpo"))
  assert_same(restored, state)
  # tuples compare equal to the lists they are stored as
  checkpoint.save(tmp_path, 2, state, dict(CONFIG, hidden=(256, 256)))
  checkpoint.restore(tmp_path, state, dict(CONFIG, hidden=[256, 256]))


def test_settings_added_since_the_checkpoint(tmp_path):
  """A stored config without a newer setting resumes only where the run has the value that
  does what runs did before the setting existed."""
  state = make_state()
  checkpoint.save(tmp_path, 1, state, CONFIG)  # written before mpo.penalty existed
  added = {"mpo.penalty": False}
  run = dict(CONFIG, mpo={"eta": 0.1, "penalty": False})
  assert_same(checkpoint.restore(tmp_path, state, run, added=added), state)
  with pytest.raises(CheckpointError, match=r"mpo\.penalty=\(unset\); this run has mpo\.penalty=true"):
    checkpoint.restore(tmp_path, state, dict(CONFIG, mpo={"eta": 0.1, "penalty": True}),
                       added=added)
  with pytest.raises(CheckpointError, match=r"mpo\.penalty"):  # not declared as added
    checkpoint.restore(tmp_path, state, run)
  # A stored value always counts, whatever `added` says.
  checkpoint.save(tmp_path, 2, state, dict(CONFIG, mpo={"eta": 0.1, "penalty": True}))
  with pytest.raises(CheckpointError, match=r"mpo\.penalty=true; this run has mpo\.penalty=false"):
    checkpoint.restore(tmp_path, state, run, added=added)


def test_structure_mismatch(tmp_path):
  state = make_state()
  checkpoint.save(tmp_path, 1, state, CONFIG)
  bad = dict(state, params={"w": jnp.zeros((3, 5)), "b": jnp.zeros(4)})
  with pytest.raises(CheckpointError, match=r"step_1 does not match the target state: leaf "
                                            r"params/w is float32 \[3, 4\] in the checkpoint, "
                                            r"float32 \[3, 5\] in the target$"):
    checkpoint.restore(tmp_path, bad, CONFIG)
  bad = dict(state, steps=state["steps"].astype(jnp.float32))
  with pytest.raises(CheckpointError, match=r"leaf steps is int32 \[8\] in the checkpoint, float"):
    checkpoint.restore(tmp_path, bad, CONFIG)
  bad = dict(state, extra=jnp.zeros(2))
  with pytest.raises(CheckpointError, match="leaf extra is missing from the checkpoint"):
    checkpoint.restore(tmp_path, bad, CONFIG)
  bad = {k: v for k, v in state.items() if k != "lr"}
  with pytest.raises(CheckpointError, match="the checkpoint has a leaf lr the target lacks$"):
    checkpoint.restore(tmp_path, bad, CONFIG)
  bad["opt"] = Opt(mu={"v": jnp.zeros((3, 4))}, count=state["opt"].count)
  with pytest.raises(CheckpointError, match=r"leaf opt/mu/v is missing from the checkpoint "
                                            r"\(and 2 more differences\)$"):
    checkpoint.restore(tmp_path, bad, CONFIG)


def test_no_checkpoint(tmp_path):
  with pytest.raises(CheckpointError, match=f"no checkpoint in {tmp_path}$"):
    checkpoint.restore(tmp_path, make_state(), CONFIG)
  with pytest.raises(CheckpointError, match="no such directory"):
    checkpoint.restore(tmp_path / "absent", make_state(), CONFIG)
  (tmp_path / "notes.txt").write_text("not a checkpoint")
  with pytest.raises(CheckpointError, match="no checkpoint in"):
    checkpoint.restore(tmp_path, make_state(), CONFIG)


def test_bad_arguments(tmp_path):
  with pytest.raises(ValueError, match="not JSON-serialisable"):
    checkpoint.save(tmp_path, 1, make_state(), {"x": object()})
  with pytest.raises(ValueError, match="keep"):
    checkpoint.save(tmp_path, 1, make_state(), CONFIG, keep=0)
  assert checkpoint.latest_step(tmp_path) is None
