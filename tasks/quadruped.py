"""Quadruped domain (dm_control/suite/quadruped.py): walk and run.

As dm_control does for these two tasks, the model drops the terrain, the rangefinders, the
walls, the ball and the target, and sizes the floor by the task's speed.
"""

from __future__ import annotations

import collections

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_form.sim import physics as physics_lib
from mjx_form.sim.rewards import tolerance
from tasks.common import ControlSuiteTask, read_model

_DEFAULT_TIME_LIMIT = 20
_RUN_SPEED = 5
_WALK_SPEED = 0.5
_WALLS = ("wall_px", "wall_py", "wall_nx", "wall_ny")
_HEIGHT_STEP = 0.01  # dm_control raises the body in 1 cm steps until nothing touches
MAX_HEIGHT_STEPS = 10000  # dm_control gives up after this many steps


class Move(ControlSuiteTask):
  """Move forward at `desired_speed` or faster while staying upright."""

  domain = "quadruped"
  observation_elements = (("egocentric_state", 44), ("torso_velocity", 3), ("torso_upright", 1),
                          ("imu", 6), ("force_torque", 24))
  xml_file = "quadruped.xml"
  n_substeps = 4  # physics dt 0.005, control dt 0.02
  fast_settings = physics_lib.SolverSettings(iterations=10, ls_iterations=10, max_contact_points=8,
                                             max_geom_pairs=8)  # benchmarks/solver_sweep.py

  def __init__(self, desired_speed: float, task: str,
               physics: str = physics_lib.DEFAULT_PHYSICS):
    self.desired_speed = desired_speed
    self.task = task
    super().__init__(physics)
    m = self.mj_model
    self._torso = self.body_id("torso")
    hinges = np.nonzero(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)[0]
    self._hinge_qpos = jnp.array(m.jnt_qposadr[hinges])
    self._hinge_qvel = jnp.array(m.jnt_dofadr[hinges])
    self._velocimeter = self.sensor_slice("velocimeter")
    sensor = mujoco.mjtSensor
    self._imu = jnp.array(self.sensor_indices(sensor.mjSENS_GYRO, sensor.mjSENS_ACCELEROMETER))
    self._force_torque = jnp.array(self.sensor_indices(sensor.mjSENS_FORCE,
                                                       sensor.mjSENS_TORQUE))
    root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "root")
    self._root_qpos = int(m.jnt_qposadr[root])

  def model_xml(self):
    root = read_model(self.xml_file)
    floor_size = _DEFAULT_TIME_LIMIT * self.desired_speed
    _find(root, "geom", "floor").set("size", f"{floor_size} {floor_size} .5")
    for name in _WALLS:
      _remove(root, "geom", name)
    _remove(root, "body", "ball")
    _remove(root, "site", "target")
    _remove(root, "geom", "terrain")
    for parent in root.iter():
      for rangefinder in parent.findall("rangefinder"):
        parent.remove(rangefinder)
    return root

  def initialize_episode(self, data, key):
    """A random orientation at the lowest height, on a 1 cm grid from 0, free of contacts."""
    orientation = jax.random.normal(key, (4,))
    orientation = orientation / jnp.linalg.norm(orientation)
    r = self._root_qpos

    def pose(steps):
      qpos = data.qpos.at[r:r + 3].set(jnp.array([0.0, 0.0, steps * _HEIGHT_STEP]))
      return qpos.at[r + 3:r + 7].set(orientation)

    def touching(steps):
      return physics_lib.has_contacts(self.mjx_model, data.replace(qpos=pose(steps)))

    def raise_body(carry):
      steps, _ = carry
      return steps + 1, touching(steps + 1)

    def keep_raising(carry):
      steps, contact = carry
      return contact & (steps < MAX_HEIGHT_STEPS)

    # Starts one step below 0 and "touching", so the loop's first pass checks height 0: the
    # contact check is traced once (the costly part of compiling a reset).
    steps, _ = jax.lax.while_loop(keep_raising, raise_body, (jnp.int32(-1), jnp.bool_(True)))
    return data.replace(qpos=pose(steps)), {}

  def torso_upright(self, data):
    return data.xmat[self._torso, 2, 2]

  def torso_velocity(self, data):
    return data.sensordata[self._velocimeter]

  def egocentric_state(self, data):
    return jnp.concatenate([data.qpos[self._hinge_qpos], data.qvel[self._hinge_qvel], data.act])

  def get_observation(self, data, task):
    obs = collections.OrderedDict()
    obs["egocentric_state"] = self.egocentric_state(data)
    obs["torso_velocity"] = self.torso_velocity(data)
    obs["torso_upright"] = self.torso_upright(data)
    obs["imu"] = data.sensordata[self._imu]
    obs["force_torque"] = jnp.arcsinh(data.sensordata[self._force_torque])
    return obs

  def get_reward(self, data, task):
    move_reward = tolerance(self.torso_velocity(data)[0],
                            bounds=(self.desired_speed, float("inf")),
                            margin=self.desired_speed, value_at_margin=0.5, sigmoid="linear")
    # dm_control's _upright_reward with deviation_angle=0: cos(0) = 1.
    upright = tolerance(self.torso_upright(data), bounds=(1.0, float("inf")), sigmoid="linear",
                        margin=2.0, value_at_margin=0)
    return upright * move_reward


def _find(root, tag, name):
  for parent in root.iter():
    for child in parent.findall(tag):
      if child.get("name") == name:
        return child
  raise KeyError(f"no <{tag} name={name!r}> in the quadruped model")


def _remove(root, tag, name):
  for parent in root.iter():
    for child in parent.findall(tag):
      if child.get("name") == name:
        parent.remove(child)
        return
  raise KeyError(f"no <{tag} name={name!r}> in the quadruped model")


def walk(physics: str = physics_lib.DEFAULT_PHYSICS) -> Move:
  return Move(_WALK_SPEED, "walk", physics)


def run(physics: str = physics_lib.DEFAULT_PHYSICS) -> Move:
  return Move(_RUN_SPEED, "run", physics)
