"""N Stewart platforms with a ball each, advanced together as NumPy arrays: the reduced model.

A ball on a plate held by six servos needs no general contact solver. :class:`BatchedSim` advances, for N
platforms at once and at the physics rate:

1. **the servos**: the same pulse handling as :class:`~stewart_gym.sim.servo_model.HobbyServos` (quantisation,
   lag, dead band, trim error, decoding by the calibration), then each shaft turns towards its target as
   PyBullet's position motor drives it: by ``position_gain`` of the error per physics step, at most
   ``max_speed``;
2. **the plate**: its pose from the six servo angles by batched forward kinematics
   (:func:`~stewart_gym.kinematics.forward_kinematics`, warm-started from the last pose), so the closed chains
   hold exactly;
3. **the ball**: a sphere rolling without slipping on the moving plate. Its acceleration along the plate is
   that of gravity, less the acceleration of the plate point under it (the plate's own acceleration, angular
   acceleration and rotation), less the Coriolis term, with the sphere's rotational inertia and the plate's
   angular acceleration acting through the rolling contact:
   ``(1 + β) w = (g − a_P − Ω × u)_t − β r (Ω̇ × n)_t + β r (σ × (Ω × n))_t``, with β = I / (m r²), u the
   ball's velocity relative to the plate, σ its spin relative to the plate and n the plate normal. The plate's
   motion comes from finite differences of its poses at the physics rate.

What it leaves out, knowingly: the servos' torque limit (the ball and plate never load a hobby servo near its
stall torque on these builds), the compliance of the joints, rolling and spinning friction (1e-5 m in the
PyBullet model: about 0.005 m/s² of deceleration), slip (the ball rolls without slipping whatever the
friction), a ball leaving the plate's surface, and the plate's edge. Arrays are float64, shape (N, …).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from stewart_gym.calibration import ServoCalibration
from stewart_gym.constants import GRAVITY
from stewart_gym.kinematics import horn_tips, inverse_kinematics
from stewart_gym.sim.backend import BallSpec
from stewart_gym.sim.servo_model import ServoSpec

__all__ = ["BatchedSim"]


def _rodrigues(v: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations by the rotation vectors ``v`` (n, 3), exactly orthogonal."""
    theta = np.sqrt(np.einsum("ni,ni->n", v, v))
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)[:, None, None]
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)[:, None, None]
    k = np.zeros(v.shape[:1] + (3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return np.eye(3) + a * k + b * (k @ k)


def _skew_vector(m: np.ndarray) -> np.ndarray:
    """(..., 3) the axial vector of the skew part of (..., 3, 3) matrices."""
    return 0.5 * np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
                          axis=-1)  # fmt: skip


class BatchedSim:
    """``n`` copies of one build, each with its own servos and ball, stepped together.

    Args:
        geometry: A rotary build (preset name, TOML path or geometry).
        n: How many platforms.
        calibration: The pulse mapping the servos obey (default: the build's default).
        physics_hz, control_hz: Rates; ``physics_hz`` a multiple of ``control_hz``.
        ball_spec, servo_spec: The nominal ball and servos; :meth:`reset` may give each platform its own.
        plate_top: m, height of the plate's surface above the platform frame origin.
    """

    def __init__(self, geometry: Any = "servo-hexapod", n: int = 1, calibration: ServoCalibration | None = None,
                 physics_hz: int = 200, control_hz: int = 50, *, ball_spec: BallSpec | None = None,
                 servo_spec: ServoSpec | None = None, plate_top: float | None = None) -> None:  # fmt: skip
        from stewart_gym.errors import ConfigError
        from stewart_gym.presets import load_geometry
        from stewart_gym.sim.urdf import MechanismSpec

        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 10_000_000:
            raise ConfigError(f"n: a whole number of platforms, 1 to 10,000,000, got {n!r}")
        if control_hz <= 0 or physics_hz <= 0 or physics_hz % control_hz:
            raise ConfigError(f"physics_hz ({physics_hz}) must be a positive multiple of control_hz ({control_hz})")
        self.geometry = load_geometry(geometry)
        if not self.geometry.is_rotary:
            raise ConfigError(f"the batched simulator models rotary servos; {self.geometry.name!r} is linear")
        self.n = int(n)
        self.calibration = calibration or ServoCalibration.default(self.geometry)
        self.physics_hz, self.control_hz = int(physics_hz), int(control_hz)
        self.substeps = self.physics_hz // self.control_hz
        self.dt = 1.0 / self.control_hz
        self.plate_top = MechanismSpec().plate_top if plate_top is None else float(plate_top)
        self.ball_spec = ball_spec or BallSpec()
        self.servo_spec = servo_spec or ServoSpec()
        self._home_alpha = inverse_kinematics(self.geometry, np.zeros(6)).servo_angles
        width, depth = self.geometry.plate_extent
        self.plate_half_extent = (width / 2, depth / 2)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self, servo_specs: list[ServoSpec] | None = None, ball_specs: list[BallSpec] | None = None) -> None:
        """Every platform at home, its servos holding neutral, its ball at rest at the plate centre; each may get
        its own servos and ball (lists of ``n``)."""
        n = self.n
        servos = servo_specs or [self.servo_spec] * n
        balls = ball_specs or [self.ball_spec] * n
        if len(servos) != n or len(balls) != n:
            raise ValueError(f"servo_specs and ball_specs give one per platform ({n})")
        phys_dt = 1.0 / self.physics_hz
        self._gain = np.array([s.position_gain for s in servos])[:, None]
        self._max_step = np.array([s.max_speed * phys_dt for s in servos])[:, None]
        self._band = np.array([s.deadband_us for s in servos])[:, None]
        self._resolution = np.array([s.resolution_us for s in servos])[:, None]
        self._delay = np.array([int(round(s.lag_s * self.physics_hz)) for s in servos])
        self._trim = np.array([s.trim_error_us for s in servos])
        self._radius = np.array([b.radius for b in balls])
        self._beta = np.array([b.inertia / (b.mass * b.radius**2) for b in balls])
        self._held = np.broadcast_to(self.calibration.neutral_us, (n, 6)).copy()
        self._sent: deque[tuple[int, np.ndarray]] = deque()
        self.alpha = np.broadcast_to(self._home_alpha, (n, 6)).copy()
        home = (np.broadcast_to(self.geometry.home_position, (n, 3)).copy(), np.broadcast_to(np.eye(3), (n, 3, 3)).copy())
        self._frames = [home, home]  # the platform frame (origin, rotation) a physics step ago and now
        self._jacobian_inverse = self._inverse_jacobian(*home, self.alpha)
        self.ball_xy = np.zeros((n, 2))
        self.ball_velocity = np.zeros((n, 2))
        self._step_count = 0

    @property
    def time(self) -> float:
        """s of simulated time since the last reset."""
        return self._step_count / self.physics_hz

    def platform_pose(self) -> np.ndarray:
        """(n, 6) (x, y, z, roll, pitch, yaw) m and rad from home, as in the kinematics."""
        origin, rot = self._frames[1]
        roll = np.arctan2(rot[:, 2, 1], rot[:, 2, 2])
        pitch = -np.arcsin(np.clip(rot[:, 2, 0], -1.0, 1.0))
        yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
        return np.concatenate([origin - self.geometry.home_position, np.stack([roll, pitch, yaw], axis=1)], axis=1)

    # ------------------------------------------------------------- the plate
    def _legs(self, origin: np.ndarray, rot: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per leg (n, 6): the rod's length error (m), its unit direction (n, 6, 3) and the plate anchor's arm
        from the platform origin (n, 6, 3), world frame."""
        arm = np.einsum("nij,kj->nki", rot, self.geometry.platform_anchors)
        d = origin[:, None, :] + arm - horn_tips(self.geometry, alpha)
        length = np.sqrt(np.einsum("nki,nki->nk", d, d))
        return length - self.geometry.rod_length, d / length[..., None], arm

    def _inverse_jacobian(self, origin: np.ndarray, rot: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """(n, 6, 6): the inverse of d(rod length errors) / d(origin, rotation vector) at this frame."""
        _, unit, arm = self._legs(origin, rot, alpha)
        return np.linalg.inv(np.concatenate([unit, np.cross(arm, unit)], axis=-1))

    def _plate_frame(self, frame: tuple[np.ndarray, np.ndarray], alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The platform frame that closes all six chains at servo angles ``alpha``: Newton's method from
        ``frame`` (a physics step earlier, so one step suffices), with the Jacobian of the control period's start
        (the chord method); a second step where the first leaves more than 1 µm."""
        origin, rot = frame
        for attempt in range(2):
            error = self._legs(origin, rot, alpha)[0]
            if attempt and np.abs(error).max() < 1e-6:
                break
            delta = -np.einsum("nij,nj->ni", self._jacobian_inverse, error)
            origin, rot = origin + delta[:, :3], _rodrigues(delta[:, 3:]) @ rot
        return origin, rot

    def ball_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ball centre (n, 3) m and velocity (n, 3) m/s in the platform frame (z: ``plate_top`` + radius; the
        velocity's z is 0: the ball rolls in the plate)."""
        z = (self.plate_top + self._radius)[:, None]
        return (np.concatenate([self.ball_xy, z], axis=1),
                np.concatenate([self.ball_velocity, np.zeros((self.n, 1))], axis=1))  # fmt: skip

    def place_ball(self, xy: np.ndarray, velocity_xy: np.ndarray | None = None, mask: np.ndarray | None = None) -> None:
        """Put each ball (where ``mask``) at ``xy`` (n, 2) m rolling with ``velocity_xy`` (n, 2) m/s, plate frame."""
        where = np.ones(self.n, bool) if mask is None else np.asarray(mask, bool)
        xy = np.broadcast_to(np.asarray(xy, float), (self.n, 2))
        v = np.zeros((self.n, 2)) if velocity_xy is None else np.broadcast_to(np.asarray(velocity_xy, float), (self.n, 2))
        self.ball_xy[where] = xy[where]
        self.ball_velocity[where] = v[where]

    # ------------------------------------------------------------ commanding
    def command(self, pulse_widths_us: np.ndarray) -> np.ndarray:
        """Send pulses (n, 6) µs to every platform's servos; they act on them after their lag. Returns them as
        quantised. Raises :class:`~stewart_gym.calibration.PulseRangeError` if any pulse leaves its channel's
        limits or is not finite: nothing is sent then."""
        w = np.asarray(pulse_widths_us, dtype=np.float64).reshape(self.n, 6)
        self.calibration.check(w)
        res = self._resolution
        quantised = np.where(res > 0, np.round(w / np.where(res > 0, res, 1.0)) * res, w)
        self._sent.append((self._step_count, quantised))
        keep = int(self._delay.max()) + 1
        while len(self._sent) > 1 and self._sent[1][0] + keep <= self._step_count:
            self._sent.popleft()  # an older command than one already due everywhere can never be due again
        return quantised

    def held_pulses(self) -> np.ndarray:
        """(n, 6) µs: the pulses the servos act on now (after lag and dead band)."""
        return self._held.copy()

    def _targets(self) -> np.ndarray:
        return self.calibration.angles(self._held - self._trim)

    def _update_held(self) -> bool:
        """Apply, per platform, the latest command that its lag has made due; whether any held pulse changed."""
        if not self._sent:
            return False
        due = None
        for sent_at, pulses in self._sent:  # oldest first: the last one due wins
            ready = (sent_at + self._delay) <= self._step_count
            if due is None:
                due = np.where(ready[:, None], pulses, np.nan)
            else:
                due = np.where(ready[:, None], pulses, due)
        assert due is not None
        new = np.isfinite(due) & (np.abs(due - self._held) > self._band)
        if not new.any():
            return False
        self._held = np.where(new, due, self._held)
        return True

    # --------------------------------------------------------------- stepping
    def step(self) -> None:
        """Advance one control period (``substeps`` physics steps)."""
        h = 1.0 / self.physics_hz
        targets = self._targets()
        alpha, frames = self.alpha, list(self._frames)  # frames: k-1, k, then k+1 … k+substeps
        self._jacobian_inverse = self._inverse_jacobian(*frames[1], alpha)
        for _ in range(self.substeps):  # the plate's path over the period: it does not depend on the ball
            if self._update_held():
                targets = self._targets()
            alpha = alpha + np.clip(self._gain * (targets - alpha), -self._max_step, self._max_step)
            frames.append(self._plate_frame(frames[-1], alpha))
            self._step_count += 1
        for j in range(self.substeps):
            self._roll(frames[j], frames[j + 1], frames[j + 2], h)
        self.alpha = alpha
        self._frames = frames[-2:]

    def _roll(self, before: tuple, now: tuple, after: tuple, h: float) -> None:
        """Advance the balls one physics step on the plate, whose frames are known a step before and after."""
        (o0, r0), (o1, r1), (o2, r2) = before, now, after
        z = (self.plate_top + self._radius)[:, None]
        q = np.concatenate([self.ball_xy, z], axis=1)  # ball centre, plate frame
        point = [o + np.einsum("nij,nj->ni", r, q) for o, r in ((o0, r0), (o1, r1), (o2, r2))]
        a_p = (point[2] - 2.0 * point[1] + point[0]) / h**2  # the plate point under the ball's centre
        w_back = _skew_vector(np.einsum("nij,nkj->nik", r1, r0)) / h  # Ω over the half steps
        w_ahead = _skew_vector(np.einsum("nij,nkj->nik", r2, r1)) / h
        omega, omega_dot = 0.5 * (w_back + w_ahead), (w_ahead - w_back) / h
        normal = r1[:, :, 2]
        u = np.einsum("nij,nj->ni", r1[:, :, :2], self.ball_velocity)  # relative velocity, world
        sigma = np.cross(normal, u) / self._radius[:, None]  # spin relative to the plate (none about n)
        beta, radius = self._beta[:, None], self._radius[:, None]
        gravity = np.array([0.0, 0.0, -GRAVITY])
        drive = (gravity - a_p - np.cross(omega, u) - beta * radius * np.cross(omega_dot, normal)
                 + beta * radius * np.cross(sigma, np.cross(omega, normal)))  # fmt: skip
        w = drive / (1.0 + beta)
        a_rel = w - np.cross(omega, u)
        accel = np.einsum("nji,nj->ni", r1[:, :, :2], a_rel)  # plate frame, in the plate (the tangential part)
        self.ball_velocity = self.ball_velocity + accel * h
        self.ball_xy = self.ball_xy + self.ball_velocity * h
