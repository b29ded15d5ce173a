"""Property tests (hypothesis) over each preset's workspace."""

from __future__ import annotations

import math

import numpy as np
from conftest import WORKSPACE_BOX, mirror_permutation
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from stewart_gym.calibration import ServoCalibration, servo_pulses_one
from stewart_gym.kinematics import (
    forward_kinematics,
    inverse_kinematics,
    pulses_many,
    pulses_one,
    rotation_matrix,
)
from stewart_gym.presets import load_preset, preset_names

unit = st.floats(-1.0, 1.0, allow_nan=False)
poses_unit = st.tuples(*[unit] * 6).map(np.array)
GEOMETRIES = {name: load_preset(name) for name in preset_names()}
ROTARY = [n for n, g in GEOMETRIES.items() if g.is_rotary]


def _pose(name: str, u: np.ndarray) -> np.ndarray:
    t, a = WORKSPACE_BOX[name]
    return u * np.array([t, t, t, a, a, a])


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(sorted(GEOMETRIES)), u=poses_unit)
def test_ik_fk_round_trip(name: str, u: np.ndarray) -> None:
    geo = GEOMETRIES[name]
    pose = _pose(name, u)
    ik = inverse_kinematics(geo, pose)
    assume(bool(ik.reachable))
    if geo.is_rotary:
        fk = forward_kinematics(geo, servo_angles=ik.servo_angles)
    else:
        fk = forward_kinematics(geo, leg_lengths=ik.leg_lengths)
    assert bool(fk.converged)
    assert np.abs(fk.pose - pose).max() <= 1e-9


@settings(max_examples=200, deadline=None)
@given(angles=st.tuples(*[st.floats(-10.0, 10.0, allow_nan=False)] * 3))
def test_rotation_is_orthonormal(angles: tuple[float, float, float]) -> None:
    r = rotation_matrix(*angles)
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-14)
    assert math.isclose(np.linalg.det(r), 1.0, abs_tol=1e-14)


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(ROTARY), u=st.tuples(*[unit] * 6).map(np.array),
       trims=st.tuples(*[st.floats(-40, 40)] * 6).map(np.array))  # fmt: skip
def test_pulse_angle_pulse_identity(name: str, u: np.ndarray, trims: np.ndarray) -> None:
    cal = ServoCalibration.default(GEOMETRIES[name], trims_us=trims)
    pulses = cal.min_us + (u + 1) / 2 * (cal.max_us - cal.min_us)
    assert np.allclose(cal.pulse_widths(cal.angles(pulses)), pulses, rtol=0, atol=1e-9)


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(sorted(GEOMETRIES)), u=poses_unit)
def test_mirrored_servo_pairs(name: str, u: np.ndarray) -> None:
    """Mirroring a pose in the y-z plane swaps mirrored legs; their pulse offsets flip sign."""
    geo = GEOMETRIES[name]
    perm = mirror_permutation(geo)
    pose = _pose(name, u)
    mirrored = pose * np.array([-1, 1, 1, 1, -1, -1])  # x, pitch and yaw change sign
    a, b = inverse_kinematics(geo, pose), inverse_kinematics(geo, mirrored)
    assert np.allclose(a.leg_lengths, b.leg_lengths[perm], atol=1e-14)
    assert bool(a.reachable) == bool(b.reachable)
    if geo.is_rotary:
        assert np.allclose(a.servo_angles, b.servo_angles[perm], atol=1e-12, equal_nan=True)
        assume(bool(a.reachable))
        cal = ServoCalibration.default(geo)
        assert np.all(cal.direction == -cal.direction[perm])  # mirrored pairs turn opposite ways
        wa, wb = cal.pulse_widths(a.servo_angles), cal.pulse_widths(b.servo_angles)
        assert np.allclose(wa - cal.neutral_us, -(wb - cal.neutral_us)[perm], atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(name=st.sampled_from(ROTARY), u=poses_unit, scale=st.sampled_from([0.5, 1.0, 3.0]))
def test_scalar_one_pose_path_equals_batched_ik(name: str, u: np.ndarray, scale: float) -> None:
    """The scalar one-pose IK and servo_pulses_one (the control-loop path) agree with the batched IK and calibration."""
    geo = GEOMETRIES[name]
    pose = _pose(name, u) * scale  # scale 3 reaches far out of the workspace
    cal = ServoCalibration.default(geo)
    one = inverse_kinematics(geo, pose)  # a single pose takes the scalar path
    batch = inverse_kinematics(geo, pose[None])
    ok = bool(one.reachable)
    assert ok == bool(batch.reachable[0])
    assert np.array_equal(one.status, batch.status[0])
    assert np.allclose(one.servo_angles, batch.servo_angles[0], rtol=0, atol=1e-12, equal_nan=True)
    pulses = servo_pulses_one(geo, cal, pose.tolist())
    reference = cal.pulse_widths(batch.servo_angles[0], out_of_range="nan")
    if np.isnan(reference).any() or not ok:
        assert pulses is None
    else:
        assert pulses is not None and np.allclose(pulses, reference, rtol=0, atol=1e-9)
        assert np.allclose(cal.angles_one(pulses), cal.angles(reference), rtol=0, atol=1e-12)
    assert cal.in_range_one(reference.tolist()) == bool(cal.in_range(reference).all())


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(sorted(GEOMETRIES)), us=st.lists(poses_unit, min_size=1, max_size=8),
       scale=st.sampled_from([0.5, 1.0, 3.0]), yaw_zero=st.booleans(),
       bad=st.sampled_from([None, math.nan, math.inf, -math.inf, 1e200]))  # fmt: skip
