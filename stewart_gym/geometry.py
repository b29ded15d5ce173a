"""Platform geometry: where the joints of a Stewart platform are, in SI units.

A :class:`PlatformGeometry` is an immutable description of one build. Two kinds
exist:

* **rotary** (6-RSS): six servo shafts at ``base_anchors`` (b_i), each turning a
  horn of length ``horn_length`` (a) in a vertical plane at angle ``servo_beta``
  (β_i) to the x-axis; a rod of length ``rod_length`` (s) joins the horn tip to
  the platform anchor p_i. Actuator limits are ``servo_angle_range`` (α, rad,
  measured from the horizontal, eq. 9 of source 000).
* **linear** (6-UPS): six extensible legs from b_i to p_i. ``rod_length`` is the
  fixed (fully retracted) part of a leg, so the actuator stroke is
  ``|l_i| - rod_length``. Actuator limits are ``leg_length_range`` (m, the whole
  anchor-to-anchor length).

Frames: the base frame has z up and its origin in the base plane; the platform
frame is fixed to the plate, and at home it is the base frame lifted by
``home_height`` (h0). Anchors are in metres.

Geometries come from :func:`stewart_gym.presets.load_preset` or from a TOML file
(:func:`stewart_gym.presets.load_geometry`, :meth:`PlatformGeometry.from_toml`);
a malformed file raises :class:`GeometryError` naming the bad field.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from stewart_gym.errors import ConfigError
from stewart_gym.tomlio import read_toml

__all__ = [
    "GEOMETRY_FIELDS",
    "SYMMETRIC_FIELDS",
    "GeometryError",
    "PlatformGeometry",
    "home_height_eq10",
    "symmetric_layout",
]

#: m: where ``home_height`` is left out, eq. 10 gives one home height per leg and the geometry takes their mean; a
#: spread beyond this is warned about in one line. Anchors measured to ±0.1 mm (every coordinate) spread the
#: presets' legs by at most 0.4 mm; one anchor 2 mm too high or low spreads them by 2 mm.
HOME_HEIGHT_SPREAD_M = 1e-3
#: Degrees: the centres of the three pairs of a ``[symmetric]`` description, in the presets' anchor order.
SYMMETRIC_PAIR_CENTRES_DEG = (330.0, 90.0, 210.0)
#: The keys of a geometry file (TOML), top level.
GEOMETRY_FIELDS = ("name", "description", "length_unit", "angle_unit", "base_anchors", "platform_anchors",
                   "rod_length", "home_height", "horn_length", "servo_beta", "servo_angle_range", "leg_length_range",
                   "plate_size", "symmetric")  # fmt: skip
SYMMETRIC_FIELDS = ("base_radius", "base_pair_angle", "platform_radius", "platform_pair_angle")
#: m: no length of a build (an anchor's distance, a horn, a rod, the plate) may exceed this; a larger number is
#: a unit mistake (metres given as millimetres) or nonsense, and would make every later figure NaN.
MAX_LENGTH_M = 10.0
#: The longest geometry name, characters.
MAX_NAME_LENGTH = 100


class GeometryError(ConfigError):
    """A geometry description is malformed; the message names the field."""


def symmetric_layout(base_radius: float, base_pair_angle: float, platform_radius: float,
                     platform_pair_angle: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """(base anchors, platform anchors, servo β) of a platform built in three pairs, as the presets are: pairs
    centred at 330°, 90° and 210° (:data:`SYMMETRIC_PAIR_CENTRES_DEG`), the first of a pair at the centre minus
    half the pair angle; each horn perpendicular to its pair's centre line, pointing away from its partner
    (β = centre − 90° for the first, centre + 90° for the second). Radii in m, angles in rad; anchors at z = 0.
    Raises :class:`GeometryError` for a radius that is not a finite positive length, or a pair angle outside 0 to
    120° (2π/3 rad: wider, the pairs overlap; an angle in degrees by mistake is far outside)."""
    for key, radius in (("base_radius", base_radius), ("platform_radius", platform_radius)):
        _positive(key, radius)
    for key, angle in (("base_pair_angle", base_pair_angle), ("platform_pair_angle", platform_pair_angle)):
        if not 0.0 <= _scalar(key, angle) <= 2 * math.pi / 3:
            raise GeometryError(f"{key}: between 0 and 2π/3 rad (120°), got {angle!r}; the angles are in radians")
    centres = np.radians(SYMMETRIC_PAIR_CENTRES_DEG)

    def ring(radius: float, pair_angle: float) -> np.ndarray:
        angles = np.array([c + side * pair_angle / 2 for c in centres for side in (-1.0, 1.0)])
        return np.stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(6)], axis=1)

    beta = np.array([c + side * math.pi / 2 for c in centres for side in (-1.0, 1.0)])
    return ring(base_radius, base_pair_angle), ring(platform_radius, platform_pair_angle), beta


def _symmetric(table: Any, ls: float, ang: float, source: str) -> dict[str, float]:
    """The four fields of a ``[symmetric]`` table in m and rad, checked."""
    if not isinstance(table, dict):
        raise GeometryError(f"symmetric: a table of {', '.join(SYMMETRIC_FIELDS)} in {source}, got {table!r}")
    unknown = sorted(set(table) - set(SYMMETRIC_FIELDS))
    missing = [k for k in SYMMETRIC_FIELDS if k not in table]
    if unknown or missing:
        raise GeometryError(f"symmetric: {'unknown field(s) ' + str(unknown) if unknown else 'missing ' + str(missing)}"
                            f" in {source}; its fields are {list(SYMMETRIC_FIELDS)}")  # fmt: skip
    out = {}
    for key in SYMMETRIC_FIELDS:
        value = _scalar(f"symmetric.{key}", table[key])
        if key.endswith("radius"):
            _positive(f"symmetric.{key}", value)
            out[key] = value * ls
        else:
            out[key] = value * ang
            if not 0.0 < out[key] < 2 * math.pi / 3:
                raise GeometryError(f"symmetric.{key}: between 0 and 120° (the pairs may not overlap), got {value:g} "
                                    f"in the file's angle_unit ({math.degrees(out[key]):g}°); check angle_unit "
                                    '(angle_unit = "deg" for degrees)')  # fmt: skip
    return out


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)  # copy, so callers cannot mutate our data
    a.setflags(write=False)
    return a


def home_height_eq10(
    base_anchors: np.ndarray, platform_anchors: np.ndarray, horn_length: float, rod_length: float
) -> np.ndarray:
    """Home height of each leg by eq. 10 of source 000, shape (6,), metres.

    h0 = sqrt(s² + a² − (x_p − x_b)² − (y_p − y_b)²) − z_p + z_b, the height at
    which horn and rod are at right angles (|l|² = s² + a²). Source 000 takes
    z_b = 0; the + z_b term keeps the definition for servos mounted above the
    base plane. NaN where no such height exists.
    """
    b = np.asarray(base_anchors, dtype=float)
    p = np.asarray(platform_anchors, dtype=float)
    d2 = rod_length**2 + horn_length**2 - (p[:, 0] - b[:, 0]) ** 2 - (p[:, 1] - b[:, 1]) ** 2
    with np.errstate(invalid="ignore"):
        return np.sqrt(d2) - p[:, 2] + b[:, 2]


@dataclass(frozen=True, eq=False)
class PlatformGeometry:
    """Immutable description of a Stewart platform, SI units.

    Attributes:
        name: A short identifier.
        base_anchors: (6, 3) m. b_i: servo shaft centres (rotary) or lower leg
            joints (linear), base frame.
        platform_anchors: (6, 3) m. p_i: upper joints, platform frame.
        rod_length: m. s: rod length (rotary) or fixed leg part (linear).
        home_height: m. h0: height of the platform origin at home.
        horn_length: m. a: servo horn length; ``None`` for a linear platform.
        servo_beta: (6,) rad. β_i: angle of each horn's plane of rotation to the
            x-axis (the direction the horn points at α = 0). ``None`` if linear.
        servo_angle_range: (lo, hi) rad. Allowed servo angle α (rotary only).
        leg_length_range: (lo, hi) m. Allowed anchor-to-anchor leg length
            (linear only).
        description: Free text: where the numbers come from.
        plate_size: (width along x, depth along y) m of the top plate (the ball's
            surface, the touch panel's extent); ``None`` means the default
            :attr:`plate_extent` derives from the anchors.
    """

    name: str
    base_anchors: np.ndarray
    platform_anchors: np.ndarray
    rod_length: float
    home_height: float
    horn_length: float | None = None
    servo_beta: np.ndarray | None = None
    servo_angle_range: tuple[float, float] | None = None
    leg_length_range: tuple[float, float] | None = None
    description: str = ""
    plate_size: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.name, str):
            raise GeometryError(f"name: text in quotes, got {self.name!r}")
        if not isinstance(self.description, str):
            raise GeometryError(f"description: free text in quotes, got {self.description!r}")
        set_(self, "base_anchors", _readonly(_shape("base_anchors", self.base_anchors, (6, 3))))
        set_(self, "platform_anchors", _readonly(_shape("platform_anchors", self.platform_anchors, (6, 3))))
        for key in ("base_anchors", "platform_anchors"):
            _spread(key, getattr(self, key))
        _positive("rod_length", self.rod_length)
        _positive("home_height", self.home_height)
        for key in ("base_anchors", "platform_anchors", "rod_length", "home_height", "horn_length"):
            value = getattr(self, key)
            if value is not None and np.max(np.abs(np.asarray(value, dtype=float))) > MAX_LENGTH_M:
                raise GeometryError(f"{key}: larger than any build ({MAX_LENGTH_M:g} m); lengths are in metres")
        set_(self, "rod_length", float(self.rod_length))
        set_(self, "home_height", float(self.home_height))
        if self.plate_size is not None:
            size = _range("plate_size", self.plate_size, positive=True, ordered=False)
            set_(self, "plate_size", size)
        if self.horn_length is not None:
            _positive("horn_length", self.horn_length)
            set_(self, "horn_length", float(self.horn_length))
            if self.servo_beta is None:
                raise GeometryError("servo_beta: required for a rotary platform (horn_length is set)")
            set_(self, "servo_beta", _readonly(_shape("servo_beta", self.servo_beta, (6,))))
            if self.servo_angle_range is None:
                raise GeometryError("servo_angle_range: required for a rotary platform")
            turn = _range("servo_angle_range", self.servo_angle_range, positive=False)
            if turn[1] - turn[0] > 2 * math.pi or max(abs(turn[0]), abs(turn[1])) > 2 * math.pi:
                raise GeometryError(f"servo_angle_range: a servo turns less than a whole turn (hobby servos about "
                                    f"180°), got {math.degrees(turn[0]):.1f}° to {math.degrees(turn[1]):.1f}°; check "
                                    "angle_unit")  # fmt: skip
            set_(self, "servo_angle_range", turn)
            if self.leg_length_range is not None:
                raise GeometryError("leg_length_range: only for a linear platform (horn_length is set)")
        else:
            if self.servo_beta is not None:
                raise GeometryError("servo_beta: only for a rotary platform (horn_length is not set)")
            if self.servo_angle_range is not None:
                raise GeometryError("servo_angle_range: only for a rotary platform (horn_length is not set)")
            if self.leg_length_range is None:
                raise GeometryError("leg_length_range: required for a linear platform")
            set_(self, "leg_length_range", _range("leg_length_range", self.leg_length_range, positive=True))

    # ------------------------------------------------------------------ kind
    @property
    def kind(self) -> Literal["rotary", "linear"]:
        """``"rotary"`` (servo horns) or ``"linear"`` (extensible legs)."""
        return "rotary" if self.horn_length is not None else "linear"

    @property
    def is_rotary(self) -> bool:
        """True for a servo (6-RSS) platform."""
        return self.horn_length is not None

    @property
    def plate_extent(self) -> tuple[float, float]:
        """(width, depth) m of the top plate: ``plate_size``, or else a square 30 % wider than the anchor circle."""
        if self.plate_size is not None:
            return self.plate_size
        side = round(2.6 * float(np.max(np.hypot(self.platform_anchors[:, 0], self.platform_anchors[:, 1]))), 4)
        return (side, side)

    @property
    def home_position(self) -> np.ndarray:
        """(3,) m: the platform origin at home, (0, 0, h0)."""
        return np.array([0.0, 0.0, self.home_height])

    def home_heights_eq10(self) -> np.ndarray:
        """(6,) m: eq. 10's home height per leg (rotary only); see :func:`home_height_eq10`."""
        if not self.is_rotary:
            raise GeometryError("home_height: eq. 10 applies to rotary platforms only")
        assert self.horn_length is not None
        return home_height_eq10(self.base_anchors, self.platform_anchors, self.horn_length, self.rod_length)

    # ------------------------------------------------------------------- I/O
    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "geometry") -> PlatformGeometry:
        """Build a geometry from a mapping as read from TOML.

        Lengths are metres and angles radians unless ``length_unit = "mm"`` or
        ``angle_unit = "deg"`` say otherwise. A ``symmetric`` table (``base_radius``, ``base_pair_angle``,
        ``platform_radius``, ``platform_pair_angle``) may replace ``base_anchors``, ``platform_anchors`` and
        ``servo_beta``: see :func:`symmetric_layout`. ``home_height`` may be left out for a rotary platform: it
        is then the mean of eq. 10's height per leg, with a one-line warning where they are more than
        :data:`HOME_HEIGHT_SPREAD_M` apart (measured anchors agree far better). Raises :class:`GeometryError`
        naming the bad field.
        """
        known = set(GEOMETRY_FIELDS)
        unknown = sorted(set(data) - known)
        if unknown:
            raise GeometryError(f"{source}: unknown field(s) {unknown}; known fields are {sorted(known)}")
        length_unit = data.get("length_unit", "m")
        angle_unit = data.get("angle_unit", "rad")
        if length_unit not in ("m", "mm"):
            raise GeometryError(f"length_unit: must be 'm' or 'mm', got {length_unit!r}")
        if angle_unit not in ("rad", "deg"):
            raise GeometryError(f"angle_unit: must be 'rad' or 'deg', got {angle_unit!r}")
        ls = 1e-3 if length_unit == "mm" else 1.0
        ang = math.pi / 180.0 if angle_unit == "deg" else 1.0

        def need(key: str) -> Any:
            if key not in data:
                raise GeometryError(f"{key}: missing field in {source}")
            return data[key]

        rotary = "horn_length" in data
        name = data.get("name", Path(source).stem)
        if (not isinstance(name, str) or not name.strip() or len(name) > MAX_NAME_LENGTH
                or any(ord(c) < 32 or ord(c) == 127 for c in name)):  # fmt: skip
            raise GeometryError(f"name: a name of 1…{MAX_NAME_LENGTH} printable characters, got {name!r}")
        layout = None
        if "symmetric" in data:
            replaced = [k for k in ("base_anchors", "platform_anchors", "servo_beta") if k in data]
            if replaced:
                raise GeometryError(f"symmetric: it gives the anchors and horn directions, so {source} may not give "
                                    f"{', '.join(replaced)} as well; keep one or the other")  # fmt: skip
            symmetric = _symmetric(data["symmetric"], ls, ang, source)
            layout = symmetric_layout(**symmetric)
        kw: dict[str, Any] = {
            "name": name,
            "description": data.get("description", ""),
            "base_anchors": layout[0] if layout else _shape("base_anchors", need("base_anchors"), (6, 3)) * ls,
            "platform_anchors": (layout[1] if layout
                                 else _shape("platform_anchors", need("platform_anchors"), (6, 3)) * ls),
            "rod_length": _scalar("rod_length", need("rod_length")) * ls,
        }
        if "plate_size" in data:
            w, d = _range("plate_size", data["plate_size"], positive=True, ordered=False)
            kw["plate_size"] = (w * ls, d * ls)
        if rotary:
            kw["horn_length"] = _scalar("horn_length", data["horn_length"]) * ls
            _positive("horn_length", kw["horn_length"])
            _positive("rod_length", kw["rod_length"])
            kw["servo_beta"] = layout[2] if layout else _shape("servo_beta", need("servo_beta"), (6,)) * ang
            kw["servo_angle_range"] = _range("servo_angle_range", need("servo_angle_range"), positive=False)
            kw["servo_angle_range"] = (kw["servo_angle_range"][0] * ang, kw["servo_angle_range"][1] * ang)
            for key in ("leg_length_range",):
                if key in data:
                    raise GeometryError(f"{key}: only for a linear platform (horn_length is set)")
        else:
            lo, hi = _range("leg_length_range", need("leg_length_range"), positive=True)
            kw["leg_length_range"] = (lo * ls, hi * ls)
            for key in ("servo_beta", "servo_angle_range"):
                if key in data:
                    raise GeometryError(f"{key}: only for a rotary platform (horn_length is not set)")
        def sizes_fit(keys: tuple[str, ...]) -> None:
            """Refuse a length of ``keys`` beyond :data:`MAX_LENGTH_M` (before it is used: 1e308 overflows)."""
            for key in keys:
                if key not in kw:
                    continue
                sizes = np.abs(np.asarray(kw[key], dtype=float))
                if np.max(sizes) <= MAX_LENGTH_M:  # (False for NaN)
                    continue
                finite = bool(np.all(np.isfinite(sizes)))
                size = np.max(sizes) if finite else np.nan
                if layout and key.endswith("anchors"):  # (the file gave a radius, not the anchors)
                    key = f"{key.split('_')[0]}_radius"
                    key, size = f"symmetric.{key}", symmetric[key]
                if not finite:
                    raise GeometryError(f"{key}: must be a finite length, got {size:g}")
                raise GeometryError(f"{key}: {size:g} m is larger than any build ({MAX_LENGTH_M:g} m); check "
                                    "length_unit")  # fmt: skip

        sizes_fit(("base_anchors", "platform_anchors", "rod_length", "horn_length", "plate_size", "leg_length_range"))
        if "home_height" in data:
            kw["home_height"] = _scalar("home_height", data["home_height"]) * ls
        elif rotary:
            h = home_height_eq10(kw["base_anchors"], kw["platform_anchors"], kw["horn_length"], kw["rod_length"])
            if not np.all(np.isfinite(h)):
                bad = [int(i) for i in np.flatnonzero(~np.isfinite(h))]
                raise GeometryError(f"home_height: eq. 10 has no solution for legs {bad} (rods too short)")
            if np.ptp(h) > HOME_HEIGHT_SPREAD_M:
                import logging

                logging.getLogger("stewart_gym").warning(
                    f"warning: {source}: eq. 10 gives home heights {1e3 * h.min():.2f}–{1e3 * h.max():.2f} mm per leg "
                    f"(apart by more than {1e3 * HOME_HEIGHT_SPREAD_M:g} mm); using their mean "
                    f"{1e3 * float(np.mean(h)):.2f} mm: check the anchors, or give home_height")  # fmt: skip
            kw["home_height"] = float(np.mean(h))
        else:
            raise GeometryError(f"home_height: missing field in {source} (required for a linear platform)")
        sizes_fit(("home_height",))
        return cls(**kw)

    @property
    def file_stem(self) -> str:
        """The name made safe as a file name: letters, digits, ``_`` and ``.`` only (never a path)."""
        stem = re.sub(r"[^A-Za-z0-9._]+", "_", self.name).strip("._")
        return stem or "geometry"

    @classmethod
    def from_toml(cls, path: str | Path) -> PlatformGeometry:
        """Load a geometry from a TOML file (see :meth:`from_dict` for the fields); an error names the file. This
        checks each field; :func:`stewart_gym.presets.load_geometry` (what the command line and the envs use) also
        checks the build as a whole: that its chains close at home, inside the actuators' travel, and hold the
        plate there."""
        data = read_toml(path, GeometryError, "geometry file")
        try:
            return cls.from_dict(data, source=str(path))
        except GeometryError as exc:
            if str(path) in str(exc):
                raise
            raise GeometryError(f"{path}: {exc}") from None

    def content_hash(self) -> str:
        """SHA-256 (hex) of :meth:`to_toml`: the same for the same build however its file is written or named."""
        import hashlib

        return hashlib.sha256(self.to_toml().encode()).hexdigest()

    def to_toml(self) -> str:
        """This geometry as TOML text in SI units, loadable by :meth:`from_toml`."""

        def fmt(v: float) -> str:
            return repr(float(v))

        def rows(a: np.ndarray) -> str:
            return "[\n" + "".join(f"  [{', '.join(fmt(x) for x in r)}],\n" for r in a) + "]"

        lines = [
            f"name = {json.dumps(self.name)}",
            f"description = {json.dumps(self.description)}",
            'length_unit = "m"',
            'angle_unit = "rad"',
            f"base_anchors = {rows(self.base_anchors)}",
            f"platform_anchors = {rows(self.platform_anchors)}",
            f"rod_length = {fmt(self.rod_length)}",
            f"home_height = {fmt(self.home_height)}",
        ]
        if self.plate_size is not None:
            lines.append(f"plate_size = [{fmt(self.plate_size[0])}, {fmt(self.plate_size[1])}]")
        if self.is_rotary:
            assert self.servo_beta is not None and self.servo_angle_range is not None
            lines += [
                f"horn_length = {fmt(self.horn_length)}",  # type: ignore[arg-type]
                f"servo_beta = [{', '.join(fmt(x) for x in self.servo_beta)}]",
                f"servo_angle_range = [{fmt(self.servo_angle_range[0])}, {fmt(self.servo_angle_range[1])}]",
            ]
        else:
            assert self.leg_length_range is not None
            lines.append(f"leg_length_range = [{fmt(self.leg_length_range[0])}, {fmt(self.leg_length_range[1])}]")
        return "\n".join(lines) + "\n"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PlatformGeometry):
            return NotImplemented
        return self.to_toml() == other.to_toml()

    def __hash__(self) -> int:
        return hash(self.to_toml())


