"""MJCF (MuJoCo) description of a Stewart platform, rotary or linear, generated from its geometry.

MuJoCo models closed chains directly, so one file holds the whole mechanism:

* **rotary (6-RSS)**: ``horn_i`` bodies on hinge joints ``servo_i`` at the base
  anchors, each carrying ``rod_i`` on a ball joint at the horn tip;
* **linear (6-UPS)**: ``tube_i`` bodies on two hinges (a universal joint) at the
  base anchors, each carrying ``rod_i`` on a slide joint ``servo_i`` along the leg;
* the **plate**, a free body whose frame is the platform frame, and optionally
  the **ball**, a free sphere resting on it;
* six ``connect`` equality constraints join each rod top (site ``rod_i_top``) to
  its plate anchor (site ``anchor_i``): the ball joints at the top;
* six **velocity actuators** ``servo_i`` with the servo's speed as their control
  range and its torque (N·m) or force (N) as their force range. :class:`~stewart_gym.sim.MujocoSim` drives them from the
  same :class:`~stewart_gym.sim.HobbyServos` front end as PyBullet's motors.

The model is written in the home configuration (every joint at 0). Masses and
inertias are those of :class:`~stewart_gym.sim.MechanismSpec`, as in the URDF.
Only the ball and the plate collide. ``python -m mujoco.viewer --mjcf FILE``
opens the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stewart_gym.constants import GRAVITY
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import horn_tips, inverse_kinematics
from stewart_gym.outputs import make_parent
from stewart_gym.presets import load_geometry
from stewart_gym.sim.backend import BallSpec
from stewart_gym.sim.servo_model import LINEAR_ACTUATOR, ServoSpec
from stewart_gym.sim.urdf import (
    MechanismSpec,
    frame_along,
    rod_frames,
    rod_inertia,
    servo_axis,
    xml_comment,
    xml_text,
)

__all__ = ["MujocoPhysics", "mechanism_mjcf", "write_mjcf"]



@dataclass(frozen=True)
class MujocoPhysics:
    """MuJoCo solver settings, chosen by measurement (``bench/bench_mujoco.py --settings``).

    Attributes:
        physics_hz: physics steps per second (a multiple of the control rate).
        integrator: MuJoCo integrator; ``implicitfast`` keeps the stiff velocity
            servos stable at a coarse step.
        cone: friction cone; ``elliptic`` rolls a ball without the pyramidal cone's creep.
        loop_solref: (time constant s, damping ratio) of the loop constraints: the
            smaller, the firmer (at least two physics steps). A damping ratio of 0.5
            halves the loop gap of 1.0 and stays stable; 0.3 is not.
        loop_solimp: MuJoCo's impedance (d0, dwidth, width m) of the loop constraints:
            close to 1 makes them hard (the default 0.9…0.95 left 0.46 mm of static gap).
        contact_solref: the same as ``loop_solref`` for the ball's contact with the plate.
        solver_iterations: Newton iterations per step.
        servo_slip: the velocity error, as a fraction of the servo's no-load speed, at
            which its motor pushes with the full stall torque (force): the velocity
            actuator's gain is ``stall_torque / (servo_slip · max_speed)``. Smaller holds
            poses more exactly; larger closes the loops better in fast moves.
    """

    physics_hz: int = 250
    integrator: str = "implicitfast"
    cone: str = "elliptic"
    loop_solref: tuple[float, float] = (0.008, 0.5)
    loop_solimp: tuple[float, float, float] = (0.999, 0.9999, 0.001)
    contact_solref: tuple[float, float] = (0.008, 1.0)
    solver_iterations: int = 20
    servo_slip: float = 0.3


def _f(v: float) -> str:
    """9 significant digits; values below 1e-12 in size (rounding noise) are written as 0."""
    return "0" if abs(v) < 1e-12 else f"{v:.9g}"


def _v(v: np.ndarray) -> str:
    return " ".join(_f(float(x)) for x in v)


def _quat(rot: np.ndarray) -> str:
    """MuJoCo quaternion (w, x, y, z) of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    if w < 0:
        x, y, z, w = -x, -y, -z, -w
    return _v(np.array([w, x, y, z]))


