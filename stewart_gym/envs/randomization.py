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
from stewart_gym.sim.twin import TWIN_FIELDS, Twin

__all__ = ["FIRST_DRAWS", "POSITIVE_RANGES", "TWIN_WIDTH_FLOOR", "EpisodeParams", "RandomizationRanges", "draw_count",
           "polar"]

#: The uniform draws of an episode's parameters before its sensor's (:meth:`EpisodeParams.from_draws`): the ball's
#: radius, mass and rolling friction, the control latency, the servos' speed, their six trims and their dead band.
FIRST_DRAWS = 12


def draw_count(sensor: TouchPanelSpec | CameraSpec) -> int:
    """How many uniform draws an episode's parameters take around ``sensor`` (a touch panel or one camera):
    :data:`FIRST_DRAWS`, the sensor's two or three, and the plate load's three and the plate friction. (From a
    tuple of cameras, the one drawn: :meth:`EpisodeParams.sample` draws it between the first draws and the rest.)"""
    if not isinstance(sensor, (TouchPanelSpec, CameraSpec)):
        raise ConfigError(f"randomize draws an episode's sensor around a touch panel or a camera, not a "
                          f"{type(sensor).__name__}: make the env with randomize=False, or add the sensor's draws to "
                          "draw_count and EpisodeParams.from_draws in stewart_gym/envs/randomization.py (docs: Add a "
                          "ball sensor)")  # fmt: skip
    return FIRST_DRAWS + (2 if isinstance(sensor, TouchPanelSpec) else 3) + 4


#: The ranges of :class:`RandomizationRanges` whose low end must be above 0 (the others' at least 0).
POSITIVE_RANGES = ("ball_mass_scale", "ball_radius_scale", "servo_speed_scale", "plate_friction")


