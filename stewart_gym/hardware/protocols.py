"""Byte-level servo-controller protocols (described in the docs: Hardware). Pure functions: no I/O here.

* :class:`Maestro`: Pololu Maestro compact protocol, targets in quarter-µs.
* :class:`SSC32`: Lynxmotion SSC-32/SSC-32U ASCII group moves.
* :class:`LineProtocol`: a plain text protocol for an Arduino with a PCA9685
  board (the sketch is ``arduino/stewart_pca9685/stewart_pca9685.ino`` in the repository): the host sends
  ``W w0,w1,w2,w3,w4,w5\\n`` (µs) and asks ``?\\n``; the board answers ``ready`` after its reset,
  ``P w0,…,w5\\n`` (the pulses it holds) to ``?``, and reports the ball as ``B x,y\\n`` (mm, plate frame).
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["MAESTRO_ERRORS", "SSC32", "LineProtocol", "Maestro"]

#: Maestro error bits (Get Errors reply), bit → meaning.
MAESTRO_ERRORS = {
    0: "serial signal error",
    1: "serial overrun error",
    2: "serial RX buffer full",
    3: "serial CRC error",
    4: "serial protocol error",
    5: "serial timeout",
    6: "script stack error",
    7: "script call stack error",
    8: "script program counter error",
}


def _check_channel(channel: int, count: int = 24) -> int:
    """``channel`` if it is one of a board's ``count`` channels (0 … count − 1)."""
    if not 0 <= int(channel) < count:
        raise ValueError(f"channel {channel} is outside 0…{count - 1}")
    return int(channel)


def _data14(value: int) -> bytes:
    """A 14-bit value as two 7-bit data bytes, low first."""
    if not 0 <= value < 1 << 14:
        raise ValueError(f"value {value} does not fit in 14 bits")
    return bytes([value & 0x7F, (value >> 7) & 0x7F])


class Maestro:
    """Pololu Maestro compact protocol. Pulse widths are given in µs and sent in quarter-µs."""

    #: the channels of the largest Maestro (the Mini Maestro 24), 0 … 23
    CHANNELS = 24

    GET_ERRORS = b"\xa1"
    GO_HOME = b"\xa2"

    @staticmethod
    def quarter_us(us: float) -> int:
        """µs → the Maestro's quarter-µs units (rounded)."""
        return int(round(float(us) * 4))

    @classmethod
    def set_target(cls, channel: int, us: float) -> bytes:
        """``84 ch lo hi``: 1500 µs on channel 2 → ``84 02 70 2E``."""
        return bytes([0x84, _check_channel(channel)]) + _data14(cls.quarter_us(us))

    @classmethod
    def set_multiple_targets(cls, first_channel: int, us: Sequence[float]) -> bytes:
        """``9F n first (lo hi)×n`` (Mini Maestro 12/18/24): contiguous channels from ``first_channel``."""
        first = _check_channel(first_channel)
        _check_channel(first + len(us) - 1)
        return bytes([0x9F, len(us), first]) + b"".join(_data14(cls.quarter_us(w)) for w in us)

    @staticmethod
    def set_speed(channel: int, units: int) -> bytes:
        """``87 ch lo hi``: speed limit in 0.25 µs / 10 ms (0 = unlimited)."""
        return bytes([0x87, _check_channel(channel)]) + _data14(int(units))

    @staticmethod
    def set_acceleration(channel: int, units: int) -> bytes:
        """``89 ch lo hi``: acceleration limit in 0.25 µs / 10 ms / 80 ms (0 = unlimited)."""
        return bytes([0x89, _check_channel(channel)]) + _data14(int(units))

    @staticmethod
    def get_position(channel: int) -> bytes:
        """``90 ch``: the reply is two bytes, low first, in quarter-µs."""
        return bytes([0x90, _check_channel(channel)])

    @staticmethod
    def decode_position(reply: bytes) -> float:
        """Get Position reply → µs."""
        if len(reply) != 2:
            raise ValueError(f"Get Position reply must be 2 bytes, got {reply!r}")
        return (reply[0] | reply[1] << 8) / 4.0

    @staticmethod
    def decode_errors(reply: bytes) -> list[str]:
        """Get Errors reply (two bytes, low first) → the names of the error bits set."""
        if len(reply) != 2:
            raise ValueError(f"Get Errors reply must be 2 bytes, got {reply!r}")
        bits = reply[0] | reply[1] << 8
        return [MAESTRO_ERRORS.get(b, f"unknown error bit {b}") for b in range(16) if bits >> b & 1]


