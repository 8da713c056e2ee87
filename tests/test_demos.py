"""Demonstration files: round trip, atomic no-clobber writes, and every validation error."""

from __future__ import annotations

import hashlib
import json
import os
import zipfile

import numpy as np
import pytest

from mjx_form.files import demos
from mjx_form.files.demos import DemonstrationError

K, T, A = 3, 5, 2
LAYOUT = {"orientations": 4, "height": 1, "velocity": 3}
D = sum(LAYOUT.values())


def arrays(seed=0):
  rng = np.random.default_rng(seed)
  return (rng.normal(size=(K, T + 1, D)).astype(np.float32),
          rng.uniform(-1, 1, size=(K, T, A)).astype(np.float32))


def metadata(**changes):
  meta = {"task": "walker_walk", "observation_layout": LAYOUT, "physics": "parity",
          "expert": {"agent": "mpo", "checkpoint": "step_1000000", "return_mean": 950.5}}
  meta.update(changes)
  return meta


@pytest.fixture
def demo_file(tmp_path):
  obs, act = arrays()
  return demos.save_demonstrations(tmp_path / "walker.npz", obs, act, metadata=metadata())


def read_raw(path):
  with np.load(path, allow_pickle=False) as npz:
    entries = {name: npz[name] for name in npz.files}
  return json.loads(entries.pop("metadata").tobytes()), entries


def write_raw(path, meta, entries, rehash=False):
  """A file built by hand (bypassing save's checks); `rehash` recomputes a valid checksum."""
  if rehash:
    meta = dict(meta, sha256=demos.checksum(entries))
  np.savez(path, metadata=np.frombuffer(json.dumps(meta).encode(), np.uint8), **entries)
  return path


def test_round_trip(tmp_path):
  obs, act = arrays()
  path = demos.save_demonstrations(tmp_path / "walker.npz", obs.astype(np.float64), act,
                                   metadata=metadata(seed=7))
  assert path == str(tmp_path / "walker.npz")
  assert os.listdir(tmp_path) == ["walker.npz"]  # no temporary file left behind
  loaded = demos.load_demonstrations(path, task="walker_walk", observation_size=D,
                                     observation_layout=LAYOUT, need_actions=True)
  assert loaded.observations.dtype == np.float32 and loaded.actions.dtype == np.float32
  np.testing.assert_array_equal(loaded.observations, obs)
  np.testing.assert_array_equal(loaded.actions, act)
  meta = loaded.metadata
  assert meta["format"] == demos.FORMAT and meta["version"] == demos.VERSION
  assert meta["observation_layout"] == [["orientations", 4], ["height", 1], ["velocity", 3]]
  assert (meta["task"], meta["physics"], meta["observation_size"], meta["action_size"]) == ("walker_walk", "parity", D, A)
  assert (meta["episodes"], meta["steps"], meta["has_actions"]) == (K, T, True)
  assert meta["expert"] == metadata()["expert"] and meta["seed"] == 7
  spec = (b"observations:<f4:3,6,8\n" + obs.tobytes() + b"actions:<f4:3,5,2\n" + act.tobytes())
  assert meta["sha256"] == hashlib.sha256(spec).hexdigest()  # as the module docstring specifies
  # a plain numpy reader sees numeric arrays only, the metadata as UTF-8 JSON bytes
  raw_meta, entries = read_raw(path)
  assert sorted(entries) == ["actions", "observations"] and raw_meta == meta


def test_round_trip_without_actions(tmp_path):
  obs, _ = arrays()
  meta = {k: v for k, v in metadata().items() if k != "expert"}
  path = demos.save_demonstrations(tmp_path / "d.npz", obs, metadata=meta)
  loaded = demos.load_demonstrations(path, observation_layout=list(LAYOUT.items()))
  assert loaded.actions is None and loaded.metadata["expert"] == {}
  assert loaded.metadata["has_actions"] is False and loaded.metadata["action_size"] is None
  np.testing.assert_array_equal(loaded.observations, obs)


def test_metadata_as_unicode_scalar_is_accepted(tmp_path, demo_file):
  meta, entries = read_raw(demo_file)
  path = tmp_path / "unicode.npz"
  np.savez(path, metadata=np.array(json.dumps(meta)), **entries)
  assert demos.load_demonstrations(path).metadata == meta


def test_refuses_to_overwrite(demo_file):
  before = open(demo_file, "rb").read()
  obs, act = arrays(seed=1)
  with pytest.raises(FileExistsError, match="overwrite=True"):
    demos.save_demonstrations(demo_file, obs, act, metadata=metadata())
  assert open(demo_file, "rb").read() == before
  assert os.listdir(os.path.dirname(demo_file)) == ["walker.npz"]
  demos.save_demonstrations(demo_file, obs, act, metadata=metadata(), overwrite=True)
  np.testing.assert_array_equal(demos.load_demonstrations(demo_file).observations, obs)


