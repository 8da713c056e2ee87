"""MJX physics: model loading with a physics mode, and dm_control's step semantics.

dm_control steps with `mj_step2; mj_step(n - 1); mj_step1` (its "legacy step"), so after a
control step the position- and velocity-dependent quantities (xpos, xmat, velocity sensors)
already belong to the new state, while acceleration-stage sensors (touch, force, torque,
accelerometer) hold the values of the last substep. `control_step` reproduces that split with
MJX's stage functions: the data carried between control steps has its position and velocity
stages computed, exactly like dm_control's `mjData` after `mj_step1`.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from mjx_form.sim import partitionable  # (also: MJX's contact culling by a stable sort)
from mjx_form.sim import mjx_patches  # noqa: F401  (MJX corrections for parity with MuJoCo C)

PHYSICS_MODES = ("parity", "fast", "fast_bounded", "fast_ls4")
DEFAULT_PHYSICS = "fast"  # as exact as parity in one-step error, 2.5-7x faster (README)
# `fast_ls4`: fast with MJX's line search capped at this many passes. Over 512 dm_control
# states per domain the one-step qvel error (median, p90, max) equals fast's 10 passes in all
# five contact domains (walker breaks at 3), the solver's iterations are unchanged, and the raw
# step is 1.29x (humanoid) to 1.52x (walker) faster on an H200 (benchmarks/results/
# 2026-11-26_solver_sweep_cpu_line_search_cap_512_states, ..._speed_h200_line_search_cap).
FAST_LS_ITERATIONS = 4

# JAX lets float32 matmuls run as TF32 (10-bit mantissa) on NVIDIA GPUs by default. Measured on
# an H200 (benchmarks/results/*parity_error_h200_*), that put one control step 100-1000x further
# from dm_control than the CPU is (walker qvel: max error 0.1 against 4e-4 at full precision).
# Everything that simulates, observes or rewards is therefore traced at full float32; the
# networks keep JAX's default.
PHYSICS_MATMUL_PRECISION = "highest"


def full_precision(fn):
  """Decorator: `fn` is traced with float32 matmuls at full precision (no TF32 on GPUs)."""
  @functools.wraps(fn)
  def wrapped(*args, **kwargs):
    with jax.default_matmul_precision(PHYSICS_MATMUL_PRECISION):
      return fn(*args, **kwargs)
  return wrapped


@dataclasses.dataclass(frozen=True)
class SolverSettings:
  """Constraint-solver and collision settings applied on top of dm_control's XML.

  None keeps the XML's own value (dm_control's XMLs keep MuJoCo's defaults: 100 iterations,
  50 line-search iterations, tolerance 1e-8, no contact culling).
  """

  iterations: int | None = None
  ls_iterations: int | None = None
  max_contact_points: int | None = None  # MJX contact culling: keep the N closest contacts
  max_geom_pairs: int | None = None  # MJX contact culling: keep the N closest geom pairs
  # The solver's iteration loop as a scan of `iterations` passes instead of a while_loop: the
  # same iterations, no per-iteration question to the devices (mjx_form.sim.partitionable).
  bounded_solver_loop: bool = False


PARITY = SolverSettings()


def check_physics_mode(physics: str | SolverSettings) -> str | SolverSettings:
  """A physics mode name (PHYSICS_MODES) or explicit `SolverSettings` (for sweeps)."""
  if not isinstance(physics, SolverSettings) and physics not in PHYSICS_MODES:
    raise ValueError(f"unknown physics mode {physics!r}; valid modes: {', '.join(PHYSICS_MODES)}")
  return physics


def apply_solver_settings(root: ET.Element, settings: SolverSettings) -> None:
  """Writes `settings` into a parsed MJCF tree (in place)."""
  option = root.find("option")
  if option is None:
    option = ET.SubElement(root, "option")
  if settings.iterations is not None:
    option.set("iterations", str(settings.iterations))
  if settings.ls_iterations is not None:
    option.set("ls_iterations", str(settings.ls_iterations))
  numerics = {"max_contact_points": settings.max_contact_points,
              "max_geom_pairs": settings.max_geom_pairs}
  numerics = {k: v for k, v in numerics.items() if v is not None}
  if numerics:
    custom = root.find("custom")
    if custom is None:
      custom = ET.SubElement(root, "custom")
    for name, value in numerics.items():
      ET.SubElement(custom, "numeric", name=name, data=str(value))


def compile_model(root: ET.Element, assets: dict[str, bytes]) -> mujoco.MjModel:
  return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"), assets)


def put_model(mj_model: mujoco.MjModel) -> mjx.Model:
  """The MJX model, on JAX's default device (`jax.default_device` where one is set: MJX itself
  would take the first device of the default backend)."""
  return mjx.put_model(mj_model, device=jax.config.jax_default_device, impl="jax")


def without_actuation(mj_model: mujoco.MjModel) -> mjx.Model:
  """The MJX model with actuation disabled, as dm_control runs `forward` after a reset."""
  model = copy.deepcopy(mj_model)
  model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION
  return put_model(model)


@full_precision
def position_velocity_stages(m: mjx.Model, d: mjx.Data) -> mjx.Data:
  """MuJoCo's `mj_step1`: position and velocity stages with their sensors."""
  d = mjx.fwd_position(m, d)
  d = mjx.sensor_pos(m, d)
  d = mjx.fwd_velocity(m, d)
  return mjx.sensor_vel(m, d)


