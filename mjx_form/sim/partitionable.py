"""MJX's step for a batch split over devices, without the devices agreeing at every step.

A batch of environments split over several devices and stepped as one program-wide batch
(`jax.vmap` under a sharded `jit`) is partitioned by XLA. Two of MJX's operations make it
exchange data between the devices (seen in the compiled step on 2 forced CPU devices):
- contact culling (`max_contact_points`, `max_geom_pairs`) picks the closest contacts with
  `lax.top_k`, which XLA does not split along the batch: it gathers the whole batch's
  distances onto every device at every substep. `stable_top_k` gives the same indices with a
  stable sort, which XLA splits; `install()` makes MJX's collision use it (for every mode:
  the same contacts).
- the constraint solver iterates in a `lax.while_loop` that goes on while any environment
  does: every iteration reduces its condition over all devices and hands it to the host.
  `solve` runs MJX's own solve with that loop as a scan of exactly `opt.iterations` passes,
  each applying the iteration only where the loop's condition still holds
  (`bounded_while_loop`, as MJX's line search already does): the same iterations per
  environment, nothing asked at run time, but the passes after convergence still cost their
  compute. Selected by `SolverSettings.bounded_solver_loop` (`--physics fast_bounded`);
  which is faster is measured on the GPUs (benchmarks/NOTES.md).
Both run MJX's own functions with `jax` seen through `_Overridden`, so no MJX code is copied.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco.mjx._src import collision_driver
from mujoco.mjx._src import solver as mjx_solver


class _Overridden:
  """`module` with some attributes replaced: what MJX's functions see as `jax` here."""

  def __init__(self, module, **overrides):
    self._module, self._overrides = module, overrides

  def __getattr__(self, name):
    if name in self._overrides:
      return self._overrides[name]
    return getattr(self._module, name)


def stable_top_k(operand: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
  """`lax.top_k(operand, k)` along the last axis (the k largest, ties to the lower index) by
  a stable sort."""
  indices = jnp.argsort(-operand, axis=-1, stable=True)[..., :k]
  return jnp.take_along_axis(operand, indices, axis=-1), indices


def bounded_while_loop(cond_fun, body_fun, init_val, max_iterations: int):
  """`while cond_fun(x): x = body_fun(x)` for at most `max_iterations` passes, as a scan of
  that length. The caller's condition must itself stop the loop by then (MJX's counts its
  iterations), so the result is `lax.while_loop`'s."""

  def one_pass(x, _):
    return jax.lax.cond(cond_fun(x), body_fun, lambda y: y, x), None

  return jax.lax.scan(one_pass, init_val, None, length=max_iterations)[0]


def _with_jax(fn, jax_view):
  """`fn` (a module-level function of MJX) running against `jax_view` as its `jax`."""
  return type(fn)(fn.__code__, {**fn.__globals__, "jax": jax_view}, fn.__name__,
                  fn.__defaults__, fn.__closure__)


def solve(m, d):
  """`mjx.solve(m, d)` with its iteration loop bounded by `m.opt.iterations`."""

  def while_loop(cond_fun, body_fun, init_val):
    return bounded_while_loop(cond_fun, body_fun, init_val, int(m.opt.iterations))

  view = _Overridden(jax, lax=_Overridden(jax.lax, while_loop=while_loop))
  return _with_jax(mjx_solver.solve, view)(m, d)


def install() -> None:
  """MJX's collision culls contacts with `stable_top_k` (its module sees `jax` through a
  view; nothing else in it changes)."""
  if not isinstance(collision_driver.jax, _Overridden):
    collision_driver.jax = _Overridden(jax, lax=_Overridden(jax.lax, top_k=stable_top_k))


install()
