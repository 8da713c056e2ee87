"""Corrections to MJX 3.17 where its JAX collision code departs from MuJoCo's C code.

Installed on import of `mjx_form.sim.physics`. Each correction is checked by the float64 parity
tests (tests/test_parity.py), which compare our step with dm_control's to rounding error.

- plane : capsule contact frames. MuJoCo C (`mjc_PlaneCapsule` + `mju_makeFrame`) always
  aligns the first tangent of both contacts with the capsule axis projected onto the plane.
  MJX uses a fixed tangent instead whenever that projection is shorter than 0.5 (capsules
  within 30 degrees of the plane normal). With the pyramidal friction cones of the Control
  Suite, the tangent frame changes the friction pyramid and so the contact forces: humanoid
  and hopper states with a steep limb on the floor stepped up to 0.16 (qvel) away from
  dm_control in float64 before this correction.
- sphere : capsule and capsule : capsule closest points. MJX regularises the divisions of its
  segment-distance routines with +1e-6, which moves contact points by up to ~1e-6 (relative)
  and, through the stiff contacts, humanoid velocities by up to ~1e-3 after one step. These
  follow MuJoCo C's closed forms (`mjraw_SphereCapsule`, `mjraw_CapsuleCapsule`). For exactly
  parallel capsules C may return two contacts; MJX's fixed contact count keeps the first.
"""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
from mujoco.mjx._src import collision_driver, collision_primitive, math
from mujoco.mjx._src.types import GeomType


@collision_primitive.collider(ncon=2)
def plane_capsule(plane, cap):
  """Two contacts between a plane and a capsule's end spheres, frames as MuJoCo C makes them."""
  n, axis = plane.mat[:, 2], cap.mat[:, 2]
  tangent = axis - n * jnp.dot(n, axis)  # mju_makeFrame: orthogonalise the hint, normalise
  norm = jnp.linalg.norm(tangent)
  safe = jnp.where(norm < mujoco.mjMINVAL, 1.0, norm)
  tangent = jnp.where(norm < mujoco.mjMINVAL, jnp.array([1.0, 0.0, 0.0]), tangent / safe)
  frame = jnp.stack([n, tangent, jnp.cross(n, tangent)])
  segment = axis * cap.size[1]
  dists, positions = [], []
  for offset in (segment, -segment):
    center = cap.pos + offset
    dist = jnp.dot(center - plane.pos, n) - cap.size[0]
    dists.append(dist)
    positions.append(center - n * (cap.size[0] + 0.5 * dist))
  return jnp.stack(dists), jnp.stack(positions), jnp.stack([frame, frame])


def _sphere_sphere(pos1, mat1, radius1, pos2, mat2, radius2):
  """MuJoCo C's `mjraw_SphereSphere`: distance, midpoint and frame (normal from 1 to 2)."""
  delta = pos2 - pos1
  length = jnp.linalg.norm(delta)
  degenerate = length < mujoco.mjMINVAL  # same centres: normal = cross of the z axes
  fallback = jnp.cross(mat1[:, 2], mat2[:, 2])
  fallback_norm = jnp.linalg.norm(fallback)
  fallback = jnp.where(fallback_norm < mujoco.mjMINVAL, jnp.array([1.0, 0.0, 0.0]),
                       fallback / jnp.where(fallback_norm < mujoco.mjMINVAL, 1.0, fallback_norm))
  normal = jnp.where(degenerate, fallback, delta / jnp.where(degenerate, 1.0, length))
  dist = length - radius1 - radius2
  pos = pos1 + normal * (radius1 + dist / 2)
  return dist, pos, math.make_frame(normal)


@collision_primitive.collider(ncon=1)
def sphere_capsule(sphere, cap):
  """One contact between a sphere and a capsule, as `mjraw_SphereCapsule`."""
  axis, half_length = cap.mat[:, 2], cap.size[1]
  x = jnp.clip(jnp.dot(axis, sphere.pos - cap.pos), -half_length, half_length)
  return _sphere_sphere(sphere.pos, sphere.mat, sphere.size[0], cap.pos + axis * x, cap.mat,
                        cap.size[0])


@collision_primitive.collider(ncon=1)
def capsule_capsule(cap1, cap2):
  """One contact between two capsules, as `mjraw_CapsuleCapsule` (general configuration)."""
  axis1, axis2 = cap1.mat[:, 2] * cap1.size[1], cap2.mat[:, 2] * cap2.size[1]
  dif = cap1.pos - cap2.pos
  ma, mb, mc = jnp.dot(axis1, axis1), -jnp.dot(axis1, axis2), jnp.dot(axis2, axis2)
  u, v = -jnp.dot(axis1, dif), jnp.dot(axis2, dif)
  det = ma * mc - mb * mb
  general = jnp.abs(det) >= mujoco.mjMINVAL
  safe_det = jnp.where(general, det, 1.0)
  x1 = (mc * u - mb * v) / safe_det
  x2 = (ma * v - mb * u) / safe_det
  x2 = jnp.where(x1 > 1, (v - mb) / mc, jnp.where(x1 < -1, (v + mb) / mc, x2))
  x1 = jnp.clip(x1, -1, 1)
  x1 = jnp.where(x2 > 1, jnp.clip((u - mb) / ma, -1, 1),
                 jnp.where(x2 < -1, jnp.clip((u + mb) / ma, -1, 1), x1))
  x2 = jnp.clip(x2, -1, 1)
  # Parallel axes: C's first candidate (x1 = 1).
  x1 = jnp.where(general, x1, 1.0)
  x2 = jnp.where(general, x2, jnp.clip((v - mb) / mc, -1, 1))
  return _sphere_sphere(cap1.pos + axis1 * x1, cap1.mat, cap1.size[0], cap2.pos + axis2 * x2,
                        cap2.mat, cap2.size[0])


def install() -> None:
  table = collision_driver._COLLISION_FUNC
  table[(GeomType.PLANE, GeomType.CAPSULE)] = plane_capsule
  table[(GeomType.SPHERE, GeomType.CAPSULE)] = sphere_capsule
  table[(GeomType.CAPSULE, GeomType.CAPSULE)] = capsule_capsule


install()
