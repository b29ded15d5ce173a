"""Physical constants, one home for each (the bottom of the layering, with the errors)."""

from __future__ import annotations

__all__ = ["GRAVITY", "HOLLOW_BALL_ROLLING", "SOLID_BALL_ROLLING"]

#: m/s², standard gravity.
GRAVITY = 9.80665
#: c in a ball's rolling acceleration a = c·g·sin(tilt): 5/7 for a solid ball, 3/5 for a thin-walled hollow one.
SOLID_BALL_ROLLING = 5.0 / 7.0
HOLLOW_BALL_ROLLING = 3.0 / 5.0
