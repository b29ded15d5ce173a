"""Batched inverse and forward kinematics of a Stewart platform (source 000).

Conventions (the docs: Conventions and presets):

* A pose is ``(x, y, z, roll, pitch, yaw)`` in metres and radians, shape (..., 6).
  The translation is measured from home ``(0, 0, h0)``.
* ``R = Rz(yaw) · Ry(pitch) · Rx(roll)`` (eq. 1).
* With a ``pivot`` c (3,), the point of the platform frame about which the
  platform turns (source 002's point of interest), platform anchor i sits at
  ``q_i = (0, 0, h0) + (x, y, z) + c + R · (p_i − c)`` in the base frame, and the
  leg vector is ``l_i = q_i − b_i`` (eq. 3). ``pivot=None`` means c = 0.
* Servo angle α_i (eq. 9, in its one consistent form, see the docs: Sources):
  ``α = asin(L / sqrt(M² + N²)) − atan2(N, M)`` with ``L = |l|² − (s² − a²)``,
  ``M = 2a (z_q − z_b)``, ``N = 2a [cos β (x_q − x_b) + sin β (y_q − y_b)]``.
  α is the horn's elevation above the horizontal; its tip is
  ``b + a (cos α cos β, cos α sin β, sin α)``.

Everything is vectorised over the leading dimensions: no per-pose Python loop.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Literal

import numpy as np

from stewart_gym.blas import OneBlasThread
from stewart_gym.checks import real_number
from stewart_gym.compiled import compiled
from stewart_gym.geometry import GeometryError, PlatformGeometry

__all__ = [
    "FKResult",
    "IKResult",
    "LegStatus",
    "actuator_jacobian",
    "euler_from_matrix",
    "forward_kinematics",
    "horn_tips",
    "inverse_kinematics",
    "rotation_matrix",
    "axis_ranges",
    "pulses_many",
    "pulses_one",
    "rotation_matrix_derivatives",
]

#: Poses are processed in blocks of this many, so temporaries stay in cache.
_CHUNK = 8192
#: From this many poses a batch's (3n × 7)·(7 × 6) product is large enough for OpenBLAS to split over threads.
#: A product this small gains nothing from them, and on a busy machine (the other cores taken) the threads
#: wait for each other: 3.5× slower under two busy processes. So the batch runs with one BLAS thread, which
#: computes every element alike (the same results to the last bit).
_ONE_THREAD_FROM = 512


class LegStatus(IntEnum):
    """Why a leg can or cannot reach its platform anchor."""

    OK = 0
    #: Rotary only: |L| > sqrt(M² + N²), no horn angle puts the rod end on the anchor.
    NO_SOLUTION = 1
    #: The servo angle or leg length is below its lower limit.
    BELOW_LIMIT = 2
    #: The servo angle or leg length is above its upper limit.
    ABOVE_LIMIT = 3
    #: The pose is not finite (NaN or infinite), or so large that the leg cannot be computed.
    NOT_FINITE = 4
    #: Linear only: the platform anchor is not above its base anchor (the mirrored assembly through the base).
    BELOW_BASE = 5


_STATUS_TEXT = {
    LegStatus.NO_SOLUTION: "no horn angle reaches the anchor (|L| > sqrt(M²+N²): rod too short or too long for the pose)",
    LegStatus.BELOW_LIMIT: "below the lower actuator limit",
    LegStatus.ABOVE_LIMIT: "above the upper actuator limit",
    LegStatus.NOT_FINITE: "the pose is not finite (NaN or infinite) or too large to compute",
    LegStatus.BELOW_BASE: "the platform anchor is not above its base anchor (the platform would pass through the base)",
}


def rotation_matrix(roll: np.ndarray | float, pitch: np.ndarray | float, yaw: np.ndarray | float) -> np.ndarray:
    """Rz(yaw)·Ry(pitch)·Rx(roll) (eq. 1), shape (..., 3, 3); inputs in rad broadcast."""
    r, p, y = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (roll, pitch, yaw)))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    out = np.empty(r.shape + (3, 3))
    out[..., 0, 0] = cy * cp
    out[..., 0, 1] = cy * sp * sr - sy * cr
    out[..., 0, 2] = cy * sp * cr + sy * sr
    out[..., 1, 0] = sy * cp
    out[..., 1, 1] = sy * sp * sr + cy * cr
    out[..., 1, 2] = sy * sp * cr - cy * sr
    out[..., 2, 0] = -sp
    out[..., 2, 1] = cp * sr
    out[..., 2, 2] = cp * cr
    return out


def euler_from_matrix(rot: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad of a rotation matrix R = Rz(yaw)·Ry(pitch)·Rx(roll), pitch in [−π/2, π/2]. Raises
    ``ValueError`` for anything but a finite 3 × 3 rotation (orthonormal to 1e-6, determinant +1)."""
    rows = np.asarray(rot, dtype=np.float64)
    if rows.shape != (3, 3):
        raise ValueError(f"rot must be one 3 × 3 rotation matrix, got shape {rows.shape}")
    (a, b, c), (d, e, f), (g, h, i) = rows.tolist()  # in scalars: each simulator step reads its plate pose here
    rr = (a * a + b * b + c * c, d * d + e * e + f * f, g * g + h * h + i * i, a * d + b * e + c * f,
          a * g + b * h + c * i, d * g + e * h + f * i)  # R·Rᵀ  # fmt: skip
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if not (all(abs(v - 1.0) <= 1e-6 for v in rr[:3]) and all(abs(v) <= 1e-6 for v in rr[3:]) and det > 0):
        raise ValueError("rot is not a finite rotation matrix (R·Rᵀ = I to 1e-6, det R = +1)")
    return math.atan2(h, i), -math.asin(max(-1.0, min(1.0, g))), math.atan2(d, a)


