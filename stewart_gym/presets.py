"""Preset platform geometries, and loading a geometry by preset name or TOML file.

Each preset is a function returning a fresh :class:`PlatformGeometry`;
:func:`load_preset` and :func:`load_geometry` are the way in. The presets are
documented in the docs' "Conventions and presets" page.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from stewart_gym.geometry import GeometryError, PlatformGeometry, home_height_eq10

__all__ = ["PRESETS", "check_home", "load_geometry", "load_preset", "polar_anchors", "preset_names"]

MM = 1e-3
DEG = math.pi / 180.0


def polar_anchors(radius: float, angles_deg: list[float], z: float = 0.0) -> np.ndarray:
    """(6, 3) anchors at ``radius`` (m) and polar angles (degrees), height ``z`` (m)."""
    ang = np.radians(angles_deg)
    return np.stack([radius * np.cos(ang), radius * np.sin(ang), np.full(6, z)], axis=1)


def servo_hexapod() -> PlatformGeometry:
    """The reference hobby ball balancer that the simulator models.

    MG996R-class servos with 25 mm horns and 160 mm rods under a 300 mm plate
    (the docs: Sources, Conventions and presets). Servo shafts sit in three pairs on a 100 mm radius,
    at ±20° about 90°, 210° and 330°; each horn turns in the plane tangent to
    that circle and points away from its partner. Rod ends sit in three pairs on
    an 80 mm radius at ±8° about the same angles. The home height follows from
    eq. 10 (h0 = 159.61 mm) and the home servo angle from eq. 12
    (α0 = 17.14°, horn slightly raised). Servo travel is ±45° about α0
    (±400 µs at 1600/π µs/rad), as in source 000. Reachable from home along one
    axis: x ±45.7 mm, y −53.3/+44.2 mm, z −18.5/+18.0 mm, roll −13.7/+13.0°,
    pitch ±13.7°, yaw ±32.5°; cond(J) = 42.8 at home.
    """
    centres = [330.0, 90.0, 210.0]
    base_deg = [c + s for c in centres for s in (-20.0, 20.0)]
    top_deg = [c + s for c in centres for s in (-8.0, 8.0)]
    # Horns point tangentially, away from the partner servo: the first of a pair
    # points clockwise (β = θ − 90°), the second anticlockwise (β = θ + 90°).
    beta = [math.radians(c + s) for c in centres for s in (-90.0, 90.0)]
    base = polar_anchors(100 * MM, base_deg)
    top = polar_anchors(80 * MM, top_deg)
    a, s = 25 * MM, 160 * MM
    h0 = float(np.mean(home_height_eq10(base, top, a, s)))
    geo = PlatformGeometry(
        name="servo-hexapod",
        base_anchors=base,
        platform_anchors=top,
        horn_length=a,
        rod_length=s,
        servo_beta=np.array(beta),
        home_height=h0,
        servo_angle_range=(-math.pi, math.pi),  # replaced below by ±45° about α0
        description="Reference hobby ball balancer: MG996R servos, 25 mm horns, 160 mm rods, 300 mm plate.",
        plate_size=(0.300, 0.300),
    )
    from stewart_gym.kinematics import inverse_kinematics

    alpha0 = float(inverse_kinematics(geo, np.zeros(6)).servo_angles[0])  # eq. 12: the same for every leg
    return replace(geo, servo_angle_range=(alpha0 - 45 * DEG, alpha0 + 45 * DEG))


def desk_rect() -> PlatformGeometry:
    """A larger desk build with a rectangular plate, of this project's design (a second trained build).

    Servo shafts in three pairs on a 120 mm radius at ±18° about 90°, 210° and
    330°, horns 30 mm, rods 190 mm, rod ends in pairs on a 95 mm radius at ±9°;
    a 400 × 260 mm plate (a 17-inch resistive panel's active area is about
    this). h0 = 189.98 mm by eq. 10, α0 = 15.69° by eq. 12, travel ±45° about
    α0. Reach from home along one axis: x ±57.2 mm, y −67.4/+54.1 mm, z
    −22.1/+21.4 mm, roll −13.8/+13.0°, pitch ±13.7°, yaw ±34.1°.
    """
    from stewart_gym.kinematics import inverse_kinematics

    centres = [330.0, 90.0, 210.0]
    base = polar_anchors(120 * MM, [c + s for c in centres for s in (-18.0, 18.0)])
    top = polar_anchors(95 * MM, [c + s for c in centres for s in (-9.0, 9.0)])
    beta = np.radians([c + s for c in centres for s in (-90.0, 90.0)])
    a, s = 30 * MM, 190 * MM
    geo = PlatformGeometry(name="desk-rect", base_anchors=base, platform_anchors=top, horn_length=a, rod_length=s,
                           servo_beta=beta, home_height=float(np.mean(home_height_eq10(base, top, a, s))),
                           servo_angle_range=(-math.pi, math.pi), plate_size=(0.400, 0.260),
                           description="Larger desk build of this project: 30 mm horns, 190 mm rods, 400 × 260 mm "
                                       "plate.")  # fmt: skip
    alpha0 = float(inverse_kinematics(geo, np.zeros(6)).servo_angles[0])
    return replace(geo, servo_angle_range=(alpha0 - 45 * DEG, alpha0 + 45 * DEG))


def memememe_liverpool() -> PlatformGeometry:
    """memememe's small platform (Liverpool 2016), from its ``stewartPlatformMath.py``.

    Base anchors on a 65.43 mm radius, rod ends on 76.35 mm, 36 mm horns, 125 mm
    rods, initial height 120 mm as given (not computed by eq. 10). Its AX-12A
    servos turn 300°; the travel here is ±90° from the horizontal.
    """
    beta = np.array([-8 * math.pi / 3, math.pi / 3, 0.0, -math.pi, -4 * math.pi / 3, -7 * math.pi / 3])
    return PlatformGeometry(
        name="memememe-liverpool",
        base_anchors=polar_anchors(65.43 * MM, [314.9, 345.1, 74.9, 105.1, 194.9, 225.1]),
        platform_anchors=polar_anchors(76.35 * MM, [322.9, 337.1, 82.9, 97.1, 202.9, 217.1]),
        horn_length=36 * MM,
        rod_length=125 * MM,
        servo_beta=beta,
        home_height=120 * MM,
        servo_angle_range=(-90 * DEG, 90 * DEG),
        description="memememe small platform (Liverpool 2016), AX-12A servos (the docs: Sources); 200 mm plate.",
        plate_size=(0.200, 0.200),
    )


def senilov2018() -> PlatformGeometry:
    """Source 001: a 6-UPS platform with linear actuators (Senilov, 2018).

    Base anchors on Rb = 0.5 m, platform anchors on Rt = 0.2 m, half-angle 10°,
    the base anchors lifted 0.02 m by the static link. Home height 0.25 m. The
    leg's fixed part is 0.2 m and its stroke 0…0.3 m, so a leg spans 0.2…0.5 m.
    """
    dt = 10.0
    return PlatformGeometry(
        name="senilov2018",
        base_anchors=polar_anchors(0.5, [330 + dt, 90 - dt, 90 + dt, 210 - dt, 210 + dt, 330 - dt], z=0.02),
        platform_anchors=polar_anchors(0.2, [30 - dt, 30 + dt, 150 - dt, 150 + dt, 270 - dt, 270 + dt]),
        rod_length=0.2,
        home_height=0.25,
        leg_length_range=(0.2, 0.5),
        description="Source 001 (Senilov 2018): 6-UPS, Rb=0.5 m, Rt=0.2 m, stroke 0..0.3 m; 500 mm plate.",
        plate_size=(0.500, 0.500),
    )


def mathcad_micro() -> PlatformGeometry:
    """Source 002: the Mathcad sheet's 22 mm micro platform.

    Anchor tables in mm converted to m; home height z_mid = 22.19 mm; legs
    31.44 mm ± 1.24 mm, so a leg spans 30.20…32.68 mm and the fixed part is
    30.20 mm.
    """
    base = np.array(
        [[4, 26, 22, -22, -26, -4], [27.7, -10.39, -17.32, -17.32, -10.39, 27.7], [0, 0, 0, 0, 0, 0]]
    ).T
    top = np.array([[5.5, 7.5, 2, -2, -7.5, -5.5], [5.48, 2.02, -7.5, -7.5, 2.02, 5.48], [0, 0, 0, 0, 0, 0]]).T
    return PlatformGeometry(
        name="mathcad-micro",
        base_anchors=base * MM,
        platform_anchors=top * MM,
        rod_length=(31.44 - 1.24) * MM,
        home_height=22.19 * MM,
        leg_length_range=((31.44 - 1.24) * MM, (31.44 + 1.24) * MM),
        description="Source 002 (Mathcad micro platform): legs 31.44 ± 1.24 mm, z_mid 22.19 mm; 30 mm plate.",
        plate_size=(0.030, 0.030),
    )


PRESETS: dict[str, Callable[[], PlatformGeometry]] = {
    "servo-hexapod": servo_hexapod,
    "memememe-liverpool": memememe_liverpool,
    "desk-rect": desk_rect,
    "senilov2018": senilov2018,
    "mathcad-micro": mathcad_micro,
}


def preset_names() -> list[str]:
    """Names accepted by :func:`load_preset`."""
    return sorted(PRESETS)


def load_preset(name: str) -> PlatformGeometry:
    """Return the named preset geometry (see :func:`preset_names`)."""
    try:
        builder = PRESETS[name]
    except (KeyError, TypeError):  # (an unhashable name too)
        raise GeometryError(f"unknown preset {name!r}; known presets: {preset_names()}") from None
    return builder()


def load_geometry(spec: str | Path | PlatformGeometry) -> PlatformGeometry:
    """A geometry from a preset name, a TOML path, or a geometry (returned as is)."""
    if isinstance(spec, PlatformGeometry):
        return spec
    if not isinstance(spec, (str, os.PathLike)):
        raise GeometryError(f"the geometry is a preset's name ({', '.join(preset_names())}), a TOML file's path or a "
                            f"PlatformGeometry, got {spec!r}")  # fmt: skip
    if isinstance(spec, str) and spec in PRESETS:
        return load_preset(spec)
    if isinstance(spec, str) and not spec.strip():
        raise GeometryError(f"the geometry is empty: give a preset ({', '.join(preset_names())}) or a TOML file")
    path = Path(spec)
    if path.suffix == ".toml" or path.exists():
        geometry = PlatformGeometry.from_toml(path)
        check_home(geometry, str(path))
        return geometry
    raise GeometryError(f"{spec!r} is neither a preset ({', '.join(preset_names())}) nor a TOML file")


#: The largest condition number of the actuators' Jacobian at home a build may have: beyond it the legs cannot hold
#: the plate there (the presets: 9 to 242; one leg given twice: 1e17).
MAX_HOME_CONDITION = 1e8


def check_home(geometry: PlatformGeometry, source: str) -> None:
    """Raise :class:`GeometryError` (naming ``source``, the file) unless the home pose is inside the actuators'
    travel: a solution of the IK at home, with each servo angle inside ``servo_angle_range`` (each leg length
    inside ``leg_length_range``), and the legs hold the plate there (their Jacobian is not singular:
    :data:`MAX_HOME_CONDITION`). A build whose home is outside its travel has no neutral pulse to start from."""
    from stewart_gym.kinematics import actuator_jacobian, inverse_kinematics

    key, what = ("servo_angle_range", "servo angles") if geometry.is_rotary else ("leg_length_range", "leg lengths")
    travel = getattr(geometry, key)
    home = inverse_kinematics(geometry, np.zeros(6))
    values = np.asarray(home.actuators, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        horn = ", horn_length" if geometry.is_rotary else ""
        raise GeometryError(f"{source}: the chains cannot close at home, {1e3 * geometry.home_height:.1f} mm up (no "
                            f"{what} reach it): check rod_length{horn}, the anchors and home_height (given, or computed "
                            "from them where it is left out)")  # fmt: skip
    lo, hi = travel
    tolerance = 1e-9 * max(1.0, abs(lo), abs(hi))
    outside = np.flatnonzero((values < lo - tolerance) | (values > hi + tolerance))
    if outside.size:
        if geometry.is_rotary:
            def show(v: float) -> str:
                return f"{v:.4g} rad ({math.degrees(v):.2f}°)"
        else:
            def show(v: float) -> str:
                return f"{v:.4g} m"
        low, high = float(values[outside].min()), float(values[outside].max())
        at_home = show(low) if high - low < tolerance else f"{show(low)} to {show(high)}"
        raise GeometryError(f"{source}: {key}: {show(lo)} to {show(hi)} does not hold the {what} at home "
                            f"(actuators {outside.tolist()}: {at_home}): widen it to include them, or change "
                            "home_height")  # fmt: skip
    if not bool(home.reachable):  # (what else the IK refuses: a platform anchor not above its base anchor)
        raise GeometryError(f"{source}: home_height: the home pose is unreachable ({home.explain()}): check "
                            "home_height and the anchors' heights")  # fmt: skip
    condition = float(np.linalg.cond(actuator_jacobian(geometry, np.zeros(6))))
    if not condition < MAX_HOME_CONDITION:
        same = [f"{i} and {j}" for i in range(6) for j in range(i + 1, 6)
                if np.allclose(geometry.base_anchors[i], geometry.base_anchors[j], rtol=0, atol=1e-6)
                and np.allclose(geometry.platform_anchors[i], geometry.platform_anchors[j], rtol=0, atol=1e-6)]
        why = f"legs {', '.join(same)} are one leg twice" if same else "the legs' lines meet or run parallel"
        raise GeometryError(f"{source}: the legs cannot hold the plate at home ({why}: a singular pose, condition "
                            f"number {condition:.3g}): check base_anchors and platform_anchors")  # fmt: skip
