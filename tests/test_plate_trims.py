"""Each servo's trim from the plate poses a camera logged (stewart_gym.plate_trims), on logs whose truth is known."""

from __future__ import annotations

import csv
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stewart_gym.actions import ActionMapper
from stewart_gym.calibration import ServoCalibration
from stewart_gym.errors import ConfigError
from stewart_gym.hardware.deploy import LOG_PLATE_COLUMNS, LOG_READING_COLUMNS
from stewart_gym.hardware.identify import PLATE_MOVES, PLATE_RAMP_S, Excitation
from stewart_gym.plate_trims import MIN_FRAMES, PlateLog, fit_trims, rotation_from_vector
from stewart_gym.presets import load_geometry
from stewart_gym.sim import BatchedSim, ServoSpec
from stewart_gym.sysid import read_log
from tests.hardware.test_identify import Still

GEOMETRY = load_geometry("servo-hexapod")
CALIBRATION = ServoCalibration.default(GEOMETRY)
PLATE_TOP = 0.005
SERVO = replace(ServoSpec(), max_speed=ServoSpec().max_speed * 0.7, deadband_us=8.0)


def plate_log(trims: np.ndarray, seconds: float, seed: int, lag_s: float = 0.04, noise_m: float = 1e-4,
              moves: bool = True, servo: ServoSpec = SERVO, jitter_s: float = 0.0,
              lift_m: float = 0.0, irregular: bool = False) -> PlateLog:  # fmt: skip
    """What identify --sensor camera logs on a platform with these trims and ``servo``, in simulated time:
    pulses toward poses held 0.1–0.5 s (tilts within ±6°; with ``moves`` heights within ±5 mm and yaws within
    ±4°), and at every tick a frame of the plate's pose as a camera sees it: tilted 3° off the vertical, 0.5 m
    above the plate, with ``noise_m`` of noise on the marker plane's position (and its equivalent in rotation),
    its time off by up to ``jitter_s`` either way (uniform); the markers ``lift_m`` above the plate's top. With
    ``irregular`` the ticks come 10, 20 or 30 ms apart (a loaded machine's: 20 ms is the median)."""
    rng = np.random.default_rng(seed)
    sim = BatchedSim(GEOMETRY, n=1, calibration=CALIBRATION, plate_top=PLATE_TOP,
                     **({"physics_hz": 200, "control_hz": 200} if irregular else {}))  # fmt: skip
    sim.reset(servo_specs=[replace(servo, lag_s=lag_s, trim_error_us=tuple(trims))])
    camera = Rotation.from_euler("xyz", [math.pi + 0.05, -0.03, 0.4]).as_matrix()
    shift = np.array([0.01, -0.02, 0.5]) - camera @ (GEOMETRY.home_position + [0.0, 0.0, PLATE_TOP])
    mapper = ActionMapper(GEOMETRY, CALIBRATION, "pose")
    t, pulses, frames = [], [], []
    hold, target = 0, None
    while sim.time < seconds:
        if hold <= 0:
            pose = np.zeros(6)
            pose[3:5] = rng.uniform(-0.1, 0.1, 2)
            if moves:
                pose[2], pose[5] = rng.uniform(-0.005, 0.005), rng.uniform(-0.07, 0.07)
            target = mapper.reachable_pose(pose)[1]
            hold = int(rng.integers(5, 25))
        hold -= 1
        t.append(sim.time)
        pulses.append(target)
        for _ in range(int(rng.choice([2, 4, 6], p=[0.25, 0.5, 0.25])) if irregular else 1):
            sim.command(target[None])
            sim.step()
        p = sim.platform_pose()[0]
        rot = Rotation.from_euler("xyz", p[3:6]).as_matrix()
        seen = camera @ rot
        origin = camera @ (rot @ [0.0, 0.0, PLATE_TOP + lift_m] + GEOMETRY.home_position + p[:3]) + shift
        turn = Rotation.from_matrix(seen).as_rotvec() + rng.normal(0.0, noise_m / 0.1, 3)
        frames.append([*turn, *(origin + rng.normal(0.0, noise_m, 3)), sim.time + rng.uniform(-jitter_s, jitter_s)])
    f = np.array(frames)
    return PlateLog(np.array(t), np.array(pulses), f[:, 6], f[:, :6])


