"""Adapting a controller's design to a build: the tilt that trim errors cause, and the integral's bound and zone
that cancel it. The PID's gains (:func:`gains_for_geometry`) and the LQR's design
(:func:`~stewart_gym.control.lqr.design_lqr`) use it.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from typing import Any

import numpy as np

from stewart_gym.actions import default_max_tilt
from stewart_gym.calibration import ServoCalibration
from stewart_gym.constants import GRAVITY
from stewart_gym.kinematics import actuator_jacobian
from stewart_gym.presets import load_geometry

__all__ = ["INTEGRAL_MARGIN", "TRIM_TOLERANCE_US", "ZONE_MARGIN", "gains_for_geometry", "grown_zone", "trim_tilt"]

#: µs: how far a hand-trimmed neutral may be off the true one (the simulator draws trim errors within ±15 µs).
TRIM_TOLERANCE_US = 15.0

#: The integral can cancel this multiple of the worst trim tilt (:func:`gains_for_geometry`).
INTEGRAL_MARGIN = 1.5
#: A conditional-integration zone covers this multiple of the offset at which the proportional terms alone hold
#: the worst trim tilt (:func:`gains_for_geometry`, :func:`design_lqr`): the ball must come to rest inside it.
ZONE_MARGIN = 1.2



def grown_zone(zone: float, rest: float) -> float:
    """A conditional-integration ``zone`` (m; 0: off, kept off) grown, if needed, to :data:`ZONE_MARGIN` × the
    offset ``rest`` (m) at which a controller's other terms alone hold the build's worst trim tilt."""
    return max(zone, ZONE_MARGIN * rest) if zone > 0 else zone


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


def gains_for_geometry(gains: Any, geometry: Any) -> Any:
    """:class:`~stewart_gym.control.pid.PIDGains` adapted to a build, without hand tuning.

    * ``max_tilt`` becomes the geometry's default (what its envs use: 10° or
      90 % of its reach, whichever is smaller).
    * ``integral_limit`` grows, if needed, until the integral term can command
      :data:`INTEGRAL_MARGIN` × the tilt that trim errors of ±15 µs cause
      (:func:`trim_tilt`): otherwise the anti-windup bound stops the integral
      short of a build's steady offset and the ball rests off target.
    * ``integral_zone`` (if set) grows, if needed, to :data:`ZONE_MARGIN` × the
      offset at which the proportional terms alone hold that trim tilt
      (``c·g·sin(tilt) / (kp_pos·kp_vel)``): otherwise the ball comes to rest
      outside the zone and the integral never starts.
    """
    geo = load_geometry(geometry)
    worst = trim_tilt(geo)
    tilt = min(INTEGRAL_MARGIN * worst, math.pi / 2)
    needed = gains.rolling_factor * GRAVITY * math.sin(tilt) / gains.ki_vel if gains.ki_vel > 0 else 0.0
    zone = gains.integral_zone
    if gains.kp_pos * gains.kp_vel > 0:
        rest = gains.rolling_factor * GRAVITY * math.sin(min(worst, math.pi / 2)) / (gains.kp_pos * gains.kp_vel)
        zone = grown_zone(zone, rest)
    return replace(gains, max_tilt=default_max_tilt(geo), integral_limit=max(gains.integral_limit, needed),
                   integral_zone=zone)  # fmt: skip
