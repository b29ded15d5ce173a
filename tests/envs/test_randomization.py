"""Domain randomisation's draws (:class:`~stewart_gym.envs.randomization.EpisodeParams`): one generator call per
run of draws gives, to the last bit, the episodes that one draw per ``rng.random()`` call gives, in the documented
order, for a touch panel, a camera and a set of cameras to draw from; and each draw, low + (high − low) · d, is
NumPy's ``rng.uniform(low, high)`` up to NumPy's own rounding of it (``conftest.uniform_draw``)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import uniform_draw

from stewart_gym.camera import CAMERA_PRESETS, CameraSpec
from stewart_gym.envs.randomization import EpisodeParams, RandomizationRanges
from stewart_gym.errors import ConfigError
from stewart_gym.sensing import TouchPanelSpec
from stewart_gym.sim import BallSpec, ServoSpec


def one_call_per_draw(rng: np.random.Generator, r: RandomizationRanges, ball: BallSpec, servo: ServoSpec,
                      sensor: TouchPanelSpec | CameraSpec | tuple[CameraSpec, ...]) -> EpisodeParams:  # fmt: skip
    """The draws written out one generator call at a time, in the order the ranges' docs give them."""
    def u(low: float, high: float) -> float:
        return uniform_draw(rng, low, high)

    ball_ep = replace(ball, radius=round(ball.radius * u(*r.ball_radius_scale), 4), mass=ball.mass * u(*r.ball_mass_scale),
                      rolling_friction=u(*r.ball_rolling_friction))  # fmt: skip
    latency = u(*r.control_latency_s)
    speed = u(*r.servo_speed_scale)
    trims = tuple(u(-r.servo_trim_us, r.servo_trim_us) for _ in range(6))
    servo_ep = replace(servo, max_speed=servo.max_speed * speed, trim_error_us=trims, deadband_us=u(*r.servo_deadband_us),
                       lag_s=servo.lag_s + latency)  # fmt: skip
    if isinstance(sensor, tuple):
        sensor = sensor[int(rng.integers(len(sensor)))]
    if isinstance(sensor, TouchPanelSpec):
        sensor_ep = TouchPanelSpec(noise_mm=u(*r.sensor_noise_mm), rate_hz=sensor.rate_hz, latency_s=u(*r.sensor_latency_s))
    else:
        sensor_ep = replace(sensor, latency_s=sensor.latency_s * u(*r.camera_latency_scale),
                            centroid_noise_px=sensor.centroid_noise_px * u(*r.camera_noise_scale),
                            miss_rate=min(0.5, sensor.miss_rate * u(*r.camera_miss_scale)))  # fmt: skip
    angle, dist = u(0, 2 * math.pi), r.plate_load_radius * math.sqrt(u(0, 1))
    load = (u(*r.plate_load_kg), np.array([dist * math.cos(angle), dist * math.sin(angle), 0.012]))
    return EpisodeParams(ball_ep, servo_ep, sensor_ep, u(*r.plate_friction), load)


CAMERAS = tuple(CAMERA_PRESETS.values())
CUSTOM = RandomizationRanges(servo_trim_us=0.0, plate_friction=(0.5, 0.5), ball_mass_scale=(0.5, 3.0))


@pytest.mark.parametrize("sensor", [TouchPanelSpec(), CAMERAS[0], CAMERAS], ids=["panel", "camera", "cameras"])
@pytest.mark.parametrize("ranges", [RandomizationRanges(), CUSTOM], ids=["defaults", "custom"])
def test_the_draws_are_one_generator_call_per_draw(sensor: object, ranges: RandomizationRanges) -> None:
    for seed in range(300):
        got_rng, want_rng = np.random.default_rng(seed), np.random.default_rng(seed)
        got = EpisodeParams.sample(got_rng, ranges, BallSpec(), ServoSpec(), sensor)
        want = one_call_per_draw(want_rng, ranges, BallSpec(), ServoSpec(), sensor)
        assert (got.ball, got.servo, got.sensor, got.plate_friction) == (want.ball, want.servo, want.sensor,
                                                                         want.plate_friction)  # fmt: skip
        assert all(type(v) is float for v in got.servo.trim_error_us)
        assert got.plate_load[0] == want.plate_load[0]
        np.testing.assert_array_equal(got.plate_load[1], want.plate_load[1])
        assert got_rng.random() == want_rng.random()  # the generator is left where one call per draw leaves it


