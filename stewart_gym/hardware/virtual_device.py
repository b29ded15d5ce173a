"""A virtual servo board with the platform attached: a pseudo-terminal that behaves like the real hardware.

``stewart-gym virtual-device`` opens a pty, parses exactly the bytes a Pololu
Maestro, a Lynxmotion SSC-32 or the PCA9685 Arduino sketch would receive, and
drives a simulated twin (PyBullet or MuJoCo, through
:class:`~stewart_gym.hardware.deploy.SimulatedPlant`) in real time from the pulse
widths it receives. It answers queries (Maestro Get Position and Get Errors,
SSC-32 ``Q`` and ``QP``), sends the sketch's ``ready`` line, and with the line
protocol reports the ball as the sketch does: ``B x,y`` (mm) at 100 Hz, with the
touch panel's noise and latency. Faults are injected on request
(:class:`Faults`). Like the Maestro, the board clamps every target to its
channel limits: whatever arrives, corrupted or not, no servo leaves them.

The twin waits, powered down, until the first valid target arrives (a servo
gets no pulse before that), then runs in real time.
"""

from __future__ import annotations

import contextlib
import fcntl
import math
import os
import pty
import re
import stat
import time
import tty
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stewart_gym.calibration import ServoCalibration
from stewart_gym.errors import ConfigError
from stewart_gym.hardware.protocols import LineProtocol
from stewart_gym.sensing import reading_is_valid

if TYPE_CHECKING:
    from stewart_gym.camera import CameraSpec
    from stewart_gym.vision import CameraConfig

__all__ = ["PARSERS", "Faults", "LineParser", "MaestroParser", "ParserFactory", "SSC32Parser", "VirtualDevice",
           "VirtualSummary", "stream_camera_config"]

#: Hz: how often the sketch reports the ball, and the rate the platform is simulated at (one step per period).
TICK_HZ = 100
#: Hz: how often the board reads its input (a frame acts within 1/POLL_HZ of its arrival).
POLL_HZ = 500


@dataclass(frozen=True)
class Faults:
    """Faults to inject.

    Attributes:
        drop_rate: fraction of received bytes lost (0…1).
        corrupt_rate: fraction of received bytes with one random bit flipped (0…1).
        stall_sensor_after_s: s after the first frame when ``B`` reports stop (line protocol); None: never.
        latency_ms: ms added before a received frame acts and before a report leaves.
        unplug_after_s: s after the first frame when the board disappears (the pty closes); None: never.
        stop_reading_after_s: s after the first frame when the board stops reading its input (a hung board: the
            bytes pile up unread); None: never.
        read_bytes_per_s: the most bytes a second the board reads (a board too slow for the frames); None: no
            limit.
    """

    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    stall_sensor_after_s: float | None = None
    latency_ms: float = 0.0
    unplug_after_s: float | None = None
    stop_reading_after_s: float | None = None
    read_bytes_per_s: float | None = None

    def __post_init__(self) -> None:
        for key in ("drop_rate", "corrupt_rate"):
            v = getattr(self, key)
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise ConfigError(f"{key.replace('_', '-')} must be a fraction in [0, 1], got {v!r}")
        if not (math.isfinite(self.latency_ms) and 0.0 <= self.latency_ms <= 1000.0):
            raise ConfigError(f"latency-ms must be in [0, 1000], got {self.latency_ms!r}")
        for key in ("stall_sensor_after_s", "unplug_after_s", "stop_reading_after_s"):
            v = getattr(self, key)
            if v is not None and not (math.isfinite(v) and v >= 0.0):
                raise ConfigError(f"{key.removesuffix('_s').replace('_', '-')} must be ≥ 0 s, got {v!r}")
        v = self.read_bytes_per_s
        if v is not None and not (math.isfinite(v) and v > 0.0):
            raise ConfigError(f"read-rate must be a positive number of bytes a second, got {v!r}")


