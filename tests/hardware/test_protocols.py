"""Serial protocols: the exact bytes of every frame (pure functions, no I/O)."""


from __future__ import annotations

import numpy as np
import pytest

from stewart_gym.calibration import ServoCalibration
from stewart_gym.hardware.protocols import SSC32, LineProtocol, Maestro

CAL = ServoCalibration.default("servo-hexapod")


PULSES = np.array([1500.0, 1400.25, 1600.5, 1100.0, 1900.0, 1234.75])


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
