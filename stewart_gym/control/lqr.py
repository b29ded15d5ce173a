"""The LQR: designed on a linear model of the ball on the lagging plate (:func:`design_lqr`), run as a policy
(:class:`LQRController`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from stewart_gym.actions import default_max_tilt
from stewart_gym.constants import GRAVITY
from stewart_gym.control.arrays import bounded, paired
from stewart_gym.control.design import INTEGRAL_MARGIN, grown_zone, trim_tilt
from stewart_gym.control.parts import EpisodicController, SquareWaveDither, TargetFeed, integrate_error
from stewart_gym.presets import load_geometry

__all__ = ["LQRController", "LQRDesign", "LQRGains", "design_lqr", "lqr_model"]


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


class LQRController(EpisodicController):
    """A policy: observation (…, 12) → tilt action (…, 2), the LQR of :class:`LQRGains`.

    It reads the ball's position and velocity (indices 0–3: best from the Kalman observer, which predicts them
    for now), the target's (4–7) and the tilt in force (8–9). It keeps the model's plate acceleration (driven
    by the commands it sees in force) and the integral of the position error, and feeds the target's
    acceleration forward (:class:`TargetFeed`, leading by ``gains.feed_lead`` on a smooth path).
    """

    def __init__(self, gains: LQRGains, plate_half: tuple[float, float] = (0.15, 0.15)) -> None:
        super().__init__(plate_half)
        self.gains = gains
        self._k = np.asarray(gains.k, dtype=float)
        self._phi = math.exp(-gains.dt / gains.tilt_lag_s)
        self._dither = SquareWaveDither(gains.dither, gains.max_tilt)
        # the target's acceleration as the sin(tilt) that rolls the ball so
        self._feed = TargetFeed(gains.dt, gains.feed_lead, divisor=gains.dt * gains.rolling_factor * GRAVITY)
        self.reset()

    def reset(self, rows: np.ndarray | None = None) -> None:
        """Start of an episode: every row, or those of the boolean mask ``rows`` (the dither is shared)."""
        st = getattr(self, "_state", None)
        if rows is not None and st is not None and st["integral"].ndim == 2 and len(st["integral"]) == len(rows):
            st["integral"][rows] = 0.0
            for key in ("accel", "in_force"):  # the model's plate starts from the tilt in force, as at a reset
                st[key][rows] = np.nan
            self._feed.reset(rows)
            return
        self._state: dict[str, np.ndarray] | None = None
        self._feed.reset()
        self._dither.reset()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        g = self.gains
        o = np.asarray(obs, dtype=np.float64)
        pos, vel, target, target_vel = self.observation.motion(o)
        roll, pitch = self.observation.commanded_tilt(o)
        in_force = paired(np.sin(pitch), -np.sin(roll))  # sin(tilt) along x and y
        err = pos - target
        st = self._state
        if st is None or st["integral"].shape != err.shape:
            st = self._state = {"accel": in_force.copy(), "integral": np.zeros_like(err),
                                "in_force": in_force.copy()}  # fmt: skip
        elif np.isnan(st["accel"]).any():  # rows started afresh (reset(rows)): from the tilt in force
            fresh = np.isnan(st["accel"])
            st["accel"] = np.where(fresh, in_force, st["accel"])
            st["in_force"] = np.where(fresh, in_force, st["in_force"])
        st["accel"] = self._phi * st["accel"] + (1 - self._phi) * st["in_force"]  # driven by last period's command
        st["in_force"] = in_force
        st["integral"] = integrate_error(st["integral"], err, g.dt, g.integral_limit, g.integral_zone)
        feed = self._feed(target_vel)  # the target's acceleration, as a sin(tilt)
        k = self._k
        u = feed - (k[0] * err + k[1] * (vel - target_vel) + k[2] * (st["accel"] - feed) + k[3] * (in_force - feed)
                    + k[4] * st["integral"])  # fmt: skip
        s = bounded(u, -1.0, 1.0)
        return self._dither(bounded(paired(-np.arcsin(s[..., 1]), np.arcsin(s[..., 0])) / g.max_tilt, -1.0, 1.0))
