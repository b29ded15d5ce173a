"""sysid: reading deploy logs, and fitting a twin from them (on logs whose truth is known)."""

from __future__ import annotations

import csv
import math
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

import stewart_gym  # noqa: F401  (registers the envs)
from stewart_gym.errors import ConfigError
from stewart_gym.hardware.deploy import LOG_READING_COLUMNS
from stewart_gym.hardware.identify import Excitation
from stewart_gym.registry import deployable_policy, resolve_policy
from stewart_gym.sim import BallSpec
from stewart_gym.sim.twin import Twin
from stewart_gym.sysid import (
    MAX_MARKER_HEIGHT,
    READ_OVERHEAD_S,
    TICK_DATED_OVERHEAD_S,
    fit_twin,
    read_log,
    twin_ball,
)
from tests.conftest import cli

TWIN = {"servos": {"speed_scale": 0.6, "deadband_us": 10.0, "trim_us": [20, -20, 10, -5, 0, 15], "latency_ms": 40.0},
        "sensor": {"noise_mm": 1.8, "latency_ms": 20.0}}  # fmt: skip
HEADER = ["t_s", *(f"pulse{i}_us" for i in range(6)), "stale", "invalid", "held", "homing", "missed_deadline",
          *LOG_READING_COLUMNS]  # fmt: skip


def synthetic_log(path, twin: dict, seconds: float, seed: int = 0, dated_at_ticks: bool = False,
                  plate_moves: bool = False) -> None:  # fmt: skip
    """What identify would log on the platform ``twin`` describes, written in simulated time (the batched
    backend, not real time): the excitation under the PID + Kalman, each tick's pulses, and the newest panel
    line the loop has at the tick, dated when it arrived: the sketch sends each sample as soon as the panel has it,
    and it takes up to 2 ms to reach the loop. ``dated_at_ticks``: dated at the tick instead, as a loop that reads
    the port only at its ticks dates them. ``plate_moves``: the plate also moves in height and yaw, and in tilt
    triplets, as identify moves it when a camera watches."""
    env = gym.make("StewartBallBalance-v0", twin=twin, backend="batched", estimator="kalman",
                   episode_s=seconds + 1).unwrapped  # fmt: skip
    policy = Excitation(deployable_policy(resolve_policy("pid-kalman")), seed=seed)
    if plate_moves:
        policy.move_plate(env.mapper)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed, options={"ball_position": (0.0, 0.0), "ball_velocity": (0.0, 0.0)})
    latency = env.sensor_model.spec.latency_s
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(HEADER)
        for _ in range(int(seconds * env.sim.control_hz)):
            t = env.sim.time
            transit = rng.uniform(0.0, 0.002)
            got = env.sensor_model.read(t - transit)
            action = policy(obs)
            obs, _, terminated, _, info = env.step(action)
            arrived = None if got is None else (t if dated_at_ticks else got[1] + latency + transit)
            reading = ("", "", "") if got is None else (*got[0], arrived)
            writer.writerow([f"{t:.4f}", *np.round(info["pulse_widths_us"], 2), 0, 0, 0, 0, 0, *reading])
            assert not terminated, "the ball left the plate during the excitation"
    env.close()


# The tests that take it share an xdist group: on `make test`'s workers it is still made once.
@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    path = tmp_path_factory.mktemp("sysid") / "log.csv"
    synthetic_log(path, TWIN, 40.0)
    return path, fit_twin([read_log(path)])


@pytest.mark.xdist_group("sysid_fit")
@pytest.mark.slow
def test_the_fit_recovers_a_known_twin(fitted):
    _, result = fitted
    truth = Twin.from_mapping(TWIN)
    twin = result.twin
    assert result.sensor == "panel"  # a log without the plate's columns: the touch panel read the ball
    assert result.total_latency_ms == pytest.approx(truth.total_latency_ms, abs=4.0)
    assert twin["servos.speed_scale"] == pytest.approx(0.6, abs=0.1)
    assert twin["servos.deadband_us"] == pytest.approx(10.0, abs=2.5)
    assert twin["sensor.noise_mm"] == pytest.approx(1.8, abs=0.2)
    # the twin written keeps the sensor's nominal latency and gives the rest to the servos
    assert twin["sensor.latency_ms"] == 10.0
    assert twin.total_latency_ms == pytest.approx(result.total_latency_ms)
    for name in ("servos.speed_scale", "servos.deadband_us", "servos.latency_ms", "sensor.noise_mm"):
        assert 0 < twin.sigma[name] < 1e3 and name not in twin.undetermined
    assert {"sensor.latency_ms", "servos.trim_us", "ball.mass_scale", "plate.load_kg"} <= set(twin.undetermined)


