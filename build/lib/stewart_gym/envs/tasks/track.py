"""``StewartBallTrack-v0``: make the ball follow a moving target."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from stewart_gym.envs.targets import TRAJECTORIES, Fixed, Target, make_trajectory
from stewart_gym.envs.task import XY, BallTask
from stewart_gym.errors import ConfigError

if TYPE_CHECKING:
    from stewart_gym.sim.backend import PhysicsBackend

__all__ = ["TrackTask"]


class TrackTask(BallTask):
    """Make the ball follow a moving target.

    ``trajectory``: ``"circle"`` (radius 60 mm, 8 s a turn, like seed 001's
    circle), ``"figure8"`` (±70 mm, 10 s a loop) or ``"waypoints"`` (random
    points within 70 mm, held 2 s, 1 s moves), with a random phase each
    episode. Success: the ball has stayed within 20 mm of the moving target for
    the last second (``success_radius`` 0.02).
    """

    name = "track"
    moving_target = True
    default_success_radius = 0.020

    def __init__(self, trajectory: str = "circle", **kwargs: Any) -> None:
        if trajectory not in TRAJECTORIES:
            raise ConfigError(f"trajectory must be one of {TRAJECTORIES}, got {trajectory!r}")
        super().__init__(**kwargs)
        self.trajectory = trajectory
        self._target: Target = Fixed()

    def reset(self, rng: np.random.Generator, backend: PhysicsBackend) -> None:
        self._target = make_trajectory(self.trajectory, rng)

    def target(self, t: float) -> tuple[XY, XY]:
        return self._target(t)
