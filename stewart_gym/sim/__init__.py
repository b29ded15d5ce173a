"""Physics of servo Stewart platforms: the backend seam, the PyBullet and MuJoCo backends, URDF and MJCF
generation, the hobby-servo model.

Submodules load on first use, so that ``stewart_gym.sim.engines`` (engine names for the command line) and
``stewart_gym.sim.backend`` import without PyBullet or MuJoCo installed (the ``[deploy]`` extra has neither).
"""

from __future__ import annotations

import importlib
from typing import Any

from stewart_gym.sim.backend import BallSpec, PhysicsBackend, PlateLoad

__all__ = [
    "BallSpec",
    "BatchedSim",
    "HobbyServos",
    "MechanismSpec",
    "PhysicsBackend",
    "PhysicsSpec",
    "PlateLoad",
    "ServoSpec",
    "StewartSim",
    "mechanism_urdf",
    "plate_urdf",
    "write_urdfs",
]

_LAZY = {
    "BatchedSim": "batched",
    "HobbyServos": "servo_model",
    "ServoSpec": "servo_model",
    "PhysicsSpec": "stewart_sim",
    "StewartSim": "stewart_sim",
    "MechanismSpec": "urdf",
    "mechanism_urdf": "urdf",
    "plate_urdf": "urdf",
    "write_urdfs": "urdf",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'stewart_gym.sim' has no attribute {name!r}")
    return getattr(importlib.import_module(f"stewart_gym.sim.{module}"), name)
