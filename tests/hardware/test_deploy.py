"""The deploy loop: watchdog, unplug, Ctrl-C, a 10 s dry run on a fake Maestro, and how a run is judged."""


from __future__ import annotations

import csv
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import Drain, FakeDevice, StaticSensor

from stewart_gym.actions import ActionMapper
from stewart_gym.calibration import ServoCalibration
from stewart_gym.hardware.deploy import DeployConfig, DeployLoop, SimulatedPlant
from stewart_gym.hardware.export import BundlePolicy, export_pid
from stewart_gym.hardware.protocols import Maestro
from stewart_gym.hardware.serial_controllers import MaestroController

CAL = ServoCalibration.default("servo-hexapod")


PULSES = np.array([1500.0, 1400.25, 1600.5, 1100.0, 1900.0, 1234.75])


def _pid_bundle(tmp_path: Path) -> BundlePolicy:
    from stewart_gym.registry import POLICY_DIR

    return BundlePolicy(export_pid(POLICY_DIR / "pid_gains.json", tmp_path / "pid"))


def test_unplug_stops_within_a_tick_and_keeps_the_log(device: FakeDevice, tmp_path: Path) -> None:
    log = tmp_path / "log.csv"
    ctl = MaestroController(device.path)
    loop = DeployLoop(_pid_bundle(tmp_path), ActionMapper("servo-hexapod", CAL), ctl, StaticSensor(),
                      DeployConfig(duration_s=5.0, log_path=str(log)))  # fmt: skip
    unplugged_at = []

    def unplug() -> None:
        unplugged_at.append(time.monotonic())
        device.unplug()

    timer = threading.Timer(0.3, unplug)
    timer.start()
    t0 = time.monotonic()
    summary = loop.run()
    assert summary.exit_code == 2 and "device failure" in summary.message and "unplugged" in summary.message
    rows = list(csv.DictReader(log.open()))
    assert len(rows) > 5  # the log survived the failure
    after = [r for r in rows if float(r["t_s"]) > unplugged_at[0] - t0]
    assert len(after) <= 1  # the loop stopped at the first tick that could not write


def test_stalled_sensor_triggers_the_watchdog(device: FakeDevice, tmp_path: Path) -> None:
    log = tmp_path / "log.csv"
    loop = DeployLoop(lambda obs: np.array([1.0, 1.0]), ActionMapper("servo-hexapod", CAL),
                      MaestroController(device.path), StaticSensor(stall_after=10),
                      DeployConfig(duration_s=1.0, log_path=str(log)))  # fmt: skip
    summary = loop.run()
    rows = list(csv.DictReader(log.open()))
    assert summary.stale >= 30 and summary.homing >= 30
    # most ticks had no fresh reading: the run failed, and says so
    assert summary.exit_code == 1 and f"no fresh valid reading on {summary.stale} of 50 ticks" in summary.message
    assert all(r["stale"] == "0" for r in rows[:10]) and all(r["homing"] == "1" for r in rows[15:])
    final = np.array([float(rows[-1][f"pulse{i}_us"]) for i in range(6)])
    assert final == pytest.approx(CAL.neutral_us)  # moved home and stayed there


def test_ctrl_c_sends_home_before_closing(device: FakeDevice, tmp_path: Path) -> None:
    ctl = MaestroController(device.path)
    loop = DeployLoop(lambda obs: np.array([1.0, -1.0]), ActionMapper("servo-hexapod", CAL), ctl,
                      StaticSensor(interrupt_at=20), DeployConfig(log_path=str(tmp_path / "log.csv")))  # fmt: skip
    summary = loop.run()
    assert summary.message == "stopped by Ctrl-C (SIGINT)" and summary.exit_code == 130
    assert summary.home == "sent" and "not confirmed" in summary.text()  # this board's answers are not read
    home_frame = b"".join(Maestro.set_target(i, w) for i, w in enumerate(CAL.neutral_us))
    data = device.read_all(wait=0.3, size=summary.frames_sent * len(home_frame))
    assert data.endswith(home_frame) and not ctl.serial.is_open