def rotation_matrix_derivatives(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """∂R/∂(roll, pitch, yaw), shape (..., 3, 3, 3): index [..., k, row, col] for angle k."""
    r, p, y = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (roll, pitch, yaw)))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    zero = np.zeros_like(r)
    d = np.empty(r.shape + (3, 3, 3))
    # d/droll
    d[..., 0, 0, :] = np.stack([zero, cy * sp * cr + sy * sr, -cy * sp * sr + sy * cr], -1)
    d[..., 0, 1, :] = np.stack([zero, sy * sp * cr - cy * sr, -sy * sp * sr - cy * cr], -1)
    d[..., 0, 2, :] = np.stack([zero, cp * cr, -cp * sr], -1)
    # d/dpitch
    d[..., 1, 0, :] = np.stack([-cy * sp, cy * cp * sr, cy * cp * cr], -1)
    d[..., 1, 1, :] = np.stack([-sy * sp, sy * cp * sr, sy * cp * cr], -1)
    d[..., 1, 2, :] = np.stack([-cp, -sp * sr, -sp * cr], -1)
    # d/dyaw
    d[..., 2, 0, :] = np.stack([-sy * cp, -sy * sp * sr - cy * cr, -sy * sp * cr + cy * sr], -1)
    d[..., 2, 1, :] = np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1)
    d[..., 2, 2, :] = 0.0
    return d


# --------------------------------------------------------------------------- IK
@dataclass(frozen=True)
class IKResult:
    """Inverse kinematics of a batch of poses; shapes follow ``pose.shape[:-1]`` (written ...).

    Attributes:
        pose: (..., 6) the poses asked for (m, rad).
        leg_vectors: (..., 6, 3) m, l_i = q_i − b_i in the base frame.
        leg_lengths: (..., 6) m, |l_i|.
        servo_angles: (..., 6) rad, α_i (eq. 9); NaN where unsolvable. ``None``
            for a linear platform.
        status: (..., 6) :class:`LegStatus` codes, per leg.
        reachable: (...,) bool, every leg ``OK``.
    """

    pose: np.ndarray
    leg_vectors: np.ndarray
    leg_lengths: np.ndarray
    servo_angles: np.ndarray | None
    status: np.ndarray
    reachable: np.ndarray

    @property
    def actuators(self) -> np.ndarray:
        """(..., 6): servo angles (rad) for a rotary platform, leg lengths (m) for a linear one."""
        return self.servo_angles if self.servo_angles is not None else self.leg_lengths

    def explain(self, index: tuple[int, ...] | int = ()) -> str:
        """Human-readable reachability of the pose at ``index`` (a batch index)."""
        status = self.status[index]
        if status.ndim != 1:
            raise IndexError(f"index {index!r} does not select one pose of batch shape {self.reachable.shape}")
        pose = self.pose[index]
        mm = [_num(v * 1e3) for v in pose[:3]]
        deg = [_num(math.degrees(v)) if math.isfinite(v) else _num(v) for v in pose[3:]]
        head = (f"pose x={mm[0]} mm y={mm[1]} mm z={mm[2]} mm "
                f"roll={deg[0]}° pitch={deg[1]}° yaw={deg[2]}°")  # fmt: skip
        bad = [i for i in range(6) if status[i] != LegStatus.OK]
        if not bad:
            return head + ": reachable"
        acts = self.actuators[index]
        unit = "°" if self.servo_angles is not None else " mm"
        scale = 180.0 / math.pi if self.servo_angles is not None else 1e3
        parts = []
        for code in dict.fromkeys(LegStatus(int(status[i])) for i in bad):  # each reason once, legs in order
            legs = [i for i in bad if status[i] == code]
            names = f"leg {legs[0]}" if len(legs) == 1 else "legs " + ", ".join(map(str, legs))
            values = [acts[i] * scale for i in legs]
            shown = f" ({', '.join(f'{v:.3f}{unit}' for v in values)})" if all(map(math.isfinite, values)) else ""
            parts.append(f"{names}: {_STATUS_TEXT[code]}{shown}")
        return head + ": unreachable; " + "; ".join(parts)


def _num(v: float) -> str:
    """Two decimals, or three significant digits for values too large to print that way."""
    return f"{v:.2f}" if abs(v) < 1e9 or not math.isfinite(v) else f"{v:.3g}"


