"""Servo calibration: servo angles ↔ pulse widths (source 000, eqs 13/14).

``W_i = W0_i + d_i · (α_i − α0_i) · r_i``

* ``W0_i`` (µs): the pulse that holds servo i at home (nominally 1500 µs plus a
  per-servo trim, since real builds differ),
* ``d_i`` = ±1: mounting direction; by default (+1, −1, +1, −1, +1, −1) because
  odd servos are mounted mirrored,
* ``α0_i`` (rad): the servo angle at home (eq. 12),
* ``r_i`` (µs/rad): 1600/π by default (400 µs per 45°).

Each channel also has pulse limits ``[min_us, max_us]``. The same object serves
the simulator and real hardware. A pulse outside the limits is an error unless
the caller asks explicitly for clipping or NaN.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np

from stewart_gym.errors import ConfigError, StewartGymError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import pulses_one
from stewart_gym.presets import load_geometry
from stewart_gym.tomlio import read_toml

__all__ = ["HARDWARE_FIELDS", "LINEAR_FIELDS", "LINEAR_SERVO_FIELDS", "PULSE_LIMITS_US", "ROTARY_FIELDS",
           "ROTARY_SERVO_FIELDS", "DEFAULT_DIRECTIONS", "DEFAULT_US_PER_RAD", "CalibrationError", "PulseRangeError",
           "ServoCalibration", "hardware_settings"]

#: 400 µs per 45° (source 000).
DEFAULT_US_PER_RAD = 1600.0 / math.pi
#: Odd servos mounted mirrored (source 000, eqs 13/14).
DEFAULT_DIRECTIONS = (1, -1, 1, -1, 1, -1)

#: The keys of a calibration file (TOML): top level and each ``[[servo]]`` table, for rotary servos and for
#: linear actuators, and its ``[hardware]`` table.
ROTARY_FIELDS = ("geometry", "geometry_sha256", "actuator", "neutral_us", "us_per_rad", "us_per_degree", "servo",
                 "hardware")  # fmt: skip
ROTARY_SERVO_FIELDS = ("channel", "trim_us", "direction", "min_us", "max_us", "home_angle_deg")
LINEAR_FIELDS = ("geometry", "geometry_sha256", "actuator", "retracted_us", "extended_us", "servo", "hardware")
LINEAR_SERVO_FIELDS = ("channel", "trim_us", "min_us", "max_us", "home_length_mm")
HARDWARE_FIELDS = ("port", "protocol", "baudrate")

OutOfRange = Literal["raise", "clip", "nan"]


class CalibrationError(ConfigError):
    """A calibration description is malformed; the message names the field."""


class PulseRangeError(StewartGymError, ValueError):
    """A pulse width falls outside its channel's limits (or is not finite)."""


