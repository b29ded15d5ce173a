"""Serial servo controllers (pyserial): send six pulse widths per tick, ask the board what it holds, read the panel.

Each controller maps servo i to ``calibration.channels[i]`` and writes one frame
per :meth:`ServoController.send`. Writing to an unplugged port raises
:class:`DeviceError` with a clear message; the control loop stops on it.

Every protocol can ask the board which pulses it holds (Maestro Get Position, SSC-32 ``QP``, the line sketch's
``?``). ``deploy`` uses that twice: while it runs, a question rides along with a frame every
:data:`ASK_EVERY_S` (:meth:`ServoController.monitor`); a question not answered within the answer timeout is
missed, and :data:`MAX_MISSED_ANSWERS` missed in a row mean the board has stopped reading, reads more slowly
than the frames arrive, or the line loses bytes: a :class:`DeviceError`. At the end, :meth:`ServoController.confirm`
asks whether the board holds the home pulses.
"""

from __future__ import annotations

import errno
import math
import os
import select
import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np
import serial

from stewart_gym.errors import ConfigError, DeviceFailure
from stewart_gym.hardware.protocols import SSC32, LineProtocol, Maestro

try:  # POSIX: pyserial's flush() calls tcdrain(), whose termios.error is not an OSError
    from termios import error as _TermiosError
except ImportError:  # Windows
    _TermiosError = OSError
#: What a port that went away can raise from write, flush, in_waiting or read.
PORT_ERRORS: tuple[type[Exception], ...] = (serial.SerialException, OSError, _TermiosError)
#: s between the questions a monitored controller asks the board (:meth:`ServoController.monitor`).
ASK_EVERY_S = 0.25
#: s: how long a monitored board may leave a question unanswered before the question counts as missed.
ANSWER_TIMEOUT_S = 0.5
#: Missed questions in a row that make a monitored board a device failure (one alone can be a byte lost on the line).
MAX_MISSED_ANSWERS = 3

__all__ = ["ANSWER_TIMEOUT_S", "ASK_EVERY_S", "PROTOCOLS", "BoardRefused", "DeviceError", "LineController",
           "MaestroController", "MAX_MISSED_ANSWERS", "ServoController", "SSC32Controller", "check_channels",
           "open_controller", "write_timeout_s"]  # fmt: skip


class DeviceError(DeviceFailure):
    """The serial device failed (unplugged, not answering, not reading, protocol error)."""


class BoardRefused(DeviceError):
    """The board refuses the frames it is sent (the sketch's ``E`` lines): it still reads and answers."""


def write_timeout_s(baudrate: int) -> float:
    """The longest one write may block, s: 50 ms plus the time the line takes to carry 256 bytes (about ten
    frames) at ``baudrate`` (10 bits a byte). A write that blocks longer means the board is not taking bytes."""
    return 0.05 + 256 * 10 / float(baudrate)


