"""The physics-backend seam: what an environment needs from a physics engine, whichever engine it is.

:class:`PhysicsBackend` is a small Protocol; :class:`~stewart_gym.sim.StewartSim`
(PyBullet) is its implementation today, and a second engine implements the same
methods (``tests/sim/test_backend_contract.py`` holds the checks every backend must
pass). Everything here is engine-neutral: :class:`BallSpec` describes the ball
in physical terms, poses and positions are in SI units in the platform frame,
and the servos are commanded in pulse widths (µs) through the shared
:class:`~stewart_gym.calibration.ServoCalibration`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from stewart_gym.checks import real_number
from stewart_gym.errors import ConfigError

if TYPE_CHECKING:
    from stewart_gym.calibration import ServoCalibration
    from stewart_gym.geometry import PlatformGeometry
    from stewart_gym.sim.servo_model import ServoSpec

__all__ = ["BallSpec", "PhysicsBackend", "PlateLoad", "SimulatorBase", "check_rates", "missing_members"]

#: An extra mass on the plate: (kg, (3,) offset of its centre in the platform frame, m).
PlateLoad = tuple[float, np.ndarray]


#: The number types :class:`BallSpec` checks with one chain of comparisons (others field by field).
_PLAIN_NUMBERS = frozenset({float, int, np.float64})


@dataclass(frozen=True)
class BallSpec:
    """The ball. Default: a 25.4 mm (1 in) solid steel ball, heavy enough for a resistive touch panel.

    Attributes:
        radius: m.
        mass: kg.
        hollow: True for a thin shell (I = 2/3 m r², e.g. a ping-pong ball:
            radius 0.02, mass 0.0027); False for a solid ball (I = 2/5 m r²).
        lateral_friction, rolling_friction, spinning_friction: PyBullet
            friction coefficients of the ball (rolling friction in m).
        restitution: bounciness, 0…1.
    """

    radius: float = 0.0127
    mass: float = 0.0668
    hollow: bool = False
    lateral_friction: float = 0.6
    rolling_friction: float = 1e-5
    spinning_friction: float = 1e-5
    restitution: float = 0.1

    def __post_init__(self) -> None:
        """Each field a finite number in its range (radius and mass above 0, the frictions at least 0, restitution
        0…1), ``hollow`` a bool; else :class:`~stewart_gym.errors.ConfigError` naming the field. (Plain floats are
        checked with one chain of comparisons: a vector env's resets make a ball per copy.)"""
        numbers = (self.radius, self.mass, self.lateral_friction, self.rolling_friction, self.spinning_friction,
                   self.restitution)  # fmt: skip
        if not (all(type(v) in _PLAIN_NUMBERS for v in numbers) and type(self.hollow) is bool
                and 0.0 < self.radius < math.inf and 0.0 < self.mass < math.inf
                and 0.0 <= self.lateral_friction < math.inf and 0.0 <= self.rolling_friction < math.inf
                and 0.0 <= self.spinning_friction < math.inf and 0.0 <= self.restitution <= 1.0):  # fmt: skip
            self._check_each()

    def _check_each(self) -> None:
        """Check field by field (:func:`~stewart_gym.checks.real_number`: a NumPy number passes, a bool, an array
        or text does not); raise :class:`~stewart_gym.errors.ConfigError` naming the first field that fails."""
        for key, positive in (("radius", True), ("mass", True), ("lateral_friction", False), ("rolling_friction", False),
                              ("spinning_friction", False), ("restitution", False)):  # fmt: skip
            real_number(f"BallSpec.{key}", getattr(self, key), low=0.0, low_open=positive,
                        high=1.0 if key == "restitution" else math.inf)  # fmt: skip
        if not isinstance(self.hollow, (bool, np.bool_)):
            raise ConfigError(f"BallSpec.hollow must be True or False, got {self.hollow!r}")

    @property
    def inertia(self) -> float:
        """kg·m², about any diameter."""
        return (2.0 / 3.0 if self.hollow else 2.0 / 5.0) * self.mass * self.radius**2


def check_rates(physics_hz: int, control_hz: int) -> None:
    """A :class:`~stewart_gym.errors.ConfigError` unless the physics rate is a positive multiple of the control
    rate (Hz): every simulator steps its physics a whole number of times per control period."""
    from stewart_gym.errors import ConfigError

    if control_hz <= 0 or physics_hz <= 0 or physics_hz % control_hz:
        raise ConfigError(f"physics_hz ({physics_hz}) must be a positive multiple of control_hz ({control_hz})")


@runtime_checkable
class PhysicsBackend(Protocol):
    """A simulated Stewart platform with a ball, as the environments use it.

    Attributes:
        geometry: The platform.
        calibration: The pulse mapping the servos obey.
        control_hz: Rate of :meth:`step`; ``dt`` = 1 / control_hz (s).
        plate_half_extent: m, half the plate's size along x and y (plate frame).
        plate_top: m, the plate surface's height above the platform frame origin.
    """

    geometry: PlatformGeometry
    calibration: ServoCalibration
    control_hz: int
    dt: float

    @property
    def plate_half_extent(self) -> tuple[float, float]: ...

    @property
    def plate_top(self) -> float: ...

    @property
    def time(self) -> float:
        """s since the last :meth:`reset`."""

    def reset(self, *, servo_spec: ServoSpec | None = None, ball_spec: BallSpec | None = None,
              plate_friction: float | None = None, plate_load: PlateLoad | None = None) -> None:  # fmt: skip
        """Home pose, servos at neutral, ball at rest at the centre; optional per-episode physics."""

    def command(self, pulse_widths_us: np.ndarray) -> np.ndarray:
        """Send six pulse widths (µs, within the calibration's limits); returns what the servos received."""

    def step(self) -> None:
        """Advance one control period."""

    def place_ball(self, xy: np.ndarray, velocity_xy: Sequence[float] = (0.0, 0.0)) -> None:
        """Put the ball on the plate at ``xy`` (m) rolling at ``velocity_xy`` (m/s), plate frame."""

    def ball_position(self) -> tuple[float, float, float]:
        """Ball centre (x, y, z) in the platform frame, m."""

    def ball_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ball position (3,) m and velocity (3,) m/s in the platform frame."""

    def push_ball(self, impulse_xy: tuple[float, float]) -> None:
        """An impulse (N·s) on the ball along the plate (plate frame)."""

    def set_plate_load(self, load: PlateLoad | None) -> None:
        """An extra mass on the plate from the next step on (None: none)."""

    def platform_pose(self) -> np.ndarray:
        """The plate's pose (6,) (x, y, z from home in m; roll, pitch, yaw in rad)."""

    def render(self) -> np.ndarray | None:
        """An RGB frame, or None."""

    def close(self) -> None:
        """Release the engine; safe to call twice."""


def missing_members(obj: object) -> list[str]:
    """The attributes and methods of :class:`PhysicsBackend` that ``obj`` lacks, by name (none: it is one)."""
    wanted = {*getattr(PhysicsBackend, "__annotations__", {}), *vars(PhysicsBackend)}
    return sorted(name for name in wanted if not name.startswith("_") and not hasattr(obj, name))


class SimulatorBase:
    """What every engine's simulator does the same way, so that each engine holds only its own engine code.

    * :meth:`_setup`: the constructor's checks (rates, render mode) and the attributes every backend has
      (geometry, calibration, rates, ball, servo model, mechanism, the hobby-servo model, the step counter);
    * :meth:`command`, :meth:`held_pulses`: pulses go through :class:`~stewart_gym.sim.servo_model.HobbyServos`;
    * :meth:`platform_pose` from the engine's :meth:`_plate_frame`;
    * the ball's rolling maths (:meth:`_rolling_velocity`, :meth:`_push_change`) and :meth:`set_plate_load`;
    * optional capabilities, declared: :attr:`renders_frames` says whether :meth:`render` gives frames,
      :attr:`renders_camera` whether :meth:`camera_image` works.

    A subclass calls :meth:`_setup`, builds its engine, and defines ``_plate_frame``, ``_apply_targets``,
    ``step``, ``reset``, the ball's state and ``close``.
    """

    geometry: PlatformGeometry
    calibration: ServoCalibration
    mechanism: Any
    physics_hz: int
    control_hz: int
    _step_count: int
    #: whether :meth:`render` gives RGB frames (an env's ``rgb_array`` render mode)
    renders_frames = True
    #: whether :meth:`camera_image` renders what a camera above the plate sees (an optional capability)
    renders_camera = False
    #: whether :meth:`set_plate_load` changes the motion (the servos' torque is modelled)
    models_plate_load = True

    def _setup(self, geometry: Any, calibration: ServoCalibration | None, physics_hz: int, control_hz: int, ball: bool,
               ball_spec: BallSpec | None, servo_spec: ServoSpec | None, mechanism: Any, render_mode: str | None,
               render_size: tuple[int, int], render_modes: tuple[str, ...]) -> None:  # fmt: skip
        """Check the options and set what every backend has; raises ``ValueError`` naming a bad option."""
        from stewart_gym.calibration import ServoCalibration
        from stewart_gym.presets import load_geometry
        from stewart_gym.sim.servo_model import LINEAR_ACTUATOR, HobbyServos, ServoSpec
        from stewart_gym.sim.urdf import MechanismSpec

        check_rates(physics_hz, control_hz)
        if render_mode is not None and render_mode not in render_modes:
            allowed = " or ".join(repr(m) for m in (None, *render_modes))
            raise ValueError(f"render_mode must be {allowed} for {type(self).__name__}, got {render_mode!r}")
        self.geometry = load_geometry(geometry)
        self.calibration = calibration or ServoCalibration.default(self.geometry)
        self.physics_hz, self.control_hz = int(physics_hz), int(control_hz)
        self.substeps = self.physics_hz // self.control_hz
        self.dt = 1.0 / self.control_hz
        self.has_ball = bool(ball)
        self.ball_spec = ball_spec or BallSpec()
        self.servo_spec = servo_spec or (ServoSpec() if self.geometry.is_rotary else LINEAR_ACTUATOR)
        self.mechanism = mechanism or MechanismSpec()
        self.render_mode = render_mode
        self.render_size = render_size
        self._servos = HobbyServos(self.servo_spec, self.calibration, 1.0 / self.physics_hz)
        self._plate_load: tuple[float, np.ndarray] | None = None
        self._step_count = 0
        self._closed = False

    # ------------------------------------------------------------ commanding
    def command(self, pulse_widths_us: np.ndarray) -> np.ndarray:
        """Send pulse widths (6,) µs to the servos; they take effect after the servo lag.

        Raises :class:`~stewart_gym.calibration.PulseRangeError` if any pulse is outside
        the calibration's channel limits (or not finite); nothing is sent then.
        Returns the pulses as the servos received them (quantised).
        """
        return self._servos.command(pulse_widths_us, self._step_count)

    def held_pulses(self) -> np.ndarray:
        """(6,) µs: the pulses the servos are acting on now (after lag and dead band)."""
        return self._servos.held_us

    def _new_servo_model(self, servo_spec: ServoSpec) -> None:
        """Use ``servo_spec`` from now on (a new episode's servos)."""
        from stewart_gym.sim.servo_model import HobbyServos

        self.servo_spec = servo_spec
        self._servos = HobbyServos(servo_spec, self.calibration, 1.0 / self.physics_hz)

    # ------------------------------------------------------------ state
    def _plate_frame(self) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - every subclass defines it
        """Platform frame in the world: origin (3,) m and rotation (3, 3)."""
        raise NotImplementedError

    def platform_pose(self) -> np.ndarray:
        """(6,) (x, y, z, roll, pitch, yaw) in m and rad, translation from home, as in the kinematics; NaN where the
        physics blew up."""
        from stewart_gym.kinematics import euler_from_matrix

        origin, rot = self._plate_frame()
        try:
            angles = euler_from_matrix(rot)
        except ValueError:
            if np.all(np.isfinite(rot)):
                raise
            return np.full(6, np.nan)
        return np.array([*(origin - self.geometry.home_position), *angles])

    def set_plate_load(self, load: PlateLoad | None) -> None:
        """Put an extra mass on the plate (or take it off) from the next ``step`` on."""
        self._plate_load = None if load is None else (float(load[0]), np.asarray(load[1], float))

    # --------------------------------------------------------------- ball
    def _require_ball(self) -> None:
        if not self.has_ball:
            raise RuntimeError(f"this {type(self).__name__} was built without a ball (ball=False)")

    def _rolling_velocity(self, velocity_xy: Sequence[float], rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World linear (3,) m/s and angular (3,) rad/s velocity of a ball rolling without slipping at
        ``velocity_xy`` (m/s, plate frame) on a plate turned by ``rot``: ω = n × v / r."""
        vel = rot @ np.array([velocity_xy[0], velocity_xy[1], 0.0])
        return vel, np.cross(rot[:, 2], vel) / self.ball_spec.radius

    def _push_change(self, impulse_xy: Sequence[float], rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The change of the ball's world velocity (3,) and angular velocity (3,) from an impulse ``impulse_xy``
        (N·s, plate frame) at its centre: Δv = J / m, and it keeps rolling, Δω = n × Δv / r."""
        dv = rot @ np.array([impulse_xy[0], impulse_xy[1], 0.0]) / self.ball_spec.mass
        return dv, np.cross(rot[:, 2], dv) / self.ball_spec.radius

    # --------------------------------------------------------- capabilities
    def camera_image(self, camera: Any, markers: Any = None, ball_rgb: tuple[float, float, float] = (1.0, 0.45, 0.0)
                     ) -> np.ndarray:  # fmt: skip
        """What a camera above the plate sees (where :attr:`renders_camera`); here: not this engine."""
        raise NotImplementedError(f"{type(self).__name__} does not render camera images (renders_camera is False); "
                                  "use the PyBullet backend for a camera")  # fmt: skip

    # ------------------------------------------------------------ geometry
    @property
    def plate_half_extent(self) -> tuple[float, float]:
        """m: half the plate's size along its x and y axes."""
        width, depth = self.geometry.plate_extent
        return (width / 2, depth / 2)

    @property
    def plate_top(self) -> float:
        """m: height of the plate's top surface above the platform frame origin."""
        return self.mechanism.plate_top

    @property
    def time(self) -> float:
        """s of simulated time since the last reset."""
        return self._step_count / self.physics_hz

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has released the engine."""
        return self._closed

    def close(self) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
