"""``StewartBallTrack-v0``: make the ball follow a moving target."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from stewart_gym.envs.targets import TRACK_TRAJECTORIES, TRAJECTORIES, Fixed, Target, make_trajectory
from stewart_gym.envs.task import XY, BallTask
from stewart_gym.errors import ConfigError

if TYPE_CHECKING:
    from stewart_gym.sim.backend import PhysicsBackend

__all__ = ["TrackTask"]


class TrackTask(BallTask):
    """Make the ball follow a moving target.

    ``trajectory``: ``"circle"`` (radius 60 mm, 8 s a turn, like source 001's
    circle), ``"figure8"`` (±70 mm, 10 s a loop) or ``"waypoints"`` (random
    points within 70 mm, held 2 s, 1 s moves), with a random phase each
    episode; ``"mixed"`` draws one of the three each episode (for training a
    tracker that follows them all). Success: the ball has stayed within 20 mm of the moving target for
    the last second (``success_radius`` 0.02).
    """

    name = "track"
    moving_target = True
    default_success_radius = 0.020

    def __init__(self, trajectory: str = "circle", **kwargs: Any) -> None:
        if trajectory not in TRACK_TRAJECTORIES:
            raise ConfigError(f"trajectory must be one of {TRACK_TRAJECTORIES}, got {trajectory!r}")
        super().__init__(**kwargs)
        self.trajectory = trajectory
        #: The trajectory of the current episode (one of the three; "mixed" draws it at each reset).
        self.current_trajectory = trajectory
        self._target: Target = Fixed()

    def reset(self, rng: np.random.Generator, backend: PhysicsBackend) -> None:
        super().reset(rng, backend)
        name = TRAJECTORIES[int(rng.integers(len(TRAJECTORIES)))] if self.trajectory == "mixed" else self.trajectory
        self._target = make_trajectory(name, rng)
        self.current_trajectory = name

    def target(self, t: float) -> tuple[XY, XY]:
        return self._target(t)
