"""The serial protocols' contract, run on every protocol in ``PROTOCOLS``: it is a ``--protocol`` choice and has a
board-side parser in the virtual device; one known frame's bytes are those its board's manual gives; the frames it
sends reach a board as the pulses sent; and the board's answer to its position query confirms the pulses held.

A new protocol (``docs/src/guides/add-a-protocol.md``) adds its parser to ``virtual_device.PARSERS`` and its known
frame, written from its board's manual rather than from its own code, to :data:`KNOWN_FRAMES`."""

from __future__ import annotations

import time

import numpy as np
import pytest
from conftest import Board, FakeDevice

from stewart_gym.cli.hardware import PROTOCOL_CHOICES
from stewart_gym.hardware.serial_controllers import PROTOCOLS, open_controller
from stewart_gym.hardware.virtual_device import PARSERS

#: Six pulses (µs) on channels 0…5, with a quarter, a half and whole microseconds.
KNOWN = (1500.0, 1000.0, 2000.0, 1234.0, 1765.5, 1600.25)


def _maestro_set_target(channel: int, us: float) -> bytes:
    """Pololu's manual: Set Target is 0x84, the channel, then the target in quarter-µs as two 7-bit bytes, low
    first."""
    q = round(us * 4)
    return bytes([0x84, channel, q & 0x7F, q >> 7])


#: The step of each protocol's pulses on the wire, µs: a Maestro's quarter microsecond, the others' whole ones.
WIRE_STEP_US = {"maestro": 0.25, "ssc32": 1.0, "line": 1.0}

#: Each protocol's bytes for :data:`KNOWN` on channels 0…5, from its board's documentation.
KNOWN_FRAMES = {
    "maestro": b"".join(_maestro_set_target(c, us) for c, us in enumerate(KNOWN)),
    "ssc32": b"#0P1500#1P1000#2P2000#3P1234#4P1766#5P1600T20\r",  # group move, whole µs, T: the move's ms
    "line": b"W 1500,1000,2000,1234,1766,1600\n",  # the sketch's frame (arduino/), whole µs
}


def test_every_protocol_is_a_choice_and_has_a_parser_and_a_known_frame() -> None:
    assert set(PROTOCOLS) == set(PARSERS) == set(PROTOCOL_CHOICES) == set(KNOWN_FRAMES) == set(WIRE_STEP_US)


@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
def test_a_known_frame_is_the_manual_s_bytes(protocol: str, device: FakeDevice) -> None:
    board = Board(device, protocol)  # (the line protocol's board says "ready" as the controller opens)
    controller = open_controller(protocol, device.path)
    try:
        assert controller.frame(np.array(KNOWN)) == KNOWN_FRAMES[protocol]
    finally:
        controller.close()
        board.stop()


@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
def test_frames_reach_the_board_as_sent_and_its_answer_confirms_them(protocol: str, device: FakeDevice) -> None:
    """Frames of random pulses through the port, parsed by the protocol's board-side parser: each arrives as the
    pulses sent, to the protocol's resolution; the board's answer to the position query confirms the last."""
    rng = np.random.default_rng(3)
    sent = rng.uniform(1000.0, 2000.0, (5, 6))
    board = Board(device, protocol)
    controller = open_controller(protocol, device.path)
    try:
        for pulses in sent:
            controller.send(pulses)
            controller.drain()
        deadline = time.monotonic() + 10.0
        while len(board.frames) < len(sent) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(board.frames) == len(sent), board.frames
        assert np.abs(np.array(board.frames) - sent).max() <= WIRE_STEP_US[protocol] / 2 + 1e-9  # rounded once
        held, answer = controller.confirm(sent[-1])
        assert held, answer
        assert not controller.confirm(sent[-1] + controller.resolution_us + 2.0)[0]  # other pulses: not confirmed
    finally:
        controller.close()
        board.stop()