def _vec6(key: str, value: Any) -> np.ndarray:
    try:
        arr = np.array(np.broadcast_to(np.asarray(value, dtype=np.float64), (6,)))
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{key}: expected a number or 6 numbers ({exc})") from None
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{key}: contains non-finite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class ServoCalibration:
    """Per-channel pulse-width mapping of six servos: W = W0 + d·r·(q − q0), q the actuator's position.

    For rotary servos q is the horn angle α (rad); for RC linear actuators
    (``actuator="linear"``, Actuonix-style: the pulse maps linearly onto the
    stroke) q is the anchor-to-anchor leg length (m), and ``home_angle`` and
    ``us_per_rad`` hold the home length (m) and µs per metre.

    Attributes (each shape (6,), indexed by leg/servo 0…5):
        neutral_us: W0_i, µs, the pulse at the home angle (trim included).
        direction: d_i, +1 or −1.
        home_angle: α0_i, rad (home leg length, m, for a linear actuator).
        us_per_rad: r_i, µs/rad (µs/m for a linear actuator), > 0.
        min_us, max_us: channel limits, µs.
        channels: controller channel of each servo (for hardware), ints.
    """

    neutral_us: np.ndarray
    direction: np.ndarray
    home_angle: np.ndarray
    us_per_rad: np.ndarray
    min_us: np.ndarray
    max_us: np.ndarray
    channels: tuple[int, ...] = (0, 1, 2, 3, 4, 5)
    actuator: str = "rotary"

    def __post_init__(self) -> None:
        if self.actuator not in ("rotary", "linear"):
            raise CalibrationError(f"actuator: 'rotary' or 'linear', got {self.actuator!r}")
        for key in ("neutral_us", "direction", "home_angle", "us_per_rad", "min_us", "max_us"):
            object.__setattr__(self, key, _vec6(key, getattr(self, key)))
        if not np.all(np.isin(self.direction, (-1.0, 1.0))):
            raise CalibrationError(f"direction: each must be +1 or -1, got {self.direction.tolist()}")
        if not np.all(self.us_per_rad > 0):
            raise CalibrationError(f"us_per_rad: must be positive, got {self.us_per_rad.tolist()}")
        if not np.all(self.min_us < self.max_us):
            raise CalibrationError(f"min_us/max_us: need min_us < max_us per channel, got {self.min_us.tolist()} / "
                                   f"{self.max_us.tolist()}")  # fmt: skip
        lo, hi = PULSE_LIMITS_US
        if np.any(self.min_us < lo) or np.any(self.max_us > hi):
            raise CalibrationError(f"min_us/max_us: each within {lo:g}–{hi:g} µs (no hobby servo takes a pulse beyond), "
                                   f"got {self.min_us.tolist()} / {self.max_us.tolist()}")  # fmt: skip
        bad = np.flatnonzero((self.neutral_us < self.min_us) | (self.neutral_us > self.max_us))
        if bad.size:
            raise CalibrationError(f"neutral_us: channels {bad.tolist()} have their neutral pulse outside [min_us, max_us]")
        given = self.channels
        if isinstance(given, (str, bytes)) or not all(isinstance(c, numbers.Integral) and not isinstance(c, bool)
                                                      for c in given):  # fmt: skip
            raise CalibrationError(f"channels: need 6 distinct whole channel numbers from 0, got {given!r}")
        channels = tuple(int(c) for c in given)
        if len(channels) != 6 or len(set(channels)) != 6 or min(channels) < 0:
            raise CalibrationError(f"channels: need 6 distinct non-negative channel numbers, got {list(self.channels)}")
        object.__setattr__(self, "channels", channels)

    # ------------------------------------------------------------ factories
    @classmethod
    def default(
        cls,
        geometry: PlatformGeometry | str = "servo-hexapod",
        *,
        neutral_us: float = 1500.0,
        trims_us: np.ndarray | float = 0.0,
        us_per_rad: float = DEFAULT_US_PER_RAD,
        direction: tuple[int, ...] = DEFAULT_DIRECTIONS,
        home_angles: np.ndarray | None = None,
    ) -> ServoCalibration:
        """Source 000's mapping for a rotary geometry.

        α0 is the IK servo angle at home (or ``home_angles``, rad, where given), and the channel limits are the
        pulses at the ends of the geometry's ``servo_angle_range`` (so they bound the same travel), within
        :data:`PULSE_LIMITS_US`: a travel wider than hobby servos' pulses express is bounded by those pulses
        instead.
        """
        geo = load_geometry(geometry)
        if not geo.is_rotary:
            return cls.linear(geo, trims_us=trims_us)
        home = _home_angles(geo) if home_angles is None else _vec6("home_angles", home_angles)
        w0 = neutral_us + _vec6("trims_us", trims_us)
        d = _vec6("direction", direction)
        lo, hi = geo.servo_angle_range  # type: ignore[misc]
        w_lo = w0 + d * (lo - home) * us_per_rad
        w_hi = w0 + d * (hi - home) * us_per_rad
        # Round outwards to 1e-6 µs so that the pulses at the travel's ends are inside.
        lo_us = np.maximum(np.floor(np.minimum(w_lo, w_hi) * 1e6) / 1e6, PULSE_LIMITS_US[0])
        hi_us = np.minimum(np.ceil(np.maximum(w_lo, w_hi) * 1e6) / 1e6, PULSE_LIMITS_US[1])
        return cls(w0, d, home, np.full(6, us_per_rad), lo_us, hi_us)

    @classmethod
    def linear(cls, geometry: PlatformGeometry | str, *, min_us: float = 1000.0, max_us: float = 2000.0,
               trims_us: np.ndarray | float = 0.0) -> ServoCalibration:  # fmt: skip
        """RC linear actuators: ``min_us`` fully retracted, ``max_us`` fully extended, linear in between.

        The geometry's ``leg_length_range`` is the stroke; the neutral pulse is
        the one of the home leg length.
        """
        from stewart_gym.kinematics import inverse_kinematics

        geo = load_geometry(geometry)
        if geo.is_rotary:
            raise CalibrationError(f"geometry: {geo.name!r} is rotary; use ServoCalibration.default")
        lo, hi = geo.leg_length_range  # type: ignore[misc]
        home = inverse_kinematics(geo, np.zeros(6)).leg_lengths
        rate = (max_us - min_us) / (hi - lo)
        w0 = min_us + rate * (home - lo) + _vec6("trims_us", trims_us)
        # the pulses of the stroke's ends, rounded outwards to 1e-6 µs so that both ends are inside the limits
        lo_us = np.floor((w0 + rate * (lo - home)) * 1e6) / 1e6
        hi_us = np.ceil((w0 + rate * (hi - home)) * 1e6) / 1e6
        return cls(w0, np.ones(6), home, np.full(6, rate), lo_us, hi_us, actuator="linear")

    @classmethod
    def from_dict(cls, data: dict[str, Any], geometry: PlatformGeometry | str | None = None,
                  *, source: str = "calibration") -> ServoCalibration:  # fmt: skip
        """Build from a mapping (TOML layout below); errors name the bad field.

        Top-level keys: ``geometry`` (preset name or TOML path; needed unless
        every servo gives ``home_angle_deg``), ``neutral_us`` (default 1500),
        ``us_per_rad`` (default 1600/π) or ``us_per_degree``, and six
        ``[[servo]]`` tables with optional ``channel``, ``trim_us``,
        ``direction``, ``min_us``, ``max_us``, ``home_angle_deg``. Missing
        channel limits default to those of :meth:`default`. An optional
        ``[hardware]`` table (``port``, ``protocol``, ``baudrate``) is for the
        deploy tools (:func:`hardware_settings`) and ignored here.

        A linear-actuator geometry (or ``actuator = "linear"``) reads the
        layout of :meth:`_linear_from_dict` instead.
        """
        if not isinstance(data.get("servo"), list) or len(data["servo"]) != 6 or not all(
                isinstance(s, dict) for s in data["servo"]):  # fmt: skip
            raise CalibrationError(f"servo: {source} needs exactly six [[servo]] tables")
        actuator = data.get("actuator")
        if actuator is not None and actuator not in ("rotary", "linear"):
            raise CalibrationError(f"actuator: 'rotary' or 'linear', got {actuator!r}")
        geo_spec = geometry if geometry is not None else data.get("geometry")
        geo = load_geometry(geo_spec) if geo_spec is not None else None
        if geo is not None and actuator is not None and (actuator == "linear") == geo.is_rotary:
            raise CalibrationError(f"actuator: {source} is for {actuator} actuators, but geometry {geo.name!r} is "
                                   f"{'rotary' if geo.is_rotary else 'linear'}")  # fmt: skip
        if actuator == "linear" or (geo is not None and not geo.is_rotary):
            if geo is None:
                raise CalibrationError("geometry: a linear-actuator calibration needs the geometry (its stroke)")
            return cls._linear_from_dict(data, geo, source)
        servos = _check_keys(data, set(ROTARY_FIELDS), set(ROTARY_SERVO_FIELDS), source)
        _limits(servos)
        if "us_per_rad" in data and "us_per_degree" in data:
            raise CalibrationError("us_per_rad: give us_per_rad or us_per_degree, not both")
        rate = _scalar("us_per_rad", data.get("us_per_rad", DEFAULT_US_PER_RAD))
        if "us_per_degree" in data:
            rate = _scalar("us_per_degree", data["us_per_degree"]) * 180.0 / math.pi
        lo_rate, hi_rate = US_PER_RAD_RANGE
        if not lo_rate <= rate <= hi_rate:
            key = "us_per_degree" if "us_per_degree" in data else "us_per_rad"
            scale, unit = (math.pi / 180.0, "µs/°") if key == "us_per_degree" else (1.0, "µs/rad")
            raise CalibrationError(f"{key}: the servos' gain, {lo_rate * scale:.4g}–{hi_rate * scale:.4g} {unit} (a "
                                   f"hobby servo's is about {DEFAULT_US_PER_RAD * scale:.4g}), got {data[key]!r}")
        neutral = _scalar("neutral_us", data.get("neutral_us", 1500.0))
        lo_us, hi_us = PULSE_LIMITS_US
        if not lo_us <= neutral <= hi_us:
            raise CalibrationError(f"neutral_us: the pulse at home, within {lo_us:g}–{hi_us:g} µs, got {neutral!r}")
        given = [i for i, s in enumerate(servos) if "home_angle_deg" in s]
        if geo is None and len(given) < 6:
            lacking = ", ".join(f"servo[{i}]" for i in range(6) if i not in given)
            raise CalibrationError(f"geometry: needed for the home angles of {lacking}, which give no "
                                   "home_angle_deg: name the geometry, or give home_angle_deg on every servo")  # fmt: skip
        geometry_home = _home_angles(geo) if geo is not None else np.zeros(6)
        home = np.radians(_per_servo(servos, "home_angle_deg", np.degrees(geometry_home)))  # where given, each
        direction = _per_servo(servos, "direction", list(DEFAULT_DIRECTIONS))
        wrong = [i for i, d in enumerate(direction) if d not in (-1.0, 1.0)]
        if wrong:
            raise CalibrationError(f"servo[{wrong[0]}].direction: +1 or -1 (the way the horn turns as the pulse grows), "
                                   f"got {servos[wrong[0]]['direction']!r}")  # fmt: skip
        far = [i for i, a in enumerate(np.degrees(home)) if abs(a) > 180.0]
        if far:
            raise CalibrationError(f"servo[{far[0]}].home_angle_deg: the horn's angle at home, within ±180°, got "
                                   f"{servos[far[0]]['home_angle_deg']!r}")  # fmt: skip
        trims = np.array(_per_servo(servos, "trim_us", 0.0))
        off = np.flatnonzero((neutral + trims < lo_us) | (neutral + trims > hi_us))
        if off.size:
            i = int(off[0])
            raise CalibrationError(f"servo[{i}].trim_us: neutral_us + trim_us, the servo's pulse at home, within "
                                   f"{lo_us:g}–{hi_us:g} µs, got {neutral:g} + {trims[i]:g}")  # fmt: skip
        base = cls.default(geo, neutral_us=neutral, trims_us=trims, us_per_rad=rate, home_angles=home,
                           direction=tuple(int(d) for d in direction)) if geo is not None else None  # fmt: skip
        return cls(
            neutral_us=neutral + trims,
            direction=np.array(direction),
            home_angle=home,
            us_per_rad=np.full(6, rate),
            min_us=np.array(_per_servo(servos, "min_us", None if base is None else base.min_us)),
            max_us=np.array(_per_servo(servos, "max_us", None if base is None else base.max_us)),
            channels=_channels(servos),
        )

    @classmethod
    def _linear_from_dict(cls, data: dict[str, Any], geo: PlatformGeometry, source: str) -> ServoCalibration:
        """RC linear actuators (``actuator = "linear"``).

        Top-level keys: ``geometry``, ``actuator``, ``retracted_us`` and
        ``extended_us`` (the pulses at the ends of the geometry's stroke,
        default 1000 and 2000; they set the µs per mm), and six ``[[servo]]``
        tables with optional ``channel``, ``trim_us`` (added to the pulse of the
        home leg length), ``min_us``, ``max_us`` (default: the stroke's ends,
        moved with the trim) and ``home_length_mm`` (default: the geometry's
        home leg length). ``[hardware]`` as for rotary servos.
        """
        servos = _check_keys(data, set(LINEAR_FIELDS), set(LINEAR_SERVO_FIELDS), source)
        _limits(servos)
        retracted = _scalar("retracted_us", data.get("retracted_us", 1000.0))
        extended = _scalar("extended_us", data.get("extended_us", 2000.0))
        if not 0 < retracted < extended:
            raise CalibrationError(f"retracted_us/extended_us: need 0 < retracted_us < extended_us, got {retracted!r}"
                                   f" / {extended!r}")  # fmt: skip
        trims = np.array(_per_servo(servos, "trim_us", 0.0))
        base = cls.linear(geo, min_us=retracted, max_us=extended, trims_us=trims)
        home = np.array(_per_servo(servos, "home_length_mm", base.home_angle * 1e3)) / 1e3
        lo = geo.leg_length_range[0]  # type: ignore[index]
        return cls(
            neutral_us=retracted + base.us_per_rad * (home - lo) + trims,
            direction=np.ones(6),
            home_angle=home,
            us_per_rad=base.us_per_rad,
            min_us=np.array(_per_servo(servos, "min_us", base.min_us)),
            max_us=np.array(_per_servo(servos, "max_us", base.max_us)),
            channels=_channels(servos),
            actuator="linear",
        )

    @classmethod
    def from_toml(cls, path: str | Path, geometry: PlatformGeometry | str | None = None) -> ServoCalibration:
        """Load a calibration TOML file (layout in :meth:`from_dict`). A relative ``geometry`` path inside the file
        is read from the file's own folder, as ``calibrate`` writes it."""
        data = read_toml(path, CalibrationError, "calibration file")
        declared = data.get("geometry")
        if isinstance(declared, str) and declared.endswith(".toml") and not Path(declared).is_absolute():
            data["geometry"] = str(Path(path).parent / declared)
        return cls.from_dict(data, geometry, source=str(path))

    def to_toml(self, geometry: PlatformGeometry | str | None = None) -> str:
        """TOML text that :meth:`from_toml` reads back to an equal calibration.

        A linear-actuator calibration needs its ``geometry`` (the stroke that
        ``retracted_us``/``extended_us`` refer to); it writes each servo's trim
        against the default linear mapping.
        """
        if np.ptp(self.us_per_rad) != 0:
            raise CalibrationError("us_per_rad: per-channel rates cannot be written to TOML")
        if self.actuator == "linear":
            return self._linear_toml(geometry)
        lines = [f"us_per_rad = {float(self.us_per_rad[0])!r}", "neutral_us = 1500.0"]
        for i in range(6):
            lines += [
                "",
                "[[servo]]",
                f"channel = {self.channels[i]}",
                f"trim_us = {_us(self.neutral_us[i] - 1500.0)!r}",
                f"direction = {int(self.direction[i])}",
                f"min_us = {_us(self.min_us[i])!r}",
                f"max_us = {_us(self.max_us[i])!r}",
                f"home_angle_deg = {math.degrees(float(self.home_angle[i]))!r}",
            ]
        return "\n".join(lines) + "\n"

    def _linear_toml(self, geometry: PlatformGeometry | str | None) -> str:
        if geometry is None:
            raise CalibrationError("geometry: writing a linear-actuator calibration needs its geometry (the stroke)")
        geo = load_geometry(geometry)
        if geo.is_rotary:
            raise CalibrationError(f"geometry: {geo.name!r} is rotary, but this calibration is for linear actuators")
        if not np.all(self.direction == 1):
            raise CalibrationError("direction: linear actuators extend with the pulse (direction +1)")
        lo, hi = geo.leg_length_range  # type: ignore[misc]
        # A common offset is a trim on every channel or a shifted retracted_us: both read back the same.
        retracted = 1000.0
        extended = retracted + float(self.us_per_rad[0]) * (hi - lo)
        untrimmed = retracted + self.us_per_rad * (self.home_angle - lo)
        lines = ['actuator = "linear"', f"retracted_us = {retracted!r}", f"extended_us = {extended!r}"]
        for i in range(6):
            lines += [
                "",
                "[[servo]]",
                f"channel = {self.channels[i]}",
                f"trim_us = {_us(self.neutral_us[i] - untrimmed[i])!r}",
                f"min_us = {_us(self.min_us[i])!r}",
                f"max_us = {_us(self.max_us[i])!r}",
                f"home_length_mm = {float(self.home_angle[i]) * 1e3!r}",
            ]
        return "\n".join(lines) + "\n"

    # -------------------------------------------------------------- mapping
    def pulse_widths(self, angles: np.ndarray, out_of_range: OutOfRange = "raise") -> np.ndarray:
        """Pulse widths (..., 6) µs for servo angles (..., 6) rad (eqs 13/14).

        ``out_of_range`` says what happens to a pulse outside ``[min_us,
        max_us]`` or a non-finite angle: ``"raise"`` (default) raises
        :class:`PulseRangeError`, ``"nan"`` returns NaN there, ``"clip"`` clamps
        finite pulses to the limits (NaN still raises).
        """
        if out_of_range not in ("raise", "clip", "nan"):
            raise ValueError(f"out_of_range must be 'raise', 'clip' or 'nan', got {out_of_range!r}")
        al = np.asarray(angles, dtype=np.float64)
        if al.shape[-1:] != (6,):
            raise ValueError(f"angles must have shape (..., 6), got {al.shape}")
        w = self.neutral_us + self.direction * self.us_per_rad * (al - self.home_angle)
        return self._limit(w, out_of_range)

    def in_range_one(self, pulse_widths: Sequence[float]) -> bool:
        """True if all six pulses (µs, Python floats) are within their channel's limits (False for NaN); raises
        ``ValueError`` for any number of pulses but six."""
        if len(pulse_widths) != 6:
            raise ValueError(f"pulse_widths must be 6 pulses, got {len(pulse_widths)}")
        for w, (_, _, _, low, high) in zip(pulse_widths, self.pulse_map):
            if not low <= w <= high:  # also False for NaN
                return False
        return True

    def angles_one(self, pulse_widths: Sequence[float]) -> list[float]:
        """The scalar twin of :meth:`angles`: six angles (rad) for six pulses (µs), as Python floats."""
        if len(pulse_widths) != 6:
            raise ValueError(f"pulse_widths must be 6 pulses, got {len(pulse_widths)}")
        return [h + (w - n) / k for w, (n, k, h, _, _) in zip(pulse_widths, self.pulse_map)]

    @cached_property
    def pulse_map(self) -> tuple[tuple[float, float, float, float, float], ...]:
        """Per servo (neutral µs, direction · µs/rad, home angle rad, min µs, max µs) as Python floats.

        Eqs 13/14 for scalar control loops: pulse = neutral + gain · (α − home),
        valid within [min, max] (:func:`servo_pulses_one`).
        """
        gain = self.direction * self.us_per_rad
        return tuple(zip(*(map(float, arr) for arr in (self.neutral_us, gain, self.home_angle, self.min_us, self.max_us))))

    def angles(self, pulse_widths: np.ndarray) -> np.ndarray:
        """Servo angles (..., 6) rad for pulse widths (..., 6) µs; the inverse of :meth:`pulse_widths`."""
        w = np.asarray(pulse_widths, dtype=np.float64)
        if w.shape[-1:] != (6,):
            raise ValueError(f"pulse_widths must have shape (..., 6), got {w.shape}")
        return self.home_angle + (w - self.neutral_us) / (self.direction * self.us_per_rad)

    def in_range(self, pulse_widths: np.ndarray) -> np.ndarray:
        """(..., 6) bool: finite and within each channel's limits."""
        w = np.asarray(pulse_widths, dtype=np.float64)
        if w.shape[-1:] != (6,):
            raise ValueError(f"pulse_widths must have shape (..., 6), got {w.shape}")
        return (w >= self.min_us) & (w <= self.max_us)

    def check(self, pulse_widths: np.ndarray) -> np.ndarray:
        """Return the pulses as float64 if all are within limits, else raise :class:`PulseRangeError`."""
        return self._limit(np.asarray(pulse_widths, dtype=np.float64), "raise")

    def _limit(self, w: np.ndarray, out_of_range: OutOfRange) -> np.ndarray:
        ok = self.in_range(w)
        if ok.all():
            return w
        if out_of_range == "nan":
            return np.where(ok, w, np.nan)
        if out_of_range == "clip" and np.all(np.isfinite(w)):
            return np.clip(w, self.min_us, self.max_us)
        flat_w = w.reshape(-1, 6)
        idx, ch = np.argwhere(~ok.reshape(-1, 6))[0]
        raise PulseRangeError(
            f"servo {ch}: pulse {flat_w[idx, ch]:.1f} µs outside [{self.min_us[ch]:.1f}, {self.max_us[ch]:.1f}] µs"
            f" (sample {idx}; {int((~ok).sum())} bad pulses in all)"
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ServoCalibration):
            return NotImplemented
        return self.channels == other.channels and all(
            np.allclose(getattr(self, k), getattr(other, k), rtol=0, atol=1e-9)
            for k in ("neutral_us", "direction", "home_angle", "us_per_rad", "min_us", "max_us")
        )

    __hash__ = None  # type: ignore[assignment]


