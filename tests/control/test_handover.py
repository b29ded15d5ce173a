"""The LQR → PID hand-over: when the PID takes the ball and when the LQR takes it back (distances, speeds, dwells,
pushes), its design as shipped, and its bundle."""


import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from conftest import lqr_obs, sg_in

from stewart_gym.control import LQRController
from stewart_gym.registry import deployable_policy, load_policy, resolve_policy
from stewart_gym.sensing import ObservationBuilder

#: The run folder of one of the shipped balance residual's six networks (seed 0)
SHIPPED_RESIDUAL_RUN = Path(__file__).resolve().parents[2] / "stewart_gym/policies/balance_residual/members/0"


def moving(ball_mm: float, mm_s: float) -> np.ndarray:
    """:func:`lqr_obs` of a ball ``ball_mm`` from the target along x, moving along x at ``mm_s`` (the target at
    rest; velocities in the observation's scale on the reference plate)."""
    obs = lqr_obs((ball_mm, 0.0))
    obs[2] = mm_s / 1e3 / ObservationBuilder(2, (0.15, 0.15)).velocity_scale[0]
    return obs


def held_by_pid(policy: Any, sequence: list[np.ndarray]) -> list[bool]:
    """From a reset, whether the hand-over's PID holds the ball after each observation of ``sequence``."""
    policy.reset()
    out = []
    for obs in sequence:
        policy(obs)
        out.append(bool(policy.pid_in_control))
    return out


def test_the_handover_gives_the_ball_to_the_pid_with_its_own_integral_and_takes_back_far_away() -> None:
    """``lqr-pid``: the LQR alone while the ball is far; within 2 mm and slow the PID takes over with the
    integral it kept all along (its action is that of the PID + Kalman run alone on the same observations, and
    the integral of 100 periods at 5 mm shows in it); beyond 20 mm the LQR again, as if it had run alone
    throughout; near a moving target the PID takes over as near a still one if the ball moves with it, the
    LQR keeps a ball that does not; rows independent."""
    from stewart_gym.control import HandoverController

    handover, lqr, pid = load_policy("lqr-pid"), load_policy("lqr"), load_policy("pid-kalman")
    assert isinstance(handover, HandoverController) and isinstance(lqr, LQRController)
    g = handover.gains
    for _ in range(100):  # 5 mm off: the LQR acts; both integrate (within their 20 mm zones)
        np.testing.assert_array_equal(handover(lqr_obs((5.0, 0.0))), lqr(lqr_obs((5.0, 0.0))))
        pid(lqr_obs((5.0, 0.0)))
    assert not handover.pid_in_control
    action = handover(lqr_obs((0.0, 0.0)))
    lqr(lqr_obs((0.0, 0.0)))
    assert handover.pid_in_control
    np.testing.assert_allclose(action, pid(lqr_obs((0.0, 0.0))), atol=1e-6)
    integral = -100 * 0.005 * g.dt  # m·s of the error (target − ball) at 5 mm, within the anti-windup bound
    sin_tilt = g.pid.ki_vel * integral / (g.pid.rolling_factor * 9.80665)
    np.testing.assert_allclose(action, [0.0, math.asin(sin_tilt) / g.max_tilt], atol=1e-6)
    assert abs(action[1]) > 0.01  # the integral is in it
    handover(lqr_obs((10.0, 0.0)))  # beyond the hand-over distance, within the release distance: the PID holds
    lqr(lqr_obs((10.0, 0.0)))
    assert handover.pid_in_control
    np.testing.assert_array_equal(handover(lqr_obs((30.0, 0.0))), lqr(lqr_obs((30.0, 0.0))))
    assert not handover.pid_in_control
    handover.reset()
    moving = lqr_obs((1.0, 0.0))
    moving[6] = 0.2  # the target moves (a tracking task) past a ball at rest: too fast relative to it
    riding = moving.copy()
    riding[2] = riding[6]  # the ball moves with the target (the scales of both velocities are the same)
    batch = np.stack([lqr_obs((1.0, 0.0)), lqr_obs((0.0, 40.0)), moving, riding])
    handover(batch)
    assert handover.pid_in_control.tolist() == [True, False, False, True]


