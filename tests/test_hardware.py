"""Deployment: protocol bytes on fake devices (pty), safety fuzz, watchdog, unplug, Ctrl-C, export parity, dry run."""

from __future__ import annotations

import csv
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import Drain, FakeDevice

from stewart_gym.actions import ActionMapper
from stewart_gym.calibration import ServoCalibration
from stewart_gym.hardware.deploy import DeployConfig, DeployLoop, SimulatedPlant
from stewart_gym.hardware.export import BundlePolicy, export_pid, export_sb3
from stewart_gym.hardware.protocols import SSC32, LineProtocol, Maestro
from stewart_gym.hardware.safety import SafetyLayer
from stewart_gym.hardware.serial_controllers import DeviceError, LineController, MaestroController, SSC32Controller

CAL = ServoCalibration.default("servo-hexapod")
PULSES = np.array([1500.0, 1400.25, 1600.5, 1100.0, 1900.0, 1234.75])


# ------------------------------------------------------------------ protocols
def test_maestro_bytes() -> None:
    assert Maestro.set_target(2, 1500) == bytes([0x84, 0x02, 0x70, 0x2E])
    assert Maestro.set_target(0, 1000.25) == bytes([0x84, 0, 4001 & 0x7F, 4001 >> 7])
    assert Maestro.set_multiple_targets(3, [1500, 1500]) == bytes([0x9F, 2, 3, 0x70, 0x2E, 0x70, 0x2E])
    assert Maestro.set_speed(1, 140) == bytes([0x87, 1, 140 & 0x7F, 140 >> 7])
    assert Maestro.set_acceleration(5, 4) == bytes([0x89, 5, 4, 0])
    assert Maestro.get_position(7) == bytes([0x90, 7])
    assert Maestro.decode_position(bytes([0x70, 0x17])) == 1500.0
    assert Maestro.decode_errors(bytes([0x21, 0x01])) == ["serial signal error", "serial timeout",
                                                          "script program counter error"]  # fmt: skip
    assert Maestro.decode_errors(b"\x00\x00") == []
    with pytest.raises(ValueError):
        Maestro.set_target(24, 1500)
    with pytest.raises(ValueError):
        Maestro.set_target(0, 5000)  # 20000 quarter-µs does not fit 14 bits


def test_ssc32_and_line_bytes() -> None:
    assert SSC32.group_move([0, 1], [1500, 1520], 20) == b"#0P1500#1P1520T20\r"
    assert LineProtocol.frame([1500, 1400.4, 1600.6, 1100, 1900, 1235]) == b"W 1500,1400,1601,1100,1900,1235\n"
    assert LineProtocol.parse_ball("B 12.5,-3.0\r\n") == (12.5, -3.0)
    assert LineProtocol.parse_ball("B -") is None and LineProtocol.parse_ball("ready") is None


def test_fake_maestro_receives_exact_bytes(device: FakeDevice) -> None:
    ctl = MaestroController(device.path, channels=[0, 1, 2, 3, 4, 5])
    ctl.send(PULSES)
    got = device.read_all()
    assert got == b"".join(Maestro.set_target(i, w) for i, w in enumerate(PULSES))
    assert got[8:12] == bytes([0x84, 0x02, 0x02, 0x32])  # 1600.5 µs = 6402 quarter-µs = 50·128 + 2, channel 2
    multi = MaestroController(device.path, channels=range(6), multiple_targets=True)
    multi.send(PULSES)
    assert device.read_all() == Maestro.set_multiple_targets(0, PULSES)

    def answer() -> None:  # the device answers Get Errors with overrun + RX-buffer-full
        for _ in range(50):
            data = device.read_all(0.02)
            if Maestro.GET_ERRORS in data:
                device.write(bytes([0x06, 0x00]))
                return

    threading.Thread(target=answer, daemon=True).start()
    assert ctl.errors() == ["serial overrun error", "serial RX buffer full"]
    ctl.close()
    multi.close()


