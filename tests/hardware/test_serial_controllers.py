"""Serial controllers on fake devices (pseudo-terminals): bytes on the wire, framing, the line protocol's ready wait."""


from __future__ import annotations

import sys
import threading
import time

import numpy as np
import pytest
from conftest import FakeDevice

from stewart_gym.calibration import ServoCalibration
from stewart_gym.hardware.protocols import Maestro
from stewart_gym.hardware.serial_controllers import DeviceError, LineController, MaestroController, SSC32Controller

CAL = ServoCalibration.default("servo-hexapod")


PULSES = np.array([1500.0, 1400.25, 1600.5, 1100.0, 1900.0, 1234.75])


def test_fake_maestro_receives_exact_bytes(device: FakeDevice) -> None:
    ctl = MaestroController(device.path, channels=[0, 1, 2, 3, 4, 5])
    ctl.send(PULSES)
    want = b"".join(Maestro.set_target(i, w) for i, w in enumerate(PULSES))
    got = device.read_all(size=len(want))
    assert got == want
    assert got[8:12] == bytes([0x84, 0x02, 0x02, 0x32])  # 1600.5 µs = 6402 quarter-µs = 50·128 + 2, channel 2
    multi = MaestroController(device.path, channels=range(6), multiple_targets=True)
    multi.send(PULSES)
    want = Maestro.set_multiple_targets(0, PULSES)
    assert device.read_all(size=len(want)) == want

    def answer() -> None:  # the device answers Get Errors with overrun + RX-buffer-full, a slow 0.2 s later
        for _ in range(250):
            data = device.read_all(0.02)
            if Maestro.GET_ERRORS in data:
                time.sleep(0.2)  # (within the answer timeout, 0.5 s; beyond one read's 0.05 s)
                device.write(bytes([0x06, 0x00]))
                return

    threading.Thread(target=answer, daemon=True).start()
    assert ctl.errors() == ["serial overrun error", "serial RX buffer full"]
    started = time.monotonic()
    with pytest.raises(DeviceError, match="did not answer Get Errors"):
        ctl.errors()  # no answer at all
    assert time.monotonic() - started >= ctl.answer_timeout_s
    ctl.close()
    multi.close()


def test_fake_ssc32_group_framing(device: FakeDevice) -> None:
    ctl = SSC32Controller(device.path, channels=[10, 11, 12, 13, 14, 15], move_ms=20)
    ctl.send(PULSES)
    want = b"#10P1500#11P1400#12P1600#13P1100#14P1900#15P1235T20\r"
    assert device.read_all(size=len(want)) == want
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
    want = b"W 1500,1400,1600,1100,1900,1235\n"
    assert device.read_all(size=len(want)) == want
    device.write(b"B 10.0,-5.5\nB 12.0,-6.0\n")
    time.sleep(0.05)
    (xy, _t) = ctl.poll_ball()
    assert xy == (12.0, -6.0)
    ctl.close()


def test_line_controller_dates_a_reading_when_it_arrives_between_ticks(device: FakeDevice) -> None:
    """The loop's wait between ticks reads the panel's lines as they come: a reading's time is its arrival, not
    the end of the wait (the next tick), which a loop reading only at its ticks would give it."""
    threading.Timer(0.2, device.write, args=(b"ready\n",)).start()  # once the port is open
    ctl = LineController(device.path, ready_timeout=3.0)
    written: list[float] = []

    def panel() -> None:
        time.sleep(0.05)
        written.append(time.monotonic())
        device.write(b"B 3.0,-4.0\n")

    threading.Thread(target=panel, daemon=True).start()
    start = time.monotonic()
    ctl.wait_until(start + 1.0)
    assert time.monotonic() >= start + 1.0  # it waited the whole time
    (xy, arrived) = ctl.poll_ball()
    assert xy == (3.0, -4.0) and written
    assert written[0] <= arrived < written[0] + 0.5  # dated when it came, not at the end of the wait
    ctl.close()


def test_line_controller_without_ready_fails_clearly(device: FakeDevice) -> None:
    with pytest.raises(DeviceError, match="no 'ready' line .* and no answer to '\\?'"):
        LineController(device.path, ready_timeout=0.2)
    assert device.read_all(0.05) == b"\n?\n"  # it asked once, after the wait (a line end first: see below)


