"""The Arduino sketch (``arduino/stewart_pca9685``) compiled and run on this machine, its Arduino core, I²C and panel
stood in for by ``tests/data/sketch_host`` (a C++ compiler is all it needs): what it writes to the PCA9685 for a
frame, what it refuses, what it says of the panel, and that the PC's side of the line protocol (``LineProtocol``,
and the virtual board's ``LineParser``) agrees with it line for line."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from stewart_gym.hardware.protocols import LineProtocol
from stewart_gym.hardware.virtual_device import LineParser, Parsed

ROOT = Path(__file__).resolve().parents[2]
HOST = ROOT / "tests" / "data" / "sketch_host"
SKETCH = ROOT / "arduino" / "stewart_pca9685" / "stewart_pca9685.ino"
COMPILER = shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")

pytestmark = pytest.mark.skipif(COMPILER is None, reason="no C++ compiler to build the sketch on this machine")

#: Lines the sketch takes: a frame, the same with the fence's ends, and the question.
GOOD = ["W 1500,1000,2000,1234,1766,1600", "W 900,2100,900,2100,900,2100", "?"]
#: Lines it refuses, each with an E line and nothing moved.
BAD = [
    "W 1500,1500,1500,1500,1500",  # five pulses
    "W 1500,1500,1500,1500,1500,1500,1500",  # seven
    "W 1500 1500 1500 1500 1500 1500",  # no commas
    "W 1500,1500,1500,1500,1500,15000",  # five digits
    "W 01500,1500,1500,1500,1500,1500",  # five digits, within the fence
    "W 150,1500,1500,1500,1500,1500",  # a dropped digit
    "W 1500,1500,1500,1500,1500,1500x",  # something after
    "W 1500,,1500,1500,1500,1500",
    "W -1500,1500,1500,1500,1500,1500",
    "W 1500,1500,1500,1500,1500,2200",  # outside the fence
    "W 1500,1500,1500,1500,1500,899",
    "? ",
    "W 1500,1500,1500,1500,1500,1500 ",  # a space after
    "W 1500,1500,1500,1500,1500,1500\0junk",  # a NUL in it
    "hello",
    "W 1500,1500,1500,1500,1500,1500" + ",1500" * 8,  # longer than the sketch's line
]


@pytest.fixture(scope="module")
def sketch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sketch built for this machine, with the address and undefined-behaviour sanitizers where the compiler
    has them (a write past the line buffer, a signed overflow: an error, not a pass). Its ``int`` is 32 bits
    here and 16 on an Uno: the sketch does its pulse arithmetic in ``long``."""
    binary = tmp_path_factory.mktemp("sketch") / "sketch"
    command = [COMPILER, "-std=c++17", "-Wall", "-Wextra", "-Werror", f"-I{HOST}", f'-DSKETCH="{SKETCH}"', "-x", "c++",
               str(HOST / "harness.cpp"), "-o", str(binary)]  # fmt: skip
    checked = subprocess.run([*command, "-fsanitize=address,undefined", "-fno-sanitize-recover=all"],
                             capture_output=True, timeout=120)  # fmt: skip
    if checked.returncode != 0:  # no sanitizer runtime here: the plain build
        subprocess.run(command, check=True, capture_output=True, timeout=120)
    return binary


def run(sketch: Path, script: list[str], *args: str) -> list[str]:
    """What the board sends (and, as ``#I2C …`` lines, what it writes to the PCA9685) for the harness ``script``."""
    done = subprocess.run([str(sketch), *args], input="\n".join(script) + "\n", capture_output=True, text=True,
                          timeout=30, check=True)  # fmt: skip
    return [line.rstrip("\r") for line in done.stdout.splitlines()]


def ticks(us: float) -> int:
    """A pulse in PCA9685 ticks at 25 MHz and prescale 121 (122 oscillator periods a tick), rounded."""
    return round(us * 25e6 / 122 / 1e6)


def channel_bytes(pulses: list[float]) -> list[int]:
    return [b for us in pulses for b in (0, 0, ticks(us) & 0xFF, ticks(us) >> 8)]


def i2c(lines: list[str]) -> list[list[int]]:
    return [[int(b, 16) for b in line.split()[1:]] for line in lines if line.startswith("#I2C")]


def test_it_sets_up_the_pca9685_goes_to_neutral_and_says_ready_with_its_fence(sketch: Path) -> None:
    out = run(sketch, [])
    assert i2c(out) == [[0x40, 0x00, 0x10], [0x40, 0xFE, 121], [0x40, 0x01, 0x04], [0x40, 0x00, 0x20],
                        [0x40, 0x06, *channel_bytes([1500] * 6)]]  # fmt: skip
    assert "ready 900,2100" in out and "#CLOCK 400000" in out
    assert LineProtocol.parse_ready("ready 900,2100") == (900.0, 2100.0)
    assert LineProtocol.ready().decode().rstrip() in out  # the line the virtual board sends too


