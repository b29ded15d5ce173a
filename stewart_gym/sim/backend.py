"""The physics-backend seam: what an environment needs from a physics engine, whichever engine it is.

:class:`PhysicsBackend` is a small Protocol; :class:`~stewart_gym.sim.StewartSim`
(PyBullet) is its implementation today, and a second engine implements the same
methods (``tests/test_backend_contract.py`` holds the checks every backend must
pass). Everything here is engine-neutral: :class:`BallSpec` describes the ball
in physical terms, poses and positions are in SI units in the platform frame,
and the servos are commanded in pulse widths (µs) through the shared
:class:`~stewart_gym.calibration.ServoCalibration`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from stewart_gym.calibration import ServoCalibration
    from stewart_gym.geometry import PlatformGeometry
    from stewart_gym.sim.servo_model import ServoSpec

__all__ = ["BallSpec", "PhysicsBackend", "PlateLoad", "SimulatorBase"]

#: An extra mass on the plate: (kg, (3,) offset of its centre in the platform frame, m).
PlateLoad = tuple[float, np.ndarray]


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

    @property
    def inertia(self) -> float:
        """kg·m², about any diameter."""
        return (2.0 / 3.0 if self.hollow else 2.0 / 5.0) * self.mass * self.radius**2


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


class SimulatorBase:
    """What every engine's simulator derives the same way from its geometry, mechanism and step counter.

    A subclass sets ``geometry``, ``mechanism`` (a :class:`~stewart_gym.sim.MechanismSpec`),
    ``physics_hz`` and ``_step_count`` (physics steps since the last reset), and defines ``close()``.
    """

    geometry: PlatformGeometry
    mechanism: Any
    physics_hz: int
    _step_count: int

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

    def close(self) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