class ServoController(ABC):
    """Six servos on a serial controller.

    Args:
        port: a device path (opened here) or an open port: a :class:`serial.Serial`
            or anything with its ``write``, ``flush``, ``read``, ``in_waiting``, ``close`` and ``port``.
        channels: controller channel of servo 0…5.
        baudrate: line speed; the write timeout follows it (:func:`write_timeout_s`).
    """

    default_baudrate = 115200
    #: µs: the pulses the board itself takes (lowest, highest), where it says: it refuses a frame with any pulse
    #: outside them, so a calibration whose limits leave them is refused before anything moves
    #: (:func:`open_controller`); None where the board does not say
    fence_us: tuple[float, float] | None = None
    #: whether frames the board refuses again and again raise :class:`BoardRefused` (the loop's rule; the drive
    #: home turns it off, and the board's answer to the position query then says whether the servos got home)
    fail_on_refusals = True

    def __init__(self, port: str | serial.Serial, channels: Sequence[int] = range(6), baudrate: int | None = None,
                 timeout: float = 0.05) -> None:  # fmt: skip
        self.channels = [int(c) for c in channels]
        if len(self.channels) != 6:
            raise ValueError(f"need 6 channels, got {self.channels}")
        self.baudrate = int(baudrate or self.default_baudrate)
        if not isinstance(port, str):
            self.serial = port
        else:
            try:
                self.serial = serial.Serial(port, self.baudrate, timeout=timeout,
                                            write_timeout=write_timeout_s(self.baudrate))  # fmt: skip
            except serial.SerialException as exc:
                code = exc.errno if isinstance(exc.errno, int) else None  # pyserial's own text repeats the port
                reason = os.strerror(code) if code is not None else str(exc)
                if code in (errno.ENOTTY, errno.EISDIR) or "Inappropriate ioctl" in str(exc):
                    reason = ("it is not a serial device: check --port (ls /dev/tty*; the board's port appears as it "
                              "is plugged in)")  # fmt: skip
                elif code == errno.EACCES:
                    reason += "; on Linux, join the dialout group (sudo usermod -aG dialout $USER, then log in again)"
                elif sys.platform == "win32" and ("Access is denied" in reason or "PermissionError" in reason):
                    reason = ("the port is in use: close the program that holds it (the Arduino IDE's serial monitor, "
                              "another stewart-gym)")  # fmt: skip
                elif sys.platform == "win32" and "FileNotFoundError" in reason:
                    reason = "no such port: check the COM number in Device Manager (Ports (COM & LPT))"
                raise DeviceError(f"cannot open {port}: {reason}") from None
        self.frames_sent = 0
        #: whether :meth:`send` asks the board along the way (:meth:`monitor`)
        self.monitoring = False
        self.answer_timeout_s = ANSWER_TIMEOUT_S
        #: answers received, questions missed, and the longest wait for an answer (s), while monitored
        self.answers = self.missed = 0
        self.longest_wait_s = 0.0
        self._missed_in_row = 0
        self._asked_at: float | None = None  # when the question in flight was asked
        self._expired = False  # whether it has already counted as missed
        self._last_asked = -math.inf
        self._replies = b""  # bytes received and not yet parsed

    # ------------------------------------------------------------ protocol
    @abstractmethod
    def frame(self, pulses_us: np.ndarray) -> bytes:
        """The bytes that command all six servos."""

    @abstractmethod
    def position_query(self) -> bytes:
        """The bytes that ask the board which pulses the six servos hold."""

    @abstractmethod
    def _parse_replies(self) -> list[np.ndarray]:
        """Complete answers to :meth:`position_query` in ``self._replies`` (six pulses, µs, each); consumes them."""

    #: how close a reported pulse must be to the commanded one, µs (the protocol's resolution)
    resolution_us = 0.5

    # ----------------------------------------------------------------- I/O
    def send(self, pulses_us: np.ndarray) -> bytes:
        """Write one frame (and, when monitored, the question due); return the frame's bytes.

        Raises :class:`DeviceError` if the port fails or a monitored board has left a question unanswered for
        longer than :attr:`answer_timeout_s`; ``ValueError`` for a pulse that is not a finite number.
        """
        pulses = np.asarray(pulses_us, dtype=np.float64).reshape(6)
        if not np.all(np.isfinite(pulses)):
            raise ValueError(f"refusing to send non-finite pulses {pulses.tolist()}")
        data = self.frame(pulses)
        out = data
        if self.monitoring:
            now = time.perf_counter()
            self._watch(now)
            if self._asked_at is None and now - self._last_asked >= ASK_EVERY_S:
                out = data + self.position_query()
                self._asked_at = self._last_asked = now
        self._write(out)
        self.frames_sent += 1
        return data

    def _watch(self, now: float) -> None:
        """The question in flight: answered in time (the count of missed questions starts over), answered late or
        not yet answered after the timeout (missed: :data:`MAX_MISSED_ANSWERS` in a row raise
        :class:`DeviceError`), or, after twice the timeout with no answer, lost on the way (asked again)."""
        asked, expired = self._asked_at, self._expired
        if self._collect(now) and asked is not None:
            if now - asked <= self.answer_timeout_s:
                self._missed_in_row = 0
            elif not expired:
                self._miss()
        elif asked is not None:
            if not self._expired and now - asked > self.answer_timeout_s:
                self._expired = True
                self._miss()
            elif self._expired and now - asked > 2 * self.answer_timeout_s:  # never to be answered: ask again
                self._resync()
                self._asked_at, self._expired = None, False

    def _miss(self) -> None:
        self.missed += 1
        self._missed_in_row += 1
        if self._missed_in_row >= MAX_MISSED_ANSWERS:
            raise DeviceError(f"the board on {self.serial.port} left {self._missed_in_row} questions in a row "
                              f"unanswered within {self.answer_timeout_s:g} s: it stopped reading, reads more slowly "
                              "than the frames arrive, or the line loses bytes")  # fmt: skip

    def monitor(self, timeout_s: float = ANSWER_TIMEOUT_S) -> None:
        """From now on, ask the board along with the frames and fail when it stops answering (see :meth:`send`)."""
        self.answer_timeout_s = float(timeout_s)
        self.monitoring = True

    def held_pulses(self, timeout_s: float = 0.5, attempts: int = 1) -> np.ndarray | None:
        """The six pulses (µs) the board says it holds now, or None if it did not answer within ``timeout_s``, asked
        up to ``attempts`` times. A question already in flight is answered first (or given up, and the bytes
        received so far dropped)."""
        for _ in range(attempts - 1):
            held = self.held_pulses(timeout_s)
            if held is not None:
                return held
        deadline = time.perf_counter() + timeout_s
        while self._asked_at is not None and time.perf_counter() < deadline:
            self._collect(time.perf_counter())
            time.sleep(0.002)
        if self._asked_at is not None:
            self._resync()
            self._asked_at, self._expired = None, False
        self._write(self.position_query())
        self._asked_at = self._last_asked = time.perf_counter()
        deadline = self._asked_at + timeout_s
        while time.perf_counter() < deadline:
            got = self._collect(time.perf_counter())
            if got:
                return got[-1]
            time.sleep(0.002)
        return None

    def confirm(self, pulses_us: np.ndarray, timeout_s: float = 0.5, attempts: int = 3) -> tuple[bool, np.ndarray | None]:
        """Whether the board holds ``pulses_us`` (within :attr:`resolution_us` + 0.5 µs), asked up to ``attempts``
        times (an answer garbled on the line is asked again); and the last answer (None: it never answered)."""
        want = np.asarray(pulses_us, dtype=np.float64).reshape(6)
        held = None
        for _ in range(attempts):
            got = self.held_pulses(timeout_s)
            held = got if got is not None else held
            if got is not None and np.all(np.abs(got - want) <= self.resolution_us + 0.5):
                return True, got
            self._resync()
        return False, held

    def _resync(self) -> None:
        """After a missed answer: forget bytes that may be half an answer (binary protocols; lines resync by
        themselves)."""
        self._read_waiting()
        self._replies = b""

    def wait_until(self, deadline: float) -> None:
        """Sleep until ``deadline`` (:func:`time.perf_counter`): what the loop does between ticks. A controller that
        reads the board's own reports (:class:`LineController`) reads them as they arrive meanwhile."""
        remaining = deadline - time.perf_counter()
        if remaining > 0:
            time.sleep(remaining)

    def drain(self) -> None:
        """Wait until every byte written has left the computer (``tcdrain``)."""
        try:
            self.serial.flush()
        except PORT_ERRORS as exc:
            raise DeviceError(f"serial write to {self.serial.port} failed (device unplugged?): {exc}") from None

    def _collect(self, now: float) -> list[np.ndarray]:
        """Read what has arrived; the answers among it (each settles the question in flight)."""
        self._read_waiting()
        got = self._parse_replies()
        if got and self._asked_at is not None:
            self.longest_wait_s = max(self.longest_wait_s, now - self._asked_at)
            self.answers += 1
            self._asked_at = None
            self._expired = False
        return got

    def _read_waiting(self) -> None:
        try:
            waiting = self.serial.in_waiting
            if waiting:
                self._replies += self.serial.read(waiting)
        except PORT_ERRORS as exc:
            raise DeviceError(f"serial read from {self.serial.port} failed (device unplugged?): {exc}") from None

    def _write(self, data: bytes) -> None:
        try:
            self.serial.write(data)
            self.serial.flush()
        except serial.SerialTimeoutException:
            limit = write_timeout_s(self.baudrate)
            raise DeviceError(f"serial write to {self.serial.port} blocked for more than {limit:.2f} s: the board "
                              "is not taking bytes") from None  # fmt: skip
        except PORT_ERRORS as exc:
            raise DeviceError(f"serial write to {self.serial.port} failed (device unplugged?): {exc}") from None

    def close(self) -> None:
        if self.serial.is_open:
            self.serial.close()


