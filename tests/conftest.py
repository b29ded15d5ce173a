"""Shared fixtures and reference implementations for the tests."""

from __future__ import annotations

import math
import os
import pty
import re
import select
import subprocess
import sys
import threading
import time
import tty

import numpy as np
import pytest

from stewart_gym.geometry import PlatformGeometry
from stewart_gym.presets import load_preset, preset_names

#: Half-widths of a box of poses around home that is mostly reachable, per preset:
#: (translation m, angle rad). Used to sample workspaces in property tests.
WORKSPACE_BOX = {
    "servo-hexapod": (0.010, math.radians(6)),
    "memememe-liverpool": (0.02, math.radians(10)),
    "desk-rect": (0.012, math.radians(6)),
    "senilov2018": (0.05, math.radians(10)),
    "mathcad-micro": (0.0006, math.radians(3)),
}


def pytest_configure(config: pytest.Config) -> None:
    """``--dist loadgroup`` (``make test``) keeps each ``xdist_group`` on one worker: the Ray sweeps never start
    two clusters at once, and a costly module fixture is made once. On pytest 9.2 with pytest-xdist up to 3.8
    the groups are ignored without a word (pytest-dev/pytest-xdist#1386): the run stops here and says so."""
    if config.getoption("dist", "no") != "loadgroup" or hasattr(config, "workerinput"):
        return
    from importlib.metadata import version

    pytest_version = tuple(int(p) for p in re.findall(r"\d+", pytest.__version__)[:2])
    xdist_version = tuple(int(p) for p in re.findall(r"\d+", version("pytest-xdist"))[:2])
    if pytest_version >= (9, 2) and xdist_version <= (3, 8):
        pytest.exit(f"pytest {pytest.__version__} with pytest-xdist {version('pytest-xdist')} ignores xdist_group "
                    "(pytest-dev/pytest-xdist#1386): install the pytest that constraints.txt allows", returncode=4)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The slow tests run first, each module's in its own order: on worker processes (``make test``), the run then
    ends on short tests that fill in around the long ones, not on a long one that one worker runs while the
    other has nothing left to do."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_a_temporary_folder(tmp_path_factory: pytest.TempPathFactory) -> None:
    """SB3 makes a folder for its logger (``$SB3_LOGDIR``, else a new ``SB3-<time>`` in the system's temporary
    folder) for a model that learns without one set, as ``examples/train_sb3.py`` does: here it goes with the
    tests' own temporary files."""
    os.environ.setdefault("SB3_LOGDIR", str(tmp_path_factory.mktemp("sb3_logs")))


@pytest.fixture(params=preset_names())
def preset(request: pytest.FixtureRequest) -> PlatformGeometry:
    return load_preset(request.param)


def reference_rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw)·Ry(pitch)·Rx(roll) from the three elementary matrices of source 000."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def reference_servo_angles(geo: PlatformGeometry, pose: np.ndarray, pivot: np.ndarray | None = None) -> np.ndarray:
    """Source 000 eq. 9 literally, one pose and one leg at a time: asin(L/√(M²+N²)) − atan2(N, M)."""
    c = np.zeros(3) if pivot is None else np.asarray(pivot)
    rot = reference_rotation(*pose[3:])
    out = np.empty(6)
    for i in range(6):
        q = np.array([0, 0, geo.home_height]) + pose[:3] + c + rot @ (geo.platform_anchors[i] - c)
        b = geo.base_anchors[i]
        leg = q - b
        a, s, beta = geo.horn_length, geo.rod_length, geo.servo_beta[i]
        big_l = leg @ leg - (s * s - a * a)
        big_m = 2 * a * (q[2] - b[2])
        big_n = 2 * a * (math.cos(beta) * (q[0] - b[0]) + math.sin(beta) * (q[1] - b[1]))
        ratio = big_l / math.hypot(big_m, big_n)
        out[i] = math.asin(ratio) - math.atan2(big_n, big_m) if abs(ratio) <= 1 else math.nan
    return out


def uniform_draw(rng: np.random.Generator, low: float, high: float) -> float:
    """One uniform draw in [low, high) from one ``rng.random()``: low + (high − low) · d, in two roundings, as
    NumPy's ``rng.uniform(low, high)`` computes it on x86-64 and in its Linux arm64 wheels. Its macOS arm64 wheels
    compute it in one rounding (a fused multiply-add), which can differ in the last bit
    (``tests/envs/test_randomization.py``): the env's draws are these, on every machine."""
    return low + (high - low) * rng.random()


