"""How precisely a servo platform can be placed (source 003), and how well conditioned it is.

For a pose with actuator Jacobian J = ∂α/∂pose (:func:`~stewart_gym.kinematics.actuator_jacobian`),
the forward Jacobian F = J⁻¹ gives the platform motion for servo steps: one
servo i stepping by Δα moves the pose by F[:, i]·Δα. The *resolution* per axis is
the largest such motion over the six servos; the worst case when every servo
may be off by Δα at once is Σ_i |F[k, i]|·Δα.

Source 003 estimates the motion as the horn tip's arc, a·Δα (a small-angle
estimate that ignores the linkage's leverage); :func:`sensitivity` reports both.

Conditioning: cond(J·S) with S = diag(1, 1, 1, 1/Lc, 1/Lc, 1/Lc) and Lc the
platform anchor radius, so that angles count as arc lengths and the number is
unit-free. Poses above ``singular_threshold`` are flagged as near-singular.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stewart_gym.checks import real_number
from stewart_gym.errors import ConfigError
from stewart_gym.geometry import GeometryError, PlatformGeometry
from stewart_gym.kinematics import actuator_jacobian, forward_kinematics, inverse_kinematics

__all__ = ["SensitivityResult", "conditioning", "fd_check", "sensitivity", "xy_grid_poses"]


def xy_grid_poses(x: np.ndarray, y: np.ndarray, z: float = 0.0,
                  orientation: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:  # fmt: skip
    """Poses (ny, nx, 6) on an x–y grid at height z and a fixed orientation."""
    gx, gy = np.meshgrid(np.asarray(x, float), np.asarray(y, float))
    poses = np.zeros(gx.shape + (6,))
    poses[..., 0], poses[..., 1], poses[..., 2], poses[..., 3:] = gx, gy, z, orientation
    return poses


@dataclass(frozen=True)
class SensitivityResult:
    """Per pose (shape ``...`` of the input poses) and overall figures.

    Attributes:
        reachable: (...,) bool.
        axis_step: (..., 6) platform motion per axis for the worst single servo step
            (m for x, y, z; rad for roll, pitch, yaw); NaN where unreachable.
        position_step: (...,) m, largest translation caused by one servo step.
        angle_step: (...,) rad, largest rotation caused by one servo step.
        all_servos: (..., 6) worst case with every servo off by the step.
        step: rad, the servo step.
        small_angle_estimate: m, source 003's a·Δα.
    """

    reachable: np.ndarray
    axis_step: np.ndarray
    position_step: np.ndarray
    angle_step: np.ndarray
    all_servos: np.ndarray
    step: float
    small_angle_estimate: float

    def worst(self) -> dict[str, float]:
        """The least precise reachable pose's figures: mm and degrees."""
        return {
            "worst_position_step_mm": float(np.nanmax(self.position_step) * 1e3),
            "worst_angle_step_deg": float(math.degrees(np.nanmax(self.angle_step))),
            "best_position_step_mm": float(np.nanmin(self.position_step) * 1e3),
            "worst_all_servos_xyz_mm": [float(v) for v in np.nanmax(self.all_servos[..., :3], axis=tuple(
                range(self.all_servos.ndim - 1))) * 1e3],  # fmt: skip
            "worst_all_servos_rpy_deg": [float(v) for v in np.degrees(np.nanmax(self.all_servos[..., 3:], axis=tuple(
                range(self.all_servos.ndim - 1))))],  # fmt: skip
            "small_angle_estimate_mm": self.small_angle_estimate * 1e3,
        }


def _forward_jacobian(geometry: PlatformGeometry, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    reach = inverse_kinematics(geometry, poses).reachable
    jac = actuator_jacobian(geometry, poses)
    fwd = np.full(jac.shape, np.nan)
    good = reach & np.all(np.isfinite(jac), axis=(-2, -1))
    fwd[good] = np.linalg.inv(jac[good])
    return reach, fwd


def sensitivity(geometry: PlatformGeometry, poses: np.ndarray, step: float = math.radians(0.1)) -> SensitivityResult:
    """Platform motion for a servo step of ``step`` rad (default 0.1°, source 003's servo resolution) at ``poses``."""
    if not geometry.is_rotary:
        raise GeometryError(f"geometry {geometry.name!r} is linear: servo sensitivity needs a rotary platform")
    step = real_number("step", step, low=0, low_open=True)
    poses = np.asarray(poses, dtype=np.float64)
    reach, fwd = _forward_jacobian(geometry, poses)
    per_servo = np.abs(fwd) * step  # (..., 6 axes, 6 servos)
    axis_step = per_servo.max(axis=-1)
    pos = np.linalg.norm(fwd[..., :3, :], axis=-2).max(axis=-1) * step
    ang = np.linalg.norm(fwd[..., 3:, :], axis=-2).max(axis=-1) * step
    return SensitivityResult(reach, axis_step, pos, ang, per_servo.sum(axis=-1), step,
                             float(geometry.horn_length) * step)  # type: ignore[arg-type]  # fmt: skip


def fd_check(geometry: PlatformGeometry, poses: np.ndarray, step: float = math.radians(0.1)) -> float:
    """Largest relative difference between F·Δα and forward kinematics of the stepped servo angles.

    Each of the six servos is stepped by ±``step`` in turn and FK (Newton,
    started at the unstepped pose) gives the new pose; the central difference is
    compared with the Jacobian's prediction, relative to its norm.
    """
    step = real_number("step", step, low=0, low_open=True)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 6)
    ik = inverse_kinematics(geometry, poses)
    poses, alpha = poses[ik.reachable], ik.servo_angles[ik.reachable]
    if len(poses) == 0:
        raise ConfigError("poses: none is reachable, so there is nothing to check; give reachable poses")
    _, fwd = _forward_jacobian(geometry, poses)
    worst = 0.0
    for i in range(6):
        d = np.zeros(6)
        d[i] = step
        plus = forward_kinematics(geometry, servo_angles=alpha + d, guess=poses)
        minus = forward_kinematics(geometry, servo_angles=alpha - d, guess=poses)
        fd = (plus.pose - minus.pose) / 2
        pred = fwd[:, :, i] * step
        ok = plus.converged & minus.converged
        rel = np.linalg.norm(fd[ok] - pred[ok], axis=1) / np.linalg.norm(pred[ok], axis=1)
        worst = max(worst, float(rel.max()))
    return worst


def conditioning(geometry: PlatformGeometry, poses: np.ndarray, singular_threshold: float = 1e3) -> dict[str, object]:
    """Condition numbers (…,) of the scaled Jacobian at ``poses`` (NaN if unreachable) and near-singular flags."""
    real_number("singular_threshold", singular_threshold, low=0, low_open=True)
    poses = np.asarray(poses, dtype=np.float64)
    reach = inverse_kinematics(geometry, poses).reachable
    jac = actuator_jacobian(geometry, poses)
    lc = float(np.mean(np.linalg.norm(geometry.platform_anchors[:, :2], axis=1)))
    scaled = jac * np.array([1, 1, 1, 1 / lc, 1 / lc, 1 / lc])
    cond = np.full(reach.shape, np.nan)
    good = reach & np.all(np.isfinite(scaled), axis=(-2, -1))
    cond[good] = np.linalg.cond(scaled[good])
    near = good & (cond > singular_threshold)
    return {"cond": cond, "near_singular": near, "threshold": singular_threshold, "length_scale_m": lc}
