"""PyBullet simulation of servo Stewart platforms: URDF generation, hobby-servo model, simulator."""

from stewart_gym.sim.backend import BallSpec, PhysicsBackend, PlateLoad
from stewart_gym.sim.servo_model import HobbyServos, ServoSpec
from stewart_gym.sim.stewart_sim import PhysicsSpec, StewartSim
from stewart_gym.sim.urdf import MechanismSpec, mechanism_urdf, plate_urdf, write_urdfs

__all__ = [
    "BallSpec",
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
