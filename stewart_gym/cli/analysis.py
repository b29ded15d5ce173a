"""``stewart-gym`` subcommands of the kinematics analyses: workspace, trajectory, sensitivity, conditioning,
planar, assembly. Each takes ``--geometry NAME|FILE``, ``--json`` and, where it draws, ``--plot FILE.png``."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.analysis.planar import PLANAR_KEYS, PLANAR_PRESETS
from stewart_gym.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    bounded_float,
    int_at_least,
    json_safe,
    output_file,
    positive_float,
)
from stewart_gym.errors import ConfigError
from stewart_gym.presets import load_geometry
from stewart_gym.tomlio import read_toml

#: Source 003's built platform reached about ±25, ±28, ±15 mm in x, y, z.
SOURCE_003_RANGES_MM = (25.0, 28.0, 15.0)
#: mm: the largest length or position the analysis commands take (10 m, as a geometry's own lengths).
MAX_MM = 10_000.0
#: The largest planar parameter (a length in the file's own unit; gamma is within a turn): beyond it the planar
#: solver's polynomial overflows.
MAX_PLANAR = 1e6



def _emit(args: argparse.Namespace, result: dict[str, Any], lines: list[str], ok: bool = True) -> int:
    if args.json:
        print(json.dumps(json_safe(result)))
    else:
        print("\n".join(lines))
    return EXIT_OK if ok else EXIT_FAILED


def _plot_path(args: argparse.Namespace, name: str = "plot") -> Any:
    """The PNG path of ``--plot`` (or ``--sweep-plot``), checked before the work starts."""
    value = getattr(args, name, None)
    return None if value is None else output_file(value, suffixes=(".png",))


def _grid_extent(geo: Any) -> tuple[float, float]:
    from stewart_gym.kinematics import axis_ranges

    r = axis_ranges(geo)
    return float(max(-r[0, 0], r[0, 1], -r[1, 0], r[1, 1])) * 1.1, float(max(-r[2, 0], r[2, 1])) * 1.2


def cmd_workspace(args: argparse.Namespace) -> int:
    """Reach along each axis, the reachable-z map over x–y (source 002) and sampled workspace volumes."""
    from stewart_gym.analysis.plots import plot_height_map
    from stewart_gym.analysis.workspace import MAX_SCAN_POSES, height_map, reachable_volume, scan_poses
    from stewart_gym.kinematics import axis_ranges

    geo = load_geometry(args.geometry)
    _plot_path(args)
    pivot = None if args.pivot is None else np.array(args.pivot) * 1e-3
    orient = tuple(math.radians(v) for v in args.orientation)
    reach = axis_ranges(geo, pivot)
    xy_ext, z_ext = _grid_extent(geo)
    if args.range is not None:
        xy_ext = args.range * 1e-3
    step = args.z_step * 1e-3
    grid = np.linspace(-xy_ext, xy_ext, args.n)
    for _ in range(4):  # the heights searched widen while the reachable ones reach their edge
        levels = np.arange(-math.ceil(z_ext / step), math.ceil(z_ext / step) + 1) * step
        if scan_poses(args.n * args.n, len(levels)) > MAX_SCAN_POSES:
            raise ConfigError(f"--n {args.n} with --z-step {args.z_step:g} scans {scan_poses(args.n**2, len(levels)):,} "
                              f"poses at once, more than {MAX_SCAN_POSES:,}: lower --n or raise --z-step")  # fmt: skip
        hm = height_map(geo, orient, pivot, x=grid, y=grid, z_levels=levels)
        at_edge = bool(np.isfinite(hm.z_max).any() and (np.nanmin(hm.z_min) <= levels[0] + 1e-12
                                                        or np.nanmax(hm.z_max) >= levels[-1] - 1e-12))  # fmt: skip
        if not at_edge:
            break
        z_ext *= 2
    vol = reachable_volume(geo, samples=args.samples, pivot=pivot)
    res: dict[str, Any] = {
        "geometry": geo.name,
        "axis_ranges": {"x_mm": reach[0] * 1e3, "y_mm": reach[1] * 1e3, "z_mm": reach[2] * 1e3,
                        "roll_deg": np.degrees(reach[3]), "pitch_deg": np.degrees(reach[4]),
                        "yaw_deg": np.degrees(reach[5])},  # fmt: skip
        "height_map": {"grid_points": args.n, "xy_extent_mm": xy_ext * 1e3, "z_step_mm": args.z_step,
                       "max_z_mm": round(float(np.nanmax(hm.z_max) * 1e3), 4) if np.isfinite(hm.z_max).any() else None,
                       "min_z_mm": round(float(np.nanmin(hm.z_min) * 1e3), 4) if np.isfinite(hm.z_min).any() else None,
                       "reachable_fraction": float(np.isfinite(hm.z_max).mean()),
                       "z_limited_by_grid": at_edge},  # fmt: skip
        "volume": vol,
    }
    lines = [f"{geo.name}: reach from home along each axis (others at 0)"]
    for k, (axis, unit, scale) in enumerate([("x", "mm", 1e3), ("y", "mm", 1e3), ("z", "mm", 1e3),
                                             ("roll", "°", 180 / math.pi), ("pitch", "°", 180 / math.pi),
                                             ("yaw", "°", 180 / math.pi)]):  # fmt: skip
        source = geo.name == "servo-hexapod" and k < 3
        extra = f"   (source 003's build: ±{SOURCE_003_RANGES_MM[k]:.0f} mm)" if source else ""
        lines.append(f"  {axis:5s} {reach[k, 0] * scale:9.2f} … {reach[k, 1] * scale:8.2f} {unit}{extra}")
    if geo.name == "servo-hexapod":
        res["source_003_ranges_mm"] = SOURCE_003_RANGES_MM
    hmr = res["height_map"]
    if hmr["max_z_mm"] is None:
        lines.append(f"reachable z over a {args.n}×{args.n} grid of ±{xy_ext * 1e3:.1f} mm: no height of the grid is "
                     f"reachable at orientation {list(args.orientation)}°")  # fmt: skip
    else:
        lines.append(f"reachable z over a {args.n}×{args.n} grid of ±{xy_ext * 1e3:.1f} mm at {args.z_step} mm steps: "
                     f"{hmr['min_z_mm']} … {hmr['max_z_mm']} mm, {hmr['reachable_fraction']:.1%} of the grid")  # fmt: skip
    if at_edge:
        lines.append(f"  (z reaches the edge of the searched range ±{z_ext * 1e3:.1f} mm: the true extreme lies beyond)")
    lines.append(f"translational workspace at home orientation ≈ {vol['volume_translation_m3'] * 1e9:,.1f} mm³; "
                 f"{vol['fraction_6dof']:.2%} of the 6-DoF box is reachable ({vol['samples']:,} samples)")  # fmt: skip
    if args.plot:
        plot_height_map(hm, args.plot, f"{geo.name}: reachable z (orientation {args.orientation} °)")
    return _emit(args, res, lines)


def cmd_trajectory(args: argparse.Namespace) -> int:
    """Run a trajectory (source 001's circle or a CSV of poses) through the IK against the limits."""
    from stewart_gym.analysis.plots import plot_trajectory
    from stewart_gym.analysis.trajectories import circle, load_pose_csv, trajectory_check

    geo = load_geometry(args.geometry)
    _plot_path(args)
    if args.csv:
        t, poses = load_pose_csv(args.csv)
    else:
        t, poses = circle(args.radius * 1e-3, args.samples, z=args.z * 1e-3)
    res = trajectory_check(geo, t, poses)
    lines = [f"{geo.name}: {len(t)} samples, {res['unreachable_fraction']:.1%} unreachable",
             "first unreachable: " + ("none" if res["first_unreachable"] is None else
                                      f"sample {res['first_unreachable']} at t = {res['first_unreachable_t']:.3f} s"),
             res["explanation"]]  # fmt: skip
    if args.plot:
        plot_trajectory(res, args.plot, f"{geo.name}: trajectory against the actuator limits")
    out = {k: res[k] for k in ("first_unreachable", "first_unreachable_t", "explanation", "unreachable_fraction",
                               "actuator_limits")}  # fmt: skip
    out["geometry"], out["samples"] = geo.name, len(t)
    return _emit(args, out, lines, ok=res["first_unreachable"] is None)


def cmd_sensitivity(args: argparse.Namespace) -> int:
    """Platform motion per servo step (source 003) over the x–y workspace; Jacobian cross-checked by FK."""
    from stewart_gym.analysis.plots import plot_sensitivity
    from stewart_gym.analysis.sensitivity import fd_check, sensitivity, xy_grid_poses

    geo = load_geometry(args.geometry)
    _plot_path(args)
    ext, _ = _grid_extent(geo)
    grid = np.linspace(-ext, ext, args.n)
    poses = xy_grid_poses(grid, grid)
    res = sensitivity(geo, poses, math.radians(args.step_deg))
    worst = res.worst()
    rng = np.random.default_rng(0)
    sample = poses.reshape(-1, 6)[res.reachable.ravel()]
    fd = fd_check(geo, sample[rng.choice(len(sample), min(args.fd_samples, len(sample)), replace=False)],
                  math.radians(args.step_deg))  # fmt: skip
    i = np.unravel_index(np.nanargmax(res.position_step), res.position_step.shape)
    out = {"geometry": geo.name, "servo_step_deg": args.step_deg, **worst, "fd_relative_error": fd,
           "least_precise_xy_mm": [float(grid[i[1]] * 1e3), float(grid[i[0]] * 1e3)]}  # fmt: skip
    lines = [f"{geo.name}: platform motion for a {args.step_deg}° servo step, over a {args.n}×{args.n} x–y grid",
             f"  one servo: translation {worst['best_position_step_mm']:.4f} … {worst['worst_position_step_mm']:.4f} mm, "
             f"rotation up to {worst['worst_angle_step_deg']:.4f}°",
             f"  all six off by the step: x, y, z up to {np.round(worst['worst_all_servos_xyz_mm'], 4).tolist()} mm, "
             f"roll, pitch, yaw up to {np.round(worst['worst_all_servos_rpy_deg'], 4).tolist()}°",
             f"  least precise at x, y = {out['least_precise_xy_mm']} mm",
             f"  source 003's small-angle estimate a·Δα = {worst['small_angle_estimate_mm']:.4f} mm",
             f"  Jacobian vs finite differences through FK: relative error {fd:.2e}"]  # fmt: skip
    if args.plot:
        plot_sensitivity(grid, grid, res.position_step, res.angle_step, args.plot,
                         f"{geo.name}: motion per {args.step_deg}° servo step")  # fmt: skip
    return _emit(args, out, lines)


def cmd_conditioning(args: argparse.Namespace) -> int:
    """Condition number of the Jacobian over the x–y workspace; near-singular poses flagged."""
    from stewart_gym.analysis.plots import plot_conditioning
    from stewart_gym.analysis.sensitivity import conditioning, xy_grid_poses

    geo = load_geometry(args.geometry)
    _plot_path(args)
    ext, _ = _grid_extent(geo)
    grid = np.linspace(-ext, ext, args.n)
    res = conditioning(geo, xy_grid_poses(grid, grid, orientation=tuple(math.radians(v) for v in args.orientation)),
                       args.threshold)  # fmt: skip
    cond, near = res["cond"], res["near_singular"]
    if not np.isfinite(cond).any():
        raise ConfigError(f"no pose of the {args.n}×{args.n} grid is reachable at orientation "
                          f"{list(args.orientation)}°: {geo.name!r} cannot tilt that far; try a smaller one")  # fmt: skip
    gx, gy = np.meshgrid(grid, grid)
    flagged = [[float(gx[i] * 1e3), float(gy[i] * 1e3), float(cond[i])] for i in zip(*np.nonzero(near))]
    out = {"geometry": geo.name, "min_cond": float(np.nanmin(cond)), "max_cond": float(np.nanmax(cond)),
           "threshold": args.threshold, "near_singular_count": int(near.sum()), "near_singular_xy_mm_cond": flagged[:50],
           "length_scale_m": res["length_scale_m"]}  # fmt: skip
    lines = [f"{geo.name}: cond(J) over the reachable {args.n}×{args.n} grid: {out['min_cond']:.2f} … "
             f"{out['max_cond']:.2f}; {out['near_singular_count']} poses above {args.threshold:g}"]  # fmt: skip
    if args.plot:
        plot_conditioning(grid, grid, cond, near, args.plot, f"{geo.name}: conditioning of the Jacobian")
    return _emit(args, out, lines)


def _planar_params(args: argparse.Namespace) -> dict[str, float]:
    if args.geometry in PLANAR_PRESETS:
        params = dict(PLANAR_PRESETS[args.geometry])
    else:
        data = read_toml(args.geometry, what="planar geometry file")
        unknown = sorted(set(data) - set(PLANAR_KEYS) - {"name", "description"})
        if unknown:
            raise ConfigError(f"{args.geometry}: unknown key(s) {unknown}; a planar geometry gives {list(PLANAR_KEYS)}")
        missing = [k for k in PLANAR_KEYS if k not in data]
        if missing:
            raise ConfigError(f"{args.geometry}: missing planar parameter(s) {missing}")
        bad = [k for k in PLANAR_KEYS if isinstance(data[k], bool) or not isinstance(data[k], (int, float))
               or not abs(data[k]) <= (2 * math.pi if k == "gamma" else MAX_PLANAR)]  # fmt: skip
        if bad:
            raise ConfigError(f"{args.geometry}: planar parameter(s) {bad} must be finite numbers within ±{MAX_PLANAR:g} "
                              "(gamma within a turn, ±2π rad)")  # fmt: skip
        params = {k: float(data[k]) for k in PLANAR_KEYS}
    for k in PLANAR_KEYS:
        v = getattr(args, k)
        if v is not None:
            params[k] = v
    return params


def _sweep_spec(text: str) -> tuple[str, float, float, int]:
    """STRUT:START:STOP:N, checked: a strut name, two positive finite lengths, N ≥ 2."""
    parts = text.split(":")
    try:
        if len(parts) != 4 or parts[0] not in ("p1", "p2", "p3"):
            raise ValueError
        start, stop, n = float(parts[1]), float(parts[2]), int(parts[3])
        if not (0 < start < stop <= MAX_PLANAR and 2 <= n <= 100_000):
            raise ValueError
    except ValueError:
        raise ConfigError(f"--sweep {text!r}: expected STRUT:START:STOP:N with STRUT p1, p2 or p3, "
                          f"0 < START < STOP ≤ {MAX_PLANAR:g} and 2 ≤ N ≤ 100000, e.g. p2:0.5:12:231") from None  # fmt: skip
    return parts[0], start, stop, n


def cmd_planar(args: argparse.Namespace) -> int:
    """All poses of the planar 3-RPR platform (source 004), optionally sweeping one strut."""
    from stewart_gym.analysis.planar import planar_continua, solve_planar, sweep_strut
    from stewart_gym.analysis.plots import plot_planar, plot_sweep

    params = _planar_params(args)
    _plot_path(args)
    _plot_path(args, "sweep_plot")
    sweep = _sweep_spec(args.sweep) if args.sweep else None
    if args.sweep_plot and not sweep:
        raise ConfigError("--sweep-plot draws a sweep: add --sweep STRUT:START:STOP:N, or leave it out")
    if args.plot and args.sweep_plot and Path(args.plot).resolve() == Path(args.sweep_plot).resolve():
        raise ConfigError(f"--plot and --sweep-plot are both {args.plot}: give two files")
    poses = solve_planar(**params)
    continua = planar_continua(**params)
    out: dict[str, Any] = {"parameters": params, "poses": poses, "count": len(poses), "continua_theta": continua}
    lines = [f"{len(poses)} pose(s) (x, y, θ):"] + [f"  {p[0]: .6f} {p[1]: .6f} {p[2]: .6f}" for p in poses]
    lines += [f"and a continuum at θ = {t:.6f}: there the moving triangle matches the base triangle and the struts are "
              f"equal, so the first vertex may be anywhere on the circle of radius p1 = {params['p1']:g} about its "
              "anchor (the struts stay parallel)" for t in continua]  # fmt: skip
    if args.plot:
        plot_planar(poses, params, args.plot)
    if sweep:
        strut, start, stop, n = sweep
        values = np.linspace(start, stop, n)
        counts, changes = sweep_strut(params, strut, values, progress=not args.json)
        out["sweep"] = {"strut": strut, "values": values, "counts": counts, "changes": changes}
        lines.append(f"sweeping {strut} over {start}…{stop}: the number of poses changes at")
        lines += [f"  {strut} = {v:.4f}: {a} → {b}" for v, a, b in changes]
        if args.sweep_plot:
            plot_sweep(values, counts, strut, changes, args.sweep_plot)
    return _emit(args, out, lines)


def cmd_assembly(args: argparse.Namespace) -> int:
    """All real assembly modes (FK branches) found from many starting guesses, for given leg lengths, or for a rotary
    build the servo angles of a pose."""
    from stewart_gym.analysis.assembly import assembly_modes
    from stewart_gym.kinematics import inverse_kinematics

    geo = load_geometry(args.geometry)
    if args.legs and geo.is_rotary:
        raise ConfigError(f"--legs: {geo.name!r} is a rotary build, whose rods have one length; its assembly modes "
                          "are those of the servo angles of a pose: give --pose instead")  # fmt: skip
    if args.legs:
        lengths = np.array(args.legs) * 1e-3
        if not np.all(lengths > 0):
            raise ConfigError("--legs: leg lengths must be positive (mm)")
        modes = assembly_modes(geo, lengths, guesses=args.guesses, progress=not args.json)
        out = {"geometry": geo.name, "leg_lengths_mm": lengths * 1e3}
    else:
        if any(abs(v) > 360.0 for v in args.pose[3:]):
            raise ConfigError(f"--pose: the angles must be within ±360°, got {list(args.pose[3:])}")
        pose = np.array([v * 1e-3 for v in args.pose[:3]] + [math.radians(v) for v in args.pose[3:]])
        ik = inverse_kinematics(geo, pose)
        if geo.is_rotary:
            if not ik.reachable:
                raise ConfigError(f"--pose: {ik.explain()}; give a pose the servos reach (stewart-gym ik checks one)")
            modes = assembly_modes(geo, servo_angles=ik.servo_angles, guesses=args.guesses, progress=not args.json)
            out = {"geometry": geo.name, "servo_angles_deg": np.degrees(ik.servo_angles)}
        else:
            modes = assembly_modes(geo, ik.leg_lengths, guesses=args.guesses, progress=not args.json)
            out = {"geometry": geo.name, "leg_lengths_mm": ik.leg_lengths * 1e3}
    out |= {"count": len(modes), "modes_mm_deg": np.c_[modes[:, :3] * 1e3, np.degrees(modes[:, 3:])]}
    given = "servo angles" if "servo_angles_deg" in out else "leg lengths"
    lines = [f"{geo.name}: {len(modes)} distinct real assembly modes for these {given} from {args.guesses} guesses "
             "(x, y, z mm from home; roll, pitch, yaw °):"]  # fmt: skip
    lines += ["  " + " ".join(f"{v:9.3f}" for v in row) for row in out["modes_mm_deg"]]
    return _emit(args, out, lines)


def _common(p: Any, geometry: str, plot: bool = True) -> None:
    """The options every analysis takes."""
    p.add_argument("--geometry", default=geometry, help="preset name or TOML file")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    if plot:
        p.add_argument("--plot", help="PNG file")


def register(sub: Any) -> None:
    """Add the analysis subcommands to the ``stewart-gym`` parser."""
    angles = dict(nargs=3, type=bounded_float(-180.0, 180.0), metavar=("ROLL", "PITCH", "YAW"))
    p = sub.add_parser("workspace", help=cmd_workspace.__doc__, description=cmd_workspace.__doc__)
    _common(p, "servo-hexapod")
    p.add_argument("--orientation", default=(0.0, 0.0, 0.0), help="degrees", **angles)
    p.add_argument("--pivot", nargs=3, type=bounded_float(-MAX_MM, MAX_MM), metavar=("X", "Y", "Z"),
                   help="mm, platform frame (±10 m)")  # fmt: skip
    p.add_argument("--range", type=bounded_float(0.0, MAX_MM, lo_open=True), help="half-width of the x–y grid, mm")
    p.add_argument("--n", type=int_at_least(2, 2000), default=100, help="grid points per axis (2–2000)")
    p.add_argument("--z-step", type=bounded_float(0.001, 100.0), default=0.1, help="mm")
    p.add_argument("--samples", type=int_at_least(1, 50_000_000), default=200_000,
                   help="Monte Carlo samples for the volumes")  # fmt: skip
    p.set_defaults(func=cmd_workspace)
    p = sub.add_parser("trajectory", help=cmd_trajectory.__doc__, description=cmd_trajectory.__doc__ +
                       " Exit 1 if any sample is unreachable.")  # fmt: skip
    _common(p, "senilov2018")
    p.add_argument("--csv", help="poses: t_s, x_m|x_mm, …, roll_rad|roll_deg, …")
    p.add_argument("--radius", type=bounded_float(0.0, MAX_MM, lo_open=True), default=200.0,
                   help="circle radius, mm (source 001: 200)")  # fmt: skip
    p.add_argument("--z", type=bounded_float(-MAX_MM, MAX_MM), default=0.0, help="circle height from home, mm")
    p.add_argument("--samples", type=int_at_least(2, 10_000_000), default=1000, help="poses along the circle")
    p.set_defaults(func=cmd_trajectory)
    p = sub.add_parser("sensitivity", help=cmd_sensitivity.__doc__, description=cmd_sensitivity.__doc__)
    _common(p, "servo-hexapod")
    p.add_argument("--step-deg", type=bounded_float(0.0, 10.0, lo_open=True), default=0.1,
                   help="servo step, degrees (source 003: 0.1)")  # fmt: skip
    p.add_argument("--n", type=int_at_least(2, 1000), default=61, help="grid points per axis of the x–y grid")
    p.add_argument("--fd-samples", type=int_at_least(1, 100_000), default=100,
                   help="poses for the finite-difference check")  # fmt: skip
    p.set_defaults(func=cmd_sensitivity)
    p = sub.add_parser("conditioning", help=cmd_conditioning.__doc__, description=cmd_conditioning.__doc__)
    _common(p, "servo-hexapod")
    p.add_argument("--orientation", default=(0.0, 0.0, 0.0), help="degrees", **angles)
    p.add_argument("--threshold", type=positive_float, default=1e3,
                   help="condition number above which a pose is flagged near-singular")
    p.add_argument("--n", type=int_at_least(2, 1000), default=61, help="grid points per axis of the x–y grid")
    p.set_defaults(func=cmd_conditioning)
    p = sub.add_parser("planar", help=cmd_planar.__doc__, description=cmd_planar.__doc__)
    p.add_argument("--geometry", default="sauer", help=f"{', '.join(PLANAR_PRESETS)} or a TOML with {PLANAR_KEYS}")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", help="PNG of every pose")
    for k in PLANAR_KEYS:
        limit = 2 * math.pi if k == "gamma" else MAX_PLANAR
        p.add_argument(f"--{k}", type=bounded_float(-limit, limit), help="override" + (" (rad)" if k == "gamma" else ""))
    p.add_argument("--sweep", help="STRUT:START:STOP:N, e.g. p2:0.5:12:231")
    p.add_argument("--sweep-plot", help="PNG of the pose count against the swept strut")
    p.set_defaults(func=cmd_planar)
    p = sub.add_parser("assembly", help=cmd_assembly.__doc__, description=cmd_assembly.__doc__)
    _common(p, "senilov2018", plot=False)
    p.add_argument("--legs", nargs=6, type=bounded_float(0.0, MAX_MM, lo_open=True), metavar="MM",
                   help="leg lengths, mm (instead of --pose; a linear build)")  # fmt: skip
    p.add_argument("--pose", nargs=6, type=bounded_float(-MAX_MM, MAX_MM), default=(10, 0, 0, 3, 1, 6), metavar="V",
                   help="a pose X Y Z (mm, from home) ROLL PITCH YAW (°) whose leg lengths are used (a rotary "
                        "build: its servo angles); default 10 0 0 3 1 6; ignored with --legs")  # fmt: skip
    p.add_argument("--guesses", type=int_at_least(1, 1_000_000), default=4000,
                   help="starting guesses for the forward kinematics")
    p.set_defaults(func=cmd_assembly)
