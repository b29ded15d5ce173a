"""The cascaded PID: an outer P loop turns the position error into a velocity set-point, an inner PI loop turns
the velocity error into a desired acceleration, which the ball model turns into roll and pitch.

Ball on a tilted plate (rolling, small angles): along x, a = c·g·sin(pitch); along y, a = −c·g·sin(roll), with
c = 5/7 for a solid ball (3/5 hollow).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from stewart_gym.actions import DEFAULT_MAX_TILT
from stewart_gym.constants import GRAVITY
from stewart_gym.control.arrays import bounded, paired
from stewart_gym.control.parts import EpisodicController, SquareWaveDither, TargetFeed, integrate_error
from stewart_gym.inputs import read_json

__all__ = ["CascadedPID", "PIDGains"]


@dataclass(frozen=True)
class PIDGains:
    """Gains of :class:`CascadedPID` (tuned by ``train/tools/tune_pid.py``; see the docs: Training and results).

    Attributes:
        kp_pos: 1/s, outer loop: velocity set-point per metre of position error.
        kp_vel: 1/s, inner loop: acceleration per m/s of velocity error.
        ki_vel: 1/s², inner integral of the position error (removes steady offsets
            from trim errors and plate loads).
        rolling_factor: c in a = c·g·sin(tilt) (5/7 for a solid ball).
        max_tilt: rad, the tilt at action ±1 (must match the env's).
        integral_limit: m·s, anti-windup bound on the integral.
        integral_zone: m; if positive, the error is integrated only while it is this small (conditional
            integration: a fast approach from far away does not wind the integral up); 0 integrates always.
        dither: rad; if positive, ± this tilt is added on both axes, the sign alternating every control
            period (:class:`SquareWaveDither`): it carries small corrections through the actuators' dead band.
            0 (off) in the shipped gains.
        feed_lead: s; if positive, the target's acceleration is fed forward this far ahead on a smooth path
            (:class:`TargetFeed`): it makes up for the servos' delay. 0 feeds the acceleration as measured.
    """

    kp_pos: float = 2.0
    kp_vel: float = 5.0
    ki_vel: float = 1.0
    rolling_factor: float = 5.0 / 7.0
    max_tilt: float = DEFAULT_MAX_TILT
    integral_limit: float = 0.05
    integral_zone: float = 0.0
    dither: float = 0.0
    feed_lead: float = 0.0


class CascadedPID(EpisodicController):
    """A policy: observation (…, 12) → tilt action (…, 2) in [-1, 1] (reads indices 0–7; keeps its own integral).

    The outer loop turns the position error into a velocity set-point about the target's velocity, the inner
    loop the velocity error (and the integral) into the ball's acceleration, and the target's acceleration (the
    change of its velocity over a period) is fed forward, as :class:`LQRController` does: a moving target is
    followed without the lag an error would have to build up; a still one adds nothing. With
    ``gains.feed_lead`` the acceleration fed forward is that far ahead on a smooth path (:class:`TargetFeed`).

    Args:
        gains: The gains.
        dt: s, control period (integration step).
        plate_half: (h_x, h_y) m of the plate the observations are scaled by (see
            :class:`~stewart_gym.sensing.ObservationBuilder`).
    """

    def __init__(self, gains: PIDGains | None = None, dt: float = 0.02,
                 plate_half: tuple[float, float] = (0.15, 0.15)) -> None:  # fmt: skip
        super().__init__(plate_half)
        self.gains = gains or PIDGains()
        self.dt = dt
        self._integral = np.zeros(2)
        self._feed = TargetFeed(dt, self.gains.feed_lead)
        self._dither = SquareWaveDither(self.gains.dither, self.gains.max_tilt)

    def reset(self, rows: np.ndarray | None = None) -> None:
        """Clear the integrator and the target's past velocities and restart the dither (call at the start of an
        episode); with ``rows``, only those rows' integrators and past velocities (the dither is shared)."""
        if rows is not None and self._integral.ndim == 2 and self._integral.shape[0] == np.shape(rows)[0]:
            self._integral[rows] = 0.0
            self._feed.reset(rows)
            return
        self._integral = np.zeros(2)
        self._feed.reset()
        self._dither.reset()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Tilt action(s) for observation(s); keeps one integrator per row of a batch."""
        g = self.gains
        pos, vel, target, target_vel = self.observation.motion(obs)
        err = target - pos
        if self._integral.shape != err.shape:
            self._integral = np.zeros(err.shape)
        self._integral = integrate_error(self._integral, err, self.dt, g.integral_limit, g.integral_zone)
        feed = self._feed(target_vel)  # the target's acceleration
        vel_sp = target_vel + g.kp_pos * err
        accel = feed + g.kp_vel * (vel_sp - vel) + g.ki_vel * self._integral  # desired ball acceleration, m/s²
        s = bounded(accel / (g.rolling_factor * GRAVITY), -1.0, 1.0)
        pitch, roll = np.arcsin(s[..., 0]), -np.arcsin(s[..., 1])
        return self._dither(bounded(paired(roll, pitch) / g.max_tilt, -1.0, 1.0))

    def save(self, path: str | Path) -> None:
        """Write the gains as JSON."""
        Path(path).write_text(json.dumps(asdict(self.gains), indent=2) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path, dt: float = 0.02) -> CascadedPID:
        """Read gains written by :meth:`save`."""
        return cls(PIDGains(**read_json(path, "gains file")), dt)
