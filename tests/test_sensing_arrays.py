"""The array sensing of the batched vector env against the one-env classes it stands for: the same readings, the
same noise, the same filters, row by row."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import replace

import numpy as np
import pytest

from stewart_gym.camera import CAMERA_PRESETS, CameraSpec, SimulatedCamera
from stewart_gym.errors import ConfigError
from stewart_gym.sensing import BallObserver, SimulatedTouchPanel, TouchPanelSpec
from stewart_gym.sensing_arrays import (
    CameraArray,
    CameraRow,
    HistoryArray,
    KalmanArray,
    ObserverArray,
    ObserverRow,
    PanelArray,
    PanelRow,
    SensorRow,
)

DT = 0.02
HALF = (0.15, 0.15)


def random_spec(rng: np.random.Generator) -> TouchPanelSpec:
    return TouchPanelSpec(noise_mm=float(rng.uniform(0.0, 3.0)), rate_hz=float(rng.choice([50.0, 100.0, 200.0])),
                          latency_s=float(rng.uniform(0.0, 0.12)))  # fmt: skip


def side_by_side(sensors: PanelArray | CameraArray, singles: list, last_row: SensorRow, steps: int,
                 restart: Callable[[], None]) -> Iterator:  # fmt: skip
    """Feed ``sensors`` (an array) and ``singles`` (one-env sensors, one per row) the same true positions, each row
    lifting now and then, row 2 restarted (``restart``) half-way; at each step, the array's readings (xy, times,
    whether there is one) and each single's. The last row read alone (``last_row``) must give its single's reading
    again."""
    n = len(singles)
    start = np.zeros(n)
    for k in range(1, steps):
        t_global = k * DT
        if k == steps // 2:
            start[2] = t_global
            restart()
        t = t_global - start
        xy = np.stack([0.1 * np.sin(t + np.arange(n)), 0.1 * np.cos(1.3 * t)], axis=1)
        touching = (k // 17 + np.arange(n)) % 5 != 0  # each row lifts now and then
        sensors.record(t, xy, touching)
        for i in range(n):
            singles[i].record(float(t[i]), xy[i], bool(touching[i]))
        got, ts, has = sensors.read(t)
        yield got, ts, has, [single.read(float(ti)) for single, ti in zip(singles, t)]
        assert last_row.read(float(t[-1])) == singles[-1].read(float(t[-1]))


def test_the_panel_rows_read_as_single_panels_through_resets_and_lifts() -> None:
    """Each row reports what a :class:`SimulatedTouchPanel` with the same spec, positions and generator reports,
    sample for sample, noise included; a row reset mid-way with a new spec (a longer latency than the history
    kept) goes on matching."""
    n, steps = 5, 240
    rng = np.random.default_rng(3)
    panels = PanelArray(n, DT)
    singles = [SimulatedTouchPanel(TouchPanelSpec()) for _ in range(n)]
    rows = [PanelRow(panels, i) for i in range(n)]

    def reset(i: int, t: float) -> None:
        spec, xy, seed = random_spec(rng), rng.uniform(-0.1, 0.1, 2), int(rng.integers(1 << 30))
        singles[i].spec = rows[i].spec = spec
        singles[i].reset(t, xy, np.random.default_rng(seed))
        rows[i].reset(t, xy, np.random.default_rng(seed))

    def restart() -> None:
        reset(2, 0.0)
        panels.set_spec(2, TouchPanelSpec(noise_mm=1.0, rate_hz=100.0, latency_s=0.9))  # needs more history
        singles[2].spec = panels.specs[2]

    for i in range(n):
        reset(i, 0.0)
    compared = touching_seen = 0
    for got, ts, on, wants in side_by_side(panels, singles, rows[-1], steps, restart):
        for i, want in enumerate(wants):
            assert on[i] == (want is not None)
            if want is not None:
                touching_seen += 1
                np.testing.assert_allclose(got[i], want[0], rtol=0, atol=1e-15)
                assert ts[i] == pytest.approx(want[1], abs=1e-15)
            compared += 1
    assert touching_seen > compared // 2


def random_camera(rng: np.random.Generator) -> CameraSpec:
    """A preset with a random latency, noise, miss rate, mount and parallax correction."""
    preset = CAMERA_PRESETS[str(rng.choice(sorted(CAMERA_PRESETS)))]
    return replace(preset, latency_s=float(rng.uniform(0.0, 0.15)), centroid_noise_px=float(rng.uniform(0.0, 2.0)),
                   miss_rate=float(rng.uniform(0.0, 0.4)), mount=str(rng.choice(["above", "below"])),
                   parallax_corrected=bool(rng.random() < 0.7))  # fmt: skip


def test_the_camera_rows_read_as_single_cameras_through_resets_and_lifts() -> None:
    """Each row reports what a :class:`SimulatedCamera` with the same spec, ball radius, positions and generator
    reports, frame for frame: the same exposure times, the same missed frames, the same noise and quantisation; a
    row reset mid-way with another camera (a longer latency than the history kept) and another ball goes on
    matching."""
    n, steps = 6, 300
    rng = np.random.default_rng(4)
    cameras = CameraArray(n, DT, CAMERA_PRESETS["pixy2"])
    singles = [SimulatedCamera(CAMERA_PRESETS["pixy2"]) for _ in range(n)]
    rows = [CameraRow(cameras, i) for i in range(n)]

    def reset(i: int, t: float, spec: CameraSpec) -> None:
        xy, seed, radius = rng.uniform(-0.1, 0.1, 2), int(rng.integers(1 << 30)), float(rng.uniform(0.008, 0.02))
        singles[i].spec = rows[i].spec = spec
        singles[i].ball_radius = rows[i].ball_radius = radius
        singles[i].reset(t, xy, np.random.default_rng(seed))
        rows[i].reset(t, xy, np.random.default_rng(seed))

    for i in range(n):
        reset(i, 0.0, random_camera(rng))
    found = missed = 0

    def restart() -> None:
        reset(2, 0.0, replace(random_camera(rng), latency_s=0.8))  # needs more history

    for got, ts, has, wants in side_by_side(cameras, singles, rows[-1], steps, restart):
        for i, want in enumerate(wants):
            assert has[i] == (want is not None)
            if want is None:
                missed += 1
            else:
                found += 1
                assert (tuple(got[i].tolist()), float(ts[i])) == want
    assert found > 0.5 * n * steps and missed > 0.1 * n * steps


@pytest.mark.parametrize("estimator", ["lowpass", "kalman"])
@pytest.mark.parametrize("integral", [False, True])
def test_the_observer_rows_observe_as_single_observers(estimator: str, integral: bool) -> None:
    """Each row's observations equal a :class:`BallObserver`'s fed the same readings (late, missing, invalid:
    NaN or off the plate), targets, tilts and actions, to float32 rounding; so do its estimates."""
    n, steps = 6, 300
    rng = np.random.default_rng(7)
    observers = ObserverArray(n, 2, HALF, estimator, integral)
    singles = [BallObserver(2, plate_half=HALF, estimator=estimator, integral=integral) for _ in range(n)]
    start = rng.uniform(-0.05, 0.05, (n, 2))
    observers.reset_rows(np.arange(n), 0.0, start)
    for i in range(n):
        singles[i].reset(0.0, start[i])
    latency = rng.uniform(0.005, 0.05, n)
    for k in range(steps):  # the first at the reset's time, as an env's reset observes
        now = np.full(n, k * DT)
        ts = np.floor((now - latency) * 100.0) / 100.0
        xy = np.stack([0.08 * np.sin(0.7 * ts + np.arange(n)), 0.08 * np.cos(0.9 * ts)], axis=1)
        xy += rng.normal(0.0, 0.001, (n, 2))
        has = rng.random(n) > 0.1
        xy[rng.random(n) < 0.03] = np.nan
        xy[rng.random(n) < 0.03] = 0.3  # off the plate: no reading
        target = np.stack([0.02 * np.sin(now), np.zeros(n)], axis=1)
        target_velocity = np.stack([0.02 * np.cos(now), np.zeros(n)], axis=1)
        tilt = rng.uniform(-0.17, 0.17, (n, 2))
        action = rng.uniform(-1, 1, (n, 2))
        got = observers.observe(np.arange(n), has, xy, ts, target, target_velocity, tilt, action, now)
        for i in range(n):
            reading = ((float(xy[i, 0]), float(xy[i, 1])), float(ts[i])) if has[i] else None
            want = singles[i].observe(reading, target[i], target_velocity[i], tilt[i], action[i], now=float(now[i]))
            np.testing.assert_allclose(got[i], want, rtol=1e-5, atol=1e-6)
    for i in range(n):
        assert observers.invalid_readings[i] == singles[i].invalid_readings > 0
        if estimator == "kalman":
            np.testing.assert_allclose(observers.kalman.state[i], singles[i].kalman.x.ravel(), rtol=1e-9, atol=1e-12)
            assert observers.kalman.variance[i] == pytest.approx(singles[i].kalman.noise.variance, rel=1e-9)
    row = ObserverRow(observers, 1)
    assert row.builder is observers.builder and row.invalid_readings == singles[1].invalid_readings


def test_a_row_observes_without_a_time_as_a_single_observer_does() -> None:
    """``now`` left out: the reading's time, or the last observation's when there is no reading."""
    observers = ObserverArray(1, 2, HALF, "kalman")
    single = BallObserver(2, plate_half=HALF, estimator="kalman")
    row = ObserverRow(observers, 0)
    row.reset(0.0, (0.01, 0.0))
    single.reset(0.0, (0.01, 0.0))
    for reading in (((0.012, 0.001), 0.02), None, ((0.015, 0.002), 0.06)):
        want = single.observe(reading, (0.0, 0.0), (0.0, 0.0), (0.01, -0.02), (0.1, 0.2))
        np.testing.assert_allclose(row.observe(reading, (0.0, 0.0), (0.0, 0.0), (0.01, -0.02), (0.1, 0.2)), want,
                                   rtol=1e-6, atol=1e-7)  # fmt: skip
    assert math.isclose(float(observers.t[0]), single.t)


def test_readings_are_judged_valid_as_one_by_one() -> None:
    """The array rule and :func:`reading_is_valid` agree: NaN, infinite, off the plate (past the margin) or not."""
    from stewart_gym.sensing import reading_is_valid, readings_are_valid

    rng = np.random.default_rng(5)
    xy = rng.uniform(-0.2, 0.2, (400, 2))
    ts = rng.uniform(0.0, 1.0, 400)
    xy[::17, 0], xy[::23, 1], ts[::29] = np.nan, np.inf, np.nan
    got = readings_are_valid(xy, ts, HALF)
    want = [reading_is_valid(((x, y), t), HALF) for (x, y), t in zip(xy.tolist(), ts.tolist())]
    assert got.tolist() == want and 0 < sum(want) < len(want)
    # at the edge, in float32 and as lists too: compared in float64, as one by one
    edge = np.float32(HALF[0] * 1.1)  # the margin rounded up to float32: past it in float64, on it in float32
    assert float(edge) > HALF[0] * 1.1
    for rows in (np.array([[edge, 0.0], [0.0, -edge]], dtype=np.float32), [[0.01, 0.02], [0.3, 0.0]]):
        want = [reading_is_valid(((float(x), float(y)), 0.5), HALF) for x, y in rows]
        assert readings_are_valid(rows, np.full(2, 0.5), HALF).tolist() == want


def test_the_kalman_filters_propagate_alike_compiled_and_as_arrays() -> None:
    """:class:`KalmanArray`'s row-by-row commands, propagation, update and estimates (compiled with numba) and its
    array ones give the same states, covariances, reading-noise estimates, pending commands and estimates to the
    last bit, through regular and irregular command times (several pending at once), regular, late and missing
    readings and rows left out of a step."""
    n = 64
    rng = np.random.default_rng(0)
    filters = KalmanArray(n), KalmanArray(n, kernel="numpy")
    assert filters[0].compiled and not filters[1].compiled
    for k in filters:
        k.reset_rows(np.arange(n), 0.0, np.stack([0.05 * np.arange(n) / n, np.full(n, -0.02)], axis=1))
    t = np.zeros(n)
    pending = 0
    for step in range(300):
        rows = np.flatnonzero(rng.random(n) < 0.9)
        if step < 100:  # steps of half the dead time: a command acts at a step's time, to rounding (the 1 ns rule)
            now = t[rows] + filters[0].spec.dead_time_s / 2
        elif step < 150:  # steps of the dead time: a command acts exactly at the next step's time
            now = t[rows] + filters[0].spec.dead_time_s
        else:
            now = t[rows] + 0.02 * rng.uniform(0.3, 1.7, len(rows))
        tilt = rng.uniform(-0.1, 0.1, (len(rows), 2))
        has = rng.random(len(rows)) < 0.8
        got = rows[has]
        ts = now[has] - (rng.uniform(0.0, 0.03, len(got)) if step % 100 >= 60 else 0.0)  # regular, then jittered
        xy = rng.normal(0.0, 0.01, (len(got), 2))
        estimates = []
        for k in filters:
            k.command(rows, t[rows].copy(), tilt)
            k.update(got, ts, xy)
            estimates.append(k.estimate(rows, now))
        pending = max(pending, int(filters[0].cmd_n.max()))
        t[rows] = now
        for a, b in zip(*estimates):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(filters[0].cmd_n, filters[1].cmd_n)  # the same commands pending
    for name in ("state", "cov", "t", "r", "variance", "noise_count", "noise_n", "noise_t", "noise_x", "noise_y",
                 "cmd_t", "cmd_u", "cmd_n", "last_issued"):
        np.testing.assert_array_equal(getattr(filters[0], name), getattr(filters[1], name), err_msg=name)
    assert filters[0].noise_count.min() > 0  # every row's noise estimate took whole windows of readings
    mask = np.arange(n) % 4 == 1  # rows as a mask: the rows it picks, on both paths
    for a, b in zip(filters[0].estimate(mask, t[mask] + 0.01), filters[1].estimate(mask, t[mask] + 0.01)):
        assert len(a) == mask.sum()
        np.testing.assert_array_equal(a, b)
    assert pending >= 2 and np.abs(filters[0].state[:, 2:4]).max() > 0.01  # commands overlapped; the balls moved
    with pytest.raises(ConfigError, match="kernel: one of auto, numba, numpy, got 'fast'"):
        KalmanArray(2, kernel="fast")
    assert KalmanArray(2, kernel="numba").compiled


def test_kalman_commands_take_their_times_as_float64_on_both_paths() -> None:
    """Command times given as float32 are taken as float64, on the compiled path and the array path alike: the
    dead time is added in float64, as to the filters' own times."""
    for kernel in ("numba", "numpy"):
        single, double = KalmanArray(3, kernel=kernel), KalmanArray(3, kernel=kernel)
        times = np.array([0.01, 0.02, 0.1], dtype=np.float32)
        tilt = np.full((3, 2), 0.05)
        single.command(slice(None), times, tilt)
        double.command(slice(None), times.astype(np.float64), tilt)
        np.testing.assert_array_equal(single.cmd_t, double.cmd_t, err_msg=kernel)
        np.testing.assert_array_equal(single.last_issued, double.last_issued, err_msg=kernel)
        dead_time = single.spec.dead_time_s
        assert single.cmd_t.dtype == np.float64 and single.cmd_t[0, 0] == np.float64(np.float32(0.01)) + dead_time