def _inertial(mass: float, com: np.ndarray, inertia: tuple[float, float, float], rot: np.ndarray | None = None) -> str:
    quat = f' quat="{_quat(rot)}"' if rot is not None else ""
    return f'<inertial pos="{_v(com)}"{quat} mass="{_f(mass)}" diaginertia="{_v(np.array(inertia))}"/>'


def mechanism_mjcf(geometry: PlatformGeometry | str = "servo-hexapod", spec: MechanismSpec | None = None,
                   servo: ServoSpec | None = None, physics: MujocoPhysics | None = None, *,
                   ball: BallSpec | None = None, plate_friction: float = 0.6) -> str:  # fmt: skip
    """MJCF text of the whole platform in its home configuration, with a ball if ``ball`` is given.

    The ball's contact uses MuJoCo's 6-D friction (sliding, torsional, rolling):
    sliding μ = ball × plate friction (PyBullet multiplies the two), rolling and
    torsional = the ball's coefficients × the plate's friction. A ball's
    restitution has no MuJoCo counterpart (contacts are soft, not bouncy) and is
    not used.
    """
    geo = load_geometry(geometry)
    spec = spec or MechanismSpec()
    servo = servo or (ServoSpec() if geo.is_rotary else LINEAR_ACTUATOR)
    phys = physics or MujocoPhysics()
    kv = servo.stall_torque / (phys.servo_slip * servo.max_speed)
    out = [
        f'<!-- Generated by stewart_gym.sim.mjcf from geometry "{xml_comment(geo.name)}". Do not edit: regenerate. -->\n',
        f'<mujoco model="{xml_text(geo.name)}">\n',
        '  <compiler angle="radian" autolimits="true"/>\n',
        f'  <option timestep="{_f(1.0 / phys.physics_hz)}" gravity="0 0 {_f(-GRAVITY)}" '
        f'integrator="{phys.integrator}" cone="{phys.cone}" iterations="{phys.solver_iterations}"/>\n',
        '  <visual><global offwidth="640" offheight="480"/></visual>\n',
        "  <default>\n    <geom contype=\"0\" conaffinity=\"0\" group=\"1\"/>\n"
        f'    <equality solref="{_v(np.array(phys.loop_solref))}" solimp="{_v(np.array(phys.loop_solimp))}"/>\n'
        "  </default>\n",
        "  <asset>\n"
        '    <material name="base_grey" rgba="0.35 0.35 0.38 1"/>\n'
        '    <material name="servo_black" rgba="0.1 0.1 0.1 1"/>\n'
        '    <material name="horn_white" rgba="0.92 0.92 0.9 1"/>\n'
        '    <material name="rod_steel" rgba="0.7 0.72 0.75 1"/>\n'
        '    <material name="plate_blue" rgba="0.55 0.75 0.95 0.9"/>\n'
        '    <material name="ball_white" rgba="0.85 0.85 0.9 1"/>\n  </asset>\n',
        "  <worldbody>\n",
        f'    <light pos="0 0 {_f(3 * geo.home_height + 0.5)}" dir="0 0 -1" directional="true"/>\n',
        f'    <camera name="view" mode="targetbody" target="plate" pos="{_v(_camera_position(geo))}"/>\n',
    ]
    r = float(np.max(np.linalg.norm(geo.base_anchors[:, :2], axis=1))) * (1.0 if geo.is_rotary else 1.1) + 0.03
    base_z = float(np.min(geo.base_anchors[:, 2])) - 0.02
    out.append(f'    <geom name="base" type="cylinder" size="{_f(r)} 0.003" pos="0 0 {_f(base_z)}" material="base_grey"/>\n')
    out += _rotary_legs(geo, spec) if geo.is_rotary else _linear_legs(geo, spec)
    out += _plate(geo, spec)
    if ball is not None:
        out += _ball(geo, spec, ball, plate_friction, phys)
    out.append("  </worldbody>\n  <equality>\n")
    out += [f'    <connect name="loop_{i}" site1="rod_{i}_top" site2="anchor_{i}"/>\n' for i in range(6)]
    out.append("  </equality>\n  <actuator>\n")
    out += [f'    <velocity name="servo_{i}" joint="servo_{i}" kv="{_f(kv)}" '
            f'ctrlrange="{_f(-servo.max_speed)} {_f(servo.max_speed)}" '
            f'forcerange="{_f(-servo.stall_torque)} {_f(servo.stall_torque)}"/>\n' for i in range(6)]  # fmt: skip
    out.append("  </actuator>\n</mujoco>\n")
    return "".join(out)