# ----------------------------------------------------------------- parsers
@dataclass
class Parsed:
    """What a parser made of the bytes fed so far."""

    targets: list[tuple[int, float]] = field(default_factory=list)  # (channel, µs)
    replies: list[bytes] = field(default_factory=list)
    messages: int = 0
    malformed: int = 0

    def latest(self, channel: int) -> float | None:
        """The last target for ``channel`` among those parsed so far (a query answers after them), or None."""
        return next((us for c, us in reversed(self.targets) if c == channel), None)


class MaestroParser:
    """Pololu Maestro compact and Pololu protocols: command bytes ≥ 0x80, 7-bit data bytes.

    ``position(channel, pending)`` gives what Get Position answers (µs): the target ``pending`` received in the
    same bytes before the query, if any, else the board's current one. A data
    byte outside a command, an unknown command, or a command cut short by the
    next command byte is malformed and sets the protocol-error bit, as the
    board does.
    """

    #: command byte → number of data bytes (Set Multiple Targets: from its count byte)
    LENGTHS = {0x84: 3, 0x87: 3, 0x89: 3, 0x90: 1, 0x93: 0, 0xA1: 0, 0xA2: 0, 0x9F: None}
    PROTOCOL_ERROR = 1 << 4

    def __init__(self, position: Callable[[int, float | None], float], home: Callable[[], None]) -> None:
        self._position, self._home = position, home
        self._msg: list[int] = []
        self.errors = 0

    def feed(self, data: bytes, out: Parsed) -> None:
        for b in data:
            if b >= 0x80:
                if self._msg:
                    self._bad(out)
                self._msg = [b]
                if b == 0xAA:
                    continue
                if b not in self.LENGTHS:
                    self._bad(out)
                    continue
            elif not self._msg:
                self._bad(out)
                continue
            else:
                self._msg.append(b)
            self._complete(out)

    def _bad(self, out: Parsed) -> None:
        out.malformed += 1
        self.errors |= self.PROTOCOL_ERROR
        self._msg = []

    def _complete(self, out: Parsed) -> None:
        msg = self._msg
        if msg[0] == 0xAA:  # Pololu protocol: AA device command&0x7F data…
            if len(msg) < 3:
                return
            cmd, data = msg[2] | 0x80, msg[3:]
            if cmd not in self.LENGTHS:
                self._bad(out)
                return
        else:
            cmd, data = msg[0], msg[1:]
        need = self.LENGTHS[cmd]
        if need is None:  # 9F n first (lo hi)×n
            need = 2 + 2 * data[0] if data else 1
        if len(data) < need:
            return
        self._msg = []
        out.messages += 1
        if cmd == 0x84:
            out.targets.append((data[0], (data[1] | data[2] << 7) / 4.0))
        elif cmd == 0x9F:
            n, first = data[0], data[1]
            out.targets += [(first + k, (data[2 + 2 * k] | data[3 + 2 * k] << 7) / 4.0) for k in range(n)]
        elif cmd == 0x90:
            q = int(round(self._position(data[0], out.latest(data[0])) * 4))
            out.replies.append(bytes([q & 0xFF, q >> 8 & 0xFF]))
        elif cmd == 0xA1:
            out.replies.append(bytes([self.errors & 0xFF, self.errors >> 8 & 0xFF]))
            self.errors = 0
        elif cmd == 0x93:
            out.replies.append(b"\x00")  # not moving: targets act at once
        elif cmd == 0xA2:
            self._home()


