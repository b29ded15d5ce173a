"""N Stewart platforms with a ball each, advanced together: the reduced model.

A ball on a plate held by six servos needs no general contact solver. :class:`BatchedSim` advances, for N
platforms at once and at the physics rate:

1. **the servos**: the same pulse handling as :class:`~stewart_gym.sim.servo_model.HobbyServos` (quantisation,
   lag, dead band, trim error, decoding by the calibration), then each shaft turns towards its target as
   PyBullet's position motor drives it: by ``position_gain`` of the error per physics step, at most
   ``max_speed``, its speed changing by at most ``stall_torque`` / ``rotor_inertia``
   (:class:`~stewart_gym.sim.urdf.MechanismSpec`) per second, so that a servo takes about 13 ms to reach
   full speed;
2. **the plate**: its pose from the six servo angles by Newton's method on the six rod lengths, as
   :func:`~stewart_gym.kinematics.forward_kinematics` finds it, for all the physics steps of a control period at
   once from the period's first pose, so the closed chains hold to a few µm of rod length under tilt commands
   (:data:`NEWTON_STEPS`);
3. **the ball**: a sphere rolling without slipping on the moving plate. Its acceleration along the plate is
   that of gravity, less the acceleration of the plate point under it (the plate's own acceleration, angular
   acceleration and rotation), less the Coriolis term, with the sphere's rotational inertia and the plate's
   angular acceleration acting through the rolling contact:
   ``(1 + β) w = (g − a_P − Ω × u)_t − β r (Ω̇ × n)_t + β r (σ × (Ω × n))_t``, with β = I / (m r²), u the
   ball's velocity relative to the plate, σ its spin relative to the plate and n the plate normal. The plate's
   motion comes from finite differences of its poses at the physics rate.

What it leaves out, knowingly: the load on the servos (the ball and plate never load a hobby servo near its stall
torque on these builds; the rotor's inertia alone limits the acceleration), the compliance of the joints, rolling
and spinning friction (1e-5 m in the PyBullet model: about 0.005 m/s² of deceleration), slip (the ball rolls
without slipping whatever the friction), a ball leaving the plate's surface, and the plate's edge. Arrays are
float64, shape (N, …).

A control period runs as one compiled loop over the platforms where numba is installed
(:mod:`stewart_gym.sim.batched_kernel`), else as NumPy arrays of all of them (``kernel="numpy"``): the same
model, to rounding.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from stewart_gym.blas import OneBlasThread
from stewart_gym.calibration import ServoCalibration
from stewart_gym.constants import GRAVITY
from stewart_gym.kinematics import horn_tips, inverse_kinematics
from stewart_gym.sim.backend import BallSpec, check_rates
from stewart_gym.sim.servo_model import ServoSpec

__all__ = ["BatchedSim"]

#: Newton steps that close the chains at each physics step (:meth:`BatchedSim._plate_frames`). On 6° tilt
#: sinusoids they leave at most about 2 µm of rod length error, and the ball's path over 3 s within 0.06 mm of
#: the exactly closed chains'; under a random full-range tilt action every period, about 6 µm and 0.06 mm. Pulses
#: that jump by up to ±150 µs every period leave up to about 40 µm and 1 mm (3 steps: 5 µm and 0.06 mm).
NEWTON_STEPS = 2
#: Commands kept in flight beyond which the simulator looks for those no platform can act on again (commands to
#: some platforms only leave older ones that the cheap check, a later command to all, does not drop).
PRUNE_FROM = 16
_IDENTITY = np.eye(3)


def _rodrigues(v: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations by the rotation vectors ``v`` (n, 3), exactly orthogonal:
    ``cos θ I + (sin θ / θ) [v]× + ((1 − cos θ) / θ²) v vᵀ``."""
    theta2 = np.einsum("ni,ni->n", v, v)
    theta = np.sqrt(theta2)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    out = (b[:, None, None] * v[:, :, None]) * v[:, None, :]
    diagonal = 1.0 - b * theta2  # cos θ, as the series gives it where θ is small
    av = a[:, None] * v
    out[:, 0, 0] += diagonal
    out[:, 1, 1] += diagonal
    out[:, 2, 2] += diagonal
    out[:, 0, 1] -= av[:, 2]
    out[:, 0, 2] += av[:, 1]
    out[:, 1, 2] -= av[:, 0]
    out[:, 1, 0] += av[:, 2]
    out[:, 2, 0] -= av[:, 1]
    out[:, 2, 1] += av[:, 0]
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3) cross products of (..., 3) vectors (broadcast), the same numbers as ``np.cross`` at half its cost
    on small batches (no axis handling)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


