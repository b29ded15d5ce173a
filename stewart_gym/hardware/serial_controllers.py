"""Serial servo controllers (pyserial): send six pulse widths per tick, read the touch panel.

Each controller maps servo i to ``calibration.channels[i]`` and writes one frame
per :meth:`ServoController.send`. Writing to an unplugged port raises
:class:`DeviceError` with a clear message; the control loop stops on it.
"""

from __future__ import annotations

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

__all__ = ["PROTOCOLS", "DeviceError", "LineController", "MaestroController", "ServoController", "SSC32Controller",
           "open_controller"]  # fmt: skip


class DeviceError(DeviceFailure):
    """The serial device failed (unplugged, not answering, protocol error)."""


class ServoController(ABC):
    """Six servos on a serial controller.

    Args:
        port: a device path (opened here) or an open port: a :class:`serial.Serial`
            or anything with its ``write``, ``flush``, ``read``, ``close`` and ``port``.
        channels: controller channel of servo 0…5.
        baudrate: line speed.
    """

    default_baudrate = 115200

    def __init__(self, port: str | serial.Serial, channels: Sequence[int] = range(6), baudrate: int | None = None,
                 timeout: float = 0.05) -> None:  # fmt: skip
        self.channels = [int(c) for c in channels]
        if len(self.channels) != 6:
            raise ValueError(f"need 6 channels, got {self.channels}")
        if not isinstance(port, str):
            self.serial = port
        else:
            try:
                self.serial = serial.Serial(port, baudrate or self.default_baudrate, timeout=timeout,
                                            write_timeout=0.5)  # fmt: skip
            except serial.SerialException as exc:
                raise DeviceError(f"cannot open {port}: {exc}") from None
        self.frames_sent = 0

    @abstractmethod
    def frame(self, pulses_us: np.ndarray) -> bytes:
        """The bytes that command all six servos."""

    def send(self, pulses_us: np.ndarray) -> bytes:
        """Write one frame; return the bytes written. Raises :class:`DeviceError` if the port fails."""
        data = self.frame(np.asarray(pulses_us, dtype=np.float64).reshape(6))
        self._write(data)
        self.frames_sent += 1
        return data

    def _write(self, data: bytes) -> None:
        try:
            self.serial.write(data)
            self.serial.flush()
        except PORT_ERRORS as exc:
            raise DeviceError(f"serial write to {self.serial.port} failed (device unplugged?): {exc}") from None

    def close(self) -> None:
        if self.serial.is_open:
            self.serial.close()


class MaestroController(ServoController):
    """Pololu Maestro, compact protocol.

    ``multiple_targets=True`` sends one Set Multiple Targets frame (Mini Maestro
    12/18/24, channels must be contiguous); otherwise six Set Target commands in
    one write (every Maestro).
    """

    def __init__(self, *args: object, multiple_targets: bool = False, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.multiple_targets = multiple_targets
        if multiple_targets and self.channels != list(range(self.channels[0], self.channels[0] + 6)):
            raise ValueError(f"Set Multiple Targets needs contiguous channels, got {self.channels}")

    def frame(self, pulses_us: np.ndarray) -> bytes:
        if self.multiple_targets:
            return Maestro.set_multiple_targets(self.channels[0], pulses_us)
        return b"".join(Maestro.set_target(c, w) for c, w in zip(self.channels, pulses_us))

    def errors(self) -> list[str]:
        """Get Errors (clears them on the device); the names of the bits set."""
        self.serial.reset_input_buffer()
        self._write(Maestro.GET_ERRORS)
        reply = self.serial.read(2)
        if len(reply) != 2:
            raise DeviceError(f"Maestro on {self.serial.port} did not answer Get Errors")
        return Maestro.decode_errors(reply)

    def configure(self, speed: int = 0, acceleration: int = 0) -> None:
        """Set Speed and Set Acceleration on the six channels (0 = unlimited)."""
        self._write(b"".join(Maestro.set_speed(c, speed) + Maestro.set_acceleration(c, acceleration)
                             for c in self.channels))  # fmt: skip


class SSC32Controller(ServoController):
    """Lynxmotion SSC-32/SSC-32U: one ASCII group move per tick, timed to arrive within ``move_ms``."""

    def __init__(self, *args: object, move_ms: int = 20, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.move_ms = move_ms

    def frame(self, pulses_us: np.ndarray) -> bytes:
        return SSC32.group_move(self.channels, pulses_us, self.move_ms)


class LineController(ServoController):
    """Arduino + PCA9685 sketch: ``W …`` frames out, ``B x,y`` ball readings in.

    Opening the port resets an Arduino Uno (DTR); the constructor waits up to
    ``ready_timeout`` s for its ``ready`` line before anything is sent.
    """

    def __init__(self, *args: object, ready_timeout: float = 3.0, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._buffer = b""
        self.last_ball_mm: tuple[float, float] | None = None
        self.last_ball_time: float | None = None
        deadline = time.monotonic() + ready_timeout
        while time.monotonic() < deadline:
            for line in self._lines():
                if line.strip() == LineProtocol.READY:
                    return
            time.sleep(0.01)
        self.close()
        raise DeviceError(f"no '{LineProtocol.READY}' line from {self.serial.port} within {ready_timeout} s "
                          "(wrong port, wrong sketch or wrong baud rate?)")  # fmt: skip

    def frame(self, pulses_us: np.ndarray) -> bytes:
        return LineProtocol.frame(pulses_us)

    def _lines(self) -> list[str]:
        try:
            waiting = self.serial.in_waiting
            if waiting:
                self._buffer += self.serial.read(waiting)
        except PORT_ERRORS as exc:
            raise DeviceError(f"serial read from {self.serial.port} failed (device unplugged?): {exc}") from None
        *lines, self._buffer = self._buffer.split(b"\n")
        return [ln.decode("ascii", "replace") for ln in lines]

    def poll_ball(self) -> tuple[tuple[float, float], float] | None:
        """The newest ``B x,y`` reading ((x, y) mm, arrival time s, monotonic) received so far, if any."""
        for line in self._lines():
            xy = LineProtocol.parse_ball(line)
            if xy is not None:
                self.last_ball_mm, self.last_ball_time = xy, time.monotonic()
        if self.last_ball_mm is None or self.last_ball_time is None:
            return None
        return self.last_ball_mm, self.last_ball_time


PROTOCOLS = {"maestro": MaestroController, "ssc32": SSC32Controller, "line": LineController}


def open_controller(protocol: str, port: str | serial.Serial, channels: Sequence[int] = range(6),
                    baudrate: int | None = None) -> ServoController:  # fmt: skip
    """A controller by protocol name (:data:`PROTOCOLS`)."""
    try:
        cls = PROTOCOLS[protocol]
    except KeyError:
        raise ConfigError(f"protocol must be one of {sorted(PROTOCOLS)}, got {protocol!r}") from None
    return cls(port, channels, baudrate)
