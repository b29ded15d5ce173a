"""Sensing: the touch-panel model's noise, rate and latency; the velocity estimator."""


from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stewart_gym.sensing import SimulatedTouchPanel, TouchPanelSpec, VelocityEstimator


def test_touch_panel_noise_rate_and_latency() -> None:
    spec = TouchPanelSpec(noise_mm=1.0, rate_hz=100.0, latency_s=0.030)
    panel = SimulatedTouchPanel(spec)
    panel.reset(0.0, np.zeros(2), np.random.default_rng(0))
    readings, truths = [], []
    for k in range(1, 2001):
        t = k * 0.02
        panel.record(t, np.array([0.1 * t, 0.0]), True)  # moving at 0.1 m/s along x
        (x, y), ts = panel.read(t)
        readings.append((x, y))
        truths.append(0.1 * ts)
        assert ts == pytest.approx(math.floor((t - 0.030) * 100 + 1e-9) / 100)
    err = np.array(readings) - np.stack([truths, np.zeros(len(truths))], 1)
    assert err.std(axis=0) == pytest.approx([1e-3, 1e-3], rel=0.1)
    assert abs(err.mean()) < 1e-4  # unbiased: the lag is exactly the sample time
    panel.record(41.0, np.zeros(2), False)
    assert panel.read(41.05) is None  # no touch, no reading


def test_velocity_estimator_converges() -> None:
    est = VelocityEstimator(cutoff_hz=8.0)
    est.reset(0.0, (0.0, 0.0))
    for k in range(1, 200):
        vx, vy = est.update(k * 0.01, (0.2 * k * 0.01, -0.1 * k * 0.01))
    assert (vx, vy) == pytest.approx((0.2, -0.1), rel=1e-6)


@pytest.mark.parametrize("estimator", ["lowpass", "kalman"])
def test_error_integral_sums_near_the_target_and_is_bounded(estimator: str) -> None:
    """``integral=True``: the last two entries integrate target − ball (m·s, scaled by h × 0.1 s) only within
    20 % of the half plate of the target, held within the bound; reset clears it; without it, 12 values."""
    from stewart_gym.sensing import BallObserver, ObservationBuilder

    assert BallObserver(2, estimator=estimator).observe(((0.0, 0.0), 0.0), (0, 0), (0, 0), (0, 0), (0, 0)).shape == (12,)
    obs = BallObserver(2, estimator=estimator, integral=True)
    assert obs.builder.size == 14 and obs.builder.space.shape == (14,)
    scale = 0.15 * ObservationBuilder.INTEGRAL_TIME

    def hold(xy: tuple[float, float], seconds: float, t0: float) -> np.ndarray:
        obs.reset(t0, xy)
        out = np.zeros(14)
        for k in range(1, int(round(seconds * 50)) + 1):
            t = t0 + k / 50
            out = obs.observe((xy, t), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), now=t)
        return out

    near = hold((0.004, -0.002), 1.0, 3.0)  # 4.5 mm from the target for 1 s: −4 and +2 mm·s
    assert near[-2:] == pytest.approx([-0.004 / scale, 0.002 / scale], rel=0.05)
    assert obs.error_integral == pytest.approx([-0.004, 0.002], rel=0.05)
    far = hold((0.05, 0.0), 1.0, 0.0)  # 50 mm away: outside the 30 mm zone, nothing is summed
    assert far[-2:] == pytest.approx([0.0, 0.0], abs=1e-9)
    wound = hold((0.02, 0.0), 10.0, 0.0)  # 20 mm for 10 s would be 0.2 m·s: held at the bound
    assert wound[-2] == pytest.approx(-2.0) and obs.error_integral[0] == pytest.approx(-2 * scale)
    obs.reset(0.0, (0.0, 0.0))
    assert obs.error_integral == [0.0, 0.0]


def test_env_integral_option() -> None:
    """The env's observation gains the two integral entries with ``integral=True``; a non-boolean is refused."""
    import gymnasium as gym

    from stewart_gym.errors import ConfigError

    env = gym.make("StewartBallBalance-v0", integral=True)
    try:
        obs, _ = env.reset(seed=0, options={"ball_position": (0.01, 0.0), "ball_velocity": (0.0, 0.0)})
        assert obs.shape == (14,) and env.observation_space.shape == (14,)
        for _ in range(10):
            obs, *_ = env.step(np.zeros(2, dtype=np.float32))
        assert obs[-2] < 0  # the ball sits at +x of the target: the error (target − ball) sums negative
    finally:
        env.close()
    with pytest.raises(ConfigError, match="integral"):
        gym.make("StewartBallBalance-v0", integral="yes")


@pytest.mark.parametrize("estimator", ["lowpass", "kalman"])
@pytest.mark.parametrize("bad", [(math.nan, 0.0), (0.0, math.inf), (-math.inf, math.nan), (1e308, -1e308),
                                 (0.2, 0.0), (0.0, -0.17)])  # fmt: skip
def test_an_invalid_reading_is_observed_as_no_reading(estimator: str, bad: tuple[float, float]) -> None:
    """The observer (the env's and deploy's) takes a NaN, infinite or off-plate reading exactly as no reading:
    the same observation as None, the count of invalid readings up by one, and the next good reading as usual."""
    from stewart_gym.sensing import BallObserver

    def observer() -> BallObserver:
        o = BallObserver(2, plate_half=(0.15, 0.15), estimator=estimator)
        o.reset(0.0, (0.03, -0.02))
        for k in range(1, 6):
            o.observe(((0.03 + 0.001 * k, -0.02), 0.02 * k), (0, 0), (0, 0), (0.01, 0.0), (0.1, 0.0), now=0.02 * k)
        return o

    with_bad, with_none = observer(), observer()
    got = with_bad.observe((bad, 0.12), (0, 0), (0, 0), (0.01, 0.0), (0.1, 0.0), now=0.12)
    want = with_none.observe(None, (0, 0), (0, 0), (0.01, 0.0), (0.1, 0.0), now=0.12)
    assert np.array_equal(got, want) and np.all(np.isfinite(got))
    assert with_bad.invalid_readings == 1 and with_none.invalid_readings == 0
    good = ((0.04, -0.02), 0.14)
    assert np.array_equal(with_bad.observe(good, (0, 0), (0, 0), (0, 0), (0, 0), now=0.14),
                          with_none.observe(good, (0, 0), (0, 0), (0, 0), (0, 0), now=0.14))


@given(x=st.floats(allow_nan=True, allow_infinity=True), y=st.floats(allow_nan=True, allow_infinity=True),
       ts=st.floats(allow_nan=True, allow_infinity=True), hx=st.floats(0.01, 1.0), hy=st.floats(0.01, 1.0))
def test_reading_validity_is_finite_and_on_the_plate(x: float, y: float, ts: float, hx: float, hy: float) -> None:
    from stewart_gym.sensing import READING_MARGIN, reading_is_valid

    on_plate = abs(x) <= hx * (1 + READING_MARGIN) and abs(y) <= hy * (1 + READING_MARGIN)
    expected = math.isfinite(x) and math.isfinite(y) and math.isfinite(ts) and on_plate
    assert reading_is_valid(((x, y), ts), (hx, hy)) == expected