def test_numpy_uniform_is_the_draw_up_to_its_rounding() -> None:
    """``rng.uniform(low, high)`` is :func:`uniform_draw`'s number from the same generator state, rounded twice
    (x86-64, Linux arm64) or, on every draw alike, once (a fused multiply-add: macOS arm64): the env's draws are
    NumPy's uniform ones to the last bit on the first machines, and within one rounding on the others. The two
    roundings differ often enough here for the check to tell them apart."""
    from fractions import Fraction

    twice_all = once_all = True
    differ = 0
    for seed in range(200):
        numpy_rng, ours = np.random.default_rng(seed), np.random.default_rng(seed)
        for low, high in [(0.9, 1.1), (0.8, 1.25), (-4.0, 4.0), (0.005, 0.03), (0.3, 0.9), (-0.1, 0.2)]:
            got, d = numpy_rng.uniform(low, high), ours.random()
            twice = low + (high - low) * d  # uniform_draw's number
            once = float(Fraction(high - low) * Fraction(d) + Fraction(low))  # exact, then one rounding
            twice_all &= got == twice
            once_all &= got == once
            differ += twice != once
    assert twice_all or once_all
    assert differ > 100  # of 1,200 draws: the two roundings are told apart


@pytest.mark.parametrize(("field", "value"), [("servo_deadband_us", (5.0, 3.0)), ("plate_friction", (0.0, math.inf)),
                                              ("ball_mass_scale", (math.nan, 1.0)), ("servo_trim_us", -1.0),
                                              ("plate_load_radius", math.inf), ("sensor_noise_mm", (1.0,)),
                                              ("control_latency_s", ("0", "1")), ("ball_mass_scale", (0.0, 0.0)),
                                              ("ball_radius_scale", (-1.0, -0.5)), ("servo_speed_scale", (0.0, 1.0)),
                                              ("plate_friction", (0.0, 0.5)),
                                              ("sensor_latency_s", (-0.01, 0.01))])  # fmt: skip
def test_bad_ranges_are_refused_naming_the_field(field: str, value: object) -> None:
    """A range or value the draws cannot use is one clear error, made directly or from a mapping (a YAML
    ``randomization:`` table)."""
    with pytest.raises(ConfigError, match=f"randomization.{field} must be"):
        RandomizationRanges(**{field: value})
    with pytest.raises(ConfigError, match=f"randomization.{field} must be"):
        RandomizationRanges.from_mapping({field: list(value) if isinstance(value, tuple) else value})


def test_ranges_are_kept_as_python_floats() -> None:
    ranges = RandomizationRanges(ball_mass_scale=(np.float32(0.9), 1), servo_trim_us=np.int64(3))
    assert ranges.ball_mass_scale == (float(np.float32(0.9)), 1.0) and ranges.servo_trim_us == 3.0
    assert all(type(v) is float for v in (*ranges.ball_mass_scale, ranges.servo_trim_us))


@pytest.mark.parametrize("backend", ["pybullet", "batched"])
def test_a_ball_of_no_size_or_mass_is_refused_before_the_engine_sees_it(backend: str) -> None:
    """A zero or negative ball range, or ball, is one error naming the field, not PyBullet's "createCollisionShape
    failed" or the batched kernel's division by zero (nor a negative mass that runs without a word)."""
    import gymnasium as gym

    from stewart_gym.sim import BallSpec

    with pytest.raises(ConfigError, match=r"randomization.ball_radius_scale must be \[lo, hi\] with finite 0 < lo"):
        gym.make("StewartBallBalance-v0", backend=backend, randomization={"ball_radius_scale": (0, 0)})
    for field, value in (("radius", -0.02), ("radius", 0.0), ("mass", -1.0)):
        with pytest.raises(ConfigError, match=f"BallSpec.{field} must be a finite number above 0, got {value!r}"):
            gym.make("StewartBallBalance-v0", backend=backend, ball=BallSpec(**{field: value}))


def test_a_ball_field_that_is_a_bool_or_an_array_is_refused_naming_it() -> None:
    """``True`` compares as 1 and ``False`` as 0: neither is a radius or a friction. An array is no one number, nor
    a string; the message says what it got."""
    from stewart_gym.sim import BallSpec

    for field, value, kind in (("radius", True, "bool"), ("lateral_friction", False, "bool"),
                               ("radius", np.True_, "bool"), ("mass", np.array([0.1, 0.2]), "ndarray"),
                               ("mass", np.array(0.1), "ndarray"), ("radius", "a", "str")):  # fmt: skip
        with pytest.raises(ConfigError, match=rf"BallSpec.{field} must be a number, got .* \({kind}\)$"):
            BallSpec(**{field: value})
    with pytest.raises(ConfigError, match=r"BallSpec.restitution must be a finite number in \[0, 1\], got 2$"):
        BallSpec(restitution=2)
    ball = BallSpec(radius=np.float32(0.02), mass=np.int64(1), hollow=np.True_)  # NumPy numbers are numbers
    assert ball.inertia == pytest.approx(2 / 3 * 1 * 0.02**2, rel=1e-6)
