"""Where the ball should be: fixed targets and moving reference trajectories on the plate.

A target is called with the time t (s) and returns its position (x, y) m and
velocity (vx, vy) m/s in the plate frame, as Python floats (it runs every
control step).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

__all__ = ["TRACK_TRAJECTORIES", "TRAJECTORIES", "Circle", "FigureEight", "Fixed", "Target", "Waypoints", "make_trajectory"]


XY = tuple[float, float]


class Target(Protocol):
    def __call__(self, t: float) -> tuple[XY, XY]: ...


class Fixed:
    """A fixed point (default the plate centre)."""

    def __init__(self, xy: tuple[float, float] = (0.0, 0.0)) -> None:
        self.xy = (float(xy[0]), float(xy[1]))

    def __call__(self, t: float) -> tuple[XY, XY]:
        return self.xy, (0.0, 0.0)


class Circle:
    """A circle of ``radius`` m traced every ``period`` s (source 001's circular motion, scaled to the plate)."""

    def __init__(self, radius: float = 0.06, period: float = 8.0, phase: float = 0.0) -> None:
        self.radius, self.omega, self.phase = radius, 2 * math.pi / period, phase

    def __call__(self, t: float) -> tuple[XY, XY]:
        a = self.omega * t + self.phase
        r, w = self.radius, self.omega
        return (r * math.cos(a), r * math.sin(a)), (-r * w * math.sin(a), r * w * math.cos(a))


class FigureEight:
    """A lemniscate of Gerono: x = A sin(ωt), y = A sin(ωt) cos(ωt); one loop every ``period`` s."""

    def __init__(self, amplitude: float = 0.07, period: float = 10.0, phase: float = 0.0) -> None:
        self.amplitude, self.omega, self.phase = amplitude, 2 * math.pi / period, phase

    def __call__(self, t: float) -> tuple[XY, XY]:
        a, w, amp = self.omega * t + self.phase, self.omega, self.amplitude
        return (amp * math.sin(a), amp * math.sin(a) * math.cos(a)), (amp * w * math.cos(a), amp * w * math.cos(2 * a))


class Waypoints:
    """Random waypoints within ``radius`` m: hold each ``hold_s``, then move to the next in ``move_s`` (smooth step)."""

    def __init__(self, rng: np.random.Generator, radius: float = 0.07, hold_s: float = 2.0, move_s: float = 1.0,
                 count: int = 32) -> None:  # fmt: skip
        ang = rng.uniform(0, 2 * math.pi, count)
        rad = radius * np.sqrt(rng.uniform(0, 1, count))
        points = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
        points[0] = 0.0
        self.points: list[XY] = [(float(x), float(y)) for x, y in points]
        self.hold_s, self.move_s = hold_s, move_s

    def __call__(self, t: float) -> tuple[XY, XY]:
        period = self.hold_s + self.move_s
        k = int(t // period)
        (ax, ay), (bx, by) = self.points[k % len(self.points)], self.points[(k + 1) % len(self.points)]
        tau = t - k * period - self.hold_s
        if tau <= 0:
            return (ax, ay), (0.0, 0.0)
        s = tau / self.move_s  # smoothstep 3s² − 2s³ from a to b
        p, dp = 3 * s * s - 2 * s**3, (6 * s - 6 * s * s) / self.move_s
        return (ax + (bx - ax) * p, ay + (by - ay) * p), ((bx - ax) * dp, (by - ay) * dp)


TRAJECTORIES = ("circle", "figure8", "waypoints")
#: What the track task takes: one of :data:`TRAJECTORIES`, or "mixed" (one of them drawn per episode).
TRACK_TRAJECTORIES = (*TRAJECTORIES, "mixed")


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
