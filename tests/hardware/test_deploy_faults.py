"""The Hardware page's "What happens when…" table, row by row, through the real command line and real processes.

Each row of :data:`~stewart_gym.hardware.behaviour.DEPLOY_BEHAVIOUR` is made to happen here: ``stewart-gym
deploy`` runs as a user runs it (the installed script, in its own process) against a scripted board on a
pseudo-terminal (:class:`~conftest.Board`: it parses what deploy writes as the real board would, answers its
position queries, and on the line protocol sends the panel's readings, good or bad). A test says which rows it
covers (:func:`covers`); the last test checks that every row is covered and that the page's table is the one
the code defines.
"""

from __future__ import annotations

import csv
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import Board, FakeDevice, cli

import stewart_gym
from stewart_gym.calibration import ServoCalibration
from stewart_gym.hardware.behaviour import DEPLOY_BEHAVIOUR, behaviour_table

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = str(Path(sys.executable).parent / "stewart-gym")
HOME = ServoCalibration.default("servo-hexapod").neutral_us
COVERED: set[str] = set()
#: s: the longest any case here may take before it counts as a hang (the issue's bound; they take 2–8 s).
HANG_S = 60


def covers(*keys: str):
    """Mark a test as making these rows of the table happen."""
    COVERED.update(keys)
    return lambda test: test


def start(device: FakeDevice, *args: str, cwd: Path, preexec_fn: Callable[[], object] | None = None) -> subprocess.Popen:
    """``stewart-gym deploy --port DEVICE ARGS`` in its own process (``preexec_fn`` runs in it before)."""
    return subprocess.Popen([SCRIPT, "deploy", "--port", device.path, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd, preexec_fn=preexec_fn)  # fmt: skip


def run(device: FakeDevice, *args: str, cwd: Path, board: Board | None) -> tuple[int, str, str, list[dict]]:
    """Run deploy to its end; (exit code, stdout, stderr, the log's rows)."""
    log = cwd / "log.csv"
    proc = start(device, *args, "--log", str(log), "--overwrite", cwd=cwd)
    out, err = proc.communicate(timeout=HANG_S)
    if board is not None:
        board.stop()
    rows = list(csv.DictReader(log.open())) if log.exists() else []
    return proc.returncode, out, err, rows


def one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err and len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def panel(good: tuple[float, float] = (40.0, -20.0), bad: bytes = b"B nan,nan\n", window=(math.inf, math.inf)):
    """The panel's lines: ``good`` (mm), but ``bad`` while ``window[0] <= t < window[1]`` (s since the first frame)."""
    ok = f"B {good[0]},{good[1]}\n".encode()
    return lambda t: bad if window[0] <= t < window[1] else ok


def line_frames(board: Board) -> np.ndarray:
    return np.array(board.frames)


# ------------------------------------------------------------------ the end
@covers("duration")
def test_a_run_that_ends_drives_home_and_the_board_confirms_it(device: FakeDevice, tmp_path: Path) -> None:
    board = Board(device)
    code, out, err, rows = run(device, "--duration", "1.5", cwd=tmp_path, board=board)
    assert code == 0 and "completed" in out and "servos homed: confirmed by the board" in out, out + err
    assert np.allclose(board.frames[-1], np.round(HOME * 4) / 4)  # the last frame is the home frame
    assert board.queries >= 6  # asked along the way (every 0.25 s) and at the end


@covers("signal")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_mid_run_drives_home_and_exits_128_plus_its_number(sig: int, device: FakeDevice,
                                                                        tmp_path: Path) -> None:  # fmt: skip
    board = Board(device)
    proc = start(device, "--log", str(tmp_path / "l.csv"), cwd=tmp_path)
    deadline = time.monotonic() + HANG_S
    while len(board.frames) < 40 and time.monotonic() < deadline:  # running: 40 frames in
        time.sleep(0.05)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=HANG_S)
    board.stop()
    name = signal.Signals(sig).name
    assert proc.returncode == 128 + sig, out + err
    assert f"stopped by {'Ctrl-C (SIGINT)' if sig == signal.SIGINT else name}" in out and "Traceback" not in err
    assert "servos homed: confirmed by the board" in out
    assert np.allclose(board.frames[-1], np.round(HOME * 4) / 4), board.frames[-1]  # the last frame received: home
    assert len(board.frames) > 40


