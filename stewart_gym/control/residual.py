"""A residual policy's action: a learned correction added to a classical controller's, faded near the target
(:func:`residual_action`), with an optional latch (:class:`ResidualMix`)."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from stewart_gym.control.arrays import bounded, planar_length
from stewart_gym.control.parts import periods_in_a_row, whole_periods
from stewart_gym.sensing import ObservationBuilder

__all__ = ["ResidualMix", "residual_action"]


@functools.lru_cache(maxsize=16)
def _observation(plate_half: tuple[float, float]) -> ObservationBuilder:
    """The observation layout of a plate (built once per plate: a step calls this every period)."""
    return ObservationBuilder(2, plate_half)


def residual_action(base_action: np.ndarray, correction: np.ndarray, obs: np.ndarray, scale: float,
                    plate_half: tuple[float, float], fade_mm: float, inner_mm: float = 0.0) -> np.ndarray:  # fmt: skip
    """What a residual policy sends: ``clip(base + scale · w · correction, −1, 1)`` (float32), where the weight
    ``w = clip((d − inner_mm) / fade_mm, 0, 1)`` with d the observed ball's distance to the target: within
    ``inner_mm`` of the target the classical controller acts alone, over the next ``fade_mm`` the learned
    correction fades in (``w = 1`` everywhere when both are 0; a step at ``inner_mm`` when ``fade_mm`` is 0)."""
    weight: Any = 1.0
    if fade_mm > 0 or inner_mm > 0:
        error = _observation((float(plate_half[0]), float(plate_half[1]))).position_error(obs)
        outside = planar_length(error, keepdims=True) * 1e3 - inner_mm  # mm beyond the inner radius
        weight = bounded(outside / fade_mm, 0.0, 1.0) if fade_mm > 0 else (outside > 0).astype(np.float64)
    total = np.asarray(base_action, dtype=np.float64) + scale * weight * np.asarray(correction, dtype=np.float64)
    return bounded(total, -1.0, 1.0).astype(np.float32)


class ResidualMix:
    """What a residual policy sends, step by step: :func:`residual_action`, and with ``release_mm`` > 0 a latch.
    Once the observed ball has come within ``inner_mm`` of the target the correction stays off (the base acts
    alone) until the ball is observed farther than ``release_mm`` from it, as the LQR → PID's hand-over does, so
    that sensor noise around the inner radius cannot switch the correction on while the base holds the ball.
    With ``dwell_s`` > 0 the latch also closes once the ball has stayed within ``release_mm`` that long (whole
    control periods of ``dt`` s) without coming within ``inner_mm``: a correction that keeps the ball circling
    the target, short of the inner radius, is cut there and the base brings it in (a guard at run time, not a
    training signal: docs, Control).
    One latch per row of a batch; :meth:`reset` at the start of an episode.
    """

    def __init__(self, scale: float, plate_half: tuple[float, float], fade_mm: float = 0.0, inner_mm: float = 0.0,
                 release_mm: float = 0.0, dwell_s: float = 0.0, dt: float = 0.02) -> None:  # fmt: skip
        if release_mm > 0 and not release_mm > inner_mm > 0:
            raise ValueError(f"release_mm ({release_mm}) must be 0 (no latch) or more than inner_mm ({inner_mm}) > 0")
        if not 0 <= dwell_s < math.inf or (dwell_s > 0 and release_mm <= 0):
            raise ValueError(f"dwell_s ({dwell_s}) must be 0 (none) or, with a latch (release_mm > 0), a finite "
                             "positive time")  # fmt: skip
        if not 0 < dt < math.inf:
            raise ValueError(f"dt must be a positive number of seconds, got {dt}")
        self.scale, self.plate_half = float(scale), (float(plate_half[0]), float(plate_half[1]))
        self.fade_mm, self.inner_mm, self.release_mm = float(fade_mm), float(inner_mm), float(release_mm)
        self.dwell_s, self.dt = float(dwell_s), float(dt)
        #: periods within release_mm after which the latch closes (0: never by time)
        self._dwell_periods = whole_periods(self.dwell_s, self.dt) if self.dwell_s > 0 else 0
        self._off: np.ndarray | None = None
        self._inside: np.ndarray | None = None
        self._observation = _observation(self.plate_half)

    def reset(self) -> None:
        """Start of an episode: the latch is open (the correction acts wherever the fade lets it)."""
        self._off = None
        self._inside = None

    def __call__(self, base_action: np.ndarray, correction: np.ndarray, obs: np.ndarray) -> np.ndarray:
        correction = np.asarray(correction, dtype=np.float64)
        if self.release_mm > 0:
            error = self._observation.position_error(obs)
            distance_mm = planar_length(error) * 1e3
            fresh = self._off is None or self._off.shape != distance_mm.shape
            off = np.zeros(distance_mm.shape, dtype=bool) if fresh else self._off
            close = distance_mm < self.inner_mm
            if self._dwell_periods:
                self._inside = periods_in_a_row(None if fresh else self._inside, distance_mm <= self.release_mm)
                close = close | (self._inside >= self._dwell_periods)
            self._off = (off | close) & ~(distance_mm > self.release_mm)
            correction = np.where(self._off[..., None], 0.0, correction)
        return residual_action(base_action, correction, obs, self.scale, self.plate_half, self.fade_mm, self.inner_mm)