def random_poses(name: str, n: int, seed: int = 0) -> np.ndarray:
    """n poses uniformly in the preset's WORKSPACE_BOX."""
    t, a = WORKSPACE_BOX[name]
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, (n, 6)) * np.array([t, t, t, a, a, a])


def mirror_permutation(geo: PlatformGeometry) -> np.ndarray:
    """π with mirror_x(b_i) = b_π(i) and mirror_x(p_i) = p_π(i), mirroring x → −x."""
    flip = np.array([-1.0, 1.0, 1.0])
    perm = np.empty(6, dtype=int)
    for i in range(6):
        d = np.linalg.norm(geo.base_anchors - geo.base_anchors[i] * flip, axis=1) + np.linalg.norm(
            geo.platform_anchors - geo.platform_anchors[i] * flip, axis=1
        )
        perm[i] = int(np.argmin(d))
        assert d[perm[i]] < 1e-9, f"{geo.name} is not mirror-symmetric about the y-z plane"
    return perm


def sg(*args: str, cwd: str | os.PathLike | None = None, timeout: float = 600, stdin: str | None = None,
       env: dict | None = None) -> subprocess.CompletedProcess:  # fmt: skip
    """Run ``python -m stewart_gym ARGS`` as a user would (``env`` adds to this process's environment)."""
    return subprocess.run([sys.executable, "-m", "stewart_gym", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=timeout, input=stdin, env={**os.environ, **(env or {})})  # fmt: skip


def cli(capfd: pytest.CaptureFixture, *args: str, cwd: str | os.PathLike | None = None) -> tuple[int, str, str]:
    """Run ``stewart-gym ARGS`` in this process, through the command line's ``main([...])``, as fast as a
    function call: (exit code, stdout, stderr), captured at the file descriptors (what a terminal would show,
    the engines' own C output included). ``cwd``: the folder it runs in."""
    from stewart_gym.cli import main

    capfd.readouterr()
    before = os.getcwd()
    if cwd is not None:
        os.chdir(cwd)
    try:
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse: --help, or a usage error
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        os.chdir(before)
    out, err = capfd.readouterr()
    return int(code), out, err


def sg_in(capfd: pytest.CaptureFixture, *args: str, cwd: str | os.PathLike | None = None) -> subprocess.CompletedProcess:
    """What :func:`sg` gives, run through :func:`cli` in this process: for commands whose processes, signals and
    ports do not matter, without the two seconds a fresh interpreter takes to import torch and the engines."""
    code, out, err = cli(capfd, *args, cwd=cwd)
    return subprocess.CompletedProcess(["stewart-gym", *args], code, out, err)


class FakeDevice:
    """A pseudo-terminal: the code under test opens ``path`` with pyserial; the test reads/writes ``master``."""

    def __init__(self) -> None:
        self.master, slave = pty.openpty()
        tty.setraw(slave)  # as a serial port: no echo of what the board sends back to it, no line endings changed
        self.path = os.ttyname(slave)
        self._slave = slave  # keep the slave open so the pty survives until the client opens it
        os.set_blocking(self.master, False)

    def read_all(self, wait: float = 0.1, size: int | None = None, timeout: float = 10.0) -> bytes:
        """What the code under test has written: read until at least ``size`` bytes have come (when given) and
        then nothing more for ``wait`` seconds, or until ``timeout``. The kernel hands bytes written to a pty over to
        its other end asynchronously, late on a loaded machine, so a fixed sleep before one read can read nothing."""
        out = b""
        start = quiet_since = time.monotonic()
        while time.monotonic() - start < timeout:
            chunk = b""
            master = self.master
            if master < 0:  # closed
                return out
            try:
                if select.select([master], [], [], 0.005)[0]:
                    chunk = os.read(master, 4096)
            except BlockingIOError:
                pass
            except (OSError, ValueError):  # EIO: the other end is closed and nothing is left; EBADF: unplugged
                return out
            if chunk:
                out += chunk
                quiet_since = time.monotonic()
            elif (size is None or len(out) >= size) and time.monotonic() - quiet_since >= wait:
                return out
        return out

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    @property
    def closed(self) -> bool:
        return self.master < 0

    def unplug(self) -> None:
        self.close()

    def close(self) -> None:
        """Close both ends. The descriptors are forgotten first, so that a reader thread still running (a test
        that failed before stopping its :class:`Drain` or :class:`Board`) meets -1 and stops, and never reads
        a descriptor number that the system has since given to something else (another test's pipe)."""
        fds, self.master, self._slave = (self.master, self._slave), -1, -1
        for fd in fds:
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass


@pytest.fixture
def device() -> FakeDevice:
    d = FakeDevice()
    yield d
    d.close()


class Drain:
    """Collects everything the code under test writes to a :class:`FakeDevice`, in a background thread."""

    def __init__(self, device: FakeDevice) -> None:
        self.device, self.data, self._stop = device, bytearray(), threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set() and not self.device.closed:
            self.data.extend(self.device.read_all(0.01))

    def stop(self, quiet: float = 0.2, timeout: float = 10.0) -> bytes:
        """Everything received, once nothing more has come for ``quiet`` seconds (the pty's hand-over lags)."""
        start, seen = time.monotonic(), -1
        while len(self.data) != seen and time.monotonic() - start < timeout:
            seen = len(self.data)
            time.sleep(quiet)
        self._stop.set()
        self._thread.join(1.0)
        return bytes(self.data)


class Board:
    """A servo board on a :class:`FakeDevice`, as the code under test meets it: a thread reads what it writes,
    parses it with the virtual device's parsers (the board's own protocol), keeps every frame, answers position
    queries with the pulses last received, and with the line protocol says ``ready`` until the first frame and
    sends the panel's lines from ``lines(t)`` (t: seconds since the first frame, 0 before it) every 10 ms.

    Faults: ``answer=False`` (a board whose replies are not wired), ``stop_reading_after`` (s after the first
    frame: it reads nothing more; the pty fills), ``read_rate`` (bytes a second it reads at most),
    ``answer_offset_us`` (it reports pulses this far from those it received), ``lose_home_frames`` (Maestro: the
    first so many home frames, six Set Targets of 1500 µs, after the platform has moved are lost on the line).
    """

    def __init__(self, device: FakeDevice, protocol: str = "maestro", lines=None, answer: bool = True,
                 stop_reading_after: float | None = None, read_rate: float | None = None,
                 answer_offset_us: float = 0.0, lose_home_frames: int = 0) -> None:  # fmt: skip
        self.lose_home_frames, self.lost_frames = lose_home_frames, 0
        self._moved = False  # whether a frame has gone more than 5 µs from home
        from stewart_gym.hardware.protocols import LineProtocol
        from stewart_gym.hardware.virtual_device import PARSERS, Parsed

        self.device, self.protocol, self.lines, self.answer = device, protocol, lines, answer
        self.stop_reading_after, self.read_rate, self.answer_offset_us = stop_reading_after, read_rate, answer_offset_us
        self.held: dict[int, float] = {}
        self._targets: list[float] = []  # targets of the frame being received
        self.frames: list[np.ndarray] = []  # each complete frame's six pulses, µs
        self.data = bytearray()
        self.queries = 0
        self.first_frame: float | None = None
        self._parsed_type = Parsed
        position = self._position
        self.parser = PARSERS[protocol](range(6), position, lambda: None)
        self._ready_line = LineProtocol.ready()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _position(self, channel: int, pending: float | None = None) -> float:
        return float(pending if pending is not None else self.held.get(channel, 0.0)) + self.answer_offset_us

    def _run(self) -> None:
        budget, last_ready, start = 0.0, -1.0, time.monotonic()
        while not self._stop.is_set() and not self.device.closed:
            now = time.monotonic()
            since = None if self.first_frame is None else now - self.first_frame
            reading = not (self.stop_reading_after is not None and since is not None and since >= self.stop_reading_after)
            size = 4096
            if self.read_rate is not None:
                budget = min(budget + self.read_rate * 0.01, max(1.0, self.read_rate))
                size = int(budget)
            chunk = b""
            master = self.device.master
            if reading and size >= 1 and master >= 0:
                try:
                    if select.select([master], [], [], 0)[0]:
                        chunk = os.read(master, size)
                except (BlockingIOError, OSError, ValueError):
                    chunk = b""
                budget -= len(chunk)
            if chunk:
                self.data.extend(chunk)
                home = [bytes([0x84, c, 0x70, 0x2E]) for c in range(6)]  # Set Target 1500 µs on channels 0…5
                if self._moved and self.lost_frames < self.lose_home_frames and all(h in chunk for h in home):
                    for h in home:  # the home frame lost on the line
                        chunk = chunk.replace(h, b"", 1)
                    self.lost_frames += 1
                parsed = self._parsed_type()
                self.parser.feed(chunk, parsed)
                for channel, us in parsed.targets:
                    self.held[channel] = us
                    self._targets.append(us)
                    if len(self._targets) == 6:
                        frame = np.array(self._targets)
                        self._targets = []
                        self._moved = self._moved or bool(np.any(np.abs(frame - 1500.0) > 5.0))
                        self.frames.append(frame)
                        if self.first_frame is None:
                            self.first_frame = time.monotonic()
                self.queries += len(parsed.replies)
                if self.answer:
                    for reply in parsed.replies:
                        self._write(reply)
            if self.protocol == "line":
                if now - last_ready >= 0.2:  # as after each reset (a host opening the port resets an Uno)
                    self._write(self._ready_line)
                    last_ready = now
                if self.lines is not None and now - start >= 0.0:
                    line = self.lines(0.0 if since is None else since)
                    if line:
                        self._write(line)
            self._stop.wait(0.01)

    def _write(self, data: bytes) -> None:
        try:
            self.device.write(data)
        except OSError:  # unplugged
            pass

    def stop(self, quiet: float = 0.2, timeout: float = 10.0) -> bytes:
        """Everything received, once nothing more has come for ``quiet`` seconds."""
        begin, seen = time.monotonic(), -1
        while len(self.data) != seen and time.monotonic() - begin < timeout:
            seen = len(self.data)
            time.sleep(quiet)
        self._stop.set()
        self._thread.join(1.0)
        return bytes(self.data)


def maestro_frames(data: bytes) -> np.ndarray:
    """The pulse widths (µs) of each Set Target ×6 frame in bytes a Maestro received; the Get Position queries
    between the frames set aside."""
    commands, k = [], 0
    while k < len(data):
        if data[k] == 0x90:  # Get Position: 90 ch
            k += 2
            continue
        commands.append(data[k:k + 4])
        k += 4
    frames = b"".join(commands)
    frames = frames[: len(frames) - len(frames) % 24]
    raw = np.frombuffer(frames, dtype=np.uint8).reshape(-1, 6, 4)
    assert np.all(raw[:, :, 0] == 0x84) and np.all(raw[:, :, 1] == np.arange(6))
    return (raw[:, :, 2].astype(int) + (raw[:, :, 3].astype(int) << 7)) / 4.0


class StaticSensor:
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


def xml_differences(a: str, b: str, tol: float = 1e-8) -> list[str]:
    """Where two URDF or MJCF texts differ beyond ``tol`` (absolute, m/rad/kg): same elements, same attributes, every
    number within the tolerance. Comparing text would fail on rounding noise that depends on the CPU (a
    coordinate of 6e-18 where another machine computes -0)."""
    import xml.etree.ElementTree as ET

    out: list[str] = []

    def walk(x: ET.Element, y: ET.Element, where: str) -> None:
        if x.tag != y.tag or set(x.attrib) != set(y.attrib) or len(x) != len(y):
            out.append(f"{where}: <{x.tag} {sorted(x.attrib)}> vs <{y.tag} {sorted(y.attrib)}>")
            return
        for key, vx in x.attrib.items():
            tx, ty = vx.split(), y.attrib[key].split()
            try:
                nx, ny = np.array(tx, dtype=float), np.array(ty, dtype=float)
            except ValueError:
                if tx != ty:
                    out.append(f"{where}/@{key}: {vx!r} vs {y.attrib[key]!r}")
                continue
            if nx.shape != ny.shape or not np.allclose(nx, ny, rtol=0, atol=tol):
                out.append(f"{where}/@{key}: {vx!r} vs {y.attrib[key]!r}")
        for k, (cx, cy) in enumerate(zip(x, y)):
            walk(cx, cy, f"{where}/{cx.tag}[{k}]")

    walk(ET.fromstring(a), ET.fromstring(b), ET.fromstring(a).tag)
    return out


def random_reachable_poses(n: int, seed: int, scale: float = 1.0, geometry: str = "servo-hexapod") -> np.ndarray:
    """``n`` random reachable poses of a rotary build (±15 mm, ±10 mm heave, ±9° tilts, ±12° yaw, × ``scale``)."""
    from stewart_gym.kinematics import inverse_kinematics

    geo = load_preset(geometry)
    rng = np.random.default_rng(seed)
    box = np.array([0.015, 0.015, 0.010, math.radians(9), math.radians(9), math.radians(12)]) * scale
    poses = rng.uniform(-1, 1, (20 * n, 6)) * box
    return poses[inverse_kinematics(geo, poses).reachable][:n]


def settled_pose_errors(sim: object, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Worst (mm, deg) error of a backend's settled pose against each commanded pose (IK → pulses, 40 control
    steps) and against FK of the pulses its servos hold."""
    from stewart_gym.kinematics import forward_kinematics, inverse_kinematics

    geo = sim.geometry
    sim.reset()
    worst, worst_fk = np.zeros(2), np.zeros(2)
    for pose in poses:
        sim.command(sim.calibration.pulse_widths(inverse_kinematics(geo, pose).servo_angles))
        for _ in range(40):
            sim.step()
        got = sim.platform_pose()
        fk = forward_kinematics(geo, servo_angles=sim.calibration.angles(sim.held_pulses()), guess=pose)
        for acc, ref in ((worst, pose), (worst_fk, fk.pose)):
            err = np.abs(got - ref)
            acc[:] = np.maximum(acc, [err[:3].max() * 1e3, math.degrees(err[3:].max())])
    return worst, worst_fk


def servo_step_response(sim_class: type, spec: object, delta_us: float,
                        seconds: float = 0.3) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A backend's servos from rest: +delta_us (even) / −delta_us (odd, mirrored) on every servo at 1 kHz;
    (time since the command s, servo angles from the start rad) at every physics step."""
    with sim_class(physics_hz=1000, control_hz=1000, servo_spec=spec) as sim:
        for _ in range(100):
            sim.step()
        start = sim.servo_angles()
        sim.command(sim.calibration.neutral_us + sim.calibration.direction * delta_us)
        t, angles = [], []
        for _ in range(int(seconds * 1000)):
            sim.step()
            t.append(sim.time - 0.1)
            angles.append(sim.servo_angles() - start)
    return np.array(t), np.array(angles)


def linear_pose_errors(sim_class: type, name: str) -> tuple[float, float, float]:
    """A 6-UPS preset in a backend: 100 random reachable poses through IK → leg lengths → pulses (dead band and
    quantisation off), 1.5 s each; the worst position error (m), angle error (deg) and loop gap (m)."""
    from dataclasses import replace

    from stewart_gym.calibration import ServoCalibration
    from stewart_gym.kinematics import inverse_kinematics
    from stewart_gym.sim.servo_model import LINEAR_ACTUATOR

    geo = load_preset(name)
    t, a = (0.05, math.radians(8)) if name == "senilov2018" else (0.0006, math.radians(3))
    rng = np.random.default_rng(7)
    poses = rng.uniform(-1, 1, (600, 6)) * np.array([t, t, t / 2, a, a, a])
    poses = poses[inverse_kinematics(geo, poses).reachable][:100]
    assert len(poses) == 100
    cal = ServoCalibration.default(geo)
    assert cal.actuator == "linear"
    worst_pos = worst_ang = worst_gap = 0.0
    with sim_class(geo, servo_spec=replace(LINEAR_ACTUATOR, deadband_us=0.0, resolution_us=0.0)) as sim:
        assert sim.calibration == cal
        for pose in poses:
            sim.command(cal.pulse_widths(inverse_kinematics(geo, pose).leg_lengths))
            for _ in range(int(1.5 * sim.control_hz)):
                sim.step()
                worst_gap = max(worst_gap, sim.constraint_error())
            err = sim.platform_pose() - pose
            worst_pos = max(worst_pos, float(np.linalg.norm(err[:3])))
            worst_ang = max(worst_ang, float(np.max(np.abs(np.degrees(err[3:])))))
    return worst_pos, worst_ang, worst_gap


def load_example(name: str):
    """``examples/NAME.py`` as a module (each offers ``main(argv)``), run as a user would run the script."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"example_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def ball_presets() -> list[str]:
    """The presets that can carry the ball (a plate big enough): the ones the LQR is designed for."""
    from stewart_gym.envs.ball_env import check_ball_geometry
    from stewart_gym.errors import ConfigError

    names = []
    for name in preset_names():
        try:
            check_ball_geometry(name)
            names.append(name)
        except ConfigError:
            pass
    return names


def lqr_obs(ball_mm: tuple[float, float], rows: int = 0) -> np.ndarray:
    """An observation with the ball at rest ``ball_mm`` from a target at the centre, the plate level."""
    obs = np.zeros(12, dtype=np.float32)
    obs[0:2] = np.asarray(ball_mm) / 150.0  # positions in plate half-widths (150 mm)
    return np.tile(obs, (rows, 1)) if rows else obs


def circle_velocities(periods: int, dt: float = 0.02, radius: float = 0.06, period_s: float = 8.0) -> np.ndarray:
    """The circle target's velocity (m/s) at each control period (as :class:`~stewart_gym.envs.targets.Circle`)."""
    w = 2 * math.pi / period_s
    t = np.arange(periods) * dt
    return np.stack([-radius * w * np.sin(w * t), radius * w * np.cos(w * t)], axis=-1)
