"""Observation standardisation by bias-corrected EMA."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_form import mesh as mesh_lib
from mjx_form.rl import normalizer


def reference(batches, decay):
  """Mean and variance from the explicit weights w_i = (1-d) d^(t-i) / (1-d^t), in float64."""
  t = len(batches)
  w = (1 - decay) * decay ** (t - np.arange(1, t + 1)) / (1 - decay ** t)
  flat = [np.asarray(b, np.float64).reshape(-1, b.shape[-1]) for b in batches]
  mean = sum(wi * b.mean(0) for wi, b in zip(w, flat))
  second = sum(wi * (b ** 2).mean(0) for wi, b in zip(w, flat))
  return mean, second - mean ** 2


def test_init():
  state = normalizer.init(4)
  np.testing.assert_array_equal(state.mean, np.zeros(4))
  np.testing.assert_array_equal(state.var, np.ones(4))
  assert int(state.count) == 0
  x = jnp.arange(8.0).reshape(2, 4)
  np.testing.assert_allclose(normalizer.normalize(state, x), x, rtol=1e-5)
  for bad in (0, -1, 2.0):
    with pytest.raises(ValueError, match="size"):
      normalizer.init(bad)


def test_first_update_sets_statistics_exactly():
  x = np.random.default_rng(0).normal([1.0, -5.0, 30.0], [0.1, 2.0, 7.0], size=(64, 3)).astype(np.float32)
  state = normalizer.update(normalizer.init(3), x, decay=0.99)
  np.testing.assert_allclose(state.mean, x.astype(np.float64).mean(0), rtol=1e-6)
  np.testing.assert_allclose(state.var, x.astype(np.float64).var(0), rtol=1e-5)
  assert int(state.count) == 1


@pytest.mark.parametrize("decay", [0.9, 0.99, 0.0])
def test_matches_numpy_ema(decay):
  rng = np.random.default_rng(1)
  update = jax.jit(normalizer.update, static_argnums=2)
  state, batches = normalizer.init(5), []
  for i in range(40):  # a drifting, non-stationary stream, with [T, B, D] batches
    batch = rng.normal(0.1 * i + np.arange(5), 1.0 + 0.05 * i, size=(4, 8, 5)).astype(np.float32)
    batches.append(batch)
    state = update(state, batch, decay)
    mean, var = reference(batches, decay)
    np.testing.assert_allclose(state.mean, mean, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(state.var, var, rtol=1e-4, atol=1e-5)
  assert int(state.count) == 40


def test_leading_axes_are_pooled():
  x = np.random.default_rng(2).normal(size=(3, 7, 2)).astype(np.float32)
  a = normalizer.update(normalizer.init(2), x)
  b = normalizer.update(normalizer.init(2), x.reshape(21, 2))
  jax.tree.map(lambda u, v: np.testing.assert_allclose(u, v, rtol=1e-6), a, b)


def test_mask_counts_only_kept_rows():
  """A masked update equals the numpy EMA over the kept rows alone; a batch with none kept
  leaves the state (count included) as it was."""
  rng = np.random.default_rng(7)
  update = jax.jit(normalizer.update, static_argnums=2)
  state, kept = normalizer.init(3), []
  for i in range(12):
    batch = rng.normal(i + np.arange(3), 1.0 + 0.3 * i, size=(6, 5, 3)).astype(np.float32)
    batch[0, 0] = 1e6  # a dropped row far from the rest: it must not leak into the statistics
    mask = rng.random((6, 5)) < 0.6
    mask[0, 0] = False
    state = update(state, batch, 0.9, mask)
    kept.append(batch[mask])
    mean, var = reference(kept, 0.9)
    np.testing.assert_allclose(state.mean, mean, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(state.var, var, rtol=1e-4, atol=1e-4)
  unchanged = update(state, batch, 0.9, np.zeros((6, 5), bool))
  jax.tree.map(np.testing.assert_array_equal, unchanged, state)
  with pytest.raises(ValueError, match="mask has shape"):
    normalizer.update(state, batch, 0.9, np.ones((6,), bool))


def test_standardises_stationary_stream():
  mu, sigma = np.array([3.0, -2.0, 100.0, 0.0]), np.array([0.5, 2.0, 10.0, 1e-3])
  update = jax.jit(normalizer.update)
  state, key = normalizer.init(4), jax.random.PRNGKey(0)
  for _ in range(300):
    key, sub = jax.random.split(key)
    state = update(state, mu + sigma * jax.random.normal(sub, (256, 4)))
  fresh = mu + sigma * jax.random.normal(jax.random.PRNGKey(1), (20_000, 4))
  z = np.asarray(normalizer.normalize(state, fresh, eps=1e-12))
  np.testing.assert_allclose(z.mean(0), 0.0, atol=0.05)
  np.testing.assert_allclose(z.std(0), 1.0, atol=0.05)


def test_constant_dimensions_do_not_blow_up():
  rng = np.random.default_rng(3)
  state = normalizer.init(3)
  for _ in range(20):
    batch = np.stack([rng.normal(size=128), np.full(128, 5.0), np.full(128, -1234.5)], -1).astype(np.float32)
    state = normalizer.update(state, batch, decay=0.9)
  np.testing.assert_array_equal(state.var[1:], 0.0)
  np.testing.assert_array_equal(state.mean[1:], [5.0, -1234.5])
  z = normalizer.normalize(state, batch)
  assert np.all(np.isfinite(z))
  np.testing.assert_array_equal(z[:, 1:], 0.0)
  off = normalizer.normalize(state, batch + 1.0, clip=5.0)  # off the constant: finite, clipped
  assert np.all(np.isfinite(off)) and np.all(np.abs(off) <= 5.0)
  np.testing.assert_array_equal(off[:, 1:], 5.0)


def test_clip():
  state = normalizer.update(normalizer.init(2), jnp.array([[0.0, 0.0], [2.0, 2.0]]))  # mean 1, var 1
  z = normalizer.normalize(state, jnp.array([[100.0, -100.0], [1.5, 0.5]]), clip=3.0, eps=0.0)
  np.testing.assert_allclose(z, [[3.0, -3.0], [0.5, -0.5]])


def test_sharded_batch_matches_unsharded():
  mesh = mesh_lib.make_mesh(jax.devices()[:2])
  rng = np.random.default_rng(4)
  update = jax.jit(normalizer.update)
  plain = sharded = normalizer.init(6)
  sharded = jax.device_put(sharded, mesh_lib.replicated(mesh))
  for i in range(5):
    batch = rng.normal(i, 1.0 + i, size=(16, 6)).astype(np.float32)
    plain = update(plain, batch)
    sharded = update(sharded, mesh_lib.shard_batch(jnp.asarray(batch), mesh))
  jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6), sharded, plain)
  assert sharded.mean.sharding.is_fully_replicated
  x = mesh_lib.shard_batch(jnp.asarray(batch), mesh)
  np.testing.assert_allclose(jax.jit(normalizer.normalize)(sharded, x),
                             normalizer.normalize(plain, batch), rtol=1e-5, atol=1e-5)


def test_validation():
  state = normalizer.init(3)
  with pytest.raises(ValueError, match=r"expected \(\.\.\., 3\)"):
    normalizer.update(state, jnp.ones((4, 2)))
  with pytest.raises(ValueError, match=r"expected \(\.\.\., 3\)"):
    normalizer.normalize(state, jnp.ones((4, 2)))
  with pytest.raises(ValueError, match=r"expected \(\.\.\., 3\)"):
    normalizer.update(state, jnp.float32(1.0))
  for decay in (1.0, -0.1, 1.5):
    with pytest.raises(ValueError, match="decay"):
      normalizer.update(state, jnp.ones((4, 3)), decay=decay)


def test_periodic_features_are_wrapped_before_statistics_and_standardisation():
  """A feature with period 2 pi: values whole turns apart update and normalise alike (checked
  against numpy's remainder into [-pi, pi)); the other features are untouched; no period leaves
  everything as it was."""
  rng = np.random.default_rng(0)
  period = np.array([0.0, 2 * np.pi, 0.0], np.float32)
  x = rng.uniform(-3, 3, size=(64, 3)).astype(np.float32)
  turns = x + period * rng.integers(-3, 4, size=(64, 1))    # whole turns on feature 1 only
  state = normalizer.init(3, period=period)
  a, b = normalizer.update(state, x), normalizer.update(state, turns)
  np.testing.assert_allclose(a.mean, b.mean, atol=1e-5)
  np.testing.assert_allclose(normalizer.normalize(a, x), normalizer.normalize(a, turns), atol=1e-4)
  expected = x.copy()
  expected[:, 1] = np.remainder(turns[:, 1] + np.pi, 2 * np.pi) - np.pi
  np.testing.assert_allclose(normalizer.wrap(state, turns), expected, atol=1e-5)
  plain = normalizer.init(3)
  np.testing.assert_array_equal(normalizer.wrap(plain, turns), turns)
  assert not np.allclose(normalizer.update(plain, turns).mean, a.mean, atol=1e-3)
  with pytest.raises(ValueError, match="period"):
    normalizer.init(3, period=[0.0, -1.0, 0.0])


def test_angle_features_replace_each_angle_by_its_cos_and_sin():
  """`angles`: the agent's features are the raw ones with the angle zeroed, then its cos and sin
  (checked against numpy); whole turns change nothing and +-pi is no jump (a wrapped angle's
  standardised value jumps there); a zero row keeps the raw angle and adds zeros; the statistics
  are the features' (the mean of the cosines is numpy's); shapes and rows are checked."""
  rng = np.random.default_rng(1)
  x = rng.uniform(-3, 3, size=(256, 3)).astype(np.float32)
  rows = normalizer.angle_rows([0.0, 2 * np.pi, 0.0])
  np.testing.assert_array_equal(rows, [[0, 1, 0]])
  state = normalizer.init(3, angles=rows)
  assert state.mean.shape == (5,) and normalizer.input_size(state) == 3
  expected = np.stack([x[:, 0], 0 * x[:, 1], x[:, 2], np.cos(x[:, 1]), np.sin(x[:, 1])], -1)
  np.testing.assert_allclose(normalizer.features(state, x), expected, atol=1e-6)
  turned = x.copy()
  turned[:, 1] += 2 * np.pi * rng.integers(-3, 4, size=256)
  np.testing.assert_allclose(normalizer.features(state, turned), expected, atol=1e-5)
  fitted = normalizer.update(state, x)
  np.testing.assert_allclose(fitted.mean[3], np.cos(x[:, 1]).mean(), atol=1e-6)
  np.testing.assert_allclose(fitted.var[4], np.sin(x[:, 1]).var(), atol=1e-6)
  edge = np.array([[0.5, np.pi - 1e-3, 0.5], [0.5, -np.pi + 1e-3, 0.5]], np.float32)
  near = normalizer.normalize(fitted, edge)
  np.testing.assert_allclose(near[0], near[1], atol=1e-2)
  wrapped = normalizer.update(normalizer.init(3, period=[0, 2 * np.pi, 0]), x)
  far = normalizer.normalize(wrapped, edge)
  assert abs(far[0, 1] - far[1, 1]) > 2.0  # the wrap's jump, which the cos and sin do not have
  off = normalizer.init(3, angles=np.zeros((1, 3)))  # a member that sees the angle raw
  np.testing.assert_allclose(normalizer.features(off, x),
                             np.concatenate([x, np.zeros((256, 2))], -1), atol=1e-6)
  with pytest.raises(ValueError, match=r"expected \(\.\.\., 3\)"):
    normalizer.normalize(state, jnp.ones((4, 5)))
  for bad in ([[0, 1]], [[0, 0.5, 0]], [[1, 1, 0]], [[0, 1, 0], [0, 1, 0]], np.zeros((0, 3))):
    with pytest.raises(ValueError, match="angles"):
      normalizer.init(3, angles=bad)