class MaestroController(ServoController):
    """Pololu Maestro, compact protocol.

    ``multiple_targets=True`` sends one Set Multiple Targets frame (Mini Maestro
    12/18/24, channels must be contiguous); otherwise six Set Target commands in
    one write (every Maestro). Positions are asked with six Get Position commands (two bytes back each).
    """

    resolution_us = 0.25

    def __init__(self, *args: object, multiple_targets: bool = False, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.multiple_targets = multiple_targets
        if multiple_targets and self.channels != list(range(self.channels[0], self.channels[0] + 6)):
            raise ValueError(f"Set Multiple Targets needs contiguous channels, got {self.channels}")

    def frame(self, pulses_us: np.ndarray) -> bytes:
        if self.multiple_targets:
            return Maestro.set_multiple_targets(self.channels[0], pulses_us)
        return b"".join(Maestro.set_target(c, w) for c, w in zip(self.channels, pulses_us))

    def position_query(self) -> bytes:
        return b"".join(Maestro.get_position(c) for c in self.channels)

    def _parse_replies(self) -> list[np.ndarray]:
        got = []
        while len(self._replies) >= 12:
            reply, self._replies = self._replies[:12], self._replies[12:]
            got.append(np.array([Maestro.decode_position(reply[k:k + 2]) for k in range(0, 12, 2)]))
        return got

    def errors(self) -> list[str]:
        """Get Errors (clears them on the device); the names of the bits set. The board has the answer timeout
        (:attr:`answer_timeout_s`) to reply, as for any question."""
        self.serial.reset_input_buffer()
        self._write(Maestro.GET_ERRORS)
        reply, deadline = b"", time.perf_counter() + self.answer_timeout_s
        while len(reply) < 2 and time.perf_counter() < deadline:
            reply += self.serial.read(2 - len(reply))
        if len(reply) != 2:
            raise DeviceError(f"Maestro on {self.serial.port} did not answer Get Errors")
        return Maestro.decode_errors(reply)

    def configure(self, speed: int = 0, acceleration: int = 0) -> None:
        """Set Speed and Set Acceleration on the six channels (0 = unlimited)."""
        self._write(b"".join(Maestro.set_speed(c, speed) + Maestro.set_acceleration(c, acceleration)
                             for c in self.channels))  # fmt: skip


class SSC32Controller(ServoController):
    """Lynxmotion SSC-32/SSC-32U: one ASCII group move per tick, timed to arrive within ``move_ms``. Positions are
    asked with six ``QP`` queries (one byte back each: µs / 10)."""

    resolution_us = 10.0

    def __init__(self, *args: object, move_ms: int = 20, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.move_ms = move_ms

    def frame(self, pulses_us: np.ndarray) -> bytes:
        return SSC32.group_move(self.channels, pulses_us, self.move_ms)

    def position_query(self) -> bytes:
        return b"".join(SSC32.query_pulse(c) for c in self.channels)

    def _parse_replies(self) -> list[np.ndarray]:
        got = []
        while len(self._replies) >= 6:
            reply, self._replies = self._replies[:6], self._replies[6:]
            got.append(np.array([10.0 * b for b in reply]))
        return got


class LineController(ServoController):
    """Arduino + PCA9685 sketch: ``W …`` frames and ``?`` out, ``B x,y`` ball readings and ``P …`` answers in.

    Opening the port resets an Arduino Uno (DTR); the constructor waits up to
    ``ready_timeout`` s for its ``ready`` line before anything is sent. A board that does not reset on open
    (native USB, DTR reset disabled, or one still running the sketch from an earlier connection) sends no
    ``ready``: then it asks ``?`` once, and the sketch's answer within :data:`QUERY_TIMEOUT_S` will do.
    """

    #: s: how long the sketch has to answer the ``?`` asked when no ``ready`` line came.
    QUERY_TIMEOUT_S = 1.0
    #: The sketch refusing this many of the last :data:`REFUSAL_WINDOW` frames sent is a device failure: its
    #: servos hold the last pose it took (one refused now and then, a line garbled on the way, is not).
    MAX_REFUSALS = 3
    REFUSAL_WINDOW = 10

    resolution_us = 1.0

    def __init__(self, *args: object, ready_timeout: float = 3.0, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.last_ball_mm: tuple[float, float] | None = None
        self.last_ball_time: float | None = None
        self._held: list[np.ndarray] = []
        self._ready = False
        self.fence_us = LineProtocol.DEFAULT_FENCE_US  # until its ready line says
        self._refused_at: list[int] = []  # frames_sent when each of the last refusals came
        self._refusals_reported = False  # (once: the run then ends, and the board's answers confirm its home)
        self._asked_first = False  # whether it asked '?' for want of a ready line
        self._said: str | None = None  # the refusal that came before the answer to that '?'
        try:
            if self._wait_ready(ready_timeout):
                return
        except DeviceError:
            self.close()
            raise
        self.close()
        raise DeviceError(f"no '{LineProtocol.READY}' line from {self.serial.port} within {ready_timeout} s, and no "
                          "answer to '?' (wrong port, wrong sketch or wrong baud rate?)"
                          + (f"; it said: {self._said}" if self._said else ""))  # fmt: skip

    def _wait_ready(self, ready_timeout: float) -> bool:
        """Whether the sketch said ``ready`` within ``ready_timeout`` s, or else answered a ``?``; an ``E`` line
        before that (no PCA9685 on the bus) is a :class:`DeviceError` saying what the board says, and one after the
        ``?`` is kept for the error where no answer comes."""
        deadline = time.perf_counter() + ready_timeout
        while time.perf_counter() < deadline:
            self._pump()
            if self._ready:
                return True
            time.sleep(0.01)
        # no reset on open: a running sketch answers. A line end first, for a half line an earlier connection left
        # in its buffer: a refusal before the answer is that half line's, not this connection's
        self._write(b"\n" + LineProtocol.QUERY)
        self._asked_first = True
        deadline = time.perf_counter() + self.QUERY_TIMEOUT_S
        while time.perf_counter() < deadline:
            self._pump()
            if self._ready or self._held:
                self._held.clear()
                self._ready = True
                return True
            time.sleep(0.01)
        return False

    def frame(self, pulses_us: np.ndarray) -> bytes:
        return LineProtocol.frame(pulses_us)

    def position_query(self) -> bytes:
        return LineProtocol.QUERY

    def _resync(self) -> None:
        self._pump()  # the lines (ball readings among them) are kept; a broken one is dropped as noise

    def _pump(self) -> None:
        """Read the lines that have arrived: the ball readings, the answers, ``ready`` and the sketch's refusals
        (:meth:`_refused`)."""
        self._read_waiting()
        *lines, self._replies = self._replies.split(b"\n")
        if len(self._replies) > 4096:  # no line end for far too long: noise, not a line
            self._replies = b""
        for raw in lines:
            line = raw.decode("ascii", "replace")
            xy = LineProtocol.parse_ball(line)
            if xy is not None:
                self.last_ball_mm, self.last_ball_time = xy, time.perf_counter()
                continue
            held = LineProtocol.parse_held(line)
            if held is not None:
                self._held.append(np.array(held))
                continue
            fence = LineProtocol.parse_ready(line)
            if fence is not None:
                self._ready, self.fence_us = True, fence
                continue
            refusal = LineProtocol.parse_refusal(line)
            if refusal is not None:
                self._refused(refusal)

    def _refused(self, message: str) -> None:
        """The sketch refused a line: before ``ready``, what it says is why it cannot start; after, a
        :class:`BoardRefused` once it has refused :data:`MAX_REFUSALS` of the last :data:`REFUSAL_WINDOW` frames
        (once: the frames refused after it, still on their way, are the run's end's, which the board's answer to
        the position query confirms or not)."""
        if not self._ready:
            if self._asked_first:  # kept, for the error if no answer comes
                self._said = message
                return
            raise DeviceError(f"the board on {self.serial.port} says: {message}")
        self._refused_at = [n for n in self._refused_at if n > self.frames_sent - self.REFUSAL_WINDOW]
        self._refused_at.append(self.frames_sent)
        if len(self._refused_at) >= self.MAX_REFUSALS and self.fail_on_refusals and not self._refusals_reported:
            self._refusals_reported = True
            raise BoardRefused(f"the board on {self.serial.port} refused {self.MAX_REFUSALS} of the last "
                              f"{self.REFUSAL_WINDOW} frames ({message}): its servos hold the last pose it took")

    def _parse_replies(self) -> list[np.ndarray]:
        self._pump()
        got, self._held = self._held, []
        return got

    def wait_until(self, deadline: float) -> None:
        """Sleep until ``deadline``, reading each line as it arrives, so that a ball reading's arrival time is when
        it came, not the next tick (the port is watched with ``select`` where it has a file descriptor, else read
        every millisecond)."""
        try:
            fd: int | None = self.serial.fileno()
        except (AttributeError, OSError, ValueError, serial.SerialException):  # not a POSIX port: a URL or a fake
            fd = None
        while (remaining := deadline - time.perf_counter()) > 0:
            if fd is None or self._woke_without_bytes(fd, remaining):
                time.sleep(max(0.0, min(deadline - time.perf_counter(), 0.001)))
            self._pump()

    def _woke_without_bytes(self, fd: int, timeout: float) -> bool:
        """Wait up to ``timeout`` s for bytes on ``fd``; whether the wait ended early with none to read (a hung-up
        descriptor is readable with nothing in it; or the port failed, which the read that follows says): the
        caller then sleeps a little rather than spin. A wait that times out is not early."""
        try:
            readable, _, _ = select.select([fd], [], [], timeout)
            return bool(readable) and not self.serial.in_waiting
        except (ValueError, *PORT_ERRORS):
            return True

    def poll_ball(self) -> tuple[tuple[float, float], float] | None:
        """The newest ``B x,y`` reading ((x, y) mm, arrival time s, monotonic) received so far, if any. The values
        are as received: the deploy loop decides whether they can be a ball on the plate."""
        self._pump()
        if self.last_ball_mm is None or self.last_ball_time is None:
            return None
        return self.last_ball_mm, self.last_ball_time


PROTOCOLS = {"maestro": MaestroController, "ssc32": SSC32Controller, "line": LineController}


def check_channels(protocol: str, channels: Sequence[int], source: str = "the calibration") -> None:
    """Raise :class:`~stewart_gym.errors.ConfigError` unless the six ``channels`` (``source``'s ``[[servo]]
    channel``) are the board's: a Maestro's 0…23, an SSC-32's 0…31; the sketch (``line``) drives servo k on its
    PCA9685 channel k, so there they are 0…5 in order."""
    channels = [int(c) for c in channels]
    if protocol == "line":
        if channels != list(range(6)):
            raise ConfigError(f"{source}: channels {channels}: the line protocol's sketch drives servo k on PCA9685 "
                              "channel k, so the channels must be 0, 1, 2, 3, 4, 5 in order: wire the servos so and "
                              "give those")  # fmt: skip
        return
    count = {"maestro": Maestro.CHANNELS, "ssc32": SSC32.CHANNELS}.get(protocol)
    outside = [c for c in channels if count is not None and not 0 <= c < count]
    if outside:
        raise ConfigError(f"{source}: channel(s) {outside} are not on a {protocol} board, whose channels are "
                          f"0…{count - 1}: give the channels the servos are wired to")  # fmt: skip


def open_controller(protocol: str, port: str | serial.Serial, channels: Sequence[int] = range(6),
                    baudrate: int | None = None, limits: tuple[Sequence[float], Sequence[float]] | None = None,
                    source: str = "the calibration") -> ServoController:  # fmt: skip
    """A controller by protocol name (:data:`PROTOCOLS`); the channels checked (:func:`check_channels`) before the
    port opens, and the servos' ``limits`` (lowest, highest µs of each, from ``source``) against the board's own
    fence once it has said it (:attr:`ServoController.fence_us`), before anything is sent."""
    try:
        cls = PROTOCOLS[protocol]
    except KeyError:
        raise ConfigError(f"protocol must be one of {sorted(PROTOCOLS)}, got {protocol!r}") from None
    check_channels(protocol, channels)
    controller = cls(port, channels, baudrate)
    if limits is not None and controller.fence_us is not None:
        lo, hi = controller.fence_us
        outside = [k for k, (a, b) in enumerate(zip(*limits)) if a < lo or b > hi]
        if outside:
            k = outside[0]
            controller.close()
            raise ConfigError(f"{source}: servo {k}'s limits {limits[0][k]:g}–{limits[1][k]:g} µs leave the board's "
                              f"fence, {lo:g}–{hi:g} µs (it would refuse those frames and hold its servos): narrow "
                              "the limits, or widen SERVO_MIN_US and SERVO_MAX_US in the sketch and flash it "
                              "again")  # fmt: skip
    return controller