@covers("signal")
def test_ctrl_c_drives_home_even_where_the_process_was_started_with_it_ignored(device: FakeDevice,
                                                                              tmp_path: Path) -> None:  # fmt: skip
    """A background job of a script starts with SIGINT ignored; deploy takes it all the same, homes and exits
    130 (a stop signal is never lost while the servos move)."""
    board = Board(device)
    proc = start(device, "--log", str(tmp_path / "l.csv"), cwd=tmp_path,
                 preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))  # fmt: skip
    deadline = time.monotonic() + HANG_S
    while len(board.frames) < 40 and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=HANG_S)
    board.stop()
    assert proc.returncode == 130 and "servos homed: confirmed by the board" in out, out + err
    assert np.allclose(board.frames[-1], np.round(HOME * 4) / 4), board.frames[-1]


#: ``python -c KICK MODULE ARGS…``: the command line (``stewart-gym ARGS…``) with a Ctrl-C (SIGINT) sent to
#: itself at the moment MODULE starts to load: a signal at an exact moment of the start-up, on any machine.
KICK = """
import os, signal, sys
module = sys.argv.pop(1)
class Kick:
    def find_spec(self, name, path=None, target=None):
        if name == module:
            os.kill(os.getpid(), signal.SIGINT)
        return None
sys.meta_path.insert(0, Kick())
from stewart_gym.cli import main
sys.exit(main())
"""


@covers("startup_signal")
@pytest.mark.parametrize("module", ["stewart_gym.envs", "stewart_gym.cli.common"])
def test_a_ctrl_c_while_the_package_loads_is_not_lost_where_it_started_ignored(module: str, device: FakeDevice,
                                                                              tmp_path: Path) -> None:  # fmt: skip
    """A background job of a script starts with SIGINT ignored; a Ctrl-C (SIGINT) while the package loads, or the
    command line's own modules, is noted and stops the command as soon as it runs: one line, exit 130, and no byte
    reaches the board (it went on to wait for the board, and then to drive it, when the signal was lost)."""
    proc = subprocess.Popen([sys.executable, "-c", KICK, module, "deploy", "--port", device.path, "--protocol", "line",
                             "--sensor", "panel", "--log", str(tmp_path / "l.csv")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))  # fmt: skip
    out, err = proc.communicate(timeout=HANG_S)
    assert one_error_line(err).startswith("error: stopped by") and proc.returncode == 130, (proc.returncode, err)
    assert device.read_all(wait=0.2, timeout=1.0) == b""  # nothing was sent


def wait_until_it_handles(proc: subprocess.Popen, sig: int) -> None:
    """Wait until the process has its own handler for ``sig`` (the SigCgt mask of ``/proc/PID/status``); where
    there is no ``/proc``, 1.5 s."""
    status = Path(f"/proc/{proc.pid}/status")
    if not status.exists():
        time.sleep(1.5)
        return
    deadline = time.monotonic() + HANG_S
    while True:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        caught = next(ln for ln in status.read_text().splitlines() if ln.startswith("SigCgt:"))
        if int(caught.split()[1], 16) >> (sig - 1) & 1:
            return
        time.sleep(0.005)


@covers("startup_signal")
@pytest.mark.parametrize("sig,after_s", [(signal.SIGINT, 0.0), (signal.SIGINT, 1.0), (signal.SIGINT, 2.0),
                                         (signal.SIGTERM, 0.0), (signal.SIGTERM, 1.0), (signal.SIGHUP, 2.0)])  # fmt: skip