@pytest.mark.slow
def test_with_the_feedforward_the_pid_kalman_and_the_handover_track_a_circle_closer_than_the_lqr() -> None:
    """On the circle (60 mm, 8 s a turn: 47 mm/s) the PID + Kalman, which used to lag the target by 6 mm,
    follows it closer than the LQR (whose hold is looser), and the LQR → PID, which now hands a ball that moves
    with the target to its PID, as close as the PID + Kalman (3 seeds, RMS over the last 5 s)."""
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    rms = {}
    for spec in ("pid-kalman", "lqr", "lqr-pid"):
        _, policy, env_kwargs = load_for_evaluation(spec, "StewartBallTrack-v0")
        rms[spec] = evaluate("StewartBallTrack-v0", policy, episodes=3, seed=0,
                             env_kwargs={**env_kwargs, "trajectory": "circle"})["per_episode"]["rms_mm"]  # fmt: skip
    assert max(rms["pid-kalman"]) < 1.5
    assert all(p < q for p, q in zip(rms["pid-kalman"], rms["lqr"]))
    np.testing.assert_allclose(rms["lqr-pid"], rms["pid-kalman"], atol=0.3)


def test_after_its_dwell_the_handover_gives_a_noisy_near_ball_to_the_pid_whatever_its_observed_speed() -> None:
    """Heavy panel noise keeps the observed speed above ``handover_mm_s``: a ball observed 1 mm from the still
    target at 30 mm/s stays with the LQR until it has been within ``release_mm`` for ``handover_dwell_s``
    (3 s, 150 periods), then the PID holds it; a ball that leaves ``release_mm`` restarts the count; with the
    dwell off (0, the shipped ``lqr-pid``'s) the LQR keeps it; rows count apart. The shipped residual's base
    has the 3 s dwell, in its bundle and in its run configuration alike."""
    from dataclasses import replace

    from stewart_gym.control import HandoverController

    shipped = load_policy("lqr-pid")
    assert isinstance(shipped, HandoverController) and shipped.gains.handover_dwell_s == 0.0
    handover = HandoverController(replace(shipped.gains, handover_dwell_s=3.0))
    periods = round(handover.gains.handover_dwell_s / handover.gains.dt)
    fast = lqr_obs((1.0, 0.0))
    fast[2] = 0.030 / ObservationBuilder(2, (0.15, 0.15)).velocity_scale[0]  # 30 mm/s
    for k in range(periods - 1):
        handover(fast)
        assert not handover.pid_in_control, k
    handover(fast)
    assert handover.pid_in_control
    handover.reset()
    for _ in range(periods - 1):
        handover(fast)
    handover(lqr_obs((25.0, 0.0)))  # beyond release_mm: the count starts again
    for _ in range(periods - 1):
        handover(fast)
    assert not handover.pid_in_control
    handover.reset()
    far = lqr_obs((30.0, 0.0))
    for _ in range(periods):
        handover(np.stack([fast, far]))
    assert handover.pid_in_control.tolist() == [True, False]
    for _ in range(5 * periods):
        shipped(fast)
    assert not shipped.pid_in_control
    bundle = json.loads((SHIPPED_RESIDUAL_RUN.parents[1] / "bundle" / "bundle.json").read_text())
    config = yaml.safe_load((SHIPPED_RESIDUAL_RUN / "config.yaml").read_text())  # one of its networks' runs
    assert config["hyperparams"]["residual"]["design"]["handover_dwell_s"] == 3.0

    def dwells(node: object) -> list[float]:  # every handover_dwell_s in the bundle (its design and its gains)
        if isinstance(node, dict):
            return [v for k, v in node.items() if k == "handover_dwell_s"] + [d for v in node.values() for d in dwells(v)]
        return [d for v in node for d in dwells(v)] if isinstance(node, list) else []

    assert dwells(bundle) == [3.0, 3.0]
    # and its release dwell (0.5 s), in every network's run configuration and in the bundle's base
    for member in SHIPPED_RESIDUAL_RUN.parent.iterdir():
        design = yaml.safe_load((member / "config.yaml").read_text())["hyperparams"]["residual"]["design"]
        assert design["release_dwell_s"] == 0.5, member
    assert bundle["residual"]["base"]["gains"]["release_dwell_s"] == 0.5
    assert load_policy("shipped-residual").base.gains.release_dwell_s == 0.5
    # and its fast release (60 mm/s: a pushed ball goes back to the LQR at once), likewise
    for member in SHIPPED_RESIDUAL_RUN.parent.iterdir():
        design = yaml.safe_load((member / "config.yaml").read_text())["hyperparams"]["residual"]["design"]
        assert design["release_mm_s"] == 60.0, member
    assert bundle["residual"]["base"]["gains"]["release_mm_s"] == 60.0
    assert load_policy("shipped-residual").base.gains.release_mm_s == 60.0
    assert load_policy("shipped-residual", "StewartBallDisturbance-v0").base.gains.release_mm_s == 60.0
    # and its release of a ball pushed within 20 mm (beyond 5 mm, faster than the noise lets it seem), likewise
    for member in SHIPPED_RESIDUAL_RUN.parent.iterdir():
        design = yaml.safe_load((member / "config.yaml").read_text())["hyperparams"]["residual"]["design"]
        assert design["push_release_mm"] == 5.0, member
    assert bundle["residual"]["base"]["gains"]["push_release_mm"] == 5.0
    assert load_policy("shipped-residual", "StewartBallDisturbance-v0").base.gains.push_release_mm == 5.0