@pytest.mark.slow
def test_a_ping_pong_ball_is_fitted_with_the_ball_its_start_twin_gives(tmp_path):
    """A thin 40 mm shell rolls at 3/5 g sin θ, not the steel ball's 5/7: the replays roll --start's ball, so that
    the servos come out right (a solid ball's replays put its slower rolling on the servos: 49 % speed and a 1 µs
    dead band, for this platform's 60 % and 10 µs), and the fitted twin keeps the ball."""
    ball = {"radius_scale": 1.575, "mass_scale": 0.04, "hollow": True}
    path = tmp_path / "ping_pong.csv"
    synthetic_log(path, {**TWIN, "ball": ball}, 30.0)
    result = fit_twin([read_log(path)], start=Twin.from_mapping({"ball": ball}))
    twin = result.twin
    assert result.total_latency_ms == pytest.approx(60.0, abs=4.0)
    assert twin["servos.speed_scale"] == pytest.approx(0.6, abs=0.1)
    assert twin["servos.deadband_us"] == pytest.approx(10.0, abs=2.5)
    assert (twin["ball.hollow"], twin["ball.radius_scale"], twin["ball.mass_scale"]) == (True, 1.575, 0.04)
    assert "ball.hollow" in twin.undetermined
    assert twin_ball(twin) == replace(BallSpec(), radius=0.02, mass=0.04 * BallSpec().mass, hollow=True,
                                      rolling_friction=0.0)  # fmt: skip


@pytest.mark.xdist_group("sysid_fit")
@pytest.mark.slow
def test_the_fitted_twin_predicts_better_than_the_nominal_one(fitted):
    _, result = fitted
    for horizon, row in result.prediction.items():
        assert row["windows"] >= 3
        assert row["fitted"] * 2 <= row["nominal"], f"{horizon} s: {row}"


def test_the_report_says_whether_the_fit_predicts_better_or_worse():
    """Each held-out horizon's line says how many times better the fitted twin predicts than the nominal one, or,
    where it predicts worse, how many times worse and what to do (a ratio below 1 is never called better)."""
    from stewart_gym.sysid import FitResult

    def line(nominal: float, fitted: float) -> str:
        result = FitResult(Twin.from_mapping(TWIN), 50.0, np.zeros(2), 1.0, {1.0: {"nominal": nominal,
                           "fitted": fitted, "windows": 5}}, 10, 5)  # fmt: skip
        return next(text for text in result.lines() if "prediction RMS" in text)

    assert line(6.0, 2.0).endswith("(3.0× better)")
    worse = line(7.53, 9.26)
    assert "better" not in worse and "1.2× worse" in worse and "run identify longer" in worse


@pytest.mark.parametrize("sensor,label", [("panel", "panel noise"), ("camera", "camera noise"),
                                          ("panel and camera", "reading noise")])  # fmt: skip
def test_the_report_names_the_sensor_whose_noise_it_fitted(sensor: str, label: str):
    """A camera log's reading noise is called the camera's, with a word that the twin's ``[sensor]`` table is the
    touch panel's (a simulated camera keeps its own model's noise); a panel log's is the panel's, as before."""
    from stewart_gym.sysid import FitResult

    lines = FitResult(Twin.from_mapping(TWIN), 50.0, np.zeros(2), 1.0, {}, 10, 5, sensor=sensor).lines()
    noise = next(text for text in lines if "noise" in text)
    assert noise.strip().startswith(label) and ("touch panel's" in noise) == (sensor != "panel"), noise