@pytest.mark.parametrize("kwargs, match", [
    (dict(observations=np.zeros((K, D), np.float32)), r"\[K, T\+1, D\]"),
    (dict(observations=np.zeros((K, 1, D), np.float32)), r"T >= 1"),
    (dict(actions=np.zeros((K, T + 1, A), np.float32)), r"actions must be \[K, T, A\]"),
    (dict(observations=np.full((K, T + 1, D), np.nan, np.float32)), "non-finite"),
    (dict(actions=np.full((K, T, A), np.inf, np.float32)), "non-finite"),
    (dict(metadata=metadata(observation_layout={"a": 2})), "sums to 2"),
    (dict(metadata=metadata(observation_layout=[["a", 0]])), "positive int"),
    (dict(metadata={"observation_layout": LAYOUT, "physics": "parity"}), "needs 'task'"),
    (dict(metadata=metadata(sha256="0")), "written by save_demonstrations"),
    (dict(metadata=metadata(episodes=K + 1)), "episodes=4 disagrees"),
    (dict(metadata=metadata(expert=[1])), "'expert' must be a dict"),
    (dict(metadata=metadata(expert={"x": object()})), "JSON"),
])
def test_save_validation(tmp_path, kwargs, match):
  obs, act = arrays()
  args = dict(observations=obs, actions=act, metadata=metadata()) | kwargs
  with pytest.raises(ValueError, match=match):
    demos.save_demonstrations(tmp_path / "bad.npz", args.pop("observations"), args.pop("actions"), **args)
  assert os.listdir(tmp_path) == []


def test_missing_file(tmp_path):
  with pytest.raises(DemonstrationError, match="nope.npz: no such demonstration file"):
    demos.load_demonstrations(tmp_path / "nope.npz")


@pytest.mark.parametrize("keep", [0.5, 0.95, 10])
def test_truncated_file(tmp_path, demo_file, keep):
  data = open(demo_file, "rb").read()
  path = tmp_path / "truncated.npz"
  path.write_bytes(data[:int(len(data) * keep) if keep < 1 else keep])
  with pytest.raises(DemonstrationError, match=r"truncated\.npz: not a readable \.npz"):
    demos.load_demonstrations(path)


def test_not_an_npz(tmp_path):
  (tmp_path / "text.npz").write_text("observations, actions\n1, 2\n")
  (tmp_path / "empty.npz").write_bytes(b"")
  np.save(tmp_path / "array.npy", np.zeros((K, T + 1, D), np.float32))
  for name in ("text.npz", "empty.npz", "array.npy"):
    with pytest.raises(DemonstrationError, match=f"{name}: not a"):
      demos.load_demonstrations(tmp_path / name)


def test_pickled_entry_is_refused(tmp_path, demo_file):
  _, entries = read_raw(demo_file)
  path = tmp_path / "pickled.npz"
  np.savez(path, metadata=np.array([{"format": demos.FORMAT}], dtype=object), **entries)
  with pytest.raises(DemonstrationError, match="pickle"):
    demos.load_demonstrations(path)


def test_corrupted_bytes_are_detected(tmp_path, demo_file):
  """Bytes flipped inside the stored observations: caught by the zip CRC or the checksum."""
  data = bytearray(open(demo_file, "rb").read())
  with zipfile.ZipFile(demo_file) as z:
    info = z.getinfo("observations.npy")
  local = info.header_offset  # the local file header: name and extra lengths at bytes 26 and 28
  member = local + 30 + int.from_bytes(data[local + 26:local + 28], "little") \
      + int.from_bytes(data[local + 28:local + 30], "little")
  assert data[member:member + 6] == b"\x93NUMPY"
  start = member + info.file_size - 4 * K * (T + 1) * D  # the float32 data ends the member
  data[start + 40:start + 44] = bytes(b ^ 0xFF for b in data[start + 40:start + 44])
  path = tmp_path / "flipped.npz"
  path.write_bytes(bytes(data))
  with pytest.raises(DemonstrationError, match="flipped.npz"):
    demos.load_demonstrations(path)


def test_checksum_mismatch(tmp_path, demo_file):
  meta, entries = read_raw(demo_file)
  entries["observations"][1, 2, 3] += 1.0  # a well-formed file whose checksum is now wrong
  path = write_raw(tmp_path / "tampered.npz", meta, entries)
  with pytest.raises(DemonstrationError, match="tampered.npz: checksum mismatch"):
    demos.load_demonstrations(path)
  path = write_raw(tmp_path / "badsum.npz", dict(meta, sha256="0" * 64), read_raw(demo_file)[1])
  with pytest.raises(DemonstrationError, match="checksum mismatch"):
    demos.load_demonstrations(path)


