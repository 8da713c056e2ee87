"""Humanoid domain (dm_control/suite/humanoid.py): stand, walk and run (egocentric features)."""

from __future__ import annotations

import collections

import jax
import jax.numpy as jnp

from mjx_form.sim import physics as physics_lib
from mjx_form.sim import randomizers
from mjx_form.sim.rewards import tolerance
from tasks.common import ControlSuiteTask

_STAND_HEIGHT = 1.4
_WALK_SPEED = 1
_RUN_SPEED = 10
# dm_control redraws until the pose has no contact, without a bound. Under vmap every
# environment waits for the slowest, so we stop after this many draws and flag the reset.
MAX_RESET_DRAWS = 1000


class Humanoid(ControlSuiteTask):
  """Stand (move_speed 0) or move at `move_speed` or faster."""

  domain = "humanoid"
  observation_elements = (("joint_angles", 21), ("head_height", 1), ("extremities", 12),
                          ("torso_vertical", 3), ("com_velocity", 3), ("velocity", 27))
  xml_file = "humanoid.xml"
  n_substeps = 5  # physics dt 0.005, control dt 0.025
  fast_settings = physics_lib.SolverSettings(iterations=10, ls_iterations=10)  # no culling: see the sweep

  def __init__(self, move_speed: float, task: str, physics: str = physics_lib.DEFAULT_PHYSICS):
    self.move_speed = move_speed
    self.task = task
    super().__init__(physics)
    self._torso, self._head = self.body_id("torso"), self.body_id("head")
    self._extremities = jnp.array([self.body_id(side + limb) for side in ("left_", "right_")
                                   for limb in ("hand", "foot")])
    self._com_velocity = self.sensor_slice("torso_subtreelinvel")

  def initialize_episode(self, data, key):
    """Random joints, redrawn until the pose is free of contacts (`ncon == 0`)."""
    def draw(key):
      key, joint_key = jax.random.split(key)
      qpos = randomizers.randomize_limited_and_rotational_joints(self.mj_model, data.qpos,
                                                                 joint_key)
      penetrating = physics_lib.has_contacts(self.mjx_model, data.replace(qpos=qpos))
      return key, qpos, penetrating

    def redraw(carry):
      key, _, _, draws = carry
      return (*draw(key), draws + 1)

    def penetrating(carry):
      return carry[2] & (carry[3] < MAX_RESET_DRAWS)

    # The first draw happens inside the loop (draws 0 -> 1), so the contact check is traced once.
    start = (key, data.qpos, jnp.bool_(True), jnp.int32(0))
    _, qpos, still_penetrating, draws = jax.lax.while_loop(penetrating, redraw, start)
    return data.replace(qpos=qpos), {"reset_draws": draws,
                                     "reset_penetrating": still_penetrating}

  def torso_upright(self, data):
    return data.xmat[self._torso, 2, 2]

  def head_height(self, data):
    return data.xpos[self._head, 2]

  def center_of_mass_velocity(self, data):
    return data.sensordata[self._com_velocity]

  def torso_vertical_orientation(self, data):
    return data.xmat[self._torso, 2, :]  # zx, zy, zz

  def joint_angles(self, data):
    return data.qpos[7:]  # skips the free root joint

  def extremities(self, data):
    """Hand and foot positions in the torso's frame: left hand, left foot, right hand, right foot."""
    torso_frame = data.xmat[self._torso]
    torso_to_limb = data.xpos[self._extremities] - data.xpos[self._torso]
    return (torso_to_limb @ torso_frame).ravel()

  def get_observation(self, data, task):
    obs = collections.OrderedDict()
    obs["joint_angles"] = self.joint_angles(data)
    obs["head_height"] = self.head_height(data)
    obs["extremities"] = self.extremities(data)
    obs["torso_vertical"] = self.torso_vertical_orientation(data)
    obs["com_velocity"] = self.center_of_mass_velocity(data)
    obs["velocity"] = data.qvel
    return obs

  def get_reward(self, data, task):
    standing = tolerance(self.head_height(data), bounds=(_STAND_HEIGHT, float("inf")),
                         margin=_STAND_HEIGHT / 4)
    upright = tolerance(self.torso_upright(data), bounds=(0.9, float("inf")), sigmoid="linear",
                        margin=1.9, value_at_margin=0)
    stand_reward = standing * upright
    small_control = tolerance(data.ctrl, margin=1, value_at_margin=0, sigmoid="quadratic").mean()
    small_control = (4 + small_control) / 5
    horizontal_velocity = self.center_of_mass_velocity(data)[:2]
    if self.move_speed == 0:
      dont_move = tolerance(horizontal_velocity, margin=2).mean()
      return small_control * stand_reward * dont_move
    move = tolerance(jnp.linalg.norm(horizontal_velocity), bounds=(self.move_speed, float("inf")),
                     margin=self.move_speed, value_at_margin=0, sigmoid="linear")
    move = (5 * move + 1) / 6
    return small_control * stand_reward * move


def stand(physics: str = physics_lib.DEFAULT_PHYSICS) -> Humanoid:
  return Humanoid(0, "stand", physics)


def walk(physics: str = physics_lib.DEFAULT_PHYSICS) -> Humanoid:
  return Humanoid(_WALK_SPEED, "walk", physics)


def run(physics: str = physics_lib.DEFAULT_PHYSICS) -> Humanoid:
  return Humanoid(_RUN_SPEED, "run", physics)