def _relative_rotation_vector(later: np.ndarray, earlier: np.ndarray) -> np.ndarray:
    """(n, 3) the axial vector of the skew part of ``later @ earlier.T`` (both (n, 3, 3)): for rotations a step
    apart, the small rotation between them. It is half the sum over columns k of ``earlier[:, :, k] ×
    later[:, :, k]``."""
    return 0.5 * _cross(earlier.transpose(0, 2, 1), later.transpose(0, 2, 1)).sum(axis=1)


class BatchedSim:
    """``n`` copies of one build, each with its own servos and ball, stepped together.

    Args:
        geometry: A rotary build (preset name, TOML path or geometry).
        n: How many platforms.
        calibration: The pulse mapping the servos obey (default: the build's default).
        physics_hz: Physics steps per second, a multiple of ``control_hz``.
        control_hz: Control periods per second (one :meth:`step` each).
        ball_spec: The nominal ball; :meth:`reset` may give each platform its own.
        servo_spec: The nominal servos; :meth:`reset` may give each platform its own.
        plate_top: m, height of the plate's surface above the platform frame origin.
        kernel: How a control period is computed: ``"numba"``, one compiled loop over the platforms
            (:mod:`stewart_gym.sim.batched_kernel`); ``"numpy"``, arrays of all platforms at once; ``"auto"``
            (default), numba where it is installed. The two agree to rounding.
    """

    def __init__(self, geometry: Any = "servo-hexapod", n: int = 1, calibration: ServoCalibration | None = None,
                 physics_hz: int = 200, control_hz: int = 50, *, ball_spec: BallSpec | None = None,
                 servo_spec: ServoSpec | None = None, plate_top: float | None = None,
                 kernel: str = "auto") -> None:  # fmt: skip
        from stewart_gym.errors import ConfigError
        from stewart_gym.presets import load_geometry
        from stewart_gym.sim.urdf import MechanismSpec

        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 10_000_000:
            raise ConfigError(f"n: a whole number of platforms, 1 to 10,000,000, got {n!r}")
        check_rates(physics_hz, control_hz)
        from stewart_gym.compiled import use_compiled
        from stewart_gym.sim import batched_kernel

        #: the kernel in use: "numba" or "numpy"
        self.kernel = "numba" if use_compiled(kernel, batched_kernel.AVAILABLE) else "numpy"
        self._advance, self._held_targets = batched_kernel.advance, batched_kernel.held_targets
        self.geometry = load_geometry(geometry)
        if not self.geometry.is_rotary:
            raise ConfigError(f"the batched simulator models rotary servos; {self.geometry.name!r} is linear")
        self.n = int(n)
        self.calibration = calibration or ServoCalibration.default(self.geometry)
        self.physics_hz, self.control_hz = int(physics_hz), int(control_hz)
        self.substeps = self.physics_hz // self.control_hz
        self.dt = 1.0 / self.control_hz
        mechanism = MechanismSpec()
        self.plate_top = mechanism.plate_top if plate_top is None else float(plate_top)
        self._rotor_inertia = mechanism.rotor_inertia
        self.ball_spec = ball_spec or BallSpec()
        self.servo_spec = servo_spec or ServoSpec()
        self._home_alpha = inverse_kinematics(self.geometry, np.zeros(6)).servo_angles
        self._cos_beta, self._sin_beta = np.cos(self.geometry.servo_beta), np.sin(self.geometry.servo_beta)
        self._rod_lengths = np.broadcast_to(np.asarray(self.geometry.rod_length, dtype=np.float64), (6,)).copy()
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
        self._gain, self._max_step, self._band, self._resolution = (np.zeros((n, 1)) for _ in range(4))
        self._max_change = np.zeros((n, 1))  # rad: the most a shaft's step changes from one physics step to the next
        self._last_step = np.zeros((n, 6))  # rad: each shaft's last physics step
        self._resolution_list = [0.0] * n
        self._delay, self._trim = np.zeros(n, dtype=np.int64), np.zeros((n, 6))
        self._radius, self._beta, self._mass = np.zeros(n), np.zeros(n), np.zeros(n)
        self._step_count = 0
        self._since = np.zeros(n, dtype=np.int64)  # the physics step of each platform's last reset
        self._sent: deque[tuple[int, np.ndarray, np.ndarray]] = deque()  # (step, pulses, which platforms)
        self._pending = np.zeros((n, 6))
        self._pending_mask = np.zeros(n, dtype=bool)
        home = (np.broadcast_to(self.geometry.home_position, (n, 3)).copy(), np.broadcast_to(np.eye(3), (n, 3, 3)).copy())
        self._frames = [home, (home[0].copy(), home[1].copy())]  # the platform frame a physics step ago and now
        self._held = np.zeros((n, 6))
        self.alpha = np.zeros((n, 6))
        self.ball_xy = np.zeros((n, 2))
        self.ball_velocity = np.zeros((n, 2))
        #: each platform's servos, ball and plate load (kg, (3,) m from the plate centre, or None) this episode
        self.servo_specs: list[ServoSpec] = list(servos)
        self.ball_specs: list[BallSpec] = list(balls)
        self.plate_loads: list[Any] = [None] * n
        self._set_platforms(np.arange(n), servos, balls)

    def reset_platform(self, i: int, servo_spec: ServoSpec | None = None, ball_spec: BallSpec | None = None) -> None:
        """Platform ``i`` alone back at home with its servos holding neutral (commands sent to it before are
        dropped), its ball at rest at the plate centre; with its own servos and ball where given."""
        self.reset_platforms(np.array([i]), [servo_spec or self.servo_spec], [ball_spec or self.ball_spec])

    def reset_platforms(self, rows: np.ndarray, servo_specs: Sequence[ServoSpec], ball_specs: Sequence[BallSpec],
                        plate_loads: Sequence[Any] | None = None) -> None:  # fmt: skip
        """Platforms ``rows`` back at home with their servos holding neutral (commands sent to them before are
        dropped), their balls at rest at the plate centre; platform ``rows[k]`` with servos ``servo_specs[k]``, ball
        ``ball_specs[k]`` and plate load ``plate_loads[k]`` (default none)."""
        rows = np.arange(self.n)[rows]  # row numbers, checked (a mask or a slice as the rows it picks)
        for name, given in (("servo_specs", servo_specs), ("ball_specs", ball_specs), ("plate_loads", plate_loads)):
            if given is not None and len(given) != len(rows):
                raise ValueError(f"reset_platforms: {len(given)} {name} for {len(rows)} platforms")
        self._set_platforms(rows, servo_specs, ball_specs, plate_loads)
        self._since[rows] = self._step_count
        self._pending_mask[rows] = False
        for frame in self._frames:
            frame[0][rows], frame[1][rows] = self.geometry.home_position, _IDENTITY

    def _set_platforms(self, rows: np.ndarray, servos: Sequence[ServoSpec], balls: Sequence[BallSpec],
                       loads: Sequence[Any] | None = None) -> None:  # fmt: skip
        """Platform ``rows[k]``'s servos, ball and plate load; its servos holding neutral and its ball at rest at the
        centre. Each number is found as a Python float, then stored."""
        phys_dt = 1.0 / self.physics_hz
        self._gain[rows, 0] = [servo.position_gain for servo in servos]
        self._max_step[rows, 0] = [servo.max_speed * phys_dt for servo in servos]
        self._max_change[rows, 0] = [servo.stall_torque / self._rotor_inertia * phys_dt**2 for servo in servos]
        self._last_step[rows] = 0.0
        self._band[rows, 0] = [servo.deadband_us for servo in servos]
        resolutions = [float(servo.resolution_us) for servo in servos]
        self._resolution[rows, 0] = resolutions
        self._delay[rows] = [int(round(servo.lag_s * self.physics_hz)) for servo in servos]
        self._trim[rows] = [servo.trim_error_us for servo in servos]
        self._radius[rows] = [ball.radius for ball in balls]
        self._mass[rows] = [ball.mass for ball in balls]
        self._beta[rows] = [ball.inertia / (ball.mass * ball.radius**2) for ball in balls]
        self._held[rows] = self.calibration.neutral_us
        self.alpha[rows] = self._home_alpha
        self.ball_xy[rows] = 0.0
        self.ball_velocity[rows] = 0.0
        for k, i in enumerate(rows.tolist()):
            self._resolution_list[i] = resolutions[k]
            self.servo_specs[i], self.ball_specs[i] = servos[k], balls[k]
            self.plate_loads[i] = None if loads is None else loads[k]

    @property
    def ball_radius(self) -> np.ndarray:
        """(n,) m: each platform's ball radius (this episode's)."""
        return self._radius

    def platform_time(self, i: int) -> float:
        """s of simulated time since platform ``i``'s last reset."""
        return float(self._step_count - self._since[i]) / self.physics_hz

    def platform_times(self) -> np.ndarray:
        """(n,) s of simulated time since each platform's last reset (:meth:`platform_time` of each)."""
        return (self._step_count - self._since).astype(np.float64) / self.physics_hz

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
    def _arms(self, rot: np.ndarray) -> np.ndarray:
        """(n, 6, 3) the plate anchors' arms R p_k from the platform origin, world frame, for rotations (n, 3, 3):
        one matrix product, (n·3, 3) × (3, 6)."""
        n = len(rot)
        return (rot.reshape(n * 3, 3) @ self.geometry.platform_anchors.T).reshape(n, 3, 6).transpose(0, 2, 1)

    def _rod_errors(self, origin: np.ndarray, rot: np.ndarray, tips: np.ndarray) -> np.ndarray:
        """(n, 6) m: each rod's length error, plate frame (``origin``, ``rot``) to the horn ``tips`` (n, 6, 3)."""
        d = self._arms(rot) + (origin[:, None, :] - tips)
        return np.sqrt(np.einsum("nki,nki->nk", d, d)) - self.geometry.rod_length

    def _inverse_jacobian(self, origin: np.ndarray, rot: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """(n, 6, 6): the inverse of d(rod length errors) / d(origin, rotation vector) at this frame."""
        arm = self._arms(rot)
        d = arm + (origin[:, None, :] - horn_tips(self.geometry, alpha))
        unit = d / np.sqrt(np.einsum("nki,nki->nk", d, d))[..., None]
        return np.linalg.inv(np.concatenate([unit, _cross(arm, unit)], axis=-1))

    def _plate_frames(self, start: tuple[np.ndarray, np.ndarray], alphas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The platform frames, origins (s, n, 3) and rotations (s, n, 3, 3), that close all six chains at the
        servo angles ``alphas`` (s, n, 6) of a control period's s physics steps: all s at once, by
        :data:`NEWTON_STEPS` steps of Newton's method from the period's ``start`` frame with its Jacobian (the
        chord method)."""
        s, n = alphas.shape[:2]
        tips = horn_tips(self.geometry, alphas.reshape(s * n, 6))
        origin = np.broadcast_to(start[0], (s, n, 3)).reshape(s * n, 3)
        rot = np.broadcast_to(start[1], (s, n, 3, 3)).reshape(s * n, 3, 3)
        for _ in range(NEWTON_STEPS):
            error = self._rod_errors(origin, rot, tips).reshape(s, n, 6)
            delta = -np.einsum("nij,snj->sni", self._jacobian_inverse, error).reshape(s * n, 6)
            origin, rot = origin + delta[:, :3], _rodrigues(delta[:, 3:]) @ rot
        return origin.reshape(s, n, 3), rot.reshape(s, n, 3, 3)

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
    def _quantised(self, w: np.ndarray, rows: Any) -> np.ndarray:
        """``w`` (rows, 6) µs checked against the channel limits (raises, naming the channel) and quantised."""
        self.calibration.check(w)
        res = self._resolution[rows]
        return np.where(res > 0, np.round(w / np.where(res > 0, res, 1.0)) * res, w)

    def command(self, pulse_widths_us: np.ndarray) -> np.ndarray:
        """Send pulses (n, 6) µs to every platform's servos; they act on them after their lag. Returns them as
        quantised. Raises :class:`~stewart_gym.calibration.PulseRangeError` if any pulse leaves its channel's
        limits or is not finite: nothing is sent then."""
        w = self._quantised(np.asarray(pulse_widths_us, dtype=np.float64).reshape(self.n, 6), slice(None))
        self._pending[:] = w
        self._pending_mask[:] = True
        return w

    def command_one(self, i: int, pulse_widths_us: np.ndarray) -> np.ndarray:
        """Send pulses (6,) µs to platform ``i``'s servos with the next :meth:`step` (checked and quantised as
        :meth:`command`)."""
        pulses = np.asarray(pulse_widths_us, dtype=np.float64).reshape(6).tolist()
        if not self.calibration.in_range_one(pulses):
            self.calibration.check(np.array([pulses]))  # raises, naming the channel
        res = self._resolution_list[i]
        if res > 0:
            pulses = [round(w / res) * res for w in pulses]
        self._pending[i] = pulses
        self._pending_mask[i] = True
        return self._pending[i].copy()

    def _send_pending(self) -> None:
        if self._pending_mask.any():
            self._sent.append((self._step_count, self._pending.copy(), self._pending_mask.copy()))
            self._pending_mask[:] = False
        keep = int(self._delay.max()) + 1
        while len(self._sent) > 1 and self._sent[1][0] + keep <= self._step_count and self._sent[1][2].all():
            self._sent.popleft()  # older than a command to every platform that is already due everywhere
        if len(self._sent) > PRUNE_FROM:  # commands to some platforms only: drop those none can act on again
            self._prune_sent()

    def _prune_sent(self) -> None:
        """Keep only the commands sent that a platform can still act on: for each platform, its newest command
        due now (which stays due) and those not yet due, since its reset."""
        at, _, which = self._sent_arrays()
        live = which & (at[:, None] >= self._since)  # (commands, platforms)
        due = live & (at[:, None] + self._delay <= self._step_count)
        order = np.arange(len(at))
        newest_due = np.where(due, order[:, None], -1).max(axis=0)  # per platform; -1 where none
        needed = (order[:, None] == newest_due).any(axis=1) | (live & ~due).any(axis=1)
        if not needed.all():
            self._sent = deque(command for command, keep in zip(self._sent, needed.tolist()) if keep)

    def _sent_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The commands in flight as arrays, oldest first: the physics step each was sent at (m,), its pulses
        (m, n, 6) µs and the platforms it went to (m, n)."""
        sent, m = self._sent, len(self._sent)
        return (np.array([at for at, _, _ in sent], dtype=np.int64).reshape(m),
                np.array([pulses for _, pulses, _ in sent], dtype=np.float64).reshape(m, self.n, 6),
                np.array([which for _, _, which in sent], dtype=bool).reshape(m, self.n))  # fmt: skip

    @property
    def commands_in_flight(self) -> int:
        """How many of the commands sent the simulator keeps: those a platform may still act on."""
        return len(self._sent)

    def held_pulses(self) -> np.ndarray:
        """(n, 6) µs: the pulses the servos act on now (after lag and dead band)."""
        return self._held.copy()

    def push(self, i: int, impulse_xy: tuple[float, float]) -> None:
        """An impulse (N·s, plate frame) on ball ``i``: its velocity changes by impulse / mass, and it keeps
        rolling."""
        self.ball_velocity[i] += np.asarray(impulse_xy, dtype=np.float64) / self._mass[i]

    def _targets(self) -> np.ndarray:
        return self.calibration.angles(self._held - self._trim)

    def _update_held(self) -> bool:
        """Apply, per platform, the latest command sent since its reset that its lag has made due; whether any held
        pulse changed."""
        if not self._sent:
            return False
        due = np.full((self.n, 6), np.nan)
        for sent_at, pulses, which in self._sent:  # oldest first: the last one due wins
            ready = which & (sent_at + self._delay <= self._step_count) & (sent_at >= self._since)
            due = np.where(ready[:, None], pulses, due)
        new = np.isfinite(due) & (np.abs(due - self._held) > self._band)
        if not new.any():
            return False
        self._held = np.where(new, due, self._held)
        return True

    # --------------------------------------------------------------- stepping
    def step(self) -> None:
        """Advance one control period (``substeps`` physics steps): by the compiled kernel, or by the NumPy one on
        one BLAS thread (:mod:`stewart_gym.blas`: the plate's matrix products gain nothing from a second one, which
        would only take another core)."""
        if self.kernel == "numba":
            self._step_compiled()
            return
        with OneBlasThread():
            self._jacobian_inverse = self._inverse_jacobian(*self._frames[1], self.alpha)
            alphas = self._servo_steps()  # the servos, then the plate's path over the period: neither needs the ball
            origin, rot = self._plate_frames(self._frames[1], alphas)
            (o0, r0), (o1, r1) = self._frames
            origins = np.concatenate([o0[None], o1[None], origin])  # frames k-1, k, then k+1 … k+substeps
            rots = np.concatenate([r0[None], r1[None], rot])
            self._roll(origins, rots)
            self._frames = [(origins[-2], rots[-2]), (origins[-1], rots[-1])]

    def _step_compiled(self) -> None:
        """:meth:`step` by the compiled kernel, which updates the state arrays in place."""
        self._send_pending()
        targets = np.empty((self.substeps, self.n, 6))
        c = self.calibration  # its angles: home + (w − neutral) / (direction · µs per rad)
        self._held_targets(*self._sent_arrays(), self._delay, self._since, self._band[:, 0], self._held, self._trim,
                           c.home_angle, c.neutral_us, c.direction * c.us_per_rad, self._step_count, targets)
        self._step_count += self.substeps
        (o0, r0), (o1, r1) = self._frames
        g = self.geometry
        self._advance(targets, self.alpha, self._last_step, self._gain[:, 0], self._max_step[:, 0],
                      self._max_change[:, 0], o0, r0, o1, r1, self.ball_xy, self.ball_velocity, self._beta,
                      self._radius, g.base_anchors, g.horn_length, self._cos_beta, self._sin_beta, g.platform_anchors,
                      self._rod_lengths, self.plate_top, GRAVITY, 1.0 / self.physics_hz, NEWTON_STEPS)  # fmt: skip

    def step_servos(self) -> np.ndarray:
        """Advance only the servos one control period, for a replay that needs their angles alone (the plate and
        the balls stay as they were, out of step with them, until :meth:`reset`): the angles (``substeps``, n, 6)
        rad at the end of each physics step."""
        return self._servo_steps()

    def _servo_steps(self) -> np.ndarray:
        """Send what was commanded and turn the servos through the period's physics steps; their angles
        (substeps, n, 6) after each."""
        alpha, last = self.alpha, self._last_step
        alphas = np.empty((self.substeps, self.n, 6))
        for j, targets in enumerate(self._servo_targets()):
            wanted = np.clip(self._gain * (targets - alpha), -self._max_step, self._max_step)
            last = np.clip(wanted, last - self._max_change, last + self._max_change)
            alpha = alpha + last
            alphas[j] = alpha
        self.alpha, self._last_step = alpha, last
        return alphas

    def _servo_targets(self) -> np.ndarray:
        """Send what was commanded and count the period's physics steps: the servos' target angles (substeps, n,
        6) rad over each, as the pulses held then (after lag and dead band) give them."""
        self._send_pending()
        targets = self._targets()
        out = np.empty((self.substeps, self.n, 6))
        for j in range(self.substeps):
            if self._update_held():
                targets = self._targets()
            out[j] = targets
            self._step_count += 1
        return out

    def _roll(self, origins: np.ndarray, rots: np.ndarray) -> None:
        """Advance the balls over the period's physics steps on the plate, whose frames, origins (s + 2, n, 3) and
        rotations (s + 2, n, 3, 3), run from a physics step before the period to its end.

        Everything that depends on the plate alone is found for all s steps at once. Along the plate's axes
        t = (x̂, ŷ) the ball's acceleration is then linear in its position and velocity:
        ``tᵀ(g − a_O − β r Ω̇ × n − (R₊ − 2R + R₋)/h² q) / (1 + β) − (2 + β)/(1 + β) (Ω·n) (−v_y, v_x)``,
        with q the ball's centre in the plate frame: the second difference of the plate point under the ball is
        a_O + (R₊ − 2R + R₋)/h² q, and the Coriolis term Ω × t v projects to (Ω·n) (−v_y, v_x). The spin term
        β r σ × (Ω × n) lies along n and drops out."""
        h = 1.0 / self.physics_hz
        s, n = len(origins) - 2, self.n
        beta, radius = self._beta, self._radius
        w = _relative_rotation_vector(rots[1:].reshape(-1, 3, 3), rots[:-1].reshape(-1, 3, 3)).reshape(s + 1, n, 3) / h
        omega, omega_dot = 0.5 * (w[:-1] + w[1:]), (w[1:] - w[:-1]) / h  # Ω and Ω̇ at each step, from the half steps
        now = rots[1:-1]
        normal, tangent = now[..., 2], now[..., :2]
        accel_origin = (origins[2:] - 2.0 * origins[1:-1] + origins[:-2]) / h**2
        accel_rot = (rots[2:] - 2.0 * rots[1:-1] + rots[:-2]) / h**2
        drive = (np.array([0.0, 0.0, -GRAVITY]) - accel_origin - accel_rot[..., 2] * (self.plate_top + radius)[:, None]
                 - (beta * radius)[:, None] * _cross(omega_dot, normal))  # fmt: skip
        scale = 1.0 / (1.0 + beta)
        push = np.einsum("snki,snk->sni", tangent, drive) * scale[:, None]
        stiffness = np.einsum("snki,snkj->snij", tangent, accel_rot[..., :2]) * scale[:, None, None]
        spin = np.einsum("snk,snk->sn", omega, normal) * ((2.0 + beta) * scale)
        xy, v = self.ball_xy, self.ball_velocity
        for j in range(s):
            accel = push[j] - np.einsum("nij,nj->ni", stiffness[j], xy)
            accel[:, 0] += spin[j] * v[:, 1]
            accel[:, 1] -= spin[j] * v[:, 0]
            v = v + accel * h
            xy = xy + v * h
        self.ball_xy, self.ball_velocity = xy, v


class BatchedPlatform:
    """One platform of a :class:`BatchedSim` as a :class:`~stewart_gym.sim.PhysicsBackend`, so that an env runs
    on it unchanged: ``gym.make(id, backend="batched")`` (a simulator of its own, which :meth:`step` advances),
    or one of the N envs of the batched vector env (a shared simulator, which the vector env advances for all
    of them at once: then :meth:`step` only marks this platform's period as asked for).

    The reduced model carries no load on its servos, so a plate load (:meth:`set_plate_load`) is kept but does not
    move the plate (:attr:`models_plate_load` is False), and the plate friction is not modelled (the ball always
    rolls).
    """

    #: the reduced model draws nothing: no frames (the env then offers no render mode), no camera images
    renders_frames = renders_camera = False
    #: whether :meth:`set_plate_load` changes the motion (the reduced model carries no load on its servos: no)
    models_plate_load = False

    def __init__(self, sim: BatchedSim, index: int = 0, *, owns_steps: bool = True) -> None:
        self.batch, self.index, self.owns_steps = sim, int(index), owns_steps
        self.geometry, self.calibration = sim.geometry, sim.calibration
        self.physics_hz, self.control_hz, self.substeps, self.dt = sim.physics_hz, sim.control_hz, sim.substeps, sim.dt
        self.plate_half_extent, self.plate_top = sim.plate_half_extent, sim.plate_top
        self.has_ball, self.render_mode = True, None
        self._closed = False

    @property
    def servo_spec(self) -> ServoSpec:
        """This platform's servos (this episode's)."""
        return self.batch.servo_specs[self.index]

    @property
    def ball_spec(self) -> BallSpec:
        """This platform's ball (this episode's)."""
        return self.batch.ball_specs[self.index]

    @property
    def time(self) -> float:
        """s of simulated time since this platform's last reset."""
        return self.batch.platform_time(self.index)

    @property
    def closed(self) -> bool:
        return self._closed

    def reset(self, *, servo_spec: ServoSpec | None = None, ball_spec: BallSpec | None = None,
              plate_friction: float | None = None, plate_load: Any = None) -> None:  # fmt: skip
        """Home, servos at neutral, ball at rest at the centre, and the plate load ``plate_load`` (none by default);
        the episode's servos and ball where given, else the last episode's."""
        self._closed = False
        self.batch.reset_platforms(np.array([self.index]), [servo_spec or self.servo_spec],
                                   [ball_spec or self.ball_spec], [plate_load])  # fmt: skip

    def command(self, pulse_widths_us: np.ndarray) -> np.ndarray:
        return self.batch.command_one(self.index, pulse_widths_us)

    def step(self) -> None:
        """Advance one control period (a simulator of its own); in a shared one the vector env advances all."""
        if self.owns_steps:
            self.batch.step()

    def held_pulses(self) -> np.ndarray:
        return self.batch.held_pulses()[self.index]

    def place_ball(self, xy: np.ndarray, velocity_xy: Any = (0.0, 0.0)) -> None:
        self.batch.ball_xy[self.index] = np.asarray(xy, dtype=np.float64)[:2]
        self.batch.ball_velocity[self.index] = np.asarray(velocity_xy, dtype=np.float64)[:2]

    def ball_position(self) -> tuple[float, float, float]:
        i = self.index
        x, y = self.batch.ball_xy[i]
        return float(x), float(y), float(self.plate_top + self.batch.ball_radius[i])

    def ball_state(self) -> tuple[np.ndarray, np.ndarray]:
        vx, vy = self.batch.ball_velocity[self.index]
        return np.array(self.ball_position()), np.array([vx, vy, 0.0])

    def push_ball(self, impulse_xy: tuple[float, float]) -> None:
        self.batch.push(self.index, impulse_xy)

    def set_plate_load(self, load: Any) -> None:
        self.batch.plate_loads[self.index] = load

    def platform_pose(self) -> np.ndarray:
        return self.batch.platform_pose()[self.index]

    def render(self) -> None:
        return None

    def camera_image(self, camera: Any, markers: Any = None, ball_rgb: Any = None) -> np.ndarray:
        raise NotImplementedError("the batched simulator does not render camera images; use the PyBullet backend")

    def close(self) -> None:
        self._closed = True

    def __enter__(self) -> BatchedPlatform:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
