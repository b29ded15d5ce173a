"""URDF descriptions of a rotary Stewart platform, generated from its geometry.

Two files, since a URDF is a tree and the mechanism has six closed loops:

* the **mechanism** (:func:`mechanism_urdf`): ``base`` → six servo horns
  (``servo_i``, revolute, with limits, effort and velocity) → six rods. The ball
  joint at the horn tip is a universal joint, two passive revolute joints
  (``rod_i_u1``, ``rod_i_u2``) with a light cross-piece between them: a rod end
  is a ball joint, but its spin about the rod axis moves nothing, so dropping it
  removes an idle degree of freedom without changing the mechanism's motion (and
  keeps the file readable by standard URDF parsers, which have no spherical
  joint). The tree is written in the home configuration: every joint at 0 puts
  the horns at α0 and the rod tops on the platform anchors.
* the **plate** (:func:`plate_urdf`): a free body whose link frame is the
  platform frame. The simulator closes each loop with a point-to-point
  constraint between rod top and plate anchor.

Masses and inertias are of a hobby build (:class:`MechanismSpec`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from stewart_gym.geometry import GeometryError, PlatformGeometry
from stewart_gym.kinematics import euler_from_matrix, horn_tips, inverse_kinematics
from stewart_gym.presets import load_geometry
from stewart_gym.sim.servo_model import LINEAR_ACTUATOR, ServoSpec

__all__ = ["MechanismSpec", "frame_along", "mechanism_urdf", "plate_urdf", "rod_frames", "rod_inertia", "servo_axis",
           "write_urdfs", "xml_comment", "xml_text"]


def xml_text(text: str) -> str:
    """``text`` safe inside a double-quoted XML attribute (``&``, ``<``, ``>``, ``"`` escaped)."""
    return escape(text, {'"': "&quot;"})


def xml_comment(text: str) -> str:
    """``text`` safe inside an XML comment (escaped, and no ``--``, which may not appear there)."""
    return xml_text(text).replace("--", "- -")


@dataclass(frozen=True)
class MechanismSpec:
    """Physical parameters of the parts, SI units.

    Attributes:
        base_mass: kg, the base plate with servos (fixed, so only for completeness).
        horn_mass: kg, one servo horn with its ball stud.
        rotor_inertia: kg·m², the servo motor's rotor inertia reflected through the
            gearbox (J_motor · N², about 5e-8 · 200² for an MG996R), added to the
            horn about its shaft: it limits how fast a servo reaches full speed
            (stall torque / rotor inertia ≈ 460 rad/s², ~13 ms to 6 rad/s).
        actuator_reflected_mass: kg, an RC linear actuator's motor and gearbox seen
            through its lead screw, J_m·(N·2π/p)²: about 1e-8 kg·m² · (50 · 2π / 2 mm)²
            ≈ 250 kg for an Actuonix-style actuator (why it cannot be back-driven);
            100 kg is used. MuJoCo's slide joints carry it as armature; PyBullet's
            prismatic motor is a hard velocity constraint and needs none.
        rod_mass: kg, one rod with two rod ends.
        cross_mass: kg, the universal joint's cross-piece (small but non-zero).
        rod_radius: m, visual and inertia radius of a rod.
        plate_areal_mass: kg/m², the top plate with brackets per unit of its area (a
            300 × 300 × 4 mm acrylic plate with brackets ≈ 0.43 kg). The plate is a box
            of the geometry's ``plate_extent`` (a touch panel is rectangular; a box also
            gives a single ball contact point, where a cylinder gives four).
        plate_thickness: m.
        plate_offset: m, height of the plate's underside above the anchor plane.
    """

    base_mass: float = 1.2
    horn_mass: float = 0.010
    rotor_inertia: float = 2e-3
    actuator_reflected_mass: float = 100.0
    rod_mass: float = 0.015
    cross_mass: float = 0.002
    rod_radius: float = 0.003
    plate_areal_mass: float = 0.43 / 0.09
    plate_thickness: float = 0.004
    plate_offset: float = 0.008

    @property
    def plate_top(self) -> float:
        """m: height of the plate's top surface above the platform frame origin."""
        return self.plate_offset + self.plate_thickness


def _f(v: float) -> str:
    """9 significant digits; values below 1e-12 in size (rounding noise such as 6e-18 or -0) are written as 0."""
    return "0" if abs(v) < 1e-12 else f"{v:.9g}"


def _xyz(v: np.ndarray) -> str:
    return " ".join(_f(float(x)) for x in v)


def _rpy(rot: np.ndarray) -> str:
    """URDF fixed-axis roll-pitch-yaw of a rotation matrix (R = Rz·Ry·Rx, as in the kinematics)."""
    return " ".join(_f(v) for v in euler_from_matrix(rot))


def frame_along(direction: np.ndarray, hint: np.ndarray) -> np.ndarray:
    """Rotation whose z column is ``direction`` and whose x column is ``hint`` made orthogonal to it."""
    z = direction / np.linalg.norm(direction)
    x = hint - (hint @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def rod_inertia(mass: float, length: float, radius: float) -> tuple[float, float, float]:
    """Principal inertia (kg·m²) of a solid cylinder along z: (Ixx, Iyy, Izz)."""
    ixx = mass * (3 * radius**2 + length**2) / 12.0
    return ixx, ixx, 0.5 * mass * radius**2


def _inertial(mass: float, com: np.ndarray, inertia: tuple[float, float, float], rpy: str = "0 0 0") -> str:
    ixx, iyy, izz = inertia
    return (
        f'    <inertial>\n      <origin xyz="{_xyz(com)}" rpy="{rpy}"/>\n      <mass value="{_f(mass)}"/>\n'
        f'      <inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/>\n    </inertial>\n'
    )


def _shape(kind: str, body: str, xyz: np.ndarray, rpy: str, colour: str | None = None) -> str:
    material = f'\n      <material name="{colour}"/>' if colour else ""
    return (
        f'    <{kind}>\n      <origin xyz="{_xyz(xyz)}" rpy="{rpy}"/>\n'
        f"      <geometry>{body}</geometry>{material}\n    </{kind}>\n"
    )


def rod_frames(geometry: PlatformGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Home configuration: horn tips (6, 3), unit rod directions (6, 3), rod frame rotations (6, 3, 3).

    The rod frame has its origin at the horn tip and its z axis along the rod,
    so the rod top is at (0, 0, s) in that frame.
    """
    if not geometry.is_rotary:
        raise GeometryError(f"geometry {geometry.name!r} is linear: the simulator models servo (rotary) platforms")
    alpha0 = inverse_kinematics(geometry, np.zeros(6)).servo_angles
    tips = horn_tips(geometry, alpha0)
    tops = geometry.platform_anchors + geometry.home_position
    dirs = (tops - tips) / np.linalg.norm(tops - tips, axis=1, keepdims=True)
    frames = np.stack([frame_along(dirs[i], servo_axis(geometry.servo_beta[i])) for i in range(6)])  # type: ignore[index]
    return tips, dirs, frames


def servo_axis(beta: float) -> np.ndarray:
    """Unit axis of a servo shaft such that a positive turn raises the horn (increases α)."""
    return np.array([math.sin(beta), -math.cos(beta), 0.0])


def mechanism_urdf(geometry: PlatformGeometry | str = "servo-hexapod", spec: MechanismSpec | None = None,
                   servo: ServoSpec | None = None, *, legs: Sequence[int] = range(6),
                   base_plate: bool = True) -> str:  # fmt: skip
    """URDF text of base, horns and rods of a rotary platform in its home configuration (or, for a linear
    platform, base, universal joints and extensible legs: see :func:`_linear_mechanism_urdf`).

    The servo's stall torque (N·m) and speed (rad/s) become each servo joint's
    ``effort`` and ``velocity`` (default MG996R at 4.8 V: 9.4 kgf·cm, 0.17 s/60°).
    Servo joint limits are the geometry's servo angle range relative to α0.

    ``legs`` (indices 0…5) and ``base_plate`` select a sub-tree: the base link
    with only those legs, with or without the base plate's shape. The simulator
    loads each leg as its own body (``legs=[i]``); the default is the whole tree.
    """
    geo = load_geometry(geometry)
    spec = spec or MechanismSpec()
    servo = servo or (ServoSpec() if geo.is_rotary else LINEAR_ACTUATOR)
    if not geo.is_rotary:
        return _linear_mechanism_urdf(geo, spec, servo, legs, base_plate)
    stall_torque, max_speed = servo.stall_torque, servo.max_speed
    tips, _, frames = rod_frames(geo)
    alpha0 = inverse_kinematics(geo, np.zeros(6)).servo_angles
    assert alpha0 is not None and geo.horn_length is not None and geo.servo_beta is not None
    a, s = geo.horn_length, geo.rod_length
    lo, hi = geo.servo_angle_range  # type: ignore[misc]
    base_r = float(np.max(np.linalg.norm(geo.base_anchors[:, :2], axis=1))) + 0.03
    base_z = float(np.min(geo.base_anchors[:, 2])) - 0.02
    legs, out = _robot_head(geo, spec, legs, base_plate, base_r, base_z,
                            {"servo_black": "0.1 0.1 0.1 1", "horn_white": "0.92 0.92 0.9 1"})  # fmt: skip
    for i in legs:
        axis = servo_axis(float(geo.servo_beta[i]))
        # servo body: a box below the shaft, long side along the shaft axis
        body_rot = frame_along(np.array([0, 0, 1.0]), axis)
        out.append(_shape("visual", '<box size="0.040 0.020 0.036"/>',
                          geo.base_anchors[i] - np.array([0, 0, 0.012]) - 0.008 * axis, _rpy(body_rot),
                          "servo_black"))  # fmt: skip
    out.append("  </link>\n")
    for i in legs:
        beta = float(geo.servo_beta[i])
        u = np.array([math.cos(beta), math.sin(beta), 0.0])
        horn_dir = math.cos(alpha0[i]) * u + math.sin(alpha0[i]) * np.array([0, 0, 1.0])
        tip = tips[i] - geo.base_anchors[i]  # horn tip relative to the shaft
        horn_rot = _rpy(frame_along(horn_dir, servo_axis(beta)))
        horn_i = tuple(v + spec.rotor_inertia for v in rod_inertia(spec.horn_mass, a, 0.004))  # any axis: the shaft's
        rod_i = rod_inertia(spec.rod_mass, s, spec.rod_radius)
        out += [
            f'  <joint name="servo_{i}" type="revolute">\n    <parent link="base"/>\n    <child link="horn_{i}"/>\n'
            f'    <origin xyz="{_xyz(geo.base_anchors[i])}" rpy="0 0 0"/>\n    <axis xyz="{_xyz(servo_axis(beta))}"/>\n'
            f'    <limit lower="{_f(lo - alpha0[i])}" upper="{_f(hi - alpha0[i])}" effort="{_f(stall_torque)}" '
            f'velocity="{_f(max_speed)}"/>\n  </joint>\n',
            f'  <link name="horn_{i}">\n',
            _inertial(spec.horn_mass, tip / 2, horn_i, horn_rot),
            _shape("visual", f'<box size="0.012 0.006 {_f(a + 0.010)}"/>', tip / 2, horn_rot, "horn_white"),
            _shape("collision", f'<box size="0.008 0.004 {_f(a + 0.008)}"/>', tip / 2, horn_rot),
            "  </link>\n",
            f'  <joint name="rod_{i}_u1" type="continuous">\n    <parent link="horn_{i}"/>\n'
            f'    <child link="rod_{i}_cross"/>\n    <origin xyz="{_xyz(tip)}" rpy="{_rpy(frames[i])}"/>\n'
            '    <axis xyz="1 0 0"/>\n  </joint>\n',
            f'  <link name="rod_{i}_cross">\n',
            _inertial(spec.cross_mass, np.zeros(3), (1e-7, 1e-7, 1e-7)),
            _shape("visual", '<sphere radius="0.005"/>', np.zeros(3), "0 0 0", "rod_steel"),
            _shape("collision", '<sphere radius="0.005"/>', np.zeros(3), "0 0 0"),
            "  </link>\n",
            f'  <joint name="rod_{i}_u2" type="continuous">\n    <parent link="rod_{i}_cross"/>\n'
            f'    <child link="rod_{i}"/>\n    <origin xyz="0 0 0" rpy="0 0 0"/>\n    <axis xyz="0 1 0"/>\n  </joint>\n',
            f'  <link name="rod_{i}">\n',
            _inertial(spec.rod_mass, np.array([0, 0, s / 2]), rod_i),
            _shape("visual", f'<cylinder radius="{_f(spec.rod_radius)}" length="{_f(s)}"/>', np.array([0, 0, s / 2]),
                   "0 0 0", "rod_steel"),  # fmt: skip
            _shape("visual", '<sphere radius="0.005"/>', np.array([0, 0, s]), "0 0 0", "rod_steel"),
            _shape("collision", f'<cylinder radius="{_f(spec.rod_radius)}" length="{_f(s)}"/>', np.array([0, 0, s / 2]),
                   "0 0 0"),  # fmt: skip
            "  </link>\n",
        ]
    out.append("</robot>\n")
    return "".join(out)


def _robot_head(geo: PlatformGeometry, spec: MechanismSpec, legs: Sequence[int], base_plate: bool, base_r: float,
                base_z: float, materials: dict[str, str]) -> tuple[list[int], list[str]]:  # fmt: skip
    """The checked leg indices, and the URDF up to the base link's shapes (the caller closes the base link).

    ``materials`` (name → rgba) are declared between the base's grey and the rods' steel.
    """
    legs = [int(i) for i in legs]
    if not legs or any(i not in range(6) for i in legs) or len(set(legs)) != len(legs):
        raise ValueError(f"legs: distinct indices in 0..5 expected, got {legs}")
    name = xml_text(geo.name if legs == list(range(6)) else f"{geo.name}-legs-{'-'.join(map(str, legs))}")
    colours = {"base_grey": "0.35 0.35 0.38 1", **materials, "rod_steel": "0.7 0.72 0.75 1"}
    out = [
        '<?xml version="1.0"?>\n',
        f'<!-- Generated by stewart_gym.sim.urdf from geometry "{xml_comment(geo.name)}". Do not edit: regenerate. -->\n',
        f'<robot name="{name}">\n',
        *(f'  <material name="{m}"><color rgba="{rgba}"/></material>\n' for m, rgba in colours.items()),
        '  <link name="base">\n',
        _inertial(spec.base_mass, np.array([0, 0, base_z]), rod_inertia(spec.base_mass, 0.006, base_r)),
    ]
    if base_plate:
        disc = f'<cylinder radius="{_f(base_r)}" length="0.006"/>'
        out += [_shape("visual", disc, np.array([0, 0, base_z]), "0 0 0", "base_grey"),
                _shape("collision", disc, np.array([0, 0, base_z]), "0 0 0")]  # fmt: skip
    return legs, out


def _linear_mechanism_urdf(geo: PlatformGeometry, spec: MechanismSpec, servo: ServoSpec, legs: Sequence[int],
                           base_plate: bool) -> str:  # fmt: skip
    """A 6-UPS platform at home: per leg a universal joint at the base anchor, a tube along the leg, and a
    prismatic joint ``servo_i`` (the RC linear actuator: joint value = leg length − home length) to the leg's
    top link ``rod_i``, whose origin is the platform anchor. ``effort`` is the actuator's force (N) and
    ``velocity`` its speed (m/s)."""
    home = inverse_kinematics(geo, np.zeros(6)).leg_lengths
    lo, hi = geo.leg_length_range  # type: ignore[misc]
    tops = geo.platform_anchors + geo.home_position
    dirs = (tops - geo.base_anchors) / home[:, None]
    base_r = float(np.max(np.linalg.norm(geo.base_anchors[:, :2], axis=1))) * 1.1
    base_z = float(np.min(geo.base_anchors[:, 2])) - 0.01
    tube, r = geo.rod_length, spec.rod_radius
    legs, out = _robot_head(geo, spec, legs, base_plate, base_r, base_z, {"tube_black": "0.1 0.1 0.1 1"})
    out.append("  </link>\n")
    for i in legs:
        frame = frame_along(dirs[i], np.cross(np.array([0, 0, 1.0]), dirs[i]) + np.array([1e-9, 0, 0]))
        rod = float(home[i]) - tube + 0.03  # the moving rod, long enough to reach into the tube at home
        out += [
            f'  <joint name="rod_{i}_u1" type="continuous">\n    <parent link="base"/>\n'
            f'    <child link="rod_{i}_cross"/>\n    <origin xyz="{_xyz(geo.base_anchors[i])}" rpy="{_rpy(frame)}"/>\n'
            '    <axis xyz="1 0 0"/>\n  </joint>\n',
            f'  <link name="rod_{i}_cross">\n',
            _inertial(spec.cross_mass, np.zeros(3), (1e-7, 1e-7, 1e-7)),
            _shape("visual", '<sphere radius="0.008"/>', np.zeros(3), "0 0 0", "rod_steel"),
            "  </link>\n",
            f'  <joint name="rod_{i}_u2" type="continuous">\n    <parent link="rod_{i}_cross"/>\n'
            f'    <child link="tube_{i}"/>\n    <origin xyz="0 0 0" rpy="0 0 0"/>\n    <axis xyz="0 1 0"/>\n  </joint>\n',
            f'  <link name="tube_{i}">\n',
            _inertial(spec.rod_mass, np.array([0, 0, tube / 2]), rod_inertia(spec.rod_mass, tube, 2 * r)),
            _shape("visual", f'<cylinder radius="{_f(2 * r)}" length="{_f(tube)}"/>', np.array([0, 0, tube / 2]),
                   "0 0 0", "tube_black"),  # fmt: skip
            "  </link>\n",
            f'  <joint name="servo_{i}" type="prismatic">\n    <parent link="tube_{i}"/>\n    <child link="rod_{i}"/>\n'
            f'    <origin xyz="0 0 {_f(home[i])}" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>\n'
            f'    <limit lower="{_f(lo - home[i])}" upper="{_f(hi - home[i])}" effort="{_f(servo.stall_torque)}" '
            f'velocity="{_f(servo.max_speed)}"/>\n  </joint>\n',
            f'  <link name="rod_{i}">\n',
            _inertial(spec.rod_mass, np.array([0, 0, -rod / 2]), rod_inertia(spec.rod_mass, rod, r)),
            _shape("visual", f'<cylinder radius="{_f(r)}" length="{_f(rod)}"/>', np.array([0, 0, -rod / 2]), "0 0 0",
                   "rod_steel"),  # fmt: skip
            _shape("visual", '<sphere radius="0.006"/>', np.zeros(3), "0 0 0", "rod_steel"),
            "  </link>\n",
        ]
    out.append("</robot>\n")
    return "".join(out)


def plate_urdf(geometry: PlatformGeometry | str = "servo-hexapod", spec: MechanismSpec | None = None) -> str:
    """URDF text of the top plate: one free link whose frame is the platform frame."""
    geo = load_geometry(geometry)
    spec = spec or MechanismSpec()
    zc = spec.plate_offset + spec.plate_thickness / 2
    (w, d), t = geo.plate_extent, spec.plate_thickness
    m = spec.plate_areal_mass * w * d
    inertia = (m * (d * d + t * t) / 12, m * (w * w + t * t) / 12, m * (w * w + d * d) / 12)
    box = f'<box size="{_f(w)} {_f(d)} {_f(t)}"/>'
    out = [
        '<?xml version="1.0"?>\n',
        f'<!-- Generated by stewart_gym.sim.urdf from geometry "{xml_comment(geo.name)}". Do not edit: regenerate. -->\n',
        f'<robot name="{xml_text(geo.name)}-plate">\n',
        '  <material name="plate_blue"><color rgba="0.55 0.75 0.95 0.9"/></material>\n',
        '  <material name="bracket_grey"><color rgba="0.3 0.3 0.3 1"/></material>\n',
        '  <link name="plate">\n',
        _inertial(m, np.array([0, 0, zc]), inertia),
        _shape("visual", box, np.array([0, 0, zc]), "0 0 0", "plate_blue"),
        _shape("collision", box, np.array([0, 0, zc]), "0 0 0"),
    ]
    for p in geo.platform_anchors:
        out.append(_shape("visual", f'<box size="0.012 0.012 {_f(spec.plate_offset)}"/>',
                          p + np.array([0, 0, spec.plate_offset / 2]), "0 0 0", "bracket_grey"))  # fmt: skip
    out += ["  </link>\n", "</robot>\n"]
    return "".join(out)


def write_urdfs(directory: str | Path, geometry: PlatformGeometry | str = "servo-hexapod",
                spec: MechanismSpec | None = None, servo: ServoSpec | None = None) -> tuple[Path, Path]:  # fmt: skip
    """Write ``<name>.urdf`` (mechanism) and ``<name>_plate.urdf`` into ``directory``; return both paths."""
    geo = load_geometry(geometry)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    stem = geo.file_stem
    mech, plate = directory / f"{stem}.urdf", directory / f"{stem}_plate.urdf"
    mech.write_text(mechanism_urdf(geo, spec, servo), encoding="utf-8")
    plate.write_text(plate_urdf(geo, spec), encoding="utf-8")
    return mech, plate
