"""The on-device replay ring buffer: wrap-around, sampling, jit/donation and sharding."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import PartitionSpec

from mjx_form import mesh as mesh_lib
from mjx_form.rl import replay

OBS, T = 3, 4  # an unroll: T+1 observations of size OBS, T rewards, an integer id


def example():
  return {"id": jax.ShapeDtypeStruct((), jnp.int32),
          "obs": jnp.zeros((T + 1, OBS), jnp.float32),
          "reward": jax.ShapeDtypeStruct((T,), jnp.float32)}


def unrolls(ids):
  """Unrolls whose every value is derived from their id (ids must be non-zero to tell apart)."""
  ids = jnp.asarray(ids, jnp.int32)
  f = ids.astype(jnp.float32)
  return {"id": ids,
          "obs": f[:, None, None] * jnp.ones((T + 1, OBS)),
          "reward": -f[:, None] * jnp.ones((T,))}


def check_consistent(batch):
  """Every sampled unroll is whole: all its leaves come from the same slot."""
  f = np.asarray(batch["id"], np.float32)
  np.testing.assert_array_equal(np.asarray(batch["obs"]), f[:, None, None] * np.ones((T + 1, OBS)))
  np.testing.assert_array_equal(np.asarray(batch["reward"]), -f[:, None] * np.ones((T,)))


def test_init():
  state = replay.init(example(), 7)
  assert state.data["obs"].shape == (7, T + 1, OBS) and state.data["obs"].dtype == jnp.float32
  assert state.data["id"].shape == (7,) and state.data["id"].dtype == jnp.int32
  assert state.data["reward"].shape == (7, T)
  assert all(not np.any(np.asarray(x)) for x in jax.tree.leaves(state.data))
  assert int(state.position) == 0 and int(state.size) == 0
  assert state.position.dtype == jnp.int32 and state.size.dtype == jnp.int32
  assert replay.capacity(state) == 7
  assert not bool(replay.can_sample(state))


@pytest.mark.parametrize("capacity", [0, -3, 2.5, True, "4"])
def test_init_rejects_bad_capacity(capacity):
  with pytest.raises(ValueError, match="capacity"):
    replay.init(example(), capacity)


def test_init_rejects_empty_example():
  with pytest.raises(ValueError, match="no array leaves"):
    replay.init({}, 4)


def test_wrap_around_overwrites_oldest_in_order():
  state = replay.init(example(), 5)
  state = replay.insert(state, unrolls([1, 2, 3]))
  np.testing.assert_array_equal(state.data["id"], [1, 2, 3, 0, 0])
  assert (int(state.position), int(state.size)) == (3, 3)
  state = replay.insert(state, unrolls([4, 5, 6]))          # slots 3, 4, 0: 1 is overwritten
  np.testing.assert_array_equal(state.data["id"], [6, 2, 3, 4, 5])
  assert (int(state.position), int(state.size)) == (1, 5)
  state = replay.insert(state, unrolls([7, 8, 9, 10]))      # slots 1..4: 2..5 are overwritten
  np.testing.assert_array_equal(state.data["id"], [6, 7, 8, 9, 10])
  assert (int(state.position), int(state.size)) == (0, 5)
  state = replay.insert(state, unrolls([11, 12, 13, 14, 15]))  # a whole capacity at once
  np.testing.assert_array_equal(state.data["id"], [11, 12, 13, 14, 15])
  assert (int(state.position), int(state.size)) == (0, 5)
  state = replay.insert(state, unrolls([16, 17]))
  state = replay.insert(state, unrolls([18, 19, 20, 21, 22]))  # full capacity from position 2
  np.testing.assert_array_equal(state.data["id"], [21, 22, 18, 19, 20])
  assert (int(state.position), int(state.size)) == (2, 5)
  check_consistent(state.data)


def test_insert_matches_reference_ring():
  """Many inserts of random sizes against a Python ring buffer."""
  rng = np.random.default_rng(0)
  cap, ring, pos, next_id = 7, [0] * 7, 0, 1
  state, insert = replay.init(example(), cap), jax.jit(replay.insert)
  for _ in range(20):
    n = int(rng.integers(1, cap + 1))
    ids = list(range(next_id, next_id + n))
    next_id += n
    for i in ids:
      ring[pos] = i
      pos = (pos + 1) % cap
    state = insert(state, unrolls(ids))
    np.testing.assert_array_equal(state.data["id"], ring)
    assert int(state.position) == pos and int(state.size) == min(next_id - 1, cap)
  check_consistent(state.data)


def test_samples_only_written_slots():
  state = replay.insert(replay.init(example(), 16), unrolls([1, 2, 3, 4, 5]))
  batch = replay.sample(state, jax.random.PRNGKey(0), 2000)
  assert batch["obs"].shape == (2000, T + 1, OBS) and batch["id"].shape == (2000,)
  assert set(np.asarray(batch["id"]).tolist()) == {1, 2, 3, 4, 5}  # never an unwritten zero slot
  check_consistent(batch)


def test_sample_is_uniform():
  state = replay.insert(replay.init(example(), 10), unrolls([1, 2, 3, 4, 5, 6]))
  n = 60_000
  ids = np.asarray(replay.sample(state, jax.random.PRNGKey(1), n)["id"])
  counts = np.bincount(ids, minlength=11)
  assert counts[0] == 0 and not counts[7:].any()
  expected = n / 6  # 10000 each, binomial std ~91
  np.testing.assert_allclose(counts[1:7], expected, rtol=0.05)
  chi2 = np.sum((counts[1:7] - expected) ** 2 / expected)
  assert chi2 < 25  # 5 degrees of freedom: p < 1e-4 to fail by chance


def test_sample_depends_only_on_key():
  state = replay.insert(replay.init(example(), 8), unrolls(np.arange(1, 9)))
  a = replay.sample(state, jax.random.PRNGKey(3), 64)
  b = replay.sample(state, jax.random.PRNGKey(3), 64)
  c = replay.sample(state, jax.random.PRNGKey(4), 64)
  np.testing.assert_array_equal(a["id"], b["id"])
  assert np.any(np.asarray(a["id"]) != np.asarray(c["id"]))


def test_sample_rejects_bad_batch_size():
  state = replay.init(example(), 4)
  for bad in (0, -1, 1.5):
    with pytest.raises(ValueError, match="batch_size"):
      replay.sample(state, jax.random.PRNGKey(0), bad)


def test_can_sample():
  state = replay.insert(replay.init(example(), 8), unrolls([1, 2, 3]))
  assert bool(replay.can_sample(state))
  assert bool(replay.can_sample(state, 3)) and not bool(replay.can_sample(state, 4))
  assert bool(jax.jit(replay.can_sample, static_argnums=1)(state, 2))


@pytest.mark.parametrize("bad, match", [
    ({"id": jnp.ones(2, jnp.int32), "obs": jnp.ones((2, T + 1, OBS))}, "structure"),
    ({**unrolls([1, 2]), "obs": jnp.ones((2, T, OBS))}, r"shape \(2, 4, 3\), expected \(N, 5, 3\)"),
    ({**unrolls([1, 2]), "id": jnp.ones(2, jnp.float32)}, "dtype float32, the buffer stores int32"),
    ({**unrolls([1, 2]), "reward": jnp.ones((3, T))}, "mismatched leading axes"),
    ({**unrolls([1, 2]), "id": jnp.int32(1)}, "scalar"),
    (unrolls(np.arange(1, 6)), "capacity 4"),
    (jax.tree.map(lambda x: x[:0], unrolls([1])), "cannot insert 0"),
])
def test_insert_validation(bad, match):
  state = replay.init(example(), 4)
  with pytest.raises(ValueError, match=match):
    replay.insert(state, bad)
  with pytest.raises(ValueError, match=match):  # at trace time too
    jax.jit(replay.insert)(state, bad)


def _step(state, new, key):
  state = replay.insert(state, new)
  return state, replay.sample(state, key, 32)


def test_jit_insert_and_sample_with_donation():
  step = jax.jit(_step, donate_argnums=0)
  state, ref = replay.init(example(), 6), replay.init(example(), 6)
  key = jax.random.PRNGKey(0)
  for i, n in enumerate([2, 5, 6, 3]):
    ids = np.arange(10 * i + 1, 10 * i + 1 + n)
    key, sub = jax.random.split(key)
    old = state
    state, batch = step(state, unrolls(ids), sub)
    assert old.data["obs"].is_deleted()  # the storage was donated, not copied
    ref = replay.insert(ref, unrolls(ids))
    jax.tree.map(np.testing.assert_array_equal, state, ref)
    np.testing.assert_array_equal(batch["id"], replay.sample(ref, sub, 32)["id"])
    assert set(np.asarray(batch["id"]).tolist()) <= set(np.asarray(ref.data["id"]).tolist()) - {0}
    check_consistent(batch)


def _run(sharding, sizes, shard_unrolls=None):
  """A fixed series of jitted inserts and samples; returns the final state and all samples."""
  step = jax.jit(_step, donate_argnums=0)
  state = replay.init(example(), 8, sharding=sharding)
  key, next_id, samples = jax.random.PRNGKey(42), 1, []
  for n in sizes:
    new = unrolls(np.arange(next_id, next_id + n))
    next_id += n
    if shard_unrolls is not None and n % 2 == 0:
      new = mesh_lib.shard_batch(new, shard_unrolls)
    key, sub = jax.random.split(key)
    state, batch = step(state, new, sub)
    samples.append(jax.device_get(batch))
  return state, samples


def test_sharded_matches_single_device():
  assert jax.device_count() >= 2, "conftest should force 2 host CPU devices"
  mesh = mesh_lib.make_mesh(jax.devices()[:2])
  sizes = [3, 4, 1, 8, 5, 2, 7]  # wrap-around, including sizes not divisible by 2
  single, single_samples = _run(None, sizes)
  sharded, sharded_samples = _run(mesh_lib.batch_sharding(mesh), sizes, shard_unrolls=mesh)
  one_device, one_samples = _run(mesh_lib.batch_sharding(mesh_lib.make_mesh(jax.devices()[:1])), sizes)
  for state in (sharded, one_device):
    jax.tree.map(np.testing.assert_array_equal, jax.device_get(state), jax.device_get(single))
  for samples in (sharded_samples, one_samples):
    for a, b in zip(samples, single_samples):
      jax.tree.map(np.testing.assert_array_equal, a, b)
  # the storage stays split over both devices through the donated, jitted updates
  for leaf in jax.tree.leaves(sharded.data):
    assert leaf.sharding.is_equivalent_to(mesh_lib.batch_sharding(mesh), leaf.ndim)
    assert len(leaf.addressable_shards) == 2 and leaf.addressable_shards[0].data.shape[0] == 4
  assert sharded.position.sharding.is_equivalent_to(mesh_lib.replicated(mesh), 0)


def test_init_sharded_placement():
  mesh = mesh_lib.make_mesh(jax.devices()[:2])
  state = replay.init(example(), 6, sharding=mesh_lib.batch_sharding(mesh))
  assert state.data["obs"].sharding.spec == PartitionSpec(mesh_lib.BATCH_AXIS)
  assert state.size.sharding.is_fully_replicated and len(state.size.sharding.device_set) == 2
  with pytest.raises(ValueError, match="cannot be split over the 2 devices"):
    replay.init(example(), 5, sharding=mesh_lib.batch_sharding(mesh))
  with pytest.raises(ValueError, match="Sharding"):
    replay.init(example(), 6, sharding="batch")