def test_fake_ssc32_group_framing(device: FakeDevice) -> None:
    ctl = SSC32Controller(device.path, channels=[10, 11, 12, 13, 14, 15], move_ms=20)
    ctl.send(PULSES)
    assert device.read_all() == b"#10P1500#11P1400#12P1600#13P1100#14P1900#15P1235T20\r"
    ctl.close()


def test_line_controller_waits_for_ready_and_reads_the_panel(device: FakeDevice) -> None:
    def boot() -> None:  # the Uno resets when the port opens and boots for 0.3 s
        time.sleep(0.3)
        device.write(b"garbage\nready\n")

    threading.Thread(target=boot, daemon=True).start()
    t0 = time.monotonic()
    ctl = LineController(device.path, ready_timeout=3.0)
    assert time.monotonic() - t0 >= 0.29
    assert device.read_all(0.05) == b""  # nothing was sent before "ready"
    ctl.send(PULSES)
    assert device.read_all() == b"W 1500,1400,1600,1100,1900,1235\n"
    device.write(b"B 10.0,-5.5\nB 12.0,-6.0\n")
    time.sleep(0.05)
    (xy, _t) = ctl.poll_ball()
    assert xy == (12.0, -6.0)
    ctl.close()


def test_line_controller_without_ready_fails_clearly(device: FakeDevice) -> None:
    with pytest.raises(DeviceError, match="no 'ready' line"):
        LineController(device.path, ready_timeout=0.2)


# --------------------------------------------------------------------- safety
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


class _StaticSensor:
    """A BallSensor whose readings are 5 ms old, or half a second old once it stalls."""

    def __init__(self, stall_after: int | None = None, interrupt_at: int | None = None) -> None:
        self.n, self.stall_after, self.interrupt_at = 0, stall_after, interrupt_at

    def read(self, t: float) -> tuple[tuple[float, float], float] | None:
        self.n += 1
        if self.interrupt_at is not None and self.n >= self.interrupt_at:
            raise KeyboardInterrupt
        if self.stall_after is not None and self.n > self.stall_after:
            return (0.03, 0.0), t - 0.5  # the last reading, half a second old
        return (0.03, 0.0), t - 0.005


@pytest.mark.slow
def test_fuzz_one_million_actions_never_leave_limits_or_rate() -> None:
    for mode in ("tilt", "pose", "pulse"):
        mapper = ActionMapper("servo-hexapod", CAL, mode)
        rng = np.random.default_rng(2)
        policy = _Fuzz(1) if mode == "tilt" else (lambda obs, rng=rng: rng.normal(0, 1e3, 6) *
                                                    rng.choice([1, np.nan, np.inf], 6, p=[0.8, 0.1, 0.1]))  # fmt: skip
        loop = DeployLoop(policy, mapper, controller=None, sensor=_StaticSensor())  # type: ignore[arg-type]
        n = 600_000 if mode == "tilt" else 200_000
        last = loop.safety.last.copy()
        outside = rate = 0
        for k in range(n):
            _, _, pulses, _ = loop.compute(((0.01, 0.0), 0.005), k * 0.02)
            outside += int(np.any(pulses < CAL.min_us) or np.any(pulses > CAL.max_us) or not np.all(np.isfinite(pulses)))
            rate += int(np.any(np.abs(pulses - last) > loop.safety.max_step_us + 1e-9))
            last = pulses
        assert outside == 0 and rate == 0, (mode, outside, rate)


# ----------------------------------------------------------------- the loop
def _pid_bundle(tmp_path: Path) -> BundlePolicy:
    from stewart_gym.registry import POLICY_DIR

    return BundlePolicy(export_pid(POLICY_DIR / "pid_gains.json", tmp_path / "pid"))