def test_compiled_pulses_of_many_poses_are_the_scalar_paths_to_the_last_bit(
        name: str, us: list, scale: float, yaw_zero: bool, bad: float | None) -> None:  # fmt: skip
    """pulses_many (the compiled pass the vector env maps its actions with) gives, pose by pose, what pulses_one
    gives: the same pulses to the last bit, and no pulses where it gives None (rotary and linear, a tilt's yaw of
    ±0, non-finite and absurd poses)."""
    geo = GEOMETRIES[name]
    poses = np.array([_pose(name, u) * scale for u in us])
    if yaw_zero:
        poses[:, 5] = np.where(np.arange(len(poses)) % 2, 0.0, -0.0)
    if bad is not None:
        poses[0, len(us) % 6] = bad
    cal = ServoCalibration.default(geo)
    pulses, ok = pulses_many(geo, poses, cal.pulse_map)
    for pose, row, good in zip(poses, pulses, ok):
        one = pulses_one(geo, pose.tolist(), cal.pulse_map)
        assert good == (one is not None)
        if good:
            assert row.tolist() == one


# ------------------------------------------------------- non-finite poses
bad_value = st.sampled_from([math.nan, math.inf, -math.inf, 1e200, -1e300])


@settings(max_examples=200, deadline=None)
@given(name=st.sampled_from(sorted(GEOMETRIES)), u=poses_unit, axis=st.integers(0, 5), value=bad_value)
def test_a_non_finite_or_absurd_pose_is_never_reachable(name: str, u: np.ndarray, axis: int, value: float) -> None:
    """NaN, ±inf or an absurd translation in any component: unreachable in the batched and the scalar IK,
    rotary and linear, and no pulses for it."""
    geo = GEOMETRIES[name]
    pose = _pose(name, u)
    if axis >= 3 and abs(value) != math.inf and not math.isnan(value):
        value = math.nan  # a huge finite angle is a valid angle; test NaN there instead
    pose[axis] = value
    batched = inverse_kinematics(geo, pose[None])
    single = inverse_kinematics(geo, pose)
    assert not batched.reachable[0] and not single.reachable
    assert np.array_equal(batched.status[0] != 0, single.status != 0)
    if geo.is_rotary:
        assert servo_pulses_one(geo, ServoCalibration.default(geo), pose.tolist()) is None
        assert np.isnan(batched.servo_angles[0]).any()


def test_linear_legs_through_the_base_are_unreachable() -> None:
    """The mirror image of a pose through the base plane has the same leg lengths but cannot be built."""
    from stewart_gym.kinematics import LegStatus

    geo = GEOMETRIES["senilov2018"]
    below = np.array([0.0, 0.0, -2 * geo.home_height, 0, 0, 0])  # the platform at −h0: mirrored through z = 0
    for ik in (inverse_kinematics(geo, below), inverse_kinematics(geo, below[None])):
        assert not np.any(ik.reachable)
        assert np.all(ik.status == LegStatus.BELOW_BASE)
