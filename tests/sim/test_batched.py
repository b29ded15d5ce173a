"""The batched simulator (:class:`~stewart_gym.sim.batched.BatchedSim`): against PyBullet on open-loop tilt
sequences that keep the ball on the plate for 3 s, platform by platform independence, and the servo rules."""

from __future__ import annotations

import numpy as np
import pytest

from stewart_gym.calibration import PulseRangeError, ServoCalibration
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.presets import load_geometry
from stewart_gym.sim.batched import BatchedSim
from stewart_gym.sim.servo_model import ServoSpec

STEPS = 150  # 3 s at 50 Hz
START = np.array([0.03, -0.02])


def tilt_pulses(seed: int, geometry: str = "servo-hexapod") -> np.ndarray:
    """(STEPS, 6) µs: roll and pitch sinusoids of 1–3° at 0.7–1.5 Hz, ramped in over 0.5 s."""
    rng = np.random.default_rng(seed)
    amplitude, frequency, phase = np.radians(rng.uniform(1.0, 3.0, 2)), rng.uniform(0.7, 1.5, 2), rng.uniform(0, 6.3, 2)
    t = np.arange(STEPS) / 50
    poses = np.zeros((STEPS, 6))
    poses[:, 3:5] = np.minimum(t / 0.5, 1.0)[:, None] * amplitude * np.sin(2 * np.pi * frequency * t[:, None] + phase)
    geo = load_geometry(geometry)
    return ServoCalibration.default(geo).pulse_widths(inverse_kinematics(geo, poses).servo_angles)


def side_by_side(reference, batched: BatchedSim, pulses: np.ndarray, read) -> list:
    """``read(reference, batched)`` after each row of ``pulses`` (steps, 6) µs, sent to both and stepped; the
    reference simulator is closed at the end."""
    out = []
    try:
        for w in pulses:
            reference.command(w)
            reference.step()
            batched.command(w[None])
            batched.step()
            out.append(read(reference, batched))
    finally:
        reference.close()
    return out


@pytest.mark.parametrize("seed", [1, 3, 5])
def test_ball_and_plate_follow_pybullet(seed: int) -> None:
    """Ball within 1 mm RMS and the plate within 0.5 mm / 0.2° of PyBullet over 3 s (the sequences keep the ball
    on the plate there)."""
    from stewart_gym.sim.stewart_sim import StewartSim

    pulses = tilt_pulses(seed)
    reference = StewartSim("servo-hexapod", ball=True)
    reference.reset()
    reference.place_ball(START)
    batched = BatchedSim("servo-hexapod", n=1)
    batched.place_ball(START[None])
    ball_a, ball_b, pose_a, pose_b = map(np.array, zip(*side_by_side(reference, batched, pulses, lambda a, b: (
        a.ball_state()[0][:2], b.ball_state()[0][0, :2], a.platform_pose(), b.platform_pose()[0]))))
    assert np.abs(ball_a).max() < 0.15  # on the 300 mm plate throughout
    assert np.abs(ball_a - START).max() > 0.02  # and it rolled
    gap = np.linalg.norm(ball_a - ball_b, axis=1)
    assert np.sqrt(np.mean(gap**2)) < 1e-3
    assert np.abs(pose_a[:, :3] - pose_b[:, :3]).max() < 0.5e-3
    assert np.degrees(np.abs(pose_a[:, 3:] - pose_b[:, 3:]).max()) < 0.2


def test_a_tilt_step_starts_as_in_pybullet() -> None:
    """On ±6° roll steps, the largest a policy asks for at once, the plate follows PyBullet's within 0.1° RMS at
    every physics step: the servos take as long to reach full speed (their rotor inertia) as PyBullet's motors."""
    from stewart_gym.sim.stewart_sim import StewartSim

    geo = load_geometry("servo-hexapod")
    calibration = ServoCalibration.default(geo)
    rolls = np.radians([0.0] * 5 + [6.0] * 40 + [-6.0] * 60 + [0.0] * 40)
    poses = np.zeros((len(rolls), 6))
    poses[:, 3] = rolls
    pulses = calibration.pulse_widths(inverse_kinematics(geo, poses).servo_angles)
    servo = ServoSpec(deadband_us=0.0, lag_s=0.0)
    reference = StewartSim("servo-hexapod", ball=False, physics_hz=150, control_hz=150, servo_spec=servo)
    reference.reset()
    batched = BatchedSim("servo-hexapod", n=1, physics_hz=150, control_hz=150, servo_spec=servo)
    rolls = side_by_side(reference, batched, pulses, lambda a, b: (a.platform_pose()[3], b.platform_pose()[0, 3]))
    roll_a, roll_b = np.degrees(np.array(rolls)).T
    assert np.abs(roll_a).max() > 5.5  # the steps were made
    assert np.sqrt(np.mean((roll_a - roll_b) ** 2)) < 0.1


def test_platforms_are_independent() -> None:
    """Three platforms stepped together move exactly as each does alone."""
    pulses = np.stack([tilt_pulses(seed)[:40] for seed in (1, 3, 5)], axis=1)  # (40, 3, 6)
    together = BatchedSim(n=3)
    together.place_ball(np.array([[0.03, -0.02], [0.0, 0.05], [-0.04, 0.0]]))
    for w in pulses:
        together.command(w)
        together.step()
    for i, start in enumerate(([0.03, -0.02], [0.0, 0.05], [-0.04, 0.0])):
        alone = BatchedSim(n=1)
        alone.place_ball(np.array([start]))
        for w in pulses[:, i]:
            alone.command(w[None])
            alone.step()
        np.testing.assert_allclose(alone.ball_state()[0][0], together.ball_state()[0][i], atol=1e-12)
        np.testing.assert_allclose(alone.platform_pose()[0], together.platform_pose()[i], atol=1e-12)