def test_unplug_stops_within_a_tick_and_keeps_the_log(device: FakeDevice, tmp_path: Path) -> None:
    log = tmp_path / "log.csv"
    ctl = MaestroController(device.path)
    loop = DeployLoop(_pid_bundle(tmp_path), ActionMapper("servo-hexapod", CAL), ctl, _StaticSensor(),
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
                      MaestroController(device.path), _StaticSensor(stall_after=10),
                      DeployConfig(duration_s=1.0, log_path=str(log)))  # fmt: skip
    summary = loop.run()
    rows = list(csv.DictReader(log.open()))
    assert summary.stale >= 30 and summary.homing >= 30 and summary.exit_code == 0
    assert all(r["stale"] == "0" for r in rows[:10]) and all(r["homing"] == "1" for r in rows[15:])
    final = np.array([float(rows[-1][f"pulse{i}_us"]) for i in range(6)])
    assert final == pytest.approx(CAL.neutral_us)  # moved home and stayed there


def test_ctrl_c_sends_home_before_closing(device: FakeDevice, tmp_path: Path) -> None:
    ctl = MaestroController(device.path)
    loop = DeployLoop(lambda obs: np.array([1.0, -1.0]), ActionMapper("servo-hexapod", CAL), ctl,
                      _StaticSensor(interrupt_at=20), DeployConfig(log_path=str(tmp_path / "log.csv")))  # fmt: skip
    summary = loop.run()
    assert summary.message == "stopped by Ctrl-C" and summary.homed and summary.exit_code == 0
    data = device.read_all()
    home_frame = b"".join(Maestro.set_target(i, w) for i, w in enumerate(CAL.neutral_us))
    assert data.endswith(home_frame) and not ctl.serial.is_open


# --------------------------------------------------------------------- export
def test_export_parity_with_sb3_predict(tmp_path: Path) -> None:
    """Bundle (onnxruntime + numpy) vs SB3 predict(deterministic=True) on 1,000 observations, for PPO, SAC and TD3."""
    import gymnasium as gym
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from stewart_gym.sb3_models import load_sb3

    obs = np.random.default_rng(0).normal(0, 1, (1000, 12)).astype(np.float32)
    for algo in (PPO, SAC, TD3):
        venv = VecNormalize(DummyVecEnv([lambda: gym.make("StewartBallBalance-v0")]))
        kwargs = {"n_steps": 64, "batch_size": 32} if algo is PPO else {"learning_starts": 10, "buffer_size": 500}
        model = algo("MlpPolicy", venv, policy_kwargs={"net_arch": [32, 32]}, device="cpu", seed=0, **kwargs)
        model.learn(100)
        folder = tmp_path / algo.__name__
        folder.mkdir()
        model.save(folder / "model.zip")
        venv.save(str(folder / "vecnormalize.pkl"))
        venv.close()
        bundle = BundlePolicy(export_sb3(folder, tmp_path / f"{algo.__name__}_bundle"))
        reference = load_sb3(folder)
        expected = reference.predict(obs, deterministic=True)[0]
        got = bundle(obs)
        assert np.abs(got - expected).max() <= 1e-5, algo.__name__
        assert not list((tmp_path / f"{algo.__name__}_bundle").glob("*.pkl"))  # no pickle in the bundle


def test_bundle_loader_needs_no_torch(tmp_path: Path) -> None:
    """The deployment side imports onnxruntime and numpy only."""
    import subprocess
    import sys

    bundle = export_pid(Path(__file__).resolve().parents[1] / "stewart_gym/policies/pid_gains.json", tmp_path / "b")
    code = ("import sys; sys.modules['torch'] = None\n"  # importing torch now fails
            "from stewart_gym.hardware.export import BundlePolicy\n"
            f"import numpy as np; p = BundlePolicy({str(bundle)!r}); print(p(np.zeros(12)).shape)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "(2,)" in out.stdout


# ----------------------------------------------------------------- end to end
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


# ------------------------------------------------------------ loop outcomes
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
                      _SlowSensor(), DeployConfig(rate_hz=200.0, duration_s=0.5, log_path=None))  # fmt: skip
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
