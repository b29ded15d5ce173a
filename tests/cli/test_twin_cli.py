"""``--twin FILE`` on the commands that simulate a platform, and ``train --resume shipped``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from conftest import cli

from stewart_gym.hardware.deploy import SimulatedPlant
from stewart_gym.hardware.virtual_device import VirtualDevice
from stewart_gym.sim import ServoSpec

TWIN = """[servos]
speed_scale = 0.5
deadband_us = 12
trim_us = [30, -30, 20, -10, 0, 25]
latency_ms = 50
[sensor]
noise_mm = 2.5
latency_ms = 30
"""


@pytest.fixture
def twin(tmp_path: Path) -> Path:
    path = tmp_path / "twin.toml"
    path.write_text(TWIN)
    return path


def test_evaluate_runs_on_exactly_the_twin(twin, capfd):
    code, out, err = cli(capfd, "evaluate", "--policy", "pid-kalman", "--episodes", "2", "--twin", str(twin), "--json")
    assert code == 0, err
    on_twin = json.loads(out)
    assert on_twin["twin"] == str(twin)
    code, out, _ = cli(capfd, "evaluate", "--policy", "pid-kalman", "--episodes", "2", "--json", "--no-randomize")
    nominal = json.loads(out)
    assert "twin" not in nominal
    code, out, _ = cli(capfd, "evaluate", "--policy", "pid", "--episodes", "1", "--twin", str(twin))
    assert code == 0 and out.splitlines()[0].endswith(f"the twin's physics ({twin})"), out
    # the slow, late, noisy twin moves the servos differently from the nominal platform on the same seeds
    assert on_twin["pulse_rate_us_per_s"] != pytest.approx(nominal["pulse_rate_us_per_s"], rel=0.02)


def test_compare_runs_every_policy_on_the_twin(twin, capfd):
    code, out, err = cli(capfd, "compare", "pid-kalman", "lqr", "--episodes", "2", "--twin", str(twin), "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["twin"] == str(twin) and result["randomize"] is False and set(result["policies"]) == {"pid-kalman",
                                                                                                       "lqr"}
    code, out, _ = cli(capfd, "compare", "pid", "lqr", "--episodes", "2", "--twin", str(twin))
    assert code == 0 and f"(seeds 0…1, the twin {twin})" in out.splitlines()[0], out


@pytest.mark.parametrize("command", [["evaluate", "--policy", "pid"], ["compare", "pid", "lqr"], ["demo"],
                                     ["train", "--timesteps", "64"], ["virtual-device"],
                                     ["deploy", "--port", "/dev/null", "--sensor", "sim"]])  # fmt: skip
def test_a_bad_twin_is_one_error_line_before_any_work(tmp_path, capfd, command):
    bad = tmp_path / "bad.toml"
    bad.write_text("[servos]\nspeed_scale = 9\n")
    code, out, err = cli(capfd, *command, "--twin", str(bad), cwd=tmp_path)
    assert code == 1 and err.startswith("error: ") and str(bad) in err and "servos.speed_scale" in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "runs").exists() and not (tmp_path / "out").exists()


def test_deploy_refuses_a_twin_without_the_simulated_plant(twin, capfd, tmp_path):
    code, _, err = cli(capfd, "deploy", "--port", "/dev/null", "--protocol", "line", "--sensor", "panel", "--twin",
                       str(twin), "--log", str(tmp_path / "log.csv"))  # fmt: skip
    assert code == 1 and "--twin describes the simulated plant: it needs --sensor sim" in err


def test_the_simulated_plant_and_the_virtual_board_are_the_twin(twin):
    plant = SimulatedPlant(twin=str(twin), randomize=True)  # the twin decides: not randomised
    servo = plant.env.params.servo
    assert servo.deadband_us == 12 and servo.max_speed == pytest.approx(0.5 * ServoSpec().max_speed)
    assert plant.env.params.sensor.latency_s == pytest.approx(0.030)
    plant.close()
    board = VirtualDevice("line", twin=str(twin))
    try:
        assert board.plant.env.params.servo.trim_error_us == (30, -30, 20, -10, 0, 25)
        assert board.plant.env.sim.control_hz == 100  # the board simulates in its own 10 ms steps
    finally:
        board.run(lambda: True)  # stops at once, closing the pty and the simulator


@pytest.mark.slow
def test_train_for_a_twin_from_the_shipped_policy(twin, tmp_path, capfd):
    code, out, err = cli(capfd, "train", "--resume", "shipped", "--twin", str(twin), "--run-dir",
                         str(tmp_path / "run"), "--timesteps", "2048", "--no-progress", "--no-tensorboard")  # fmt: skip
    assert code == 0, err
    config = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert config["hyperparams"]["env_kwargs"]["twin"]["servos"]["deadband_us"] == 12.0
    assert config["options"]["resume"].endswith("policies/balance")
    assert json.loads(out)["timesteps"] > 150_000  # it went on from the shipped policy's steps
    code, out, err = cli(capfd, "evaluate", "--policy", str(tmp_path / "run"), "--episodes", "2", "--twin",
                         str(twin), "--json")  # fmt: skip
    assert code == 0 and json.loads(out)["twin"] == str(twin), err
