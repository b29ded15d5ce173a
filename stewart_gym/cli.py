"""The ``stewart-gym`` command line."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from stewart_gym.geometry import load_geometry, preset_names
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.servo import ServoCalibration

if TYPE_CHECKING:
    from stewart_gym.sim import StewartSim


def _geometry_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--geometry", default="servo-hexapod", help=f"preset ({', '.join(preset_names())}) or TOML file")


def _json_safe(value: object) -> object:
    """Replace NaN/inf floats by None so the output is strict JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def cmd_ik(args: argparse.Namespace) -> int:
    """Inverse kinematics of one pose: leg lengths, servo angles, pulse widths."""
    geo = load_geometry(args.geometry)
    pose = np.array([v * 1e-3 for v in args.pose[:3]] + [math.radians(v) for v in args.pose[3:]])
    ik = inverse_kinematics(geo, pose)
    out: dict = {
        "geometry": geo.name,
        "pose": {"x_mm": args.pose[0], "y_mm": args.pose[1], "z_mm": args.pose[2],
                 "roll_deg": args.pose[3], "pitch_deg": args.pose[4], "yaw_deg": args.pose[5]},  # fmt: skip
        "reachable": bool(ik.reachable),
        "leg_lengths_mm": (ik.leg_lengths * 1e3).round(4).tolist(),
        "status": [int(s) for s in ik.status],
    }
    if geo.is_rotary:
        out["servo_angles_deg"] = np.degrees(ik.servo_angles).round(4).tolist()
        cal = ServoCalibration.default(geo)
        out["pulse_widths_us"] = cal.pulse_widths(ik.servo_angles, out_of_range="nan").round(2).tolist()
    if args.json:
        print(json.dumps(_json_safe(out)))
    else:
        print(ik.explain())
        for key in ("leg_lengths_mm", "servo_angles_deg", "pulse_widths_us"):
            if key in out:
                print(f"  {key:18s} " + "  ".join(f"{v:9.3f}" for v in out[key]))
    return 0 if ik.reachable else 1


def cmd_demo(args: argparse.Namespace) -> int:
    """Pulse widths along a demo trajectory: a 20 mm circle with a tilt that follows it."""
    geo = load_geometry(args.geometry)
    cal = ServoCalibration.default(geo)
    t = np.linspace(0.0, 2.0, 9)
    phase = 2 * math.pi * t / 2.0
    poses = np.zeros((len(t), 6))
    poses[:, 0] = 0.02 * np.cos(phase)
    poses[:, 1] = 0.02 * np.sin(phase)
    poses[:, 3] = math.radians(5) * np.sin(phase)
    poses[:, 4] = -math.radians(5) * np.cos(phase)
    ik = inverse_kinematics(geo, poses)
    pulses = cal.pulse_widths(ik.servo_angles, out_of_range="nan")
    print(f"{geo.name}: h0 = {geo.home_height * 1e3:.2f} mm, α0 = {math.degrees(cal.home_angle[0]):.2f}°, "
          f"pulse limits {cal.min_us[0]:.0f}…{cal.max_us[0]:.0f} µs")  # fmt: skip
    print(f"{'t s':>5} {'x mm':>7} {'y mm':>7} {'roll°':>6} {'pitch°':>6}  " + " ".join(f"{'W' + str(i) + ' µs':>8}" for i in range(6)))
    for k in range(len(t)):
        print(f"{t[k]:5.2f} {poses[k, 0] * 1e3:7.2f} {poses[k, 1] * 1e3:7.2f} {math.degrees(poses[k, 3]):6.2f} "
              f"{math.degrees(poses[k, 4]):6.2f}  " + " ".join(f"{w:8.1f}" for w in pulses[k]))  # fmt: skip
    print(f"reachable: {int(ik.reachable.sum())}/{len(t)} poses")
    return 0


def cmd_urdf(args: argparse.Namespace) -> int:
    """Write the mechanism and plate URDFs of a rotary geometry."""
    from stewart_gym.sim.urdf import write_urdfs

    for path in write_urdfs(args.out, args.geometry):
        print(path)
    return 0


def settle_at(sim: StewartSim, pose: np.ndarray, seconds: float = 1.0) -> np.ndarray:
    """Command ``pose`` through IK → pulses, step ``seconds``, and return the pulses sent."""
    ik = inverse_kinematics(sim.geometry, pose)
    if not ik.reachable:
        raise ValueError(ik.explain())
    pulses = sim.calibration.pulse_widths(ik.servo_angles)
    sim.command(pulses)
    for _ in range(int(round(seconds * sim.control_hz))):
        sim.step()
    return pulses


def cmd_render(args: argparse.Namespace) -> int:
    """Render the simulated mechanism at a pose to a PNG file."""
    import imageio.v3 as iio

    from stewart_gym.sim import StewartSim

    pose = np.array([v * 1e-3 for v in args.pose[:3]] + [math.radians(v) for v in args.pose[3:]])
    size = (args.width, args.height)
    with StewartSim(args.geometry, ball=args.ball, render_mode="rgb_array", render_size=size) as sim:
        settle_at(sim, pose)
        if args.ball:
            sim.place_ball(np.zeros(2))
        iio.imwrite(args.out, sim.render())
        print(f"{args.out}: pose reached {np.round(sim.platform_pose()[:3] * 1e3, 3).tolist()} mm, "
              f"{np.round(np.degrees(sim.platform_pose()[3:]), 3).tolist()} deg")  # fmt: skip
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stewart-gym", description="Servo Stewart platform toolkit")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("ik", help=cmd_ik.__doc__)
    _geometry_arg(p)
    p.add_argument("pose", nargs=6, type=float, metavar=("X_MM", "Y_MM", "Z_MM", "ROLL_DEG", "PITCH_DEG", "YAW_DEG"))
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_ik)
    p = sub.add_parser("urdf", help=cmd_urdf.__doc__)
    _geometry_arg(p)
    p.add_argument("--out", default="urdf", help="directory (default urdf/)")
    p.set_defaults(func=cmd_urdf)
    p = sub.add_parser("render", help=cmd_render.__doc__)
    _geometry_arg(p)
    p.add_argument("pose", nargs=6, type=float, metavar=("X_MM", "Y_MM", "Z_MM", "ROLL_DEG", "PITCH_DEG", "YAW_DEG"))
    p.add_argument("--out", required=True, help="PNG file")
    p.add_argument("--ball", action="store_true", help="put a ball on the plate")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.set_defaults(func=cmd_render)
    p = sub.add_parser("demo", help=cmd_demo.__doc__)
    _geometry_arg(p)
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
