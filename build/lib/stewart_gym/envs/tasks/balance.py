"""``StewartBallBalance-v0``: hold the ball at the plate centre."""

from __future__ import annotations

from stewart_gym.envs.task import BallTask

__all__ = ["BalanceTask"]


class BalanceTask(BallTask):
    """Hold the ball at the plate centre. Success: within 10 mm of it for the last second."""

    name = "balance"