class SSC32Parser:
    """Lynxmotion SSC-32: CR-terminated ASCII. ``#<ch>P<µs>…[T<ms>]`` moves, ``Q`` → ``.``, ``QP<ch>`` → µs/10."""

    MOVE = re.compile(r"^(?:#\d{1,2}P\d{3,4}(?:S\d+)?)+(?:T\d+)?$")
    PART = re.compile(r"#(\d{1,2})P(\d{3,4})")

    def __init__(self, position: Callable[[int, float | None], float]) -> None:
        self._position = position
        self._buffer = b""

    def feed(self, data: bytes, out: Parsed) -> None:
        self._buffer += data
        *lines, self._buffer = self._buffer.split(b"\r")
        if len(self._buffer) > 512:  # no CR for far too long: garbage
            self._buffer, out.malformed = b"", out.malformed + 1
        for raw in lines:
            line = raw.decode("ascii", "replace").strip()
            if not line:
                continue
            if self.MOVE.match(line):
                out.messages += 1
                out.targets += [(int(c), float(w)) for c, w in self.PART.findall(line)]
            elif line == "Q":
                out.messages += 1
                out.replies.append(b".")
            elif re.fullmatch(r"QP\d{1,2}", line):
                out.messages += 1
                ch = int(line[2:])
                out.replies.append(bytes([min(255, int(round(self._position(ch, out.latest(ch)) / 10)))]))
            else:
                out.malformed += 1


class LineParser:
    """The PCA9685 sketch's ``W w0,…,w5\\n`` frames (whole µs of 3 or 4 digits, channels in order), and ``?`` →
    ``P w0,…,w5`` (the pulses held, ``position(channel)``), taken and refused as the sketch takes and refuses them
    (``tests/hardware/test_sketch.py`` runs the two side by side): any other line, one longer than the sketch's
    buffer, or a frame with a pulse outside its fence (:data:`LineProtocol.DEFAULT_FENCE_US
    <stewart_gym.hardware.protocols.LineProtocol.DEFAULT_FENCE_US>`) is answered with an ``E`` line and moves
    nothing."""

    #: The longest line the sketch holds (its buffer of 64 bytes, less the end).
    MAX_LINE = 63
    FRAME = re.compile(r"W (\d{3,4}),(\d{3,4}),(\d{3,4}),(\d{3,4}),(\d{3,4}),(\d{3,4})")

    def __init__(self, channels: Sequence[int], position: Callable[[int, float | None], float] | None = None) -> None:
        self._channels = list(channels)
        self._position = position
        self._buffer = b""

    def feed(self, data: bytes, out: Parsed) -> None:
        self._buffer += data
        *lines, self._buffer = self._buffer.split(b"\n")
        if len(self._buffer) > 512:
            self._buffer, out.malformed = b"", out.malformed + 1
        lo, hi = LineProtocol.DEFAULT_FENCE_US
        for raw in lines:
            line = raw.replace(b"\r", b"").decode("ascii", "replace")
            if len(line) > self.MAX_LINE:
                self._refuse(out, "line too long")
            elif "\0" in line:
                self._refuse(out, "NUL in line")
            elif not line:  # the end of a half line an earlier connection left: nothing to say
                continue
            elif line == "?" and self._position is not None:
                out.messages += 1
                held = ",".join(str(int(round(self._position(c, out.latest(c))))) for c in self._channels)
                out.replies.append(f"P {held}\n".encode())
            elif (m := self.FRAME.fullmatch(line)) is None:
                self._refuse(out, "expected W w0,w1,w2,w3,w4,w5 or ?")
            elif not all(lo <= float(w) <= hi for w in m.groups()):
                self._refuse(out, "pulse outside the fence")
            else:
                out.messages += 1
                out.targets += [(c, float(w)) for c, w in zip(self._channels, m.groups())]

    @staticmethod
    def _refuse(out: Parsed, message: str) -> None:
        out.malformed += 1
        out.replies.append(f"E {message}\n".encode())


#: A board-side parser of a protocol's bytes: made from the board's channels (servo k's channel is ``channels[k]``),
#: ``position(channel, pending)`` (what a position query answers) and ``home()`` (what a "go home" command does).
ParserFactory = Callable[[Sequence[int], Callable[[int, float | None], float], Callable[[], None]], Any]

