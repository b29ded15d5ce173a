"""What ``stewart-gym deploy`` does when something happens: one row per event, with its exit code.

The Hardware page's "What happens when…" table is :func:`behaviour_table` of :data:`DEPLOY_BEHAVIOUR`, written
into the page and kept equal by a test; each row's ``key`` names the test that makes it happen through the real
command line (``tests/hardware/test_deploy_faults.py``), so the table and the program cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DEPLOY_BEHAVIOUR", "Behaviour", "behaviour_table"]


@dataclass(frozen=True)
class Behaviour:
    """One row: ``when`` it happens, ``then`` what deploy does, and the ``exit`` code (text: some rows have two)."""

    key: str
    when: str
    then: str
    exit: str


DEPLOY_BEHAVIOUR: tuple[Behaviour, ...] = (
    Behaviour("duration", "the run reaches `--duration`",
              "drives the servos home at the rate limit, waits until the bytes have left (`tcdrain`), asks the board "
              "which pulses it holds and prints the summary: *servos homed: confirmed by the board*", "0"),
    Behaviour("signal", "Ctrl-C (SIGINT), SIGTERM (`kill`, systemd) or SIGHUP (the terminal closes) during the run",
              "the same drive home, confirmation and summary (*stopped by SIGTERM*); a second signal does not cut "
              "the drive home short (at most 2 s)", "128 + the signal's number: 130, 143, 129"),
    Behaviour("startup_signal", "one of those signals before the loop starts (loading, opening the port, waiting for "
              "the board)", "one line, *error: stopped by … before the command finished*; nothing has moved, no "
              "traceback (in Python's own start, the first few hundredths of a second before the package loads, the "
              "system's default ends the process, also before anything is sent)", "130, 143, 129"),
    Behaviour("invalid_readings", "readings that are NaN, infinite or off the plate (more than 10 % of its half "
              "size beyond its edge)",
              "each is no reading: the last valid one goes on ageing, so after `--watchdog-ms` (100) the platform "
              "drives home; control resumes on the first tick with a fresh valid reading; the log marks the ticks "
              "`invalid` and the summary counts them", "0"),
    Behaviour("no_valid_readings", "no fresh valid reading on most ticks (a sensor that sends only nonsense, "
              "garbage or nothing)", "the platform is held home meanwhile; the run ends *failed: no fresh valid "
              "reading on N of M ticks*", "1"),
    Behaviour("garbage", "lines that are not readings (noise, a half line, a reset's banner)",
              "ignored: only `B x,y`, `P …`, `ready` and `E …` mean something", "0"),
    Behaviour("board_refuses", "the sketch refuses frames (`E …`: a garbled line, a pulse outside its fence)",
              "one now and then is let go; 3 of the last 10 frames refused is a device failure (its servos would "
              "hold their pose): the run drives home and the board is asked to confirm it", "2"),
    Behaviour("held_elsewhere", "the board holds other pulses than home at the start (it did not reset, and a "
              "run that crashed left its servos there)",
              "the first frames move from where it holds them at the rate limit, not straight home; deploy says "
              "so (a channel that is off, or outside its limits, starts from home)", "0"),
    Behaviour("board_silent", "the board does not answer the first position query (replies not wired, an old "
              "sketch)", "refused before anything moves; `--write-only` runs without asking (homing is then "
              "*sent, not confirmed*)", "2"),
    Behaviour("board_stops", "the board stops reading, or reads more slowly than the frames arrive",
              "3 position queries in a row not answered within `--answer-timeout-ms` (500; a late answer is none): "
              "a device failure within about 3 s; the home frames are still written, and the summary says "
              "*servos NOT confirmed home*", "2"),
    Behaviour("home_lost", "the home frame (or the board's answer) is lost or garbled on the line",
              "the home frame is sent again and the board asked again, for up to 3 s: *servos homed: confirmed by the "
              "board (after sending the home frame N more time(s))*", "0"),
    Behaviour("home_mismatch", "the board still reports other pulses than the home ones at the end",
              "*servos NOT confirmed home (the board holds …)*", "2"),
    Behaviour("unplugged", "the port goes away (cable pulled, board reset)",
              "the loop stops at the first write or read that fails, keeps its log, and says *servos NOT homed*",
              "2"),
    Behaviour("camera_silent", "the camera (or the pipe it reads) delivers no frame within 5 s",
              "refused before the port opens: nothing moves (`camera-check` too says so after 5 s)", "2"),
    Behaviour("camera_ends", "the camera's video runs out during the run",
              "no frame comes after: the last reading ages, so after `--watchdog-ms` the platform drives home and "
              "is held there; the summary says *the sensor's source ended at tick N (the video ran out)*, and the "
              "run fails if most ticks had no fresh reading", "0, or 1 if most ticks had none"),
    Behaviour("camera_lost", "a live camera, or the stream it reads, stops delivering frames during the run",
              "a device failure: the run ends and drives home, and the board is still asked to confirm it "
              "(*device failure: camera …: the camera stopped delivering frames*)", "2"),
    Behaviour("bad_input", "a damaged bundle (a field of the wrong size or type), a bad calibration or camera "
              "config (its `source` a folder, or a file that is no video), a log that exists",
              "one `error:` line naming the file and the field, before the port opens", "1"),
    Behaviour("policy_unusable", "the policy gives a NaN or unreachable action",
              "that tick holds the last safe pulses; a run where every tick held fails", "0 (1 if every tick held)"),
    Behaviour("log_unwritable", "the log cannot be written (a full disk, a file size limit)",
              "before the port opens: one `error:` line naming the log, nothing moves; during the run: the run ends, "
              "drives home and prints its summary, *error: the log … cannot be written*", "1"),
    Behaviour("missed_deadlines", "the computer cannot keep the rate (more than 5 % of the deadlines missed)",
              "a late tick drives home; the run fails", "1"),
)


def behaviour_table() -> str:
    """:data:`DEPLOY_BEHAVIOUR` as a Markdown table."""
    rows = ["| when | deploy | exit code |", "|---|---|---|"]
    rows += [f"| {b.when} | {b.then} | {b.exit} |" for b in DEPLOY_BEHAVIOUR]
    return "\n".join(rows)
