"""Cheetah domain (dm_control/suite/cheetah.py): run."""

from __future__ import annotations

import collections

import jax
import jax.numpy as jnp

from mjx_form.sim import physics as physics_lib
from mjx_form.sim.rewards import tolerance
from tasks.common import ControlSuiteTask

_RUN_SPEED = 10
_SETTLE_STEPS = 200


class Cheetah(ControlSuiteTask):
  """Run forward as fast as possible."""

  domain = "cheetah"
  observation_elements = (("position", 8), ("velocity", 9))
  periodic_observations = ("position[1]",)  # rooty, the torso's pitch (no joint limit)
  task = "run"
  xml_file = "cheetah.xml"
  n_substeps = 1  # physics dt 0.01 = control dt
  fast_settings = physics_lib.SolverSettings(iterations=10, ls_iterations=10, max_contact_points=4,
                                             max_geom_pairs=4)  # benchmarks/solver_sweep.py

  def __init__(self, physics: str = physics_lib.DEFAULT_PHYSICS):
    super().__init__(physics)
    self._speed = self.sensor_slice("torso_subtreelinvel").start

  def initialize_episode(self, data, key):
    m = self.mj_model
    assert m.nq == m.njnt  # every joint has one degree of freedom, as dm_control asserts
    limited = m.jnt_limited == 1
    lower, upper = m.jnt_range[limited].T
    qpos = data.qpos.at[limited].set(
        jax.random.uniform(key, (int(limited.sum()),), minval=lower, maxval=upper))
    return self.settle(data, qpos), {}

  def settle(self, data, qpos):
    """dm_control's `physics.step(nstep=200)` with zero control from `qpos`, then time = 0.

    Its first mj_step2 uses the kinematics of mj_resetData's forward pass (at qpos0), since
    only qpos was overwritten before stepping; so does ours.
    """
    settled = self.after_reset(data).replace(qpos=qpos)
    settled = physics_lib.physics_step(self.mjx_model, settled, _SETTLE_STEPS,
                                       self.solver_settings.bounded_solver_loop)
    return settled.replace(time=jnp.zeros_like(settled.time))

  def speed(self, data):
    """Horizontal speed of the cheetah's torso subtree."""
    return data.sensordata[self._speed]

  def get_observation(self, data, task):
    obs = collections.OrderedDict()
    obs["position"] = data.qpos[1:]  # ignores horizontal position
    obs["velocity"] = data.qvel
    return obs

  def get_reward(self, data, task):
    return tolerance(self.speed(data), bounds=(_RUN_SPEED, float("inf")), margin=_RUN_SPEED,
                     value_at_margin=0, sigmoid="linear")


def run(physics: str = physics_lib.DEFAULT_PHYSICS) -> Cheetah:
  return Cheetah(physics)