#: Each protocol's board-side parser, by the name ``--protocol`` takes (the names of
#: :data:`~stewart_gym.hardware.serial_controllers.PROTOCOLS`).
PARSERS: dict[str, ParserFactory] = {
    "maestro": lambda channels, position, home: MaestroParser(position, home),
    "ssc32": lambda channels, position, home: SSC32Parser(position),
    "line": lambda channels, position, home: LineParser(channels, position),
}

# ------------------------------------------------------------------ camera
def stream_camera_config(camera: CameraSpec, pipe: str | Path) -> CameraConfig:
    """The :class:`~stewart_gym.vision.CameraConfig` that reads a board's camera stream: the pipe (as an
    absolute path), the preset ``camera``'s resolution, frame rate and field of view, and the markers and ball as
    the twin is rendered with them."""
    from stewart_gym.vision import CameraConfig

    return CameraConfig(source=str(Path(pipe).resolve()), resolution=tuple(camera.resolution), fps=camera.fps,
                        fov_deg=camera.fov_deg)  # fmt: skip


class CameraStream:
    """Rendered frames as an MJPEG stream in a named pipe (what ``deploy --sensor camera`` reads as a camera).

    The pipe is made at ``path``; a thread waits for a reader, then writes the newest frame as it comes (an
    old frame is dropped rather than queued: a camera delivers the present). A reader that goes away is
    waited for again.
    """

    def __init__(self, path: str) -> None:
        import queue
        import threading

        p = Path(path)
        if p.exists():  # an old pipe (the device checked that it is one)
            p.unlink()
        os.mkfifo(p)
        self.path = p
        self.connected = False
        self._frames: queue.Queue[bytes] = queue.Queue(maxsize=1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera-stream", daemon=True)
        self._thread.start()

    def put(self, image_bgr: np.ndarray) -> None:
        import queue

        import cv2

        ok, jpeg = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, 92])
        if not ok:
            return
        try:
            self._frames.get_nowait()  # drop a frame the reader has not taken yet
        except queue.Empty:
            pass
        self._frames.put_nowait(jpeg.tobytes())

    def _run(self) -> None:
        import queue

        while not self._stop.is_set():
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:  # no reader yet
                self._stop.wait(0.05)
                continue
            os.set_blocking(fd, True)
            # the smallest pipe (a page, on Linux): a reader that falls behind then gets the newest frame, as from a
            # camera, not one of the ten or so (about 6 KB each at pixy2's size) the default 64 KB would queue
            with contextlib.suppress(OSError, AttributeError):
                fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, 4096)
            self.connected = True
            try:
                while not self._stop.is_set():
                    try:
                        data = self._frames.get(timeout=0.1)
                    except queue.Empty:
                        continue
                    os.write(fd, data)
            except OSError:  # the reader went away
                pass
            finally:
                self.connected = False
                os.close(fd)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        if self.path.exists():
            self.path.unlink()


# ------------------------------------------------------------------ device
@dataclass
class VirtualSummary:
    """What the board saw, printed at exit."""

    protocol: str
    messages: int = 0
    malformed: int = 0
    queries: int = 0
    dropped_bytes: int = 0
    corrupted_bytes: int = 0
    clamped: int = 0
    reports: int = 0
    sim_time_s: float = 0.0
    ball_mm: tuple[float, float] | None = None
    fell_off: bool = False
    unplugged: bool = False
    camera_frames: int = 0
    balls_put_back: int = 0

    def text(self) -> str:
        ball = "never placed" if self.ball_mm is None else (
            f"ended at ({self.ball_mm[0]:.1f}, {self.ball_mm[1]:.1f}) mm, "
            f"{math.hypot(*self.ball_mm):.1f} mm from the centre, " + ("fell off" if self.fell_off else "on the plate"))
        if self.balls_put_back:
            ball += f" (put back on the plate {self.balls_put_back} time{'s' if self.balls_put_back > 1 else ''})"
        extra = f", {self.reports} ball reports sent" if self.protocol == "line" else ""
        extra += f", {self.camera_frames} camera frames streamed" if self.camera_frames else ""
        return (f"virtual {self.protocol}: {self.messages} messages received, {self.malformed} malformed, "
                f"{self.queries} queries answered, {self.clamped} targets clamped to the channel limits{extra}; "
                f"faults injected: {self.dropped_bytes} bytes dropped, {self.corrupted_bytes} corrupted"
                f"{', unplugged' if self.unplugged else ''}; {self.sim_time_s:.1f} s simulated; ball {ball}")


