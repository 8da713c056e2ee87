"""The 13 Control Suite tasks of the FORM paper, on MJX, by name (`humanoid_run`)."""

from __future__ import annotations

import functools
import os
from typing import Callable

import jax

from mjx_form.sim.env import Task
from mjx_form.sim.physics import DEFAULT_PHYSICS, PHYSICS_MODES, check_physics_mode
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

# Trained expert policies shipped with the suite: experts/<task>.npz (format:
# mjx_form.files.policy_io).
EXPERTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "experts")


def _check_name(name: str) -> None:
  if name not in _REGISTRY:
    raise ValueError(f"unknown task {name!r}; valid tasks: {', '.join(TASKS)}")


def make(name: str, physics: str = DEFAULT_PHYSICS) -> Task:
  """The task `name` (e.g. 'humanoid_run') with the physics mode 'parity' or 'fast'.

  One object per task, physics mode, default device and float width in a process, shared by
  every caller: its jitted `reset` and `step` are then traced once for every run of the process
  that steps it (a cached trace of MJX saves each further run of a test suite or a sweep ~5 s
  of tracing on the CPU). Do not change it; `build` gives an object of one's own.
  """
  _check_name(name)
  return _make(_REGISTRY[name], check_physics_mode(physics), jax.config.jax_default_device,
               jax.config.jax_enable_x64)


def build(name: str, physics: str = DEFAULT_PHYSICS) -> Task:
  """A new task object (`make` without the sharing), e.g. to change it in a test."""
  _check_name(name)
  return _REGISTRY[name](check_physics_mode(physics))


@functools.cache
def _make(factory: Callable[[str], Task], physics, device, x64: bool) -> Task:
  del device, x64  # (keys: the model's arrays are placed on the default device at its width)
  return factory(physics)


def clear_cache() -> None:
  """Forgets the tasks `make` built: the next call builds (and its first run traces) afresh."""
  _make.cache_clear()


# FORM demonstrator effect models trained on the shipped experts' demonstrations:
# demonstrators/<task>.npz (format: mjx_form.files.effect_models).
DEMONSTRATORS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "demonstrators")


def bundled_demonstrator(name: str) -> str | None:
  """The path of the shipped demonstrator model for task `name`, or None if none is shipped."""
  _check_name(name)
  path = os.path.join(DEMONSTRATORS_DIR, f"{name}.npz")
  return path if os.path.isfile(path) else None


def bundled_experts() -> dict[str, str]:
  """{task name: path} of the expert policies shipped in tasks/experts/, in task order."""
  paths = {name: os.path.join(EXPERTS_DIR, f"{name}.npz") for name in TASKS}
  return {name: path for name, path in paths.items() if os.path.isfile(path)}


def bundled_expert(name: str) -> str:
  """The path of the shipped expert policy for task `name`; a clear error if there is none."""
  _check_name(name)
  available = bundled_experts()
  if name not in available:
    raise ValueError(f"no shipped expert for {name!r} (shipped: {', '.join(available) or 'none'});"
                     f" train one with: python scripts/run.py --task {name} --method expert "
                     "--num_envs 512 --updates_per_iteration 128 --env_steps 40000000 (README: "
                     "Training an expert)")
  return available[name]


__all__ = ["TASKS", "PHYSICS_MODES", "EXPERTS_DIR", "DEMONSTRATORS_DIR", "bundled_demonstrator",
           "bundled_expert", "bundled_experts", "make"]
