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
  compute. `forward` and `step` are MJX's with that solve (resets; a raw loop); humanoid's and
  quadruped's resets still loop on contacts in while_loops of their own. Selected by
  `SolverSettings.bounded_solver_loop` (`--physics fast_bounded`); which is faster is
  measured on the GPUs (benchmarks/NOTES.md). `solve_iterations` counts the passes an
  environment needs of each of MJX's loops (benchmarks/solver_iterations.py).
Both run MJX's own functions with some of their module's names seen through `_Overridden`, so
no MJX code is copied; each checks that its replacement was used (a newer MJX that no longer
calls it fails loudly).
"""

from __future__ import annotations

import inspect

import jax
import jax.numpy as jnp
from mujoco.mjx._src import collision_driver
from mujoco.mjx._src import forward as mjx_forward
from mujoco.mjx._src import solver as mjx_solver


class _Overridden:
  """`module` with some attributes replaced: what MJX's functions see as `jax` here."""

  def __init__(self, module, **overrides):
    self._module, self._overrides = module, overrides

  def __getattr__(self, name):
    if name in self._overrides:
      return self._overrides[name]
    return getattr(self._module, name)


def _total_order_key(x: jax.Array) -> jax.Array:
  """int32 keys ordered as float32 `x` in IEEE total order (-NaN < -inf < ... < -0.0 < +0.0
  < ... < +inf < +NaN), the order `lax.top_k` ranks by."""
  bits = jax.lax.bitcast_convert_type(x, jnp.int32)
  return jnp.where(bits < 0, bits ^ jnp.int32(0x7FFFFFFF), bits)


def stable_top_k(operand: jax.Array, k: int) -> tuple[jax.Array, jax.Array]:
  """`lax.top_k(operand, k)` along the last axis (the k largest, ties to the lower index): for
  float32 (the physics' dtype) by a stable sort in IEEE total order, for other dtypes (float64
  under `jax.enable_x64`) `lax.top_k` itself."""
  if operand.dtype != jnp.float32:
    return jax.lax.top_k(operand, k)  # (`install` changes MJX's view of jax only)
  descending = ~_total_order_key(operand)  # (~ reverses the order of int32 without overflow)
  indices = jnp.argsort(descending, axis=-1, stable=True)[..., :k]
  return jnp.take_along_axis(operand, indices, axis=-1), indices


def bounded_while_loop(cond_fun, body_fun, init_val, max_iterations: int):
  """`while cond_fun(x): x = body_fun(x)` for at most `max_iterations` passes, as a scan of
  that length. The caller's condition must itself stop the loop by then (MJX's counts its
  iterations), so the result is `lax.while_loop`'s."""

  def one_pass(x, _):
    return jax.lax.cond(cond_fun(x), body_fun, lambda y: y, x), None

  return jax.lax.scan(one_pass, init_val, None, length=max_iterations)[0]


def _rebound(fn, **names):
  """`fn` (a module-level function of MJX) running with `names` in place of its module's."""
  if inspect.unwrap(fn) is not fn:
    raise RuntimeError(f"{fn.__qualname__} is wrapped: mjx_form.sim.partitionable expects "
                       "MJX's plain function")
  rebound = type(fn)(fn.__code__, {**fn.__globals__, **names}, fn.__name__, fn.__defaults__,
                     fn.__closure__)
  rebound.__kwdefaults__ = fn.__kwdefaults__
  return rebound


def _recorded(fn):
  """(`fn` recording its calls, the list of its calls): whether MJX used a replacement."""
  calls = []

  def recording(*args):
    calls.append(True)
    return fn(*args)

  return recording, calls