#: s, the soonest the board puts a fallen ball back: the sensor then reports nothing for at least this long, so
#: that a log (``identify``, then ``sysid``) never shows the ball leaping back to the centre between two readings.
MIN_PUT_BACK_S = 0.5


class VirtualDevice:
    """The board and the twin. Call :meth:`run` (blocks until ``stop()`` returns True), then read :attr:`summary`.

    Args:
        protocol: ``"maestro"``, ``"ssc32"`` or ``"line"``.
        backend: ``"pybullet"``, ``"mujoco"`` or ``"auto"`` (PyBullet where it imports).
        geometry: the platform (preset name, TOML path or geometry).
        calibration: the board's channels and limits (default: the geometry's).
        faults: :class:`Faults` to inject.
        seed: the twin's episode (ball start, physics, panel noise).
        randomize: domain randomisation of that episode.
        link: a path to make a symlink to the pty (replaced if it is a link).
        env_id: the env whose task places the ball.
        camera: the camera preset whose view is streamed (with ``camera_stream``).
        camera_stream: a named pipe to stream the camera's view into, as MJPEG.
        twin: the platform's twin (:class:`~stewart_gym.sim.twin.Twin`, its tables or a file): the platform has
            exactly its parameters (``randomize`` is then ignored).
        put_ball_back_after_s: s (simulated, :data:`MIN_PUT_BACK_S` or more) after the ball leaves the plate when
            the board puts it back, at rest at the plate's centre, as a person at the bench would; None: it stays
            where it fell.

    Timing: the board reads its input at :data:`POLL_HZ`; the platform is simulated in steps of 1/:data:`TICK_HZ`
    kept within half a step of real time, and a frame acts from the step that starts nearest its arrival; the
    sketch sends each panel sample as soon as the panel has it.
    """

    def __init__(self, protocol: str, backend: str = "auto", geometry: Any = "servo-hexapod",
                 calibration: ServoCalibration | None = None, faults: Faults | None = None, seed: int = 0,
                 randomize: bool = True, link: str | None = None, env_id: str = "StewartBallBalance-v0",
                 camera: Any = None, camera_stream: str | None = None, twin: Any = None,
                 put_ball_back_after_s: float | None = 2.0) -> None:  # fmt: skip
        from stewart_gym.hardware.deploy import SimulatedPlant
        from stewart_gym.presets import load_geometry

        if protocol not in PARSERS:
            raise ConfigError(f"protocol must be one of {sorted(PARSERS)}, got {protocol!r}")
        after = put_ball_back_after_s
        if after is not None and (isinstance(after, (bool, np.bool_)) or not isinstance(after, (int, float, np.number))
                                  or not MIN_PUT_BACK_S <= after <= 1e6):  # fmt: skip
            raise ConfigError(f"put-ball-back-after must be a number of seconds from {MIN_PUT_BACK_S} to 1e6, got "
                              f"{after!r}")  # fmt: skip
        if camera_stream:  # the checks first, before anything is built
            from stewart_gym.sim.engines import backend_class

            if not backend_class(backend).renders_camera:
                raise ConfigError(f"--camera-stream renders the twin's camera, which the {backend} backend cannot: "
                                  "use --backend pybullet")  # fmt: skip
        if link and Path(link).exists() and not Path(link).is_symlink():
            raise ConfigError(f"{link} exists and is not a link: give another --link path")
        if link and Path(link).is_symlink() and Path(link).exists():  # it leads to a terminal that is open
            raise ConfigError(f"--link {link} leads to {os.readlink(link)}, which is open: another board (or program) "
                              "has it; stop that board, or give another --link path")  # fmt: skip
        if link and not Path(link).parent.is_dir():
            parent = Path(link).parent
            raise ConfigError(f"--link {link}: {parent} is a file, not a folder; link elsewhere" if parent.exists()
                              else f"--link {link}: the folder {parent} does not exist; create it or link elsewhere")
        if camera_stream and Path(camera_stream).exists() and not stat.S_ISFIFO(Path(camera_stream).stat().st_mode):
            raise ConfigError(f"--camera-stream {camera_stream} exists and is not a pipe: give another path")
        if camera_stream and not Path(camera_stream).parent.is_dir():
            parent, flag = Path(camera_stream).parent, f"--camera-stream {camera_stream}"
            raise ConfigError(f"{flag}: {parent} is a file, not a folder; give a path in another folder" if parent.exists()
                              else f"{flag}: the folder {parent} does not exist; create it or give a path in another "
                              "folder")  # fmt: skip
        self.protocol = protocol
        self.faults = faults or Faults()
        geo = load_geometry(geometry)
        self.calibration = calibration or ServoCalibration.default(geo)
        self._channel_index = {c: i for i, c in enumerate(self.calibration.channels)}
        self.plant = SimulatedPlant(env_id, seed=seed, randomize=randomize, geometry=geo, backend=backend, twin=twin,
                                    control_hz=TICK_HZ)  # fmt: skip
        self._rng = np.random.default_rng(seed + 7919)
        self.held = self.calibration.neutral_us.copy()
        self.commanded = self.held.copy()  # the last targets received (acting after any injected latency)
        self.summary = VirtualSummary(protocol)
        self.parser: Any = PARSERS[protocol](self.calibration.channels, self._position, self._go_home)
        self._master, slave = pty.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave  # kept open so that the pty lives while no host has it open
        os.set_blocking(self._master, False)
        self.link = None
        if link:
            p = Path(link)
            try:
                if p.is_symlink():  # a board's old link
                    p.unlink()
                p.symlink_to(self.path)
            except OSError as exc:
                for fd in (self._master, slave):
                    os.close(fd)
                raise ConfigError(f"--link {link}: the link cannot be made there ({exc.strerror}); give a path in a "
                                  "folder you can write, such as /tmp/stewart0") from None  # fmt: skip
            self.link = p
        self.camera, self.stream = camera, None
        if camera_stream:
            self.stream = CameraStream(camera_stream)
        self._next_frame = 0.0
        self._incoming: deque[tuple[float, list[tuple[int, float]]]] = deque()
        self._outgoing: deque[tuple[float, bytes]] = deque()
        self._started: float | None = None
        self._read_budget = 0.0
        self._last_ready = -1.0  # when the last ``ready`` line left
        self._next_report = 0.0  # when the next scheduled panel line is due
        self._last_sample_t: float | None = None  # the sample time of the last panel reading sent
        self.put_ball_back_after_s = None if after is None else float(after)
        self._off_since: float | None = None  # the simulated time the ball left the plate (None: on it)

    # ----------------------------------------------------------- board
    def _position(self, channel: int, pending: float | None = None) -> float:
        """What the board answers for ``channel``: the last target it received (``pending``: one received in the
        same read, not yet stored), clamped to the channel's limits as the board clamps it; 0 for no servo."""
        i = self._channel_index.get(channel)
        if i is None:
            return 0.0
        if pending is None:
            return float(self.commanded[i])
        return min(max(pending, float(self.calibration.min_us[i])), float(self.calibration.max_us[i]))

    def _go_home(self) -> None:
        self.held = self.calibration.neutral_us.copy()
        self.commanded = self.held.copy()

    def _apply_targets(self, targets: list[tuple[int, float]]) -> None:
        cal = self.calibration
        for channel, us in targets:
            i = self._channel_index.get(channel)
            if i is None:
                continue  # a channel with no servo on it
            clamped = min(max(us, float(cal.min_us[i])), float(cal.max_us[i]))
            if clamped != us:
                self.summary.clamped += 1
            self.held[i] = clamped
        if self._started is None and targets:
            self._started = time.monotonic()

    def _receive(self, now: float) -> None:
        f = self.faults
        since = None if self._started is None else now - self._started
        if f.stop_reading_after_s is not None and since is not None and since >= f.stop_reading_after_s:
            return  # a hung board: what the host writes piles up unread
        size = 4096
        if f.read_bytes_per_s is not None:  # a slow board: a budget of bytes that grows with time
            self._read_budget = min(self._read_budget + f.read_bytes_per_s / POLL_HZ, max(1.0, f.read_bytes_per_s))
            size = int(self._read_budget)
            if size < 1:
                return
        try:
            data = os.read(self._master, size)
        except (BlockingIOError, OSError):  # nothing waiting, or no host has the port open
            return
        if f.read_bytes_per_s is not None:
            self._read_budget -= len(data)
        if f.drop_rate or f.corrupt_rate:
            out = bytearray()
            for b in data:
                if f.drop_rate and self._rng.random() < f.drop_rate:
                    self.summary.dropped_bytes += 1
                    continue
                if f.corrupt_rate and self._rng.random() < f.corrupt_rate:
                    b ^= 1 << int(self._rng.integers(8))
                    self.summary.corrupted_bytes += 1
                out.append(b)
            data = bytes(out)
        parsed = Parsed()
        self.parser.feed(data, parsed)
        self.summary.messages += parsed.messages
        self.summary.malformed += parsed.malformed
        self.summary.queries += len(parsed.replies)
        for reply in parsed.replies:
            self._send(reply, now)
        if parsed.targets:
            self._incoming.append((now + f.latency_ms / 1e3, parsed.targets))
            for channel, us in parsed.targets:
                i = self._channel_index.get(channel)
                if i is not None:
                    self.commanded[i] = self._position(channel, us)

    def _send(self, data: bytes, now: float) -> None:
        self._outgoing.append((now + self.faults.latency_ms / 1e3, data))

    def _flush(self, now: float) -> None:
        while self._outgoing and self._outgoing[0][0] <= now:
            _, data = self._outgoing.popleft()
            try:
                os.write(self._master, data)
            except (BlockingIOError, OSError):  # no host reading, or its buffer is full: the bytes are lost
                pass

    # ------------------------------------------------------------ loop
    def run(self, stop: Callable[[], bool]) -> VirtualSummary:
        """Serve until ``stop()`` is True; returns (and keeps) the summary."""
        f = self.faults
        period = 1.0 / POLL_HZ
        step = 1.0 / TICK_HZ
        next_tick = time.monotonic()
        backend = self.plant.backend
        try:
            while not stop():
                now = time.monotonic()
                if not self.summary.unplugged:
                    self._receive(now)
                    if self._started is None:  # powered down: the first frame starts the clock
                        while self._incoming and self._incoming[0][0] <= now:
                            self._apply_targets(self._incoming.popleft()[1])
                    since = None if self._started is None else now - self._started
                    if since is not None and f.unplug_after_s is not None and since >= f.unplug_after_s:
                        self._unplug()
                        continue
                    if since is not None:
                        while backend.time + step / 2 <= since:  # real time, to half a step
                            due = self._started + backend.time + step / 2  # a frame acts from the step nearest it
                            while self._incoming and self._incoming[0][0] <= due:
                                self._apply_targets(self._incoming.popleft()[1])
                            self.plant.apply(self.held)
                            self._tend_ball()
                        while self._incoming and self._incoming[0][0] <= now:  # what is left acts from the next
                            self._apply_targets(self._incoming.popleft()[1])
                    if self.stream is not None and self.stream.connected and now >= self._next_frame:
                        self.stream.put(backend.camera_image(self.camera))  # what the camera sees now
                        self._next_frame = max(self._next_frame + 1.0 / self.camera.fps, now - 0.5)
                        self.summary.camera_frames += 1
                    if self.protocol == "line":
                        self._serve_lines(now, since)
                    self._flush(now)
                next_tick += period
                time.sleep(max(0.0, next_tick - time.monotonic()))
                if next_tick < time.monotonic() - 1.0:  # far behind (machine stalled): do not try to catch up
                    next_tick = time.monotonic()
        finally:
            self._finish()
        return self.summary

    def _tend_ball(self) -> None:
        """After a physics tick: once the ball has been off the plate for :attr:`put_ball_back_after_s` of simulated
        time, put it back at rest at the plate's centre (and count it)."""
        if self.put_ball_back_after_s is None:
            return
        t = self.plant.backend.time
        if self.plant.ball_on_plate():
            self._off_since = None
        elif self._off_since is None:
            self._off_since = t
        elif t - self._off_since >= self.put_ball_back_after_s:
            self.plant.put_ball_back()
            self._off_since = None
            self.summary.balls_put_back += 1

    def _serve_lines(self, now: float, since: float | None) -> None:
        """The sketch's lines at real time ``now`` (``since``: s since the first frame, None while powered down):
        ``ready`` every 0.25 s while powered down, and the panel. The sketch reports from power-up, the ball resting
        where it was put, every 1/:data:`TICK_HZ`; once the platform runs, it sends each panel sample as soon as the
        panel has it (its latency after the ball was there), and ``B -`` on the same schedule while the panel touches
        nothing."""
        f = self.faults
        if since is None and now - self._last_ready >= 0.25:
            self._send(LineProtocol.ready(), now)
            self._last_ready = now
        if f.stall_sensor_after_s is not None and since is not None and since >= f.stall_sensor_after_s:
            return
        got = self.plant.sensor.read(self.plant.backend.time if since is None else since)
        if got is not None and not reading_is_valid(got, self.plant.env.plate_half_extent):
            got = None  # the sketch reports what the panel can touch: nothing off the plate
        step = 1.0 / TICK_HZ
        if since is not None and got is not None:  # running, the ball on the panel: each new sample as it comes
            if got[1] == self._last_sample_t:
                return
            self._last_sample_t, self._next_report = got[1], now + step
        elif now < self._next_report:
            return
        else:  # on the schedule: one period on (from now, after a stall)
            self._next_report = now + step if now - self._next_report > step else self._next_report + step
        line = "B -\n" if got is None else f"B {got[0][0] * 1e3:.1f},{got[0][1] * 1e3:.1f}\n"
        self._send(line.encode(), now)
        self.summary.reports += 1

    def _unplug(self) -> None:
        self.summary.unplugged = True
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def _finish(self) -> None:
        s = self.summary
        backend = self.plant.backend
        s.sim_time_s = backend.time
        if self._started is not None:
            x, y, z = backend.ball_position()
            from stewart_gym.sensing import ball_contact

            half, top, radius = self.plant.env.plate_half_extent, backend.plate_top, self.plant.env.params.ball.radius
            on, _ = ball_contact(x, y, z, half, top, radius)
            s.ball_mm, s.fell_off = (x * 1e3, y * 1e3), not on
        self.plant.close()
        if self.stream is not None:
            self.stream.close()
        if not s.unplugged:
            self._unplug()
            s.unplugged = False
        if self.link is not None and self.link.is_symlink() and os.readlink(self.link) == self.path:  # (not another's)
            self.link.unlink()
