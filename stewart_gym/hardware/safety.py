"""The last line of defence between a policy and the servos.

Every tick :meth:`SafetyLayer.filter` turns whatever was requested into pulses
that are (1) inside each channel's calibrated limits, always, and (2) within a
per-channel rate limit of the previous tick's pulses. A request that is missing,
non-finite or flagged unreachable is replaced by the last safe command
("hold"). :meth:`SafetyLayer.toward_home` moves towards the home pulses at the
rate limit (watchdog, shutdown).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stewart_gym.calibration import ServoCalibration

__all__ = ["SafetyLayer", "SafetyResult"]


@dataclass(frozen=True)
class SafetyResult:
    """Pulses to send (6,) µs and what the layer did to get them."""

    pulses: np.ndarray
    held: bool  # the request was unusable: the last safe command was kept
    clamped: bool  # some requested pulse was outside its channel limits
    rate_limited: bool  # some channel was slowed to the rate limit
    homing: bool = False


class SafetyLayer:
    """Per-channel limits and rate limit.

    Args:
        calibration: Channel limits and home (neutral) pulses.
        max_step_us: largest change of any channel in one tick, µs (default
            60 µs: at 50 Hz that is 3,000 µs/s, about 338°/s of horn at the
            default 1600/π µs/rad, just under an MG996R's 353°/s (0.17 s/60°),
            so it stops jumps without slowing a move the servo could make).
    """

    def __init__(self, calibration: ServoCalibration, max_step_us: float = 60.0) -> None:
        if not max_step_us > 0:
            raise ValueError(f"max_step_us must be positive, got {max_step_us}")
        self.calibration = calibration
        self.max_step_us = float(max_step_us)
        self.lo, self.hi = calibration.min_us.copy(), calibration.max_us.copy()
        self.home = np.clip(calibration.neutral_us, self.lo, self.hi)
        self.last = self.home.copy()

    def reset(self, pulses: np.ndarray | None = None) -> None:
        """Assume the servos hold ``pulses`` (default home) now."""
        self.last = self.home.copy() if pulses is None else np.clip(np.asarray(pulses, float), self.lo, self.hi)

    def _limit_rate(self, target: np.ndarray) -> tuple[np.ndarray, bool]:
        step = np.clip(target - self.last, -self.max_step_us, self.max_step_us)
        out = np.clip(self.last + step, self.lo, self.hi)
        return out, bool(np.any(out != target))

    def filter(self, requested: np.ndarray | None, usable: bool = True) -> SafetyResult:
        """Safe pulses for this tick from ``requested`` (6,) µs; ``usable=False`` (e.g. unreachable) holds."""
        req = None if requested is None else np.asarray(requested, dtype=np.float64).reshape(6)
        if req is None or not usable or not np.all(np.isfinite(req)):
            return SafetyResult(self.last.copy(), held=True, clamped=False, rate_limited=False)
        clamped_req = np.clip(req, self.lo, self.hi)
        out, rate_limited = self._limit_rate(clamped_req)
        self.last = out
        return SafetyResult(out.copy(), held=False, clamped=bool(np.any(clamped_req != req)),
                            rate_limited=rate_limited)  # fmt: skip

    def toward_home(self) -> SafetyResult:
        """One rate-limited step towards the home pulses."""
        out, limited = self._limit_rate(self.home)
        self.last = out
        return SafetyResult(out.copy(), held=False, clamped=False, rate_limited=limited, homing=True)

    def at_home(self) -> bool:
        """True when the last command is the home command."""
        return bool(np.allclose(self.last, self.home))
