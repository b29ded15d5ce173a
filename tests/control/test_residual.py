"""Residual policies: the learned correction added to a classical base, its fade and latch, in evaluation and
in bundles, and the base a run records."""


import json
import math
import shutil
from dataclasses import asdict
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from conftest import sg_in

from stewart_gym.control import shipped_design
from stewart_gym.registry import deployable_policy, load_policy, resolve_policy
from stewart_gym.training import load_hyperparams

#: The run folder of one of the shipped balance residual's six networks (seed 0)
SHIPPED_RESIDUAL_RUN = Path(__file__).resolve().parents[2] / "stewart_gym/policies/balance_residual/members/0"


@pytest.mark.slow
def test_a_residual_policy_adds_its_correction_to_the_lqr_pid_in_evaluation_and_in_its_bundle(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """Train a residual PPO (the track settings) for a moment (CLI), then: the evaluated policy is
    clip(LQR → PID + 0.5 · w · network), with w = clip((distance − 2 mm) / 15 mm, 0, 1) and 0 from the first
    step within 2 mm until the ball is beyond 20 mm (the LQR → PID stepped alongside on the same observations),
    the bundle gives the same actions with numpy + onnxruntime, and records the LQR → PID, the fade, the latch
    and the Kalman observer."""
    from stewart_gym.sb3_models import load_sb3

    run, bundle_dir = tmp_path / "run", tmp_path / "bundle"
    hp = Path(__file__).resolve().parents[2] / "stewart_gym/hyperparams/ppo_residual.yml"
    for args in (["train", "--env", "StewartBallTrack-v0", "--hyperparams", str(hp), "--run-dir", str(run),
                  "--timesteps", "1024", "--n-envs", "1",
                  "--eval-freq", "1024", "--eval-episodes", "1", "--no-progress", "--no-tensorboard"],
                 ["export", "--policy", str(run), "--out", str(bundle_dir)]):  # fmt: skip
        proc = sg_in(capfd, *args)
        assert proc.returncode == 0, proc.stderr[-2000:]
    meta = json.loads((bundle_dir / "bundle.json").read_text())
    assert meta["estimator"] == "kalman" and meta["residual"]["scale"] == 0.5 and meta["residual"]["fade_mm"] == 15
    assert meta["residual"]["inner_mm"] == 2 and meta["residual"]["release_mm"] == 20
    recorded = yaml.safe_load((run / "config.yaml").read_text())["hyperparams"]["residual"]["design"]
    assert recorded == asdict(shipped_design("lqr-pid"))  # the base as it was trained over
    assert meta["residual"]["base"]["kind"] == "handover"
    policy, bundle = load_policy(str(run)), deployable_policy(resolve_policy(str(bundle_dir)))
    network, base = load_sb3(run), load_policy("lqr-pid")
    rng = np.random.default_rng(1)
    latched, weights = False, []
    for k in range(60):
        obs = rng.uniform(-0.6, 0.6, 12).astype(np.float32)
        if k % 3 == 1:
            obs[4:6] = obs[0:2] + rng.uniform(-0.08, 0.08, 2)  # within 12 mm of the target: the fade acts
        if k % 20 == 5:
            obs[4:6] = obs[0:2] + 0.005  # within 2 mm: the latch closes until the ball is beyond 20 mm
        action, _ = policy.predict(obs, episode_start=np.array([k == 0]))
        distance_mm = 150 * np.hypot(*(obs[0:2] - obs[4:6]))  # observations are in plate half-widths (150 mm)
        latched = (latched or distance_mm < 2) and not distance_mm > 20
        weights.append(0.0 if latched else float(np.clip((distance_mm - 2) / 15, 0, 1)))
        by_base = base.predict(obs, episode_start=np.array([k == 0]))[0]
        expected = np.clip(by_base + 0.5 * weights[-1] * network.predict(obs)[0], -1, 1)
        np.testing.assert_allclose(action, expected, atol=1e-5)
        np.testing.assert_allclose(bundle.predict(obs, episode_start=np.array([k == 0]))[0], action, atol=1e-4)
    assert sum(w == 0 for w in weights) >= 3 and sum(0 < w < 1 for w in weights) >= 3  # both the latch and the fade


def test_the_shipped_balance_residual_is_the_lqr_pid_near_the_target_and_its_bundle_agrees() -> None:
    """The shipped balance residual: within 5 mm of the target its action is the LQR → PID's exactly (the same
    integrator and hand-over history), beyond 15 mm the network's correction acts, and its bundle gives the
    same."""
    source = resolve_policy("shipped-residual")
    assert source.env_kwargs["residual"]["base"] == "lqr-pid" and source.env_kwargs["residual"]["inner_mm"] == 5
    rng = np.random.default_rng(3)
    for within_mm, same in ((4.0, True), (40.0, False)):
        residual, pid, bundle = load_policy(source), load_policy("lqr-pid"), deployable_policy(source)
        differs = 0.0
        for k in range(30):
            obs = rng.uniform(-0.2, 0.2, 12).astype(np.float32)
            direction = rng.uniform(0, 2 * math.pi)
            obs[0:2] = obs[4:6] + within_mm / 150 * np.array([math.cos(direction), math.sin(direction)])
            start = np.array([k == 0])
            action = residual.predict(obs, episode_start=start)[0]
            base = pid.predict(obs, episode_start=start)[0]
            np.testing.assert_allclose(bundle(obs), action, atol=1e-4)
            differs = max(differs, float(np.abs(np.asarray(action) - base).max()))
        assert (differs == 0.0) if same else (differs > 1e-3), (within_mm, differs)


@pytest.mark.slow
def test_a_trained_residual_keeps_the_base_design_its_run_recorded(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """A run folder's residual adds to the base gains its config.yaml recorded, not to whatever the package ships
    now (a later retune of the shipped PID must not change a trained policy); its bundle records the same."""
    from dataclasses import replace

    run = tmp_path / "run"
    shutil.copytree(SHIPPED_RESIDUAL_RUN, run)
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    from stewart_gym.control import checked_design

    recorded = checked_design(cfg["hyperparams"]["residual"]["design"], "handover")
    recipe = load_hyperparams("ppo", "StewartBallBalance-v0", "ppo_residual")["residual"]["design"]
    assert recipe == {"handover_dwell_s": 3.0, "release_dwell_s": 0.5, "release_mm_s": 60.0, "push_release_mm": 5.0}
    assert recorded == replace(shipped_design("lqr-pid"), **recipe)  # the recipe's changes, and only those
    cfg["hyperparams"]["residual"]["design"]["pid"]["kp_pos"] = 1.25
    (run / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    assert load_policy(str(run)).base.gains.pid.kp_pos == 1.25
    assert load_policy("shipped-residual").base.gains.pid.kp_pos == shipped_design("lqr-pid").pid.kp_pos != 1.25
    proc = sg_in(capfd, "export", "--policy", str(run), "--out", str(tmp_path / "bundle"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    meta = json.loads((tmp_path / "bundle" / "bundle.json").read_text())
    assert meta["residual"]["base"]["gains"]["pid"]["kp_pos"] == 1.25


@pytest.mark.parametrize(("distance_mm", "inner_mm", "fade_mm", "weight"),
                         [(3.0, 5.0, 10.0, 0.0), (10.0, 5.0, 10.0, 0.5), (20.0, 5.0, 10.0, 1.0), (7.5, 0.0, 15.0, 0.5),
                          (4.0, 5.0, 0.0, 0.0), (6.0, 5.0, 0.0, 1.0), (0.1, 0.0, 0.0, 1.0)])  # fmt: skip
def test_the_residual_weight_is_zero_inside_the_inner_radius_and_fades_in_beyond(distance_mm: float, inner_mm: float,
                                                                                 fade_mm: float, weight: float) -> None:
    from stewart_gym.control import residual_action

    obs = np.zeros(12)
    obs[0] = distance_mm / 150.0  # plate half-widths of 150 mm; the target at the centre
    base, correction = np.array([0.1, -0.2]), np.array([0.4, 0.4])
    got = residual_action(base, correction, obs, 0.5, (0.15, 0.15), fade_mm, inner_mm)
    np.testing.assert_allclose(got, base + 0.5 * weight * correction, atol=1e-6)


def test_the_latch_keeps_the_correction_off_from_the_inner_radius_until_the_release_distance() -> None:
    """With release_mm, the correction is off from the first step within inner_mm until the ball is farther than
    release_mm (the fade alone would let it back in at inner_mm); a reset reopens it; without, the fade alone."""
    from stewart_gym.control import ResidualMix

    base, correction = np.array([0.1, -0.2]), np.array([0.4, 0.4])
    distances = [30.0, 12.0, 4.0, 8.0, 12.0, 19.0, 25.0, 12.0]
    latched = [1.0, 0.7, 0.0, 0.0, 0.0, 0.0, 1.0, 0.7]  # inner 5 mm, fade 10 mm, release 20 mm
    faded = [1.0, 0.7, 0.0, 0.3, 0.7, 1.0, 1.0, 0.7]
    for release_mm, weights in ((20.0, latched), (0.0, faded)):
        mix = ResidualMix(0.5, (0.15, 0.15), fade_mm=10.0, inner_mm=5.0, release_mm=release_mm)
        for episode in range(2):  # the second after a reset: the same
            mix.reset()
            for distance_mm, weight in zip(distances, weights):
                obs = np.zeros(12)
                obs[1], obs[5] = 0.2 + distance_mm / 150.0, 0.2  # the target off the centre, the ball beyond it
                np.testing.assert_allclose(mix(base, correction, obs), base + 0.5 * weight * correction, atol=1e-6,
                                           err_msg=f"release {release_mm}, {distance_mm} mm, episode {episode}")
    rows = ResidualMix(0.5, (0.15, 0.15), fade_mm=10.0, inner_mm=5.0, release_mm=20.0)  # one latch per row
    obs = np.zeros((2, 12))
    obs[:, 0] = [4.0 / 150, 30.0 / 150]
    rows(np.zeros((2, 2)), np.ones((2, 2)), obs)
    obs[:, 0] = 8.0 / 150
    np.testing.assert_allclose(rows(np.zeros((2, 2)), np.ones((2, 2)), obs), [[0.0, 0.0], [0.15, 0.15]], atol=1e-6)
    with pytest.raises(ValueError, match="release_mm"):
        ResidualMix(0.5, (0.15, 0.15), inner_mm=5.0, release_mm=3.0)


def test_the_latch_dwell_closes_the_latch_after_that_long_within_the_release_distance() -> None:
    """With dwell_s, a ball that stays within release_mm (never within inner_mm) has the correction cut from its
    ceil(dwell_s / dt)-th period there until it is beyond release_mm; leaving release_mm restarts the count, as
    does a reset; one count per row; a dwell without a latch, or a negative or non-finite one, is refused."""
    from stewart_gym.control import ResidualMix

    def obs_at(distance_mm: float | list[float]) -> np.ndarray:
        d = np.atleast_1d(np.asarray(distance_mm, dtype=float))
        o = np.zeros((d.size, 12))
        o[:, 0] = d / 150.0
        return o if d.size > 1 else o[0]

    base, correction = np.array([0.1, -0.2]), np.array([0.4, 0.4])
    mix = ResidualMix(0.5, (0.15, 0.15), fade_mm=10.0, inner_mm=2.0, release_mm=20.0, dwell_s=0.1, dt=0.02)  # 5
    for episode in range(2):
        mix.reset()
        sent = [mix(base, correction, obs_at(d)) for d in [15.0, 12.0, 25.0] + [12.0] * 6 + [15.0, 21.0, 12.0]]
        on = [not np.allclose(a, base) for a in sent]
        #   15 12 | 25 (count restarts) | 12 ×4 on, the 5th in a row closes it | 15 still off | 21 reopens | 12 on
        assert on == [True, True, True, True, True, True, True, False, False, False, True, True], (episode, on)
    rows = ResidualMix(0.5, (0.15, 0.15), fade_mm=10.0, inner_mm=2.0, release_mm=20.0, dwell_s=0.04, dt=0.02)
    for d in ([12.0, 30.0], [12.0, 12.0]):
        out = rows(np.zeros((2, 2)), np.ones((2, 2)), obs_at(d))
    np.testing.assert_allclose(out, [[0.0, 0.0], [0.5, 0.5]], atol=1e-6)  # row 0 two periods inside: cut
    without = ResidualMix(0.5, (0.15, 0.15), fade_mm=10.0, inner_mm=2.0, release_mm=20.0)
    assert all(not np.allclose(without(base, correction, obs_at(12.0)), base) for _ in range(200))
    for bad in ({"dwell_s": 1.0}, {"release_mm": 20.0, "dwell_s": -1.0}, {"release_mm": 20.0, "dwell_s": math.nan},
                {"release_mm": 20.0, "dwell_s": math.inf}):  # fmt: skip
        with pytest.raises(ValueError, match="dwell_s"):
            ResidualMix(0.5, (0.15, 0.15), inner_mm=2.0, **bad)


@pytest.mark.slow
def test_a_one_network_tracker_circling_short_of_the_target_is_brought_in_by_the_latch_dwell(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """A track network trained over the LQR (``tests/data/circling_tracker``: network 5 of the track residual
    shipped until 2026-11-25), alone, keeps the ball circling 6–17 mm from the circle's target on seed 17 (its
    correction never lets the ball within 2 mm, so the latch never closes). Its run folder with
    ``dwell_s: 3`` added to the residual it records: the LQR alone takes over after 3 s within 20 mm and tracks
    within 2 mm RMS over the last 5 s, where without it the error stays above 5 mm (the circling is an
    attractor: observations perturbed by 1e-6 end in it too); the bundle exported from it records the dwell and
    sends the same actions."""
    from stewart_gym.evaluation import run_episode
    from stewart_gym.registry import load_for_evaluation
    from stewart_gym.sb3_models import check_residual, residual_base

    member = Path(__file__).resolve().parents[1] / "data" / "circling_tracker"
    run = tmp_path / "run"
    shutil.copytree(member, run)
    config = yaml.safe_load((run / "config.yaml").read_text())
    assert "dwell_s" not in config["hyperparams"]["residual"]
    config["hyperparams"]["residual"]["dwell_s"] = 3.0
    (run / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    tails = {}
    for label, folder in (("alone", member), ("dwell", run)):
        source, policy, env_kwargs = load_for_evaluation(str(folder), "StewartBallTrack-v0")
        env = gym.make("StewartBallTrack-v0", randomize=True, **{**env_kwargs, "trajectory": "circle"})
        log = run_episode(env, policy, 17)
        tails[label] = float(np.sqrt(np.mean(np.square(log.distance_mm[-250:]))))
        env.close()
    assert tails["alone"] > 5.0 and tails["dwell"] < 2.0, tails  # here 12.0 and 0.8 (10.4 and 0.8 with 1e-6 noise)
    proc = sg_in(capfd, "export", "--policy", str(run), "--out", str(tmp_path / "bundle"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((tmp_path / "bundle" / "bundle.json").read_text())["residual"]["dwell_s"] == 3.0
    policy, bundle = load_policy(str(run)), deployable_policy(resolve_policy(str(tmp_path / "bundle")))
    lqr = residual_base(check_residual(config["hyperparams"]["residual"], recorded=True))  # the base alongside
    obs = np.zeros(12, dtype=np.float32)
    obs[4] = 0.1  # a still target 15 mm from the ball
    for k in range(160):  # inside 20 mm from the first period: the 150th closes the latch
        start = np.array([k == 0])
        action = policy.predict(obs, episode_start=start)[0]
        by_lqr = lqr.predict(obs, episode_start=start)[0]
        np.testing.assert_allclose(bundle.predict(obs, episode_start=start)[0], action, atol=1e-4)
        assert (np.abs(action - by_lqr).max() > 1e-3) == (k < 149), k


@pytest.mark.slow
def test_a_residual_run_at_another_control_rate_runs_its_base_and_latch_at_that_rate(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """A residual run recorded at 25 Hz (control_hz in its env keywords): evaluation designs its LQR base for
    0.04 s and times its latch dwell in 0.04 s periods, as training did, and so does its exported bundle."""
    from stewart_gym.registry import POLICY_DIR

    run = tmp_path / "run"
    shutil.copytree(POLICY_DIR / "track_residual" / "members" / "0", run)
    config = yaml.safe_load((run / "config.yaml").read_text())
    config["hyperparams"]["env_kwargs"] = {**config["hyperparams"]["env_kwargs"], "control_hz": 25}
    config["hyperparams"]["residual"]["dwell_s"] = 3.0
    (run / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    source = resolve_policy(str(run))
    assert source.env_kwargs["control_hz"] == 25
    policy = load_policy(source)
    assert policy.base.gains.dt == pytest.approx(0.04) and policy.mix.dt == pytest.approx(0.04)
    proc = sg_in(capfd, "export", "--policy", str(run), "--out", str(tmp_path / "bundle"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    meta = json.loads((tmp_path / "bundle" / "bundle.json").read_text())
    assert meta["control_hz"] == 25 and meta["residual"]["base"]["gains"]["dt"] == pytest.approx(0.04)
    bundle = deployable_policy(resolve_policy(str(tmp_path / "bundle")))
    rng = np.random.default_rng(3)
    for k in range(20):
        obs = rng.uniform(-0.3, 0.3, 12).astype(np.float32)
        start = np.array([k == 0])
        np.testing.assert_allclose(bundle.predict(obs, episode_start=start)[0],
                                   policy.predict(obs, episode_start=start)[0], atol=1e-4)  # fmt: skip


def test_the_shipped_balance_residual_latches_its_correction_off_in_evaluation_and_in_its_bundle() -> None:
    """The shipped balance residual (release_mm 20): after the ball has been within 5 mm, at 8 mm its action is
    the LQR → PID's exactly (the fade alone would add 0.3 of the correction), until it is beyond 20 mm; its
    bundle sends the same throughout."""
    source = resolve_policy("shipped-residual")
    assert source.env_kwargs["residual"]["release_mm"] == 20
    residual, base, bundle = load_policy(source), load_policy("lqr-pid"), deployable_policy(source)
    rng = np.random.default_rng(5)
    target = rng.uniform(-0.2, 0.2, 2)
    for k, (distance_mm, same) in enumerate([(40.0, False), (4.0, True), (8.0, True), (12.0, True), (30.0, False),
                                             (8.0, False)]):  # fmt: skip
        obs = rng.uniform(-0.2, 0.2, 12).astype(np.float32)
        direction = rng.uniform(0, 2 * math.pi)
        obs[4:6] = target
        obs[0:2] = target + distance_mm / 150 * np.array([math.cos(direction), math.sin(direction)])
        start = np.array([k == 0])
        action, by_base = residual.predict(obs, episode_start=start)[0], base.predict(obs, episode_start=start)[0]
        np.testing.assert_allclose(bundle.predict(obs, episode_start=start)[0], action, atol=1e-4)
        differs = float(np.abs(np.asarray(action) - by_base).max())
        assert (differs == 0.0) if same else (differs > 1e-3), (k, distance_mm, differs)


@pytest.mark.parametrize(("spec", "match"), [({"base": "mpc"}, "base: lqr|pid|pid-kalman"),
                                             ({"base": "lqr", "gain": 1}, "base: lqr"),
                                             ({"base": "lqr", "scale": 0}, "scale"),
                                             ({"base": "lqr", "fade_mm": -1}, "fade_mm"),
                                             ({"base": "pid", "inner_mm": float("nan")}, "inner_mm"),
                                             ({"base": "pid", "inner_mm": True}, "inner_mm"),
                                             ({"base": "lqr-pid", "inner_mm": 5, "release_mm": 5}, "release_mm"),
                                             ({"base": "lqr", "release_mm": 20}, "release_mm"),
                                             ({"base": "lqr", "inner_mm": 5, "release_mm": -1}, "release_mm"),
                                             ({"base": "lqr", "inner_mm": 5, "release_mm": float("inf")}, "release_mm"),
                                             ({"base": "lqr", "inner_mm": 5, "dwell_s": 3}, "dwell_s"),
                                             ({"base": "lqr", "inner_mm": 2, "release_mm": 20, "dwell_s": -3}, "dwell_s"),
                                             ({"base": "lqr", "inner_mm": 2, "release_mm": 20, "dwell_s": "3 s"}, "dwell_s"),
                                             ({"base": "pid", "design": {"kp_pos": float("nan")}}, "design.*finite"),
                                             ({"base": "lqr", "design": {"kp_pos": 2.0}}, "unknown.*'kp_pos'.*LQR"),
                                             ({"base": "lqr", "design": {"tilt": -0.1}}, "design.*positive")])  # fmt: skip
def test_a_malformed_residual_is_refused_naming_the_key(spec: dict, match: str) -> None:
    from stewart_gym.errors import ConfigError
    from stewart_gym.sb3_models import check_residual

    with pytest.raises(ConfigError, match=match):
        check_residual(spec)
    assert check_residual({"base": "pid-kalman", "inner_mm": 5})["inner_mm"] == 5.0


def test_a_residual_design_replaces_only_the_fields_it_gives() -> None:
    """``design: {handover_dwell_s: 3}`` (the balance recipe's) is the shipped LQR → PID with that one field
    changed; a run's recorded design is taken whole (a field added since is off); a bad value in it, or a design
    that is not a mapping, is refused naming the base."""
    from dataclasses import asdict, replace

    from stewart_gym.errors import ConfigError
    from stewart_gym.sb3_models import check_residual

    spec = check_residual({"base": "lqr-pid", "design": {"handover_dwell_s": 3}})
    assert spec["design"] == asdict(replace(shipped_design("lqr-pid"), handover_dwell_s=3.0))
    recipe = load_hyperparams("ppo", "StewartBallBalance-v0", "ppo_residual")["residual"]
    assert check_residual(recipe)["design"]["handover_dwell_s"] == 3.0
    # a run's recorded design is whole as it trained: a field added since stays off, not the shipped value
    run = yaml.safe_load((Path(__file__).resolve().parents[1] / "data/circling_tracker/config.yaml").read_text())
    recorded = run["hyperparams"]["residual"]
    assert recorded["base"] == "lqr" and "feed_lead" not in recorded["design"]
    assert check_residual(recorded, recorded=True)["design"] == {**recorded["design"], "feed_lead": 0.0}
    assert check_residual(recorded)["design"]["feed_lead"] == shipped_design("lqr").feed_lead > 0
    for bad in ({"handover_dwell_s": -1}, [3.0]):
        with pytest.raises(ConfigError, match="lqr-pid base"):
            check_residual({"base": "lqr-pid", "design": bad})
