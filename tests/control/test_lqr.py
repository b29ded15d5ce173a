"""The LQR: its design (stable on every preset), its bundle (the same actions, the Kalman observer), and its
control of the simulated ball, a moving target included."""


import math
from pathlib import Path

import numpy as np
import pytest
from conftest import ball_presets, circle_velocities, lqr_obs, sg_in

from stewart_gym.control import LQRController, LQRDesign, design_lqr, lqr_model
from stewart_gym.registry import deployable_policy, load_policy, resolve_policy
from stewart_gym.sensing import ObservationBuilder


@pytest.mark.parametrize("name", ball_presets())
def test_the_lqr_closed_loop_is_stable_on_every_preset(name: str) -> None:
    """Every eigenvalue of A − B·K (the discrete model with its integral) inside the unit circle, with margin."""
    gains = design_lqr(geometry=name)
    a, b = lqr_model(LQRDesign(), gains.dt)
    eig = np.linalg.eigvals(a - b @ np.asarray(gains.k)[None, :])
    assert np.all(np.abs(eig) < 0.995), eig
    assert gains.integral_limit > 0 and 0 < gains.max_tilt < math.pi / 2


@pytest.mark.slow
def test_the_lqr_balances_the_randomised_ball() -> None:
    """10 randomised seeds from the env's random starts: all succeed, and the ball ends within 3 mm."""
    from stewart_gym.evaluation import evaluate

    metrics = evaluate("StewartBallBalance-v0", load_policy("lqr"), episodes=10, seed=100,
                       env_kwargs={"estimator": "kalman"})  # fmt: skip
    assert metrics["success_rate"] == 1.0 and metrics["final_error_mm"] < 3.0, metrics


def test_the_shipped_lqrs_lead_adds_the_led_feed_through_its_gains_and_leaves_the_waypoints_as_they_were(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """The shipped LQR (``feed_lead`` 0.08 s) against the same gains without the lead, on the same observations
    along a circle: the same commands until the target's path has held steady for 1.5 s, then commands that
    differ by the lead's part of the feed times the gains that act on it (command = feed − k·(…, a − feed,
    u − feed, …)). Closed loop, the same waypoint episodes to the last bit (2 seeds); the bundle exported
    through the CLI carries the lead and acts as the controller does along the circle. Where the lead acts
    the measured gain is small (50 tuning seeds, RMS: circle −0.02 mm, figure-8 −0.07 mm), too small for a
    test of a few episodes; the docs quote it."""
    from dataclasses import replace

    from stewart_gym.constants import GRAVITY
    from stewart_gym.control import TargetFeed
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    _, led, env_kwargs = load_for_evaluation("lqr", "StewartBallTrack-v0")
    assert isinstance(led, LQRController) and led.gains.feed_lead == pytest.approx(0.08)
    g = led.gains
    unled = LQRController(replace(g, feed_lead=0.0))
    v_scale = ObservationBuilder(2, (0.15, 0.15)).velocity_scale[0]
    vel = circle_velocities(150, g.dt)
    steady = round(TargetFeed.STEADY_S / g.dt)
    per_feed = 1.0 + g.k[2] + g.k[3]  # how much of the feed reaches the command (sin(tilt))
    for k, v in enumerate(vel):
        obs = lqr_obs((1.0, -1.0))
        obs[6:8] = v / v_scale
        a, b = led(obs), unled(obs)
        if k < steady:
            np.testing.assert_array_equal(a, b)
        elif k > steady + 3:
            change = v - 2 * vel[k - 1] + vel[k - 2]
            extra = change * g.feed_lead / (g.dt * g.dt * g.rolling_factor * GRAVITY) * per_feed
            # the action is the tilt (roll, pitch) over max_tilt: pitch follows x, roll −y; small angles
            got = np.array([math.sin(a[1] * g.max_tilt) - math.sin(b[1] * g.max_tilt),
                            -(math.sin(a[0] * g.max_tilt) - math.sin(b[0] * g.max_tilt))])  # fmt: skip
            np.testing.assert_allclose(got, extra, rtol=1e-3, atol=1e-9)
            assert np.linalg.norm(extra) > 3e-5  # far above the float32 action's rounding (about 1e-9 here)
    rms = {}
    for name, policy in (("led", led), ("unled", unled)):
        metrics = evaluate("StewartBallTrack-v0", policy, episodes=2, seed=0, settling=False,
                           env_kwargs={**env_kwargs, "trajectory": "waypoints"})  # fmt: skip
        rms[name] = metrics["per_episode"]["rms_mm"]
    assert rms["led"] == rms["unled"]
    out = tmp_path / "bundle"
    proc = sg_in(capfd, "export", "--policy", "lqr", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    bundle, direct = deployable_policy(resolve_policy(str(out))), load_policy("lqr")
    for v in vel:
        obs = lqr_obs((1.0, -1.0))
        obs[6:8] = v / v_scale
        np.testing.assert_allclose(bundle(obs), direct(obs), atol=1e-6)