def test_the_histories_record_and_read_alike_compiled_and_as_arrays() -> None:
    """:class:`HistoryArray`'s compiled loops and its array path keep the same histories and read the same positions
    to the last bit: between two records, at one, before the oldest, after the newest, at a repeated time (a
    reset's), at NaN, with lifts, for some rows at a time."""
    n = 40
    rng = np.random.default_rng(7)
    histories = HistoryArray(n), HistoryArray(n, kernel="numpy")
    assert histories[0].compiled and not histories[1].compiled
    for h in histories:
        h.keep(11)
        h.reset_rows(np.arange(n), np.full(n, -1.3), 0.0, np.stack([0.01 * np.arange(n), np.full(n, -0.02)], axis=1))
    t = np.zeros(n)
    for _ in range(200):
        rows = np.flatnonzero(rng.random(n) < 0.8)
        t[rows] += rng.choice([0.0, 0.004, 0.02], len(rows))  # a repeated time now and then
        xy = rng.normal(0.0, 0.05, (len(rows), 2))
        xy[::7] = -0.0  # a signed zero: the weight-0 sum must keep its sign as the arrays do
        on = rng.random(len(rows)) < 0.9
        ts = t[rows] - rng.choice([0.0, 0.003, 0.05, 2.0, -0.01, math.nan], len(rows))
        for h in histories:
            h.record(t[rows].copy(), xy, on, rows)
        got, want = histories[0].at(rows, ts), histories[1].at(rows, ts)
        for a, b in zip(got, want):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
            assert np.array_equal(np.signbit(a), np.signbit(b))
    for name in ("t", "x", "y", "on"):
        np.testing.assert_array_equal(getattr(histories[0], name), getattr(histories[1], name))
    mask = np.arange(n) % 3 == 0  # recorded through a mask, one time and lift for all: both paths alike
    for h in histories:
        h.record(float(t.max()) + 0.01, np.tile([0.01, 0.02], (int(mask.sum()), 1)), True, mask)
    when = np.full(int(mask.sum()), t.max())
    for a, b in zip(histories[0].at(np.flatnonzero(mask), when), histories[1].at(np.flatnonzero(mask), when)):
        np.testing.assert_array_equal(a, b)
    for h in histories:
        with pytest.raises(IndexError):
            h.at(np.array([n]), np.zeros(1))  # a row it does not have
    with pytest.raises(ConfigError, match="kernel"):
        HistoryArray(2, kernel="jit")