def test_a_stop_signal_during_start_up_is_one_line_and_moves_nothing(sig: int, after_s: float, device: FakeDevice,
                                                                    tmp_path: Path) -> None:  # fmt: skip
    """Loading the commands' modules and the policy, then waiting for the line sketch's ``ready`` (this board
    never says it): a signal at any of these moments, ``after_s`` after the package began to note stop signals as
    it loads as the command (0: while it loads), is one line and 128 + its number, and no byte reaches the board.
    (SIGINT starts at its default, as in a terminal; before that, in the interpreter's own start-up, a signal ends
    the process as the operating system's default says, before anything is sent.)"""
    proc = start(device, "--protocol", "line", "--sensor", "panel", "--log", str(tmp_path / "l.csv"), cwd=tmp_path,
                 preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    wait_until_it_handles(proc, signal.SIGTERM)  # main() is running: its stop handlers are in
    time.sleep(after_s)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=HANG_S)
    line = one_error_line(err)
    assert line.startswith("error: stopped by") and proc.returncode == 128 + sig, (proc.returncode, err)
    assert device.read_all(wait=0.2, timeout=1.0) == b""  # nothing was sent
    assert not (tmp_path / "l.csv").exists()


# -------------------------------------------------------------- the readings
@pytest.mark.slow
@covers("invalid_readings")
@pytest.mark.parametrize("bad", [b"B nan,nan\n", b"B inf,-inf\n", b"B 900.0,0.0\n"])
def test_invalid_readings_mid_run_are_no_reading_and_control_resumes(bad: bytes, device: FakeDevice,
                                                                    tmp_path: Path) -> None:  # fmt: skip
    """0.3 s of NaN, infinite or off-plate readings 1 s in: the ticks are marked invalid, the watchdog drives
    home, and control resumes within 2 ticks of the first good reading; no NaN pulse reaches the wire."""
    board = Board(device, "line", lines=panel(bad=bad, window=(1.0, 1.3)))
    code, out, err, rows = run(device, "--protocol", "line", "--sensor", "panel", "--duration", "3", cwd=tmp_path,
                               board=board)  # fmt: skip
    assert code == 0 and "Traceback" not in err, out + err
    invalid = [k for k, r in enumerate(rows) if r["invalid"] == "1"]
    assert len(invalid) >= 8, out  # about 15 ticks of 20 ms
    assert any(r["homing"] == "1" for r in rows[invalid[0]:invalid[-1] + 1])  # the watchdog sent it home
    after = rows[invalid[-1] + 1:invalid[-1] + 3]  # the 2 ticks after the first good reading
    assert any(r["stale"] == "0" and r["homing"] == "0" and r["held"] == "0" for r in after), after
    assert all(r["invalid"] == "0" and r["stale"] == "0" for r in rows[invalid[-1] + 5:])  # and stays in control
    assert f"invalid readings {len(invalid)}" in out
    pulses = np.array([[float(r[f"pulse{i}_us"]) for i in range(6)] for r in rows])
    assert np.all(np.isfinite(pulses)) and np.all(np.isfinite(line_frames(board)))
    assert np.all((line_frames(board) >= 1000) & (line_frames(board) <= 2000))


@covers("invalid_readings")
def test_nan_readings_at_the_start_hold_home_until_good_ones_come(device: FakeDevice, tmp_path: Path) -> None:
    board = Board(device, "line", lines=panel(window=(0.0, 0.8)))
    code, out, err, rows = run(device, "--protocol", "line", "--sensor", "panel", "--duration", "3", cwd=tmp_path,
                               board=board)  # fmt: skip
    assert code == 0, out + err
    first = [r for r in rows if float(r["t_s"]) < 0.7]
    assert first and all(r["stale"] == "1" and r["homing"] == "1" for r in first)
    late = [r for r in rows if float(r["t_s"]) > 1.2]
    assert late and all(r["stale"] == "0" and r["invalid"] == "0" for r in late)
    # in control from then on, but for a tick after the loop overran (a busy machine held it): that one goes home
    assert all(r["homing"] == "0" for r in late if r["missed_deadline"] == "0")
    assert sum(r["missed_deadline"] == "0" for r in late) >= len(late) // 2


