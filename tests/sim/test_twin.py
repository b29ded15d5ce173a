"""The twin file: its format, its checks, and what the env makes of it."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import stewart_gym  # noqa: F401  (registers the envs)
from stewart_gym.envs.randomization import TWIN_WIDTH_FLOOR, RandomizationRanges
from stewart_gym.errors import ConfigError
from stewart_gym.sensing import TouchPanelSpec
from stewart_gym.sim import BallSpec, ServoSpec
from stewart_gym.sim.twin import TWIN_FIELDS, Twin, load_twin

#: The issue's example, as a user would save it.
EXAMPLE = """\
[servos]
speed_scale = 1.0                  # × the servo model's nominal speed
deadband_us = 5.0
trim_us = [0, 0, 0, 0, 0, 0]       # each servo's neutral error (what a perfect calibration would remove)
latency_ms = 0.0                   # delay between a pulse leaving and the servo acting on it
[ball]
mass_scale = 1.0
radius_scale = 1.0
rolling_friction = 0.0             # m
[plate]
friction = 0.6
load_kg = 0.0
[sensor]
noise_mm = 1.0
latency_ms = 10.0
"""

SLOW = {"servos": {"speed_scale": 0.5, "deadband_us": 12, "trim_us": [30, -30, 20, -10, 0, 25], "latency_ms": 50},
        "ball": {"mass_scale": 1.5, "radius_scale": 1.1, "rolling_friction": 2e-5, "hollow": True},
        "plate": {"friction": 0.4, "load_kg": 0.2}, "sensor": {"noise_mm": 2.5, "latency_ms": 30}}  # fmt: skip


def toml_text(tables: dict) -> str:
    """Tables of scalars and lists as TOML (JSON spells them alike), a value that is no table as a bare key."""
    lines = []
    for table, values in tables.items():
        if not isinstance(values, dict):
            lines.insert(0, f"{table} = {json.dumps(values)}")
            continue
        lines.append(f"[{table}]")
        for key, value in values.items():
            text = "nan" if isinstance(value, float) and value != value else json.dumps(value)
            if isinstance(value, dict):  # an inline table
                text = "{" + ", ".join(f'"{k}" = {json.dumps(v)}' for k, v in value.items()) + "}"
            lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


def test_the_example_file_is_the_nominal_twin(tmp_path):
    path = tmp_path / "twin.toml"
    path.write_text(EXAMPLE)
    twin = load_twin(path)
    assert twin.values == Twin().values
    assert twin.total_latency_ms == 10.0
    assert set(Twin().values) == set(TWIN_FIELDS)


def test_missing_keys_take_the_nominal_values():
    twin = Twin.from_mapping({"servos": {"speed_scale": 0.5}})
    assert twin["servos.speed_scale"] == 0.5
    assert twin["servos.deadband_us"] == 5.0 and twin["sensor.latency_ms"] == 10.0 and twin["plate.friction"] == 0.6


@pytest.mark.parametrize("tables, words", [
    ({"servos": {"speed": 1.0}}, "unknown key(s) ['speed'] in [servos]"),
    ({"motors": {}}, "unknown table(s) ['motors']"),
    ({"servos": {"speed_scale": 0.0}}, "servos.speed_scale must be a number in 0.1…5"),
    ({"servos": {"deadband_us": -1}}, "servos.deadband_us"),
    ({"servos": {"latency_ms": float("nan")}}, "servos.latency_ms"),
    ({"servos": {"latency_ms": True}}, "servos.latency_ms"),
    ({"servos": {"trim_us": [0, 0, 0]}}, "servos.trim_us must be six numbers"),
    ({"servos": {"trim_us": [0, 0, 0, 0, 0, 500]}}, "servos.trim_us must be six numbers in -200…200"),
    ({"sensor": {"noise_mm": "1"}}, "sensor.noise_mm"),
    ({"ball": {"rolling_friction": 0.01}}, "ball.rolling_friction"),
    ({"ball": {"hollow": "yes"}}, "ball.hollow must be true or false, got 'yes'"),
    ({"ball": {"hollow": 1}}, "ball.hollow must be true or false, got 1"),
    ({"ball": {"mass_scale": 0.01}}, "ball.mass_scale must be a number in 0.02…10"),
    ({"fit": {"sigma": {"ball.hollow": 0.5}}}, 'fit.sigma "ball.hollow": not a twin key with a number'),
    ({"fit": {"sigma": {"ball.foo": 0.1}}}, 'fit.sigma "ball.foo": not a twin key'),
    ({"fit": {"sigma": {"servos.speed_scale": "0.1"}}}, 'fit.sigma "servos.speed_scale" must be a number ≥ 0, got '
                                                       "'0.1'"),
    ({"fit": {"undetermined": ["ball.diameter"]}, "ball": {"hollow": True}},
     "fit.undetermined lists 'ball.diameter', not a twin key"),
    ({"fit": {"undetermined": ["ball.mass_scale"], "sigma": {}}}, "the twin file sets nothing"),  # [fit] alone
    ({"ball": {}}, "the twin file sets nothing"),
    ({"plate": 3}, "[plate] must be a table"),
    ({"fit": {"sigma": {"servos.speed": 1}}}, "fit.sigma"),
    ({"fit": {"sigma": {"servos.trim_us": 1e9}}}, 'fit.sigma "servos.trim_us" = 1e+09 is wider than the value\'s whole '
                                                  "range (-200…200 µs)"),
    ({"speed_scale": 0.5}, "key(s) ['speed_scale'] outside any table; a twin's keys go in its tables"),
    ({}, "the twin file sets nothing"),  # an emptied file is not the nominal platform
])  # fmt: skip
def test_a_bad_twin_is_one_error_naming_the_file_and_key(tmp_path, tables, words):
    path = tmp_path / "mine.toml"
    path.write_text(toml_text(tables))
    with pytest.raises(ConfigError) as err:
        load_twin(path)
    assert str(path) in str(err.value) and words in str(err.value)


def test_a_twin_round_trips_through_its_file(tmp_path):
    twin = Twin.from_mapping(SLOW)
    fitted = Twin(twin.values, {"servos.speed_scale": 0.05, "servos.latency_ms": 2.0}, ("ball.mass_scale",))
    path = tmp_path / "t.toml"
    path.write_text(fitted.toml({"ball.mass_scale": "undetermined"}))
    back = load_twin(path)
    for key, value in twin.values.items():
        assert np.allclose(back.values[key], value, rtol=1e-5), key
    assert back.sigma == pytest.approx(fitted.sigma) and back.undetermined == ("ball.mass_scale",)
    assert Twin.from_mapping(back.to_mapping()).values == back.values


def test_the_env_simulates_exactly_the_twin():
    env = gym.make("StewartBallBalance-v0", twin=SLOW, backend="batched").unwrapped
    env.reset(seed=3)
    p, nominal = env.params, ServoSpec()
    assert p.servo.max_speed == pytest.approx(0.5 * nominal.max_speed)
    assert p.servo.deadband_us == 12 and p.servo.trim_error_us == (30, -30, 20, -10, 0, 25)
    assert p.servo.lag_s == pytest.approx(nominal.lag_s + 0.050)
    assert p.sensor == TouchPanelSpec(noise_mm=2.5, rate_hz=100.0, latency_s=0.030)
    assert p.ball.mass == pytest.approx(1.5 * BallSpec().mass)
    assert p.ball.radius == pytest.approx(round(1.1 * BallSpec().radius, 5)) and p.ball.rolling_friction == 2e-5
    assert p.ball.hollow
    assert p.plate_friction == 0.4 and p.plate_load[0] == 0.2
    env.reset(seed=4)  # another seed: the same platform
    assert env.params.servo == p.servo and env.params.sensor == p.sensor
    env.close()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), sigma=st.floats(0.0, 0.3))
def test_randomised_around_a_twin_each_value_stays_within_its_width(seed, sigma):
    twin = Twin(Twin.from_mapping(SLOW).values, {"servos.speed_scale": sigma}, ("plate.friction",))
    from stewart_gym.envs.randomization import EpisodeParams

    rng = np.random.default_rng(seed)
    p = EpisodeParams.from_twin(twin, BallSpec(), ServoSpec(), TouchPanelSpec(), rng, RandomizationRanges())
    width = max(2 * sigma, TWIN_WIDTH_FLOOR["servos.speed_scale"])
    assert abs(p.servo.max_speed / ServoSpec().max_speed - 0.5) <= width + 1e-9
    assert abs(p.servo.deadband_us - 12) <= TWIN_WIDTH_FLOOR["servos.deadband_us"] + 1e-9
    assert np.all(np.abs(np.subtract(p.servo.trim_error_us, SLOW["servos"]["trim_us"]))
                  <= TWIN_WIDTH_FLOOR["servos.trim_us"] + 1e-9)  # fmt: skip
    assert abs(p.sensor.latency_s - 0.030) <= TWIN_WIDTH_FLOOR["sensor.latency_ms"] / 1e3 + 1e-12
    lo, hi = RandomizationRanges().plate_friction  # undetermined: drawn from today's range
    assert lo <= p.plate_friction <= hi


def test_a_bad_twin_keyword_is_refused_by_the_env():
    with pytest.raises(ConfigError, match="unknown key"):
        gym.make("StewartBallBalance-v0", twin={"servos": {"speed": 2}})


#: A 40 mm ping-pong ball of 2.7 g, a thin shell, as its user writes it.
PING_PONG = {"ball": {"radius_scale": 1.575, "mass_scale": 0.04, "hollow": True}}


@pytest.mark.parametrize("backend", ["pybullet", "mujoco", "batched"])
def test_a_ping_pong_ball_twin_rolls_at_three_fifths_of_g_sin_theta(backend):
    """Under the same held tilt, a thin shell rolls at 3/5 g sin θ and the solid nominal ball at 5/7 g sin θ: the
    ratio of their accelerations is 0.84 in every engine (its 2.7 g and 20 mm change nothing of it)."""
    accelerations = []
    for twin in ({}, PING_PONG):
        env = gym.make("StewartBallBalance-v0", backend=backend, randomize=False, **({"twin": twin} if twin else {}))
        env.reset(seed=0, options={"ball_position": (0.0, 0.0), "ball_velocity": (0.0, 0.0)})
        ball = env.unwrapped.sim.ball_spec
        assert (ball.hollow, ball.radius, ball.mass) == ((True, 0.02, 0.04 * BallSpec().mass) if twin
                                                         else (False, BallSpec().radius, BallSpec().mass))  # fmt: skip
        xs = []
        for _ in range(35):  # a held tilt about y: the ball rolls along x
            _, _, terminated, _, info = env.step(np.array([0.0, 0.25], dtype=np.float32))
            assert not terminated
            xs.append(info["ball_xy_m"][0])
        env.close()
        t = np.arange(1, 36) / 50.0
        accelerations.append(2.0 * np.polyfit(t[15:], np.array(xs[15:]), 2)[0])  # once the plate has tilted
    solid, shell = accelerations
    assert solid > 0.1
    assert shell / solid == pytest.approx((3 / 5) / (5 / 7), abs=0.01)


def test_undetermined_ball_scales_are_drawn_around_the_twins_ball():
    """A fitted twin leaves the ball undetermined (the ball's rolling shows neither its mass nor its size):
    training draws them from today's ranges as factors of the twin's own, so that a ping-pong ball's twin trains
    on ping-pong balls, and the nominal twin draws exactly as before."""
    from stewart_gym.envs.randomization import EpisodeParams

    ranges = RandomizationRanges()
    undetermined = ("ball.mass_scale", "ball.radius_scale", "ball.hollow")
    for values, scale in ((Twin.from_mapping(PING_PONG).values, 1.575), (Twin().values, 1.0)):
        twin = Twin(values, {}, undetermined)
        for seed in range(20):
            p = EpisodeParams.from_twin(twin, BallSpec(), ServoSpec(), TouchPanelSpec(), np.random.default_rng(seed),
                                        ranges)  # fmt: skip
            lo, hi = ranges.ball_radius_scale
            assert scale * lo * BallSpec().radius - 1e-5 <= p.ball.radius <= scale * hi * BallSpec().radius + 1e-5
            assert p.ball.hollow == (scale != 1.0)
    nominal = Twin(Twin().values, {}, undetermined)
    for seed in range(5):  # the nominal twin: the same draws as the ranges themselves give
        p = EpisodeParams.from_twin(nominal, BallSpec(), ServoSpec(), TouchPanelSpec(), np.random.default_rng(seed),
                                    ranges)  # fmt: skip
        rng = np.random.default_rng(seed)
        assert p.ball.mass == BallSpec().mass * rng.uniform(*ranges.ball_mass_scale)
        assert p.ball.radius == round(BallSpec().radius * rng.uniform(*ranges.ball_radius_scale), 5)


def test_what_a_twin_file_leaves_out_is_randomised_as_without_a_twin(tmp_path):
    """A twin of the ball alone says nothing of the servos, the panel or the plate: training (``rng``) draws them
    from today's ranges, as ``randomize`` does without a twin, not narrowly around nominal values nobody measured;
    a fixed episode (no ``rng``) keeps the nominal ball's, servos' and panel's own values. The keys left out
    survive the trip through the command line's tables (``to_mapping``)."""
    from stewart_gym.envs.randomization import EpisodeParams

    path = tmp_path / "ball.toml"
    path.write_text(toml_text(PING_PONG))
    twin = load_twin(path)
    assert set(twin.omitted) == {f"{t}.{k}" for t, k in TWIN_FIELDS} - {"ball.radius_scale", "ball.mass_scale",
                                                                         "ball.hollow"}  # fmt: skip
    assert Twin.from_mapping(twin.to_mapping()).omitted == twin.omitted
    servo, panel = ServoSpec(deadband_us=4.0, trim_error_us=(5.0,) * 6), TouchPanelSpec(noise_mm=0.7)
    fixed = EpisodeParams.from_twin(twin, BallSpec(), servo, panel)
    assert fixed.servo == servo and fixed.sensor == panel and fixed.ball.rolling_friction == BallSpec().rolling_friction
    assert fixed.ball.radius == 0.02 and fixed.ball.hollow
    ranges = RandomizationRanges()
    drawn = [EpisodeParams.from_twin(twin, BallSpec(), ServoSpec(), TouchPanelSpec(), np.random.default_rng(seed),
                                     ranges) for seed in range(300)]  # fmt: skip
    speeds = np.array([p.servo.max_speed / ServoSpec().max_speed for p in drawn])
    trims = np.array([p.servo.trim_error_us for p in drawn])
    lags = np.array([p.servo.lag_s - ServoSpec().lag_s for p in drawn])
    noises = np.array([p.sensor.noise_mm for p in drawn])
    for values, (lo, hi) in ((speeds, ranges.servo_speed_scale), (lags, ranges.control_latency_s),
                             (noises, ranges.sensor_noise_mm), (trims, (-ranges.servo_trim_us, ranges.servo_trim_us)),
                             ([p.plate_friction for p in drawn], ranges.plate_friction)):  # fmt: skip
        values = np.asarray(values)
        assert lo - 1e-12 <= values.min() and values.max() <= hi + 1e-12
        assert values.max() - values.min() > 0.8 * (hi - lo)  # the whole range, not a narrow band
    width = BallSpec().radius * TWIN_WIDTH_FLOOR["ball.radius_scale"] + 1e-5  # (the radius rounded to 10 µm)
    assert all(p.ball.hollow and abs(p.ball.radius - 0.02) <= width for p in drawn)  # the ball given: narrowly
