"""The 13 Control Suite tasks of the FORM paper, on MJX, by name (`humanoid_run`)."""

from __future__ import annotations

from typing import Callable

from mjx_form.env import Task
from mjx_form.physics import DEFAULT_PHYSICS, PHYSICS_MODES, check_physics_mode
from tasks import cheetah, hopper, humanoid, quadruped, reacher, walker

_REGISTRY: dict[str, Callable[[str], Task]] = {
    "reacher_easy": reacher.easy,
    "reacher_hard": reacher.hard,
    "cheetah_run": cheetah.run,
    "quadruped_walk": quadruped.walk,
    "quadruped_run": quadruped.run,
    "hopper_stand": hopper.stand,
    "hopper_hop": hopper.hop,
    "walker_stand": walker.stand,
    "walker_walk": walker.walk,
    "walker_run": walker.run,
    "humanoid_stand": humanoid.stand,
    "humanoid_walk": humanoid.walk,
    "humanoid_run": humanoid.run,
}
TASKS: tuple[str, ...] = tuple(_REGISTRY)


def make(name: str, physics: str = DEFAULT_PHYSICS) -> Task:
  """Builds the task `name` (e.g. 'humanoid_run') with the physics mode 'parity' or 'fast'."""
  if name not in _REGISTRY:
    raise ValueError(f"unknown task {name!r}; valid tasks: {', '.join(TASKS)}")
  return _REGISTRY[name](check_physics_mode(physics))


__all__ = ["TASKS", "PHYSICS_MODES", "make"]
