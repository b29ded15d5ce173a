"""Classical ball controllers: a cascaded PID, an LQR, and the LQR handing over to the PID near the target,
commanding plate tilt through the same IK → pulse path.

Both read the same observation vector as a learned policy
(:class:`~stewart_gym.sensing.ObservationBuilder`) and return a "tilt" action,
so the environments, ``evaluate`` and ``deploy`` treat them like any policy.

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
from dataclasses import fields as dataclass_fields
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.actions import DEFAULT_MAX_TILT, default_max_tilt
from stewart_gym.calibration import ServoCalibration
from stewart_gym.inputs import read_text
from stewart_gym.kinematics import actuator_jacobian
from stewart_gym.presets import load_geometry
from stewart_gym.sensing import ESTIMATORS, ObservationBuilder

__all__ = ["CLASSICAL", "CLASSICAL_KINDS", "CascadedPID", "EpisodicController", "HandoverController",
           "HandoverDesign", "HandoverGains", "LQRController", "LQRDesign", "LQRGains", "PIDGains", "ResidualMix",
           "TRIM_TOLERANCE_US", "ZONE_MARGIN", "checked_design", "classical_controller", "controller_from_gains",
           "design_estimator", "design_kind", "design_lqr", "fastest_settling", "gains_for_geometry", "grown_zone",
           "integrate_error", "periods_in_a_row", "residual_action", "shipped_design", "trim_tilt", "whole_periods",
           "SquareWaveDither", "bounded", "paired", "planar_length"]  # fmt: skip

GRAVITY = 9.80665

#: µs: how far a hand-trimmed neutral may be off the true one (the simulator draws trim errors within ±15 µs).
TRIM_TOLERANCE_US = 15.0

#: The integral can cancel this multiple of the worst trim tilt (:func:`gains_for_geometry`).
INTEGRAL_MARGIN = 1.5
#: A conditional-integration zone covers this multiple of the offset at which the proportional terms alone hold
#: the worst trim tilt (:func:`gains_for_geometry`, :func:`design_lqr`): the ball must come to rest inside it.
ZONE_MARGIN = 1.2


# Small-array arithmetic. A control step works on 2-vectors, where numpy's ``clip``, ``linalg.norm`` and ``stack``
# wrappers cost several times the arithmetic they wrap. These three give numpy's values bit for bit (but for the
# sign of a zero: −0 clipped at a bound of 0 comes out +0) at a ufunc's cost.
def bounded(x: Any, low: Any, high: Any) -> Any:
    """``np.clip(x, low, high)``'s values (NaN stays NaN) without its wrapper: ``min(max(x, low), high)``."""
    return np.minimum(np.maximum(x, low), high)