def test_a_level_plate_keeps_a_resting_ball_still() -> None:
    sim = BatchedSim(n=2)
    sim.place_ball(np.array([[0.05, 0.05], [-0.1, 0.0]]))
    for _ in range(50):
        sim.command(np.broadcast_to(sim.calibration.neutral_us, (2, 6)))
        sim.step()
    np.testing.assert_allclose(sim.ball_state()[0][:, :2], [[0.05, 0.05], [-0.1, 0.0]], atol=1e-9)
    np.testing.assert_allclose(sim.platform_pose(), 0.0, atol=1e-9)
    assert sim.time == pytest.approx(1.0)


def test_a_pulse_out_of_range_is_refused_and_nothing_is_sent() -> None:
    sim = BatchedSim(n=2)
    bad = np.broadcast_to(sim.calibration.neutral_us, (2, 6)).copy()
    bad[1, 3] = 5000.0
    with pytest.raises(PulseRangeError, match="servo 3"):
        sim.command(bad)
    sim.step()
    np.testing.assert_array_equal(sim.held_pulses(), np.broadcast_to(sim.calibration.neutral_us, (2, 6)))


def test_each_platform_has_its_own_servos() -> None:
    """A slower servo is further from a step's target after one period; a wide dead band ignores a small step."""
    sim = BatchedSim(n=3)
    sim.reset(servo_specs=[ServoSpec(), ServoSpec(max_speed=1.0), ServoSpec(deadband_us=30.0)])
    step = np.broadcast_to(sim.calibration.neutral_us + 20.0, (3, 6))
    sim.command(step)
    sim.step()
    moved = np.abs(sim.alpha - sim.calibration.angles(np.broadcast_to(sim.calibration.neutral_us, (3, 6))))
    assert moved[1].max() < moved[0].min()
    assert moved[2].max() == 0.0 and np.array_equal(sim.held_pulses()[2], sim.calibration.neutral_us)


def test_stepping_the_servos_alone_turns_them_as_a_full_step_does() -> None:
    """``step_servos`` (the camera trims' replay) gives the servo angles of every physics step exactly as
    ``step`` leaves them, for servos of their own speed, dead band and lag."""
    specs = [ServoSpec(), ServoSpec(max_speed=3.0, deadband_us=12.0), ServoSpec(lag_s=0.03)]
    full, servos_only = BatchedSim(n=3), BatchedSim(n=3)
    for sim in (full, servos_only):
        sim.reset(servo_specs=specs)
    pulses = tilt_pulses(4)[:60]
    start, moved = full.alpha.copy(), 0.0
    for w in pulses:
        for sim in (full, servos_only):
            sim.command(np.broadcast_to(w, (3, 6)))
        full.step()
        angles = servos_only.step_servos()
        assert angles.shape == (full.substeps, 3, 6)
        np.testing.assert_array_equal(angles[-1], full.alpha)
        np.testing.assert_array_equal(servos_only.held_pulses(), full.held_pulses())
        moved = max(moved, float(np.abs(full.alpha - start).min(axis=1).max()))
    assert moved > 0.01  # the servos turned: the comparison saw motion, not three platforms at rest


def test_platforms_reset_together_as_one_by_one() -> None:
    """``reset_platforms`` of some rows (numbers or a mask) leaves each as ``reset_platform`` of it alone would, the
    others untouched; specs not one per row are refused before anything changes."""
    from stewart_gym.sim import BallSpec

    servos = [ServoSpec(max_speed=5.0 + i, lag_s=0.01 * i, trim_error_us=(float(i),) * 6) for i in range(3)]
    balls = [BallSpec(radius=0.012 + 0.001 * i, mass=0.05 + 0.01 * i) for i in range(3)]
    together, alone = BatchedSim(n=5), BatchedSim(n=5)
    pulses = together.calibration.neutral_us + np.array([30.0, -20.0, 10.0, 0.0, 5.0, -5.0])
    for sim in (together, alone):
        sim.command(np.tile(pulses, (5, 1)))
        sim.step()
    together.reset_platforms(np.array([False, True, False, True, True]), servos, balls, [None, (0.02, np.zeros(3)), None])
    for k, i in enumerate([1, 3, 4]):
        alone.reset_platform(i, servos[k], balls[k])
    alone.plate_loads[3] = (0.02, np.zeros(3))
    for sim in (together, alone):
        sim.command(np.tile(pulses, (5, 1)))
        sim.step()
    np.testing.assert_array_equal(together.alpha, alone.alpha)
    np.testing.assert_array_equal(together.ball_xy, alone.ball_xy)
    np.testing.assert_array_equal(together.platform_times(), alone.platform_times())
    assert together.servo_specs == alone.servo_specs and together.ball_specs == alone.ball_specs
    assert together.plate_loads[3][0] == 0.02 and together.plate_loads[0] is None
    before = together.alpha.copy()
    with pytest.raises(ValueError, match="2 ball_specs for 3 platforms"):
        together.reset_platforms(np.array([0, 1, 2]), servos, balls[:2])
    np.testing.assert_array_equal(together.alpha, before)