def _us(v: float) -> float:
    """A pulse value for a file: rounded to 1e-6 µs, so float noise (1084.999999999) is not written."""
    return round(float(v), 6) + 0.0  # + 0.0 turns -0.0 into 0.0


def hardware_settings(path: str | Path) -> dict[str, Any]:
    """The ``[hardware]`` table of a calibration file (``port``, ``protocol``, ``baudrate``); {} if absent."""
    table = read_toml(path, CalibrationError, "calibration file").get("hardware", {})
    if not isinstance(table, dict):
        raise CalibrationError(f"{path}: hardware must be a table ([hardware] with port, protocol, baudrate), got "
                               f"{table!r}")  # fmt: skip
    unknown = sorted(set(table) - set(HARDWARE_FIELDS))
    if unknown:
        raise CalibrationError(f"{path}: hardware: unknown field(s) {unknown}; known: {sorted(HARDWARE_FIELDS)}")
    return dict(table)


def _check_keys(data: dict[str, Any], known_top: set[str], known_servo: set[str], source: str) -> list[dict]:
    """The six ``[[servo]]`` tables, after refusing unknown keys at either level."""
    unknown = sorted(set(data) - known_top)
    if unknown:
        raise CalibrationError(f"{source}: unknown field(s) {unknown}; known: {sorted(known_top)}")
    servos = data["servo"]
    for i, s in enumerate(servos):
        extra = sorted(set(s) - known_servo)
        if extra:
            raise CalibrationError(f"servo[{i}]: unknown field(s) {extra}; known: {sorted(known_servo)}")
    return servos