@dataclass(frozen=True)
class RandomizationRanges:
    """Ranges drawn uniformly once per episode (``randomize=True``).

    Multiplicative ranges scale the nominal value; the others are absolute. Every range is [lo, hi] with
    0 ≤ lo ≤ hi, and 0 < lo for the ball's scales, the servos' speed and the plate's friction
    (:data:`POSITIVE_RANGES`).
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
            positive = f.name in POSITIVE_RANGES  # a scale of 0 or less is no ball, no servo, no friction
            if not ok or (items[0] > items[1] or (items[0] <= 0 if positive else items[0] < 0) if pair
                          else items[0] < 0):  # fmt: skip
                want = (("[lo, hi] with finite 0 < lo ≤ hi" if positive else "[lo, hi] with finite 0 ≤ lo ≤ hi")
                        if pair else "a finite number ≥ 0")  # fmt: skip
                raise ConfigError(f"randomization.{f.name} must be {want}, got {value!r}")
            object.__setattr__(self, f.name, (float(items[0]), float(items[1])) if pair else float(items[0]))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> RandomizationRanges:
        """The defaults with some fields replaced, e.g. from a YAML ``env_kwargs: {randomization: {...}}``; a
        range is ``[lo, hi]`` (finite, 0 ≤ lo ≤ hi; 0 < lo for :data:`POSITIVE_RANGES`), a single value a finite
        number ≥ 0 (:meth:`__post_init__`). Raises
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
        cameras: one of them, drawn uniformly, then varied).

        The draws come from one generator call, ``rng.random(k)`` (:func:`draw_count`), at a seventh of the cost
        of a ``rng.uniform(low, high)`` call per draw, and are that call's numbers (:meth:`from_draws`). From a
        tuple of cameras, the first :data:`FIRST_DRAWS` come first, then the camera's draw (``rng.integers``), then
        the rest: the order the ranges' docs give."""
        if isinstance(sensor, tuple):
            first = rng.random(FIRST_DRAWS)
            sensor = sensor[int(rng.integers(len(sensor)))]
            draws = np.concatenate([first, rng.random(draw_count(sensor) - FIRST_DRAWS)])
        else:
            draws = rng.random(draw_count(sensor))
        return cls.from_draws(draws[None], ranges, ball, servo, sensor)[0]

    @classmethod
    def from_draws(cls, draws: np.ndarray, ranges: RandomizationRanges, ball: BallSpec, servo: ServoSpec,
                   sensor: TouchPanelSpec | CameraSpec) -> list[EpisodeParams]:  # fmt: skip
        """The episodes of rows of uniform draws in [0, 1) (m × :func:`draw_count` of ``sensor``), around the
        nominal ``ball``, ``servo`` and ``sensor``, in one pass of array arithmetic: the batched vector env's copies
        that reset together (:meth:`StewartBallEnv.draw_episodes
        <stewart_gym.envs.ball_env.StewartBallEnv.draw_episodes>`), and one episode's :meth:`sample`.

        A row's draws are, in order: the ball's radius, mass and rolling friction, the control latency, the servos'
        speed, their six trims and their dead band (:data:`FIRST_DRAWS`); then the sensor's two (a touch panel:
        noise, latency) or three (a camera: latency, noise, misses), the plate load's angle, distance and mass, and
        the plate friction. Each number is low + (high − low) · d of its range, which is NumPy's ``rng.uniform(low,
        high)`` from the same generator state to the last bit where NumPy rounds that product and sum apart
        (x86-64, Linux arm64), and within one rounding where it fuses them (macOS arm64)
        (``tests/envs/test_randomization.py``). The arithmetic is IEEE's + − × and √ on float64 either way, and the
        radius's rounding, cosine and sine are Python's, so a row gives the same episode alone or among others."""
        draw_count(sensor)  # a touch panel or one camera, else the ConfigError that says what to do
        r = ranges
        panel = isinstance(sensor, TouchPanelSpec)
        measured = ((r.sensor_noise_mm, r.sensor_latency_s) if panel
                    else (r.camera_latency_scale, r.camera_noise_scale, r.camera_miss_scale))  # fmt: skip
        trim = (-r.servo_trim_us, r.servo_trim_us)
        bounds = np.array([r.ball_radius_scale, r.ball_mass_scale, r.ball_rolling_friction, r.control_latency_s,
                           r.servo_speed_scale, *[trim] * 6, r.servo_deadband_us, *measured, (0.0, 2 * math.pi),
                           (0.0, 1.0), r.plate_load_kg, r.plate_friction])  # fmt: skip
        if draws.ndim != 2 or draws.shape[1] != len(bounds):
            raise ValueError(f"from_draws: expected rows of {len(bounds)} draws, got an array of shape {draws.shape}")
        low, high = bounds[:, 0], bounds[:, 1]
        values = low + (high - low) * draws
        radii = (ball.radius * values[:, 0]).tolist()
        masses, rolling = (ball.mass * values[:, 1]).tolist(), values[:, 2].tolist()
        lags, speeds = (servo.lag_s + values[:, 3]).tolist(), (servo.max_speed * values[:, 4]).tolist()
        trims, deadbands = values[:, 5:11].tolist(), values[:, 11].tolist()
        k = FIRST_DRAWS + len(measured)  # the load's and the plate's draws follow the sensor's
        if panel:
            sensors = values[:, FIRST_DRAWS:k].tolist()
        else:
            scales = values[:, FIRST_DRAWS:k]
            sensors = np.stack([sensor.latency_s * scales[:, 0], sensor.centroid_noise_px * scales[:, 1],
                                np.minimum(0.5, sensor.miss_rate * scales[:, 2])], axis=1).tolist()  # fmt: skip
        offsets = polar(r.plate_load_radius * np.sqrt(values[:, k + 1]), values[:, k])  # the loads' (x, y)
        loads, frictions = values[:, k + 2].tolist(), values[:, k + 3].tolist()
        out = []
        for j, measures in enumerate(sensors):
            ball_ep = _replaced(ball, radius=round(radii[j], 4), mass=masses[j], rolling_friction=rolling[j])
            servo_ep = _replaced(servo, max_speed=speeds[j], trim_error_us=tuple(trims[j]), deadband_us=deadbands[j],
                                 lag_s=lags[j])  # fmt: skip
            if panel:
                sensor_ep: TouchPanelSpec | CameraSpec = TouchPanelSpec(noise_mm=measures[0], rate_hz=sensor.rate_hz,
                                                                        latency_s=measures[1])  # fmt: skip
            else:
                sensor_ep = _replaced(sensor, latency_s=measures[0], centroid_noise_px=measures[1],
                                      miss_rate=measures[2])  # fmt: skip
            load = (loads[j], np.array([offsets[j, 0], offsets[j, 1], 0.012]))
            out.append(cls(ball_ep, servo_ep, sensor_ep, frictions[j], load))
        return out

    @classmethod
    def from_twin(cls, twin: Twin, ball: BallSpec, servo: ServoSpec, sensor: TouchPanelSpec | CameraSpec | tuple,
                  rng: np.random.Generator | None = None,
                  ranges: RandomizationRanges | None = None) -> EpisodeParams:  # fmt: skip
        """The platform ``twin`` describes, from the nominal ``ball``, ``servo`` and ``sensor``. With ``rng``, each
        value is drawn around the twin's (:data:`TWIN_WIDTH_FLOOR`; an undetermined ball or plate key from
        ``ranges``, the ball's scales as factors of the twin's: a ping-pong ball's twin draws ping-pong balls). The
        ball is a thin shell where the twin says so (or the nominal ball is one).

        A key the twin's file leaves out (:attr:`Twin.omitted <stewart_gym.sim.twin.Twin.omitted>`) is the nominal
        ``ball``'s, ``servo``'s or ``sensor``'s own, or with ``rng`` drawn from ``ranges`` as :meth:`sample` draws
        it: a twin of the ball alone leaves the servos, the sensor and the plate as randomised as without a twin.

        The twin's ``[sensor]`` is the touch panel's; a camera keeps its own latency and noise (a tuple of
        cameras: one of them, drawn uniformly with ``rng``, else the first)."""
        ranges = ranges or RandomizationRanges()
        undetermined, omitted = set(twin.undetermined), set(twin.omitted)
        panel = sensor if isinstance(sensor, TouchPanelSpec) else TouchPanelSpec()
        # a left-out key: the nominal's own value, and the range it is drawn from (ms for the latencies)
        own = {"servos.deadband_us": servo.deadband_us, "ball.rolling_friction": ball.rolling_friction,
               "sensor.noise_mm": panel.noise_mm, "sensor.latency_ms": panel.latency_s * 1e3}  # fmt: skip
        drawn_from = {
            "ball.mass_scale": ranges.ball_mass_scale, "ball.radius_scale": ranges.ball_radius_scale,
            "ball.rolling_friction": ranges.ball_rolling_friction, "plate.friction": ranges.plate_friction,
            "plate.load_kg": ranges.plate_load_kg, "servos.speed_scale": ranges.servo_speed_scale,
            "servos.deadband_us": ranges.servo_deadband_us,
            "servos.latency_ms": tuple(1e3 * v for v in ranges.control_latency_s),
            "sensor.noise_mm": ranges.sensor_noise_mm,
            "sensor.latency_ms": tuple(1e3 * v for v in ranges.sensor_latency_s),
        }  # fmt: skip

        def value(name: str, lo: float, hi: float) -> float:
            v = float(twin[name])
            if name in omitted:
                return own.get(name, v) if rng is None else float(rng.uniform(*drawn_from[name]))
            if rng is None:
                return v
            if name in undetermined and name.startswith(("ball.", "plate.")):
                drawn = float(rng.uniform(*drawn_from[name]))
                return float(np.clip(v * drawn, lo, hi)) if name.endswith("_scale") else drawn
            w = max(2.0 * twin.sigma.get(name, 0.0), TWIN_WIDTH_FLOOR[name])
            return float(np.clip(rng.uniform(v - w, v + w), lo, hi))

        mass = value("ball.mass_scale", *TWIN_FIELDS[("ball", "mass_scale")][1:3])
        radius = value("ball.radius_scale", *TWIN_FIELDS[("ball", "radius_scale")][1:3])
        ball_ep = replace(ball, radius=round(ball.radius * radius, 5), mass=ball.mass * mass,
                          rolling_friction=value("ball.rolling_friction", 0.0, 1e-3),
                          hollow=ball.hollow or bool(twin["ball.hollow"]))  # fmt: skip
        trim = np.asarray(twin["servos.trim_us"], dtype=float)
        if "servos.trim_us" in omitted:
            trim = (np.asarray(servo.trim_error_us, dtype=float) if rng is None
                    else rng.uniform(-ranges.servo_trim_us, ranges.servo_trim_us, 6))  # fmt: skip
        elif rng is not None:
            w = max(2.0 * twin.sigma.get("servos.trim_us", 0.0), TWIN_WIDTH_FLOOR["servos.trim_us"])
            trim = np.clip(trim + rng.uniform(-w, w, 6), -200.0, 200.0)  # within a twin's trims, as the others
        servo_ep = replace(servo, max_speed=servo.max_speed * value("servos.speed_scale", 0.1, 5.0),
                           deadband_us=value("servos.deadband_us", 0.0, 50.0), trim_error_us=tuple(trim),
                           lag_s=servo.lag_s + value("servos.latency_ms", 0.0, 200.0) / 1e3)  # fmt: skip
        if isinstance(sensor, tuple):
            sensor = sensor[int(rng.integers(len(sensor)))] if rng is not None else sensor[0]
        sensor_ep: TouchPanelSpec | CameraSpec = sensor
        if isinstance(sensor, TouchPanelSpec):
            sensor_ep = TouchPanelSpec(noise_mm=value("sensor.noise_mm", 0.0, 20.0), rate_hz=sensor.rate_hz,
                                       latency_s=value("sensor.latency_ms", 0.0, 300.0) / 1e3)  # fmt: skip
        load_kg = value("plate.load_kg", *TWIN_FIELDS[("plate", "load_kg")][1:3])
        load = (load_kg, np.array([0.0, 0.0, 0.012])) if load_kg > 0 else None
        return cls(ball_ep, servo_ep, sensor_ep, value("plate.friction", *TWIN_FIELDS[("plate", "friction")][1:3]), load)


def polar(radii: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(m, 2): each (r cos a, r sin a) of ``radii`` and ``angles`` (m,), with Python's cosine and sine, which give the
    same bits on every machine (NumPy's SIMD ones may not)."""
    return np.array([(r * math.cos(a), r * math.sin(a)) for r, a in zip(radii.tolist(), angles.tolist())],
                    dtype=np.float64).reshape(-1, 2)  # fmt: skip


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