# ---------------------------------------------------------------- validation
def _shape(key: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GeometryError(f"{key}: not numeric ({exc})") from None
    if arr.shape != shape:
        raise GeometryError(f"{key}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise GeometryError(f"{key}: contains non-finite values")
    return arr


def _scalar(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise GeometryError(f"{key}: expected a number, got {value!r}")
    return float(value)


def _positive(key: str, value: Any) -> None:
    v = _scalar(key, value)
    if not math.isfinite(v) or v <= 0.0:
        raise GeometryError(f"{key}: must be a finite positive length, got {v!r}")


#: m: how far the six anchors of a side must spread across their plane (its narrower way): less, and they lie on a
#: line (or in one point), where no platform can hold a pose.
MIN_ANCHOR_SPREAD = 1e-3


def _spread(key: str, anchors: np.ndarray) -> None:
    """Raise :class:`GeometryError` if the six ``anchors`` (6, 3) m lie on one line or in one point: their spread
    across the narrower way of the best-fitting plane is under :data:`MIN_ANCHOR_SPREAD`."""
    widths = np.linalg.svd(anchors - anchors.mean(axis=0), compute_uv=False)
    if not widths[1] >= MIN_ANCHOR_SPREAD:  # (NaN too)
        raise GeometryError(f"{key}: the six anchors lie on one line or in one point (they spread "
                            f"{widths[1] * 1e3:.3g} mm across it): a platform needs them around a plane, as a "
                            "ring of pairs")  # fmt: skip


def _range(key: str, value: Any, *, positive: bool, ordered: bool = True) -> tuple[float, float]:
    arr = _shape(key, value, (2,))
    lo, hi = float(arr[0]), float(arr[1])
    if ordered and not lo < hi:
        raise GeometryError(f"{key}: expected [low, high] with low < high, got {[lo, hi]}")
    if positive and min(lo, hi) <= 0.0:
        raise GeometryError(f"{key}: lengths must be positive, got {[lo, hi]}")
    return (lo, hi)