@pytest.mark.slow
@covers("no_valid_readings")
@pytest.mark.parametrize("bad", [b"B 1e308,-1e308\n", b"B nan,nan\n", b"B 0.5,\n"])
def test_a_run_without_valid_readings_fails(bad: bytes, device: FakeDevice, tmp_path: Path) -> None:
    """Absurd (1e308), NaN or unparsable readings for the whole run: no tick takes them as fresh, the platform is
    held home, and the run fails."""
    board = Board(device, "line", lines=lambda t: bad)
    code, out, err, rows = run(device, "--protocol", "line", "--sensor", "panel", "--duration", "1.5", cwd=tmp_path,
                               board=board)  # fmt: skip
    assert code == 1 and "failed: no fresh valid reading on 75 of 75 ticks" in out, out + err
    assert all(r["stale"] == "1" for r in rows) and "servos homed: confirmed by the board" in out
    assert np.allclose(line_frames(board), np.round(HOME))  # never left home


@covers("garbage")
def test_garbage_after_ready_is_ignored(device: FakeDevice, tmp_path: Path) -> None:
    noise = [b"\x00\xff\xfe garbage\n", b"B 12.0\n", b"Bx 1,2\n", b"ready\n", b"P 1,2,3\n", b"Ex junk\n"]
    good = b"B 40.0,-20.0\n"
    board = Board(device, "line", lines=lambda t: noise[int(t * 100) % len(noise)] + good)
    code, out, err, rows = run(device, "--protocol", "line", "--sensor", "panel", "--duration", "1.5", cwd=tmp_path,
                               board=board)  # fmt: skip
    assert code == 0 and "Traceback" not in err, out + err
    assert sum(r["stale"] == "1" for r in rows) <= 3 and all(r["invalid"] == "0" for r in rows)
    assert "servos homed: confirmed by the board" in out


# ----------------------------------------------------------------- the board
@pytest.mark.slow
@covers("board_silent")
def test_a_board_that_never_answers_is_refused_before_anything_moves(device: FakeDevice, tmp_path: Path) -> None:
    board = Board(device, answer=False)
    code, out, err, _ = run(device, "--duration", "1", cwd=tmp_path, board=board)
    assert code == 2 and "did not answer a position query" in one_error_line(err) and "--write-only" in err
    assert board.frames == []  # not one frame
    board = Board(device, answer=False)  # with its replies declared unwired, it runs, and says what it cannot know
    code, out, err, _ = run(device, "--duration", "1", "--write-only", cwd=tmp_path, board=board)
    assert code == 0 and "home frame sent, not confirmed" in out and board.queries == 0, out + err


@pytest.mark.slow
@covers("board_stops")
@pytest.mark.parametrize("fault", [{"stop_reading_after": 1.0}, {"read_rate": 600.0}])
def test_a_board_that_stops_reading_or_reads_too_slowly_is_a_device_failure(fault: dict, device: FakeDevice,
                                                                            tmp_path: Path) -> None:  # fmt: skip
    """It stops reading 1 s in, or reads 600 bytes/s of the 1,250 sent: deploy does not report success."""
    board = Board(device, **fault)
    start_s = time.monotonic()
    code, out, err, rows = run(device, "--duration", "30", cwd=tmp_path, board=board)
    assert code == 2 and "device failure" in out and "unanswered" in out, out + err
    assert "servos NOT" in out and "confirmed by the board" not in out
    # it stopped long before its 30 s (2.5–6 s in here; the bound is loose for a loaded machine, not a speed test)
    assert float(rows[-1]["t_s"]) < 25.0 and time.monotonic() - start_s < HANG_S


@covers("home_mismatch")
def test_a_board_that_reports_other_pulses_at_the_end_is_not_confirmed(device: FakeDevice, tmp_path: Path) -> None:
    board = Board(device, answer_offset_us=25.0)
    code, out, err, _ = run(device, "--duration", "1", cwd=tmp_path, board=board)
    assert code == 2 and "servos NOT confirmed home (the board holds" in out, out + err


@covers("home_lost")
def test_a_home_frame_lost_on_the_line_is_sent_again_until_the_board_holds_it(device: FakeDevice,
                                                                             tmp_path: Path) -> None:  # fmt: skip
    board = Board(device, lose_home_frames=2)
    code, out, err, _ = run(device, "--duration", "1", cwd=tmp_path, board=board)
    assert board.lost_frames == 2 and np.allclose(board.frames[-1], np.round(HOME * 4) / 4)
    assert code == 0 and "confirmed by the board (after sending the home frame 2 more time(s))" in out, out + err


