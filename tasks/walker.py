"""Planar walker domain (dm_control/suite/walker.py): stand, walk and run."""

from __future__ import annotations

import collections

from mjx_form.sim import physics as physics_lib
from mjx_form.sim import randomizers
from mjx_form.sim.rewards import tolerance
from tasks.common import ControlSuiteTask

_STAND_HEIGHT = 1.2
_WALK_SPEED = 1
_RUN_SPEED = 8


class PlanarWalker(ControlSuiteTask):
  """Stand (move_speed 0) or move forward at `move_speed` or faster."""

  domain = "walker"
  observation_elements = (("orientations", 14), ("height", 1), ("velocity", 9))
  xml_file = "walker.xml"
  n_substeps = 10  # physics dt 0.0025, control dt 0.025
  fast_settings = physics_lib.SolverSettings(iterations=10, ls_iterations=10, max_contact_points=8,
                                             max_geom_pairs=8)  # benchmarks/solver_sweep.py

  def __init__(self, move_speed: float, task: str, physics: str = physics_lib.DEFAULT_PHYSICS):
    self.move_speed = move_speed
    self.task = task
    super().__init__(physics)
    self._torso = self.body_id("torso")
    self._speed = self.sensor_slice("torso_subtreelinvel").start

  def initialize_episode(self, data, key):
    qpos = randomizers.randomize_limited_and_rotational_joints(self.mj_model, data.qpos, key)
    return data.replace(qpos=qpos), {}

  def torso_upright(self, data):
    return data.xmat[self._torso, 2, 2]

  def torso_height(self, data):
    return data.xpos[self._torso, 2]

  def horizontal_velocity(self, data):
    return data.sensordata[self._speed]

  def orientations(self, data):
    """xx and xz entries of every body's orientation except the world's."""
    return data.xmat[1:, 0, :3:2].ravel()

  def get_observation(self, data, task):
    obs = collections.OrderedDict()
    obs["orientations"] = self.orientations(data)
    obs["height"] = self.torso_height(data)
    obs["velocity"] = data.qvel
    return obs

  def get_reward(self, data, task):
    standing = tolerance(self.torso_height(data), bounds=(_STAND_HEIGHT, float("inf")),
                         margin=_STAND_HEIGHT / 2)
    upright = (1 + self.torso_upright(data)) / 2
    stand_reward = (3 * standing + upright) / 4
    if self.move_speed == 0:
      return stand_reward
    move_reward = tolerance(self.horizontal_velocity(data),
                            bounds=(self.move_speed, float("inf")), margin=self.move_speed / 2,
                            value_at_margin=0.5, sigmoid="linear")
    return stand_reward * (5 * move_reward + 1) / 6


def stand(physics: str = physics_lib.DEFAULT_PHYSICS) -> PlanarWalker:
  return PlanarWalker(0, "stand", physics)


def walk(physics: str = physics_lib.DEFAULT_PHYSICS) -> PlanarWalker:
  return PlanarWalker(_WALK_SPEED, "walk", physics)


def run(physics: str = physics_lib.DEFAULT_PHYSICS) -> PlanarWalker:
  return PlanarWalker(_RUN_SPEED, "run", physics)
