"""Any platform, end to end: a user's own geometry TOML through train, export, calibrate and deploy (the real CLI),
its plate in the env, bundles that know their build, refusals, and the PID on every ball preset."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from conftest import Board, FakeDevice, cli, maestro_frames, sg, sg_in

from stewart_gym.calibration import ServoCalibration
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.presets import load_preset


def my_build(tmp_path: Path) -> Path:
    """A user's TOML: the desk-rect build under another name, with a 350 × 250 mm plate."""
    text = load_preset("desk-rect").to_toml().replace('name = "desk-rect"', 'name = "my-build"')
    text = text.replace("plate_size = [0.4, 0.26]", "plate_size = [0.35, 0.25]")
    path = tmp_path / "my_build.toml"
    path.write_text(text)
    return path


def test_the_env_follows_the_plate_of_the_geometry(tmp_path: Path) -> None:
    env = gym.make("StewartBallBalance-v0", geometry=str(my_build(tmp_path)))
    try:
        u = env.unwrapped
        assert u.plate_half_extent == (0.175, 0.125)
        obs, _ = env.reset(seed=0, options={"ball_position": (0.07, -0.05), "ball_velocity": (0.0, 0.0)})
        assert obs[0] == pytest.approx(0.07 / 0.175, abs=0.05) and obs[1] == pytest.approx(-0.05 / 0.125, abs=0.05)
        from stewart_gym.errors import ConfigError

        with pytest.raises(ConfigError, match="off the plate"):  # within the 350 mm width, beyond the 250 mm depth
            env.reset(options={"ball_position": (0.0, 0.14)})
        env.reset(seed=1, options={"ball_position": (0.0, 0.10), "ball_velocity": (0.0, 0.6)})
        for _ in range(50):
            _, _, terminated, _, info = env.step(np.zeros(2, dtype=np.float32))
            if terminated:
                break
        assert terminated and 0.125 < abs(info["ball_xy_m"][1]) < 0.175  # off the short side, inside the long one
    finally:
        env.close()


