"""Sensing: the touch-panel model's noise, rate and latency; the velocity estimator."""


from __future__ import annotations

import math

import numpy as np
import pytest

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
