"""Workspace of a platform: how far it reaches from home."""

from __future__ import annotations

import math

import numpy as np

from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import inverse_kinematics

__all__ = ["axis_ranges"]


def axis_ranges(geometry: PlatformGeometry, pivot: np.ndarray | None = None, *, samples: int = 4001,
                tol: float = 1e-9) -> np.ndarray:  # fmt: skip
    """Reach along each pose axis from home, the others held at 0: array (6, 2) of [low, high].

    Rows are x, y, z (m) and roll, pitch, yaw (rad). Each of the 12 rays is
    sampled on ``samples`` points up to ``home_height`` (translations) or π/2
    (angles); the first unreachable sample is then bracketed and bisected to
    ``tol`` (relative to the search bound), all rays at once.
    """
    bound = np.array([geometry.home_height] * 3 + [math.pi / 2] * 3)
    signs = np.array([-1.0, 1.0])
    # rays[k, d]: unit pose of axis k in direction d, scaled by its bound
    rays = np.zeros((6, 2, 6))
    for k in range(6):
        rays[k, :, k] = signs * bound[k]
    frac = np.linspace(0.0, 1.0, samples)
    reach = inverse_kinematics(geometry, rays[:, :, None, :] * frac[:, None], pivot).reachable  # (6, 2, n)
    if not reach[..., 0].all():
        raise ValueError(f"home is not reachable for geometry {geometry.name!r}")
    first_bad = np.where(reach.all(axis=-1), samples, np.argmin(reach, axis=-1))  # (6, 2)
    lo = frac[first_bad - 1]
    hi = np.where(first_bad < samples, frac[np.minimum(first_bad, samples - 1)], 1.0)
    open_ = first_bad < samples
    while np.any(open_ & (hi - lo > tol)):
        mid = (lo + hi) / 2
        ok = inverse_kinematics(geometry, rays * mid[..., None], pivot).reachable
        lo = np.where(open_ & ok, mid, lo)
        hi = np.where(open_ & ~ok, mid, hi)
    return lo * bound[:, None] * signs
