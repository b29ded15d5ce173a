"""What the classical controllers share: the episodic base, the integral, counting periods, the target's
acceleration fed forward, and the dither.

:class:`EpisodicController` is the base of every controller: a Stable-Baselines3-style ``predict`` that resets
the rows of a batch where an episode starts, and the observation read through
:class:`~stewart_gym.sensing.ObservationBuilder`'s accessors.
"""

from __future__ import annotations

import math

import numpy as np

from stewart_gym.control.arrays import bounded, planar_length
from stewart_gym.sensing import ObservationBuilder

__all__ = ["EpisodicController", "SquareWaveDither", "TargetFeed", "integrate_error", "periods_in_a_row",
           "whole_periods"]


class EpisodicController:
    """A controller whose state is one episode's, one row per ball in a batch: observation (…, obs size) → tilt
    action (…, 2) in [−1, 1].

    Subclasses implement :meth:`reset` (all rows, or the rows of a boolean mask) and ``__call__``; they read the
    observation through :attr:`observation` (an :class:`~stewart_gym.sensing.ObservationBuilder` of the plate
    the observations are scaled by).

    Args:
        plate_half: (h_x, h_y) m, half the plate's size (the observation's position scale).
    """

    def __init__(self, plate_half: tuple[float, float] = (0.15, 0.15)) -> None:
        self.observation = ObservationBuilder(2, plate_half)

    def reset(self, rows: np.ndarray | None = None) -> None:
        """Start of an episode: every row (``rows`` None) or the rows where the boolean mask ``rows`` is True."""
        raise NotImplementedError

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def predict(self, obs: np.ndarray, state: object = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        """Stable-Baselines3-style ``predict``: resets the rows where an episode starts (all of them for a single
        observation)."""
        if episode_start is not None and np.any(episode_start):
            starts = np.asarray(episode_start, dtype=bool)
            self.reset(None if starts.ndim == 0 or starts.all() else starts)
        return self(obs), None


class SquareWaveDither:
    """± ``dither`` rad of tilt (at action ±1 = ``max_tilt``) added to both axes of each action, the sign
    alternating every control period from + after :meth:`reset`: a square wave whose mean is zero. The servos'
    dead band (3–8 µs) otherwise swallows the small corrections of a quiet controller, and the ball rests
    where the last correction that got through left it. ``dither`` 0 passes actions through; it must be less
    than half ``max_tilt`` (more would leave the controller less than half its range: ``ValueError``)."""

    def __init__(self, dither: float, max_tilt: float) -> None:
        if not 0 <= dither < max_tilt / 2:
            raise ValueError(f"dither must be 0 (off) or more and less than half the build's max tilt "
                             f"({math.degrees(max_tilt) / 2:.2f}°), got {math.degrees(dither):.2f}°")  # fmt: skip
        self.step = dither / max_tilt
        self.sign = 1.0

    def reset(self) -> None:
        self.sign = 1.0

    def __call__(self, action: np.ndarray) -> np.ndarray:
        """``action`` (…, 2) in [−1, 1] plus this period's ± step, clipped to [−1, 1] (float32)."""
        if self.step <= 0:
            return np.asarray(action, dtype=np.float32)
        out = bounded(np.asarray(action, dtype=np.float64) + self.sign * self.step, -1.0, 1.0)
        self.sign = -self.sign
        return out.astype(np.float32)


def whole_periods(seconds: float, dt: float) -> int:
    """The control periods of ``dt`` s that make ``seconds``, rounded up (3 s at 50 Hz: 150; a float's last bit
    does not add one)."""
    return math.ceil(seconds / dt - 1e-9)


def periods_in_a_row(count: np.ndarray | None, condition: np.ndarray) -> np.ndarray:
    """How many periods in a row each row's ``condition`` has held, one period on from ``count`` (None, or a
    count of another shape: from the start)."""
    start = count if count is not None and count.shape == condition.shape else np.zeros(condition.shape, dtype=int)
    return np.where(condition, start + 1, 0)


def integrate_error(integral: np.ndarray, err: np.ndarray, dt: float, limit: float, zone: float) -> np.ndarray:
    """The integral of the position error one period on, held within ±``limit`` (anti-windup); with ``zone`` > 0,
    only rows whose error is at most ``zone`` (m) long integrate (conditional integration)."""
    step = err * dt
    if zone > 0:
        step = np.where(planar_length(err, keepdims=True) <= zone, step, 0.0)
    return bounded(integral + step, -limit, limit)


class TargetFeed:
    """The target's acceleration (m/s², …, 2) a controller feeds forward, from the target's velocity each period;
    one row per ball in a batch.

    The acceleration is the change of the target's velocity over the last period (0 in a row's first period).
    That backward difference is half a period late, and the servos take about two more periods to tilt the
    plate, so on a moving target the ball lags its path. With ``lead`` > 0 the acceleration is carried ``lead``
    s ahead along its rate of change (the velocity's second difference), but only once that rate has held
    steady, changing by at most :attr:`STEADY_CHANGE` of its size a period, for :attr:`STEADY_S`. On a smooth
    path (the circle, the figure-8) the extrapolation is right. Where the acceleration jumps (a waypoint move
    starts and ends with a jump) no extrapolation sees the jump coming, the ball starts behind, and leading
    the falling acceleration through the move would take feed away while it catches up.

    Args:
        dt: s, control period.
        lead: s, how far ahead (0: the acceleration as measured).
        divisor: what the velocity's change over a period is divided by: ``dt`` (the default) gives m/s²; the
            LQR passes ``dt·c·g`` for the ``sin(tilt)`` that rolls the ball so.
    """

    STEADY_CHANGE = 0.3
    STEADY_S = 1.5

    def __init__(self, dt: float, lead: float = 0.0, divisor: float | None = None) -> None:
        self.dt, self.lead = dt, lead
        self.divisor = dt if divisor is None else divisor
        self._steady_periods = whole_periods(self.STEADY_S, dt)
        self.reset()

    def reset(self, rows: np.ndarray | None = None) -> None:
        """Forget the target's past velocities: all of them, or those of the batch's ``rows`` (a boolean mask)."""
        if rows is None or self._vel is None or self._vel.shape[:-1] != np.shape(rows):
            self._vel: np.ndarray | None = None  # last period's velocity (NaN in a row: none yet)
            self._prev: np.ndarray | None = None  # the one before
            self._change: np.ndarray | None = None  # last period's second difference
            self._steady: np.ndarray | None = None  # periods in a row that it held steady
            return
        for past in (self._vel, self._prev, self._change):
            past[rows] = np.nan
        self._steady[rows] = 0

    def __call__(self, target_vel: np.ndarray) -> np.ndarray:
        v = np.asarray(target_vel, dtype=np.float64)
        if self._vel is None or self._vel.shape != v.shape:
            self._vel, self._prev, self._change = (np.full(v.shape, np.nan) for _ in range(3))
            self._steady = np.zeros(v.shape[:-1], dtype=int)
        accel = (v - np.where(np.isnan(self._vel), v, self._vel)) / self.divisor
        if self.lead > 0:
            change = v - 2 * self._vel + self._prev  # NaN until three velocities are in
            size = np.maximum(planar_length(change), planar_length(self._change))
            steady = planar_length(change - self._change) <= self.STEADY_CHANGE * size  # False where NaN
            self._steady = periods_in_a_row(self._steady, steady)
            ahead = change * (self.lead / (self.dt * self.divisor))
            accel = np.where((self._steady >= self._steady_periods)[..., None], accel + ahead, accel)
            self._change = change
        self._prev, self._vel = self._vel, v.copy()
        return accel
