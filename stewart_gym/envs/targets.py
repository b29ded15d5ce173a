"""Where the ball should be: fixed targets and moving reference trajectories on the plate.

A target is called with the time t (s) and returns position (2,) m and velocity
(2,) m/s in the plate frame.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

__all__ = ["TRAJECTORIES", "Circle", "FigureEight", "Fixed", "Target", "Waypoints", "make_trajectory"]


class Target(Protocol):
    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]: ...


class Fixed:
    """A fixed point (default the plate centre)."""

    def __init__(self, xy: tuple[float, float] = (0.0, 0.0)) -> None:
        self.xy = np.asarray(xy, dtype=np.float64)

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.xy.copy(), np.zeros(2)


class Circle:
    """A circle of ``radius`` m traced every ``period`` s (seed 001's circular motion, scaled to the plate)."""

    def __init__(self, radius: float = 0.06, period: float = 8.0, phase: float = 0.0) -> None:
        self.radius, self.omega, self.phase = radius, 2 * math.pi / period, phase

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        a = self.omega * t + self.phase
        r, w = self.radius, self.omega
        return np.array([r * math.cos(a), r * math.sin(a)]), np.array([-r * w * math.sin(a), r * w * math.cos(a)])


class FigureEight:
    """A lemniscate of Gerono: x = A sin(ωt), y = A sin(ωt) cos(ωt); one loop every ``period`` s."""

    def __init__(self, amplitude: float = 0.07, period: float = 10.0, phase: float = 0.0) -> None:
        self.amplitude, self.omega, self.phase = amplitude, 2 * math.pi / period, phase

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        a, w, amp = self.omega * t + self.phase, self.omega, self.amplitude
        pos = np.array([amp * math.sin(a), amp * math.sin(a) * math.cos(a)])
        vel = np.array([amp * w * math.cos(a), amp * w * math.cos(2 * a)])
        return pos, vel


class Waypoints:
    """Random waypoints within ``radius`` m: hold each ``hold_s``, then move to the next in ``move_s`` (smooth step)."""

    def __init__(self, rng: np.random.Generator, radius: float = 0.07, hold_s: float = 2.0, move_s: float = 1.0,
                 count: int = 32) -> None:  # fmt: skip
        ang = rng.uniform(0, 2 * math.pi, count)
        rad = radius * np.sqrt(rng.uniform(0, 1, count))
        self.points = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
        self.points[0] = 0.0
        self.hold_s, self.move_s = hold_s, move_s

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        period = self.hold_s + self.move_s
        k = int(t // period)
        a, b = self.points[k % len(self.points)], self.points[(k + 1) % len(self.points)]
        tau = t - k * period - self.hold_s
        if tau <= 0:
            return a.copy(), np.zeros(2)
        s = tau / self.move_s  # smoothstep 3s² − 2s³ from a to b
        return a + (b - a) * (3 * s * s - 2 * s**3), (b - a) * (6 * s - 6 * s * s) / self.move_s


TRAJECTORIES = ("circle", "figure8", "waypoints")


def make_trajectory(name: str, rng: np.random.Generator) -> Target:
    """A moving target by name (:data:`TRAJECTORIES`), with a random phase drawn from ``rng``."""
    phase = float(rng.uniform(0, 2 * math.pi))
    if name == "circle":
        return Circle(phase=phase)
    if name == "figure8":
        return FigureEight(phase=phase)
    if name == "waypoints":
        return Waypoints(rng)
    raise ValueError(f"trajectory must be one of {TRAJECTORIES}, got {name!r}")