class SSC32:
    """Lynxmotion SSC-32/SSC-32U: one CR-terminated ASCII group move for all servos."""

    #: its servo channels, 0 … 31
    CHANNELS = 32

    QUERY_MOVEMENT = b"Q\r"

    @staticmethod
    def group_move(channels: Sequence[int], us: Sequence[float], time_ms: int | None = None) -> bytes:
        """``#0P1500#1P1520…T20\\r``: every channel in one line, arriving together after ``time_ms``."""
        if len(channels) != len(us):
            raise ValueError("one pulse width per channel")
        body = "".join(f"#{_check_channel(c, SSC32.CHANNELS)}P{int(round(float(w)))}" for c, w in zip(channels, us))
        if time_ms is not None:
            body += f"T{int(time_ms)}"
        return (body + "\r").encode("ascii")

    @staticmethod
    def query_pulse(channel: int) -> bytes:
        """``QP<ch>\\r``: the reply is one byte, µs / 10."""
        return f"QP{_check_channel(channel, SSC32.CHANNELS)}\r".encode("ascii")


class LineProtocol:
    """Text lines to and from the PCA9685 Arduino sketch."""

    READY = "ready"
    #: Asks the board which pulses it holds; it answers ``P w0,…,w5``.
    QUERY = b"?\n"
    #: µs: the sketch's fence where its ``ready`` line does not give one (a sketch from before it did): a frame
    #: with a pulse outside it is refused whole.
    DEFAULT_FENCE_US = (900.0, 2100.0)

    @staticmethod
    def frame(us: Sequence[float]) -> bytes:
        """``W 1500,1500,1500,1500,1500,1500\\n`` (whole µs)."""
        return ("W " + ",".join(str(int(round(float(w)))) for w in us) + "\n").encode("ascii")

    @staticmethod
    def parse_ball(line: str) -> tuple[float, float] | None:
        """``B x,y`` (mm) → (x, y) in mm; ``None`` for any other line (``ready``, ``B -`` for no touch, noise)."""
        line = line.strip()
        if not line.startswith("B "):
            return None
        try:
            x, y = (float(v) for v in line[2:].split(","))
        except ValueError:
            return None
        return (x, y)

    @staticmethod
    def parse_held(line: str) -> tuple[float, ...] | None:
        """``P w0,…,w5`` (the answer to :attr:`QUERY`) → the six pulse widths, µs; ``None`` for any other line."""
        line = line.strip()
        if not line.startswith("P "):
            return None
        try:
            values = tuple(float(v) for v in line[2:].split(","))
        except ValueError:
            return None
        return values if len(values) == 6 else None

    @staticmethod
    def ready(fence_us: tuple[float, float] = DEFAULT_FENCE_US) -> bytes:
        """The sketch's line after a reset, with its fence: ``ready 900,2100\\n``."""
        return f"{LineProtocol.READY} {fence_us[0]:g},{fence_us[1]:g}\n".encode("ascii")

    @staticmethod
    def parse_ready(line: str) -> tuple[float, float] | None:
        """``ready lo,hi`` (sent once after a reset, with the sketch's fence in µs) → (lo, hi); a bare ``ready``
        → :attr:`DEFAULT_FENCE_US`; ``None`` for any other line."""
        words = line.strip().split()
        if not words or words[0] != LineProtocol.READY or len(words) > 2:
            return None
        if len(words) == 1:
            return LineProtocol.DEFAULT_FENCE_US
        try:
            lo, hi = (float(v) for v in words[1].split(","))
        except ValueError:
            return None
        return (lo, hi) if 0.0 < lo < hi else None

    @staticmethod
    def parse_refusal(line: str) -> str | None:
        """``E <message>`` (the sketch refused a line: nothing moved) → the message; ``None`` for any other line."""
        line = line.strip()
        return line[2:].strip() or "(no message)" if line.startswith("E ") or line == "E" else None
