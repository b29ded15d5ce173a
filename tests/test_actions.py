"""Actions → pose → pulses: every mode within the limits, unreachable poses scaled back on the ray."""


from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stewart_gym.actions import ActionMapper
from stewart_gym.kinematics import inverse_kinematics


@pytest.mark.parametrize("mode", ["tilt", "pose", "pulse"])
def test_extreme_actions_are_commanded_within_limits(mode: str) -> None:
    """Actions at and beyond ±1 (where float rounding can land a pulse a hair outside a limit) never raise."""
    env = gym.make("StewartBallBalance-v0", action_mode=mode)
    env.reset(seed=0)
    cal = env.unwrapped.sim.calibration
    n = env.action_space.shape[0]
    for a in (np.ones(n), -np.ones(n), np.full(n, 7.0), np.full(n, -7.0), np.r_[1.0, -1.0, np.ones(n - 2)]):
        _, _, _, _, info = env.step(a.astype(np.float32))
        assert cal.in_range(info["pulse_widths_us"]).all()
    env.close()


def test_unreachable_pose_goes_to_the_nearest_reachable_on_the_ray() -> None:
    mapper = ActionMapper(mode="pose")
    action = np.ones(6)
    mapped = mapper(action)
    commanded = mapper.pose(action)
    assert mapped.scaled and 0.0 < mapped.scale < 1.0
    assert mapped.pose == pytest.approx(mapped.scale * commanded)
    geo = mapper.geometry
    assert inverse_kinematics(geo, mapped.pose).reachable
    assert not inverse_kinematics(geo, (mapped.scale + 1 / 2048) * commanded).reachable  # nearest, to 1/4096
    assert np.all(mapper.calibration.in_range(mapped.pulses))
    tilt = ActionMapper(mode="tilt")(np.array([0.5, -0.5]))
    assert not tilt.scaled and tilt.pose[3] == pytest.approx(math.radians(5))
    pulse = ActionMapper(mode="pulse")
    assert pulse(np.full(6, 1.0)).pulses == pytest.approx(pulse.calibration.max_us)
    with pytest.raises(ValueError, match="finite"):
        pulse(np.array([0, 0, np.nan, 0, 0, 0]))


def test_a_repeated_unreachable_pose_is_answered_alike_without_a_second_search(monkeypatch) -> None:
    """A saturated diagonal tilt (the corner is out of reach) searches its ray once; sent again, it gets the
    same pose, pulses and scale as the first time and as a fresh mapper's search, with one IK pass (the direct
    try), and changing an answer's arrays does not change the next one."""
    import stewart_gym.actions as actions

    passes: list[int] = []
    ik = actions.servo_pulses_one
    monkeypatch.setattr(actions, "servo_pulses_one", lambda *args: passes.append(1) or ik(*args))
    mapper, corner = ActionMapper(mode="tilt"), np.array([1.0, 1.0])
    first = mapper(corner)
    searched = len(passes)
    again = mapper(corner)
    assert first.scaled and 0.5 < first.scale < 1.0 and searched > 20 and len(passes) == searched + 1
    fresh = ActionMapper(mode="tilt")(corner)
    for other in (again, fresh):
        assert np.array_equal(other.pose, first.pose) and np.array_equal(other.pulses, first.pulses)
        assert other.scale == first.scale and other.scaled
    again.pulses[:] = 0.0
    assert np.array_equal(mapper(corner).pulses, first.pulses)


POSE_MAPPER = ActionMapper(mode="pose")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6))
def test_the_ray_search_ends_on_the_edge_of_the_feasible(action: list[float]) -> None:
    """Any pose action: the pose sent can be commanded (IK and pulse limits); if it was scaled, 1/4096 of the
    pose farther out along the ray cannot."""
    from stewart_gym.calibration import servo_pulses_one

    mapper = POSE_MAPPER
    mapped = mapper(np.array(action))
    assert servo_pulses_one(mapper.geometry, mapper.calibration, mapped.pose.tolist()) is not None
    assert np.all(mapper.calibration.in_range(mapped.pulses))
    if mapped.scaled:
        farther = (mapped.scale + 1 / 4096) * mapper.pose(np.array(action))
        assert servo_pulses_one(mapper.geometry, mapper.calibration, farther.tolist()) is None


@pytest.mark.parametrize("mode", ["tilt", "pose", "pulse"])
def test_mapping_many_actions_at_once_maps_each_as_alone(mode: str) -> None:
    """``map_arrays`` gives, row by row, what one call per action gives: the same pose, scale and clipped action,
    pulses equal to rounding, unreachable poses (pose mode at the corners) scaled back the same way."""
    mapper = ActionMapper("servo-hexapod", mode=mode)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.3, 1.3, (200, mapper.size))
    many = mapper.map_arrays(actions)
    assert many.pulses.shape == (len(actions), 6) and many.actions.shape == actions.shape
    for i, action in enumerate(actions):
        want = mapper(action)
        np.testing.assert_allclose(many.pulses[i], want.pulses, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(many.poses[i], want.pose)
        assert (many.scaled[i], many.scales[i], tuple(many.actions[i].tolist())) == (want.scaled, want.scale,
                                                                                      want.action)  # fmt: skip
    if mode == "pose":
        assert many.scaled.sum() > 10
    with pytest.raises(ValueError, match="finite"):
        mapper.map_arrays(np.where(np.arange(mapper.size) == 1, np.nan, 0.0)[None, :])


@pytest.mark.parametrize("mode", ["tilt", "pose"])
def test_a_pose_offset_moves_every_commanded_pose(mode: str) -> None:
    """With an offset, each action's pose is the pose without it plus the offset, one at a time and many at once,
    and its pulses are the inverse kinematics of that pose; None takes it off again."""
    mapper = ActionMapper("servo-hexapod", mode=mode)
    actions = np.random.default_rng(1).uniform(-0.3, 0.3, (50, mapper.size))
    plain = [mapper(a) for a in actions]
    offset = np.array([0.002, -0.001, 0.004, 0.01, -0.02, 0.05])
    mapper.set_offset(offset)
    np.testing.assert_array_equal(mapper.offset, offset)
    for got, base, many in zip((mapper(a) for a in actions), plain, mapper.map_arrays(actions).pulses):
        assert not got.scaled
        np.testing.assert_allclose(got.pose, base.pose + offset, rtol=0, atol=1e-15)
        want = mapper.calibration.pulse_widths(inverse_kinematics(mapper.geometry, got.pose).servo_angles)
        np.testing.assert_allclose(got.pulses, want, rtol=0, atol=1e-9)
        np.testing.assert_allclose(many, got.pulses, rtol=0, atol=1e-9)
        assert not np.allclose(got.pulses, base.pulses)
    with pytest.raises(ValueError, match="finite"):
        mapper.set_offset([0, 0, np.nan, 0, 0, 0])
    mapper.set_offset(None)
    np.testing.assert_array_equal(mapper(actions[0]).pulses, plain[0].pulses)
    assert not mapper.offset.any()
