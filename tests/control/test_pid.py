"""The cascaded PID: its feed-forward of the target's acceleration, its lead, conditional integration, and the
PID retuned behind the Kalman observer."""


import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import circle_velocities, lqr_obs, sg_in

from stewart_gym.registry import deployable_policy, load_policy, resolve_policy
from stewart_gym.sensing import ObservationBuilder


def test_the_pid_feeds_the_targets_acceleration_forward_from_the_second_period_of_each_episode() -> None:
    """The PID adds the change of the target's velocity over a period divided by the period (the target's
    acceleration) to the ball's acceleration it asks for; nothing on an episode's first period (nothing to
    difference yet), after ``reset``, or in a row of a batch where ``predict`` starts an episode; a target at a
    steady velocity (a still one among them) adds nothing."""
    from stewart_gym.control import CascadedPID, PIDGains

    gains = PIDGains(kp_pos=2.0, kp_vel=3.0, ki_vel=0.0)
    pid, dt = CascadedPID(gains, dt=0.02), 0.02
    v_scale = ObservationBuilder(2, (0.15, 0.15)).velocity_scale[0]

    def obs(target_vel_x: float) -> np.ndarray:
        o = lqr_obs((0.0, 0.0))
        o[6] = o[2] = target_vel_x / v_scale  # the ball moves with the target: no error, no velocity error
        return o

    def tilt_x(action: np.ndarray) -> float:  # sin(pitch) the action commands (pitch tilts along x)
        return math.sin(float(action[..., 1]) * gains.max_tilt)

    assert tilt_x(pid(obs(0.05))) == pytest.approx(0.0, abs=1e-9)  # first period: no feed
    accel = (0.06 - 0.05) / dt
    assert tilt_x(pid(obs(0.06))) == pytest.approx(accel / (gains.rolling_factor * 9.80665), rel=1e-6)
    assert tilt_x(pid(obs(0.06))) == pytest.approx(0.0, abs=1e-9)  # a steady velocity: no acceleration
    pid.reset()
    assert tilt_x(pid(obs(0.07))) == pytest.approx(0.0, abs=1e-9)  # a new episode: no feed from the last one
    batch = np.stack([obs(0.05), obs(0.05)])
    pid.predict(batch, episode_start=np.array([True, True]))
    action, _ = pid.predict(np.stack([obs(0.06), obs(0.06)]), episode_start=np.array([False, True]))
    assert tilt_x(action[0]) == pytest.approx(accel / (gains.rolling_factor * 9.80665), rel=1e-6)
    assert tilt_x(action[1]) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.slow
def test_the_shipped_pids_lead_follows_the_figure8_closer_and_leaves_the_waypoints_as_they_were(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """The shipped PID + Kalman (``feed_lead`` 0.06 s) against the same gains without the lead (2 seeds each):
    on the figure-8 at least 10 % closer over both episodes (about 25 % here), the same waypoint episodes to
    the last bit; its bundle, exported through
    the CLI, carries the lead and acts as the controller does along a circle; a negative lead is refused."""
    from dataclasses import replace

    from stewart_gym.control import CascadedPID, checked_design
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    _, led, env_kwargs = load_for_evaluation("pid-kalman", "StewartBallTrack-v0")
    assert isinstance(led, CascadedPID) and led.gains.feed_lead == pytest.approx(0.06)
    unled = CascadedPID(replace(led.gains, feed_lead=0.0), led.dt)
    rms = {}
    for trajectory in ("figure8", "waypoints"):
        for name, policy in (("led", led), ("unled", unled)):
            metrics = evaluate("StewartBallTrack-v0", policy, episodes=2, seed=0, settling=False,
                               env_kwargs={**env_kwargs, "trajectory": trajectory})  # fmt: skip
            rms[trajectory, name] = metrics["per_episode"]["rms_mm"]
    assert np.mean(rms["figure8", "led"]) < 0.9 * np.mean(rms["figure8", "unled"])
    assert rms["waypoints", "led"] == rms["waypoints", "unled"]
    out = tmp_path / "bundle"
    proc = sg_in(capfd, "export", "--policy", "pid-kalman", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    bundle, direct = deployable_policy(resolve_policy(str(out))), load_policy("pid-kalman")

    v_scale = ObservationBuilder(2, (0.15, 0.15)).velocity_scale[0]
    for v in circle_velocities(120):
        obs = lqr_obs((1.0, -1.0))
        obs[6:8] = v / v_scale
        np.testing.assert_allclose(bundle(obs), direct(obs), atol=1e-6)
    values = json.loads((Path(__file__).resolve().parents[2] / "stewart_gym/policies/pid_kalman_gains.json").read_text())
    with pytest.raises(ValueError, match="feed_lead must be 0"):
        checked_design({**values, "feed_lead": -0.01}, "pid")


def test_conditional_integration_sums_only_near_the_target(tmp_path: Path) -> None:
    """With an ``integral_zone`` the PID and the LQR integrate the error only within it (a fast approach from
    far away leaves the integral at zero), hold it within the limit, and their bundles carry the zone."""
    from stewart_gym.control import CascadedPID, PIDGains, integrate_error
    from stewart_gym.hardware.export import BundlePolicy, classical_meta

    err = np.array([[0.05, 0.0], [0.003, -0.004], [0.0, 0.0]])  # 50 mm, 5 mm, on target
    out = integrate_error(np.zeros((3, 2)), err, 0.02, 0.05, 0.02)
    np.testing.assert_allclose(out, [[0, 0], [0.003 * 0.02, -0.004 * 0.02], [0, 0]])
    np.testing.assert_allclose(integrate_error(np.zeros((3, 2)), err, 0.02, 0.05, 0.0), err * 0.02)  # 0: always
    np.testing.assert_allclose(integrate_error(np.full((3, 2), 0.049), err, 1.0, 0.05, 0.0)[0], [0.05, 0.049])  # held
    for zone, summed in ((0.0, True), (0.02, False)):
        pid = CascadedPID(PIDGains(integral_zone=zone))
        far = np.zeros(12, dtype=np.float32)
        far[0] = 0.05 / 0.15  # the ball 50 mm from the target, at rest…
        for _ in range(10):
            pid(far)
        assert bool(np.any(pid(np.zeros(12, dtype=np.float32)) != 0)) is summed  # …then on it: only the integral acts
    lqr = load_policy("lqr")
    shipped = json.loads((Path(__file__).resolve().parents[2] / "stewart_gym/policies/lqr.json").read_text())
    assert shipped["integral_zone_mm"] > 0 and lqr.gains.integral_zone == pytest.approx(shipped["integral_zone_mm"] * 1e-3)
    for kind, policy in (("lqr", lqr), ("pid", load_policy("pid-kalman"))):
        bundle = BundlePolicy.from_meta(classical_meta(kind, vars(policy.gains), estimator="kalman"))
        assert policy.gains.integral_zone > 0 and bundle.meta["gains"]["integral_zone"] == policy.gains.integral_zone
        rng = np.random.default_rng(2)
        policy.reset()
        for _ in range(30):  # the same actions, step after step (the integral included)
            obs = rng.uniform(-0.1, 0.1, 12).astype(np.float32)
            np.testing.assert_allclose(bundle(obs), policy(obs), atol=1e-6)