@covers("log_unwritable")
def test_a_log_that_cannot_be_written_ends_the_run_home_with_its_summary(device: FakeDevice, tmp_path: Path) -> None:
    """A file size limit (as a full disk) stops the log after a few rows: the run ends, drives home, and prints its
    summary naming the log. A log that cannot take even its header is one error line, and nothing moves."""
    import resource

    board = Board(device)
    limit = lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))  # noqa: E731  (Python ignores SIGXFSZ)
    proc = start(device, "--duration", "5", "--log", str(tmp_path / "l.csv"), cwd=tmp_path, preexec_fn=limit)
    out, err = proc.communicate(timeout=HANG_S)
    board.stop()
    assert proc.returncode == 1 and "Traceback" not in err, out + err
    assert f"error: the log {tmp_path / 'l.csv'} cannot be written (File too large)" in out, out
    assert "servos homed: confirmed by the board" in out and np.allclose(board.frames[-1], np.round(HOME * 4) / 4)
    assert 10 < len(board.frames) < 5 * 50  # it ran, and stopped early

    (tmp_path / "full.csv").symlink_to("/dev/full")
    board = Board(device)
    proc = start(device, "--duration", "1", "--log", str(tmp_path / "full.csv"), "--overwrite", cwd=tmp_path)
    out, err = proc.communicate(timeout=HANG_S)
    board.stop()
    assert proc.returncode == 1 and "No space left on device); nothing was moved" in one_error_line(err), err
    assert board.frames == []


@pytest.mark.slow
@covers("unplugged")
def test_an_unplugged_port_stops_the_run_and_says_it_could_not_home(device: FakeDevice, tmp_path: Path) -> None:
    board = Board(device)
    proc = start(device, "--log", str(tmp_path / "l.csv"), cwd=tmp_path)
    deadline = time.monotonic() + HANG_S
    while len(board.frames) < 20 and time.monotonic() < deadline:
        time.sleep(0.05)
    board.stop()
    device.unplug()
    out, err = proc.communicate(timeout=HANG_S)
    assert proc.returncode == 2 and "device failure" in out and "servos NOT homed" in out, out + err
    assert "Traceback" not in err and len((tmp_path / "l.csv").read_text().splitlines()) > 10


@pytest.mark.slow
@covers("camera_silent")
def test_a_camera_that_delivers_no_frame_is_refused_before_the_port_opens(device: FakeDevice, tmp_path: Path) -> None:
    """The camera config a virtual board writes for its stream, but nobody writes to the pipe: one error line (no
    line of OpenCV's before it), exit 2, and the port never written."""
    from stewart_gym.camera import CAMERA_PRESETS
    from stewart_gym.hardware.virtual_device import stream_camera_config

    pipe = tmp_path / "camera.mjpg"  # as the docs name it (OpenCV's warning came with this suffix, not .mjpeg)
    os.mkfifo(pipe)  # nobody ever writes to it
    config = tmp_path / "camera.toml"
    config.write_text(stream_camera_config(CAMERA_PRESETS["pixy2"], pipe).to_toml())
    board = Board(device)
    began = time.monotonic()
    code, out, err, _ = run(device, "--sensor", "camera", "--camera-config", str(config), "--duration", "2",
                            cwd=tmp_path, board=board)  # fmt: skip
    assert code == 2 and "delivered no frame within 5 s" in one_error_line(err), err
    assert board.data == bytearray() and time.monotonic() - began < HANG_S  # the port was never written


@covers("bad_input")
def test_a_damaged_bundle_is_refused_before_the_port_opens(device: FakeDevice, tmp_path: Path) -> None:
    """A bundle with 3 of its 12 obs_mean values (and the table's other cases: ``test_cli.BAD``)."""
    import json
    import shutil

    from stewart_gym.registry import POLICY_DIR

    bundle = tmp_path / "bundle"
    shutil.copytree(POLICY_DIR / "balance" / "bundle", bundle)
    meta = json.loads((bundle / "bundle.json").read_text())
    meta["obs_mean"] = meta["obs_mean"][:3]
    (bundle / "bundle.json").write_text(json.dumps(meta))
    board = Board(device)
    code, out, err, _ = run(device, "--policy", str(bundle), "--duration", "1", cwd=tmp_path, board=board)
    assert code == 1 and "obs_mean must be 12 finite numbers" in one_error_line(err) and board.data == bytearray()


