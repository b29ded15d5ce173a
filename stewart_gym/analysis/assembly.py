"""All real assembly modes of a 6-6 platform for given leg lengths (forward kinematics, every branch).

The general Gough–Stewart platform has up to 40 complex solutions; the real
ones are the assembly modes. For a rotary build the actuators are the servo
angles: the horn tips are then fixed, and each rod (of its fixed length) spans
a horn tip to a plate anchor. Newton's method from one guess finds the nearest
one; from many random guesses (a wide box of positions, any orientation,
platform above and below the base) it finds many. Distinct converged poses are
kept (within ``tol``), with each mode checked by inverse kinematics.
"""

from __future__ import annotations

import math

import numpy as np

from stewart_gym.checks import finite_array, real_number
from stewart_gym.errors import ConfigError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import forward_kinematics, horn_tips, inverse_kinematics, rotation_matrix
from stewart_gym.progress import Progress

__all__ = ["assembly_modes"]


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + math.pi) % (2 * math.pi) - math.pi


def assembly_modes(geometry: PlatformGeometry, leg_lengths: np.ndarray | None = None, guesses: int = 4000,
                   seed: int = 0, tol: float = 1e-6, progress: bool = False, *,
                   servo_angles: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """Distinct poses (k, 6) with these leg lengths (6,) m, or (a rotary build) these servo angles (6,) rad, sorted by
    z; Euler angles wrapped to (−π, π]. Exactly one of ``leg_lengths`` and ``servo_angles`` is given.

    Equivalent Euler triples (roll, pitch, yaw) and (roll + π, π − pitch, yaw + π) describe
    one rotation: the one with |pitch| ≤ π/2 is returned, and modes are compared by rotation
    matrix and position, not by angles.
    """
    if (leg_lengths is None) == (servo_angles is None):
        raise ValueError("give exactly one of leg_lengths or servo_angles")
    guesses = real_number("guesses", guesses, whole=True, low=1)
    real_number("tol", tol, low=0, low_open=True)
    if servo_angles is not None:
        angles = finite_array("servo_angles", servo_angles, (6,))
        tips = horn_tips(geometry, angles)  # the rods' fixed lower ends
        reach = float(np.max(np.linalg.norm(tips, axis=1))) + float(np.max(geometry.rod_length))
        actuators = {"servo_angles": angles}
    else:
        if geometry.is_rotary:
            raise ConfigError(f"leg_lengths: {geometry.name!r} is a rotary build, whose rods have one length; its "
                              "assembly modes are those of its servo angles: give servo_angles")  # fmt: skip
        lengths = finite_array("leg_lengths", leg_lengths, (6,))
        if not np.all(lengths > 0):
            raise ConfigError(f"leg_lengths must be above zero (m), got {lengths.tolist()}")
        reach = float(np.max(lengths))
        actuators = {"leg_lengths": lengths}
    rng = np.random.default_rng(seed)
    span = reach + float(np.max(np.linalg.norm(geometry.platform_anchors, axis=1)))
    g = np.empty((guesses, 6))
    g[:, :2] = rng.uniform(-span, span, (guesses, 2))
    g[:, 2] = rng.uniform(-span - geometry.home_height, span - geometry.home_height, guesses)
    g[:, 3:] = rng.uniform(-math.pi, math.pi, (guesses, 3))
    chunks = np.array_split(np.arange(guesses), max(1, guesses // 500))
    bar = Progress(len(chunks), "batches", "assembly modes") if progress else None  # (a bar on a terminal, else lines)
    found = []
    for idx in chunks:
        given = {name: np.broadcast_to(value, (len(idx), 6)) for name, value in actuators.items()}
        fk = forward_kinematics(geometry, **given, guess=g[idx], max_iter=60)
        found.append(fk.pose[fk.converged])
        if bar is not None:
            bar.advance()
    if bar is not None:
        bar.close()
    poses = np.concatenate(found) if found else np.zeros((0, 6))
    # one Euler triple per rotation: (r, p, y) and (r + π, π − p, y + π) are the same; keep |pitch| ≤ π/2
    flip = np.abs(_wrap(poses[:, 4])) > math.pi / 2
    poses[flip, 3:] += np.array([math.pi, 0.0, math.pi])
    poses[flip, 4] = math.pi - poses[flip, 4]
    poses[:, 3:] = _wrap(poses[:, 3:])
    modes: list[np.ndarray] = []
    keys: list[np.ndarray] = []
    for p in poses:
        key = np.concatenate([p[:3], rotation_matrix(*p[3:]).ravel() * span])
        if all(np.max(np.abs(key - k)) > tol * span * 10 for k in keys):
            keys.append(key)
            modes.append(p)
    out = np.array(modes).reshape(-1, 6)
    if len(out):
        legs = inverse_kinematics(geometry, out).leg_vectors
        if servo_angles is None:
            assert np.allclose(np.linalg.norm(legs, axis=-1), lengths, atol=1e-8)
        else:  # each rod spans its horn tip to its plate anchor (q_i = b_i + l_i)
            rods = np.linalg.norm(legs + geometry.base_anchors - tips, axis=-1)
            assert np.allclose(rods, geometry.rod_length, atol=1e-8)
    return out[np.argsort(out[:, 2])]
