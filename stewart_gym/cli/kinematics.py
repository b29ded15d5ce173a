"""``stewart-gym`` kinematics commands: ik, urdf, mjcf, render."""

from __future__ import annotations

import argparse
import json
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from stewart_gym.calibration import ServoCalibration
from stewart_gym.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    add_geometry,
    bounded_float,
    finite_float,
    int_at_least,
    output_dir,
    output_file,
)
from stewart_gym.errors import UnreachableError
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.outputs import make_parent
from stewart_gym.presets import load_geometry

if TYPE_CHECKING:
    from stewart_gym.sim import StewartSim

__all__ = ["register", "settle_at"]


#: deg: the largest angle ``ik`` and ``render`` take, a whole turn either way (a position of any size is taken, and
#: is unreachable beyond the platform's reach).
MAX_POSE_ANGLE = 360.0


def _pose_args(parser: argparse.ArgumentParser) -> None:
    """Six positional pose values, each a finite number, the angles within ±:data:`MAX_POSE_ANGLE`."""
    for name, unit in (("x", "mm"), ("y", "mm"), ("z", "mm"), ("roll", "deg"), ("pitch", "deg"), ("yaw", "deg")):
        kind = finite_float if unit == "mm" else bounded_float(-MAX_POSE_ANGLE, MAX_POSE_ANGLE)
        limit = "" if unit == "mm" else f", ±{MAX_POSE_ANGLE:g}"
        parser.add_argument(f"{name}_{unit}", type=kind, metavar=f"{name.upper()}_{unit.upper()}",
                            help=f"{name} ({unit}{', from home' if name == 'z' else ''}{limit})")  # fmt: skip


def _pose(args: argparse.Namespace) -> np.ndarray:
    """The pose of the six positionals, m and rad."""
    return np.array([args.x_mm * 1e-3, args.y_mm * 1e-3, args.z_mm * 1e-3, math.radians(args.roll_deg),
                     math.radians(args.pitch_deg), math.radians(args.yaw_deg)])  # fmt: skip


# ------------------------------------------------------------- kinematics
def cmd_ik(args: argparse.Namespace) -> int:
    """Inverse kinematics of one pose: leg lengths, servo angles, pulse widths. Exit 1 if it is unreachable."""
    from stewart_gym.cli.analysis import json_safe

    geo = load_geometry(args.geometry)
    pose = _pose(args)
    ik = inverse_kinematics(geo, pose)
    out: dict = {
        "geometry": geo.name,
        "pose": {"x_mm": args.x_mm, "y_mm": args.y_mm, "z_mm": args.z_mm,
                 "roll_deg": args.roll_deg, "pitch_deg": args.pitch_deg, "yaw_deg": args.yaw_deg},  # fmt: skip
        "reachable": bool(ik.reachable),
        "leg_lengths_mm": (ik.leg_lengths * 1e3).round(4).tolist(),
        "status": [int(s) for s in ik.status],
    }
    if geo.is_rotary:
        out["servo_angles_deg"] = np.degrees(ik.servo_angles).round(4).tolist()
        cal = ServoCalibration.default(geo)
        out["pulse_widths_us"] = cal.pulse_widths(ik.servo_angles, out_of_range="nan").round(2).tolist()
    if args.json:
        print(json.dumps(json_safe(out)))
    else:
        print(ik.explain())
        for key in ("leg_lengths_mm", "servo_angles_deg", "pulse_widths_us"):
            if key in out:
                print(f"  {key:18s} " + "  ".join(f"{v:9.3f}" for v in out[key]))
    return EXIT_OK if ik.reachable else EXIT_FAILED


def cmd_urdf(args: argparse.Namespace) -> int:
    """Write the mechanism and plate URDFs of a geometry (rotary or linear)."""
    from stewart_gym.sim.urdf import write_urdfs

    geo = load_geometry(args.geometry)
    output_dir(args.out)
    for path in write_urdfs(args.out, geo):
        print(path)
    return EXIT_OK


def cmd_mjcf(args: argparse.Namespace) -> int:
    """Write a geometry's MuJoCo model (MJCF: closed loops, servos, plate, ball); python -m mujoco.viewer opens it."""
    from stewart_gym.sim.mjcf import write_mjcf

    geo = load_geometry(args.geometry)
    out = output_file(args.out, suffixes=(".xml",))
    write_mjcf(out, geo, ball=not args.no_ball)
    print(f"{out} (open it: python -m mujoco.viewer --mjcf {out})")
    return EXIT_OK


def settle_at(sim: StewartSim, pose: np.ndarray, seconds: float = 1.0) -> np.ndarray:
    """Command ``pose`` through IK → pulses, step ``seconds``, and return the pulses sent."""
    ik = inverse_kinematics(sim.geometry, pose)
    if not ik.reachable:
        raise UnreachableError(ik.explain())
    pulses = sim.calibration.pulse_widths(ik.actuators, out_of_range="nan")
    if np.isnan(pulses).any():
        raise UnreachableError(f"{ik.explain()}, but a pulse width would leave its channel's limits")
    sim.command(pulses)
    for _ in range(int(round(seconds * sim.control_hz))):
        sim.step()
    return pulses


def cmd_render(args: argparse.Namespace) -> int:
    """Render the simulated mechanism at a pose to a PNG file (exit 1 if the pose is unreachable)."""
    import imageio.v3 as iio

    from stewart_gym.sim import StewartSim

    geo = load_geometry(args.geometry)
    pose = _pose(args)
    out = output_file(args.out, suffixes=(".png",))
    ik = inverse_kinematics(geo, pose)
    if not ik.reachable:
        raise UnreachableError(ik.explain())
    with StewartSim(geo, ball=args.ball, render_mode="rgb_array", render_size=(args.width, args.height)) as sim:
        settle_at(sim, pose)
        if args.ball:
            sim.place_ball(np.zeros(2))
        make_parent(out).write_bytes(iio.imwrite("<bytes>", sim.render(), extension=".png"))  # (no '~' expanded)
        reached = sim.platform_pose()
        print(f"{out}: pose reached {np.round(reached[:3] * 1e3, 3).tolist()} mm, "
              f"{np.round(np.degrees(reached[3:]), 3).tolist()} deg")  # fmt: skip
    return EXIT_OK


def register(sub: Any) -> None:
    """Add the kinematics subcommands to the ``stewart-gym`` parser."""
    p = sub.add_parser("ik", help=cmd_ik.__doc__, description=cmd_ik.__doc__)
    add_geometry(p)
    _pose_args(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_ik)

    p = sub.add_parser("urdf", help=cmd_urdf.__doc__, description=cmd_urdf.__doc__)
    add_geometry(p)
    p.add_argument("--out", default="urdf", help="folder (default urdf/)")
    p.set_defaults(func=cmd_urdf)

    p = sub.add_parser("mjcf", help=cmd_mjcf.__doc__, description=cmd_mjcf.__doc__)
    add_geometry(p)
    p.add_argument("--out", required=True, help="MJCF file (.xml)")
    p.add_argument("--no-ball", action="store_true", help="the platform alone")
    p.set_defaults(func=cmd_mjcf)

    p = sub.add_parser("render", help=cmd_render.__doc__, description=cmd_render.__doc__)
    add_geometry(p)
    _pose_args(p)
    p.add_argument("--out", required=True, help="PNG file")
    p.add_argument("--ball", action="store_true", help="put a ball on the plate")
    p.add_argument("--width", type=int_at_least(16, 4096), default=640, help="pixels")
    p.add_argument("--height", type=int_at_least(16, 4096), default=480, help="pixels")
    p.set_defaults(func=cmd_render)