def test_line_controller_takes_a_board_that_did_not_reset(device: FakeDevice) -> None:
    """A board still running the sketch (no reset on open) sends no 'ready', but answers '?'; a line end goes first,
    to end a half line an earlier connection may have left in its buffer."""

    def answer() -> None:  # a half line left in its buffer earns a refusal, which is not this connection's
        assert device.read_all(size=3) == b"\n?\n"
        device.write(b"E expected W w0,w1,w2,w3,w4,w5 or ?\nP 1500,1500,1500,1500,1500,1500\n")

    threading.Thread(target=answer, daemon=True).start()
    ctl = LineController(device.path, ready_timeout=0.2)
    ctl.send(PULSES)
    want = b"W 1500,1400,1600,1100,1900,1235\n"
    assert device.read_all(size=len(want)) == want
    ctl.close()


def test_a_sketch_without_its_pca9685_is_named_before_anything_is_sent(device: FakeDevice) -> None:
    threading.Timer(0.2, device.write, args=(b"E no PCA9685 at I2C address 0x40: check its wiring and power\n",)).start()
    with pytest.raises(DeviceError, match=r"the board on .* says: no PCA9685 at I2C address 0x40: check its wiring"):
        LineController(device.path, ready_timeout=3.0)
    assert device.read_all(0.05) == b""


def test_the_sketch_s_fence_is_checked_against_the_calibration_before_anything_is_sent(device: FakeDevice) -> None:
    """Its ready line gives the fence; limits that leave it are refused naming the servo, the limits and the fence
    (the sketch would refuse those frames and freeze its servos); limits within it are taken."""
    from stewart_gym.errors import ConfigError
    from stewart_gym.hardware.serial_controllers import open_controller

    threading.Timer(0.2, device.write, args=(b"ready 1000,2000\n",)).start()
    lows, highs = [1100.0] * 6, [1900.0] * 6
    highs[3] = 2050.0
    with pytest.raises(ConfigError, match=r"^cal.toml: servo 3's limits 1100–2050 µs leave the board's fence, "
                                          r"1000–2000 µs .*widen SERVO_MIN_US and SERVO_MAX_US in the sketch"):  # fmt: skip
        open_controller("line", device.path, range(6), limits=(lows, highs), source="cal.toml")
    assert device.read_all(0.05) == b""
    threading.Timer(0.2, device.write, args=(b"ready\n",)).start()  # a sketch that gives no fence: 900–2100
    ctl = open_controller("line", device.path, range(6), limits=(lows, highs))
    assert ctl.fence_us == (900.0, 2100.0)
    ctl.close()


def test_frames_the_sketch_refuses_again_and_again_are_a_device_failure(device: FakeDevice) -> None:
    """One refused frame (a line garbled on the way) is let go; 3 of the last 10 mean its servos are frozen."""
    threading.Timer(0.2, device.write, args=(b"ready 900,2100\n",)).start()
    ctl = LineController(device.path, ready_timeout=3.0)
    for _ in range(10):
        ctl.send(PULSES)
    device.write(b"E pulse outside the fence\n")
    ctl.wait_until(time.monotonic() + 0.1)  # read and let go
    for _ in range(10):
        ctl.send(PULSES)
    device.write(b"E pulse outside the fence\nE pulse outside the fence\n")
    ctl.wait_until(time.monotonic() + 0.1)  # 2 of the last 10: let go too (the first was 10 frames before)
    for _ in range(3):
        ctl.send(PULSES)
    device.write(b"E pulse outside the fence\n")
    time.sleep(0.1)
    with pytest.raises(DeviceError, match=r"refused 3 of the last 10 frames \(pulse outside the fence\): its servos"):
        ctl.wait_until(time.monotonic() + 0.1)
    ctl.close()


@pytest.mark.skipif(sys.platform == "win32", reason="termios is POSIX-only")
def test_a_port_that_fails_in_flush_is_a_device_error() -> None:
    """pyserial's flush() is tcdrain(): on a pty whose other end went away it raises termios.error, not OSError."""
    import termios

    class DrainFails:
        port = "/dev/ttyFAKE"
        is_open = True

        def write(self, data: bytes) -> int:
            return len(data)

        def flush(self) -> None:
            raise termios.error(5, "Input/output error")

    ctl = SSC32Controller(DrainFails())
    with pytest.raises(DeviceError, match="device unplugged"):
        ctl.send(PULSES)
    assert ctl.frames_sent == 0