def test_with_a_release_dwell_the_handover_keeps_a_ball_observed_briefly_beyond_the_release_distance() -> None:
    """Heavy panel noise throws the filtered position beyond ``release_mm`` now and then while the PID holds the
    ball: with ``release_dwell_s`` (0.5 s, 25 periods) the LQR takes it back only after 25 periods in a row beyond
    it (a period back inside restarts the count); with none (the shipped ``lqr-pid``'s) at the first; a target
    that starts moving does not take it back (the PID follows it); the field is kept by a bundle's gains."""
    from dataclasses import replace

    from stewart_gym.control import HandoverController, controller_from_gains

    shipped = load_policy("lqr-pid")
    assert isinstance(shipped, HandoverController) and shipped.gains.release_dwell_s == 0.0
    handover = HandoverController(replace(shipped.gains, release_dwell_s=0.5))
    periods = round(handover.gains.release_dwell_s / handover.gains.dt)
    near, far = lqr_obs((1.0, 0.0)), lqr_obs((25.0, 0.0))

    assert held_by_pid(handover, [near] + [far] * (periods - 1) + [near] + [far] * periods) == \
        [True] * (1 + periods - 1 + 1 + periods - 1) + [False]  # fmt: skip
    assert held_by_pid(shipped, [near, far, near]) == [True, False, True]  # at once (and back: at rest within 2 mm)
    moving = lqr_obs((1.0, 0.0))
    moving[6] = 0.030 / ObservationBuilder(2, (0.15, 0.15)).velocity_scale[0]  # the target moves at 30 mm/s
    assert held_by_pid(handover, [near, moving]) == [True, True]
    assert held_by_pid(handover, [moving]) == [False]  # …but 30 mm/s relative to the ball is too fast to take it over
    gains = {k: v for k, v in asdict(handover.gains).items()}
    rebuilt = controller_from_gains("handover", gains)
    assert rebuilt.gains.release_dwell_s == 0.5
    assert held_by_pid(rebuilt, [near] + [far] * (periods - 1)) == [True] * periods


def test_with_release_mm_s_the_handover_gives_a_pushed_ball_back_to_the_lqr_at_once() -> None:
    """A push, unlike the noise a release dwell waits out, sends the ball beyond ``release_mm`` fast: with
    ``release_mm_s`` (60 mm/s) the LQR takes back at once a ball beyond 20 mm moving faster than that relative to
    the target, whatever the dwell; a slower one, or a fast one still within 20 mm, waits as before; 0 turns the
    exception off; a bundle's gains keep the field, and a bundle written before it loads with it off."""
    from dataclasses import replace

    from stewart_gym.control import HandoverController, controller_from_gains

    shipped = load_policy("lqr-pid")
    assert isinstance(shipped, HandoverController) and shipped.gains.release_mm_s == 0.0
    dwell = replace(shipped.gains, release_dwell_s=0.5)
    fast_release = HandoverController(replace(dwell, release_mm_s=60.0))
    near = lqr_obs((1.0, 0.0))
    assert held_by_pid(fast_release, [near, moving(25.0, 80.0)]) == [True, False]  # a push: back to the LQR at once
    assert held_by_pid(fast_release, [near, moving(25.0, -80.0)]) == [True, False]  # coming back fast counts too
    assert held_by_pid(fast_release, [near, moving(25.0, 40.0)]) == [True, True]  # slower: the dwell holds it
    assert held_by_pid(fast_release, [near, moving(15.0, 80.0)]) == [True, True]  # fast but within 20 mm: the PID's
    assert held_by_pid(HandoverController(dwell), [near, moving(25.0, 80.0)]) == [True, True]  # 0: no exception
    rows = np.stack([moving(25.0, 80.0), moving(25.0, 40.0)])
    fast_release.reset()
    fast_release(np.stack([near, near]))
    fast_release(rows)
    assert fast_release.pid_in_control.tolist() == [False, True]  # per row
    gains = asdict(fast_release.gains)
    assert held_by_pid(controller_from_gains("handover", gains), [near, moving(25.0, 80.0)]) == [True, False]
    del gains["release_mm_s"]  # a bundle written before the field
    assert controller_from_gains("handover", gains).gains.release_mm_s == 0.0


