"""The touch panels, cameras and observers of N envs as arrays: what the batched vector env senses and observes
with.

:class:`PanelArray` is N :class:`~stewart_gym.sensing.SimulatedTouchPanel`, :class:`CameraArray` N
:class:`~stewart_gym.camera.SimulatedCamera` and :class:`ObserverArray` N :class:`~stewart_gym.sensing.BallObserver`
(the low-pass or the Kalman estimator, with the error integral or without), one row each, advanced for every row
with one NumPy operation per step of the arithmetic instead of one Python call per env, or, where numba is
installed, in compiled loops over the rows (the histories and the Kalman filters: the same operations in the same
order, so the same bits). They follow the one-env classes step for step: the same sample times, the same noise and
missed frames (drawn from each row's own generator, in the same order), the same filter equations; the results
agree to rounding (``tests/test_sensing_arrays.py``).

Each env of the vector env holds its own row as :class:`PanelRow`, :class:`CameraRow` and :class:`ObserverRow`, which
follow the one-env classes' interface, so that an env resets and observes alone exactly as it would with its own
sensor and observer, while the vector env resets (``set_specs``, ``reset_rows``) and steps many rows at once.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from stewart_gym.camera import FRAME_DRAWS, CameraSpec, camera_height, detection
from stewart_gym.compiled import compiled, exp_each, use_compiled
from stewart_gym.constants import GRAVITY
from stewart_gym.rows import put_rows
from stewart_gym.sensing import (
    BallKalmanFilter,
    BallObserver,
    KalmanSpec,
    ObservationBuilder,
    ReadingNoise,
    TouchPanelSpec,
    readings_are_valid,
)

__all__ = ["CameraArray", "CameraRow", "HistoryArray", "ObserverArray", "ObserverRow", "PanelArray", "PanelRow",
           "SensorRow"]

#: Standard normals drawn from a row's generator at a time, as :class:`~stewart_gym.sensing.SimulatedTouchPanel`.
DRAW_BLOCK = 128


def _history_record(rows: np.ndarray, t: np.ndarray, x: np.ndarray, y: np.ndarray, on: np.ndarray, ht: np.ndarray,
                    hx: np.ndarray, hy: np.ndarray, hon: np.ndarray) -> None:  # fmt: skip  # pragma: no cover - compiled
    """:meth:`HistoryArray.record` row by row: each row of ``rows`` shifts its history one column older and takes
    ``t``, ``x``, ``y``, ``on`` as its newest."""
    last = ht.shape[1] - 1
    for j in range(rows.shape[0]):
        r = rows[j]
        for c in range(last):
            ht[r, c], hx[r, c], hy[r, c], hon[r, c] = ht[r, c + 1], hx[r, c + 1], hy[r, c + 1], hon[r, c + 1]
        ht[r, last], hx[r, last], hy[r, last], hon[r, last] = t[j], x[j], y[j], on[j]


def _history_at(index: np.ndarray, ts: np.ndarray, ht: np.ndarray, hx: np.ndarray, hy: np.ndarray, hon: np.ndarray,
                x: np.ndarray, y: np.ndarray, on: np.ndarray) -> None:  # fmt: skip  # pragma: no cover - compiled
    """:meth:`HistoryArray.at` row by row into ``x``, ``y`` and ``on``: the same operations as its array path (a
    weight of 0 included, so that the same bits come out)."""
    last = ht.shape[1] - 1
    for j in range(index.shape[0]):
        r, t = index[j], ts[j]
        count = 0
        for c in range(last + 1):
            if ht[r, c] <= t:
                count += 1
        i = max(count - 1, 0)
        k = min(i + 1, last)
        x0, y0 = hx[r, i], hy[r, i]
        if i < last:
            t0, t1 = ht[r, i], ht[r, k]
            w = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
            x[j], y[j] = x0 + w * (hx[r, k] - x0), y0 + w * (hy[r, k] - y0)
        else:
            x[j], y[j] = x0, y0
        on[j] = hon[r, i] and hon[r, k]


#: :func:`_history_record` and :func:`_history_at` compiled (None without numba)
_history_record_compiled, _history_at_compiled = compiled(_history_record), compiled(_history_at)


class HistoryArray:
    """The true ball positions recorded for ``n`` simulated sensors, the newest ``columns`` per row, oldest first
    (column -1 the newest), read as :class:`~stewart_gym.sensing.BallHistory` reads them.

    Args:
        n: How many rows.
        columns: How many recorded positions a row keeps at first (:meth:`keep` makes room for more).
        kernel: ``"numba"``: recorded and read row by row in loops compiled with numba; ``"numpy"``: as arrays;
            ``"auto"`` (default): numba where it is installed. The two give the same numbers to the last bit.
    """

    def __init__(self, n: int, columns: int = 8, kernel: str = "auto") -> None:
        #: whether the rows are recorded and read by the compiled loops
        self.compiled = use_compiled(kernel, _history_at_compiled is not None)
        self.n, self.columns = int(n), int(columns)
        self.t = np.zeros((self.n, self.columns))
        self.x, self.y = np.zeros((self.n, self.columns)), np.zeros((self.n, self.columns))
        self.on = np.ones((self.n, self.columns), dtype=bool)

    def keep(self, columns: int) -> None:
        """Keep at least ``columns`` positions per row from now on (the added ones copies of each row's oldest)."""
        if columns > self.columns:
            extra = columns - self.columns
            self.t, self.x, self.y, self.on = (np.concatenate([np.repeat(a[:, :1], extra, axis=1), a], axis=1)
                                               for a in (self.t, self.x, self.y, self.on))  # fmt: skip
            self.columns = columns

    def reset_rows(self, rows: np.ndarray, before: np.ndarray, t: float, xy: np.ndarray) -> None:
        """``rows`` start over: each row's ball at rest at its ``xy`` (rows × 2, m) from its time ``before`` to ``t``
        (s), touching."""
        self.t[rows, :-1] = np.asarray(before, dtype=np.float64)[:, None]
        self.t[rows, -1] = t
        self.x[rows], self.y[rows], self.on[rows] = xy[:, :1], xy[:, 1:2], True

    def record(self, t: np.ndarray, xy: np.ndarray, on_plate: np.ndarray, rows: Any = slice(None)) -> None:
        """The true positions ``xy`` (m, rows × 2) at times ``t`` (s) of ``rows``."""
        if self.compiled:
            index = np.atleast_1d(np.arange(self.n)[rows])
            xy = np.broadcast_to(np.asarray(xy, dtype=np.float64), (len(index), 2))
            _history_record_compiled(index, np.broadcast_to(np.asarray(t, dtype=np.float64), len(index)),
                                     xy[:, 0], xy[:, 1], np.broadcast_to(np.asarray(on_plate, dtype=bool), len(index)),
                                     self.t, self.x, self.y, self.on)  # fmt: skip
            return
        for history, value in ((self.t, t), (self.x, xy[:, 0]), (self.y, xy[:, 1]), (self.on, on_plate)):
            history[rows, :-1] = history[rows, 1:]
            history[rows, -1] = value

    def at(self, index: np.ndarray, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows ``index``'s (x, y, touching) at times ``ts``: linear between the positions around it, the newest
        after it, and touching only if both neighbours were."""
        if self.compiled:
            index = np.arange(self.n)[index]  # row numbers, checked (a mask or a slice as the rows it picks)
            x, y, on = np.empty(len(index)), np.empty(len(index)), np.empty(len(index), dtype=bool)
            _history_at_compiled(index, np.broadcast_to(np.asarray(ts, dtype=np.float64), len(index)), self.t, self.x,
                                 self.y, self.on, x, y, on)  # fmt: skip
            return x, y, on
        ht, hx, hy, hon = self.t[index], self.x[index], self.y[index], self.on[index]
        last = ht.shape[1] - 1
        i = np.maximum((ht <= ts[:, None]).sum(axis=1) - 1, 0)
        j = np.minimum(i + 1, last)
        pick = np.arange(len(index))
        t0, t1 = ht[pick, i], ht[pick, j]
        inner = (i < last) & (t1 > t0)
        w = np.where(inner, (ts - t0) / np.where(inner, t1 - t0, 1.0), 0.0)
        x0, y0 = hx[pick, i], hy[pick, i]
        x = np.where(i < last, x0 + w * (hx[pick, j] - x0), x0)
        y = np.where(i < last, y0 + w * (hy[pick, j] - y0), y0)
        return x, y, hon[pick, i] & hon[pick, j]


class PanelArray:
    """``n`` simulated touch panels, each with its own spec, history, noise and generator.

    Args:
        n: How many panels.
        control_dt: s between :meth:`record` calls (sizes the history kept).
    """

    def __init__(self, n: int, control_dt: float) -> None:
        self.n, self.control_dt = int(n), float(control_dt)
        self.specs: list[TouchPanelSpec] = [TouchPanelSpec()] * self.n
        self.noise_m, self.rate, self.latency = np.full(self.n, 1e-3), np.full(self.n, 100.0), np.full(self.n, 0.01)
        self.history = HistoryArray(self.n)
        self.last_k = np.full(self.n, np.iinfo(np.int64).min)  # the sample whose noise is in noise_x, noise_y
        self.noise_x, self.noise_y = np.zeros(self.n), np.zeros(self.n)  # m
        self.draws = np.zeros((self.n, DRAW_BLOCK))
        self.left = np.zeros(self.n, dtype=np.int64)  # draws not yet used, taken from the end
        self.rngs: list[np.random.Generator | None] = [None] * self.n

    def set_spec(self, i: int, spec: TouchPanelSpec) -> None:
        """Row ``i``'s panel from now on."""
        self.set_specs(np.array([i]), [spec])

    def set_specs(self, rows: np.ndarray, specs: Sequence[TouchPanelSpec]) -> None:
        """Row ``rows[k]``'s panel is ``specs[k]`` from now on."""
        for i, spec in zip(rows.tolist(), specs):
            self.specs[i] = spec
        self.noise_m[rows] = [spec.noise_mm * 1e-3 for spec in specs]
        self.rate[rows] = [spec.rate_hz for spec in specs]
        self.latency[rows] = [spec.latency_s for spec in specs]
        self.history.keep(max((int(math.ceil((spec.latency_s + 1.0 / spec.rate_hz) / self.control_dt))
                               for spec in specs), default=0) + 3)  # fmt: skip

    def reset_rows(self, rows: np.ndarray, t: float, xy: np.ndarray, rngs: Sequence[np.random.Generator]) -> None:
        """:meth:`SimulatedTouchPanel.reset <stewart_gym.sensing.SimulatedTouchPanel.reset>` of each of ``rows``: its
        ball at ``xy`` (rows × 2, m) at time ``t``, its noise drawn from ``rngs[k]`` from now on."""
        # at rest there from before the first sample the panel can take
        self.history.reset_rows(rows, t - self.latency[rows] - 1.0 / self.rate[rows] - 1.0, t, xy)
        self.last_k[rows] = np.iinfo(np.int64).min
        self.left[rows] = 0
        for i, rng in zip(rows.tolist(), rngs):
            self.rngs[i] = rng

    def record(self, t: np.ndarray, xy: np.ndarray, on_plate: np.ndarray, rows: Any = slice(None)) -> None:
        """The true positions ``xy`` (m, rows × 2) at times ``t`` (s) of ``rows``."""
        self.history.record(t, xy, on_plate, rows)

    def read(self, t: np.ndarray, rows: Any = slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What ``rows`` report at times ``t``: (x, y) m (rows × 2), the sample times (s) and whether there is a
        reading (the ball touching at the sample time)."""
        index = np.arange(self.n)[rows]
        rate, latency = self.rate[index], self.latency[index]
        k = np.floor((t - latency) * rate + 1e-9).astype(np.int64)
        ts = k / rate
        x, y, on = self.history.at(index, ts)
        fresh = on & (k != self.last_k[index])
        for row in index[fresh & (self.left[index] < 2)]:  # a new block of draws, from the row's generator
            self.draws[row] = self.rngs[row].standard_normal(DRAW_BLOCK)
            self.left[row] = DRAW_BLOCK
        new = index[fresh]
        if len(new):
            sigma, left = self.noise_m[new], self.left[new]
            self.noise_x[new] = sigma * self.draws[new, left - 1]
            self.noise_y[new] = sigma * self.draws[new, left - 2]
            self.left[new] = left - 2
            self.last_k[new] = k[fresh]
        xy = np.stack([x + self.noise_x[index], y + self.noise_y[index]], axis=1)
        return xy, ts, on


class CameraArray:
    """``n`` simulated cameras (:class:`~stewart_gym.camera.SimulatedCamera`), each with its own spec, ball
    radius, history, draws and generator.

    Args:
        n: How many cameras.
        control_dt: s between :meth:`record` calls (sizes the history kept).
        spec: Every row's camera until :meth:`set_spec` gives it another.
        ball_radius: m, every row's ball radius until it is set (:attr:`ball_radius`).
    """

    def __init__(self, n: int, control_dt: float, spec: CameraSpec, ball_radius: float = 0.0127) -> None:
        self.n, self.control_dt = int(n), float(control_dt)
        self.specs: list[CameraSpec] = [spec] * self.n
        self.fps, self.latency, self.noise_px, self.miss_rate = (np.zeros(self.n) for _ in range(4))
        self.focal, self.camera_z, self.corrected = np.zeros(self.n), np.zeros(self.n), np.zeros(self.n, dtype=bool)
        #: m, each row's ball radius: its centre's height above the plate, and the plane the pipeline maps onto
        self.ball_radius = np.full(self.n, float(ball_radius))
        self.history = HistoryArray(self.n)
        self._take(slice(None), [spec])  # one spec: every row's
        self.last_k = np.full(self.n, np.iinfo(np.int64).min)  # the frame in self.frame
        self.frame = np.zeros((self.n, 2))
        self.found = np.zeros(self.n, dtype=bool)  # whether that frame found the ball
        self.misses, self.normals = np.zeros((self.n, FRAME_DRAWS)), np.zeros((self.n, FRAME_DRAWS, 2))
        self.drawn = np.full(self.n, FRAME_DRAWS)  # frames of the row's block of draws used
        self.rngs: list[np.random.Generator | None] = [None] * self.n

    def set_spec(self, i: int, spec: CameraSpec) -> None:
        """Row ``i``'s camera from now on."""
        self.set_specs(np.array([i]), [spec])

    def set_specs(self, rows: np.ndarray, specs: Sequence[CameraSpec]) -> None:
        """Row ``rows[k]`` sees with camera ``specs[k]`` from now on, with the history it needs."""
        for i, spec in zip(rows.tolist(), specs):
            self.specs[i] = spec
        self._take(rows, specs)

    def _take(self, rows: Any, specs: Sequence[CameraSpec]) -> None:
        """``rows`` see with ``specs``' numbers (one spec per row, or one for all) from now on, with the history
        they need."""
        self.fps[rows] = [spec.fps for spec in specs]
        self.latency[rows] = [spec.latency_s for spec in specs]
        self.noise_px[rows] = [spec.centroid_noise_px for spec in specs]
        self.miss_rate[rows] = [spec.miss_rate for spec in specs]
        self.focal[rows] = [spec.focal_px for spec in specs]
        self.camera_z[rows] = [camera_height(spec) for spec in specs]
        self.corrected[rows] = [spec.parallax_corrected for spec in specs]
        self.history.keep(max((int(math.ceil((spec.latency_s + 1.0 / spec.fps) / self.control_dt))
                               for spec in specs), default=0) + 3)  # fmt: skip

    def reset_rows(self, rows: np.ndarray, t: float, xy: np.ndarray, rngs: Sequence[np.random.Generator]) -> None:
        """:meth:`SimulatedCamera.reset <stewart_gym.camera.SimulatedCamera.reset>` of each of ``rows``: its ball at
        ``xy`` (rows × 2, m) at time ``t``, its frames' misses and noise drawn from ``rngs[k]`` from now on."""
        self.history.reset_rows(rows, t - self.latency[rows] - 2.0 / self.fps[rows] - 1.0, t, xy)
        self.last_k[rows] = np.iinfo(np.int64).min
        self.drawn[rows] = FRAME_DRAWS
        for i, rng in zip(rows.tolist(), rngs):
            self.rngs[i] = rng

    def record(self, t: np.ndarray, xy: np.ndarray, touching: np.ndarray, rows: Any = slice(None)) -> None:
        """The true positions ``xy`` (m, rows × 2) at times ``t`` (s) of ``rows``."""
        self.history.record(t, xy, touching, rows)

    def detect(self, index: np.ndarray, x: np.ndarray, y: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """(rows × 2) :meth:`SimulatedCamera.detect <stewart_gym.camera.SimulatedCamera.detect>` of rows ``index``
        for balls at plate (``x``, ``y``) with centroid noise ``noise`` (rows × 2, px)."""
        r = self.ball_radius[index]
        plane = np.where(self.corrected[index], r, 0.0)
        u, v = detection(x, y, noise[:, 0], noise[:, 1], self.focal[index], self.camera_z[index], r, plane)
        return np.stack([u, v], axis=1)

    def read(self, t: np.ndarray, rows: Any = slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What ``rows`` report at times ``t``: (x, y) m (rows × 2) of the newest frame available then, its exposure
        times (s), and whether it found the ball (else it missed it, or the ball was off the plate)."""
        index = np.arange(self.n)[rows]
        fps = self.fps[index]
        k = np.floor((t - self.latency[index]) * fps + 1e-9).astype(np.int64)
        ts = k / fps
        fresh = k != self.last_k[index]
        new = index[fresh]
        if len(new):
            for row in new[self.drawn[new] == FRAME_DRAWS]:  # a new block of draws, from the row's generator
                self.misses[row] = self.rngs[row].random(FRAME_DRAWS)
                self.normals[row] = self.rngs[row].standard_normal((FRAME_DRAWS, 2))
                self.drawn[row] = 0
            used = self.drawn[new]
            self.drawn[new] = used + 1
            x, y, on = self.history.at(new, ts[fresh])
            found = on & ~(self.misses[new, used] < self.miss_rate[new])
            self.found[new] = found
            self.frame[new] = self.detect(new, x, y, self.normals[new, used] * self.noise_px[new, None])
            self.last_k[new] = k[fresh]
        return self.frame[index], ts, self.found[index]


class SensorRow:
    """Row ``i`` of a :class:`PanelArray` or a :class:`CameraArray` as one simulated sensor
    (:class:`~stewart_gym.sensing.SimulatedSensor`)."""

    def __init__(self, sensors: PanelArray | CameraArray, i: int) -> None:
        self.sensors, self.i = sensors, int(i)

    @property
    def spec(self) -> Any:
        return self.sensors.specs[self.i]

    @spec.setter
    def spec(self, value: Any) -> None:
        self.sensors.set_spec(self.i, value)

    def reset(self, t: float, xy: Sequence[float], rng: np.random.Generator) -> None:
        self.sensors.reset_rows(np.array([self.i]), t, np.array([[float(xy[0]), float(xy[1])]]), [rng])

    def record(self, t: float, xy: Sequence[float], touching: bool) -> None:
        self.sensors.record(np.array([t]), np.array([[xy[0], xy[1]]], dtype=np.float64), np.array([touching]),
                            [self.i])  # fmt: skip

    def read(self, t: float) -> tuple[tuple[float, float], float] | None:
        xy, ts, has = self.sensors.read(np.array([t]), [self.i])
        return ((float(xy[0, 0]), float(xy[0, 1])), float(ts[0])) if has[0] else None


class PanelRow(SensorRow):
    """Row ``i`` of a :class:`PanelArray` as one :class:`~stewart_gym.sensing.SimulatedTouchPanel`."""

    sensors: PanelArray

    def __init__(self, panels: PanelArray, i: int) -> None:
        super().__init__(panels, i)


class CameraRow(SensorRow):
    """Row ``i`` of a :class:`CameraArray` as one :class:`~stewart_gym.camera.SimulatedCamera`, its ball radius
    included."""

    sensors: CameraArray

    def __init__(self, cameras: CameraArray, i: int) -> None:
        super().__init__(cameras, i)

    @property
    def ball_radius(self) -> float:
        return float(self.sensors.ball_radius[self.i])

    @ball_radius.setter
    def ball_radius(self, value: float) -> None:
        self.sensors.ball_radius[self.i] = float(value)


def _acting(when: np.ndarray, inputs: np.ndarray, count: np.ndarray, i: int,
            at: float) -> tuple[float, float]:  # fmt: skip  # pragma: no cover - compiled
    """Row ``i``'s input acting at ``at``: its last command acting by then (within 1 ns), else none."""
    for k in range(count[i] - 1, -1, -1):
        if when[i, k] <= at + 1e-9:
            return inputs[i, k, 0], inputs[i, k, 1]
    return 0.0, 0.0


def _carry(state: np.ndarray, cov: np.ndarray, with_cov: bool, i: int, h: float, ux: float, uy: float, tau: float,
           gain: float, qa: float, qb: float) -> None:  # fmt: skip  # pragma: no cover - compiled
    """Row ``i`` of :meth:`KalmanArray._advance`, the same operations in the same order (so the same bits)."""
    h = np.rint(h * 1e6) / 1e6  # np.round(h, 6)
    e = math.exp(-h / tau)
    lag = tau * (1.0 - e)
    c = tau * h - tau * lag
    half_h2 = 0.5 * h * h
    gp, gv, ga = gain * (0.5 * h * h - tau * h + tau * lag), gain * (h - lag), gain * (1.0 - e)
    px, py, vx, vy, ax, ay, bx, by = (state[i, 0], state[i, 1], state[i, 2], state[i, 3], state[i, 4], state[i, 5],
                                      state[i, 6], state[i, 7])  # fmt: skip
    state[i, 0] = px + h * vx + c * ax + half_h2 * bx + gp * ux
    state[i, 1] = py + h * vy + c * ay + half_h2 * by + gp * uy
    state[i, 2] = vx + lag * ax + h * bx + gv * ux
    state[i, 3] = vy + lag * ay + h * by + gv * uy
    state[i, 4] = e * ax + ga * ux
    state[i, 5] = e * ay + ga * uy
    if not with_cov:
        return
    q0, q1, q2 = (h * qa * h + half_h2 * qb * half_h2) * h, (h * qa + half_h2 * qb * h) * h, half_h2 * qb * h
    q3, q4, q5 = (qa + h * qb * h) * h, h * qb * h, qb * h
    pp, pv, pa, pb, vv, va, vb, aa, ab, bb = (cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3], cov[i, 4], cov[i, 5],
                                              cov[i, 6], cov[i, 7], cov[i, 8], cov[i, 9])  # fmt: skip
    m00 = pp + h * pv + c * pa + half_h2 * pb
    m01 = pv + h * vv + c * va + half_h2 * vb
    m02 = pa + h * va + c * aa + half_h2 * ab
    m03 = pb + h * vb + c * ab + half_h2 * bb
    m11, m12, m13 = vv + lag * va + h * vb, va + lag * aa + h * ab, vb + lag * ab + h * bb
    cov[i, 0] = m00 + h * m01 + c * m02 + half_h2 * m03 + q0
    cov[i, 1] = m01 + lag * m02 + h * m03 + q1
    cov[i, 2] = e * m02
    cov[i, 3] = m03 + q2
    cov[i, 4] = m11 + lag * m12 + h * m13 + q3
    cov[i, 5] = e * m12
    cov[i, 6] = m13 + q4
    cov[i, 7] = e * e * aa
    cov[i, 8] = e * ab
    cov[i, 9] = bb + q5


def _propagate_row(state: np.ndarray, cov: np.ndarray, with_cov: bool, s: int, when: np.ndarray, inputs: np.ndarray,
                   count: np.ndarray, i: int, t0: float, t1: float, tau: float, gain: float, qa: float,
                   qb: float) -> None:  # fmt: skip  # pragma: no cover - compiled
    """:meth:`KalmanArray._propagate` of row ``s`` of ``state`` (and ``cov``) in place, its commands being row ``i``
    of ``when``, ``inputs`` and ``count``: an interval per command that acts between ``t0`` and ``t1`` (in time
    order), then the rest up to ``t1``."""
    now = t0
    for j in range(count[i]):
        w = when[i, j]
        if w > t0 and w < t1:
            ux, uy = _acting(when, inputs, count, i, now)
            _carry(state, cov, with_cov, s, w - now, ux, uy, tau, gain, qa, qb)
            now = w
    h = t1 - now
    if h < 0.0:  # as np.maximum(h, 0.0): NaN stays NaN
        h = 0.0
    ux, uy = _acting(when, inputs, count, i, now)
    _carry(state, cov, with_cov, s, h, ux, uy, tau, gain, qa, qb)


def _update_rows(rows: np.ndarray, ts: np.ndarray, xy: np.ndarray, state: np.ndarray, cov: np.ndarray,
                 t: np.ndarray, r: np.ndarray, noise_t: np.ndarray, noise_x: np.ndarray, noise_y: np.ndarray,
                 noise_n: np.ndarray, noise_count: np.ndarray, variance: np.ndarray, when: np.ndarray,
                 inputs: np.ndarray, count: np.ndarray, prior_readings: float, window: float, min_variance: float,
                 tau: float, gain: float, qa: float, qb: float) -> None:  # fmt: skip  # pragma: no cover - compiled
    """:meth:`KalmanArray.update` row by row, in place, for rows ``rows`` whose readings ``xy`` (rows × 2) were
    taken at ``ts``, all later than their filters' times: the same operations in the same order as its array path
    (so the same bits), on the filters' own arrays."""
    for j in range(rows.shape[0]):
        i, at, x, y = rows[j], ts[j], xy[j, 0], xy[j, 1]
        # the reading noise (ReadingNoise.update)
        c = noise_n[i]
        prev, prev2 = noise_t[i, max(c - 1, 0)], noise_t[i, max(c - 2, 0)]
        if c >= 2 and abs((at - prev) - (prev - prev2)) > 0.25 * (at - prev):  # keep only the newest
            noise_t[i, 0], noise_x[i, 0], noise_y[i, 0] = noise_t[i, c - 1], noise_x[i, c - 1], noise_y[i, c - 1]
            c = 1
        noise_t[i, c], noise_x[i, c], noise_y[i, c] = at, x, y
        c += 1
        if c == 4:
            dx = noise_x[i, 3] - 3 * noise_x[i, 2] + 3 * noise_x[i, 1] - noise_x[i, 0]
            dy = noise_y[i, 3] - 3 * noise_y[i, 2] + 3 * noise_y[i, 1] - noise_y[i, 0]
            if math.isfinite(dx) and math.isfinite(dy):
                noise_count[i] += 1
                weight = 1.0 / (noise_count[i] + prior_readings)
                if weight < 1.0 / window:
                    weight = 1.0 / window
                variance[i] += weight * ((dx * dx + dy * dy) / 40.0 - variance[i])
            for k in range(3):
                noise_t[i, k], noise_x[i, k], noise_y[i, k] = noise_t[i, k + 1], noise_x[i, k + 1], noise_y[i, k + 1]
            c = 3
        noise_n[i] = c
        r[i] = min_variance if variance[i] < min_variance else variance[i]  # as np.maximum: NaN stays NaN
        # the filter: carried to the reading's time, then corrected by it
        _propagate_row(state, cov, True, i, when, inputs, count, i, t[i], at, tau, gain, qa, qb)
        t[i] = at
        pp, pv, pa, pb = cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3]
        s = pp + r[i]
        k0, k1, k2, k3 = pp / s, pv / s, pa / s, pb / s
        ex, ey = x - state[i, 0], y - state[i, 1]
        state[i, 0] += k0 * ex
        state[i, 1] += k0 * ey
        state[i, 2] += k1 * ex
        state[i, 3] += k1 * ey
        state[i, 4] += k2 * ex
        state[i, 5] += k2 * ey
        state[i, 6] += k3 * ex
        state[i, 7] += k3 * ey
        cov[i, 4] -= k1 * pv
        cov[i, 5] -= k1 * pa
        cov[i, 6] -= k1 * pb
        cov[i, 7] -= k2 * pa
        cov[i, 8] -= k2 * pb
        cov[i, 9] -= k3 * pb
        cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3] = pp - k0 * pp, pv - k0 * pv, pa - k0 * pa, pb - k0 * pb


def _estimate_rows(rows: np.ndarray, t: np.ndarray, state: np.ndarray, kt: np.ndarray, when: np.ndarray,
                   inputs: np.ndarray, count: np.ndarray, tau: float, gain: float, qa: float, qb: float,
                   out: np.ndarray) -> None:  # fmt: skip  # pragma: no cover - compiled
    """:meth:`KalmanArray.estimate` row by row: each row of ``rows``'s state carried from its time ``kt`` to ``t``
    (not before its time) into ``out`` (rows × 8), the filters left as they are."""
    for j in range(rows.shape[0]):
        i = rows[j]
        for k in range(8):
            out[j, k] = state[i, k]
        t1 = kt[i] if t[j] < kt[i] or kt[i] != kt[i] else t[j]  # as np.maximum: NaN from either side
        _propagate_row(out, out, False, j, when, inputs, count, i, kt[i], t1, tau, gain, qa, qb)


def _command_rows(rows: np.ndarray, t: np.ndarray, u: np.ndarray, again: np.ndarray, dead_time: float,
                  when: np.ndarray, inputs: np.ndarray, count: np.ndarray, last_issued: np.ndarray,
                  kt: np.ndarray) -> None:  # fmt: skip  # pragma: no cover - compiled
    """:meth:`KalmanArray.command` row by row, in place, its slots grown already: each row of ``rows`` takes input
    ``u`` at ``t`` (as its last command again where ``again``), then drops the commands spent before its time
    ``kt``, shifting its whole row of slots as the array path does."""
    slots = when.shape[1]
    for j in range(rows.shape[0]):
        i = rows[j]
        c = count[i]
        if again[j]:
            inputs[i, c - 1, 0], inputs[i, c - 1, 1] = u[j, 0], u[j, 1]
        else:
            last_issued[i] = t[j]
            when[i, c] = t[j] + dead_time
            inputs[i, c, 0], inputs[i, c, 1] = u[j, 0], u[j, 1]
            count[i] = c + 1
        while count[i] > 1 and when[i, 1] <= kt[i]:
            for k in range(slots - 1):
                when[i, k] = when[i, k + 1]
                inputs[i, k, 0], inputs[i, k, 1] = inputs[i, k + 1, 0], inputs[i, k + 1, 1]
            count[i] -= 1


_acting, _carry, _propagate_row = (compiled(f) or f for f in (_acting, _carry, _propagate_row))
#: :func:`_command_rows`, :func:`_update_rows` and :func:`_estimate_rows` compiled (None without numba:
#: :class:`KalmanArray` then works as arrays)
_command_compiled, _update_compiled = compiled(_command_rows), compiled(_update_rows)
_estimate_compiled = compiled(_estimate_rows)


class KalmanArray:
    """``n`` :class:`~stewart_gym.sensing.BallKalmanFilter` of one spec, with their reading-noise estimates.

    Args:
        n: How many filters.
        spec: Their spec.
        kernel: ``"numba"``: the filters command, propagate, update and estimate row by row in loops compiled
            with numba; ``"numpy"``: as arrays; ``"auto"`` (default): numba where it is installed. The two give
            the same numbers to the last bit.
    """

    def __init__(self, n: int, spec: KalmanSpec | None = None, kernel: str = "auto") -> None:
        #: whether the filters command, propagate, update and estimate row by row in compiled loops (else as arrays)
        self.compiled = use_compiled(kernel, _update_compiled is not None)
        self.spec = spec or KalmanSpec()
        c = self.spec
        if not c.noise_window:
            raise ValueError("KalmanArray estimates the readings' noise: it needs a spec with noise_window > 0")
        self.n = int(n)
        self.prior = (c.measurement_noise_mm * 1e-3) ** 2
        self.state = np.zeros((self.n, 8))  # px, py, vx, vy, ax, ay, bx, by
        self.cov = np.zeros((self.n, 10))  # the upper triangle of P, row by row
        self.t = np.zeros(self.n)
        self.r = np.full(self.n, self.prior)
        # the commands (when each acts, sin of the tilt along x, y), in time order
        self._slots = 4
        self.cmd_t = np.zeros((self.n, self._slots))
        self.cmd_u = np.zeros((self.n, self._slots, 2))
        self.cmd_n = np.zeros(self.n, dtype=np.int64)
        self.last_issued = np.full(self.n, -np.inf)
        # ReadingNoise: the last (up to 4) equally spaced readings, the estimate and its count
        self.noise_t, self.noise_x, self.noise_y = (np.zeros((self.n, 4)) for _ in range(3))
        self.noise_n = np.zeros(self.n, dtype=np.int64)
        self.variance = np.full(self.n, self.prior)
        self.noise_count = np.zeros(self.n, dtype=np.int64)
        template = ReadingNoise(c.measurement_noise_mm, c.noise_window)
        self.window, self.prior_readings = template.window, template.prior_readings
        self.qc_a, self.qc_b = c.accel_noise**2, c.bias_noise**2

    def reset_rows(self, rows: np.ndarray, t: float, xy: np.ndarray) -> None:
        """:meth:`BallKalmanFilter.reset <stewart_gym.sensing.BallKalmanFilter.reset>` of each of ``rows``: its ball
        at ``xy`` (rows × 2, m) at rest at time ``t`` (s)."""
        self.noise_n[rows], self.noise_count[rows], self.variance[rows] = 0, 0, self.prior
        self.r[rows] = self.prior
        self.state[rows] = 0.0
        self.state[rows, :2] = xy
        self.cov[rows] = (self.prior, 0.0, 0.0, 0.0, 0.1**2, 0.0, 0.0, 0.5**2, 0.0, 0.5**2)
        self.t[rows] = float(t)
        self.cmd_n[rows] = 0
        self.last_issued[rows] = -np.inf

    def command(self, rows: np.ndarray, t: np.ndarray, roll_pitch: np.ndarray) -> None:
        """:meth:`BallKalmanFilter.command <stewart_gym.sensing.BallKalmanFilter.command>` of ``rows``, issued at
        times ``t`` (s, taken as float64 whatever their type, as the filters' own times are)."""
        rows = np.arange(self.n)[rows]  # row numbers, checked (a mask or a slice as the rows it picks)
        t = np.asarray(t, dtype=np.float64)
        u = np.stack([np.sin(roll_pitch[:, 1]), -np.sin(roll_pitch[:, 0])], axis=1)
        count = self.cmd_n[rows]
        again = (count > 0) & (t <= self.last_issued[rows])
        if self.compiled:
            new = ~again
            if new.any() and int(count[new].max()) >= self._slots:
                self._grow()
            _command_compiled(rows, t, u, again,
                              self.spec.dead_time_s, self.cmd_t, self.cmd_u, self.cmd_n, self.last_issued, self.t)
            return
        if again.any():
            r = rows[again]
            self.cmd_u[r, self.cmd_n[r] - 1] = u[again]
        new = ~again
        if new.any():
            r, tn = rows[new], t[new]
            if int(self.cmd_n[r].max()) >= self._slots:
                self._grow()
            self.last_issued[r] = tn
            self.cmd_t[r, self.cmd_n[r]] = tn + self.spec.dead_time_s
            self.cmd_u[r, self.cmd_n[r]] = u[new]
            self.cmd_n[r] += 1
        while True:  # drop the commands spent before the estimate's time
            spent = rows[(self.cmd_n[rows] > 1) & (self.cmd_t[rows, 1] <= self.t[rows])]
            if not len(spent):
                break
            self.cmd_t[spent, :-1] = self.cmd_t[spent, 1:]
            self.cmd_u[spent, :-1] = self.cmd_u[spent, 1:]
            self.cmd_n[spent] -= 1

    def _grow(self) -> None:
        """More commands pending than slots: twice the slots."""
        grow = self._slots
        self.cmd_t = np.concatenate([self.cmd_t, np.zeros((self.n, grow))], axis=1)
        self.cmd_u = np.concatenate([self.cmd_u, np.zeros((self.n, grow, 2))], axis=1)
        self._slots += grow

    def _noise_update(self, rows: np.ndarray, ts: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """:meth:`ReadingNoise.update <stewart_gym.sensing.ReadingNoise.update>` of ``rows``; their variances."""
        count = self.noise_n[rows]
        pick = np.arange(len(rows))
        lt = self.noise_t[rows]
        prev, prev2 = lt[pick, np.maximum(count - 1, 0)], lt[pick, np.maximum(count - 2, 0)]
        restart = (count >= 2) & (np.abs((ts - prev) - (prev - prev2)) > 0.25 * (ts - prev))
        if restart.any():  # keep only the newest
            r = rows[restart]
            last = count[restart] - 1
            for table in (self.noise_t, self.noise_x, self.noise_y):
                table[r, 0] = table[r, last]
            count = np.where(restart, 1, count)
        self.noise_t[rows, count], self.noise_x[rows, count], self.noise_y[rows, count] = ts, xy[:, 0], xy[:, 1]
        count = count + 1
        full = count == 4
        if full.any():
            r = rows[full]
            x0, x1, x2, x3 = (self.noise_x[r, j] for j in range(4))
            y0, y1, y2, y3 = (self.noise_y[r, j] for j in range(4))
            dx, dy = x3 - 3 * x2 + 3 * x1 - x0, y3 - 3 * y2 + 3 * y1 - y0
            ok = np.isfinite(dx) & np.isfinite(dy)
            good = r[ok]
            self.noise_count[good] += 1
            weight = np.maximum(1.0 / (self.noise_count[good] + self.prior_readings), 1.0 / self.window)
            d2 = dx[ok] * dx[ok] + dy[ok] * dy[ok]
            self.variance[good] += weight * (d2 / 40.0 - self.variance[good])
            for table in (self.noise_t, self.noise_x, self.noise_y):
                table[r, :3] = table[r, 1:]
            count = np.where(full, 3, count)
        self.noise_n[rows] = count
        return self.variance[rows]

    def update(self, rows: np.ndarray, ts: np.ndarray, xy: np.ndarray) -> None:
        """:meth:`BallKalmanFilter.update <stewart_gym.sensing.BallKalmanFilter.update>` of ``rows``."""
        rows = np.arange(self.n)[rows]
        later = ts > self.t[rows]
        rows, ts, xy = rows[later], ts[later], xy.compress(later, axis=0)
        if not len(rows):
            return
        if self.compiled:
            _update_compiled(rows, np.ascontiguousarray(ts, dtype=np.float64),
                                 np.ascontiguousarray(xy, dtype=np.float64), self.state, self.cov, self.t, self.r,
                                 self.noise_t, self.noise_x, self.noise_y, self.noise_n, self.noise_count,
                                 self.variance, self.cmd_t, self.cmd_u, self.cmd_n, float(self.prior_readings),
                                 float(self.window), BallKalmanFilter.MIN_NOISE_M**2, self.spec.tilt_lag_s,
                                 self.spec.rolling_factor * GRAVITY, self.qc_a, self.qc_b)  # fmt: skip
            return
        self.r[rows] = np.maximum(self._noise_update(rows, ts, xy), BallKalmanFilter.MIN_NOISE_M**2)
        state, cov = self._propagate(rows, self.state[rows], self.cov[rows], self.t[rows], ts)
        self.t[rows] = ts
        pp, pv, pa, pb, vv, va, vb, aa, ab, bb = cov.T
        s = pp + self.r[rows]
        k0, k1, k2, k3 = pp / s, pv / s, pa / s, pb / s
        px, py, vx, vy, ax, ay, bx, by = state.T
        ex, ey = xy[:, 0] - px, xy[:, 1] - py
        self.state[rows] = np.stack([px + k0 * ex, py + k0 * ey, vx + k1 * ex, vy + k1 * ey,
                                     ax + k2 * ex, ay + k2 * ey, bx + k3 * ex, by + k3 * ey], axis=1)  # fmt: skip
        self.cov[rows] = np.stack([pp - k0 * pp, pv - k0 * pv, pa - k0 * pa, pb - k0 * pb, vv - k1 * pv, va - k1 * pa,
                                   vb - k1 * pb, aa - k2 * pa, ab - k2 * pb, bb - k3 * pb], axis=1)  # fmt: skip

    def estimate(self, rows: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted positions and velocities (rows × 2) of ``rows`` at times ``t``."""
        rows = np.arange(self.n)[rows]
        if self.compiled:
            state = np.empty((len(rows), 8))
            _estimate_compiled(rows, np.broadcast_to(np.asarray(t, dtype=np.float64), len(rows)), self.state, self.t,
                               self.cmd_t, self.cmd_u, self.cmd_n, self.spec.tilt_lag_s,
                               self.spec.rolling_factor * GRAVITY, self.qc_a, self.qc_b, state)  # fmt: skip
            return state[:, 0:2], state[:, 2:4]
        state, _ = self._propagate(rows, self.state[rows], None, self.t[rows], np.maximum(t, self.t[rows]))
        return state[:, 0:2], state[:, 2:4]

    def _propagate(self, rows: np.ndarray, state: np.ndarray, cov: np.ndarray | None, t0: np.ndarray,
                   t1: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:  # fmt: skip
        """:meth:`BallKalmanFilter._propagate <stewart_gym.sensing.BallKalmanFilter._propagate>` of ``rows``: one
        exact step per interval of constant input, the intervals' ends being the times the commands act."""
        state = state.copy()
        cov = None if cov is None else cov.copy()
        when, inputs, count = self.cmd_t[rows], self.cmd_u[rows], self.cmd_n[rows]
        valid = np.arange(self._slots)[None, :] < count[:, None]
        edges = valid & (when > t0[:, None]) & (when < t1[:, None])
        now = t0.copy()
        for j in np.flatnonzero(edges.any(axis=0)):  # a row without an edge here stays put: an interval of 0
            m = edges[:, j]
            self._advance(state, cov, np.where(m, when[:, j] - now, 0.0), self._input(when, inputs, valid, now))
            now = np.where(m, when[:, j], now)
        self._advance(state, cov, np.maximum(t1 - now, 0.0), self._input(when, inputs, valid, now))
        return state, cov

    @staticmethod
    def _input(when: np.ndarray, inputs: np.ndarray, valid: np.ndarray, at: np.ndarray) -> np.ndarray:
        """(rows × 2) the input acting at ``at``: the last command acting by then (within 1 ns), else none."""
        acting = valid & (when <= at[:, None] + 1e-9)
        last = acting.shape[1] - 1 - np.argmax(acting[:, ::-1], axis=1)
        return np.where(acting.any(axis=1)[:, None], inputs[np.arange(len(at)), last], 0.0)

    def _advance(self, state: np.ndarray, cov: np.ndarray | None, h: np.ndarray, u: np.ndarray) -> None:
        """Carry ``state`` (and ``cov``) over intervals ``h`` (s, one per row) with inputs ``u``, in place:
        :meth:`BallKalmanFilter._discrete <stewart_gym.sensing.BallKalmanFilter._discrete>`'s closed form. An
        interval of 0 leaves a row exactly as it is."""
        tau, gain = self.spec.tilt_lag_s, self.spec.rolling_factor * GRAVITY
        h = np.round(h, 6)  # the one-env filter's transitions are per µs of interval
        e = exp_each(-h / tau)  # math.exp's numbers, as the one-env filter's (np.exp's SIMD code can differ)
        lag = tau * (1.0 - e)
        c = tau * h - tau * lag
        half_h2 = 0.5 * h * h
        gp, gv, ga = gain * (0.5 * h * h - tau * h + tau * lag), gain * (h - lag), gain * (1.0 - e)
        ux, uy = u[:, 0], u[:, 1]
        px, py, vx, vy, ax, ay, bx, by = state.T
        state[:] = np.stack([px + h * vx + c * ax + half_h2 * bx + gp * ux, py + h * vy + c * ay + half_h2 * by + gp * uy,
                             vx + lag * ax + h * bx + gv * ux, vy + lag * ay + h * by + gv * uy,
                             e * ax + ga * ux, e * ay + ga * uy, bx, by], axis=1)  # fmt: skip
        if cov is None:
            return
        qa, qb = self.qc_a, self.qc_b
        q = ((h * qa * h + half_h2 * qb * half_h2) * h, (h * qa + half_h2 * qb * h) * h, half_h2 * qb * h,
             (qa + h * qb * h) * h, h * qb * h, qb * h)  # Φ Qc Φᵀ h on Φ's entries (Qc = diag(0, qa, 0, qb))
        pp, pv, pa, pb, vv, va, vb, aa, ab, bb = cov.T
        m00 = pp + h * pv + c * pa + half_h2 * pb
        m01 = pv + h * vv + c * va + half_h2 * vb
        m02 = pa + h * va + c * aa + half_h2 * ab
        m03 = pb + h * vb + c * ab + half_h2 * bb
        m11, m12, m13 = vv + lag * va + h * vb, va + lag * aa + h * ab, vb + lag * ab + h * bb
        cov[:] = np.stack([m00 + h * m01 + c * m02 + half_h2 * m03 + q[0], m01 + lag * m02 + h * m03 + q[1],
                           e * m02, m03 + q[2], m11 + lag * m12 + h * m13 + q[3], e * m12, m13 + q[4],
                           e * e * aa, e * ab, bb + q[5]], axis=1)  # fmt: skip


class ObserverArray:
    """``n`` :class:`~stewart_gym.sensing.BallObserver` of one layout and estimator (default Kalman spec).

    Args:
        n: How many.
        action_size: 2 ("tilt") or 6, as :class:`~stewart_gym.sensing.BallObserver`.
        plate_half: (h_x, h_y) m, half the plate's width and depth.
        estimator: ``"lowpass"`` or ``"kalman"``.
        integral: Append the error integral.
        velocity_cutoff_hz: The low-pass estimator's cut-off.
    """

    def __init__(self, n: int, action_size: int, plate_half: tuple[float, float] = (0.15, 0.15),
                 estimator: str = "lowpass", integral: bool = False, velocity_cutoff_hz: float = 8.0) -> None:  # fmt: skip
        template = BallObserver(action_size, velocity_cutoff_hz, plate_half, estimator, integral=integral)
        self.n, self.estimator, self.builder = int(n), estimator, template.builder
        self.plate_half = template.plate_half
        self.integral_limit, self.integral_zone = np.array(template.integral_limit), template.integral_zone
        self.invalid_readings = np.zeros(self.n, dtype=np.int64)
        self.reading = np.zeros((self.n, 2))
        self.t = np.zeros(self.n)
        self.error_integral, self.integral_t = np.zeros((self.n, 2)), np.zeros(self.n)
        self.kalman = KalmanArray(self.n) if estimator == "kalman" else None
        self.tau = 1.0 / (2 * math.pi * velocity_cutoff_hz)
        self.velocity, self.velocity_t, self.velocity_xy = np.zeros((self.n, 2)), np.zeros(self.n), np.zeros((self.n, 2))

    def reset_rows(self, rows: np.ndarray, t: float, xy: np.ndarray) -> None:
        """:meth:`BallObserver.reset <stewart_gym.sensing.BallObserver.reset>` of each of ``rows``: its ball at
        ``xy`` (rows × 2, m) at time ``t`` (s)."""
        t = float(t)
        self.velocity_t[rows], self.velocity_xy[rows], self.velocity[rows] = t, xy, 0.0
        self.reading[rows] = xy
        self.t[rows] = t
        self.error_integral[rows], self.integral_t[rows] = 0.0, t
        if self.kalman is not None:
            self.kalman.reset_rows(rows, t, xy)

    def observe(self, rows: np.ndarray, has: np.ndarray, xy: np.ndarray, ts: np.ndarray, target_xy: np.ndarray,
                target_velocity: np.ndarray, roll_pitch: np.ndarray, previous_action: np.ndarray,
                now: np.ndarray) -> np.ndarray:  # fmt: skip
        """:meth:`BallObserver.observe <stewart_gym.sensing.BallObserver.observe>` of ``rows`` (each argument with a
        row each): ``has`` says which have a reading (``xy`` taken at ``ts``); observations (rows × size), float32."""
        valid = has & readings_are_valid(xy, ts, self.plate_half)
        self.invalid_readings[rows[has & ~valid]] += 1
        got = rows[valid]
        xy_got = xy.compress(valid, axis=0)  # (compress and take: several times faster than NumPy's row indexing)
        put_rows(self.reading, got, xy_got)
        if self.kalman is None:
            dt = ts[valid] - self.velocity_t[got]
            moved = dt > 0
            r, dt = got[moved], dt[moved]
            alpha = (dt / (dt + self.tau))[:, None]
            sample = self.reading[r]
            self.velocity[r] += alpha * ((sample - self.velocity_xy[r]) / dt[:, None] - self.velocity[r])
            self.velocity_t[r], self.velocity_xy[r] = ts[valid][moved], sample
            pos, vel = self.reading[rows], self.velocity[rows]
        else:
            self.kalman.command(rows, self.t[rows], roll_pitch)
            self.kalman.update(got, np.minimum(ts[valid], now[valid]), xy_got)
            pos, vel = self.kalman.estimate(rows, now)
            self.t[rows] = now
        parts = [pos, vel, target_xy, target_velocity, roll_pitch, previous_action]
        if self.builder.integral:
            dt = np.maximum(0.0, now - self.integral_t[rows])
            self.integral_t[rows] = np.maximum(now, self.integral_t[rows])
            error = target_xy - pos
            near = (error * error).sum(axis=1) <= self.integral_zone * self.integral_zone
            r = rows[near]
            self.error_integral[r] = np.clip(self.error_integral[r] + error[near] * dt[near, None],
                                             -self.integral_limit, self.integral_limit)  # fmt: skip
            parts.append(self.error_integral[rows])
        return self.builder.build_many(np.concatenate(parts, axis=1))


class ObserverRow:
    """Row ``i`` of an :class:`ObserverArray` as one :class:`~stewart_gym.sensing.BallObserver`."""

    def __init__(self, observers: ObserverArray, i: int) -> None:
        self.observers, self.i = observers, int(i)
        self.builder: ObservationBuilder = observers.builder
        self.estimator, self.plate_half = observers.estimator, observers.plate_half

    @property
    def invalid_readings(self) -> int:
        return int(self.observers.invalid_readings[self.i])

    def reset(self, t: float, xy: Sequence[float]) -> None:
        self.observers.reset_rows(np.array([self.i]), t, np.array([[float(xy[0]), float(xy[1])]]))

    def observe(self, reading: tuple[tuple[float, float], float] | None, target_xy: Sequence[float],
                target_velocity: Sequence[float], roll_pitch: Sequence[float], previous_action: Sequence[float],
                now: float | None = None) -> np.ndarray:  # fmt: skip
        o = self.observers
        has = reading is not None
        xy, ts = (reading[0], reading[1]) if has else ((math.nan, math.nan), math.nan)
        if now is None:
            now = float(ts) if has else float(o.t[self.i])
        row = np.array([self.i])
        return o.observe(row, np.array([has]), np.array([xy], dtype=np.float64), np.array([ts], dtype=np.float64),
                         np.array([target_xy], dtype=np.float64), np.array([target_velocity], dtype=np.float64),
                         np.array([roll_pitch], dtype=np.float64), np.array([previous_action], dtype=np.float64),
                         np.array([now], dtype=np.float64))[0]  # fmt: skip