def _per_servo(servos: list[dict], key: str, default: Any) -> list[float]:
    """``key`` of each servo table as a number; ``default`` (a value or six) where absent; None default: required."""
    out = []
    for i, s in enumerate(servos):
        v = s.get(key, default[i] if isinstance(default, (list, tuple, np.ndarray)) else default)
        if v is None:
            raise CalibrationError(f"servo[{i}].{key}: missing")
        out.append(_scalar(f"servo[{i}].{key}", v))
    return out


#: µs/rad: the servos' gain a calibration file may give (a hobby servo's is about 509: 400 µs per 45°; beyond this
#: range a gain is a typing error, or in the wrong unit).
US_PER_RAD_RANGE = (50.0, 5000.0)

#: µs: the pulse limits a calibration file may give (hobby servos take about 500–2500 µs; beyond this a limit is a
#: typing error that would let a servo be driven past its end stop).
PULSE_LIMITS_US = (400.0, 2600.0)


def _channels(servos: list[dict]) -> tuple[int, ...]:
    """Each servo table's ``channel`` (default its index): a whole number."""
    out = []
    for i, s in enumerate(servos):
        c = s.get("channel", i)
        if isinstance(c, bool) or not isinstance(c, int) or c < 0:
            raise CalibrationError(f"servo[{i}].channel: the board's channel, a whole number from 0, got {c!r}")
        out.append(c)
    return tuple(out)


