"""dm_control's joint randomisation (`suite/utils/randomizers.py`) as a pure JAX function."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np


def random_limited_quaternion(key: jax.Array, limit: float) -> jax.Array:
  """A rotation about a uniformly random axis by an angle uniform in [0, limit)."""
  axis_key, angle_key = jax.random.split(key)
  axis = jax.random.normal(axis_key, (3,))
  axis = axis / jnp.linalg.norm(axis)
  angle = jax.random.uniform(angle_key) * limit
  return jnp.concatenate([jnp.cos(angle / 2)[None], jnp.sin(angle / 2) * axis])


def randomize_limited_and_rotational_joints(mj_model: mujoco.MjModel, qpos: jax.Array,
                                            key: jax.Array) -> jax.Array:
  """Returns `qpos` with joints drawn as dm_control draws them.

  - limited hinges and slides: uniform in their range;
  - unlimited hinges: uniform in [-pi, pi];
  - limited balls: random axis, angle uniform up to the range's upper limit;
  - unlimited balls: uniform on the unit 3-sphere;
  - free joints: quaternion `rand(4)` normalised (dm_control's own, not uniform, choice),
    position left as it is;
  - unlimited slides: unchanged.
  """
  keys = jax.random.split(key, mj_model.njnt)
  jt = mujoco.mjtJoint
  for j in range(mj_model.njnt):
    adr = int(mj_model.jnt_qposadr[j])
    kind = mujoco.mjtJoint(int(mj_model.jnt_type[j]))
    lo, hi = (float(v) for v in mj_model.jnt_range[j])
    if mj_model.jnt_limited[j]:
      if kind in (jt.mjJNT_HINGE, jt.mjJNT_SLIDE):
        qpos = qpos.at[adr].set(jax.random.uniform(keys[j], minval=lo, maxval=hi))
      elif kind == jt.mjJNT_BALL:
        qpos = qpos.at[adr:adr + 4].set(random_limited_quaternion(keys[j], hi))
    else:
      if kind == jt.mjJNT_HINGE:
        qpos = qpos.at[adr].set(jax.random.uniform(keys[j], minval=-np.pi, maxval=np.pi))
      elif kind == jt.mjJNT_BALL:
        quat = jax.random.normal(keys[j], (4,))
        qpos = qpos.at[adr:adr + 4].set(quat / jnp.linalg.norm(quat))
      elif kind == jt.mjJNT_FREE:
        quat = jax.random.uniform(keys[j], (4,))
        qpos = qpos.at[adr + 3:adr + 7].set(quat / jnp.linalg.norm(quat))
  return qpos
