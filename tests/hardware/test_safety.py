"""The safety layer: channel limits, rate limit, hold; a million random, NaN, infinite and huge actions."""


from __future__ import annotations

import numpy as np
import pytest
from conftest import StaticSensor

from stewart_gym.actions import ActionMapper
from stewart_gym.calibration import ServoCalibration
from stewart_gym.hardware.deploy import DeployLoop
from stewart_gym.hardware.safety import SafetyLayer

CAL = ServoCalibration.default("servo-hexapod")


PULSES = np.array([1500.0, 1400.25, 1600.5, 1100.0, 1900.0, 1234.75])


def test_safety_layer_limits_rate_and_holds() -> None:
    safety = SafetyLayer(CAL, max_step_us=40)
    r = safety.filter(np.full(6, 5000.0))
    assert r.clamped and r.rate_limited and np.all(r.pulses == 1540.0)
    r = safety.filter(np.array([np.nan, 1500, 1500, 1500, 1500, 1500]))
    assert r.held and np.all(r.pulses == 1540.0)
    r = safety.filter(np.full(6, 1520.0), usable=False)  # e.g. an unreachable pose
    assert r.held and np.all(r.pulses == 1540.0)
    for _ in range(3):
        r = safety.toward_home()
    assert r.homing and safety.at_home()


class _Fuzz:
    """A 'policy' that returns random, NaN, infinite and huge actions."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        kind = self.rng.integers(6)
        if kind == 0:
            return self.rng.uniform(-1, 1, 2)
        if kind == 1:
            return self.rng.normal(0, 1e6, 2)
        if kind == 2:
            return np.array([np.nan, self.rng.uniform(-1, 1)])
        if kind == 3:
            return np.array([np.inf, -np.inf]) * self.rng.choice([-1, 1])
        if kind == 4:
            return self.rng.uniform(-3, 3, 2)
        return np.array([1e308, -1e308])


@pytest.mark.slow
def test_fuzz_one_million_actions_never_leave_limits_or_rate() -> None:
    for mode in ("tilt", "pose", "pulse"):
        mapper = ActionMapper("servo-hexapod", CAL, mode)
        rng = np.random.default_rng(2)
        policy = _Fuzz(1) if mode == "tilt" else (lambda obs, rng=rng: rng.normal(0, 1e3, 6) *
                                                    rng.choice([1, np.nan, np.inf], 6, p=[0.8, 0.1, 0.1]))  # fmt: skip
        loop = DeployLoop(policy, mapper, controller=None, sensor=StaticSensor())  # type: ignore[arg-type]
        n = 600_000 if mode == "tilt" else 200_000
        sent = np.empty((n + 1, 6))  # the pulses before the first tick, then each tick's, checked all at once
        sent[0] = loop.safety.last
        for k in range(n):
            sent[k + 1] = loop.compute(((0.01, 0.0), 0.005), k * 0.02)[2]
        outside = int(np.sum(~np.all(np.isfinite(sent[1:]) & (sent[1:] >= CAL.min_us) & (sent[1:] <= CAL.max_us), axis=1)))
        rate = int(np.sum(np.any(np.abs(np.diff(sent, axis=0)) > loop.safety.max_step_us + 1e-9, axis=1)))
        assert outside == 0 and rate == 0, (mode, outside, rate)