def _limits(servos: list[dict]) -> None:
    """Refuse a ``min_us`` or ``max_us`` given outside :data:`PULSE_LIMITS_US`."""
    lo, hi = PULSE_LIMITS_US
    for i, s in enumerate(servos):
        for key in ("min_us", "max_us"):
            if key in s and not lo <= _scalar(f"servo[{i}].{key}", s[key]) <= hi:
                raise CalibrationError(f"servo[{i}].{key}: {s[key]!r} µs is outside {lo:g}–{hi:g} µs, beyond any "
                                       "hobby servo's pulses: check the number (the servo's data sheet gives its "
                                       "range)")  # fmt: skip


def _scalar(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CalibrationError(f"{key}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise CalibrationError(f"{key}: must be finite, got {value!r}")
    return float(value)


def _home_angles(geometry: PlatformGeometry) -> np.ndarray:
    if not geometry.is_rotary:
        raise CalibrationError(f"geometry: {geometry.name!r} is linear; servo calibration needs a rotary platform")
    from stewart_gym.kinematics import inverse_kinematics

    alpha = inverse_kinematics(geometry, np.zeros(6)).servo_angles
    assert alpha is not None
    if not np.all(np.isfinite(alpha)):
        raise CalibrationError(f"geometry: home pose of {geometry.name!r} has no servo solution")
    return alpha


def servo_pulses_one(geometry: PlatformGeometry, calibration: ServoCalibration,
                     pose: Sequence[float]) -> list[float] | None:  # fmt: skip
    """Pulse widths (6 Python floats, µs) of one pose, or None if it cannot be commanded.

    IK and the calibration's eqs 13/14 in one scalar pass (~6 µs,
    :func:`stewart_gym.kinematics.pulses_one`), for control loops: None if any
    leg is unreachable, outside the servo angle range or would get a pulse
    outside its channel's limits. Agrees with
    ``calibration.pulse_widths(inverse_kinematics(geometry, pose).servo_angles)``.
    """
    return pulses_one(geometry, pose, calibration.pulse_map)  # rotary: servo angles; linear: leg lengths
