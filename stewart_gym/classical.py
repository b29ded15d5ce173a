"""Classical ball controller: a cascaded PID that commands plate tilt through the same IK → pulse path.

It reads the same observation vector as a learned policy
(:class:`~stewart_gym.sensing.ObservationBuilder`) and returns a "tilt" action,
so the environments, ``evaluate`` and ``deploy`` treat it like any policy.

Ball on a tilted plate (rolling, small angles): along x, a = c·g·sin(pitch);
along y, a = −c·g·sin(roll), with c = 5/7 for a solid ball (3/5 hollow).
Cascade: an outer P loop turns the position error into a velocity set-point,
an inner PI loop turns the velocity error into a desired acceleration, which
the ball model turns into roll and pitch.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.actions import DEFAULT_MAX_TILT, default_max_tilt
from stewart_gym.calibration import ServoCalibration
from stewart_gym.kinematics import actuator_jacobian
from stewart_gym.presets import load_geometry
from stewart_gym.sensing import ObservationBuilder

__all__ = ["TRIM_TOLERANCE_US", "CascadedPID", "PIDGains", "gains_for_geometry", "trim_tilt"]

GRAVITY = 9.80665

#: µs: how far a hand-trimmed neutral may be off the true one (the simulator draws trim errors within ±15 µs).
TRIM_TOLERANCE_US = 15.0

#: The integral can cancel this multiple of the worst trim tilt (:func:`gains_for_geometry`).
INTEGRAL_MARGIN = 1.5


@dataclass(frozen=True)
class PIDGains:
    """Gains of :class:`CascadedPID` (tuned by ``train/tune_pid.py``; see the docs: Training and results).

    Attributes:
        kp_pos: 1/s, outer loop: velocity set-point per metre of position error.
        kp_vel: 1/s, inner loop: acceleration per m/s of velocity error.
        ki_vel: 1/s², inner integral of the position error (removes steady offsets
            from trim errors and plate loads).
        rolling_factor: c in a = c·g·sin(tilt) (5/7 for a solid ball).
        max_tilt: rad, the tilt at action ±1 (must match the env's).
        integral_limit: m·s, anti-windup bound on the integral.
    """

    kp_pos: float = 2.0
    kp_vel: float = 5.0
    ki_vel: float = 1.0
    rolling_factor: float = 5.0 / 7.0
    max_tilt: float = DEFAULT_MAX_TILT
    integral_limit: float = 0.05


class CascadedPID:
    """A policy: observation (…, 12) → tilt action (…, 2) in [-1, 1] (reads indices 0–7; keeps its own integral).

    Args:
        gains: The gains.
        dt: s, control period (integration step).
        plate_half: (h_x, h_y) m of the plate the observations are scaled by (see
            :class:`~stewart_gym.sensing.ObservationBuilder`).
    """

    def __init__(self, gains: PIDGains | None = None, dt: float = 0.02,
                 plate_half: tuple[float, float] = (0.15, 0.15)) -> None:  # fmt: skip
        self.gains = gains or PIDGains()
        self.dt = dt
        scales = ObservationBuilder(2, plate_half)
        self._position_scale = np.array(scales.position_scale)
        self._velocity_scale = np.array(scales.velocity_scale)
        self._integral = np.zeros(2)

    def reset(self) -> None:
        """Clear the integrator (call at the start of an episode)."""
        self._integral = np.zeros(2)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Tilt action(s) for observation(s); keeps one integrator per row of a batch."""
        g = self.gains
        o = np.asarray(obs, dtype=np.float64)
        pos = o[..., 0:2] * self._position_scale
        vel = o[..., 2:4] * self._velocity_scale
        target = o[..., 4:6] * self._position_scale
        target_vel = o[..., 6:8] * self._velocity_scale
        err = target - pos
        if self._integral.shape != err.shape:
            self._integral = np.zeros(err.shape)
        self._integral = np.clip(self._integral + err * self.dt, -g.integral_limit, g.integral_limit)
        vel_sp = target_vel + g.kp_pos * err
        accel = g.kp_vel * (vel_sp - vel) + g.ki_vel * self._integral  # desired ball acceleration, m/s²
        s = np.clip(accel / (g.rolling_factor * GRAVITY), -1.0, 1.0)
        pitch, roll = np.arcsin(s[..., 0]), -np.arcsin(s[..., 1])
        action = np.stack([roll, pitch], axis=-1) / g.max_tilt
        return np.clip(action, -1.0, 1.0).astype(np.float32)

    def predict(self, obs: np.ndarray, state: object = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        """Stable-Baselines3-style ``predict``: resets the integrator where an episode starts."""
        if episode_start is not None and np.any(episode_start):
            if self._integral.ndim == 2:
                self._integral[np.asarray(episode_start, dtype=bool)] = 0.0
            else:
                self.reset()
        return self(obs), None

    def save(self, path: str | Path) -> None:
        """Write the gains as JSON."""
        Path(path).write_text(json.dumps(asdict(self.gains), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path, dt: float = 0.02) -> CascadedPID:
        """Read gains written by :meth:`save`."""
        return cls(PIDGains(**json.loads(Path(path).read_text())), dt)


def trim_tilt(geometry: Any, tolerance_us: float = TRIM_TOLERANCE_US) -> float:
    """rad: the largest plate tilt at home that neutral errors within ±``tolerance_us`` on every channel can cause.

    Small-signal: the forward Jacobian at home maps each channel's error (µs →
    servo angle or leg length through the geometry's default calibration) to
    roll and pitch; the worst of the 64 sign patterns is returned. A hobby
    servo's 15 µs moves a 0.3 m reference plate by 0.8°, an RC linear actuator
    with a 300 mm stroke (``senilov2018``) by 3.7°.
    """
    geo = load_geometry(geometry)
    cal = ServoCalibration.default(geo)
    forward = np.linalg.inv(actuator_jacobian(geo, np.zeros(6)))
    tilt_per_us = forward[3:5, :] / (cal.direction * cal.us_per_rad)  # (roll, pitch) rad per µs of each channel
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=6)))
    return float(np.linalg.norm(signs @ tilt_per_us.T, axis=1).max() * tolerance_us)


def gains_for_geometry(gains: PIDGains, geometry: Any) -> PIDGains:
    """``gains`` adapted to a build, without hand tuning.

    * ``max_tilt`` becomes the geometry's default (what its envs use: 10° or
      90 % of its reach, whichever is smaller).
    * ``integral_limit`` grows, if needed, until the integral term can command
      :data:`INTEGRAL_MARGIN` × the tilt that trim errors of ±15 µs cause
      (:func:`trim_tilt`): otherwise the anti-windup bound stops the integral
      short of a build's steady offset and the ball rests off target.
    """
    geo = load_geometry(geometry)
    tilt = min(INTEGRAL_MARGIN * trim_tilt(geo), math.pi / 2)
    needed = gains.rolling_factor * GRAVITY * math.sin(tilt) / gains.ki_vel if gains.ki_vel > 0 else 0.0
    return replace(gains, max_tilt=default_max_tilt(geo), integral_limit=max(gains.integral_limit, needed))
