"""Policy files: round trip, atomic no-clobber writes, and the validation errors."""

from __future__ import annotations

import json
import os

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_form.files import policy_io
from mjx_form.files.policy_io import PolicyFileError

D, A = 6, 2
LAYOUT = {"orientations": 4, "height": 1, "velocity": 1}


class Policy(nn.Module):
  @nn.compact
  def __call__(self, x):
    return nn.Dense(A)(nn.tanh(nn.Dense(8)(x)))


def tree():
  variables = Policy().init(jax.random.PRNGKey(0), jnp.zeros((1, D)))
  return {**variables, "normalizer": {"mean": np.arange(D, dtype=np.float64),
                                      "var": np.ones(D, np.float32),
                                      "count": np.int32(12)}}


def metadata(**changes):
  meta = {"task": "walker_walk", "observation_layout": LAYOUT, "observation_size": D,
          "action_size": A, "network": {"hidden": [8], "activation": "tanh"},
          "training_steps": 1_000_000, "return": 950.5}
  meta.update(changes)
  return meta


def test_round_trip(tmp_path):
  path = tmp_path / "walker.npz"
  params = tree()
  assert policy_io.save_policy(path, params, metadata()) == os.fspath(path)
  with np.load(path, allow_pickle=False) as npz:
    assert sorted(npz.files) == ["metadata", "normalizer/count", "normalizer/mean",
                                 "normalizer/var", "params/Dense_0/bias", "params/Dense_0/kernel",
                                 "params/Dense_1/bias", "params/Dense_1/kernel"]
  loaded, meta = policy_io.load_policy(path, task="walker_walk", observation_size=D,
                                       action_size=A, observation_layout=LAYOUT)
  assert jax.tree.structure(loaded) == jax.tree.structure(jax.tree.map(np.asarray, params))
  for a, b in zip(jax.tree.leaves(loaded), jax.tree.leaves(params)):
    assert isinstance(a, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(a, b)
  assert loaded["normalizer"]["mean"].dtype == np.float64
  assert loaded["params"]["Dense_0"]["kernel"].dtype == np.float32
  expected = json.loads(json.dumps(metadata(observation_layout=list(map(list, LAYOUT.items())))))
  assert {k: v for k, v in meta.items() if k not in ("format", "version", "sha256")} == expected
  assert meta["format"] == policy_io.FORMAT and meta["version"] == policy_io.VERSION
  assert meta["sha256"] == policy_io.checksum(
      {"/".join(str(k.key) for k in p): np.asarray(x)
       for p, x in jax.tree_util.tree_flatten_with_path(params)[0]})
  # the loaded params drive the network
  x = jnp.ones((1, D))
  np.testing.assert_array_equal(Policy().apply({"params": loaded["params"]}, x),
                                Policy().apply({"params": params["params"]}, x))
  assert os.path.getsize(path) < 4096 and not [f for f in os.listdir(tmp_path) if ".tmp" in f]


def test_overwrite_refused(tmp_path):
  path = tmp_path / "p.npz"
  policy_io.save_policy(path, tree(), metadata())
  before = path.read_bytes()
  with pytest.raises(FileExistsError, match="overwrite=True"):
    policy_io.save_policy(path, tree(), metadata(task="cheetah_run"))
  assert path.read_bytes() == before
  policy_io.save_policy(path, tree(), metadata(task="cheetah_run"), overwrite=True)
  assert policy_io.load_policy(path)[1]["task"] == "cheetah_run"
  assert os.listdir(tmp_path) == ["p.npz"]


def test_checksum_mismatch(tmp_path):
  path = tmp_path / "p.npz"
  policy_io.save_policy(path, tree(), metadata())
  with np.load(path, allow_pickle=False) as npz:
    entries = {name: npz[name] for name in npz.files}
  entries["params/Dense_1/bias"] = entries["params/Dense_1/bias"] + 1.0
  with open(path, "wb") as f:
    np.savez_compressed(f, **entries)  # modified array, the old metadata
  with pytest.raises(PolicyFileError, match=f"{path}: checksum mismatch"):
    policy_io.load_policy(path)


def test_mismatches(tmp_path):
  path = tmp_path / "p.npz"
  policy_io.save_policy(path, tree(), metadata())
  with pytest.raises(PolicyFileError, match=f"{path}: the policy is for walker_walk, "
                                            "this run is cheetah_run"):
    policy_io.load_policy(path, task="cheetah_run")
  with pytest.raises(PolicyFileError, match=f"{path}: the policy's observation size is 6, "
                                            "this run's is 17"):
    policy_io.load_policy(path, task="walker_walk", observation_size=17)
  with pytest.raises(PolicyFileError, match="the policy's action size is 2, this run's is 6"):
    policy_io.load_policy(path, action_size=6)
  with pytest.raises(PolicyFileError, match="observation layout"):
    policy_io.load_policy(path, observation_layout={"position": 5, "velocity": 1})


def test_bad_files(tmp_path):
  with pytest.raises(PolicyFileError, match="no such policy file"):
    policy_io.load_policy(tmp_path / "absent.npz")
  path = tmp_path / "p.npz"
  policy_io.save_policy(path, tree(), metadata())
  data = path.read_bytes()
  for size in (len(data) // 2, len(data) - 10, 30):
    truncated = tmp_path / f"truncated_{size}.npz"
    truncated.write_bytes(data[:size])
    with pytest.raises(PolicyFileError, match=f"{truncated}: not a readable .npz"):
      policy_io.load_policy(truncated)
  npy = tmp_path / "array.npz"
  with open(npy, "wb") as f:
    np.save(f, np.zeros(3))
  with pytest.raises(PolicyFileError, match="not an .npz archive"):
    policy_io.load_policy(npy)
  text = tmp_path / "text.npz"
  text.write_text("hello")
  with pytest.raises(PolicyFileError, match="not a readable .npz"):
    policy_io.load_policy(text)
  pickled = tmp_path / "pickled.npz"
  np.savez(pickled, params=np.array([{"w": 1}], dtype=object), metadata=np.zeros(1, np.uint8))
  with pytest.raises(PolicyFileError, match="not a readable .npz"):
    policy_io.load_policy(pickled)
  other = tmp_path / "demos.npz"
  meta = json.dumps({"format": "mjx-form-demonstrations", "version": 1}).encode()
  np.savez(other, observations=np.zeros(3), metadata=np.frombuffer(meta, np.uint8))
  with pytest.raises(PolicyFileError, match="unknown format 'mjx-form-demonstrations'"):
    policy_io.load_policy(other)


def test_bad_arguments(tmp_path):
  path = tmp_path / "p.npz"
  with pytest.raises(ValueError, match=r"metadata needs \['action_size'\]"):
    policy_io.save_policy(path, tree(), {"task": "walker_walk", "observation_size": D})
  with pytest.raises(ValueError, match="observation_layout sums to 6"):
    policy_io.save_policy(path, tree(), metadata(observation_size=7))
  with pytest.raises(ValueError, match="written by the file writer"):
    policy_io.save_policy(path, tree(), metadata(sha256="x"))
  with pytest.raises(ValueError, match="not JSON-serialisable"):
    policy_io.save_policy(path, tree(), metadata(**{"return": float("nan")}))
  with pytest.raises(ValueError, match="without '/'"):
    policy_io.save_policy(path, {"a/b": np.zeros(2)}, metadata())
  with pytest.raises(ValueError, match="non-empty dict"):
    policy_io.save_policy(path, {"params": {}}, metadata())
  with pytest.raises(ValueError, match="dtype <U"):
    policy_io.save_policy(path, {"name": np.array(["x"])}, metadata())
  assert not os.listdir(tmp_path)
