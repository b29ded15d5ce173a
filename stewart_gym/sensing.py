"""Ball sensing and observations, shared by the environments and the hardware control loop.

* :class:`BallSensor`: the sensor seam, a small Protocol. The env reads a
  simulated sensor through it and ``deploy`` reads a real one (the touch panel
  on the serial line today, a camera next); :class:`SimulatedSensor` adds what
  a simulated one needs from the physics.
* :func:`ball_contact`: whether the ball is on the plate and touching it (one
  rule for the env and the deploy dry run).
* :class:`SimulatedTouchPanel`: what a resistive touch panel reports of the
  simulated ball: plate-frame (x, y) sampled at ``rate_hz``, ``latency_s`` old,
  with Gaussian noise of ``noise_mm``; nothing while the ball is off the plate.
* :class:`VelocityEstimator`: velocity from successive position samples (finite
  difference, first-order low-pass), as a real controller must estimate it.
* :class:`BallKalmanFilter`: position and velocity *now* from delayed, noisy
  samples, with the plate's commanded tilt as the model's input (the
  observer's ``estimator="kalman"``).
* :class:`ObservationBuilder`: the observation vector and its bounds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from stewart_gym.constants import GRAVITY

__all__ = ["ESTIMATORS", "BallKalmanFilter", "BallObserver", "BallSensor", "KalmanSpec", "ObservationBuilder", "Reading",
           "SimulatedSensor", "SimulatedTouchPanel", "TouchPanelSpec", "VelocityEstimator", "ball_contact",
           "observation_table", "READING_MARGIN", "reading_is_valid", "readings_are_valid"]  # fmt: skip

#: How the observer estimates the ball's state from the readings (:class:`BallObserver`).
ESTIMATORS = ("lowpass", "kalman")

#: A sensor reading: ((x, y) m in the plate frame, the time the sample was taken, s, on the reader's clock).
Reading = tuple[tuple[float, float], float]
#: Fraction of the plate's half size that a reading may lie beyond the plate's edge (a noisy reading of a ball
#: on the rim) and still count. Further out, the sensor is wrong: no ball can be there.
READING_MARGIN = 0.1


def reading_is_valid(reading: Reading, plate_half: Sequence[float]) -> bool:
    """Whether a sensor reading can be a ball on the plate: (x, y) and its time finite numbers, and (x, y) within
    the plate's half size ``plate_half`` (m) plus :data:`READING_MARGIN`.

    A reading that fails is *no reading*: the environments' observer, the camera sensor and the deploy loop
    treat it exactly as a sample that never arrived (so the deploy watchdog sees the sensor go stale).
    """
    try:
        (x, y), ts = reading
        x, y, ts = float(x), float(y), float(ts)
    except (TypeError, ValueError):
        return False
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(ts)):
        return False
    reach = 1.0 + READING_MARGIN
    return abs(x) <= plate_half[0] * reach and abs(y) <= plate_half[1] * reach


def readings_are_valid(xy: np.ndarray, ts: np.ndarray, plate_half: Sequence[float]) -> np.ndarray:
    """:func:`reading_is_valid` of many readings at once: ``xy`` (rows × 2) m taken at ``ts`` (rows) s; (rows) bool."""
    reach = np.array([plate_half[0], plate_half[1]], dtype=np.float64) * (1.0 + READING_MARGIN)
    xy = np.asarray(xy)
    # column by column (NumPy's reductions along rows of two are several times slower), compared in float64 as
    # reading_is_valid compares; a NaN or an infinite coordinate fails its comparison
    return np.isfinite(ts) & (np.abs(xy[:, 0]) <= reach[0]) & (np.abs(xy[:, 1]) <= reach[1])


@runtime_checkable
class BallSensor(Protocol):
    """Where a sensor says the ball is.

    ``read(t)`` gives the newest reading available at time ``t`` (s) or None
    when there is none (no ball, nothing received yet). The sample time is on
    the same clock as ``t`` and never later than it; its age ``t − sample
    time`` is what the deploy watchdog checks.
    """

    def read(self, t: float) -> Reading | None: ...


@runtime_checkable
class SimulatedSensor(BallSensor, Protocol):
    """A sensor model fed by the physics: the env calls :meth:`reset` at each episode start and
    :meth:`record` with the true ball position every control step."""

    def reset(self, t: float, xy: Sequence[float], rng: np.random.Generator) -> None: ...

    def record(self, t: float, xy: Sequence[float], touching: bool) -> None: ...


def ball_contact(x: Any, y: Any, z: Any, half_extent: tuple[float, float], plate_top: Any,
                 radius: Any) -> tuple[Any, Any]:  # fmt: skip
    """(on the plate, touching the panel) for a ball centre at (x, y, z) in the platform frame: numbers, or
    arrays with a value per ball (then two boolean arrays).

    On the plate: its centre is over the plate and above the surface. Touching:
    on the plate and its centre lower than 1.5 radii above the surface (a ball
    in the air presses nothing). A NaN anywhere is neither.
    """
    on = (np.abs(x) <= half_extent[0]) & (np.abs(y) <= half_extent[1]) & (z > plate_top)
    return on, on & (z < plate_top + 1.5 * radius)


@dataclass(frozen=True)
class TouchPanelSpec:
    """A resistive touch panel.

    Attributes:
        noise_mm: standard deviation of each reported coordinate, mm.
        rate_hz: samples per second.
        latency_s: age of a sample when it is reported, s.
    """

    noise_mm: float = 1.0
    rate_hz: float = 100.0
    latency_s: float = 0.010

    def __post_init__(self) -> None:
        if not (self.noise_mm >= 0 and self.rate_hz > 0 and self.latency_s >= 0):
            raise ValueError(f"invalid touch panel spec {self}")


class BallHistory:
    """The true ball positions a sensor model was fed: (t, x, y, touching), interpolated in between.

    Args:
        history_s: roughly how much to keep (1,000 entries per second of it, at least 8).
    """

    def __init__(self, history_s: float = 1.0) -> None:
        self._entries: deque[tuple[float, float, float, bool]] = deque(maxlen=max(8, int(history_s * 1000)))

    def clear(self) -> None:
        self._entries.clear()

    def append(self, t: float, x: float, y: float, touching: bool) -> None:
        self._entries.append((float(t), float(x), float(y), bool(touching)))

    def at(self, ts: float) -> tuple[float, float, bool]:
        """(x, y, touching) at time ``ts``: linear between the entries around it, the last one after it, and
        touching only if both neighbours were."""
        hist = self._entries
        i = len(hist) - 1
        while i > 0 and hist[i][0] > ts:
            i -= 1
        t0, x0, y0, on0 = hist[i]
        if i + 1 < len(hist):
            t1, x1, y1, on1 = hist[i + 1]
            w = (ts - t0) / (t1 - t0) if t1 > t0 else 0.0
            return x0 + w * (x1 - x0), y0 + w * (y1 - y0), on0 and on1
        return x0, y0, on0


class SimulatedTouchPanel:
    """Touch-panel readings of a simulated ball.

    Feed it the true ball position every control step with :meth:`record`; read
    the panel with :meth:`read`. The sample reported at time t is the one taken
    at ``floor((t − latency) · rate) / rate``, the true position then (linear
    interpolation between recorded steps) plus noise drawn once per sample.
    """

    def __init__(self, spec: TouchPanelSpec, history_s: float = 1.0) -> None:
        self.spec = spec
        self._history = BallHistory(history_s)
        self._noise: dict[int, tuple[float, float]] = {}
        self._draws: list[float] = []
        self._rng = np.random.default_rng()

    def reset(self, t: float, xy: np.ndarray, rng: np.random.Generator) -> None:
        """Start over at time ``t`` (s) with the ball at ``xy`` (m), drawing noise from ``rng``."""
        self._history.clear()
        self._noise.clear()
        self._draws.clear()
        self._rng = rng
        # The ball was at rest there before t, so readings older than t are defined.
        self._history.append(t - self.spec.latency_s - 1.0 / self.spec.rate_hz - 1.0, xy[0], xy[1], True)
        self.record(t, xy, True)

    def record(self, t: float, xy: np.ndarray, on_plate: bool) -> None:
        """Record the true plate-frame ball position ``xy`` (m) at time ``t`` (s)."""
        self._history.append(t, xy[0], xy[1], on_plate)

    def read(self, t: float) -> tuple[tuple[float, float], float] | None:
        """((x, y) m, sample time s) reported at time ``t``, or None if the ball was not touching the panel."""
        spec = self.spec
        k = math.floor((t - spec.latency_s) * spec.rate_hz + 1e-9)
        ts = k / spec.rate_hz
        x, y, on = self._history.at(ts)
        if not on:
            return None
        noise = self._noise.get(k)
        if noise is None:
            if not self._draws:  # standard normals in blocks: one generator call per 64 samples
                self._draws = self._rng.standard_normal(128).tolist()
            sigma = spec.noise_mm * 1e-3
            noise = (sigma * self._draws.pop(), sigma * self._draws.pop())
            if len(self._noise) > 256:
                self._noise.clear()
            self._noise[k] = noise
        return (x + noise[0], y + noise[1]), ts


class VelocityEstimator:
    """Velocity (m/s) from successive position samples: finite difference, then a first-order low-pass.

    Args:
        cutoff_hz: low-pass cut-off frequency.
    """

    def __init__(self, cutoff_hz: float = 8.0) -> None:
        self.tau = 1.0 / (2 * math.pi * cutoff_hz)
        self.reset(0.0, (0.0, 0.0))

    def reset(self, t: float, xy: tuple[float, float] | np.ndarray) -> None:
        """Start from rest at ``xy`` (m) at time ``t`` (s)."""
        self._t, self._x, self._y = float(t), float(xy[0]), float(xy[1])
        self.vx = self.vy = 0.0

    def update(self, t: float, xy: tuple[float, float] | np.ndarray) -> tuple[float, float]:
        """Add the sample ``xy`` (m) taken at ``t`` (s); return the filtered velocity (m/s)."""
        dt = float(t) - self._t
        if dt <= 0:
            return self.vx, self.vy
        x, y = float(xy[0]), float(xy[1])
        alpha = dt / (dt + self.tau)
        self.vx += alpha * ((x - self._x) / dt - self.vx)
        self.vy += alpha * ((y - self._y) / dt - self.vy)
        self._t, self._x, self._y = float(t), x, y
        return self.vx, self.vy


class ReadingNoise:
    """The noise of a sensor's readings, estimated from the readings themselves.

    The third difference of equally spaced readings, ``z[k] − 3 z[k−1] + 3 z[k−2] − z[k−3]``, cancels every
    motion of constant acceleration; what motion leaves (the jerk times the spacing cubed: micrometres for a
    rolling ball read at 50 Hz) is small against the noise, whose part has variance 20 σ² for independent
    noise of σ per coordinate. The estimate of σ² is a running mean of that, over both axes, that starts at
    ``prior_mm`` (weighed as ``prior_readings`` readings) and forgets with a window of ``window`` readings.
    A reading whose spacing differs by more than a quarter from the one before (a missed sample, the ball
    lifted off) starts the differences over; the estimate is kept.
    """

    def __init__(self, prior_mm: float, window: int = 50, prior_readings: int = 10) -> None:
        if not (math.isfinite(prior_mm) and prior_mm > 0 and window >= 1 and prior_readings >= 1):
            raise ValueError(f"need prior_mm > 0, window ≥ 1 and prior_readings ≥ 1, got {prior_mm!r}, {window!r}, "
                             f"{prior_readings!r}")  # fmt: skip
        self.prior = (prior_mm * 1e-3) ** 2
        self.window, self.prior_readings = int(window), int(prior_readings)
        self.reset()

    def reset(self) -> None:
        """Back to the prior, no readings."""
        self.variance = self.prior  # m², per coordinate
        self.count = 0
        self._last: list[tuple[float, float, float]] = []  # (t, x, y), equally spaced, oldest first

    @property
    def noise_mm(self) -> float:
        """The estimated standard deviation of one coordinate of a reading, mm."""
        return math.sqrt(self.variance) * 1e3

    def update(self, ts: float, xy: Sequence[float]) -> float:
        """A reading ``xy`` (m) taken at ``ts`` (s), later than the last; returns the estimated variance (m²)."""
        last = self._last
        if len(last) >= 2 and abs((ts - last[-1][0]) - (last[-1][0] - last[-2][0])) > 0.25 * (ts - last[-1][0]):
            del last[:-1]
        last.append((float(ts), float(xy[0]), float(xy[1])))
        if len(last) == 4:
            (_, x0, y0), (_, x1, y1), (_, x2, y2), (_, x3, y3) = last
            dx, dy = x3 - 3 * x2 + 3 * x1 - x0, y3 - 3 * y2 + 3 * y1 - y0
            if math.isfinite(dx) and math.isfinite(dy):
                self.count += 1
                weight = max(1.0 / (self.count + self.prior_readings), 1.0 / self.window)
                self.variance += weight * ((dx * dx + dy * dy) / 40.0 - self.variance)
            del last[0]
        return self.variance


@dataclass(frozen=True)
class KalmanSpec:
    """The model of :class:`BallKalmanFilter`, per plate axis.

    The ball rolls with acceleration ``a + b``: ``a`` follows the commanded tilt's ``c·g·sin(tilt)`` as a
    first-order lag of ``tilt_lag_s`` after a dead time of ``dead_time_s`` (the servos': measured on the
    reference build, 17 ms and 19 ms for a 2.5° step), and ``b`` is a slowly drifting bias (trim errors, a load
    on the plate, a plate that is not level). Defaults: a solid ball on the reference servos, a resistive panel.

    Attributes:
        rolling_factor: c (5/7 solid ball, 3/5 hollow).
        tilt_lag_s: s, time constant of the plate's tilt after the dead time.
        dead_time_s: s, from a command to the start of the plate's motion.
        accel_noise: m/s², white acceleration noise (rolling friction, tilt errors, contact).
        bias_noise: m/s² per √s, random walk of the bias.
        measurement_noise_mm: mm, standard deviation of a reading: the filter's starting value when it
            estimates the noise itself.
        noise_window: readings; > 0: the filter estimates the readings' noise from the readings
            (:class:`ReadingNoise`, this window) and weighs them by it, so one filter suits a quiet panel and a
            noisy one; 0: it keeps ``measurement_noise_mm``.
    """

    rolling_factor: float = 5.0 / 7.0
    tilt_lag_s: float = 0.019
    dead_time_s: float = 0.017
    accel_noise: float = 0.05
    bias_noise: float = 0.05
    measurement_noise_mm: float = 1.5
    noise_window: int = 50

    def __post_init__(self) -> None:
        if not (isinstance(self.noise_window, int) and self.noise_window >= 0):
            raise ValueError(f"noise_window must be a whole number ≥ 0, got {self.noise_window!r}")
        for key in ("rolling_factor", "tilt_lag_s", "accel_noise", "measurement_noise_mm"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{key} must be a positive number, got {v!r}")
        for key in ("dead_time_s", "bias_noise"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{key} must be ≥ 0, got {v!r}")


class BallKalmanFilter:
    """Ball position and velocity *now*, from delayed and noisy readings, both plate axes at once.

    State per axis: position, velocity, plate acceleration ``a`` and bias ``b`` (:class:`KalmanSpec`). The
    input is the commanded tilt, known to the controller. A reading taken at ``ts`` updates the estimate at
    ``ts`` (the filter runs at the readings' own times, so sensing latency is in the model, not an error), and
    :meth:`estimate` predicts from there to now through the commands sent since, which also bridges missed
    readings. Exact discretisation for any interval (the matrix exponential in closed form: :meth:`transition`).
    By default it weighs each reading by the noise it measures in the readings (:class:`ReadingNoise`,
    ``KalmanSpec.noise_window``), so the same filter smooths a noisy panel more and follows a quiet one more
    closely.
    """

    #: m: the least reading noise the filter assumes when it measures less (a noise-free simulated sensor; a
    #: real panel's quantisation is more), so that it never takes a reading for exact.
    MIN_NOISE_M = 5e-5

    def __init__(self, spec: KalmanSpec | None = None) -> None:
        self.spec = spec or KalmanSpec()
        c = self.spec
        self._qc_diagonal = np.array([0.0, c.accel_noise**2, 0.0, c.bias_noise**2])  # Qc is diagonal
        self.noise = ReadingNoise(c.measurement_noise_mm, c.noise_window) if c.noise_window else None
        self._r = (c.measurement_noise_mm * 1e-3) ** 2
        self._cache: dict[float, tuple[Any, ...]] = {}  # by µs of interval
        self._seen: dict[float, tuple[Any, ...]] = {}  # by interval, as given
        self.reset(0.0, (0.0, 0.0))

    def reset(self, t: float, xy: Sequence[float]) -> None:
        """The ball at rest at ``xy`` (m) at ``t`` (s), no commands yet; the bias and velocity uncertain."""
        if self.noise is not None:
            self.noise.reset()
            self._r = self.noise.variance
        self._state = (float(xy[0]), float(xy[1]), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self._cov = (self._r, 0.0, 0.0, 0.0, 0.1**2, 0.0, 0.0, 0.5**2, 0.0, 0.5**2)
        self.t = float(t)  # the time of the estimate self.x
        # (when it acts: issued + the dead time, sin of the tilt along x, y), in time order
        self._commands: list[tuple[float, tuple[float, float]]] = []
        self._last_issued = -math.inf

    @property
    def x(self) -> np.ndarray:
        """The estimate at :attr:`t`, 4×2: rows position, velocity, plate acceleration, bias; columns x, y."""
        return np.array(self._state).reshape(4, 2)

    @property
    def P(self) -> np.ndarray:  # noqa: N802 (the covariance's usual name)
        """The estimate's covariance at :attr:`t`, 4×4 (the same for both axes): position, velocity, plate
        acceleration, bias."""
        pp, pv, pa, pb, vv, va, vb, aa, ab, bb = self._cov
        return np.array([[pp, pv, pa, pb], [pv, vv, va, vb], [pa, va, aa, ab], [pb, vb, ab, bb]])

    def command(self, t: float, roll_pitch: Sequence[float]) -> None:
        """The plate was commanded to (roll, pitch) rad at ``t`` (s)."""
        u = (math.sin(roll_pitch[1]), -math.sin(roll_pitch[0]))  # x rolls with pitch, y against roll
        if self._commands and t <= self._last_issued:
            self._commands[-1] = (self._commands[-1][0], u)
        else:
            self._last_issued = float(t)
            self._commands.append((self._last_issued + self.spec.dead_time_s, u))
        while len(self._commands) > 1 and self._commands[1][0] <= self.t:  # spent before the estimate's time
            self._commands.pop(0)

    def update(self, ts: float, xy: Sequence[float]) -> None:
        """A reading of the ball at ``xy`` (m) taken at ``ts`` (s); older than the estimate: ignored."""
        if ts <= self.t:
            return
        if self.noise is not None:
            self._r = max(self.noise.update(ts, xy), self.MIN_NOISE_M**2)
        self._state, self._cov = self._propagate(self._state, self._cov, self.t, ts)
        self.t = float(ts)
        # The gain is P's first column over (P₀₀ + r); P loses gain_i · P₀ⱼ. Written out on the ten entries of
        # the symmetric P (upper triangle, row by row) and the eight of the state (rows as above, x then y).
        pp, pv, pa, pb, vv, va, vb, aa, ab, bb = self._cov
        s = pp + self._r
        k0, k1, k2, k3 = pp / s, pv / s, pa / s, pb / s
        px, py, vx, vy, ax, ay, bx, by = self._state
        ex, ey = float(xy[0]) - px, float(xy[1]) - py
        self._state = (px + k0 * ex, py + k0 * ey, vx + k1 * ex, vy + k1 * ey,
                       ax + k2 * ex, ay + k2 * ey, bx + k3 * ex, by + k3 * ey)  # fmt: skip
        self._cov = (pp - k0 * pp, pv - k0 * pv, pa - k0 * pa, pb - k0 * pb, vv - k1 * pv, va - k1 * pa,
                     vb - k1 * pb, aa - k2 * pa, ab - k2 * pb, bb - k3 * pb)  # fmt: skip

    def estimate(self, t: float) -> tuple[tuple[float, float], tuple[float, float]]:
        """Predicted (x, y) position (m) and velocity (m/s) at ``t`` (s)."""
        px, py, vx, vy = self._propagate(self._state, None, self.t, max(t, self.t))[0][:4]
        return (px, py), (vx, vy)

    def _propagate(self, state: tuple[float, ...], cov: tuple[float, ...] | None, t0: float,
                   t1: float) -> tuple[tuple[float, ...], Any]:  # fmt: skip
        """The state (and covariance, unless None) carried from ``t0`` to ``t1`` through the commands acting in
        between: one exact step per interval of constant input (a command acts a dead time after it was
        issued). Φ x + Γ u and Φ P Φᵀ + Q are written out on Φ's non-zero entries (:meth:`transition`): on a
        4×4 matrix numpy's per-call overhead would be most of the work (``bench/bench_env.py``)."""
        if t1 <= t0:
            return state, cov
        acting, seen = self._commands, self._seen
        edges = [t0, *[s for s, _ in acting if t0 < s < t1], t1]
        (ux, uy), k, n = (0.0, 0.0), 0, len(acting)
        for a, b in zip(edges[:-1], edges[1:]):
            while k < n and acting[k][0] <= a + 1e-9:  # the last command acting at a
                (ux, uy), k = acting[k][1], k + 1
            h, c, lag, half_h2, e, gp, gv, ga, q = seen.get(b - a) or self._discrete(b - a)
            px, py, vx, vy, ax, ay, bx, by = state
            state = (px + h * vx + c * ax + half_h2 * bx + gp * ux, py + h * vy + c * ay + half_h2 * by + gp * uy,
                     vx + lag * ax + h * bx + gv * ux, vy + lag * ay + h * by + gv * uy,
                     e * ax + ga * ux, e * ay + ga * uy, bx, by)  # fmt: skip
            if cov is not None:
                pp, pv, pa, pb, vv, va, vb, aa, ab, bb = cov
                # M = Φ P, rows 0 and 1 (rows 2 and 3 are e·P₂ⱼ and P₃ⱼ); then Φ P Φᵀ = M Φᵀ, upper triangle
                m00 = pp + h * pv + c * pa + half_h2 * pb
                m01 = pv + h * vv + c * va + half_h2 * vb
                m02 = pa + h * va + c * aa + half_h2 * ab
                m03 = pb + h * vb + c * ab + half_h2 * bb
                m11, m12, m13 = vv + lag * va + h * vb, va + lag * aa + h * ab, vb + lag * ab + h * bb
                cov = (m00 + h * m01 + c * m02 + half_h2 * m03 + q[0], m01 + lag * m02 + h * m03 + q[1],
                       e * m02, m03 + q[2], m11 + lag * m12 + h * m13 + q[3], e * m12, m13 + q[4],
                       e * e * aa, e * ab, bb + q[5])  # fmt: skip
        return state, cov

    def _discrete(self, h: float) -> tuple[Any, ...]:
        """Φ's non-zero entries over an interval of ``h`` s (h, Φ₀₂, Φ₁₂, Φ₀₃, Φ₂₂), Γ's (Γ₀, Γ₁, Γ₂), and the
        process noise ``Q = Φ Qc Φᵀ h``'s (Q₀₀, Q₀₁, Q₀₃, Q₁₁, Q₁₃, Q₃₃; its row and column 2 are zero, as Qc's
        are and Φ keeps them): the model's exact transition in closed form (:meth:`transition`). Cached per µs
        of interval: the simulator's intervals repeat; a real clock's seldom do, and there each interval costs a few
        ufunc calls and one 4×4 product (``bench/bench_deploy.py``), where a general matrix exponential would cost
        several times more and stall on a busy machine. Called for an interval not yet in ``self._seen`` (the
        intervals as given, which :meth:`_propagate` looks up first, so that a repeat skips the rounding); it
        records it there."""
        key = round(h, 6)
        found = self._cache.get(key)
        if found is None:
            e, lag, phi02, gammas = self._closed_form(key)
            phi = self._phi(key, e, lag, phi02)
            # Φ Qc is Φ's columns scaled by Qc's diagonal (the same values as the product with the diagonal
            # matrix); (Φ Qc) Φᵀ stays one matrix product, whose rounding the published figures were made with.
            q = ((phi * self._qc_diagonal) @ phi.T * key).tolist()
            noise = (q[0][0], q[0][1], q[0][3], q[1][1], q[1][3], q[3][3])
            found = self._cache[key] = (key, phi02, lag, 0.5 * key * key, e, *gammas, noise)
        for table in (self._seen, self._cache):
            if len(table) > 512:
                table.clear()
        self._seen[h] = found
        return found

    def _closed_form(self, h: float) -> tuple[float, float, float, tuple[float, float, float]]:
        """E = exp(−h/τ), the lag τ(1 − E), Φ₀₂ and (Γ₀, Γ₁, Γ₂) over ``h`` s (:meth:`transition`)."""
        tau, k = self.spec.tilt_lag_s, self.spec.rolling_factor * GRAVITY
        e = math.exp(-h / tau)
        lag = tau * (1.0 - e)  # ∫ e^(−s/τ) ds over the interval
        gammas = (k * (0.5 * h * h - tau * h + tau * lag), k * (h - lag), k * (1.0 - e))
        return e, lag, tau * h - tau * lag, gammas

    @staticmethod
    def _phi(h: float, e: float, lag: float, phi02: float) -> np.ndarray:
        return np.array([[1.0, h, phi02, 0.5 * h * h],
                         [0.0, 1.0, lag, h],
                         [0.0, 0.0, e, 0.0],
                         [0.0, 0.0, 0.0, 1.0]])  # fmt: skip

    def transition(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        """Φ (4×4) and Γ (4,) of the model over ``h`` s, so that x(t + h) = Φ x(t) + Γ u for a constant input u
        (the sine of the commanded tilt): ``expm([[A, B], [0, 0]] h)`` in closed form. With E = exp(−h/τ), the
        plate's acceleration a relaxes to c·g·u as a + (c·g·u − a)(1 − E); velocity and position integrate it
        and the bias."""
        e, lag, phi02, gammas = self._closed_form(h)
        return self._phi(h, e, lag, phi02), np.array([*gammas, 0.0])


class ObservationBuilder:
    """The observation vector (float32) of the ball environments and the deployed controller.

    Its layout is :attr:`FIELDS` (one copy: the docs' table and the env's
    docstring are generated from it by :func:`observation_table`). Positions
    are divided by the plate's half size h along each axis and velocities by
    h / (0.3 s), so the same policy sees the same numbers on any plate (on the
    reference 300 mm plate: 0.15 m and 0.5 m/s); tilts are divided by 0.25 rad.
    Each entry is then clipped to its bound, so it lies in about [-1, 1].

    Args:
        action_size: 2 ("tilt") or 6.
        plate_half: (h_x, h_y) m, half the plate's width and depth.
    """

    #: s: velocities are divided by h / VELOCITY_TIME (0.5 m/s on the reference 0.15 m half plate).
    VELOCITY_TIME = 0.3
    TILT_SCALE = 0.25
    #: Version of the layout below: a bundle records it, and deploy refuses a bundle made for another.
    LAYOUT_VERSION = 2
    #: (what, count, divided by, bound) per group of entries, in order; count None is the action size.
    FIELDS: tuple[tuple[str, int | None, str, float], ...] = (
        ("ball x, y from the sensor (plate frame)", 2, "h_x, h_y (m)", 2.0),
        ("ball velocity, estimated from the readings", 2, "h_x, h_y / 0.3 s (m/s)", 5.0),
        ("target x, y (plate frame)", 2, "h_x, h_y (m)", 2.0),
        ("target velocity", 2, "h_x, h_y / 0.3 s (m/s)", 5.0),
        ("commanded roll, pitch (0 in `pulse` mode)", 2, "0.25 rad", 2.0),
        ("previous action, as applied", None, "1", 1.0),
    )
    #: The names of :attr:`FIELDS`' groups, in order: what the accessors (:meth:`ball_position`, …) read.
    FIELD_NAMES = ("ball_position", "ball_velocity", "target_position", "target_velocity", "commanded_tilt",
                   "previous_action")  # fmt: skip
    #: s: the error integral is divided by h × INTEGRAL_TIME (0.015 m·s on the reference plate).
    INTEGRAL_TIME = 0.1
    #: The optional last group (``integral=True``): the observer's integral of the position error.
    INTEGRAL_FIELD: tuple[str, int, str, float] = (
        "integral of target − ball near the target (only with `integral=True`)", 2, "h_x, h_y × 0.1 s (m·s)", 2.0)

    def __init__(self, action_size: int, plate_half: tuple[float, float] = (0.15, 0.15),
                 integral: bool = False) -> None:  # fmt: skip
        self.action_size = int(action_size)
        self.integral = bool(integral)
        hx, hy = (float(v) for v in plate_half)
        if not (math.isfinite(hx) and math.isfinite(hy) and hx > 0 and hy > 0):
            raise ValueError(f"plate_half must be two positive lengths, got {plate_half!r}")
        self.position_scale = (hx, hy)
        self.velocity_scale = (hx / self.VELOCITY_TIME, hy / self.VELOCITY_TIME)
        scales = [*self.position_scale, *self.velocity_scale, *self.position_scale, *self.velocity_scale,
                  self.TILT_SCALE, self.TILT_SCALE] + [1.0] * self.action_size  # fmt: skip
        self.integral_scale = (hx * self.INTEGRAL_TIME, hy * self.INTEGRAL_TIME)
        high: list[float] = []
        for _, count, _, bound in self.FIELDS + ((self.INTEGRAL_FIELD,) if self.integral else ()):
            high += [bound] * (self.action_size if count is None else count)
        if self.integral:
            scales += list(self.integral_scale)
        self.size = len(high)
        first, self.slices = 0, {}
        for name, (_, count, _, _) in zip(self.FIELD_NAMES, self.FIELDS):
            count = self.action_size if count is None else count
            self.slices[name] = slice(first, first + count)
            first += count
        self._positions = np.array(self.position_scale)
        self._velocities = np.array(self.velocity_scale)
        high_arr = np.array(high, dtype=np.float32)
        self.low, self.high = -high_arr, high_arr
        self._scales, self._highs = [1.0 / k for k in scales], [float(v) for v in high_arr]
        self._scale_array, self._high_array = np.array(self._scales), np.array(self._highs)

    @property
    def space(self) -> Any:
        """The Gymnasium ``Box`` of the observation (needs gymnasium: the env side only)."""
        from gymnasium import spaces

        return spaces.Box(self.low, self.high, dtype=np.float32)

    # ------------------------------------------------------------ reading an observation back (…, size)
    def ball_position(self, obs: np.ndarray) -> np.ndarray:
        """(…, 2) m: the ball's position in observation(s) ``obs``, unscaled."""
        return np.asarray(obs, dtype=np.float64)[..., self.slices["ball_position"]] * self._positions

    def ball_velocity(self, obs: np.ndarray) -> np.ndarray:
        """(…, 2) m/s: the ball's estimated velocity, unscaled."""
        return np.asarray(obs, dtype=np.float64)[..., self.slices["ball_velocity"]] * self._velocities

    def target_position(self, obs: np.ndarray) -> np.ndarray:
        """(…, 2) m: the target's position, unscaled."""
        return np.asarray(obs, dtype=np.float64)[..., self.slices["target_position"]] * self._positions

    def target_velocity(self, obs: np.ndarray) -> np.ndarray:
        """(…, 2) m/s: the target's velocity, unscaled."""
        return np.asarray(obs, dtype=np.float64)[..., self.slices["target_velocity"]] * self._velocities

    def motion(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ball position, ball velocity, target position, target velocity), each (…, 2), m and m/s."""
        return self.ball_position(obs), self.ball_velocity(obs), self.target_position(obs), self.target_velocity(obs)

    def commanded_tilt(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(roll, pitch), rad, each (…): the tilt commanded at the previous observation, in force since."""
        o = np.asarray(obs, dtype=np.float64)
        first = self.slices["commanded_tilt"].start
        return o[..., first] * self.TILT_SCALE, o[..., first + 1] * self.TILT_SCALE

    def position_error(self, obs: np.ndarray) -> np.ndarray:
        """(…, 2) m: the ball's position less the target's."""
        o = np.asarray(obs, dtype=np.float64)
        return (o[..., self.slices["ball_position"]] - o[..., self.slices["target_position"]]) * self._positions

    def build(self, ball_xy: Sequence[float], ball_velocity: Sequence[float], target_xy: Sequence[float],
              target_velocity: Sequence[float], roll_pitch: Sequence[float],
              previous_action: Sequence[float], error_integral: Sequence[float] = ()) -> np.ndarray:  # fmt: skip
        """Assemble, scale and clip one observation; shape (size,), float32 (``error_integral``: m·s, only with
        ``integral=True``)."""
        raw = [*ball_xy, *ball_velocity, *target_xy, *target_velocity, *roll_pitch, *previous_action,
               *error_integral]  # fmt: skip
        if len(raw) != self.size:
            raise ValueError(f"observation parts add up to {len(raw)} values, expected {self.size}")
        # scalar arithmetic: for a dozen values it is several times faster than numpy calls
        return np.array([hi if (v := x * k) > hi else -hi if v < -hi else v
                         for x, k, hi in zip(raw, self._scales, self._highs)], dtype=np.float32)  # fmt: skip

    def build_many(self, raw: np.ndarray) -> np.ndarray:
        """:meth:`build` of many observations at once from their parts laid end to end (rows × size, in the
        layout's order, unscaled): scaled and clipped, (rows × size) float32."""
        highs = self._high_array
        scaled = np.multiply(raw, self._scale_array, dtype=np.float64)
        np.minimum(np.maximum(scaled, -highs, out=scaled), highs, out=scaled)  # np.clip's numbers, without its overhead
        return scaled.astype(np.float32)


class BallObserver:
    """Sensor readings → observation, the same way in the environments and on hardware.

    ``estimator="lowpass"`` (the default, what the shipped policies were trained with): the position is the
    last reading, held while the sensor reports none, and the velocity a low-passed finite difference of the
    readings (:class:`VelocityEstimator`). ``estimator="kalman"``: both are :class:`BallKalmanFilter`'s
    prediction for *now*, through the sensing delay and any missed readings, with the commanded tilt as input.
    The observation is built by :class:`ObservationBuilder`.

    ``integral=True`` appends the integral of the position error (target − estimate, m·s) per axis, what a
    PID's integral term sees: the error is summed only while the ball is within :attr:`INTEGRAL_ZONE` of the
    plate's half size of the target (so a fast approach does not wind it up), and the sum is held within the
    observation's bound (± 2 × h × 0.1 s, anti-windup). It lets a learned policy cancel a steady offset, such
    as the tilt left by servo trim errors.
    """

    #: Fraction of the plate's half size: the error is integrated only this close to the target (30 mm on 300 mm).
    INTEGRAL_ZONE = 0.2

    def __init__(self, action_size: int, velocity_cutoff_hz: float = 8.0,
                 plate_half: tuple[float, float] = (0.15, 0.15), estimator: str = "lowpass",
                 kalman: KalmanSpec | None = None, integral: bool = False) -> None:  # fmt: skip
        if estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {list(ESTIMATORS)}, got {estimator!r}")
        self.estimator = estimator
        self.builder = ObservationBuilder(action_size, plate_half, integral=integral)
        self.plate_half = self.builder.position_scale
        #: readings refused by :func:`reading_is_valid` since the observer was made (each observed as no reading)
        self.invalid_readings = 0
        bound = ObservationBuilder.INTEGRAL_FIELD[3]
        self.integral_limit = tuple(bound * k for k in self.builder.integral_scale)
        self.integral_zone = self.INTEGRAL_ZONE * min(float(v) for v in plate_half)
        # one estimator of the velocity: the low-pass finite difference, or the Kalman filter
        self.kalman = BallKalmanFilter(kalman) if estimator == "kalman" else None
        self.velocity = VelocityEstimator(velocity_cutoff_hz) if self.kalman is None else None
        self.reset(0.0, (0.0, 0.0))

    def reset(self, t: float, xy: tuple[float, float] | np.ndarray) -> None:
        """Start at time ``t`` (s) with the ball believed at rest at ``xy`` (m)."""
        if self.velocity is not None:
            self.velocity.reset(t, xy)
        self.reading = (float(xy[0]), float(xy[1]))
        self.t = float(t)
        self.error_integral = [0.0, 0.0]
        self.integral_t = float(t)
        if self.kalman is not None:
            self.kalman.reset(t, xy)

    def observe(self, reading: tuple[tuple[float, float], float] | None, target_xy: Sequence[float],
                target_velocity: Sequence[float], roll_pitch: Sequence[float], previous_action: Sequence[float],
                now: float | None = None) -> np.ndarray:  # fmt: skip
        """One observation from a ``reading`` ((x, y) m, sample time s) or None (no reading).

        ``roll_pitch`` is the tilt commanded at the previous observation (in force since), ``now`` the time of
        this one (s; default the reading's time): the Kalman filter uses both. A reading that is not
        :func:`valid <reading_is_valid>` (NaN, infinite, off the plate) is observed as no reading.
        """
        if reading is not None and not reading_is_valid(reading, self.plate_half):
            self.invalid_readings += 1
            reading = None
        if reading is not None:
            self.reading = reading[0]
        pos: Sequence[float] = self.reading
        if self.velocity is not None:
            vel = (self.velocity.vx, self.velocity.vy) if reading is None else self.velocity.update(reading[1], pos)
        else:  # the Kalman filter
            if now is None:
                now = reading[1] if reading is not None else self.t
            self.kalman.command(self.t, roll_pitch)
            if reading is not None:
                self.kalman.update(min(reading[1], now), reading[0])
            pos, vel = self.kalman.estimate(now)
            self.t = float(now)
        if not self.builder.integral:
            return self.builder.build(pos, vel, target_xy, target_velocity, roll_pitch, previous_action)
        t = self.integral_t if now is None and reading is None else float(reading[1] if now is None else now)
        dt, self.integral_t = max(0.0, t - self.integral_t), max(t, self.integral_t)
        ex, ey = target_xy[0] - pos[0], target_xy[1] - pos[1]
        if ex * ex + ey * ey <= self.integral_zone * self.integral_zone:
            self.error_integral = [min(lim, max(-lim, acc + e * dt))
                                   for acc, e, lim in zip(self.error_integral, (ex, ey), self.integral_limit)]  # fmt: skip
        return self.builder.build(pos, vel, target_xy, target_velocity, roll_pitch, previous_action,
                                  self.error_integral)  # fmt: skip


def observation_table() -> str:
    """The observation layout as a Markdown table (for the docs; generated from :attr:`ObservationBuilder.FIELDS`)."""
    rows = ["| index | observation | divided by | clipped to |", "|---|---|---|---|"]
    first = 0
    for what, count, scale, bound in ObservationBuilder.FIELDS:
        index = f"{first}, {first + 1}" if count == 2 else f"{first} … {first} + n − 1"
        rows.append(f"| {index} | {what} | {scale} | ±{bound:g} |")
        first += count or 0
    what, _, scale, bound = ObservationBuilder.INTEGRAL_FIELD
    rows.append(f"| 10 + n, 11 + n | {what} | {scale} | ±{bound:g} |")
    return "\n".join(rows)