@pytest.mark.slow
def test_the_fitted_twin_predicts_better_where_the_plate_turns_under_the_ball(tmp_path):
    """identify's yaw moves (with a camera) turn the plate under the ball, so that the ball's path depends on its
    own velocity: the prediction starts each twin's ball where the past readings put it, and the fitted twin still
    predicts the held-out ball at least twice as well as the nominal one."""
    path = tmp_path / "log.csv"
    synthetic_log(path, TWIN, 30.0, seed=4, plate_moves=True)
    result = fit_twin([read_log(path)])
    for horizon, row in result.prediction.items():
        assert row["windows"] >= 2
        assert row["fitted"] * 2 <= row["nominal"], f"{horizon} s: {row}"
    assert result.prediction[1.0]["fitted"] < 10.0  # mm


@pytest.mark.xdist_group("sysid_fit")
@pytest.mark.slow
def test_the_tilt_offset_gives_trims_that_tilt_the_ball_the_same_way(fitted):
    """The fitted trims, put into a simulated platform at rest, make the ball accelerate as the fit says."""
    from stewart_gym.sim import BatchedSim, ServoSpec

    _, result = fitted
    sim = BatchedSim(n=1)
    sim.reset(servo_specs=[ServoSpec(trim_error_us=result.twin["servos.trim_us"])])
    home = sim.calibration.neutral_us[None]
    for _ in range(25):
        sim.command(home)
        sim.step()
    sim.place_ball(np.zeros((1, 2)))
    for _ in range(10):
        sim.command(home)
        sim.step()
    accel = 2 * sim.ball_xy[0] / (10 * sim.dt) ** 2
    assert np.allclose(accel, result.tilt_accel, atol=0.1 * np.linalg.norm(result.tilt_accel) + 1e-3)


@pytest.mark.slow
def test_sysid_writes_the_twin_and_its_report(tmp_path, capfd):
    """The command on a log of 20 s (the fit's figures are the tests' above, on 40 s)."""
    log = tmp_path / "log.csv"
    synthetic_log(log, TWIN, 20.0)
    code, out, err = cli(capfd, "sysid", str(log), "--out", str(tmp_path / "twin.toml"), "--report",
                         str(tmp_path / "report"))  # fmt: skip
    assert code == 0, err
    from stewart_gym.sim.twin import load_twin

    twin = load_twin(tmp_path / "twin.toml")
    assert twin.sigma and "total latency" in out and "undetermined" in out
    assert (tmp_path / "report" / "report.md").read_text().count("prediction RMS") == 2
    assert (tmp_path / "report" / "paths.png").stat().st_size > 1000
    assert sorted(p.name for p in (tmp_path / "report").iterdir()) == ["paths.png", "report.md"]  # no scratch left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv", "report", "twin.toml"]


@pytest.mark.slow
def test_what_the_logs_cannot_determine_is_the_start_twins_or_widely_uncertain(tmp_path, capfd):
    """A log whose pulses never move (every servo speed and dead band replays it alike): the speed and the dead
    band are undetermined. With --start, the twin keeps its speed, dead band and measured trims, and says so;
    without, it holds the search's best with an uncertainty of a fifth of the search, not a narrow one."""
    from stewart_gym.sim.twin import load_twin
    from stewart_gym.sysid import DEADBAND_GRID, SPEED_GRID, UNDETERMINED_FRACTION

    moving = tmp_path / "moving.csv"
    synthetic_log(moving, TWIN, 20.0)
    rows = list(csv.reader(moving.open()))
    pulses = [rows[0].index(f"pulse{i}_us") for i in range(6)]
    still = tmp_path / "still.csv"
    with still.open("w", newline="") as fh:
        csv.writer(fh).writerows([rows[0], *([v if j not in pulses else "1500" for j, v in enumerate(r)]
                                             for r in rows[1:])])  # fmt: skip
    start = tmp_path / "start.toml"
    start.write_text("[servos]\nspeed_scale = 0.5\ndeadband_us = 12.0\ntrim_us = [30, -30, 20, -10, 0, 25]\n")
    code, out, err = cli(capfd, "sysid", str(still), "--start", str(start), "--out", str(tmp_path / "twin.toml"))
    assert code == 0, err
    twin = load_twin(tmp_path / "twin.toml")
    assert {"servos.speed_scale", "servos.deadband_us", "servos.trim_us"} <= set(twin.undetermined)
    assert twin["servos.speed_scale"] == 0.5 and twin["servos.deadband_us"] == 12.0
    assert list(twin["servos.trim_us"]) == [30, -30, 20, -10, 0, 25]
    assert "servos.speed_scale" not in twin.sigma and "servos.deadband_us" not in twin.sigma
    assert "the twin keeps --start's 0.5" in out and "the twin keeps --start's, each servo's own" in out
    assert "keeps these as written" not in out
    speed_only = Twin.from_mapping({"servos": {"speed_scale": 0.5}})  # sets no trims: the smallest that tilt alike
    assert any(fit_twin([read_log(still)], start=speed_only).twin["servos.trim_us"])
    alone = fit_twin([read_log(still)]).twin  # no --start: the search's best, widely uncertain
    for name, grid in (("servos.speed_scale", SPEED_GRID), ("servos.deadband_us", DEADBAND_GRID)):
        assert name in alone.undetermined
        assert alone.sigma[name] >= UNDETERMINED_FRACTION * (grid[-1] - grid[0]) - 1e-12