def test_a_frame_moves_all_six_servos_in_one_transaction_and_the_answer_echoes_it(sketch: Path) -> None:
    pulses = [1500.0, 1000.0, 2000.0, 1234.0, 1766.0, 1600.0]
    frame = LineProtocol.frame(pulses).decode()
    assert frame.endswith("\n") and frame.count("\n") == 1
    out = run(sketch, [f"send {frame[:-1]}", "send ?", "loop 1"])
    assert i2c(out)[-1] == [0x40, 0x06, *channel_bytes(pulses)]  # 1500 µs: 307 ticks (4.9 µs each)
    answers = [line for line in out if line.startswith("P ")]
    assert len(answers) == 1 and LineProtocol.parse_held(answers[0]) == tuple(pulses)


@pytest.mark.parametrize("bad", BAD)
def test_a_line_it_cannot_take_is_refused_and_nothing_moves(sketch: Path, bad: str) -> None:
    out = run(sketch, [f"send {bad}", "send ?", "loop 1"])
    refusals = [line for line in out if line.startswith("E ")]
    assert len(refusals) == 1 and LineProtocol.parse_refusal(refusals[0]) is not None, out
    assert len(i2c(out)) == 5  # the set-up's writes alone
    assert [line for line in out if line.startswith("P ")] == ["P 1500,1500,1500,1500,1500,1500"]


def test_the_virtual_board_takes_and_refuses_the_lines_the_sketch_does(sketch: Path) -> None:
    """The virtual board stands in for the sketch in the tests and in ``virtual-device``: line by line, it takes
    what the sketch takes (a frame's targets, an answer to ``?``), answers an E line where the sketch does, and
    lets an empty line go without a word, as the sketch does."""
    for text in GOOD + BAD + [""]:
        out = run(sketch, [f"send {text}", "loop 1"])
        sketch_took = len(i2c(out)) > 5 or any(line.startswith("P ") for line in out)
        sketch_refused = any(line.startswith("E ") for line in out)
        parsed = Parsed()
        LineParser(range(6), lambda channel, pending=None: 1500.0).feed(text.encode() + b"\n", parsed)
        board_took = bool(parsed.targets) or any(reply.startswith(b"P ") for reply in parsed.replies)
        board_refused = any(reply.startswith(b"E ") for reply in parsed.replies)
        assert (board_took, board_refused) == (sketch_took, sketch_refused), text
        assert sketch_took != sketch_refused or text == "", text  # (an empty line: neither)


def test_the_panel_says_no_touch_when_nothing_presses_it(sketch: Path) -> None:
    """Untouched, the sense pins float (mid-scale here): the touch test says no ball, not a ball at the centre."""
    import itertools

    out = run(sketch, ["loop 35", "touch 700 300", "loop 35", "untouch", "loop 35"])  # 100 Hz: 3 or 4 each
    assert not any(line.startswith("#BADREAD") for line in out)  # no pin read in a state the panel cannot be in
    runs = [(line, len(list(group))) for line, group in itertools.groupby(line for line in out if line.startswith("B "))]
    assert [line for line, _ in runs] == ["B -", "B 64.9,-73.1", "B -"] and all(n >= 3 for _, n in runs), runs
    assert LineProtocol.parse_ball(runs[1][0]) == pytest.approx(((700 - 512) * 0.345, (300 - 512) * 0.345), abs=0.05)
    assert LineProtocol.parse_ball("B -") is None


def test_a_pca9685_that_reset_is_set_up_again_and_a_frame_it_did_not_take_is_not_held(sketch: Path) -> None:
    """Its power dipped: it woke asleep with its prescale lost. The next frame says so, sets it up again and goes
    out. A frame the bus did not carry is refused, and the answer to ``?`` keeps the pulses it holds."""
    out = run(sketch, ["brownout", "send W 1600,1600,1600,1600,1600,1600", "loop 1", "nack",
                       "send W 1700,1700,1700,1700,1700,1700", "send ?", "loop 1"])  # fmt: skip
    assert "E PCA9685 had reset (its power dipped?): set up again" in out
    assert i2c(out)[5:] == [[0x40, 0x00, 0x10], [0x40, 0xFE, 121], [0x40, 0x01, 0x04], [0x40, 0x00, 0x20],
                            [0x40, 0x06, *channel_bytes([1600] * 6)]]  # fmt: skip
    assert "E PCA9685 did not take the frame (I2C error)" in out
    assert [line for line in out if line.startswith("P ")] == ["P 1600,1600,1600,1600,1600,1600"]


def test_without_a_pca9685_it_says_so_and_never_ready(sketch: Path) -> None:
    out = run(sketch, [], "nopca")
    assert out == ["E no PCA9685 at I2C address 0x40: check its wiring and power"] * 3

