"""Pose trajectories: test moves and reference paths, as arrays of poses (n, 6)."""

from __future__ import annotations

import math

import numpy as np

from stewart_gym.analysis.workspace import axis_ranges
from stewart_gym.geometry import PlatformGeometry

__all__ = ["aggressive_moves"]


def aggressive_moves(geometry: PlatformGeometry, rate_hz: float = 50.0, *, fraction: float = 0.95,
                     frequency_hz: float = 2.0, hold_s: float = 0.5, sine_s: float = 1.0) -> np.ndarray:  # fmt: skip
    """Full-range steps, then sinusoids, along each pose axis, sampled at ``rate_hz``: (n, 6).

    For each axis: a jump to ``fraction`` of its reach in one direction held
    ``hold_s``, then straight to the other end held ``hold_s``; then for each axis
    a sinusoid of amplitude ``fraction`` of its smaller reach at ``frequency_hz``
    for ``sine_s``. Every pose is reachable.
    """
    reach = axis_ranges(geometry) * fraction
    hold, sine = int(round(hold_s * rate_hz)), int(round(sine_s * rate_hz))
    t = np.arange(sine) / rate_hz
    parts = []
    for k in range(6):
        for end in reach[k]:
            seg = np.zeros((hold, 6))
            seg[:, k] = end
            parts.append(seg)
    for k in range(6):
        seg = np.zeros((sine, 6))
        seg[:, k] = min(-reach[k, 0], reach[k, 1]) * np.sin(2 * math.pi * frequency_hz * t)
        parts.append(seg)
    return np.concatenate(parts)