def test_with_push_release_mm_the_handover_gives_a_ball_pushed_within_the_release_distance_back_to_the_lqr() -> None:
    """A push that leaves the ball within ``release_mm`` (20 mm): with ``push_release_mm`` (8 mm) the LQR takes
    back at once a held ball beyond 8 mm moving faster than ``release_mm_s`` (60 mm/s) and than 3 times the RMS
    speed observed while the PID held it (averaged over about 1 s). A quiet hold (10 mm/s of observed speed):
    80 mm/s is a push; a noisy one (±30 mm/s for 2 s: 28 mm/s RMS so far): 80 mm/s is not, 100 mm/s is.
    Within 8 mm, or slower than 60 mm/s, the PID keeps it; the speed it remembers survives the LQR's turn and
    starts over each episode; 0 turns the rule off; a bundle's gains keep the field, and one written before it
    loads with it off; the design refuses a value not below ``release_mm``."""
    from dataclasses import replace

    from stewart_gym.control import HandoverController, checked_design, controller_from_gains
    from stewart_gym.control.handover import PUSH_SPEED_SIGMAS

    shipped = load_policy("lqr-pid")
    assert isinstance(shipped, HandoverController) and shipped.gains.push_release_mm == 0.0
    base = replace(shipped.gains, release_dwell_s=0.5, release_mm_s=60.0)
    push_release = HandoverController(replace(base, push_release_mm=8.0))
    near = lqr_obs((1.0, 0.0))
    quiet = [near] + [moving(1.0, v) for v in (10.0, -10.0) * 50]  # 2 s held at ±10 mm/s: an RMS of 10
    noisy = [near] + [moving(1.0, v) for v in (30.0, -30.0) * 50]  # ±30 mm/s for 2 s: 28 mm/s (limit 85 mm/s)
    assert PUSH_SPEED_SIGMAS == 3.0
    assert held_by_pid(push_release, [*quiet, moving(12.0, 80.0)])[-1] is False  # a push: back to the LQR at once
    assert held_by_pid(push_release, [*quiet, moving(12.0, -80.0)])[-1] is False  # either way
    assert held_by_pid(push_release, [*quiet, moving(12.0, 50.0)])[-1] is True  # below release_mm_s
    assert held_by_pid(push_release, [*quiet, moving(6.0, 80.0)])[-1] is True  # within 8 mm
    assert held_by_pid(push_release, [*noisy, moving(12.0, 80.0)])[-1] is True  # what this noise lets it seem
    assert held_by_pid(push_release, [*noisy, moving(12.0, 100.0)])[-1] is False
    assert held_by_pid(HandoverController(base), [*quiet, moving(12.0, 80.0)])[-1] is True  # 0: off
    # the noisy hold's speed is remembered through the LQR's turn (the ball pushed beyond 20 mm and brought back)
    turn = [moving(25.0, 100.0), near, near]
    assert held_by_pid(push_release, [*noisy, *turn, moving(12.0, 80.0)])[-4:] == [False, True, True, True]
    push_release.reset()  # …and starts over from handover_mm_s (10 mm/s) each episode: 60 mm/s is the limit then
    assert held_by_pid(push_release, [near, moving(12.0, 70.0)]) == [True, False]
    gains = asdict(push_release.gains)
    assert held_by_pid(controller_from_gains("handover", gains), [*quiet, moving(12.0, 80.0)])[-1] is False
    del gains["push_release_mm"]  # a bundle written before the field
    assert controller_from_gains("handover", gains).gains.push_release_mm == 0.0
    design = json.loads((Path(__file__).resolve().parents[2] / "stewart_gym/policies/lqr_pid.json").read_text())
    assert checked_design({**design, "push_release_mm": 8}, "handover").push_release_mm == 8.0
    assert checked_design(design, "handover").push_release_mm == 0.0  # off unless given
    for bad, match in (({**design, "push_release_mm": 20.0}, "less than release_mm"),
                       ({**design, "push_release_mm": -8}, "positive"), ({**design, "push_release_mm": "8"}, "positive")):
        with pytest.raises(ValueError, match=match):
            checked_design(bad, "handover")


