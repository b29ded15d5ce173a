"""Progress of a long run, for a person watching: a bar on a terminal, otherwise (a log file, a pipe, CI) a line at
least every :data:`LINE_INTERVAL_S` seconds (or ``$STEWART_GYM_PROGRESS_S``) with what is done of the total and
the time left.

The library reports progress through a callback (``on_progress(amount)``); the command line makes a
:class:`Progress` and passes its :meth:`Progress.advance`.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["INTERVAL_RANGE_S", "INTERVAL_VARIABLE", "LINE_INTERVAL_S", "Progress", "duration", "line_interval_s"]

#: Seconds: the longest a run that is not on a terminal stays silent, unless :data:`INTERVAL_VARIABLE` says otherwise.
LINE_INTERVAL_S = 10.0
#: The environment variable that sets the seconds between progress lines, for a log that wants them more or less
#: often (``STEWART_GYM_PROGRESS_S=60 stewart-gym train … > train.log``).
INTERVAL_VARIABLE = "STEWART_GYM_PROGRESS_S"
#: The range :data:`INTERVAL_VARIABLE` may take (s).
INTERVAL_RANGE_S = (0.1, 86400.0)


def line_interval_s() -> float:
    """The seconds between progress lines: ``$STEWART_GYM_PROGRESS_S`` where it is set, else :data:`LINE_INTERVAL_S`.

    Raises:
        ValueError: the variable is not a number of seconds within :data:`INTERVAL_RANGE_S`.
    """
    text = os.environ.get(INTERVAL_VARIABLE, "").strip()
    if not text:
        return LINE_INTERVAL_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    low, high = INTERVAL_RANGE_S
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{INTERVAL_VARIABLE} must be the seconds between progress lines, a number from {low:g} to "
                          f"{high:g}; got {text!r} (set it to, say, 60, or unset it for {LINE_INTERVAL_S:g})")
    return value


def duration(seconds: float) -> str:
    """``0:42``, ``3:05``, ``1:02:03``."""
    s = int(round(max(seconds, 0.0)))
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class Progress:
    """``label``'s progress through ``total`` ``unit`` on ``stream`` (default stderr).

    On a terminal, a tqdm bar where tqdm is installed; otherwise a line such as
    ``evaluate: 40/200 episodes (20 %), 0:12 elapsed, about 0:48 left`` at most every ``interval_s`` seconds
    (default :func:`line_interval_s`; the first once that much time has passed, so that a short run prints
    none). ``close()`` ends the bar; a run that stops early says so with :meth:`stopped`.

    The time left is estimated at the pace since the first amount came, not since the start: the time to the
    first amount holds the run's start-up (building the envs and the model, compiling the batched kernel), which
    would inflate the estimate many times over. So no line comes before the second amount.
    """

    def __init__(self, total: float, unit: str, label: str, stream: TextIO | None = None,
                 interval_s: float | None = None, clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        if not (math.isfinite(total) and total > 0):
            raise ValueError(f"total must be a positive number, got {total!r}")
        self.total, self.unit, self.label, self.clock = total, unit, label, clock
        self.interval_s = line_interval_s() if interval_s is None else interval_s
        self.stream = sys.stderr if stream is None else stream
        self.done = 0.0
        self.started = self.last_line = clock()
        self.first: tuple[float, float] | None = None  # when the first amount came, and the amount done then
        self.bar = None
        if getattr(self.stream, "isatty", lambda: False)():
            try:
                from tqdm import tqdm
            except ImportError:
                pass
            else:
                self.bar = tqdm(total=total, unit=f" {unit}", desc=label, file=self.stream, leave=False)

    def advance(self, amount: float = 1.0) -> None:
        self.done = min(self.done + amount, self.total)
        if self.bar is not None:
            self.bar.update(amount)
            return
        now = self.clock()
        if self.first is None:  # the end of the start-up: the pace is measured from here
            self.first = (now, self.done)
            return
        if now - self.last_line >= self.interval_s:
            self.last_line = now
            print(self.line(now), file=self.stream, flush=True)

    def line(self, now: float | None = None) -> str:
        """The progress as one line of text."""
        now = self.clock() if now is None else now
        left = None
        if self.first is not None and self.done > self.first[1]:
            since, done_then = self.first
            left = (now - since) * (self.total - self.done) / (self.done - done_then)
        elapsed = now - self.started
        count = f"{math.floor(self.done):,}/{self.total:,.0f}"  # whole units done (an episode counts once finished)
        return (f"{self.label}: {count} {self.unit} ({100 * self.done / self.total:.0f} %), {duration(elapsed)} "
                f"elapsed" + (f", about {duration(left)} left" if left is not None else ""))

    def stopped(self, why: str) -> None:
        """Say that the run ends before its total, and why (one line)."""
        self.close()
        print(f"{self.label}: stopped at {math.floor(self.done):,}/{self.total:,.0f} {self.unit}: {why}",
              file=self.stream, flush=True)  # fmt: skip

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
