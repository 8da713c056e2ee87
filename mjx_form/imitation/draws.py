"""Uniform draws of demonstrated transitions (GAIfO's expert inputs, BC's and BCO's pairs)."""

from __future__ import annotations

import jax


def draw_transitions(length: int, episodes: int, n: int, key: jax.Array
                     ) -> tuple[jax.Array, jax.Array]:
  """n transitions drawn uniformly from `episodes` x `length`: (episode [n], step [n])."""
  k_key, t_key = jax.random.split(key)
  return (jax.random.randint(k_key, (n,), 0, episodes),
          jax.random.randint(t_key, (n,), 0, length))