@pytest.mark.slow
def test_dry_run_with_a_fake_maestro(device: FakeDevice, tmp_path: Path) -> None:
    """deploy --sensor sim: 10 s at 50 Hz, pulses to a fake Maestro on a pty, the simulated ball stays balanced."""
    from stewart_gym.registry import POLICY_DIR

    bundle_dir = POLICY_DIR / "balance" / "bundle"
    policy = BundlePolicy(bundle_dir) if (bundle_dir / "bundle.json").exists() else _pid_bundle(tmp_path)
    received = bytearray()
    stop = threading.Event()

    def drain() -> None:
        while not stop.is_set():
            received.extend(device.read_all(0.02))

    threading.Thread(target=drain, daemon=True).start()
    plant = SimulatedPlant(seed=3, ball_position=(0.05, -0.03))
    loop = DeployLoop(policy, ActionMapper("servo-hexapod", CAL, policy.action_mode), MaestroController(device.path),
                      plant, DeployConfig(duration_s=10.0, log_path=str(tmp_path / "log.csv")), plant=plant)  # fmt: skip
    summary = loop.run()
    time.sleep(0.1)
    stop.set()
    frames = [bytes(received[i:i + 24]) for i in range(0, len(received) - len(received) % 24, 24)]
    well_formed = [f for f in frames if all(f[k] == 0x84 and f[k + 1] == k // 4 for k in range(0, 24, 4))]
    print(summary.text(), f"final ball error {plant.final_error_mm:.1f} mm")
    assert summary.exit_code == 0 and 490 <= summary.ticks <= 510
    assert len(received) % 24 == 0 and len(well_formed) == len(frames) and len(frames) >= 490
    assert plant.final_error_mm is not None and plant.final_error_mm < 15.0  # still balanced near the centre after 10 s


def test_the_simulated_plant_dates_a_reading_when_it_arrives_as_a_real_panels(tmp_path: Path) -> None:
    """A real panel's line says nothing of when it was sampled: the loop dates it on arrival. The simulated plant
    dates its readings so too (the sample's time plus the panel's latency), so that a dry run's loop and log see the
    sensing delay as on the bench, and sysid fits it in the total latency (it was missed by the sensor's 30 ms)."""
    twin = tmp_path / "twin.toml"
    twin.write_text("[sensor]\nlatency_ms = 30\nnoise_mm = 0\n")
    plant = SimulatedPlant(twin=str(twin))
    home = CAL.neutral_us.copy()
    rate = plant.sensor.spec.rate_hz
    ages = []
    for k in range(100):
        plant.apply(home)
        got = plant.read(10.0 + 0.02 * k)  # the loop's clock, ahead of the simulator's by 10 s
        if got is not None:
            ages.append(10.0 + 0.02 * k - got[1])
    plant.close()
    assert len(ages) > 90 and min(ages) >= -1e-9 and max(ages) <= 1.0 / rate + 1e-9, (min(ages), max(ages))


@pytest.mark.parametrize("field,value", [("rate_hz", -5.0), ("rate_hz", 0.0), ("rate_hz", 1e5), ("rate_hz", math.nan),
                                         ("duration_s", -1.0), ("duration_s", math.inf), ("watchdog_s", 0.0),
                                         ("max_step_us", -1.0)])  # fmt: skip
def test_deploy_config_refuses_nonsense(field: str, value: float) -> None:
    from stewart_gym.errors import ConfigError

    with pytest.raises(ConfigError, match=field):
        DeployConfig(**{field: value})


class _SlowSensor:
    """A sensor whose every read takes longer than two control periods: the loop misses its deadlines."""

    def read(self, t: float) -> tuple[tuple[float, float], float] | None:
        time.sleep(0.05)
        return (0.0, 0.0), t


def test_a_loop_that_misses_its_deadlines_fails(device: FakeDevice, tmp_path: Path) -> None:
    policy = _pid_bundle(tmp_path)
    drain = Drain(device)
    loop = DeployLoop(policy, ActionMapper("servo-hexapod", CAL, "tilt"), MaestroController(device.path),
                      _SlowSensor(), DeployConfig(rate_hz=200.0, duration_s=0.1, log_path=None))  # fmt: skip
    summary = loop.run()
    drain.stop()
    assert summary.exit_code == 1 and "missed" in summary.message and summary.missed_deadlines > 0.05 * summary.ticks


class _Broken:
    """A policy that never gives a usable action (NaN): every tick holds."""

    obs_size, action_size = 12, 2

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.full(2, np.nan)


class _StillSensor:
    def read(self, t: float) -> tuple[tuple[float, float], float] | None:
        return (0.0, 0.0), t


def test_a_loop_where_every_tick_holds_fails(device: FakeDevice, tmp_path: Path) -> None:
    drain = Drain(device)
    loop = DeployLoop(_Broken(), ActionMapper("servo-hexapod", CAL, "tilt"), MaestroController(device.path),
                      _StillSensor(), DeployConfig(duration_s=0.2, log_path=None))  # fmt: skip
    summary = loop.run()
    drain.stop()
    assert summary.exit_code == 1 and summary.held == summary.ticks > 0 and "no usable action" in summary.message


def test_a_policy_that_does_not_fit_the_action_mode_is_refused(device: FakeDevice, tmp_path: Path) -> None:
    from stewart_gym.errors import PolicyError

    with pytest.raises(PolicyError, match="needs 16 and 6"):
        DeployLoop(_Broken(), ActionMapper("servo-hexapod", CAL, "pose"), MaestroController(device.path),
                   _StillSensor(), DeployConfig(duration_s=0.2, log_path=None))  # fmt: skip


class _EndingSensor:
    """Fresh readings for ``fresh`` reads; then its source has run out (``ended`` says why) and the last reading
    ages; with ``live``, reading after that is a device failure, as a camera that stops delivering frames."""

    def __init__(self, fresh: int, live: bool = False) -> None:
        self.fresh, self.live, self.reads, self.ended, self.last = fresh, live, 0, None, None

    def read(self, t: float) -> tuple[tuple[float, float], float] | None:
        from stewart_gym.errors import DeviceFailure

        self.reads += 1
        if self.reads > self.fresh:
            if self.live:
                raise DeviceFailure("camera 0: the camera stopped delivering frames")
            self.ended = "the video ran out"
            return self.last
        self.last = ((0.0, 0.0), t)
        return self.last


@pytest.mark.parametrize(("fresh", "code"), [(5, 1), (45, 0)])
def test_a_sensor_whose_source_runs_out_is_named_with_its_tick(device: FakeDevice, tmp_path: Path, fresh: int,
                                                               code: int) -> None:  # fmt: skip
    """A video that ends after 5 of 50 ticks: held home, the run fails; after 45: the run completes. Either way the
    summary says at which tick, and why."""
    from conftest import Board

    board = Board(device)
    loop = DeployLoop(_pid_bundle(tmp_path), ActionMapper("servo-hexapod", CAL, "tilt"), MaestroController(device.path),
                      _EndingSensor(fresh), DeployConfig(duration_s=1.0, log_path=None))  # fmt: skip
    summary = loop.run()
    board.stop()
    assert summary.exit_code == code and summary.source_ended_tick == fresh, summary.text()
    assert f"the sensor's source ended at tick {fresh} (the video ran out)" in summary.text()


def test_a_live_camera_lost_mid_run_is_a_device_failure_and_the_board_confirms_home(device: FakeDevice,
                                                                                     tmp_path: Path) -> None:  # fmt: skip
    """The sensor fails, not the port: the board is still asked, and confirms home."""
    from conftest import Board

    board = Board(device)
    controller = MaestroController(device.path)
    controller.monitor()
    loop = DeployLoop(_pid_bundle(tmp_path), ActionMapper("servo-hexapod", CAL, "tilt"), controller,
                      _EndingSensor(10, live=True), DeployConfig(duration_s=1.0, log_path=None))  # fmt: skip
    summary = loop.run()
    board.stop()
    assert summary.exit_code == 2 and summary.ticks == 10, summary.text()
    assert summary.message == "device failure: camera 0: the camera stopped delivering frames"
    assert summary.home == "confirmed", summary.text()
