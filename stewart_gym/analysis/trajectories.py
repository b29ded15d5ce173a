"""Pose trajectories: test moves and reference paths, as arrays of poses (n, 6)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from stewart_gym.calibration import ServoCalibration
from stewart_gym.errors import ConfigError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.inputs import DATA_LIMIT, read_text
from stewart_gym.kinematics import axis_ranges, inverse_kinematics

__all__ = ["aggressive_moves", "circle", "load_pose_csv", "trajectory_check"]


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


def circle(radius: float = 0.2, samples: int = 1000, turns: float = 1.0, z: float = 0.0,
           duration_s: float = 40.0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Source 001's circular motion: (t (n,) s, poses (n, 6)), x = r cos φ, y = r sin φ at height z from home."""
    t = np.linspace(0.0, duration_s, samples)
    phi = 2 * math.pi * turns * t / duration_s
    poses = np.zeros((samples, 6))
    poses[:, 0], poses[:, 1], poses[:, 2] = radius * np.cos(phi), radius * np.sin(phi), z
    return t, poses


_UNITS = {"m": 1.0, "mm": 1e-3, "rad": 1.0, "deg": math.pi / 180}


def load_pose_csv(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Read a pose trajectory: (t (n,) s, poses (n, 6) m, rad).

    The header names the columns with units: ``t_s`` (optional; else sample
    index), ``x_m`` or ``x_mm`` (likewise y, z) and ``roll_rad`` or ``roll_deg``
    (likewise pitch, yaw). Missing pose columns are zero, but at least one pose
    column must be there. An unknown column, a non-numeric or non-finite value
    or a time column that goes backwards raises :class:`ConfigError` naming it.
    """
    import csv
    import io

    text = read_text(path, "CSV of poses", DATA_LIMIT)
    try:
        lines = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as exc:
        raise ConfigError(f"{path}: not a valid CSV file ({exc})") from None
    header = [c.strip() for c in lines[0]] if lines else []
    body = [(number, line) for number, line in enumerate(lines[1:], start=2) if line]  # (blank lines skipped)
    if not body:
        raise ConfigError(f"{path}: no rows (expected a header line and one pose per line)")
    known = {"t_s"} | {f"{a}_{u}" for a in ("x", "y", "z") for u in ("m", "mm")} | {
        f"{a}_{u}" for a in ("roll", "pitch", "yaw") for u in ("rad", "deg")}  # fmt: skip
    unknown = [c for c in header if c not in known]
    if unknown:
        raise ConfigError(f"{path}: unknown column(s) {unknown}; use t_s, x_m|x_mm, y_…, z_…, roll_rad|roll_deg, "
                          "pitch_…, yaw_…")  # fmt: skip
    twice = sorted({c for c in header if header.count(c) > 1})
    if twice:
        raise ConfigError(f"{path}: column(s) {twice} given more than once")
    if not set(header) - {"t_s"}:
        raise ConfigError(f"{path}: no pose column (x_mm, y_mm, z_mm, roll_deg, … )")
    for number, line in body:
        if len(line) != len(header):
            raise ConfigError(f"{path}: line {number} has {len(line)} field(s), the header {len(header)}")
    rows = [dict(zip(header, line)) for _, line in body]
    poses = np.zeros((len(rows), 6))

    def column(name: str) -> np.ndarray:
        try:
            values = np.array([float(r[name]) for r in rows])
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{path}: column {name!r}: {exc}") from None
        if not np.all(np.isfinite(values)):
            row = body[int(np.argmin(np.isfinite(values)))][0]
            raise ConfigError(f"{path}: column {name!r} has a non-finite value (line {row})")
        limit = {"deg": 360.0, "rad": 2 * math.pi}.get(name.split("_", 1)[1])
        if limit is not None and np.any(np.abs(values) > limit):
            row = body[int(np.argmax(np.abs(values) > limit))][0]
            raise ConfigError(f"{path}: column {name!r} has an angle beyond a whole turn (line {row})")
        return values

    for k, axis in enumerate(("x", "y", "z", "roll", "pitch", "yaw")):
        cols = [c for c in header if c.split("_")[0] == axis]
        if len(cols) > 1:
            raise ConfigError(f"{path}: more than one column for {axis}: {cols}")
        if cols:
            poses[:, k] = column(cols[0]) * _UNITS[cols[0].split("_", 1)[1]]
    t = column("t_s") if "t_s" in header else np.arange(len(rows), dtype=float)
    if np.any(np.diff(t) < 0):
        raise ConfigError(f"{path}: t_s goes backwards (line {body[int(np.argmax(np.diff(t) < 0)) + 1][0]})")
    return t, poses


def trajectory_check(geometry: PlatformGeometry, t: np.ndarray, poses: np.ndarray,
                     calibration: ServoCalibration | None = None) -> dict[str, Any]:  # fmt: skip
    """Run a trajectory through the IK: actuators and pulses over time against their limits.

    Returns a dict with ``reachable`` (n,), ``actuators`` (n, 6: servo angles rad
    or leg lengths m), ``actuator_limits``, ``pulses_us`` (n, 6; NaN outside the
    channel limits; rotary only), ``first_unreachable`` (index or None) and its
    ``first_unreachable_t`` and ``explanation``.
    """
    ik = inverse_kinematics(geometry, poses)
    out: dict[str, Any] = {"t": np.asarray(t), "poses": poses, "reachable": ik.reachable, "actuators": ik.actuators,
                           "kind": geometry.kind}  # fmt: skip
    if geometry.is_rotary:
        cal = calibration or ServoCalibration.default(geometry)
        out["pulses_us"] = cal.pulse_widths(ik.servo_angles, out_of_range="nan")
        out["pulse_limits_us"] = (cal.min_us, cal.max_us)
        out["actuator_limits"] = geometry.servo_angle_range
    else:
        out["actuator_limits"] = geometry.leg_length_range
    bad = np.flatnonzero(~ik.reachable)
    out["first_unreachable"] = int(bad[0]) if bad.size else None
    out["first_unreachable_t"] = float(t[bad[0]]) if bad.size else None
    out["explanation"] = ik.explain(int(bad[0])) if bad.size else "every sample is reachable"
    out["unreachable_fraction"] = float((~ik.reachable).mean())
    return out
