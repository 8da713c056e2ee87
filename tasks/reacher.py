"""Reacher domain (dm_control/suite/reacher.py): easy and hard."""

from __future__ import annotations

import collections

import jax
import jax.numpy as jnp

from mjx_form.sim import physics as physics_lib
from mjx_form.sim import randomizers
from mjx_form.sim.rewards import tolerance
from tasks.common import ControlSuiteTask

_BIG_TARGET = .05
_SMALL_TARGET = .015


class Reacher(ControlSuiteTask):
  """Reach a randomly placed target with the two-link arm's fingertip."""

  domain = "reacher"
  observation_elements = (("position", 2), ("to_target", 2), ("velocity", 2))
  periodic_observations = ("position[0]",)  # the shoulder (no joint limit)
  xml_file = "reacher.xml"
  n_substeps = 1  # physics dt 0.02 = control dt
  fast_settings = physics_lib.SolverSettings()  # contacts are disabled: nothing to solve

  def __init__(self, target_size: float, task: str, physics: str = physics_lib.DEFAULT_PHYSICS):
    self.task = task
    self.target_size = target_size
    super().__init__(physics)
    self._finger = self.geom_id("finger")
    self._finger_size = float(self.mj_model.geom_size[self._finger, 0])

  def initialize_episode(self, data, key):
    joint_key, angle_key, radius_key = jax.random.split(key, 3)
    qpos = randomizers.randomize_limited_and_rotational_joints(self.mj_model, data.qpos, joint_key)
    # dm_control moves the target geom (a child of the world body, so geom_xpos == geom_pos).
    angle = jax.random.uniform(angle_key, minval=0, maxval=2 * jnp.pi)
    radius = jax.random.uniform(radius_key, minval=.05, maxval=.20)
    target = jnp.stack([radius * jnp.sin(angle), radius * jnp.cos(angle)])
    return data.replace(qpos=qpos), {"target": target}

  def finger_to_target(self, data, task):
    """Vector from the finger to the target in global coordinates (x, y)."""
    return task["target"] - data.geom_xpos[self._finger, :2]

  def get_observation(self, data, task):
    obs = collections.OrderedDict()
    obs["position"] = data.qpos
    obs["to_target"] = self.finger_to_target(data, task)
    obs["velocity"] = data.qvel
    return obs

  def get_reward(self, data, task):
    radii = self.target_size + self._finger_size
    distance = jnp.linalg.norm(self.finger_to_target(data, task))
    return tolerance(distance, (0, radii))


def easy(physics: str = physics_lib.DEFAULT_PHYSICS) -> Reacher:
  return Reacher(_BIG_TARGET, "easy", physics)


def hard(physics: str = physics_lib.DEFAULT_PHYSICS) -> Reacher:
  return Reacher(_SMALL_TARGET, "hard", physics)