@pytest.mark.parametrize("content, words", [
    ("t_s,pulse0_us\n0,1500\n", "not a deploy log with readings (no column 'pulse1_us')"),
    ("", "empty"),
    (",".join(HEADER) + "\n" + "".join(f"{k / 50},1500,1500,1500,1500,1500,1500,0,0,0,0,0,0,0,{k / 50}\n"
                                        for k in range(100)), "at least 5 s"),
    (",".join(HEADER) + "\n" + "".join(f"{k * 0.02},1500,1500,1500,1500,1500,1500,0,0,0,0,0,0,0,{k * 0.02}\n"
                                        for k in range(250)), "4.98 s of ticks"),  # (printed as 5.0 s: no contradiction)
    (",".join(HEADER) + "\n0.02,1500,1500,1500,1500,1500,1500,0,0,0,0,0,,,\n0.0,1500,1500,1500,1500,1500,1500,0,0,0,0,"
     "0,,,\n", "line 3: t_s 0 is not finite, or not after the tick before it"),
    (",".join(HEADER) + "\n0,1500,x,1500,1500,1500,1500,0,0,0,0,0,,,\n", "line 2 is not a deploy log's row (could not "
     "convert string to float: 'x')"),
    (",".join(HEADER) + "\n0,1500,1500,1500,1500,1500,1500,0,0,0,0,0,,,\n0.02,1500,1500,1500\n0.04,1500,1500,1500,1500,"
     "1500,1500,0,0,0,0,0,,,\n", "line 3 is not a deploy log's row (4 fields, the header has 15)"),
    (",".join(HEADER) + "\n0,1500,1500,nan,1500,1500,1500,0,0,0,0,0,,,\n0.02,1500,1500,1500,1500,1500,1500,0,0,0,0,0,,,"
     "\n", "line 2: pulse2_us is nan, not a finite pulse width"),
    (",".join(HEADER) + ",bogus\n", "unknown column(s) ['bogus']"),
    (",".join(HEADER) + ",t_s\n", "column(s) ['t_s'] given more than once"),
    (",".join(HEADER) + "\n" + "".join(f"{k / 50},1500,{1e9 if k == 100 else 1500},1500,1500,1500,1500,0,0,0,0,0,0,0,"
                                        f"{k / 50}\n" for k in range(300)),
     "pulse1_us 1e+09 µs (tick 101, t_s 2) is outside the calibration's [1100, 1900] µs (1 pulse(s) in all)"),
])  # fmt: skip
def test_a_bad_log_is_one_error_line(tmp_path, capfd, content, words):
    log = tmp_path / "log.csv"
    log.write_text(content)
    code, out, err = cli(capfd, "sysid", str(log), "--out", str(tmp_path / "twin.toml"))
    assert code == 1 and words in err and str(log) in err and "Traceback" not in err
    assert err.strip().count("\n") == 0 and not (tmp_path / "twin.toml").exists()