@pytest.mark.slow
def test_custom_geometry_train_export_calibrate_deploy(tmp_path: Path, device: FakeDevice,
                                                       capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """Through the real CLI: the frames sent are the IK pulses of the user's geometry, not the reference's."""
    geo_path = my_build(tmp_path)
    hp = tmp_path / "hp.yml"
    hp.write_text("StewartBallBalance-v0:\n  n_envs: 2\n  n_timesteps: 128\n  normalize: true\n  policy: MlpPolicy\n"
                  "  n_steps: 64\n  batch_size: 32\n  n_epochs: 1\n  policy_kwargs:\n    net_arch: [16, 16]\n")  # fmt: skip
    run = sg_in(capfd, "train", "--geometry", str(geo_path), "--hyperparams", str(hp), "--run-dir", str(tmp_path / "run"),
             "--eval-freq", "64", "--eval-episodes", "1", "--no-progress", "--no-tensorboard", cwd=tmp_path)  # fmt: skip
    assert run.returncode == 0, run.stderr
    exported = sg_in(capfd, "export", "--policy", str(tmp_path / "run"), "--out", str(tmp_path / "b"), cwd=tmp_path)
    assert exported.returncode == 0, exported.stderr
    meta = json.loads((tmp_path / "b" / "bundle.json").read_text())
    assert meta["geometry"]["name"] == "my-build" and "plate_size = [0.35, 0.25]" in meta["geometry"]["toml"]
    assert meta["observation_layout"] >= 2 and meta["control_hz"] == 50

    drain = Board(device)
    cal = sg("calibrate", "--geometry", str(geo_path), "--port", device.path, "--protocol", "maestro", "--out",
             str(tmp_path / "cal.toml"), stdin="+\nq\n", cwd=tmp_path)  # fmt: skip
    assert cal.returncode == 0, cal.stderr
    drain.stop()
    drain = Board(device)
    dep = sg("deploy", "--policy", str(tmp_path / "b"), "--calibration", str(tmp_path / "cal.toml"), "--sensor", "sim",
             "--duration", "1", "--log", str(tmp_path / "log.csv"), cwd=tmp_path)  # fmt: skip
    data = drain.stop()
    assert dep.returncode == 0, dep.stdout + dep.stderr
    rows = list(csv.DictReader((tmp_path / "log.csv").open()))
    calibration = ServoCalibration.from_toml(tmp_path / "cal.toml", str(geo_path))
    mine, reference = ServoCalibration.default(load_preset("servo-hexapod")), load_preset("servo-hexapod")
    checked = 0
    for r in rows:
        if any(int(r[k]) for k in ("held", "rate_limited", "homing", "stale", "unreachable")):
            continue
        pose = np.array([float(r[k]) for k in ("x_m", "y_m", "z_m", "roll", "pitch", "yaw")])
        sent = np.array([float(r[f"pulse{i}_us"]) for i in range(6)])
        expected = calibration.pulse_widths(inverse_kinematics(load_preset("desk-rect"), pose).servo_angles)
        assert np.allclose(sent, expected, atol=0.01)
        other = mine.pulse_widths(inverse_kinematics(reference, pose).servo_angles, out_of_range="nan")
        assert not np.allclose(sent, other, atol=1.0)  # the reference build would get other pulses
        checked += 1
    assert checked >= 5
    wire = maestro_frames(data)
    logged = np.array([[float(r[f"pulse{i}_us"]) for i in range(6)] for r in rows])
    assert np.allclose(wire[: len(logged)], np.round(logged * 4) / 4, atol=0.01)  # what was logged went on the wire


@pytest.mark.slow
def test_a_linear_build_calibrates_and_deploys(tmp_path: Path, device: FakeDevice, capfd: pytest.CaptureFixture) -> None:
    """senilov2018 (RC linear actuators) through the real CLI: calibrate with scripted keys, export the PID, deploy
    with the calibration; the frames are the trimmed pulses of the IK leg lengths."""
    drain = Board(device)
    cal = sg("calibrate", "--geometry", "senilov2018", "--port", device.path, "--protocol", "maestro", "--out",
             str(tmp_path / "cal.toml"), "--step", "2", stdin="+\n+\nn\n-\nq\n", cwd=tmp_path)  # fmt: skip
    drain.stop()
    assert cal.returncode == 0, cal.stderr
    text = (tmp_path / "cal.toml").read_text()
    assert 'actuator = "linear"' in text and 'geometry = "senilov2018"' in text
    calibration = ServoCalibration.from_toml(tmp_path / "cal.toml")
    nominal = ServoCalibration.linear("senilov2018")
    assert calibration.actuator == "linear"
    assert np.allclose(calibration.neutral_us - nominal.neutral_us, [4, -2, 0, 0, 0, 0], atol=1e-6)
    assert sg_in(capfd, "export", "--policy", "pid", "--geometry", "senilov2018", "--out", str(tmp_path / "pid"),
              cwd=tmp_path).returncode == 0  # fmt: skip
    drain = Board(device)
    dep = sg("deploy", "--policy", str(tmp_path / "pid"), "--calibration", str(tmp_path / "cal.toml"), "--sensor",
             "sim", "--duration", "1", "--log", str(tmp_path / "log.csv"), cwd=tmp_path)  # fmt: skip
    data = drain.stop()
    assert dep.returncode == 0, dep.stdout + dep.stderr
    geo = load_preset("senilov2018")
    checked = 0
    rows = list(csv.DictReader((tmp_path / "log.csv").open()))
    for r in rows:
        if any(int(r[k]) for k in ("held", "rate_limited", "homing", "stale", "unreachable")):
            continue
        pose = np.array([float(r[k]) for k in ("x_m", "y_m", "z_m", "roll", "pitch", "yaw")])
        sent = np.array([float(r[f"pulse{i}_us"]) for i in range(6)])
        assert np.allclose(sent, calibration.pulse_widths(inverse_kinematics(geo, pose).leg_lengths), atol=0.01)
        checked += 1
    assert checked >= 5
    wire = maestro_frames(data)
    logged = np.array([[float(r[f"pulse{i}_us"]) for i in range(6)] for r in rows])
    assert np.allclose(wire[: len(logged)], np.round(logged * 4) / 4, atol=0.01)


def test_linear_calibration_files_round_trip_and_name_their_mistakes(tmp_path: Path) -> None:
    from stewart_gym.calibration import CalibrationError

    cal = ServoCalibration.linear("senilov2018", trims_us=np.array([3.0, -2.0, 0.0, 0.0, 1.5, 0.25]))
    path = tmp_path / "lin.toml"
    path.write_text('geometry = "senilov2018"\n' + cal.to_toml("senilov2018"))
    assert ServoCalibration.from_toml(path) == cal
    for old, new, field in [
        ("retracted_us = 1000.0", "retracted_us = 2500.0", "retracted_us"),
        ("home_length_mm", "home_angle_deg", r"servo\[0\]"),
        ('actuator = "linear"', 'actuator = "rotary"', "actuator"),
    ]:
        path.write_text('geometry = "senilov2018"\n' + cal.to_toml("senilov2018").replace(old, new, 1))
        with pytest.raises(CalibrationError, match=field):
            ServoCalibration.from_toml(path)
    with pytest.raises(CalibrationError, match="geometry"):
        cal.to_toml()  # a linear file needs the stroke it refers to
    with pytest.raises(CalibrationError, match="rotary"):
        cal.to_toml("servo-hexapod")


def test_a_bundle_and_a_calibration_for_different_builds_are_refused(tmp_path: Path, device: FakeDevice,
                                                                     capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    geo_path = my_build(tmp_path)
    assert sg_in(capfd, "export", "--policy", "pid", "--geometry", str(geo_path), "--out", str(tmp_path / "pid"),
              cwd=tmp_path).returncode == 0  # fmt: skip
    (tmp_path / "cal.toml").write_text('geometry = "servo-hexapod"\n' + ServoCalibration.default("servo-hexapod").to_toml())
    drain = Board(device)
    dep = sg("deploy", "--policy", str(tmp_path / "pid"), "--calibration", str(tmp_path / "cal.toml"), "--port",
             device.path, "--duration", "1", cwd=tmp_path)  # fmt: skip
    assert dep.returncode == 1 and drain.stop() == b""  # refused before the port opened
    line = [ln for ln in dep.stderr.splitlines() if ln.startswith("error:")]
    assert len(line) == 1 and "servo-hexapod" in line[0] and "my-build" in line[0], dep.stderr
    layout = json.loads((tmp_path / "pid" / "bundle.json").read_text())
    layout["observation_layout"] = 1
    (tmp_path / "pid" / "bundle.json").write_text(json.dumps(layout))
    old = sg("deploy", "--policy", str(tmp_path / "pid"), "--port", device.path, "--duration", "1", cwd=tmp_path)
    assert old.returncode == 1 and "observation layout" in old.stderr and "re-export" in old.stderr


@pytest.mark.slow
def test_a_geometry_that_cannot_carry_the_task_says_why(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    proc = sg_in(capfd, "evaluate", "--policy", "pid", "--geometry", "mathcad-micro", "--episodes", "1", cwd=tmp_path)
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert proc.returncode == 1 and len(lines) == 1 and "too small" in lines[0] and "Traceback" not in proc.stderr
    small = load_preset("servo-hexapod").to_toml().replace("plate_size = [0.3, 0.3]", "plate_size = [0.08, 0.08]")
    (tmp_path / "small.toml").write_text(small)
    proc = sg_in(capfd, "train", "--geometry", str(tmp_path / "small.toml"), "--run-dir", str(tmp_path / "r"), cwd=tmp_path)
    assert proc.returncode == 1 and "too small" in proc.stderr and not (tmp_path / "r").exists()


def test_a_trained_policy_stays_on_its_build(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    proc = sg_in(capfd, "evaluate", "--policy", str(Path(__file__).resolve().parents[1] / "stewart_gym/policies/track"),
              "--geometry", "memememe-liverpool", "--episodes", "1", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 1 and "trained for geometry 'servo-hexapod'" in proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("geometry", ["servo-hexapod", "memememe-liverpool", "desk-rect", "senilov2018"])
def test_the_pid_balances_on_every_ball_preset(geometry: str) -> None:
    """No retuning by hand: the gains are the reference's; tilt scale, integral bound and observation scales follow
    the build (``senilov2018``: 6-UPS with RC linear actuators, 500 mm plate)."""
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    _, pid, env_kwargs = load_for_evaluation("pid", "StewartBallBalance-v0", geometry)
    m = evaluate("StewartBallBalance-v0", pid, episodes=20, seed=1000, env_kwargs=env_kwargs, settling=False)
    assert m["success_rate"] >= 0.9 and m["fell_rate"] == 0.0, m


@pytest.mark.parametrize("geometry", ["servo-hexapod", "memememe-liverpool", "senilov2018", "mathcad-micro"])
def test_trim_tilt_agrees_with_forward_kinematics(geometry: str) -> None:
    """The small-signal worst trim tilt against the exact one: forward kinematics of every ±15 µs sign pattern."""
    import itertools

    from stewart_gym.control import trim_tilt
    from stewart_gym.kinematics import forward_kinematics, rotation_matrix

    geo = load_preset(geometry)
    cal = ServoCalibration.default(geo)
    home = inverse_kinematics(geo, np.zeros(6))
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=6)))
    delta = signs * 15.0 / (cal.direction * cal.us_per_rad)
    if geo.is_rotary:
        fk = forward_kinematics(geo, servo_angles=home.servo_angles + delta)
    else:
        fk = forward_kinematics(geo, leg_lengths=home.leg_lengths + delta)
    assert np.all(fk.converged)
    tilts = []
    for roll, pitch, yaw in fk.pose[:, 3:]:
        normal = rotation_matrix(roll, pitch, yaw) @ np.array([0.0, 0.0, 1.0])
        tilts.append(np.arccos(np.clip(normal[2], -1.0, 1.0)))
    exact = max(tilts)
    assert trim_tilt(geo) == pytest.approx(exact, rel=0.03)


def test_pid_integral_bound_follows_the_build() -> None:
    """The linear build's trim tilt (3.7°) needs a larger integral than the reference's 0.05 m·s; the rotary
    reference keeps its tuned bound."""
    import dataclasses

    from stewart_gym.constants import GRAVITY
    from stewart_gym.control import PIDGains, gains_for_geometry, trim_tilt

    base = PIDGains(kp_pos=2.0, kp_vel=3.0, ki_vel=3.0)
    assert gains_for_geometry(base, "servo-hexapod").integral_limit == base.integral_limit
    lin = gains_for_geometry(base, "senilov2018")
    can = lin.ki_vel * lin.integral_limit / (lin.rolling_factor * GRAVITY)
    assert can == pytest.approx(np.sin(1.5 * trim_tilt("senilov2018")), rel=1e-9) and lin.integral_limit > 0.2
    assert dataclasses.replace(lin, integral_limit=base.integral_limit, max_tilt=base.max_tilt) == base


def test_deploy_the_pid_on_another_preset(tmp_path: Path, device: FakeDevice) -> None:
    drain = Board(device)
    proc = sg("deploy", "--policy", "pid", "--geometry", "memememe-liverpool", "--port", device.path, "--duration",
              "1", "--log", str(tmp_path / "l.csv"), cwd=tmp_path)  # fmt: skip
    drain.stop()
    assert proc.returncode == 0, proc.stderr
    assert "completed; simulated ball" in proc.stdout


def test_integral_zones_follow_the_build() -> None:
    """Conditional integration must start where the ball comes to rest against the worst trim tilt: on the
    linear build (3.7°) the proportional terms alone hold it 75 mm (PID + Kalman) and 30 mm (LQR) out, beyond
    the shipped 20 mm zones. Checked on the controllers themselves: at the zone's edge / ZONE_MARGIN, at rest,
    they command that tilt (the ball stays there), and the zone is larger; the reference keeps its 20 mm."""
    from stewart_gym.control import (
        ZONE_MARGIN,
        CascadedPID,
        LQRController,
        design_lqr,
        gains_for_geometry,
        shipped_design,
        trim_tilt,
    )
    from stewart_gym.sensing import ObservationBuilder

    assert gains_for_geometry(shipped_design("pid-kalman"), "servo-hexapod").integral_zone == pytest.approx(0.02)
    assert design_lqr(shipped_design("lqr"), geometry="servo-hexapod").integral_zone == pytest.approx(0.02)
    half = tuple(v / 2 for v in load_preset("senilov2018").plate_extent)
    scale = ObservationBuilder(2, half)
    worst = trim_tilt("senilov2018")
    pid_gains = gains_for_geometry(shipped_design("pid-kalman"), "senilov2018")
    lqr_gains = design_lqr(shipped_design("lqr"), geometry="senilov2018")
    for ctrl, zone in ((CascadedPID(pid_gains, plate_half=half), pid_gains.integral_zone),
                       (LQRController(lqr_gains, plate_half=half), lqr_gains.integral_zone)):  # fmt: skip
        rest = zone / ZONE_MARGIN
        assert rest > 0.025
        # the ball at rest `rest` m along −x of a target at the centre; the plate holds the tilt it commands
        obs = np.zeros(12, dtype=np.float32)
        obs[0] = -rest / scale.position_scale[0]
        obs[9] = worst / ObservationBuilder.TILT_SCALE  # pitch: the plate tilted along x
        first = ctrl.predict(obs[None], episode_start=np.array([True]))[0][0]
        commanded = first[1] * pid_gains.max_tilt
        # within 2 %: the one period of integral that the first call adds
        assert commanded == pytest.approx(worst, rel=0.02), (type(ctrl).__name__, commanded, worst)


@pytest.mark.slow
def test_the_pid_kalman_rests_on_target_on_the_linear_build() -> None:
    """Seeds where the ball came to rest outside the 20 mm integral zone (with trims, dead band off) and the
    PID + Kalman failed before the zone followed the build."""
    from stewart_gym.evaluation import run_episode
    from stewart_gym.registry import load_for_evaluation

    _, policy, env_kwargs = load_for_evaluation("pid-kalman", "StewartBallBalance-v0", "senilov2018")
    env = gym.make("StewartBallBalance-v0", **{**env_kwargs, "randomize": True,
                                                "randomization": {"servo_deadband_us": [0, 0]}})  # fmt: skip
    logs = [run_episode(env, policy, seed) for seed in (5, 6, 7, 10)]
    assert all(lg.success for lg in logs), [round(lg.distance_mm[-1], 1) for lg in logs]


@pytest.mark.slow
def test_a_design_file_runs_like_the_named_controller_on_a_build(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """A user's copy of a gains or design file (``--policy my.json``) is told apart by its fields and runs on
    the build ``--geometry`` names exactly as the named controller does (gains adapted to that build, its
    plate's observation scales, the observer the file names or else the Kalman observer for the LQR and the
    hand-over); export keeps the kind. A file naming an unknown observer, or a dither the build cannot give,
    is refused with one ``error:`` line."""
    policies = Path(__file__).resolve().parents[1] / "stewart_gym" / "policies"
    results = {}
    for name, file in (("pid", "pid_gains.json"), ("pid-kalman", "pid_kalman_gains.json"), ("lqr-pid", "lqr_pid.json")):
        mine = tmp_path / f"my_{file}"
        mine.write_text((policies / file).read_text())
        for spec in (name, str(mine)):
            proc = sg_in(capfd, "evaluate", "--policy", spec, "--geometry", "memememe-liverpool", "--episodes", "2",
                         "--json", cwd=tmp_path)  # fmt: skip
            assert proc.returncode == 0, proc.stderr[-2000:]
            results[spec] = json.loads(proc.stdout)
        named, copied = results[name], results[str(mine)]
        for key in ("success_rate", "rms_error_mm", "final_error_mm", "settling_time_s", "settled_pulse_p2p_us"):
            assert copied[key] == pytest.approx(named[key], rel=1e-6, abs=1e-9), (name, key)
    proc = sg_in(capfd, "export", "--policy", str(tmp_path / "my_lqr_pid.json"), "--out", str(tmp_path / "b"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    meta = json.loads((tmp_path / "b" / "bundle.json").read_text())
    assert meta["kind"] == "handover" and meta["estimator"] == "kalman", meta
    pid_kalman = json.loads((policies / "pid_kalman_gains.json").read_text())
    for bad, says in (({**pid_kalman, "estimator": "magic"}, "estimator must be one of"),
                      ({**pid_kalman, "dither": 0.1}, "less than half the build's max tilt")):  # 5.7° of 10°
        (tmp_path / "bad.json").write_text(json.dumps(bad))
        proc = sg_in(capfd, "evaluate", "--policy", str(tmp_path / "bad.json"), "--episodes", "1", cwd=tmp_path)
        assert proc.returncode != 0 and proc.stderr.startswith("error: ") and says in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr


@pytest.mark.slow
def test_the_residual_recipe_trains_on_another_plate(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """The shipped residual recipe, named as a user would, on the user's plate: its training starts (50–110 mm
    out, for the 300 mm plate) are scaled to that plate, with a note, and the run records what it trained with;
    a misspelt recipe is one error line naming the shipped ones."""
    import yaml

    run = sg_in(capfd, "train", "--hyperparams", "ppo_residual", "--geometry", str(my_build(tmp_path)), "--run-dir",
             str(tmp_path / "run"), "--timesteps", "64", "--n-envs", "1", "--eval-freq", "64", "--eval-episodes", "1",
             "--no-progress", "--no-tensorboard", cwd=tmp_path)  # fmt: skip
    assert run.returncode == 0, run.stderr
    # the 250 mm depth: the settling test starts 83.3 mm out, not 100 mm, so 0.8333 of the recipe's distances
    assert "note: start_distance scaled to" in run.stderr and "[0.0417, 0.0917] m" in run.stderr
    config = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert config["hyperparams"]["env_kwargs"]["start_distance"] == [0.0417, 0.0917]
    bad = sg_in(capfd, "train", "--hyperparams", "ppo_residul", "--run-dir", str(tmp_path / "bad"), cwd=tmp_path)
    assert bad.returncode == 1 and bad.stderr.count("\n") == 1 and not (tmp_path / "bad").exists()
    assert bad.stderr.startswith("error: --hyperparams ppo_residul: neither a file nor a shipped recipe (ppo, ")


def test_recipe_distances_are_scaled_only_across_builds() -> None:
    from stewart_gym.training import TrainConfig, run_env_kwargs, run_hyperparams

    root = Path(__file__).resolve().parents[1]
    cfg = TrainConfig(hyperparams=str(root / "stewart_gym/hyperparams/ppo_residual.yml"), run_dir="unused")
    for geometry in (None, "servo-hexapod", "senilov2018"):  # the reference plate, and one whose test also starts 100 mm out
        kwargs, note = run_env_kwargs(TrainConfig(**{**vars(cfg), "geometry": geometry}), run_hyperparams(cfg))
        assert kwargs["start_distance"] == [0.05, 0.11] and note is None  # the very numbers: make train-residual's bits
    kwargs, note = run_env_kwargs(TrainConfig(**{**vars(cfg), "geometry": "memememe-liverpool"}), run_hyperparams(cfg))
    assert kwargs["start_distance"] == [0.0333, 0.0733] and "67 mm out here, 100 mm there" in note
    hp = run_hyperparams(cfg)  # a recipe written for the build it trains on is left as written
    hp["env_kwargs"] = {**hp["env_kwargs"], "geometry": "memememe-liverpool", "start_distance": [0.02, 0.07]}
    kwargs, note = run_env_kwargs(TrainConfig(**{**vars(cfg), "geometry": "memememe-liverpool"}), hp)
    assert kwargs["start_distance"] == [0.02, 0.07] and note is None
    kwargs, note = run_env_kwargs(TrainConfig(**{**vars(cfg), "geometry": "servo-hexapod"}), hp)  # and back again
    assert kwargs["start_distance"] == [0.03, 0.105] and "memememe-liverpool" in note


def test_a_run_keeps_its_build_when_the_geometry_file_moves_or_changes(tmp_path: Path,
                                                                         capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """A run trained on a TOML keeps a copy in its folder: the run folder and the TOML may move; evaluating it runs
    on the build it was trained for; an edited TOML given with --geometry is refused, naming both builds."""
    import shutil

    geo_path = my_build(tmp_path)
    hp = tmp_path / "hp.yml"
    hp.write_text("StewartBallBalance-v0:\n  n_envs: 1\n  n_timesteps: 64\n  policy: MlpPolicy\n  n_steps: 64\n"
                  "  batch_size: 32\n  n_epochs: 1\n  policy_kwargs: {net_arch: [8]}\n")  # fmt: skip
    code, _, err = cli(capfd, "train", "--geometry", str(geo_path), "--hyperparams", str(hp), "--run-dir",
                            str(tmp_path / "run"), "--eval-freq", "1000", "--no-progress", "--no-tensorboard")  # fmt: skip
    assert code == 0, err
    assert (tmp_path / "run" / "geometry.toml").read_text() == load_preset("desk-rect").to_toml().replace(
        'name = "desk-rect"', 'name = "my-build"').replace("plate_size = [0.4, 0.26]", "plate_size = [0.35, 0.25]")
    moved = tmp_path / "elsewhere" / "run"
    shutil.move(tmp_path / "run", moved)
    geo_path.rename(tmp_path / "renamed.toml")
    code, out, err = cli(capfd, "evaluate", "--policy", str(moved), "--episodes", "1", "--no-randomize", "--json")
    assert code == 0, err
    assert json.loads(out)["geometry"] == str(moved / "geometry.toml")
    edited = tmp_path / "renamed.toml"
    edited.write_text(edited.read_text().replace("rod_length = 0.19", "rod_length = 0.2"))
    code, _, err = cli(capfd, "evaluate", "--policy", str(moved), "--geometry", str(edited), "--episodes", "1")
    assert code == 1 and "trained for geometry" in err and str(edited) in err and "Traceback" not in err


def test_a_calibration_follows_its_geometry_file_by_content(tmp_path: Path, device: FakeDevice) -> None:
    """``calibrate`` names the geometry file from the calibration's own folder, with its content's hash: read
    from another folder it works; with the geometry file moved it still works (same content); with the geometry
    file edited, deploy refuses, naming both files."""
    geo_path = my_build(tmp_path)
    (tmp_path / "cal").mkdir()
    drain = Board(device)
    cal = sg("calibrate", "--geometry", str(geo_path), "--port", device.path, "--protocol", "maestro", "--out",
             str(tmp_path / "cal" / "calibration.toml"), stdin="q\n", cwd=tmp_path)  # fmt: skip
    drain.stop()
    assert cal.returncode == 0, cal.stderr
    text = (tmp_path / "cal" / "calibration.toml").read_text()
    assert 'geometry = "../my_build.toml"' in text and "geometry_sha256 = " in text
    from stewart_gym.hardware.deploy_setup import load_calibration

    load_calibration(str(tmp_path / "cal" / "calibration.toml"), str(geo_path))  # from the calibration's folder
    moved = geo_path.rename(tmp_path / "cal" / "elsewhere.toml")
    load_calibration(str(tmp_path / "cal" / "calibration.toml"), str(moved))  # the file moved: same content
    moved.rename(geo_path)
    geo_path.write_text(geo_path.read_text().replace("rod_length = 0.19", "rod_length = 0.2"))
    from stewart_gym.errors import ConfigError

    with pytest.raises(ConfigError, match=r"my_build\.toml has changed since .*calibration\.toml was calibrated"):
        load_calibration(str(tmp_path / "cal" / "calibration.toml"), str(geo_path))


def test_a_bundle_for_my_build_evaluates_on_the_build_it_holds(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """A bundle carries its build: evaluate runs it there (by the bundle's geometry, not by a preset of its name),
    accepts ``--geometry`` of the same build and refuses another."""
    geo_path = my_build(tmp_path)
    assert sg_in(capfd, "export", "--policy", "pid", "--geometry", str(geo_path), "--out", str(tmp_path / "pid"),
                 cwd=tmp_path).returncode == 0  # fmt: skip
    (tmp_path / "elsewhere").mkdir()  # (no my_build.toml beside it: the bundle alone says what the build is)
    run = sg_in(capfd, "evaluate", "--policy", str(tmp_path / "pid"), "--episodes", "1", "--json",
                cwd=tmp_path / "elsewhere")  # fmt: skip
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    assert (result["geometry"], result["geometry_name"]) == ("my-build", "my-build"), result
    same = sg_in(capfd, "evaluate", "--policy", str(tmp_path / "pid"), "--geometry", str(geo_path), "--episodes", "1",
                 cwd=tmp_path)  # fmt: skip
    assert same.returncode == 0 and "on my-build" in same.stdout, same.stderr
    other = sg_in(capfd, "evaluate", "--policy", str(tmp_path / "pid"), "--geometry", "desk-rect", cwd=tmp_path)
    assert other.returncode == 1 and "trained for geometry 'my-build', not 'desk-rect'" in other.stderr, other.stderr