def _camera_position(geo: PlatformGeometry) -> np.ndarray:
    """The reference view (yaw 35°, 20° down), widened for a big plate, as PyBullet's render."""
    distance = max(0.58, 1.95 * max(geo.plate_extent))
    yaw, pitch = np.radians(35.0), np.radians(-20.0)
    target = np.array([0.0, 0.0, geo.home_height * 0.55])
    return target + distance * np.array([-np.sin(yaw) * np.cos(pitch), np.cos(yaw) * np.cos(pitch), -np.sin(pitch)])


def _rotary_legs(geo: PlatformGeometry, spec: MechanismSpec) -> list[str]:
    tips, _, frames = rod_frames(geo)
    alpha0 = inverse_kinematics(geo, np.zeros(6)).servo_angles
    assert alpha0 is not None and geo.horn_length is not None and geo.servo_beta is not None
    lo, hi = geo.servo_angle_range  # type: ignore[misc]
    a, s = geo.horn_length, geo.rod_length
    horn_tip = horn_tips(geo, alpha0) - geo.base_anchors
    out = []
    for i in range(6):
        axis = servo_axis(float(geo.servo_beta[i]))
        horn_rot = frame_along(horn_tip[i], axis)
        rod_i = rod_inertia(spec.rod_mass, s, spec.rod_radius)
        out += [
            f'    <body name="horn_{i}" pos="{_v(geo.base_anchors[i])}">\n',
            f'      <geom type="box" size="0.008 0.018 0.02" pos="{_v(np.array([0, 0, -0.012]) - 0.008 * axis)}" '
            f'quat="{_quat(frame_along(np.array([0, 0, 1.0]), axis))}" material="servo_black"/>\n',
            f'      <joint name="servo_{i}" type="hinge" axis="{_v(axis)}" range="{_f(lo - alpha0[i])} '
            f'{_f(hi - alpha0[i])}" armature="{_f(spec.rotor_inertia)}"/>\n',
            f"      {_inertial(spec.horn_mass, horn_tip[i] / 2, rod_inertia(spec.horn_mass, a, 0.004), horn_rot)}\n",
            f'      <geom type="capsule" fromto="0 0 0 {_v(horn_tip[i])}" size="0.003" material="horn_white"/>\n',
            f'      <body name="rod_{i}" pos="{_v(horn_tip[i])}" quat="{_quat(frames[i])}">\n',
            f'        <joint name="rod_{i}_ball" type="ball"/>\n',
            f"        {_inertial(spec.rod_mass, np.array([0, 0, s / 2]), rod_i)}\n",
            f'        <geom type="capsule" fromto="0 0 0 0 0 {_f(s)}" size="{_f(spec.rod_radius)}" material="rod_steel"/>\n',
            f'        <site name="rod_{i}_top" pos="0 0 {_f(s)}"/>\n',
            "      </body>\n",
            "    </body>\n",
        ]
    return out


