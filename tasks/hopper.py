"""Hopper domain (dm_control/suite/hopper.py): stand and hop."""

from __future__ import annotations

import collections

import jax.numpy as jnp

from mjx_form.sim import physics as physics_lib
from mjx_form.sim import randomizers
from mjx_form.sim.rewards import tolerance
from tasks.common import ControlSuiteTask

_STAND_HEIGHT = 0.6
_HOP_SPEED = 2


class Hopper(ControlSuiteTask):
  """Stand upright (hopping=False) or hop forward (hopping=True)."""

  domain = "hopper"
  hop_speed = _HOP_SPEED  # the speed hop's reward asks for (m/s)
  observation_elements = (("position", 6), ("velocity", 7), ("touch", 2))
  periodic_observations = ("position[1]",)  # rooty, the torso's pitch (no joint limit)
  xml_file = "hopper.xml"
  n_substeps = 4  # physics dt 0.005, control dt 0.02
  fast_settings = physics_lib.SolverSettings(iterations=10, ls_iterations=10, max_contact_points=8,
                                             max_geom_pairs=8)  # benchmarks/solver_sweep.py

  def __init__(self, hopping: bool, physics: str = physics_lib.DEFAULT_PHYSICS):
    self.hopping = hopping
    self.task = "hop" if hopping else "stand"
    super().__init__(physics)
    self._torso, self._foot = self.body_id("torso"), self.body_id("foot")
    self._speed = self.sensor_slice("torso_subtreelinvel").start
    self._touch = jnp.array([self.sensor_slice("touch_toe").start,
                             self.sensor_slice("touch_heel").start])

  def initialize_episode(self, data, key):
    qpos = randomizers.randomize_limited_and_rotational_joints(self.mj_model, data.qpos, key)
    return data.replace(qpos=qpos), {}

  def height(self, data):
    """Height of the torso with respect to the foot."""
    return data.xipos[self._torso, 2] - data.xipos[self._foot, 2]

  def speed(self, data):
    return data.sensordata[self._speed]

  def touch(self, data):
    return jnp.log1p(data.sensordata[self._touch])

  def get_observation(self, data, task):
    obs = collections.OrderedDict()
    obs["position"] = data.qpos[1:]  # ignores horizontal position
    obs["velocity"] = data.qvel
    obs["touch"] = self.touch(data)
    return obs

  def get_reward(self, data, task):
    standing = tolerance(self.height(data), (_STAND_HEIGHT, 2))
    if self.hopping:
      hopping = tolerance(self.speed(data), bounds=(self.hop_speed, float("inf")),
                          margin=self.hop_speed / 2, value_at_margin=0.5, sigmoid="linear")
      return standing * hopping
    small_control = tolerance(data.ctrl, margin=1, value_at_margin=0, sigmoid="quadratic").mean()
    small_control = (small_control + 4) / 5
    return standing * small_control


def stand(physics: str = physics_lib.DEFAULT_PHYSICS) -> Hopper:
  return Hopper(False, physics)


def hop(physics: str = physics_lib.DEFAULT_PHYSICS) -> Hopper:
  return Hopper(True, physics)
