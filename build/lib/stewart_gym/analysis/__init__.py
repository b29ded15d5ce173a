"""Kinematic analyses built on the kinematics core: workspace, trajectories, sensitivity, planar FK."""

from stewart_gym.analysis.trajectories import aggressive_moves
from stewart_gym.kinematics import axis_ranges

__all__ = ["aggressive_moves", "axis_ranges"]