def _linear_legs(geo: PlatformGeometry, spec: MechanismSpec) -> list[str]:
    home = inverse_kinematics(geo, np.zeros(6)).leg_lengths
    lo, hi = geo.leg_length_range  # type: ignore[misc]
    tops = geo.platform_anchors + geo.home_position
    dirs = (tops - geo.base_anchors) / home[:, None]
    tube, r = geo.rod_length, spec.rod_radius
    out = []
    for i in range(6):
        frame = frame_along(dirs[i], np.cross(np.array([0, 0, 1.0]), dirs[i]) + np.array([1e-9, 0, 0]))
        rod = float(home[i]) - tube + 0.03
        out += [
            f'    <body name="tube_{i}" pos="{_v(geo.base_anchors[i])}" quat="{_quat(frame)}">\n',
            f'      <joint name="rod_{i}_u1" type="hinge" axis="1 0 0"/>\n',
            f'      <joint name="rod_{i}_u2" type="hinge" axis="0 1 0"/>\n',
            f"      {_inertial(spec.rod_mass, np.array([0, 0, tube / 2]), rod_inertia(spec.rod_mass, tube, 2 * r))}\n",
            f'      <geom type="cylinder" fromto="0 0 0 0 0 {_f(tube)}" size="{_f(2 * r)}" material="servo_black"/>\n',
            f'      <body name="rod_{i}" pos="0 0 {_f(home[i])}">\n',
            f'        <joint name="servo_{i}" type="slide" axis="0 0 1" range="{_f(lo - home[i])} {_f(hi - home[i])}" '
            f'armature="{_f(spec.actuator_reflected_mass)}"/>\n',
            f"        {_inertial(spec.rod_mass, np.array([0, 0, -rod / 2]), rod_inertia(spec.rod_mass, rod, r))}\n",
            f'        <geom type="cylinder" fromto="0 0 {_f(-rod)} 0 0 0" size="{_f(r)}" material="rod_steel"/>\n',
            f'        <site name="rod_{i}_top" pos="0 0 0"/>\n',
            "      </body>\n",
            "    </body>\n",
        ]
    return out


def _plate(geo: PlatformGeometry, spec: MechanismSpec) -> list[str]:
    zc = spec.plate_offset + spec.plate_thickness / 2
    (w, d), t = geo.plate_extent, spec.plate_thickness
    m = spec.plate_areal_mass * w * d
    inertia = (m * (d * d + t * t) / 12, m * (w * w + t * t) / 12, m * (w * w + d * d) / 12)
    out = [
        f'    <body name="plate" pos="{_v(geo.home_position)}">\n',
        '      <freejoint name="plate"/>\n',
        f"      {_inertial(m, np.array([0, 0, zc]), inertia)}\n",
        f'      <geom name="plate" type="box" size="{_f(w / 2)} {_f(d / 2)} {_f(t / 2)}" pos="0 0 {_f(zc)}" '
        'contype="1" conaffinity="1" condim="6" material="plate_blue"/>\n',
    ]
    out += [f'      <site name="anchor_{i}" pos="{_v(p)}"/>\n' for i, p in enumerate(geo.platform_anchors)]
    out.append("    </body>\n")
    return out


def _ball(geo: PlatformGeometry, spec: MechanismSpec, ball: BallSpec, plate_friction: float,
          phys: MujocoPhysics) -> list[str]:  # fmt: skip
    z = geo.home_height + spec.plate_top + ball.radius
    inertia = (ball.inertia,) * 3
    return [
        f'    <body name="ball" pos="0 0 {_f(z)}">\n',
        '      <freejoint name="ball"/>\n',
        f"      {_inertial(ball.mass, np.zeros(3), inertia)}\n",
        f'      <geom name="ball" type="sphere" size="{_f(ball.radius)}" contype="1" conaffinity="1" condim="6" '
        f'priority="1" solref="{_v(np.array(phys.contact_solref))}" '
        f'friction="{_v(np.array(ball_friction(ball, plate_friction)))}" material="ball_white"/>\n',
        "    </body>\n",
    ]


def ball_friction(ball: BallSpec, plate_friction: float) -> tuple[float, float, float]:
    """MuJoCo (sliding, torsional, rolling) friction of the ball–plate contact (see :func:`mechanism_mjcf`)."""
    return (ball.lateral_friction * plate_friction, ball.spinning_friction * plate_friction,
            ball.rolling_friction * plate_friction)  # fmt: skip


def write_mjcf(path: str | Path, geometry: PlatformGeometry | str = "servo-hexapod", *, ball: bool = True) -> Path:
    """Write the platform's MJCF (with the default ball unless ``ball=False``) to ``path``; return it."""
    path = make_parent(path)
    path.write_text(mechanism_mjcf(geometry, ball=BallSpec() if ball else None), encoding="utf-8")
    return path
