"""Domain randomisation: per-episode physical parameters drawn from documented ranges."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from stewart_gym.camera import CameraSpec
from stewart_gym.errors import ConfigError
from stewart_gym.sensing import TouchPanelSpec
from stewart_gym.sim import BallSpec, ServoSpec
from stewart_gym.sim.twin import Twin

__all__ = ["TWIN_WIDTH_FLOOR", "EpisodeParams", "RandomizationRanges"]


@dataclass(frozen=True)
class RandomizationRanges:
    """Ranges drawn uniformly once per episode (``randomize=True``).

    Multiplicative ranges scale the nominal value; the others are absolute.
    """

    ball_mass_scale: tuple[float, float] = (0.8, 1.2)
    ball_radius_scale: tuple[float, float] = (0.9, 1.1)  # radius rounded to 0.1 mm
    ball_rolling_friction: tuple[float, float] = (0.0, 5e-5)  # m
    plate_friction: tuple[float, float] = (0.4, 0.8)
    servo_speed_scale: tuple[float, float] = (0.8, 1.1)
    servo_trim_us: float = 15.0  # ± per servo
    servo_deadband_us: tuple[float, float] = (3.0, 8.0)
    sensor_noise_mm: tuple[float, float] = (0.5, 2.0)  # touch panel
    sensor_latency_s: tuple[float, float] = (0.005, 0.025)  # touch panel
    camera_latency_scale: tuple[float, float] = (0.5, 1.5)  # × the camera's exposure-to-output latency
    camera_noise_scale: tuple[float, float] = (0.5, 2.0)  # × its centroid noise (px)
    camera_miss_scale: tuple[float, float] = (0.0, 2.0)  # × its missed-detection rate
    control_latency_s: tuple[float, float] = (0.0, 0.015)  # added to the servo lag
    plate_load_kg: tuple[float, float] = (0.0, 0.05)
    plate_load_radius: float = 0.10  # m, offset of the load from the plate centre

    def __post_init__(self) -> None:
        """Every range two finite numbers, low ≤ high, and every single value (a trim's or a load's reach) a finite
        number ≥ 0, all as Python floats; else :class:`ConfigError` naming the field."""
        for f in fields(self):
            value = getattr(self, f.name)
            pair = isinstance(f.default, tuple)
            items = list(value) if pair and isinstance(value, (list, tuple)) else [value]
            ok = len(items) == (2 if pair else 1) and all(
                not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(v)
                for v in items)  # fmt: skip
            if not ok or (items[0] > items[1] if pair else items[0] < 0):
                want = "[lo, hi] with finite lo ≤ hi" if pair else "a finite number ≥ 0"
                raise ConfigError(f"randomization.{f.name} must be {want}, got {value!r}")
            object.__setattr__(self, f.name, (float(items[0]), float(items[1])) if pair else float(items[0]))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> RandomizationRanges:
        """The defaults with some fields replaced, e.g. from a YAML ``env_kwargs: {randomization: {...}}``; a
        range is ``[lo, hi]`` (finite, lo ≤ hi), a single value a finite number ≥ 0 (:meth:`__post_init__`). Raises
        :class:`ConfigError` naming the field."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"randomization: unknown field(s) {unknown}; fields: {sorted(known)}")
        return cls(**dict(values))  # checked field by field as it is made


#: ``randomize`` around a twin: each value is drawn uniformly within ± max(2 σ of its fit, this floor), where
#: σ is the ``[fit]`` uncertainty ``sysid`` wrote (0 for a twin written by hand). The ball's and the plate's keys
#: that the fit left undetermined are drawn from today's ranges (:class:`RandomizationRanges`) instead.
TWIN_WIDTH_FLOOR: dict[str, float] = {
    "servos.speed_scale": 0.05, "servos.deadband_us": 1.0, "servos.trim_us": 3.0, "servos.latency_ms": 3.0,
    "ball.mass_scale": 0.05, "ball.radius_scale": 0.02, "ball.rolling_friction": 5e-6, "plate.friction": 0.05,
    "plate.load_kg": 0.005, "sensor.noise_mm": 0.15, "sensor.latency_ms": 3.0,
}