def test_the_handover_design_is_the_shipped_lqr_and_pid_kalman_and_is_checked() -> None:
    """``policies/lqr_pid.json`` holds today's ``lqr.json`` and ``pid_kalman_gains.json`` (no stale copy), but
    for the LQR's feed-forward lead, which it leaves off (there the PID follows a moving target; with the
    LQR's lead the LQR → PID tracked the same: 50 tuning seeds, a tie), and a malformed hand-over design is
    refused saying what is wrong."""
    from stewart_gym.control import checked_design

    policies = Path(__file__).resolve().parents[2] / "stewart_gym/policies"
    design = json.loads((policies / "lqr_pid.json").read_text())
    lqr = json.loads((policies / "lqr.json").read_text())
    assert lqr.pop("feed_lead") > 0 and design["lqr"] == lqr
    pid_kalman = json.loads((policies / "pid_kalman_gains.json").read_text())
    assert pid_kalman.pop("estimator") == "kalman" and design["pid"] == pid_kalman
    assert checked_design({**design, "handover_dwell_s": 0}, "handover").handover_dwell_s == 0.0  # 0: off
    assert checked_design({**design, "release_dwell_s": 0.5}, "handover").release_dwell_s == 0.5
    assert checked_design({**design, "release_mm_s": 60}, "handover").release_mm_s == 60.0
    assert checked_design(design, "handover").release_mm_s == 0.0  # off unless given
    for bad, match in (({**design, "release_mm": 1.0}, "release_mm"), ({"lqr": design["lqr"]}, "missing pid"),
                       ({**design, "handover_mm_s": -1}, "positive"), ({**design, "handover_dwell_s": -0.5}, "positive"),
                       ({**design, "handover_dwell_s": float("nan")}, "positive"),
                       ({**design, "release_dwell_s": -0.5}, "positive"), ({**design, "release_dwell_s": True}, "positive"),
                       ({**design, "release_mm_s": -60}, "positive"), ({**design, "release_mm_s": float("inf")}, "positive"),
                       ({**design, "pid": {**design["pid"], "kp_pos": "x"}}, "handover: gains must be finite")):
        with pytest.raises(ValueError, match=match):
            checked_design(bad, "handover")


@pytest.mark.slow
def test_the_handover_settles_like_the_lqr_and_its_bundle_acts_as_it(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """10 randomised seeds: all succeed, the ball ends within 3 mm, settles from 100 mm in under 0.75 s (the
    LQR's pace); the exported bundle (CLI) gives the same actions through hand-overs and records the Kalman
    observer."""
    from stewart_gym.evaluation import evaluate

    metrics = evaluate("StewartBallBalance-v0", load_policy("lqr-pid"), episodes=10, seed=100,
                       env_kwargs={"estimator": "kalman"})  # fmt: skip
    assert metrics["success_rate"] == 1.0 and metrics["final_error_mm"] < 3.0, metrics
    assert metrics["settled_fraction"] == 1.0 and metrics["settling_time_s"] < 0.75, metrics
    out = tmp_path / "lqr_pid"
    proc = sg_in(capfd, "export", "--policy", "lqr-pid", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((out / "bundle.json").read_text())
    assert meta["kind"] == "handover" and meta["estimator"] == "kalman" and meta["gains"]["handover_mm"] == 2.0
    assert meta["gains"]["handover_dwell_s"] == 0.0
    bundle, direct = deployable_policy(resolve_policy(str(out))), load_policy("lqr-pid")
    rng = np.random.default_rng(4)
    held = 0
    for _ in range(80):
        obs = lqr_obs(tuple(rng.uniform(-25, 25, 2) * rng.choice([0.05, 1.0])))
        obs[2:4] = rng.uniform(-0.02, 0.02, 2)
        np.testing.assert_allclose(bundle(obs), direct(obs), atol=1e-6)
        held += bool(direct.pid_in_control)
    assert 0 < held < 80  # both controllers acted