@covers("policy_unusable", "missed_deadlines")
def test_the_loop_s_own_failures_are_in_test_deploy() -> None:
    """A policy that never gives a usable action, and a machine that misses its deadlines, are the loop's own
    verdicts: ``test_deploy.test_a_loop_where_every_tick_holds_fails`` and
    ``test_deploy.test_a_loop_that_misses_its_deadlines_fails`` make them happen with the loop in this process
    (no command line option makes a policy return NaN). Here: those tests exist."""
    import test_deploy

    assert callable(test_deploy.test_a_loop_where_every_tick_holds_fails)
    assert callable(test_deploy.test_a_loop_that_misses_its_deadlines_fails)


@covers("camera_ends", "camera_lost")
def test_a_camera_source_that_ends_is_in_test_deploy_and_test_camera() -> None:
    """A source that runs out, and a live one lost, are the loop's to handle: ``test_deploy`` drives the loop with
    a sensor that does each (the tick named; exit 0 or 1; exit 2 with home confirmed), and ``test_camera`` plays a
    0.5 s video in a 1 s deploy through the command line. Here: those tests exist."""
    import importlib.util

    import test_deploy

    assert callable(test_deploy.test_a_sensor_whose_source_runs_out_is_named_with_its_tick)
    assert callable(test_deploy.test_a_live_camera_lost_mid_run_is_a_device_failure_and_the_board_confirms_home)
    spec = importlib.util.spec_from_file_location("camera_tests", ROOT / "tests" / "test_camera.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert callable(module.test_a_camera_that_never_finds_the_ball_sends_the_platform_home)


# -------------------------------------------------------------- the table
def test_every_row_of_the_table_is_made_to_happen_and_the_page_shows_the_table() -> None:
    assert {b.key for b in DEPLOY_BEHAVIOUR} == COVERED
    page = (ROOT / "docs" / "src" / "hardware.md").read_text()
    assert behaviour_table() in page


def _calibration(servo_lines: list[str] | None = None, hardware: str = "") -> str:
    """A calibration file: six servos (each with ``servo_lines[i]`` where given) and a ``hardware`` line or table."""
    lines = servo_lines or [""] * 6
    servos = "".join(f"\n[[servo]]\n{'' if 'channel' in lines[i] else f'channel = {i}'}\n{lines[i]}\n" for i in range(6))
    return hardware + "\n" + servos


MISWIRED = [
    # (calibration file text, deploy's options, what the one error line must say)
    (_calibration(hardware="hardware = 3"), [], "hardware must be a table"),
    (_calibration(hardware='[hardware]\nparity = "N"'), [], "cal.toml: hardware: unknown field(s) ['parity']"),
    (_calibration(["channel = 0.9"] + [""] * 5), [], "servo[0].channel: the board's channel, a whole number"),
    (_calibration(["direction = 0.5"] + [""] * 5), [], "servo[0].direction: +1 or -1"),
    (_calibration(["home_angle_deg = 1000"] * 6), [], "servo[0].home_angle_deg: the horn's angle at home, within ±180°"),
    (_calibration(["min_us = 100"] + [""] * 5), [], "servo[0].min_us: 100 µs is outside 400–2600 µs"),
    (_calibration(["max_us = 3000"] + [""] * 5), [], "servo[0].max_us: 3000 µs is outside 400–2600 µs"),
    ("\n".join(f"[[servo]]\nchannel = {c}" for c in (5, 4, 3, 2, 1, 0)), ["--protocol", "line", "--sensor", "panel"],
     "the line protocol's sketch drives servo k on PCA9685 channel k"),
    ("\n".join(f"[[servo]]\nchannel = {c}" for c in range(26, 32)), ["--protocol", "ssc32"], ""),  # an SSC-32's 0…31
    ("\n".join(f"[[servo]]\nchannel = {c}" for c in range(20, 26)), ["--protocol", "maestro"],
     "channel(s) [24, 25] are not on a maestro board, whose channels are 0…23"),
]


@pytest.mark.parametrize("text,options,says", MISWIRED, ids=[m[2][:40] or "ssc32 channels 26-31" for m in MISWIRED])
def test_a_calibration_the_board_cannot_follow_is_refused_before_the_port_opens(
        text: str, options: list[str], says: str, tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """Each is one error line naming the field, before the port (which does not exist) opens; channels 26–31 on an
    SSC-32 are its own, so there the port is what fails (exit 2)."""
    (tmp_path / "cal.toml").write_text(text)
    code, out, err = cli(capfd, "deploy", "--calibration", "cal.toml", "--port", str(tmp_path / "no_port"), *options,
                         "--duration", "1", cwd=tmp_path)  # fmt: skip
    line = one_error_line(err)
    if says:
        assert code == 1 and says in line, line
    else:
        assert code == 2 and "no_port" in line, line


@covers("held_elsewhere")
def test_servos_held_elsewhere_start_from_where_they_are_at_the_rate_limit(device: FakeDevice,
                                                                            tmp_path: Path) -> None:  # fmt: skip
    """A Maestro that did not reset holds 1300 µs on every channel (a run that crashed left them there): the first
    frames move from 1300 at the rate limit (60 µs a tick), not straight to home, and deploy says so."""
    board = Board(device)
    board.held.update({c: 1300.0 for c in range(6)})
    code, out, err, _ = run(device, "--duration", "1", cwd=tmp_path, board=board)
    assert code == 0, out + err
    assert "the board holds 1300, 1300, 1300, 1300, 1300, 1300 µs: the first frames move from there" in out
    frames = np.array(board.frames)
    assert np.all(np.abs(frames[0] - 1300.0) <= 60.5), frames[0]
    assert np.all(np.abs(np.diff(frames, axis=0)) <= 60.5)


@covers("board_refuses")
def test_a_board_that_refuses_frames_is_a_device_failure_and_confirms_home(device: FakeDevice,
                                                                          tmp_path: Path) -> None:  # fmt: skip
    """From 0.5 s to 0.7 s the sketch sends an E line every 10 ms (frames garbled on the way): the run stops as a
    device failure within a few frames, drives home, and the board, which still reads, confirms it."""
    board = Board(device, "line", lines=lambda t: b"B 40.0,-20.0\n" + (b"E pulse outside the fence\n" if 0.5 <= t < 0.7
                                                                       else b""))  # fmt: skip
    code, out, err, rows = run(device, "--protocol", "line", "--sensor", "panel", "--duration", "3", cwd=tmp_path,
                               board=board)  # fmt: skip
    assert code == 2 and "refused 3 of the last 10 frames (pulse outside the fence)" in out, out + err
    assert "servos homed: confirmed by the board" in out and "Traceback" not in err
    assert 0.4 < float(rows[-1]["t_s"]) < 1.2  # stopped within a few frames of the refusals


def test_refusals_that_come_while_the_servos_go_home_leave_the_board_to_confirm_it(device: FakeDevice,
                                                                                     tmp_path: Path) -> None:  # fmt: skip
    """E lines from 1 s on in a 1 s run: they come during the drive home and the question that confirms it; the
    drive goes on, and the board's answer, home, confirms it."""
    board = Board(device, "line", lines=lambda t: b"B 40.0,-20.0\n" + (b"E pulse outside the fence\n" if t >= 1.0
                                                                       else b""))  # fmt: skip
    code, out, err, _ = run(device, "--protocol", "line", "--sensor", "panel", "--duration", "1", cwd=tmp_path,
                            board=board)  # fmt: skip
    assert "servos homed: confirmed by the board" in out and "Traceback" not in err, out + err
    assert code == 0, out  # the run had ended


@covers("bad_input")
def test_a_calibration_beyond_the_sketch_s_fence_is_refused_before_anything_moves(device: FakeDevice,
                                                                                   tmp_path: Path) -> None:  # fmt: skip
    """Limits of 850–2150 µs: the sketch (its ready line gives its fence, 900–2100) would refuse those frames and
    freeze its servos. One error line naming the calibration, the servo and the fence; nothing is written."""
    (tmp_path / "cal.toml").write_text("\n".join(f"[[servo]]\nchannel = {c}\nmin_us = 850\nmax_us = 2150"
                                                  for c in range(6)))  # fmt: skip
    board = Board(device, "line")
    code, out, err, _ = run(device, "--calibration", "cal.toml", "--protocol", "line", "--sensor", "panel",
                            "--duration", "1", cwd=tmp_path, board=board)  # fmt: skip
    line = one_error_line(err)
    assert code == 1 and "cal.toml: servo 0's limits 850–2150 µs leave the board's fence, 900–2100 µs" in line, line
    assert board.frames == [] and b"W " not in board.data


@pytest.mark.parametrize("options,says", [
    (["--trajectory", "circle"], "--trajectory needs a track policy (StewartBallTrack-v0)"),
    (["--rate", "10", "--max-step-us", "0.2"], "the drive home would take"),
])  # fmt: skip
def test_options_that_cannot_run_are_refused_in_one_line(options: list[str], says: str, tmp_path: Path,
                                                         capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    code, out, err = cli(capfd, "deploy", "--port", str(tmp_path / "no_port"), *options, "--duration", "1",
                         cwd=tmp_path)  # fmt: skip
    assert code == 1 and says in one_error_line(err), err


def test_a_slow_control_rate_gets_a_rate_limit_it_accepts(device: FakeDevice, tmp_path: Path) -> None:
    """At 2 Hz the default slew (3,000 µs/s) would be 1,500 µs a tick, beyond the loop's 1,000: it is held there,
    and the run goes home as any other."""
    board = Board(device)
    code, out, err, rows = run(device, "--rate", "2", "--duration", "2", cwd=tmp_path, board=board)
    assert code == 0 and "servos homed: confirmed by the board" in out, out + err
    assert len(rows) == 4


@pytest.mark.parametrize("command,noted", [(["-m", "stewart_gym", "ik"], True), (["-m", "stewart_gym.cli"], True),
                                           (["-m", "stewart_gym.envs.split_vector", "3", "4"], False),
                                           (["-c", "pass"], False)])  # fmt: skip
def test_only_the_command_itself_notes_stop_signals_while_it_loads(command: list[str], noted: bool) -> None:
    """The package notes SIGTERM and SIGHUP as it loads only in the command (its script, ``python -m stewart_gym``):
    another module of it run with ``-m`` (the split vector env's worker) or a program that imports it keeps the
    system's default, so that SIGTERM still ends it."""
    probe = ("import signal, sys; sys.orig_argv = [sys.executable, *{command!r}]; sys.argv = [{first!r}]; "
             "import stewart_gym; print(stewart_gym.AS_COMMAND, signal.getsignal(signal.SIGTERM) is signal.SIG_DFL)")
    first = "-m" if command[0] == "-m" else "-c"
    proc = subprocess.run([sys.executable, "-c", probe.format(command=command, first=first)], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == [str(noted), str(not noted)], proc.stdout


@pytest.mark.parametrize("script,given,expected", [
    ("/home/u/.venv/bin/stewart-gym", [], True), ("stewart-gym", [], True),
    (r"C:\Users\u\venv\Scripts\stewart-gym.exe", [], True), (r"C:\venv\Scripts\STEWART-GYM.EXE", [], True),
    (r"C:\venv\Scripts\stewart-gym-script.py", [], True), ("-m", ["python", "-m", "stewart_gym", "ik"], True),
    ("/home/u/bin/not-stewart-gym", [], False), ("/x/stewart-gym.py", [], False),
    ("-m", ["python", "-m", "stewart_gym.envs.split_vector", "3", "4"], False), ("-c", ["python", "-c", "-m"], False),
])  # fmt: skip
def test_the_command_is_known_by_its_script_on_every_system(script: str, given: list[str], expected: bool) -> None:
    """The command's script is known by its name in any folder, with Windows' separators and its ``.exe`` launcher
    too, so that a stop while it loads is one line there as well."""
    assert stewart_gym.is_command(script, given) is expected