def _pivot(pivot: np.ndarray | None) -> np.ndarray:
    if pivot is None:
        return np.zeros(3)
    c = np.asarray(pivot, dtype=np.float64)
    if c.shape != (3,):
        raise ValueError(f"pivot must have shape (3,), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"pivot must be finite, got {c.tolist()}")
    return c


def _as_pose(pose: np.ndarray) -> np.ndarray:
    if np.iscomplexobj(pose):
        raise ValueError("pose must be real numbers, got complex ones")
    pose = np.asarray(pose, dtype=np.float64)
    if pose.ndim == 0 or pose.shape[-1] != 6:
        raise ValueError(f"pose must have shape (..., 6) = (x, y, z, roll, pitch, yaw), got {pose.shape}")
    return pose


@dataclass(frozen=True)
class _IKConstants:
    """Per-(geometry, pivot) constants of the IK hot path."""

    rhs: np.ndarray  # (7, 6): rows (p_i − c)ᵀ, ones, ((0, 0, h0) + c − b_i)ᵀ
    legs: tuple[tuple[float, ...], ...]  # per leg (p − c, (0, 0, h0) + c − b, cos β, sin β) as Python floats
    cos_beta: np.ndarray  # (6,), ones for a linear platform
    sin_beta: np.ndarray  # (6,)
    half_l0: float  # (s² − a²) / (2a)
    inv_2a: float  # 1 / (2a)
    lo: float  # actuator limits
    hi: float
    rotary: bool


_CONSTANTS: dict[tuple[int, bytes], tuple[PlatformGeometry, _IKConstants]] = {}
_NO_PIVOT = np.zeros(3)
_NO_PIVOT_KEY = _NO_PIVOT.tobytes()
_NO_SOLUTION, _BELOW, _ABOVE = int(LegStatus.NO_SOLUTION), int(LegStatus.BELOW_LIMIT), int(LegStatus.ABOVE_LIMIT)
_NOT_FINITE, _BELOW_BASE = int(LegStatus.NOT_FINITE), int(LegStatus.BELOW_BASE)
#: Squared leg lengths (m²) at or above this are treated as not computable (a NaN compares False with it too).
_HUGE = 1e200


def _geometry(geometry: object) -> PlatformGeometry:
    if not isinstance(geometry, PlatformGeometry):
        raise TypeError(f"geometry must be a PlatformGeometry (stewart_gym.presets.load_geometry gives one from a "
                        f"preset's name or a file), got {type(geometry).__name__}")  # fmt: skip
    return geometry


def _constants(geo: PlatformGeometry, c: np.ndarray) -> _IKConstants:
    key = (id(geo), c.tobytes())  # pulses_one looks up (id, _NO_PIVOT_KEY) directly
    hit = _CONSTANTS.get(key)
    if hit is not None and hit[0] is geo:
        return hit[1]
    _geometry(geo)
    rotary = geo.is_rotary
    a = geo.horn_length or 1.0
    beta = geo.servo_beta if rotary else np.zeros(6)
    lo, hi = geo.servo_angle_range if rotary else geo.leg_length_range  # type: ignore[misc]
    rhs = np.vstack([(geo.platform_anchors - c).T, np.ones((1, 6)), (geo.home_position + c)[:, None] - geo.base_anchors.T])
    consts = _IKConstants(
        rhs=rhs,
        legs=tuple(tuple(float(v) for v in leg) for leg in np.vstack([rhs[:3], rhs[4:], np.cos(beta), np.sin(beta)]).T),
        cos_beta=np.cos(beta),  # type: ignore[arg-type]
        sin_beta=np.sin(beta),  # type: ignore[arg-type]
        half_l0=(geo.rod_length**2 - a * a) / (2 * a),
        inv_2a=1.0 / (2 * a),
        lo=float(lo),
        hi=float(hi),
        rotary=rotary,
    )
    if len(_CONSTANTS) > 64:
        _CONSTANTS.clear()
    _CONSTANTS[key] = (geo, consts)
    return consts


def _ik_block(k: _IKConstants, poses: np.ndarray, aug: np.ndarray, legs: np.ndarray, lengths: np.ndarray,
              alpha: np.ndarray | None) -> None:  # fmt: skip
    """IK of a (n, 6) block of poses into ``legs`` (n, 3, 6), ``lengths`` and ``alpha`` (n, 6).

    ``aug`` (≥n, 3, 7) is scratch whose last three columns hold the identity.
    Row c of leg i is ``[R | t | e_c] · rhs``: rotation, translation and the
    constant offsets in one BLAS call.

    The servo angle uses eq. 9 rewritten with one atan2: with L, M, N divided by
    2a and ρ² = M² + N², ``asin(L/ρ) − atan2(N, M) = atan2(L·M − r·N, r·M + L·N)``
    where ``r = sqrt(ρ² − L²)`` (ρ times the cosine of the asin term). It is the
    same angle, wrapped to [−π, π], and NaN where |L| > ρ.
    """
    n = poses.shape[0]
    aug = aug[:n]
    roll, pitch, yaw = poses[:, 3], poses[:, 4], poses[:, 5]
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    cy_sp, sy_sp = cy * sp, sy * sp
    aug[:, 0, 0] = cy * cp
    aug[:, 0, 1] = cy_sp * sr - sy * cr
    aug[:, 0, 2] = cy_sp * cr + sy * sr
    aug[:, 1, 0] = sy * cp
    aug[:, 1, 1] = sy_sp * sr + cy * cr
    aug[:, 1, 2] = sy_sp * cr - cy * sr
    aug[:, 2, 0] = -sp
    aug[:, 2, 1] = cp * sr
    aug[:, 2, 2] = cp * cr
    aug[:, :, 3] = poses[:, :3]
    np.matmul(aug.reshape(n * 3, 7), k.rhs, out=legs.reshape(n * 3, 6))
    lx, ly, lz = legs[:, 0], legs[:, 1], legs[:, 2]
    sq = lx * lx
    sq += ly * ly
    sq += lz * lz
    np.sqrt(sq, out=lengths)
    if alpha is None:
        return
    # L/(2a) = (|l|² − (s² − a²)) / (2a);  M/(2a) = l_z;  N/(2a) = cos β l_x + sin β l_y
    big_l = sq
    big_l *= k.inv_2a
    big_l -= k.half_l0
    big_n = lx * k.cos_beta
    big_n += ly * k.sin_beta
    root = lz * lz
    root += big_n * big_n
    root -= big_l * big_l
    np.sqrt(root, out=root)
    num = big_l * lz
    num -= root * big_n
    root *= lz
    big_l *= big_n
    root += big_l
    # atan2(num, den) as arctan(num / den), half the cost; fix the quadrant where den < 0.
    np.divide(num, root, out=alpha)
    np.arctan(alpha, out=alpha)
    back = root < 0.0
    if back.any():
        alpha[back] += np.copysign(np.pi, num[back])


def _ik_scalar(k: _IKConstants, pose: Sequence[float],
               pulse_map: Sequence[tuple[float, ...]] | None = None) -> list | None:  # fmt: skip
    """The arithmetic of :func:`_ik_block` for one pose in scalar ``math``.

    Without ``pulse_map``: one row per leg, (l_x, l_y, l_z, |l|, actuator,
    status), where ``actuator`` is the servo angle (rad; NaN without a
    solution) of a rotary platform or the leg length (m) of a linear one.

    With ``pulse_map`` (per servo: neutral µs, signed µs/rad, home angle rad,
    min µs, max µs; eqs 13/14): the six pulse widths (µs), or None as soon as a
    leg has no solution, leaves the servo angle range or its pulse leaves the
    channel's limits. One pass, no arrays: the control-loop path.
    """
    x, y, z, roll, pitch, yaw = pose
    try:
        cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
        cy, sy = math.cos(yaw), math.sin(yaw)
    except ValueError:  # an infinite angle (math.cos raises; NaN flows through and is caught below)
        cr = sr = cp = sp = cy = sy = math.nan
    cy_sp, sy_sp = cy * sp, sy * sp
    r00, r01, r02 = cy * cp, cy_sp * sr - sy * cr, cy_sp * cr + sy * sr
    r10, r11, r12 = sy * cp, sy_sp * sr + cy * cr, sy_sp * cr - cy * sr
    r20, r21, r22 = -sp, cp * sr, cp * cr
    out: list = []
    lo, hi, inv_2a, half_l0, rotary = k.lo, k.hi, k.inv_2a, k.half_l0, k.rotary
    sqrt, atan2, below, above = math.sqrt, math.atan2, _BELOW, _ABOVE  # locals: this loop is the control-loop hot path
    for (px, py, pz, ox, oy, oz, cb, sb), pulse in zip(k.legs, pulse_map or _NO_PULSE_MAP):
        lx = r00 * px + r01 * py + r02 * pz + x + ox
        ly = r10 * px + r11 * py + r12 * pz + y + oy
        lz = r20 * px + r21 * py + r22 * pz + z + oz
        sq = lx * lx + ly * ly + lz * lz
        if not sq < _HUGE:  # NaN, infinite or absurd pose: never "reachable"
            if pulse is not None:
                return None
            out.append((lx, ly, lz, sqrt(sq) if sq == sq else math.nan, math.nan, _NOT_FINITE))
            continue
        if rotary:
            big_l = sq * inv_2a - half_l0
            big_n = lx * cb + ly * sb
            root2 = lz * lz + big_n * big_n - big_l * big_l
            if root2 < 0.0:
                if pulse is not None:
                    return None
                out.append((lx, ly, lz, sqrt(sq), math.nan, _NO_SOLUTION))
                continue
            root = sqrt(root2)
            value = atan2(big_l * lz - root * big_n, root * lz + big_l * big_n)
            status = 0 if lo <= value <= hi else below if value < lo else above
        else:
            value = sqrt(sq)
            status = _BELOW_BASE if lz <= 0.0 else 0 if lo <= value <= hi else below if value < lo else above
        if pulse is None:
            out.append((lx, ly, lz, sqrt(sq), value, status))
            continue
        neutral, gain, home, low, high = pulse
        width = neutral + gain * (value - home)
        if status or not low <= width <= high:
            return None
        out.append(width)
    return out


_NO_PULSE_MAP = (None,) * 6


def _ik_one(k: _IKConstants, pose: np.ndarray) -> IKResult:
    """:func:`inverse_kinematics` of a single pose (6,) through :func:`_ik_scalar` (low latency)."""
    table = np.array(_ik_scalar(k, pose.tolist()))
    status = table[:, 5].astype(np.uint8)
    return IKResult(
        pose=pose,
        leg_vectors=table[:, :3],
        leg_lengths=table[:, 3],
        servo_angles=table[:, 4] if k.rotary else None,
        status=status,
        reachable=np.bool_(not status.any()),
    )


def pulses_one(geometry: PlatformGeometry, pose: Sequence[float],
               pulse_map: Sequence[tuple[float, float, float, float, float]]) -> list[float] | None:  # fmt: skip
    """The IK of one pose mapped straight to pulse widths (6 Python floats, µs), or None.

    ``pulse_map`` gives per servo (neutral µs, signed µs/rad, home angle rad,
    min µs, max µs): ``w = neutral + gain · (α − home)`` (eqs 13/14). None as
    soon as a leg has no solution, leaves the servo angle range or its pulse
    leaves ``[min, max]``. One scalar pass, no arrays (~6 µs): the control-loop
    path; :func:`stewart_gym.calibration.servo_pulses_one` is its user. For a
    linear platform the actuator value is the leg length (m) instead of α.
    """
    if len(pose) != 6 or len(pulse_map) != 6:
        raise ValueError(f"pose and pulse_map must have 6 entries each, got {len(pose)} and {len(pulse_map)}")
    hit = _CONSTANTS.get((id(geometry), _NO_PIVOT_KEY))
    k = hit[1] if hit is not None and hit[0] is geometry else _constants(geometry, _NO_PIVOT)
    return _ik_scalar(k, pose, pulse_map)


def _pulses_rows(poses: np.ndarray, legs: np.ndarray, pulse_map: np.ndarray, lo: float, hi: float, inv_2a: float,
                 half_l0: float, rotary: bool, out: np.ndarray, ok: np.ndarray) -> None:  # fmt: skip  # pragma: no cover
    """:func:`_ik_scalar` with a pulse map, row by row (compiled): the pulses of pose ``poses[i]`` into ``out[i]``
    and ``ok[i]`` True, or ``ok[i]`` False where :func:`_ik_scalar` gives None. ``legs`` (6, 8) and ``pulse_map``
    (6, 5): :class:`_IKConstants`' legs and the pulse map as arrays. The same operations in the same order (math's
    cos, sin and atan2 are the C library's, as Python's), so the same bits."""
    for i in range(poses.shape[0]):
        x, y, z, roll, pitch, yaw = poses[i, 0], poses[i, 1], poses[i, 2], poses[i, 3], poses[i, 4], poses[i, 5]
        cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
        if yaw == 0.0:  # (a tilt: cos ±0 is 1 and sin ±0 is ±0, exactly, as the C library gives them)
            cy, sy = 1.0, yaw
        else:
            cy, sy = math.cos(yaw), math.sin(yaw)
        cy_sp, sy_sp = cy * sp, sy * sp
        r00, r01, r02 = cy * cp, cy_sp * sr - sy * cr, cy_sp * cr + sy * sr
        r10, r11, r12 = sy * cp, sy_sp * sr + cy * cr, sy_sp * cr - cy * sr
        r20, r21, r22 = -sp, cp * sr, cp * cr
        ok[i] = True
        for j in range(6):
            px, py, pz, ox, oy, oz, cb, sb = (legs[j, 0], legs[j, 1], legs[j, 2], legs[j, 3], legs[j, 4], legs[j, 5],
                                              legs[j, 6], legs[j, 7])  # fmt: skip
            lx = r00 * px + r01 * py + r02 * pz + x + ox
            ly = r10 * px + r11 * py + r12 * pz + y + oy
            lz = r20 * px + r21 * py + r22 * pz + z + oz
            sq = lx * lx + ly * ly + lz * lz
            if not sq < _HUGE:
                ok[i] = False
                break
            if rotary:
                big_l = sq * inv_2a - half_l0
                big_n = lx * cb + ly * sb
                root2 = lz * lz + big_n * big_n - big_l * big_l
                if root2 < 0.0:
                    ok[i] = False
                    break
                root = math.sqrt(root2)
                value = math.atan2(big_l * lz - root * big_n, root * lz + big_l * big_n)
                inside = lo <= value <= hi
            else:
                value = math.sqrt(sq)
                inside = lz > 0.0 and lo <= value <= hi
            width = pulse_map[j, 0] + pulse_map[j, 1] * (value - pulse_map[j, 2])
            if not (inside and pulse_map[j, 3] <= width <= pulse_map[j, 4]):
                ok[i] = False
                break
            out[i, j] = width


_pulses_compiled = compiled(_pulses_rows)


def pulses_many(geometry: PlatformGeometry, poses: np.ndarray,
                pulse_map: Sequence[tuple[float, float, float, float, float]]) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`pulses_one` of each pose (n, 6) in one compiled pass: the pulses (n, 6) µs and whether each pose has
    them (n,) (where not, its row of pulses is undefined); None without numba. The same numbers to the last bit
    where numba's cos, sin and atan2 are the C library's that Python's ``math`` calls (as
    :func:`~stewart_gym.compiled.exp_each` assumes of exp)."""
    if _pulses_compiled is None:  # pragma: no cover - the dev install has numba
        return None
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 6:
        raise ValueError(f"poses must have shape (n, 6), got {poses.shape}")
    table = np.array(pulse_map, dtype=np.float64)
    if table.shape != (6, 5):  # (the compiled loop reads it unchecked)
        raise ValueError(f"pulse_map must be 6 rows of 5 numbers, got shape {table.shape}")
    hit = _CONSTANTS.get((id(geometry), _NO_PIVOT_KEY))
    k = hit[1] if hit is not None and hit[0] is geometry else _constants(geometry, _NO_PIVOT)
    out, ok = np.empty((len(poses), 6)), np.empty(len(poses), dtype=np.bool_)
    _pulses_compiled(poses, np.array(k.legs), table, k.lo, k.hi, k.inv_2a, k.half_l0, k.rotary, out, ok)
    return out, ok


def inverse_kinematics(geometry: PlatformGeometry, pose: np.ndarray, pivot: np.ndarray | None = None) -> IKResult:
    """Leg vectors, lengths, servo angles and reachability for poses of shape (..., 6).

    Args:
        geometry: The platform.
        pose: (..., 6) (x, y, z, roll, pitch, yaw), m and rad, translation from home.
        pivot: (3,) m, the point in the platform frame about which the platform
            rotates (source 002's point of interest); default the platform origin.

    Returns:
        An :class:`IKResult`. Unreachable poses are flagged (``reachable`` False,
        per-leg ``status``) and unsolvable servo angles are NaN; nothing is clipped.
    """
    pose = _as_pose(pose)
    k = _constants(geometry, _pivot(pivot))
    if pose.ndim == 1:
        return _ik_one(k, pose)
    batch = pose.shape[:-1]
    flat = pose.reshape(-1, 6)
    n = flat.shape[0]
    legs = np.empty((n, 3, 6))
    lengths = np.empty((n, 6))
    alpha = np.empty((n, 6)) if k.rotary else None
    aug = np.zeros((min(n, _CHUNK), 3, 7))
    aug[:, :, 4:] = np.eye(3)
    threads = OneBlasThread() if n >= _ONE_THREAD_FROM else contextlib.nullcontext()
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"), threads:
        for start in range(0, n, _CHUNK):
            sl = slice(start, start + _CHUNK)
            _ik_block(k, flat[sl], aug, legs[sl], lengths[sl], None if alpha is None else alpha[sl])
    act = lengths if alpha is None else alpha
    status = (act < k.lo).view(np.uint8) * np.uint8(LegStatus.BELOW_LIMIT)
    status[act > k.hi] = LegStatus.ABOVE_LIMIT
    if alpha is not None:
        status[np.isnan(alpha)] = LegStatus.NO_SOLUTION
    else:
        status[legs[:, 2] <= 0.0] = LegStatus.BELOW_BASE
    with np.errstate(invalid="ignore"):
        not_finite = ~(lengths * lengths < _HUGE)  # NaN, inf or absurd: never reachable
    if not_finite.any():
        status[not_finite] = LegStatus.NOT_FINITE
        if alpha is not None:
            alpha[not_finite] = np.nan
    flagged = status[:, 0].copy()  # any leg's status, column by column: several times faster than a row's any()
    for j in range(1, 6):
        flagged |= status[:, j]
    reachable = flagged == 0
    return IKResult(
        pose=pose,
        leg_vectors=legs.transpose(0, 2, 1).reshape(batch + (6, 3)),
        leg_lengths=lengths.reshape(batch + (6,)),
        servo_angles=None if alpha is None else alpha.reshape(batch + (6,)),
        status=status.reshape(batch + (6,)),
        reachable=reachable.reshape(batch),
    )


def horn_tips(geometry: PlatformGeometry, servo_angles: np.ndarray) -> np.ndarray:
    """Horn tip positions A_i = b_i + a (cos α cos β, cos α sin β, sin α), shape (..., 6, 3), m."""
    if not _geometry(geometry).is_rotary:
        raise GeometryError(f"geometry {geometry.name!r} is linear: it has no servo horns")
    assert geometry.horn_length is not None and geometry.servo_beta is not None
    al = np.asarray(servo_angles, dtype=np.float64)
    if al.shape[-1:] != (6,):
        raise ValueError(f"servo_angles must have shape (..., 6), got {al.shape}")
    a, beta = geometry.horn_length, geometry.servo_beta
    ca = np.cos(al)
    tips = np.stack([a * ca * np.cos(beta), a * ca * np.sin(beta), a * np.sin(al)], axis=-1)
    return tips + geometry.base_anchors


# ------------------------------------------------------------------- Jacobian
def _anchor_jacobian(geometry: PlatformGeometry, pose: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Platform anchors q (..., 6, 3) and ∂q/∂pose (..., 6, 3, 6)."""
    rmat = rotation_matrix(pose[..., 3], pose[..., 4], pose[..., 5])
    drot = rotation_matrix_derivatives(pose[..., 3], pose[..., 4], pose[..., 5])
    pp = geometry.platform_anchors - c  # (6, 3)
    q = np.einsum("...rk,ik->...ir", rmat, pp) + (geometry.home_position + c + pose[..., None, :3])
    dq = np.empty(pose.shape[:-1] + (6, 3, 6))
    dq[..., :3] = np.eye(3)
    dq[..., 3:] = np.einsum("...jrk,ik->...irj", drot, pp)
    return q, dq


def actuator_jacobian(
    geometry: PlatformGeometry,
    pose: np.ndarray,
    pivot: np.ndarray | None = None,
    actuator: Literal["servo", "leg"] | None = None,
) -> np.ndarray:
    """Analytic inverse Jacobian J = ∂(actuators)/∂(pose), shape (..., 6, 6).

    Row i is the derivative of actuator i, column j of pose component j
    (x, y, z in m; roll, pitch, yaw Euler angles in rad). With
    ``actuator="servo"`` (default for rotary platforms) the actuators are servo
    angles in rad; with ``"leg"`` (default for linear ones) leg lengths in m.
    ``d(actuators) = J · d(pose)``; the forward Jacobian is ``inv(J)``. Entries
    are NaN where the pose is not solvable.
    """
    pose = _as_pose(pose)
    c = _pivot(pivot)
    actuator = actuator or ("servo" if _geometry(geometry).is_rotary else "leg")
    q, dq = _anchor_jacobian(geometry, pose, c)
    legs = q - geometry.base_anchors
    if actuator == "leg":
        unit = legs / np.linalg.norm(legs, axis=-1, keepdims=True)
        return np.einsum("...ir,...irj->...ij", unit, dq)
    if actuator != "servo":
        raise ValueError(f"actuator must be 'servo' or 'leg', got {actuator!r}")
    if not geometry.is_rotary:
        raise GeometryError(f"geometry {geometry.name!r} is linear: it has no servo angles")
    alpha = inverse_kinematics(geometry, pose, c).servo_angles
    assert alpha is not None and geometry.horn_length is not None and geometry.servo_beta is not None
    rod = q - horn_tips(geometry, alpha)  # (..., 6, 3) horn tip → anchor
    a, beta = geometry.horn_length, geometry.servo_beta
    dtip = np.stack([-a * np.sin(alpha) * np.cos(beta), -a * np.sin(alpha) * np.sin(beta), a * np.cos(alpha)], -1)
    # |q − A(α)|² = s²  ⇒  dα = (q − A)·dq / ((q − A)·A'(α))
    denom = np.einsum("...ir,...ir->...i", rod, dtip)
    return np.einsum("...ir,...irj->...ij", rod, dq) / denom[..., None]


# --------------------------------------------------------------------------- FK
@dataclass(frozen=True)
class FKResult:
    """Forward kinematics of a batch; ``...`` is the batch shape of the actuator input.

    Attributes:
        pose: (..., 6) m, rad. NaN where the solve did not converge: a pose is
            never returned unless its residual is within tolerance.
        converged: (...,) bool.
        iterations: (...,) int, Newton iterations used.
        residual: (...,) m, largest leg closure error |·| at the returned pose.
    """

    pose: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray


def forward_kinematics(
    geometry: PlatformGeometry,
    leg_lengths: np.ndarray | None = None,
    servo_angles: np.ndarray | None = None,
    guess: np.ndarray | None = None,
    pivot: np.ndarray | None = None,
    *,
    xtol: float = 1e-12,
    ftol: float = 1e-11,
    max_iter: int = 30,
) -> FKResult:
    """Pose from leg lengths or servo angles by batched Newton–Raphson.

    Exactly one of ``leg_lengths`` (..., 6) m or ``servo_angles`` (..., 6) rad
    (rotary platforms) is given. The residual per leg is ``|q_i − b_i| − l_i``
    (lengths) or ``|q_i − A_i(α_i)| − s`` (servo angles: the rod must span horn
    tip to anchor); its Jacobian is analytic. ``guess`` (..., 6) defaults to home.
    A pose counts as converged when the Newton step is below ``xtol`` and the
    largest residual below ``ftol`` (m); otherwise it is NaN and ``converged``
    is False. The solution found is the assembly mode nearest the guess, its
    angles as Newton reaches them from the guess (not wrapped to ±π). Raises
    ``ValueError`` for a guess that is not finite or does not broadcast to the
    batch, or tolerances and ``max_iter`` that are not positive.
    """
    _geometry(geometry)
    if (leg_lengths is None) == (servo_angles is None):
        raise ValueError("give exactly one of leg_lengths or servo_angles")
    xtol, ftol = (real_number(name, value, low=0, low_open=True) for name, value in (("xtol", xtol), ("ftol", ftol)))
    max_iter = real_number("max_iter", max_iter, whole=True, low=1)
    c = _pivot(pivot)
    if servo_angles is not None:
        target = np.asarray(servo_angles, dtype=np.float64)
        if target.shape[-1:] != (6,):
            raise ValueError(f"servo_angles must have shape (..., 6), got {target.shape}")
        anchors = horn_tips(geometry, target)  # (..., 6, 3) fixed lower ends
        lengths = np.full(target.shape, geometry.rod_length)
    else:
        lengths = np.asarray(leg_lengths, dtype=np.float64)
        if lengths.shape[-1:] != (6,):
            raise ValueError(f"leg_lengths must have shape (..., 6), got {lengths.shape}")
        anchors = np.broadcast_to(geometry.base_anchors, lengths.shape + (3,))
    batch = lengths.shape[:-1]
    if guess is None:
        x = np.zeros(batch + (6,))
    else:
        start = np.asarray(guess, dtype=np.float64)
        try:
            x = np.array(np.broadcast_to(start, batch + (6,)))
        except ValueError:
            raise ValueError(f"guess must be a pose (6,) or one per target {batch + (6,)}, got {start.shape}") from None
        if not np.all(np.isfinite(x)):
            raise ValueError("guess holds a NaN or infinite value")
    x = x.reshape(-1, 6)
    lengths = lengths.reshape(-1, 6)
    anchors = anchors.reshape(-1, 6, 3)
    n = x.shape[0]
    iterations = np.zeros(n, dtype=np.int64)
    residual = np.full(n, np.inf)
    converged = np.zeros(n, dtype=bool)
    active = np.flatnonzero(np.all(np.isfinite(lengths), axis=1))
    scale = geometry.rod_length + geometry.home_height
    for _ in range(max_iter):
        if active.size == 0:
            break
        xa = x[active]
        q, dq = _anchor_jacobian(geometry, xa, c)
        legs = q - anchors[active]
        norm = np.linalg.norm(legs, axis=-1)
        res = norm - lengths[active]
        jac = np.einsum("kir,kirj->kij", legs / norm[..., None], dq)
        try:
            step = np.linalg.solve(jac, -res[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a singular Jacobian somewhere in the batch
            step = np.einsum("kji,ki->kj", np.linalg.pinv(jac), -res)
        x[active] = xa + step
        iterations[active] += 1
        residual[active] = np.max(np.abs(res), axis=1)
        step_norm = np.max(np.abs(step), axis=1)
        done = (step_norm <= xtol) & (residual[active] <= ftol)
        diverged = ~np.isfinite(step_norm) | (np.max(np.abs(x[active, :3]), axis=1) > 10 * scale)
        converged[active[done]] = True
        active = active[~(done | diverged)]
    # Final residual at the returned pose.
    q, _ = _anchor_jacobian(geometry, x, c)
    residual = np.max(np.abs(np.linalg.norm(q - anchors, axis=-1) - lengths), axis=1)
    converged &= residual <= ftol
    x[~converged] = np.nan
    return FKResult(
        pose=x.reshape(batch + (6,)),
        converged=converged.reshape(batch),
        iterations=iterations.reshape(batch),
        residual=residual.reshape(batch),
    )


# ------------------------------------------------------------------- reach
def axis_ranges(geometry: PlatformGeometry, pivot: np.ndarray | None = None, *, samples: int = 4001,
                tol: float = 1e-9) -> np.ndarray:  # fmt: skip
    """Reach along each pose axis from home, the others held at 0: array (6, 2) of [low, high].

    Rows are x, y, z (m) and roll, pitch, yaw (rad). Each of the 12 rays is
    sampled on ``samples`` points up to ``home_height`` (translations) or π/2
    (angles); the first unreachable sample is then bracketed and bisected to
    ``tol`` (relative to the search bound), all rays at once. The result is
    remembered per geometry object (building an env, its action mapper and its
    tilt default all ask for it; ~30 ms each time otherwise). Raises
    ``ValueError`` unless ``samples`` is a whole number from 2 and ``tol`` a
    number from 1e-15 (a float's resolution) to 1.
    """
    _geometry(geometry)
    samples = real_number("samples", samples, whole=True, low=2)
    tol = real_number("tol (relative to the search bound)", tol, low=1e-15, high=1.0)
    key = (id(geometry), _pivot(pivot).tobytes(), samples, tol)
    hit = _REACH.get(key)
    if hit is not None and hit[0] is geometry:
        return hit[1].copy()
    reach = _axis_ranges(geometry, pivot, samples, tol)
    if len(_REACH) > 64:
        _REACH.clear()
    _REACH[key] = (geometry, reach)
    return reach.copy()


_REACH: dict[tuple, tuple[PlatformGeometry, np.ndarray]] = {}


def _axis_ranges(geometry: PlatformGeometry, pivot: np.ndarray | None, samples: int, tol: float) -> np.ndarray:
    bound = np.array([geometry.home_height] * 3 + [math.pi / 2] * 3)
    signs = np.array([-1.0, 1.0])
    # rays[k, d]: unit pose of axis k in direction d, scaled by its bound
    rays = np.zeros((6, 2, 6))
    for k in range(6):
        rays[k, :, k] = signs * bound[k]
    frac = np.linspace(0.0, 1.0, samples)
    reach = inverse_kinematics(geometry, rays[:, :, None, :] * frac[:, None], pivot).reachable  # (6, 2, n)
    if not reach[..., 0].all():
        raise GeometryError(f"home is not reachable for geometry {geometry.name!r}")
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