def planar_length(v: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """``np.linalg.norm(v, axis=-1, keepdims=keepdims)`` of 2-vectors (…, 2), the same values: √(x·x + y·y)."""
    x, y = v[..., 0], v[..., 1]
    length = np.sqrt(x * x + y * y)
    return length[..., None] if keepdims else length


def paired(x: Any, y: Any) -> np.ndarray:
    """``np.stack([x, y], axis=-1)`` of two float arrays of one shape: (…, 2), float64."""
    out = np.empty(np.shape(x) + (2,))
    out[..., 0] = x
    out[..., 1] = y
    return out


#: The shipped classical controllers by name (``--policy NAME``, a residual policy's ``base``): their kind
#: ("pid", "lqr" or "handover"), their file under ``stewart_gym/policies/`` and the observer they run behind.
CLASSICAL = {"pid": ("pid", "pid_gains.json", "lowpass"), "pid-kalman": ("pid", "pid_kalman_gains.json", "kalman"),
             "lqr": ("lqr", "lqr.json", "kalman"), "lqr-pid": ("handover", "lqr_pid.json", "kalman")}  # fmt: skip
CLASSICAL_KINDS = ("pid", "lqr", "handover")


def observed_motion(obs: np.ndarray, position_scale: np.ndarray,
                    velocity_scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The ball's and the target's position (m) and velocity (m/s) in observation(s) (…, 12), unscaled."""
    o = np.asarray(obs, dtype=np.float64)
    return (o[..., 0:2] * position_scale, o[..., 2:4] * velocity_scale, o[..., 4:6] * position_scale,
            o[..., 6:8] * velocity_scale)  # fmt: skip


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


def grown_zone(zone: float, rest: float) -> float:
    """A conditional-integration ``zone`` (m; 0: off, kept off) grown, if needed, to :data:`ZONE_MARGIN` × the
    offset ``rest`` (m) at which a controller's other terms alone hold the build's worst trim tilt."""
    return max(zone, ZONE_MARGIN * rest) if zone > 0 else zone


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


class CascadedPID:
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
        self.gains = gains or PIDGains()
        self.dt = dt
        scales = ObservationBuilder(2, plate_half)
        self._position_scale = np.array(scales.position_scale)
        self._velocity_scale = np.array(scales.velocity_scale)
        self._integral = np.zeros(2)
        self._feed = TargetFeed(dt, self.gains.feed_lead)
        self._dither = SquareWaveDither(self.gains.dither, self.gains.max_tilt)

    def reset(self) -> None:
        """Clear the integrator and the target's past velocities, restart the dither (call at the start of an
        episode)."""
        self._integral = np.zeros(2)
        self._feed.reset()
        self._dither.reset()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Tilt action(s) for observation(s); keeps one integrator per row of a batch."""
        g = self.gains
        pos, vel, target, target_vel = observed_motion(obs, self._position_scale, self._velocity_scale)
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

    def predict(self, obs: np.ndarray, state: object = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        """Stable-Baselines3-style ``predict``: resets the integrator and the target's last velocity where an
        episode starts."""
        if episode_start is not None and np.any(episode_start):
            if self._integral.ndim == 2:
                rows = np.asarray(episode_start, dtype=bool)
                self._integral[rows] = 0.0
                self._feed.reset(rows)
            else:
                self.reset()
        return self(obs), None

    def save(self, path: str | Path) -> None:
        """Write the gains as JSON."""
        Path(path).write_text(json.dumps(asdict(self.gains), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path, dt: float = 0.02) -> CascadedPID:
        """Read gains written by :meth:`save`."""
        return cls(PIDGains(**json.loads(read_text(path, "gains file"))), dt)


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


# ------------------------------------------------------------------------------------------------------- LQR
@dataclass(frozen=True)
class LQRDesign:
    """What :func:`design_lqr` designs from: the model and the weights (Bryson's rule: the acceptable size of
    each term). Stored as ``policies/lqr.json``.

    Model per plate axis, sampled at the control period ``dt``: the ball rolls with ``c·g·a`` where ``a``
    follows the commanded ``sin(tilt)`` as a first-order lag of ``tilt_lag_s`` after one control period of
    dead time (the servos: 17 ms dead time and a 19 ms lag, measured; see
    :class:`~stewart_gym.sensing.KalmanSpec`). The sensing delay is the Kalman filter's: it hands the
    controller its estimate for now. The state is (position error, velocity error, plate acceleration, the
    command in flight, integral of the position error).

    Attributes:
        position_mm: acceptable position error.
        velocity_mm_s: acceptable velocity error.
        integral_mm_s: acceptable integral of the position error (sets how fast offsets are removed).
        tilt: acceptable commanded ``sin(tilt)``.
        tilt_step: acceptable change of ``sin(tilt)`` per control period (servo rate and wear).
        rolling_factor: c (5/7 solid ball).
        tilt_lag_s: s.
        integral_zone_mm: if positive, the error is integrated only while it is this small (as
            :attr:`PIDGains.integral_zone`); 0 integrates always.
        dither: rad, as :attr:`PIDGains.dither` (0: off).
        feed_lead: s, as :attr:`PIDGains.feed_lead`: on a moving target the acceleration fed forward leads by
            this much on a smooth path (0: as measured).

    The tilt at action ±1 is the geometry's default ``max_tilt`` (:func:`design_lqr`).
    """

    position_mm: float = 4.0
    velocity_mm_s: float = 40.0
    integral_mm_s: float = 6.0
    tilt: float = 0.1
    tilt_step: float = 0.002
    rolling_factor: float = 5.0 / 7.0
    tilt_lag_s: float = 0.019
    integral_zone_mm: float = 0.0
    dither: float = 0.0
    feed_lead: float = 0.0


@dataclass(frozen=True)
class LQRGains:
    """A designed LQR (what a bundle stores: deploying it needs numpy only).

    Attributes:
        k: the feedback gains on (position error m, velocity error m/s, the plate's lagged sin(tilt),
            command in flight, integral m·s): command = −k · state, a ``sin(tilt)``.
        rolling_factor, tilt_lag_s, dt: the model it was designed with.
        max_tilt: rad, the tilt at action ±1.
        integral_limit: m·s, anti-windup bound on the integral.
        integral_zone: m, integrate only within it (0: always).
        dither: rad, as :attr:`PIDGains.dither` (0: off).
        feed_lead: s, as :attr:`LQRDesign.feed_lead` (0: off).
    """

    k: tuple[float, float, float, float, float]
    rolling_factor: float
    tilt_lag_s: float
    dt: float
    max_tilt: float
    integral_limit: float
    integral_zone: float = 0.0
    dither: float = 0.0
    feed_lead: float = 0.0  # after the others: bundles written before it load without it


def lqr_model(design: LQRDesign, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The discrete model (A, B) per axis of :class:`LQRDesign`'s state; the input is the new ``sin(tilt)``."""
    from scipy.linalg import expm

    tau = design.tilt_lag_s
    cont = np.zeros((4, 4))  # (p, v, a, u in flight): a' = (u − a)/τ, v' = c·g·a
    cont[0, 1], cont[1, 2] = 1.0, design.rolling_factor * GRAVITY
    cont[2, 2], cont[2, 3] = -1.0 / tau, 1.0 / tau
    step = expm(cont * dt)
    a = np.zeros((5, 5))
    a[:3, :4] = step[:3, :4]  # the command in flight acts through this period…
    a[4, 0], a[4, 4] = dt, 1.0  # …the integral sums the position error
    b = np.zeros((5, 1))
    b[3, 0] = 1.0  # …and the new command is in flight next
    return a, b


def fastest_settling(start: tuple[float, float], radius: float, max_tilt: float = DEFAULT_MAX_TILT,
                     design: LQRDesign | None = None, dt: float = 0.02, hold_s: float = 0.8,
                     sides: int = 16) -> float:  # fmt: skip
    """s: a lower bound on the settling time from rest at ``start`` (x, y, m from the target) under the LQR's
    linear model (:func:`lqr_model` of ``design``: the rolling ball, one control period of dead time, the tilt's
    lag, the command held for ``dt``), each axis' tilt within ±``max_tilt``: the fewest periods N such that some
    command sequence keeps the ball within ``radius`` (a ``sides``-gon inside that circle) from period N on for
    ``hold_s`` more and leaves it at rest. Each N is a linear program (scipy's HiGHS), N found by bisection
    (a sequence that settles by N settles by N + 1). The simulator adds
    what the model leaves out (the ball's first push away from the target as the plate starts to turn, rolling
    friction, the servos' speed limit), so no controller there reaches this bound; it tells how far one is
    from it."""
    from scipy.optimize import linprog

    d = design or LQRDesign()
    a4 = lqr_model(d, dt)[0][:4, :4]  # (p, v, a, u in flight); the new command enters as u in flight
    limit, hold = math.sin(max_tilt), max(1, round(hold_s / dt))

    def feasible(n: int) -> bool:
        periods = n + hold
        rows, bounds_ub = [], []
        free = [np.array([p0, 0.0, 0.0, 0.0]) for p0 in start]  # each axis' state with no command
        gain = [np.zeros((4, periods)) for _ in start]  # … and its response to each command
        for k in range(periods + 1):
            if k >= n:
                for i in range(sides):
                    cx, cy = math.cos(2 * math.pi * i / sides), math.sin(2 * math.pi * i / sides)
                    rows.append(np.concatenate([cx * gain[0][0], cy * gain[1][0]]))
                    bounds_ub.append(radius * math.cos(math.pi / sides) - cx * free[0][0] - cy * free[1][0])
            if k == periods:
                break
            for axis in range(2):
                free[axis], gain[axis] = a4 @ free[axis], a4 @ gain[axis]
                gain[axis][3, k] += 1.0  # the command sent at period k is in flight during period k + 1
        none = np.zeros(periods)  # at rest at the end: each axis' velocity from its own commands
        at_rest = np.array([np.concatenate([gain[0][1], none]), np.concatenate([none, gain[1][1]])])
        result = linprog(np.zeros(2 * periods), A_ub=np.array(rows), b_ub=np.array(bounds_ub), A_eq=at_rest,
                         b_eq=[-free[0][1], -free[1][1]], bounds=[(-limit, limit)] * (2 * periods),
                         method="highs")  # fmt: skip
        return bool(result.status == 0)

    low, high = 0, 1  # settles by high, not by low − 1
    while not feasible(high):
        low, high = high + 1, 2 * high
    while low < high:
        mid = (low + high) // 2
        low, high = (low, mid) if feasible(mid) else (mid + 1, high)
    return high * dt


def design_lqr(design: LQRDesign | None = None, dt: float = 0.02, geometry: Any = "servo-hexapod") -> LQRGains:
    """Discrete LQR gains for ``design`` at control period ``dt`` on ``geometry`` (its max tilt and trim tilt).

    Cost per period: Σ (state/acceptable)² + (u/tilt)² + ((u − u_in_flight)/tilt_step)², the last a cross
    term (DARE with ``s``). The anti-windup bound lets the integral command 1.5× the worst trim tilt; the
    integral zone (if set) grows, if needed, to :data:`ZONE_MARGIN` × the offset at which the other terms alone
    hold that tilt (``sin(tilt)·(1 + k_a + k_u) / k_p``), as :func:`gains_for_geometry` does for the PID.
    """
    from scipy.linalg import solve_discrete_are

    d = design or LQRDesign()
    a, b = lqr_model(d, dt)
    rd = 1.0 / d.tilt_step**2
    q = np.diag([1 / (d.position_mm * 1e-3) ** 2, 1 / (d.velocity_mm_s * 1e-3) ** 2, 0.0, rd,
                 1 / (d.integral_mm_s * 1e-3) ** 2])  # fmt: skip
    r = np.array([[1 / d.tilt**2 + rd]])
    n = np.zeros((5, 1))
    n[3, 0] = -rd
    p = solve_discrete_are(a, b, q, r, s=n)
    k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a + n.T).ravel()
    geo = load_geometry(geometry)
    worst = trim_tilt(geo)
    needed = math.sin(min(INTEGRAL_MARGIN * worst, math.pi / 2))
    zone = grown_zone(d.integral_zone_mm * 1e-3, math.sin(min(worst, math.pi / 2)) * abs(1 + k[2] + k[3]) / abs(k[0]))
    return LQRGains(k=tuple(float(v) for v in k), rolling_factor=d.rolling_factor, tilt_lag_s=d.tilt_lag_s, dt=dt,
                    max_tilt=default_max_tilt(geo), integral_limit=float(needed / abs(k[4])),
                    integral_zone=float(zone), dither=d.dither, feed_lead=d.feed_lead)  # fmt: skip


class EpisodicController:
    """A controller whose state is one episode's: its Stable-Baselines3-style ``predict`` resets it (every row)
    where an episode starts. Subclasses give ``reset`` and ``__call__``."""

    def reset(self) -> None:
        raise NotImplementedError

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def predict(self, obs: np.ndarray, state: object = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        """Stable-Baselines3-style ``predict``: resets the state where an episode starts."""
        if episode_start is not None and np.any(episode_start):
            self.reset()
        return self(obs), None


class LQRController(EpisodicController):
    """A policy: observation (…, 12) → tilt action (…, 2), the LQR of :class:`LQRGains`.

    It reads the ball's position and velocity (indices 0–3: best from the Kalman observer, which predicts them
    for now), the target's (4–7) and the tilt in force (8–9). It keeps the model's plate acceleration (driven
    by the commands it sees in force) and the integral of the position error, and feeds the target's
    acceleration forward (:class:`TargetFeed`, leading by ``gains.feed_lead`` on a smooth path).
    """

    def __init__(self, gains: LQRGains, plate_half: tuple[float, float] = (0.15, 0.15)) -> None:
        self.gains = gains
        scales = ObservationBuilder(2, plate_half)
        self._position_scale = np.array(scales.position_scale)
        self._velocity_scale = np.array(scales.velocity_scale)
        self._k = np.asarray(gains.k, dtype=float)
        self._phi = math.exp(-gains.dt / gains.tilt_lag_s)
        self._dither = SquareWaveDither(gains.dither, gains.max_tilt)
        # the target's acceleration as the sin(tilt) that rolls the ball so
        self._feed = TargetFeed(gains.dt, gains.feed_lead, divisor=gains.dt * gains.rolling_factor * GRAVITY)
        self.reset()

    def reset(self) -> None:
        """Start of an episode."""
        self._state: dict[str, np.ndarray] | None = None
        self._feed.reset()
        self._dither.reset()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        g = self.gains
        o = np.asarray(obs, dtype=np.float64)
        pos, vel, target, target_vel = observed_motion(o, self._position_scale, self._velocity_scale)
        roll, pitch = o[..., 8] * ObservationBuilder.TILT_SCALE, o[..., 9] * ObservationBuilder.TILT_SCALE
        in_force = paired(np.sin(pitch), -np.sin(roll))  # sin(tilt) along x and y
        err = pos - target
        st = self._state
        if st is None or st["integral"].shape != err.shape:
            st = self._state = {"accel": in_force.copy(), "integral": np.zeros_like(err),
                                "in_force": in_force.copy()}  # fmt: skip
        st["accel"] = self._phi * st["accel"] + (1 - self._phi) * st["in_force"]  # driven by last period's command
        st["in_force"] = in_force
        st["integral"] = integrate_error(st["integral"], err, g.dt, g.integral_limit, g.integral_zone)
        feed = self._feed(target_vel)  # the target's acceleration, as a sin(tilt)
        k = self._k
        u = feed - (k[0] * err + k[1] * (vel - target_vel) + k[2] * (st["accel"] - feed) + k[3] * (in_force - feed)
                    + k[4] * st["integral"])  # fmt: skip
        s = bounded(u, -1.0, 1.0)
        return self._dither(bounded(paired(-np.arcsin(s[..., 1]), np.arcsin(s[..., 0])) / g.max_tilt, -1.0, 1.0))


# -------------------------------------------------------------------------------------------------- hand-over
#: The hand-over's own sizes (:class:`HandoverDesign`): the first three positive, the rest 0 (off) or more.
HANDOVER_SIZES = ("handover_mm", "handover_mm_s", "release_mm", "handover_dwell_s", "release_dwell_s", "release_mm_s",
                  "push_release_mm")
#: The sizes that may be 0 (off).
HANDOVER_OPTIONAL = ("handover_dwell_s", "release_dwell_s", "release_mm_s", "push_release_mm")


@dataclass(frozen=True)
class HandoverDesign:
    """The LQR bringing the ball in, the PID holding it (``policies/lqr_pid.json``, ``--policy lqr-pid``).

    The LQR settles fastest and the PID behind the Kalman observer holds the ball tightest and quietest, on a
    still target and, as both feed the target's acceleration forward, on a moving one; this controller runs the
    LQR until the ball is within ``handover_mm`` of the target and slower than ``handover_mm_s`` relative to it,
    then the PID, until the ball is farther than ``release_mm`` (then the LQR again). Under heavy panel noise
    the observed speed seldom falls below ``handover_mm_s`` (8 mm of noise leaves about 20 mm/s in the
    estimate), so once the ball has stayed within ``release_mm`` of the target for ``handover_dwell_s``, the
    PID takes over within ``handover_mm`` whatever the observed speed (0: never). Under the same noise the
    filtered position strays beyond ``release_mm`` now and then while the ball itself is held; with
    ``release_dwell_s`` the LQR takes the ball back only once it has been observed beyond ``release_mm`` that
    long (0: at once), unless it is also faster than ``release_mm_s`` relative to the target: a push, which the
    LQR brings back sooner, more than noise (8 mm of it leaves about 20 mm/s of error in the filtered speed; 0:
    no exception). A push that leaves the ball within ``release_mm`` is caught by ``push_release_mm``: while the
    PID holds, a ball beyond it that moves faster than ``release_mm_s`` and than :data:`PUSH_SPEED_SIGMAS` times
    the RMS speed observed during the hold (over about :data:`PUSH_NOISE_WINDOW_S`; what the panel's noise
    leaves in the estimate, so a noisy panel needs a harder push) goes back to the LQR at once. The PID takes over
    with its own integral, which it has kept within
    its integration zone all along (loading it with the LQR's integral term instead carried over a transient:
    after a fast approach the ball could drift out of the success radius for seconds).

    Attributes:
        lqr: the LQR's design.
        pid: the PID's gains.
        handover_mm, handover_mm_s: the PID takes over within this distance of the target and below this speed
            relative to it.
        release_mm: the LQR takes back beyond this distance (more than ``handover_mm``).
        handover_dwell_s: after this long within ``release_mm`` the speed no longer matters (0: it always does).
        release_dwell_s: the LQR takes back after this long beyond ``release_mm`` (0: at once).
        release_mm_s: with a release dwell, the LQR takes back at once a ball beyond ``release_mm`` that moves
            faster than this relative to the target (0: never).
        push_release_mm: within ``release_mm``, the LQR takes back at once a ball beyond this distance that moves
            faster than ``release_mm_s`` and than the noise allows (above; 0: never; less than ``release_mm``).
    """

    lqr: LQRDesign
    pid: PIDGains
    handover_mm: float = 2.0
    handover_mm_s: float = 10.0
    release_mm: float = 20.0
    handover_dwell_s: float = 0.0
    release_dwell_s: float = 0.0
    release_mm_s: float = 0.0
    push_release_mm: float = 0.0


@dataclass(frozen=True)
class HandoverGains:
    """A designed :class:`HandoverController` (what a bundle stores): the LQR's gains, the PID's gains (both for
    one geometry), the tilt at action ±1, the hand-over sizes and the control period."""

    lqr: LQRGains
    pid: PIDGains
    max_tilt: float
    handover_mm: float
    handover_mm_s: float
    release_mm: float
    dt: float
    handover_dwell_s: float = 0.0  # after the others: bundles written before it load without it
    release_dwell_s: float = 0.0  # likewise
    release_mm_s: float = 0.0  # likewise
    push_release_mm: float = 0.0  # likewise


#: :attr:`HandoverDesign.push_release_mm`: a push is faster than this many times the RMS speed observed while the
#: PID holds, which is averaged over about this many seconds of holding (from ``handover_mm_s``, the speed the PID
#: takes over below, at the start of an episode; kept while the LQR has the ball, as the noise is the same).
PUSH_SPEED_SIGMAS = 3.0
PUSH_NOISE_WINDOW_S = 1.0


class HandoverController(EpisodicController):
    """A policy: observation (…, 12) → tilt action (…, 2): the LQR far from the target, the PID near it
    (:class:`HandoverDesign`). Both run every period (each keeps its state); one row per ball in a batch."""

    def __init__(self, gains: HandoverGains, plate_half: tuple[float, float] = (0.15, 0.15)) -> None:
        self.gains = gains
        self.lqr = LQRController(gains.lqr, plate_half)
        self.pid = CascadedPID(gains.pid, gains.dt, plate_half)
        scales = ObservationBuilder(2, plate_half)
        self._position_scale = np.array(scales.position_scale)
        self._velocity_scale = np.array(scales.velocity_scale)
        self.reset()

    def reset(self) -> None:
        """Start of an episode: the LQR is in control."""
        self.lqr.reset()
        self.pid.reset()
        self._near: np.ndarray | None = None
        self._inside: np.ndarray | None = None  # periods each ball has been within release_mm of the target
        self._beyond: np.ndarray | None = None  # periods each ball has been observed beyond release_mm
        self._held_speed2: np.ndarray | None = None  # (mm/s)²: mean square speed observed while the PID holds

    @property
    def pid_in_control(self) -> np.ndarray | None:
        """Whether the PID holds each row (None before the first observation)."""
        return None if self._near is None else self._near.copy()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        g = self.gains
        o = np.asarray(obs, dtype=np.float64)
        by_lqr = self.lqr(o)
        pos, vel, target, target_vel = observed_motion(o, self._position_scale, self._velocity_scale)
        distance_mm = planar_length(target - pos) * 1e3
        speed_mm_s = planar_length(vel - target_vel) * 1e3
        fresh = self._near is None or self._near.shape != distance_mm.shape
        near = np.zeros(distance_mm.shape, dtype=bool) if fresh else self._near
        self._inside = periods_in_a_row(None if fresh else self._inside, distance_mm <= g.release_mm)
        slow = speed_mm_s < g.handover_mm_s
        if g.handover_dwell_s > 0:  # whole periods: 3 s at 50 Hz is the 150th
            slow |= self._inside >= whole_periods(g.handover_dwell_s, g.dt)
        enter = ~near & (distance_mm < g.handover_mm) & slow
        self._beyond = periods_in_a_row(None if fresh else self._beyond, distance_mm > g.release_mm)
        gone = self._beyond >= max(1, whole_periods(g.release_dwell_s, g.dt))  # 0 s: the first period beyond
        if g.release_mm_s > 0:  # a push, not noise: the LQR takes back at once
            gone |= (distance_mm > g.release_mm) & (speed_mm_s > g.release_mm_s)
        if g.push_release_mm > 0:  # a push within release_mm: faster than the noise lets the held ball seem
            held2 = self._held_speed2
            if fresh or held2 is None:
                held2 = np.full(distance_mm.shape, g.handover_mm_s**2)
            limit = np.maximum(g.release_mm_s, PUSH_SPEED_SIGMAS * np.sqrt(held2))
            gone |= near & (distance_mm > g.push_release_mm) & (speed_mm_s > limit)
            weight = min(1.0, g.dt / PUSH_NOISE_WINDOW_S)
            self._held_speed2 = np.where(near, held2 + weight * (speed_mm_s * speed_mm_s - held2), held2)
        self._near = (near | enter) & ~gone
        by_pid = self.pid(o)
        return np.where(self._near[..., None], by_pid, by_lqr).astype(np.float32)


#: Design fields that are bounds, zones, dither or the feed-forward's lead (0 turns them off; a negative one is
#: refused) and the LQR design's acceptable sizes and servo lag (must be positive).
NON_NEGATIVE_GAINS = ("integral_limit", "integral_zone", "integral_zone_mm", "dither", "feed_lead")
POSITIVE_GAINS = ("position_mm", "velocity_mm_s", "integral_mm_s", "tilt", "tilt_step", "tilt_lag_s")


#: The optional field of a gains or design file that names the observer it was tuned behind (``lowpass`` or
#: ``kalman``): a copy of ``pid_kalman_gains.json`` runs behind the Kalman observer, as ``--policy pid-kalman`` does.
ESTIMATOR_FIELD = "estimator"


def design_estimator(values: Any) -> str | None:
    """The observer a gains or design file's values name (their ``estimator`` field; None without one). Raises
    ``ValueError`` if it is not one of :data:`~stewart_gym.sensing.ESTIMATORS`."""
    if not isinstance(values, dict) or ESTIMATOR_FIELD not in values:
        return None
    named = values[ESTIMATOR_FIELD]
    if named not in ESTIMATORS:
        raise ValueError(f"{ESTIMATOR_FIELD} must be one of {list(ESTIMATORS)}, got {named!r}")
    return str(named)


def design_kind(values: Any) -> str:
    """The kind of controller a gains or design file's values describe: ``"handover"`` (``lqr`` and ``pid``
    sections), ``"lqr"`` (an LQR design: it has the acceptable sizes, e.g. ``position_mm``) or ``"pid"``."""
    if isinstance(values, dict) and {"lqr", "pid"} & set(values):
        return "handover"
    only_lqr = {f.name for f in dataclass_fields(LQRDesign)} - {f.name for f in dataclass_fields(PIDGains)}
    if isinstance(values, dict) and only_lqr & set(values):
        return "lqr"
    return "pid"


def checked_design(values: Any, kind: str) -> PIDGains | LQRDesign | HandoverDesign:
    """The PID's gains (``kind`` "pid"), the LQR's design (``"lqr"``) or the hand-over's (``"handover"``:
    :func:`checked_handover`) from a mapping of its fields, checked: known fields, finite numbers, no negative
    bound or zone, positive LQR sizes; an ``estimator`` field (:func:`design_estimator`) is checked and left
    out. Raises ``ValueError`` saying what is wrong (callers add where the values came from)."""
    if design_estimator(values) is not None:
        values = {k: v for k, v in values.items() if k != ESTIMATOR_FIELD}
    if kind == "handover":
        return checked_handover(values)
    cls = LQRDesign if kind == "lqr" else PIDGains
    if not isinstance(values, dict):
        raise ValueError(f"expected {cls.__name__} values as a mapping, got {type(values).__name__}")
    try:
        design = cls(**values)
    except TypeError as exc:
        raise ValueError(f"not {cls.__name__} values ({exc})") from None
    fields = vars(design)
    bad = [k for k, v in fields.items() if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)]
    if bad:
        raise ValueError(f"gains must be finite numbers: {bad}")
    wrong = [f"{k} must be 0 (off) or more" for k in NON_NEGATIVE_GAINS if k in fields and fields[k] < 0]
    wrong += [f"{k} must be positive" for k in POSITIVE_GAINS if k in fields and fields[k] <= 0]
    if wrong:
        raise ValueError("; ".join(wrong))
    return design


def checked_handover(values: Any) -> HandoverDesign:
    """:class:`HandoverDesign` from a mapping (``lqr`` and ``pid`` sub-mappings and the hand-over sizes), checked."""
    if not isinstance(values, dict) or not {"lqr", "pid"} <= set(values) or set(values) - set(HANDOVER_SIZES) - {
            "lqr", "pid"}:  # fmt: skip
        raise ValueError(f"expected HandoverDesign values {{lqr: {{…}}, pid: {{…}}, {', '.join(HANDOVER_SIZES)}}}, "
                         f"got {values!r}")  # fmt: skip
    try:
        lqr, pid = checked_design(values["lqr"], "lqr"), checked_design(values["pid"], "pid")
    except ValueError as exc:
        raise ValueError(f"handover: {exc}") from None
    assert isinstance(lqr, LQRDesign) and isinstance(pid, PIDGains)
    sizes = {k: values.get(k, getattr(HandoverDesign, k)) for k in HANDOVER_SIZES}
    bad = [k for k, v in sizes.items() if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
           or v < 0 or (v == 0 and k not in HANDOVER_OPTIONAL)]  # fmt: skip
    if bad:
        raise ValueError(f"{bad} must be positive numbers ({', '.join(HANDOVER_OPTIONAL)} may be 0: off)")
    if sizes["release_mm"] <= sizes["handover_mm"]:
        raise ValueError(f"release_mm ({sizes['release_mm']}) must be more than handover_mm ({sizes['handover_mm']})")
    if sizes["push_release_mm"] >= sizes["release_mm"]:
        raise ValueError(f"push_release_mm ({sizes['push_release_mm']}) must be less than release_mm "
                         f"({sizes['release_mm']}), or 0 (off)")  # fmt: skip
    return HandoverDesign(lqr=lqr, pid=pid, **{k: float(v) for k, v in sizes.items()})


def shipped_design(name: str) -> PIDGains | LQRDesign | HandoverDesign:
    """The design of the shipped classical controller ``name`` (a key of :data:`CLASSICAL`), from its file."""
    kind, filename, _ = CLASSICAL[name]
    return checked_design(json.loads((Path(__file__).resolve().parent / "policies" / filename).read_text()), kind)


def classical_controller(kind: str, design: PIDGains | LQRDesign | HandoverDesign, geometry: Any = "servo-hexapod",
                         dt: float = 0.02, plate_half: tuple[float, float] | None = None) -> Any:  # fmt: skip
    """The PID (``kind`` ``"pid"``, from its gains, adapted by :func:`gains_for_geometry`), the LQR (``"lqr"``,
    designed by :func:`design_lqr`) or the LQR → PID hand-over (``"handover"``, both so) for ``geometry`` at
    control period ``dt``; observation scales follow the plate (``plate_half``, default the geometry's)."""
    geo = load_geometry(geometry)
    half = plate_half or (geo.plate_extent[0] / 2, geo.plate_extent[1] / 2)
    if kind == "handover":
        assert isinstance(design, HandoverDesign)
        lqr = design_lqr(design.lqr, dt=dt, geometry=geo)
        pid = gains_for_geometry(design.pid, geo)
        return HandoverController(HandoverGains(lqr=lqr, pid=pid, max_tilt=pid.max_tilt, handover_mm=design.handover_mm,
                                                handover_mm_s=design.handover_mm_s, release_mm=design.release_mm,
                                                dt=dt, handover_dwell_s=design.handover_dwell_s,
                                                release_dwell_s=design.release_dwell_s,
                                                release_mm_s=design.release_mm_s,
                                                push_release_mm=design.push_release_mm),
                                  plate_half=half)  # fmt: skip
    if kind == "lqr":
        assert isinstance(design, LQRDesign)
        return LQRController(design_lqr(design, dt=dt, geometry=geo), plate_half=half)
    assert isinstance(design, PIDGains)
    return CascadedPID(gains_for_geometry(design, geo), dt=dt, plate_half=half)


def controller_from_gains(kind: str, gains: dict[str, Any],
                          plate_half: tuple[float, float] = (0.15, 0.15)) -> Any:  # fmt: skip
    """The controller of ``kind`` from gains as a bundle stores them (the fields of :class:`PIDGains`,
    :class:`LQRGains` or :class:`HandoverGains`, lists for tuples): no design step, numpy only. Raises
    ``KeyError``, ``TypeError`` or ``ValueError`` for malformed gains."""

    def lqr_gains(values: dict[str, Any]) -> LQRGains:
        lqr = LQRGains(**{**values, "k": tuple(float(v) for v in values["k"])})
        if len(lqr.k) != 5:
            raise TypeError(f"k has {len(lqr.k)} gains, expected 5")
        return lqr

    if kind == "pid":
        return CascadedPID(PIDGains(**gains), plate_half=plate_half)
    if kind == "lqr":
        return LQRController(lqr_gains(gains), plate_half=plate_half)
    if kind == "handover":
        rest = {k: v for k, v in gains.items() if k not in ("lqr", "pid")}
        return HandoverController(HandoverGains(lqr=lqr_gains(gains["lqr"]), pid=PIDGains(**gains["pid"]), **rest),
                                  plate_half=plate_half)  # fmt: skip
    raise ValueError(f"unknown classical kind {kind!r} (expected one of {list(CLASSICAL_KINDS)})")


def residual_action(base_action: np.ndarray, correction: np.ndarray, obs: np.ndarray, scale: float,
                    plate_half: tuple[float, float], fade_mm: float, inner_mm: float = 0.0) -> np.ndarray:  # fmt: skip
    """What a residual policy sends: ``clip(base + scale · w · correction, −1, 1)`` (float32), where the weight
    ``w = clip((d − inner_mm) / fade_mm, 0, 1)`` with d the observed ball's distance to the target: within
    ``inner_mm`` of the target the classical controller acts alone, over the next ``fade_mm`` the learned
    correction fades in (``w = 1`` everywhere when both are 0; a step at ``inner_mm`` when ``fade_mm`` is 0)."""
    o = np.asarray(obs, dtype=np.float64)
    weight: Any = 1.0
    if fade_mm > 0 or inner_mm > 0:
        error = (o[..., 0:2] - o[..., 4:6]) * np.asarray(plate_half, dtype=np.float64)
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
    the target, short of the inner radius, is cut there and the base brings it in (a run-time guard: two track
    networks trained with it learned to circle wider instead, in and out of ``release_mm``; docs: Control).
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

    def reset(self) -> None:
        """Start of an episode: the latch is open (the correction acts wherever the fade lets it)."""
        self._off = None
        self._inside = None

    def __call__(self, base_action: np.ndarray, correction: np.ndarray, obs: np.ndarray) -> np.ndarray:
        correction = np.asarray(correction, dtype=np.float64)
        if self.release_mm > 0:
            o = np.asarray(obs, dtype=np.float64)
            error = (o[..., 0:2] - o[..., 4:6]) * np.asarray(self.plate_half, dtype=np.float64)
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
