"""Progress of a long run, for a person watching: a bar on a terminal, otherwise (a log file, a pipe, CI) a line at
least every :data:`LINE_INTERVAL_S` seconds with what is done of the total and the time left.

The library reports progress through a callback (``on_progress(amount)``); the command line makes a
:class:`Progress` and passes its :meth:`Progress.advance`.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["LINE_INTERVAL_S", "Progress", "duration"]

#: Seconds: the longest a run that is not on a terminal stays silent.
LINE_INTERVAL_S = 10.0


def duration(seconds: float) -> str:
    """``0:42``, ``3:05``, ``1:02:03``."""
    s = int(round(max(seconds, 0.0)))
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class Progress:
    """``label``'s progress through ``total`` ``unit`` on ``stream`` (default stderr).

    On a terminal, a tqdm bar where tqdm is installed; otherwise a line such as
    ``evaluate: 40/200 episodes (20 %), 0:12 elapsed, about 0:48 left`` at most every ``interval_s`` seconds
    (the first once that much time has passed, so that a short run prints none). ``close()`` ends the bar; a
    run that stops early says so with :meth:`stopped`.
    """

    def __init__(self, total: float, unit: str, label: str, stream: TextIO | None = None,
                 interval_s: float = LINE_INTERVAL_S, clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        if not (math.isfinite(total) and total > 0):
            raise ValueError(f"total must be a positive number, got {total!r}")
        self.total, self.unit, self.label, self.interval_s, self.clock = total, unit, label, interval_s, clock
        self.stream = sys.stderr if stream is None else stream
        self.done = 0.0
        self.started = self.last_line = clock()
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
        if now - self.last_line >= self.interval_s:
            self.last_line = now
            print(self.line(now), file=self.stream, flush=True)

    def line(self, now: float | None = None) -> str:
        """The progress as one line of text."""
        elapsed = (self.clock() if now is None else now) - self.started
        left = elapsed * (self.total - self.done) / self.done if self.done > 0 else None
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