@full_precision
def acceleration_stage_and_integrate(m: mjx.Model, d: mjx.Data,
                                     bounded_solver_loop: bool = False) -> mjx.Data:
  """MuJoCo's `mj_step2` for the Euler integrator: forces, constraint solve, sensors, advance."""
  d = mjx.fwd_actuation(m, d)
  d = mjx.fwd_acceleration(m, d)
  if d._impl.efc_J.size == 0:  # no constraint rows (e.g. reacher has contacts disabled)
    d = d.replace(qacc=d.qacc_smooth)
  else:
    d = (partitionable.solve if bounded_solver_loop else mjx.solve)(m, d)
  d = mjx.sensor_acc(m, d)
  return mjx.euler(m, d)


# `position_velocity_stages` as its own jitted function: a program that calls it twice (a parity
# check recomputes a recorded state's stages, then steps) traces it once. Used by parity checks
# only; the environments' step inlines the stages as before (its compiled program, and so its
# rounding, unchanged). Measured: quadruped's parity step traced in 16 s instead of 26 s.
shared_position_velocity_stages = jax.jit(position_velocity_stages)


@full_precision
def physics_step(m: mjx.Model, d: mjx.Data, n_substeps: int,
                 bounded_solver_loop: bool = False,
                 stages=position_velocity_stages) -> mjx.Data:
  """dm_control's `physics.step(n)`: `mj_step2; mj_step(n - 1); mj_step1`.

  Written as n repetitions of (mj_step2; mj_step1), the same sequence, so each stage is
  compiled once. `d` must have its position and velocity stages computed for its current
  qpos/qvel (true for every state this module returns); so does the result. `stages`: the
  position and velocity stages' function (`shared_position_velocity_stages` for parity checks).
  """
  def substep(d, _):
    d = acceleration_stage_and_integrate(m, d, bounded_solver_loop)
    return stages(m, d), None
  d, _ = jax.lax.scan(substep, d, None, length=n_substeps)
  return d


@full_precision
def has_contacts(m: mjx.Model, d: mjx.Data) -> jax.Array:
  """Whether MuJoCo's collision detection reports any contact (`ncon > 0`) at d.qpos."""
  d = mjx.kinematics(m, d)
  d = mjx.collision(m, d)
  if d._impl.contact.dist.size == 0:
    return jnp.array(False)
  contact = d._impl.contact
  return jnp.any(contact.dist < contact.includemargin)


def physics_state_is_finite(d: mjx.Data) -> jax.Array:
  """False where qpos, qvel, act or qacc hold NaN or inf (MuJoCo's bad-state warnings)."""
  parts = (d.qpos, d.qvel, d.act, d.qacc)
  return jnp.all(jnp.stack([jnp.all(jnp.isfinite(p)) for p in parts]))