@pytest.mark.parametrize("changes, match", [
    ({"format": "something-else"}, "unknown format 'something-else'"),
    ({"format": None}, "unknown format None"),
    ({"version": 2}, "unsupported format version 2"),
    ({"task": 3}, "'task' is 3, expected a str"),
    ({"episodes": "3"}, "'episodes' is '3', expected a int"),
    ({"has_actions": 1}, "'has_actions' is 1"),
    ({"observation_layout": [["a", 1]]}, "sums to 1, observation_size is 8"),
    ({"episodes": K + 1}, r"observations are float32 \[3, 6, 8\], the metadata says float32 \[4, 6, 8\]"),
    ({"steps": T + 1}, r"observations are float32 \[3, 6, 8\], the metadata says float32 \[3, 7, 8\]"),
    ({"action_size": A + 1}, r"actions are float32 \[3, 5, 2\], the metadata says float32 \[3, 5, 3\]"),
    ({"has_actions": False}, "has_actions is False but the file has actions"),
])
def test_bad_metadata(tmp_path, demo_file, changes, match):
  meta, entries = read_raw(demo_file)
  path = write_raw(tmp_path / "bad.npz", dict(meta, **changes), entries)
  with pytest.raises(DemonstrationError, match=match):
    demos.load_demonstrations(path)


def test_unreadable_or_missing_entries(tmp_path, demo_file):
  meta, entries = read_raw(demo_file)
  np.savez(tmp_path / "notjson.npz", metadata=np.frombuffer(b"{not json", np.uint8), **entries)
  np.savez(tmp_path / "nometa.npz", **entries)
  write_raw(tmp_path / "extra.npz", meta, dict(entries, rewards=np.zeros((K, T), np.float32)))
  write_raw(tmp_path / "list.npz", [meta], entries)
  for name, match in [("notjson", "unreadable metadata"), ("nometa", "expected metadata"),
                      ("extra", "'rewards'"), ("list", "not a JSON object")]:
    with pytest.raises(DemonstrationError, match=match):
      demos.load_demonstrations(tmp_path / f"{name}.npz")


def test_shapes_inconsistent_with_metadata(tmp_path, demo_file):
  """Files with valid checksums whose arrays disagree with what the metadata declares."""
  meta, entries = read_raw(demo_file)
  cases = {
      "no_extra_obs": (meta, dict(entries, observations=entries["observations"][:, :T])),  # [K, T, D]
      "flat": (meta, dict(entries, observations=entries["observations"].reshape(K, -1))),
      "float64": (meta, dict(entries, observations=entries["observations"].astype(np.float64))),
      "no_actions": (meta, {"observations": entries["observations"]}),
      "ragged_actions": (meta, dict(entries, actions=entries["actions"][:2])),
  }
  for name, (m, e) in cases.items():
    path = write_raw(tmp_path / f"{name}.npz", m, e, rehash=True)
    with pytest.raises(DemonstrationError, match=f"{name}.npz: .*(metadata says|has_actions)"):
      demos.load_demonstrations(path)


def test_non_finite_values(tmp_path, demo_file):
  meta, entries = read_raw(demo_file)
  for name, value in [("observations", np.nan), ("actions", -np.inf)]:
    bad = dict(entries)
    bad[name] = bad[name].copy()
    bad[name][0, 1, 0] = value
    path = write_raw(tmp_path / f"{name}.npz", meta, bad, rehash=True)
    with pytest.raises(DemonstrationError, match=f"{name} contain non-finite values"):
      demos.load_demonstrations(path)


def test_task_mismatch(demo_file):
  with pytest.raises(DemonstrationError,
                     match="walker.npz: demonstrations are for walker_walk, this run is cheetah_run"):
    demos.load_demonstrations(demo_file, task="cheetah_run")


def test_observation_size_mismatch(demo_file):
  with pytest.raises(DemonstrationError, match="observation size 8 does not match this run's 17"):
    demos.load_demonstrations(demo_file, observation_size=17)


def test_observation_layout_mismatch(demo_file):
  reordered = {"height": 1, "orientations": 4, "velocity": 3}  # same size, another order
  with pytest.raises(DemonstrationError, match="observation layout .* does not match"):
    demos.load_demonstrations(demo_file, observation_size=D, observation_layout=reordered)
  with pytest.raises(DemonstrationError, match="observation layout"):
    demos.load_demonstrations(demo_file, observation_layout={**LAYOUT, "velocity": 2})


def test_actions_required_but_absent(tmp_path):
  path = demos.save_demonstrations(tmp_path / "obs_only.npz", arrays()[0], metadata=metadata())
  with pytest.raises(DemonstrationError, match="obs_only.npz: this run needs actions"):
    demos.load_demonstrations(path, need_actions=True)
  assert demos.load_demonstrations(path).actions is None


def test_error_is_a_value_error():
  assert issubclass(DemonstrationError, ValueError)