def test_a_log_whose_last_line_was_cut_as_it_was_written_is_read_without_it(tmp_path):
    """A crash or a full disk leaves the log's last line half written (it is flushed line by line): the rows before
    it stand. A short row inside the log is still refused (test_a_bad_log_is_one_error_line)."""
    rows = "".join(f"{k / 50},1500,1500,1500,1500,1500,1500,0,0,0,0,0,0.01,0.02,{k / 50}\n" for k in range(400))
    whole = tmp_path / "whole.csv"
    whole.write_text(",".join(HEADER) + "\n" + rows)
    cut = tmp_path / "cut.csv"
    cut.write_text(",".join(HEADER) + "\n" + rows + "8.0,1500,15")
    a, b = read_log(whole), read_log(cut)
    assert len(b.t) == len(a.t) == 400 and np.array_equal(a.pulses, b.pulses)


def test_a_log_of_another_build_is_refused_before_the_fit(tmp_path, capfd):
    """A log's pulses are its build's and calibration's for the poses it asked for: sysid given another geometry
    (or a calibration the log was not run with) says so in one line instead of fitting a twin of another plant;
    the right ones agree on the log's ticks to its rounding, the small mathcad-micro build's too."""
    from stewart_gym.calibration import ServoCalibration
    from stewart_gym.kinematics import inverse_kinematics
    from stewart_gym.presets import load_geometry
    from stewart_gym.sysid import POSE_COLUMNS, pose_agreement

    def log_of(geometry: str, reach: float) -> object:
        geo, cal = load_geometry(geometry), ServoCalibration.default(geometry)
        rng = np.random.default_rng(1)
        k = np.arange(500)
        poses = np.zeros((500, 6))
        poses[:, :3] = reach * rng.uniform(-1, 1, (500, 3))
        poses[:, 3:] = 0.05 * np.stack([np.sin(k / 20), np.cos(k / 25), 0.3 * np.sin(k / 30)], axis=1)
        pulses = cal.pulse_widths(inverse_kinematics(geo, poses).actuators)
        path = tmp_path / f"{geometry}.csv"
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow([*HEADER, *POSE_COLUMNS])
            for i in range(500):  # as deploy writes them: pulses to 0.01 µs, poses to 1e-6
                writer.writerow([f"{i / 50:.4f}", *np.round(pulses[i], 2), 0, 0, 0, 0, 0, 0.01, 0.02, f"{i / 50:.4f}",
                                 *np.round(poses[i], 6)])  # fmt: skip
        return path

    hexapod = log_of("servo-hexapod", 0.004)
    assert pose_agreement(read_log(hexapod), load_geometry("servo-hexapod"),
                          ServoCalibration.default("servo-hexapod")) == 1.0  # fmt: skip
    micro = log_of("mathcad-micro", 0.0001)
    assert pose_agreement(read_log(micro), load_geometry("mathcad-micro"),
                          ServoCalibration.default("mathcad-micro")) == 1.0  # fmt: skip
    code, _, err = cli(capfd, "sysid", str(hexapod), "--geometry", "desk-rect", "--out", str(tmp_path / "t.toml"))
    assert code == 1 and err.strip().splitlines() == [
        f"error: {hexapod}: its pulses are not what geometry 'desk-rect' and this calibration give for the poses it "
        "asked for (0 % of its ticks away from home agree): give the --geometry and --calibration it was run with"]
    assert not (tmp_path / "t.toml").exists()