def solve(m, d):
  """`mjx.solve(m, d)` with its iteration loop bounded by `m.opt.iterations`."""
  while_loop, used = _recorded(lambda cond_fun, body_fun, init_val: bounded_while_loop(
      cond_fun, body_fun, init_val, int(m.opt.iterations)))
  view = _Overridden(jax, lax=_Overridden(jax.lax, while_loop=while_loop))
  d = _rebound(mjx_solver.solve, jax=view)(m, d)
  if int(m.opt.iterations) > 1 and not used:
    raise RuntimeError("MJX's solve no longer iterates in jax.lax.while_loop: "
                       "mjx_form.sim.partitionable needs updating")
  return d


def solve_iterations(m, d) -> tuple[jax.Array, jax.Array]:
  """How `mjx.solve(m, d)` iterates from `d`: its iterations (solver_niter, at most
  `m.opt.iterations`: the passes a batch's `while_loop` needs for this environment) and the
  line search's passes in each of them ([m.opt.iterations], 0 after the last; MJX runs the
  line search as a scan of `m.opt.ls_iterations` passes, of which only these change it)."""
  cap = int(m.opt.iterations)
  searches, found = [], []

  def line_search_loop(cond_fun, body_fun, init_val, max_iter):
    searches.append(mjx_solver._while_loop_scan(cond_fun, body_fun, init_val, max_iter))
    return searches[-1]

  def while_loop(cond_fun, body_fun, init_val):
    def counted(carry):  # (the line search's count is read in the same trace as the body)
      ctx, passes = carry
      searches.clear()
      new = body_fun(ctx)
      if len(searches) != 1:
        raise RuntimeError("MJX's solver iteration no longer runs one line search in "
                           "_while_loop_scan: mjx_form.sim.partitionable needs updating")
      return new, passes.at[ctx.solver_niter].set(searches[-1].ls_iter)
    found.append(jax.lax.while_loop(lambda carry: cond_fun(carry[0]), counted,
                                    (init_val, jnp.zeros(cap, jnp.int32))))
    return found[-1][0]

  line_search = _rebound(mjx_solver._linesearch, _while_loop_scan=line_search_loop)
  if cap == 1:  # (MJX's solve then takes its one iteration without a loop)
    _rebound(mjx_solver.solve, _linesearch=line_search)(m, d)
    return jnp.ones((), jnp.int32), jnp.stack([searches[-1].ls_iter])
  view = _Overridden(jax, lax=_Overridden(jax.lax, while_loop=while_loop))
  _rebound(mjx_solver.solve, jax=view, _linesearch=line_search)(m, d)
  if len(found) != 1:
    raise RuntimeError("MJX's solve no longer iterates in one jax.lax.while_loop: "
                       "mjx_form.sim.partitionable needs updating")
  ctx, passes = found[0]
  return ctx.solver_niter, passes


def forward(m, d):
  """`mjx.forward(m, d)` (MuJoCo's mj_forward) with `solve` as its constraint solver."""
  bounded, used = _recorded(solve)
  d = _rebound(inspect.unwrap(mjx_forward.forward),
               solver=_Overridden(mjx_solver, solve=bounded))(m, d)
  if d._impl.efc_J.size and not used:
    raise RuntimeError("MJX's forward no longer calls solver.solve: "
                       "mjx_form.sim.partitionable needs updating")
  return d


def step(m, d):
  """`mjx.step(m, d)` with `forward` (so `solve`) in place of MJX's forward."""
  bounded, used = _recorded(forward)
  d = _rebound(inspect.unwrap(mjx_forward.step), forward=bounded)(m, d)
  if not used:
    raise RuntimeError("MJX's step no longer calls forward: "
                       "mjx_form.sim.partitionable needs updating")
  return d


def install() -> None:
  """MJX's collision culls contacts with `stable_top_k` (its module sees `jax` through a
  view; nothing else in it changes). Process-wide: every MJX step culls so, including a plain
  `mjx.step` (benchmarks' raw loop, peers on MJX)."""
  if not isinstance(collision_driver.jax, _Overridden):
    collision_driver.jax = _Overridden(jax, lax=_Overridden(jax.lax, top_k=stable_top_k))


install()
