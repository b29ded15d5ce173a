"""Workspace of a platform: how far it reaches from home."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stewart_gym.checks import finite_array, real_number
from stewart_gym.errors import ConfigError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import axis_ranges, inverse_kinematics

__all__ = ["HeightMap", "height_map", "reachable_volume"]


@dataclass(frozen=True)
class HeightMap:
    """Largest and smallest reachable z over an x–y grid at a fixed orientation (source 002's contour chart).

    Attributes:
        x, y: (nx,), (ny,) m, grid coordinates (translation from home).
        z_levels: (nz,) m, the heights tried.
        z_max, z_min: (ny, nx) m, highest / lowest reachable level; NaN where no level is reachable.
    """

    x: np.ndarray
    y: np.ndarray
    z_levels: np.ndarray
    z_max: np.ndarray
    z_min: np.ndarray


#: The most poses :func:`height_map`'s first scan may solve at once (about 15 s and a few GB of memory).
MAX_SCAN_POSES = 20_000_000


def scan_poses(cells: int, levels: int, stride: int = 16) -> int:
    """How many poses :func:`height_map` solves at once in its first scan of ``cells`` (x, y) points over
    ``levels`` heights (every ``stride``-th one, and the last)."""
    return cells * (len(range(0, levels, stride)) + 1)


def height_map(geometry: PlatformGeometry, orientation: tuple[float, float, float] = (0.0, 0.0, 0.0),
               pivot: np.ndarray | None = None, *, x: np.ndarray, y: np.ndarray, z_levels: np.ndarray,
               stride: int = 16) -> HeightMap:  # fmt: skip
    """Highest and lowest reachable level of ``z_levels`` at each (x, y), like source 002's Check(x, y).

    Vectorised over the whole grid: the levels are scanned every ``stride``-th
    one, then the boundary between the last reachable and the next scanned
    level is found by bisection on the level index. That equals a full scan when
    the reachable heights at each (x, y) form one interval (true for these
    mechanisms); columns where no scanned level is reachable are scanned fully.
    """
    x, y, levels = (finite_array(name, v, (None,)) for name, v in (("x", x), ("y", y), ("z_levels", z_levels)))
    if not np.all(np.diff(levels) > 0):
        raise ConfigError("z_levels must rise from the lowest to the highest level (the bisection relies on it)")
    orientation = finite_array("orientation", orientation, (3,))
    stride = real_number("stride", stride, whole=True, low=1)
    gx, gy = np.meshgrid(x, y)
    cells = gx.size
    nz = len(levels)

    def ok(idx: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Reachable at level index ``idx`` for grid cells ``rows`` (both (m,))."""
        poses = np.zeros((len(rows), 6))
        poses[:, 0], poses[:, 1], poses[:, 2] = gx.ravel()[rows], gy.ravel()[rows], levels[idx]
        poses[:, 3:] = orientation
        return inverse_kinematics(geometry, poses, pivot).reachable

    coarse = np.unique(np.r_[np.arange(0, nz, stride), nz - 1])
    poses = np.zeros((cells, len(coarse), 6))
    poses[..., 0], poses[..., 1] = gx.ravel()[:, None], gy.ravel()[:, None]
    poses[..., 2] = levels[coarse]
    poses[..., 3:] = orientation
    reach = inverse_kinematics(geometry, poses, pivot).reachable  # (cells, ncoarse)
    any_ok = reach.any(axis=1)
    out_max = np.full(cells, -1)
    out_min = np.full(cells, -1)
    rows = np.flatnonzero(any_ok)
    for out, pick, step in ((out_max, np.max, 1), (out_min, np.min, -1)):
        # last reachable coarse index (or first, for the minimum), then bisection towards the next scanned level
        ci = np.array([pick(np.flatnonzero(r)) for r in reach[rows]], dtype=int)
        lo = coarse[ci]
        nxt = np.clip(ci + step, 0, len(coarse) - 1)
        hi = np.where(nxt == ci, lo, coarse[nxt])
        # invariant: lo reachable; hi unreachable unless hi == lo
        while True:
            gap = np.abs(hi - lo) > 1
            if not gap.any():
                break
            mid = (lo + hi) // 2 if step == 1 else -((-lo - hi) // 2)
            good = ok(mid[gap], rows[gap])
            sel = np.flatnonzero(gap)
            lo[sel[good]] = mid[gap][good]
            hi[sel[~good]] = mid[gap][~good]
        last = np.where((hi != lo) & ok(hi, rows), hi, lo)  # the neighbour itself may be reachable
        out[rows] = last
    rest = np.flatnonzero(~any_ok)
    if rest.size:  # no scanned level reachable: scan every level for these cells
        full = np.zeros((rest.size, nz, 6))
        full[..., 0], full[..., 1] = gx.ravel()[rest][:, None], gy.ravel()[rest][:, None]
        full[..., 2], full[..., 3:] = levels, orientation
        r = inverse_kinematics(geometry, full, pivot).reachable
        has = r.any(axis=1)
        out_max[rest[has]] = [np.flatnonzero(v).max() for v in r[has]]
        out_min[rest[has]] = [np.flatnonzero(v).min() for v in r[has]]
    z_max = np.where(out_max >= 0, levels[np.maximum(out_max, 0)], np.nan).reshape(gx.shape)
    z_min = np.where(out_min >= 0, levels[np.maximum(out_min, 0)], np.nan).reshape(gx.shape)
    return HeightMap(x, y, levels, z_max, z_min)


def reachable_volume(geometry: PlatformGeometry, samples: int = 200_000, seed: int = 0,
                     pivot: np.ndarray | None = None) -> dict[str, float]:  # fmt: skip
    """Monte Carlo estimates of the workspace.

    * 6-DoF: poses drawn uniformly in the box spanned by :func:`axis_ranges`;
      the reachable fraction times the box volume (m³·rad³).
    * translational workspace at home orientation: positions drawn in the
      translation box; reachable fraction times its volume (m³).
    Both with the standard error of the fraction.
    """
    samples = real_number("samples", samples, whole=True, low=1)
    rng = np.random.default_rng(seed)
    reach = axis_ranges(geometry, pivot)
    lo, hi = reach[:, 0], reach[:, 1]
    poses = lo + (hi - lo) * rng.uniform(0, 1, (samples, 6))
    f6 = float(inverse_kinematics(geometry, poses, pivot).reachable.mean())
    trans = poses.copy()
    trans[:, 3:] = 0.0
    f3 = float(inverse_kinematics(geometry, trans, pivot).reachable.mean())
    box6 = float(np.prod(hi - lo))
    box3 = float(np.prod(hi[:3] - lo[:3]))
    se = lambda f: math.sqrt(f * (1 - f) / samples)  # noqa: E731
    return {
        "samples": samples,
        "fraction_6dof": f6,
        "fraction_6dof_se": se(f6),
        "volume_6dof_m3_rad3": f6 * box6,
        "fraction_translation": f3,
        "fraction_translation_se": se(f3),
        "volume_translation_m3": f3 * box3,
        "volume_translation_cm3": f3 * box3 * 1e6,
    }