def test_sysid_refuses_before_any_work(tmp_path, capfd):
    (tmp_path / "twin.toml").write_text("")
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), "--out", str(tmp_path / "twin.toml"))
    assert code == 1 and "exists" in err  # the output is checked first
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / "report.md").write_text("an earlier fit's\n")
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), "--out", str(tmp_path / "new.toml"), "--report",
                       str(tmp_path / "report"))  # fmt: skip
    assert code == 1 and "holds a report already; give another folder or --overwrite" in err
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), str(tmp_path / "." / "none.csv"), "--out",
                       str(tmp_path / "new.toml"))  # fmt: skip
    assert code == 1 and "a log given twice would count its windows twice" in err
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), "--out", str(tmp_path / "new.toml"), "--report",
                       str(tmp_path / "new.toml"))  # fmt: skip
    assert code == 1 and "--out and --report both name" in err  # (the fit ran, then the twin could not be written)
    (tmp_path / "other" / "paths.png").mkdir(parents=True)
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), "--out", str(tmp_path / "new.toml"), "--report",
                       str(tmp_path / "other"))  # fmt: skip
    assert code == 1 and "paths.png is a folder, where the report writes a file" in err
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), "--out", str(tmp_path / "new.toml"))
    assert code == 1 and "none.csv" in err
    rows = "".join(f"{k / 50},1500,1500,1500,1500,1500,1500,0,0,0,0,0,0.01,0.02,{k / 50}\n" for k in range(400))
    (tmp_path / "a.csv").write_text(",".join(HEADER) + "\n" + rows)
    (tmp_path / "b.csv").write_text(",".join(HEADER) + "\n" + rows)  # a copy under another name
    code, _, err = cli(capfd, "sysid", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--out",
                       str(tmp_path / "new.toml"))  # fmt: skip
    assert code == 1 and f"{tmp_path / 'a.csv'} and {tmp_path / 'b.csv'} hold the same log" in err, err
    assert not (tmp_path / "new.toml").exists()


@pytest.mark.parametrize("height", ["-0.1", "25", "nan"])
def test_a_bad_marker_height_is_one_error_line(tmp_path, capfd, height):
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), "--out", str(tmp_path / "twin.toml"),
                       "--marker-height-mm", height)  # fmt: skip
    assert code != 0 and "--marker-height-mm" in err and "Traceback" not in err
    assert not (tmp_path / "twin.toml").exists()
    with pytest.raises(ConfigError, match="markers' height"):
        fit_twin([], marker_height=0.03)


def test_the_command_line_takes_the_markers_sysid_takes(tmp_path, capfd):
    """The parser's bound on --marker-height-mm is sysid's MAX_MARKER_HEIGHT (the parser cannot import it)."""
    highest = f"{MAX_MARKER_HEIGHT * 1e3:g}"
    out = ["--out", str(tmp_path / "twin.toml")]
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), *out, "--marker-height-mm", highest)
    assert code == 1 and "none.csv" in err and "--marker-height-mm" not in err  # taken: the missing log is the error
    above = f"{MAX_MARKER_HEIGHT * 1e3 + 0.1:g}"
    code, _, err = cli(capfd, "sysid", str(tmp_path / "none.csv"), *out, "--marker-height-mm", above)
    assert code != 0 and "--marker-height-mm" in err


def test_nan_and_off_plate_readings_are_no_readings(tmp_path):
    rows = [",".join(HEADER)]
    for k in range(400):
        t = k / 50
        x = "nan" if k % 7 == 0 else ("0.9" if k % 11 == 0 else f"{0.01 * math.sin(t):.5f}")
        rows.append(f"{t:.4f},1500,1500,1500,1500,1500,1500,0,0,0,0,0,{x},0.0,{t:.4f}")
    (tmp_path / "log.csv").write_text("\n".join(rows) + "\n")
    log = read_log(tmp_path / "log.csv")
    assert np.all(np.isfinite(log.reading_xy)) and np.all(np.abs(log.reading_xy) <= 0.16)
    assert len(log.reading_t) == len([k for k in range(400) if k % 7 and k % 11])
    assert log.dated_at_ticks and log.read_overhead_s == READ_OVERHEAD_S + TICK_DATED_OVERHEAD_S


def test_a_log_dated_at_arrival_is_told_from_one_dated_at_ticks(tmp_path):
    synthetic_log(tmp_path / "arrival.csv", TWIN, 6.0)
    synthetic_log(tmp_path / "ticks.csv", TWIN, 6.0, dated_at_ticks=True)
    arrival, ticks = read_log(tmp_path / "arrival.csv"), read_log(tmp_path / "ticks.csv")
    assert not arrival.dated_at_ticks and arrival.read_overhead_s == READ_OVERHEAD_S
    assert ticks.dated_at_ticks and ticks.read_overhead_s == pytest.approx(READ_OVERHEAD_S + TICK_DATED_OVERHEAD_S)
    assert ticks.read_time_var_s2 > arrival.read_time_var_s2 > 0