@dataclass(frozen=True)
class EpisodeParams:
    """Physical parameters of one episode."""

    ball: BallSpec
    servo: ServoSpec
    sensor: TouchPanelSpec | CameraSpec
    plate_friction: float
    plate_load: tuple[float, np.ndarray] | None

    @classmethod
    def sample(cls, rng: np.random.Generator, ranges: RandomizationRanges, ball: BallSpec, servo: ServoSpec,
               sensor: TouchPanelSpec | CameraSpec | tuple[CameraSpec, ...]) -> EpisodeParams:  # fmt: skip
        """Draw one episode's parameters around the nominal ``ball``, ``servo`` and ``sensor`` (a tuple of
        cameras: one of them, drawn uniformly, then varied)."""
        r = ranges
        # The draws come from one generator call per run of them (:func:`_uniform`), at a seventh of the cost of
        # a ``rng.uniform(low, high)`` call per draw, and are that call's numbers (see :func:`_uniform`). First the
        # ball's radius, mass and rolling friction, the control latency, the servos' speed, their six trims and
        # their dead band; then (after the camera's draw, from a tuple of them) the sensor's two (a touch panel:
        # noise, latency) or three (a camera: latency, noise, misses), the plate load's angle, distance and mass,
        # and the plate friction. Without a camera to draw, both runs come from one call: the same numbers.
        trim = (-r.servo_trim_us, r.servo_trim_us)
        first = (r.ball_radius_scale, r.ball_mass_scale, r.ball_rolling_friction, r.control_latency_s,
                 r.servo_speed_scale, *[trim] * 6, r.servo_deadband_us)  # fmt: skip

        def then(spec: TouchPanelSpec | CameraSpec) -> tuple[tuple[float, float], ...]:
            measured = ((r.sensor_noise_mm, r.sensor_latency_s) if isinstance(spec, TouchPanelSpec)
                        else (r.camera_latency_scale, r.camera_noise_scale, r.camera_miss_scale))  # fmt: skip
            return (*measured, (0.0, 2 * math.pi), (0.0, 1.0), r.plate_load_kg, r.plate_friction)

        chosen = isinstance(sensor, tuple)
        values = _uniform(rng, first if chosen else first + then(sensor))
        radius_scale, mass_scale, rolling, control_latency, speed_scale, *trims, deadband = values[:len(first)]
        ball_ep = _replaced(ball, radius=round(ball.radius * radius_scale, 4), mass=ball.mass * mass_scale,
                            rolling_friction=rolling)  # fmt: skip
        servo_ep = _replaced(servo, max_speed=servo.max_speed * speed_scale, trim_error_us=tuple(trims),
                             deadband_us=deadband, lag_s=servo.lag_s + control_latency)  # fmt: skip
        if chosen:
            sensor = sensor[int(rng.integers(len(sensor)))]
            values = _uniform(rng, then(sensor))
        else:
            values = values[len(first):]
        panel = isinstance(sensor, TouchPanelSpec)
        *draws, angle, dist_squared, load_kg, friction = values
        if panel:
            sensor_ep: TouchPanelSpec | CameraSpec = TouchPanelSpec(noise_mm=draws[0], rate_hz=sensor.rate_hz,
                                                                    latency_s=draws[1])  # fmt: skip
        else:
            sensor_ep = _replaced(sensor, latency_s=sensor.latency_s * draws[0],
                                  centroid_noise_px=sensor.centroid_noise_px * draws[1],
                                  miss_rate=min(0.5, sensor.miss_rate * draws[2]))  # fmt: skip
        dist = r.plate_load_radius * math.sqrt(dist_squared)
        load = (load_kg, np.array([dist * math.cos(angle), dist * math.sin(angle), 0.012]))
        return cls(ball_ep, servo_ep, sensor_ep, friction, load)

    @classmethod
    def from_twin(cls, twin: Twin, ball: BallSpec, servo: ServoSpec, sensor: TouchPanelSpec | CameraSpec | tuple,
                  rng: np.random.Generator | None = None,
                  ranges: RandomizationRanges | None = None) -> EpisodeParams:  # fmt: skip
        """The platform ``twin`` describes, from the nominal ``ball``, ``servo`` and ``sensor``. With ``rng``, each
        value is drawn around the twin's (:data:`TWIN_WIDTH_FLOOR`; an undetermined ball or plate key from
        ``ranges``).

        The twin's ``[sensor]`` is the touch panel's; a camera keeps its own latency and noise (a tuple of
        cameras: one of them, drawn uniformly with ``rng``, else the first)."""
        ranges = ranges or RandomizationRanges()
        undetermined = set(twin.undetermined)

        def value(name: str, lo: float, hi: float, wide: tuple[float, float] | None = None) -> float:
            v = float(twin[name])
            if rng is None:
                return v
            if name in undetermined and wide is not None:
                return float(rng.uniform(*wide))
            w = max(2.0 * twin.sigma.get(name, 0.0), TWIN_WIDTH_FLOOR[name])
            return float(np.clip(rng.uniform(v - w, v + w), lo, hi))

        mass = value("ball.mass_scale", 0.1, 10.0, ranges.ball_mass_scale)
        radius = value("ball.radius_scale", 0.5, 2.0, ranges.ball_radius_scale)
        ball_ep = replace(ball, radius=round(ball.radius * radius, 5), mass=ball.mass * mass,
                          rolling_friction=value("ball.rolling_friction", 0.0, 1e-3, ranges.ball_rolling_friction))
        trim = np.asarray(twin["servos.trim_us"], dtype=float)
        if rng is not None:
            w = max(2.0 * twin.sigma.get("servos.trim_us", 0.0), TWIN_WIDTH_FLOOR["servos.trim_us"])
            trim = trim + rng.uniform(-w, w, 6)
        servo_ep = replace(servo, max_speed=servo.max_speed * value("servos.speed_scale", 0.1, 5.0),
                           deadband_us=value("servos.deadband_us", 0.0, 50.0), trim_error_us=tuple(trim),
                           lag_s=servo.lag_s + value("servos.latency_ms", 0.0, 200.0) / 1e3)  # fmt: skip
        if isinstance(sensor, tuple):
            sensor = sensor[int(rng.integers(len(sensor)))] if rng is not None else sensor[0]
        sensor_ep: TouchPanelSpec | CameraSpec = sensor
        if isinstance(sensor, TouchPanelSpec):
            sensor_ep = TouchPanelSpec(noise_mm=value("sensor.noise_mm", 0.0, 20.0), rate_hz=sensor.rate_hz,
                                       latency_s=value("sensor.latency_ms", 0.0, 300.0) / 1e3)  # fmt: skip
        load_kg = value("plate.load_kg", 0.0, 2.0, ranges.plate_load_kg)
        load = (load_kg, np.array([0.0, 0.0, 0.012])) if load_kg > 0 else None
        return cls(ball_ep, servo_ep, sensor_ep, value("plate.friction", 0.05, 2.0, ranges.plate_friction), load)


def _uniform(rng: np.random.Generator, ranges: tuple[tuple[float, float], ...]) -> list[float]:
    """One uniform draw within each (low, high) of ``ranges``, in order, from one ``rng.random(k)`` call: low +
    (high − low) · d, the same numbers on every machine. They are those of a ``rng.uniform(low, high)`` call for
    each, to the last bit where NumPy rounds that product and sum apart (x86-64, Linux arm64), and within one
    rounding where it fuses them (macOS arm64) (``tests/envs/test_randomization.py``)."""
    return [low + (high - low) * d for (low, high), d in zip(ranges, rng.random(len(ranges)).tolist())]


def _replaced(spec: Any, **changes: Any) -> Any:
    """``dataclasses.replace(spec, **changes)`` for a dataclass with a ``__dict__`` and no init-only fields: a copy
    with ``changes``, checked by its ``__post_init__``, at a sixth of ``replace``'s cost (which looks its fields up
    each time)."""
    new = object.__new__(type(spec))
    new.__dict__.update(spec.__dict__, **changes)  # (a frozen dataclass's fields are its __dict__)
    check = getattr(new, "__post_init__", None)
    if check is not None:
        check()
    return new