def test_rotation_vectors_match_scipy() -> None:
    v = np.random.default_rng(0).normal(0.0, 1.5, (50, 3))
    v[0] = 0.0
    np.testing.assert_allclose(rotation_from_vector(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-12)


@pytest.mark.parametrize("seed", [1, 2])
def test_the_trims_come_back_within_three_microseconds(seed: int) -> None:
    """30 s of a synthetic camera log with the plate moving in height and yaw: each trim within ±3 µs (trims up
    to ±40 µs, an unknown camera pose, 0.1 mm of noise), the delay within a tick of the servos' lag, and the
    stated uncertainties cover the errors."""
    trims = np.random.default_rng(seed).uniform(-40.0, 40.0, 6)
    log = plate_log(trims, 30.0, seed)
    fit = fit_trims(GEOMETRY, CALIBRATION, [log], SERVO, 0.0, PLATE_TOP)
    err = fit.trims_us - trims
    assert np.all(np.abs(err) <= 3.0), (fit.trims_us, trims)
    assert abs(fit.delay_s - 0.04) <= 0.02
    assert np.all(np.abs(err) <= 4.0 * fit.sigma_us + 0.5), (err, fit.sigma_us)
    assert fit.frames >= 29 * 50


def test_without_height_and_yaw_moves_the_trims_are_less_well_determined() -> None:
    """Tilts alone leave the trims more mixed up with the camera's pose: the fit says so through its
    uncertainties, which are larger than on a log of the same length with the moves."""
    trims = np.array([25.0, -20.0, 10.0, -30.0, 5.0, 15.0])
    still = fit_trims(GEOMETRY, CALIBRATION, [plate_log(trims, 20.0, 3, moves=False)], SERVO, 0.04, PLATE_TOP)
    moving = fit_trims(GEOMETRY, CALIBRATION, [plate_log(trims, 20.0, 3)], SERVO, 0.04, PLATE_TOP)
    assert np.median(still.sigma_us) > 1.3 * np.median(moving.sigma_us), (still.sigma_us, moving.sigma_us)


def test_the_replay_keeps_the_candidate_servo_the_plate_poses_fit_best() -> None:
    """Given candidates with the true servo neither first nor last, the fit replays with the true one (the
    plate poses tell a servo 30 % too fast or slow, or with a dead band 6 µs off, from the truth), and the trims
    come back within ±4 µs from 12 s of frames."""
    trims = np.array([-20.0, 15.0, 30.0, -5.0, 0.0, -25.0])
    log = plate_log(trims, 12.0, 6)
    fast = replace(SERVO, max_speed=SERVO.max_speed * 1.3)
    wide = replace(SERVO, deadband_us=SERVO.deadband_us + 6.0)
    slow = replace(SERVO, max_speed=SERVO.max_speed / 1.3)
    fit = fit_trims(GEOMETRY, CALIBRATION, [log], [fast, wide, SERVO, slow], 0.04, PLATE_TOP)
    assert fit.servo == SERVO
    assert np.all(np.abs(fit.trims_us - trims) <= 4.0), (fit.trims_us, trims)


def test_the_frames_timing_scatter_is_measured_and_weighed() -> None:
    """Frame times off by up to ±8 ms (uniform: 4.6 ms RMS): the fit finds a timing scatter within a millisecond
    of that, where exact times give under a millisecond, and the trims still come back within ±3 µs."""
    trims = np.array([10.0, -30.0, 5.0, 20.0, -15.0, 25.0])
    exact = fit_trims(GEOMETRY, CALIBRATION, [plate_log(trims, 12.0, 7)], SERVO, 0.04, PLATE_TOP)
    late = fit_trims(GEOMETRY, CALIBRATION, [plate_log(trims, 12.0, 7, jitter_s=0.008)], SERVO, 0.04, PLATE_TOP)
    assert exact.timing_s < 0.001 and abs(late.timing_s - 0.008 / math.sqrt(3)) < 0.001, (exact.timing_s,
                                                                                          late.timing_s)  # fmt: skip
    assert np.all(np.abs(late.trims_us - trims) <= 3.0), (late.trims_us, trims)


def test_ticks_that_come_early_or_late_are_replayed_when_they_came() -> None:
    """Ticks 10, 20 or 30 ms apart: each tick's pulses act from its own time, so the trims come back within ±5 µs
    and within their stated uncertainty (replayed as if every tick held 20 ms, they were up to 16 µs off, at 9
    sigma), and the plate poses fit to about the camera's noise."""
    trims = np.array([10.0, -30.0, 5.0, 20.0, -15.0, 25.0])
    fit = fit_trims(GEOMETRY, CALIBRATION, [plate_log(trims, 12.0, 7, irregular=True)], SERVO, 0.04, PLATE_TOP)
    err = fit.trims_us - trims
    assert np.all(np.abs(err) <= 5.0), (fit.trims_us, trims)
    assert np.all(np.abs(err) <= 3.0 * fit.sigma_us + 1.0) and np.all(fit.sigma_us > 0.05), (err, fit.sigma_us)
    assert fit.rms_m < 2e-4, fit.rms_m


def test_markers_above_the_plates_top_are_allowed_for() -> None:
    """Markers 3 mm above the plate's top (tiles cut from acrylic), the fit told so: the trims come back within
    ±3 µs."""
    trims = np.array([-15.0, 25.0, -5.0, 10.0, 30.0, -20.0])
    log = plate_log(trims, 20.0, 8, lift_m=0.003)
    fit = fit_trims(GEOMETRY, CALIBRATION, [log], SERVO, 0.04, PLATE_TOP + 0.003)
    assert np.all(np.abs(fit.trims_us - trims) <= 3.0), (fit.trims_us, trims)


def test_too_few_frames_is_refused() -> None:
    log = plate_log(np.zeros(6), 3.0, 4)
    with pytest.raises(ConfigError, match=f"need {MIN_FRAMES} or more"):
        fit_trims(GEOMETRY, CALIBRATION, [log], SERVO, 0.04, PLATE_TOP)


def test_read_log_keeps_each_camera_frame_once(tmp_path) -> None:
    """A frame read at several ticks is one frame; ticks without a plate pose add none; a log without the plate
    columns has no plate part."""
    header = ["t_s", *(f"pulse{i}_us" for i in range(6)), "stale", *LOG_READING_COLUMNS]
    rows = []
    for k in range(400):
        t = k / 50
        frame = k // 2  # a 25 fps camera: each frame at two ticks
        pose = ["", "", "", "", "", "", ""] if frame % 10 == 9 else [3.1, 0.01 * math.sin(frame), 0.0, 0.001, 0.002,
                                                                      0.5 + 1e-4 * frame, frame / 25 + 1e-5 * k]
        rows.append([t, *([1500.0] * 6), 0, 0.01, 0.0, t - 0.03, *pose])
    with_plate, without = tmp_path / "camera.csv", tmp_path / "panel.csv"
    for path, cols, cut in ((with_plate, [*header, *LOG_PLATE_COLUMNS], None), (without, header, len(header))):
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(cols)
            writer.writerows(r[:cut] for r in rows)
    log = read_log(with_plate)
    assert log.plate is not None and len(log.plate.frame_t) == 200 - 20
    assert np.all(np.diff(log.plate.frame_t) > 0)
    assert read_log(without).plate is None


def test_the_excitation_moves_the_plate_within_reach() -> None:
    """With a mapper to move, the excitation sets its pose offset to heights and yaws within the stated fractions
    of the reach, changes them every 1–2 s, and keeps every tilt it sends within reach at the offset of the
    moment. Half its tilt levels are triplets: large tilts (60 % of the reach or more) whose parts cancel."""

    class Push:
        action_mode, geometry, max_tilt = "tilt", GEOMETRY, None

        def __call__(self, obs):
            return np.array([0.9, -0.9])

        def reset(self):
            pass

    mapper = ActionMapper(GEOMETRY, CALIBRATION, "tilt")
    scale = ActionMapper(GEOMETRY, CALIBRATION, "pose").pose_scale
    ex = Excitation(Push(), amplitude=0.6, seed=5)
    ex.move_plate(mapper)
    offsets = []
    for _ in range(500):
        action = ex(np.zeros(12))
        offsets.append(mapper.offset)
        assert not mapper(action).scaled
    o = np.array(offsets)
    lift, turn = PLATE_MOVES["z"] * scale[2], PLATE_MOVES["yaw"] * scale[5]
    assert np.all(np.abs(o[:, 2]) <= lift + 1e-12) and np.all(np.abs(o[:, 5]) <= turn + 1e-12)
    assert np.ptp(o[:, 2]) > 0.8 * lift and np.ptp(o[:, 5]) > 0.8 * turn
    # from one level to the next along a half cosine over PLATE_RAMP_S (no step: the ball would hop and slip),
    # then held; a move starts every 1–2 s at 50 Hz
    ramp = int(round(PLATE_RAMP_S * 50))
    step = np.abs(np.diff(o[:, [2, 5]], axis=0))
    assert np.all(step <= np.pi / 2 * 2 * np.array([lift, turn]) / ramp + 1e-12)
    moving = np.r_[True, np.any(step > 0, axis=1)]  # the first tick moves from home
    starts = np.flatnonzero(moving & ~np.r_[False, moving[:-1]])
    ends = np.flatnonzero(moving & ~np.r_[moving[1:], False])
    assert np.all(ends - starts + 1 <= ramp) and np.max(ends - starts + 1) >= ramp - 1
    assert 4 <= len(starts) <= 11 and np.min(np.diff(starts)) >= 49
    assert np.all(o[:, [0, 1, 3, 4]] == 0.0)
    still = Excitation(Still(), seed=6)
    still.move_plate(mapper)
    tilts = np.array([still(np.zeros(12)) for _ in range(50 * 60)])
    size = np.hypot(tilts[:, 0], tilts[:, 1])
    large = size >= 0.6 * min(still.max_tilt_action, 1.0) - 1e-9
    assert 0.3 < large.mean() < 0.9 and np.all(size <= still.max_tilt_action + 1e-9)
    assert np.all(np.abs(tilts[large].mean(axis=0)) < 0.01)  # the triplets' parts cancel
    pose_mapper = ActionMapper(GEOMETRY, CALIBRATION, "pose")
    with pytest.raises(ConfigError, match="'tilt' mode"):
        Excitation(Push()).move_plate(pose_mapper)
