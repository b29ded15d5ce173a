"""Kinematic analyses on cases with answers known independently."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from stewart_gym.analysis.assembly import assembly_modes
from stewart_gym.analysis.planar import PLANAR_PRESETS, planar_continua, planar_f, planar_struts, solve_planar, sweep_strut
from stewart_gym.analysis.sensitivity import conditioning, fd_check, sensitivity, xy_grid_poses
from stewart_gym.analysis.trajectories import circle, load_pose_csv, trajectory_check
from stewart_gym.analysis.workspace import height_map, reachable_volume
from stewart_gym.cli import main
from stewart_gym.errors import ConfigError
from stewart_gym.kinematics import axis_ranges, forward_kinematics, horn_tips, inverse_kinematics
from stewart_gym.presets import load_preset

MM = 1e-3


# ------------------------------------------------------------------ workspace
def test_mathcad_height_map_agrees_with_the_seeds_check() -> None:
    """Source 002's Check(x, y): for k = 0…30, keep k/10 mm if every leg is within 31.44 ± 1.24 mm."""
    g = load_preset("mathcad-micro")
    pivot = np.array([10, 0, 10]) * MM
    xs = np.linspace(-2.5, 2.5, 100) * MM
    hm = height_map(g, pivot=pivot, x=xs, y=xs, z_levels=np.arange(31) / 10 * MM)

    def check(x: float, y: float) -> float:  # literal transcription of the Mathcad procedure
        temp = 0.0
        for k in range(31):
            t = np.array([x + 10 * MM, y, k / 10 * MM + 22.19 * MM + 10 * MM])
            legs = t + (g.platform_anchors - pivot) - g.base_anchors
            length = np.linalg.norm(legs, axis=1) - 31.44 * MM
            if length.max() < 1.24 * MM and length.min() > -1.24 * MM:
                temp = k / 10
        return temp

    rng = np.random.default_rng(0)
    for i, j in rng.integers(0, 100, (200, 2)):
        got = hm.z_max[i, j]
        assert (0.0 if np.isnan(got) else got / MM) == pytest.approx(check(xs[j], xs[i]), abs=1e-9)


def test_symmetric_geometry_has_a_symmetric_workspace() -> None:
    g = load_preset("servo-hexapod")
    xs = np.linspace(-0.05, 0.05, 41)
    hm = height_map(g, x=xs, y=xs, z_levels=np.arange(-250, 251) * 1e-4)
    assert np.array_equal(np.isnan(hm.z_max), np.isnan(hm.z_max[:, ::-1]))
    assert np.allclose(hm.z_max, hm.z_max[:, ::-1], equal_nan=True)  # mirror x → −x
    # 120° symmetry of the reach along x/y directions is not axis-aligned, but roll/pitch mirror: pitch range is ±
    r = axis_ranges(g)
    assert r[0, 0] == pytest.approx(-r[0, 1], rel=1e-6) and r[4, 0] == pytest.approx(-r[4, 1], rel=1e-6)
    assert r[5, 0] == pytest.approx(-r[5, 1], rel=1e-6)


def test_height_map_equals_a_full_scan() -> None:
    g = load_preset("servo-hexapod")
    xs = np.linspace(-0.06, 0.06, 9)
    levels = np.arange(-250, 251) * 1e-4
    hm = height_map(g, (0.05, -0.02, 0.1), x=xs, y=xs, z_levels=levels)
    gx, gy = np.meshgrid(xs, xs)
    poses = np.zeros(gx.shape + (len(levels), 6))
    poses[..., 0], poses[..., 1] = gx[..., None], gy[..., None]
    poses[..., 2], poses[..., 3:] = levels, (0.05, -0.02, 0.1)
    reach = inverse_kinematics(g, poses).reachable
    ref_max = np.where(reach.any(-1), levels[np.where(reach, np.arange(len(levels)), -1).max(-1)], np.nan)
    ref_min = np.where(reach.any(-1), levels[np.where(reach, np.arange(len(levels)), 10**6).min(-1) % 10**6], np.nan)
    assert np.allclose(hm.z_max, ref_max, equal_nan=True) and np.allclose(hm.z_min, ref_min, equal_nan=True)


def test_reachable_volume_is_consistent() -> None:
    v = reachable_volume(load_preset("servo-hexapod"), samples=50_000)
    assert 0 < v["fraction_6dof"] < v["fraction_translation"] < 1
    assert v["fraction_6dof_se"] < 0.01


# --------------------------------------------------------------- trajectories
def test_seed_001_circle_names_the_first_unreachable_sample() -> None:
    t, poses = circle(0.2, 200)
    res = trajectory_check(load_preset("senilov2018"), t, poses)
    assert res["first_unreachable"] == 0 and "above the upper actuator limit" in res["explanation"]
    small = trajectory_check(load_preset("servo-hexapod"), *circle(0.02, 200))
    assert small["first_unreachable"] is None and np.all(np.isfinite(small["pulses_us"]))
    t, poses = circle(0.045, 400)  # 45 mm: within the x reach (45.7 mm), beyond +y (44.2 mm)
    res = trajectory_check(load_preset("servo-hexapod"), t, poses)
    k = res["first_unreachable"]
    assert k is not None and res["reachable"][:k].all() and not res["reachable"][k]


def test_pose_csv_units(tmp_path: Path) -> None:
    path = tmp_path / "p.csv"
    path.write_text("t_s,x_mm,roll_deg\n0,1,0\n0.5,2,10\n")
    t, poses = load_pose_csv(str(path))
    assert t.tolist() == [0, 0.5] and poses[1, 0] == pytest.approx(0.002) and poses[1, 3] == pytest.approx(math.radians(10))
    path.write_text("x\n1\n")
    with pytest.raises(ValueError, match="unknown column"):
        load_pose_csv(str(path))


# ---------------------------------------------------------------- sensitivity
def test_sensitivity_jacobian_agrees_with_finite_differences() -> None:
    g = load_preset("servo-hexapod")
    rng = np.random.default_rng(1)
    poses = rng.uniform(-1, 1, (60, 6)) * [0.01, 0.01, 0.008, 0.1, 0.1, 0.2]
    assert fd_check(g, poses) < 1e-5
    res = sensitivity(g, xy_grid_poses(np.linspace(-0.03, 0.03, 11), np.linspace(-0.03, 0.03, 11)))
    worst = res.worst()
    # one 0.1° servo step moves the plate by about the horn tip's arc, scaled by the linkage
    assert 0.5 < worst["worst_position_step_mm"] / worst["small_angle_estimate_mm"] < 3
    # a pure servo step at home: translation from F·Δα equals the IK-inverse (a single-servo step)
    home = sensitivity(g, np.zeros(6))
    assert home.position_step == pytest.approx(res.position_step[5, 5], rel=1e-9)


def test_conditioning_flags_a_near_singular_pose() -> None:
    g = load_preset("servo-hexapod")
    c = conditioning(g, np.zeros((1, 6)))
    assert 1 < c["cond"][0] < 100 and not c["near_singular"][0]
    # with rods nearly in line with the horns (the workspace edge), conditioning degrades
    edge = np.array([[0, 0, 0.0179, 0, 0, 0]])
    ce = conditioning(g, edge, singular_threshold=c["cond"][0] * 1.5)
    assert ce["cond"][0] > c["cond"][0]


# --------------------------------------------------------------------- planar
def test_planar_sauer_cases() -> None:
    p = PLANAR_PRESETS["sauer-test"]
    poses = solve_planar(**p)
    assert poses[:, 2] == pytest.approx([-math.pi / 4, math.pi / 4], abs=1e-10)
    assert np.allclose(poses[:, :2], [[1, 2], [2, 1]], atol=1e-9)
    p4 = PLANAR_PRESETS["sauer"]
    assert len(solve_planar(**p4)) == 4
    assert len(solve_planar(**{**p4, "p2": 7.0})) == 6
    f = planar_f(solve_planar(**p4)[:, 2], **p4)
    assert np.abs(f).max() < 1e-8 * np.abs(planar_f(np.linspace(-3, 3, 100), **p4)).max()


def test_planar_recovers_a_known_pose() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        params = {"L1": 0.0, "L2": rng.uniform(1, 3), "L3": rng.uniform(1, 3), "gamma": rng.uniform(0.5, 2.0),
                  "x1": rng.uniform(3, 6), "x2": rng.uniform(-1, 1), "y2": rng.uniform(3, 6)}  # fmt: skip
        params["L1"] = math.sqrt(params["L2"] ** 2 + params["L3"] ** 2
                                 - 2 * params["L2"] * params["L3"] * math.cos(params["gamma"]))  # fmt: skip
        pose = np.array([rng.uniform(1, 3), rng.uniform(1, 3), rng.uniform(-math.pi, math.pi)])
        struts = planar_struts(pose, params["L2"], params["L3"], params["gamma"], params["x1"], params["x2"], params["y2"])
        found = solve_planar(**params, p1=struts[0], p2=struts[1], p3=struts[2])
        assert np.min(np.linalg.norm(found - pose, axis=1)) < 1e-7
        assert np.all(np.diff(found[:, 2]) > 0)  # sorted by θ


def test_planar_tangential_root_is_found() -> None:
    """At a strut length where two poses merge, f touches zero without changing sign: that pose is still found."""
    p = PLANAR_PRESETS["sauer"]
    lo, hi = 4.85, 4.88  # the count goes 2 → 4 near p2 = 4.8637 (a double root appears)
    for _ in range(60):
        mid = (lo + hi) / 2
        if len(solve_planar(**{**p, "p2": mid})) <= 2:
            lo = mid
        else:
            hi = mid
    at = solve_planar(**{**p, "p2": hi})
    assert len(at) in (3, 4)
    theta = np.linspace(-math.pi, math.pi, 200001)
    f = planar_f(theta, **{**p, "p2": hi})
    double = theta[np.argmin(np.abs(f))]
    assert np.min(np.abs(at[:, 2] - double)) < 1e-3
    counts, changes = sweep_strut(p, "p2", np.linspace(0.5, 12, 116))
    assert [c for _, _, c in changes] == [2, 4, 6, 4, 2, 0]
    assert [round(v, 2) for v, _, _ in changes] == [3.71, 4.86, 6.97, 7.02, 7.85, 9.26]


def test_planar_no_solution_is_empty() -> None:
    p = {**PLANAR_PRESETS["sauer"], "p2": 20.0}
    assert solve_planar(**p).shape == (0, 3)
    with pytest.raises(ValueError, match="p1"):
        solve_planar(**{**p, "p1": -1.0})


def test_planar_poses_where_the_two_linear_equations_are_one_are_found() -> None:
    """At θ = 0 here the second and third vertices' offsets from their anchors are parallel (D = 0): the poses there
    are where one line meets the first strut's circle, (1, ±2.5), and both are found with the others."""
    g = {"L1": math.sqrt(5), "L2": 1.0, "L3": 2.0, "gamma": math.pi / 2, "x1": 4.0, "x2": 3.0, "y2": 1.0}
    p1, p2, p3 = planar_struts(np.array([1.0, 2.5, 0.0]), g["L2"], g["L3"], g["gamma"], g["x1"], g["x2"], g["y2"])
    poses = solve_planar(**g, p1=p1, p2=p2, p3=p3)
    for want in ([1.0, 2.5, 0.0], [1.0, -2.5, 0.0]):
        assert np.min(np.abs(poses - want).max(axis=1)) < 1e-9, poses
    struts = planar_struts(poses, g["L2"], g["L3"], g["gamma"], g["x1"], g["x2"], g["y2"])
    assert np.allclose(struts, [p1, p2, p3], atol=1e-9)
    assert planar_continua(**g, p1=p1, p2=p2, p3=p3) == []


def test_planar_names_a_continuum_of_poses_and_a_side_l1_that_is_not_the_triangles(
        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """An equilateral platform on its own equilateral base with three equal struts moves as a parallelogram: every
    point of the first strut's circle is a pose at θ = 0, which the command says (and each is one: checked at a
    few). An L1 that is not the side the law of cosines gives is refused, naming it."""
    side = 5.0
    eq = {"L1": side, "L2": side, "L3": side, "gamma": math.pi / 3, "x1": side, "x2": side / 2,
          "y2": side * math.sqrt(3) / 2, "p1": 3.0, "p2": 3.0, "p3": 3.0}  # fmt: skip
    assert planar_continua(**eq) == [0.0]
    for phi in np.linspace(0.0, 2 * math.pi, 7):
        pose = np.array([3.0 * math.cos(phi), 3.0 * math.sin(phi), 0.0])
        assert np.allclose(planar_struts(pose, side, side, math.pi / 3, side, side / 2, eq["y2"]), 3.0)
    assert main(["planar", *[a for k, v in eq.items() for a in (f"--{k}", repr(v))], "--json"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["continua_theta"] == [0.0]
    assert main(["planar", *[a for k, v in eq.items() for a in (f"--{k}", repr(v))]]) == 0
    assert "and a continuum at θ = 0.000000" in capsys.readouterr().out
    with pytest.raises(ConfigError, match="L1 is the side opposite"):
        solve_planar(**{**eq, "L1": 4.0})
    assert main(["planar", "--geometry", "sauer", "--L1", "9"]) == 1
    assert "give L1 = 3" in capsys.readouterr().err


# ------------------------------------------------------------- assembly modes
def test_assembly_modes_include_the_true_pose_and_satisfy_the_legs() -> None:
    g = load_preset("senilov2018")
    pose = np.array([0.01, 0.0, 0.0, 0.05, 0.02, 0.1])
    lengths = inverse_kinematics(g, pose).leg_lengths
    modes = assembly_modes(g, lengths, guesses=1500)
    assert len(modes) >= 2 and len(modes) % 2 == 0  # coplanar base anchors: each mode has its mirror image
    assert np.min(np.abs(modes - pose).max(axis=1)) < 1e-8
    assert np.allclose(inverse_kinematics(g, modes).leg_lengths, lengths, atol=1e-9)


def test_a_rotary_builds_assembly_modes_hold_its_servo_angles() -> None:
    """For a rotary build the horn tips are fixed by the servo angles: every mode has each rod spanning its horn tip
    to its plate anchor, the pose the angles came from is one of them, and each is a pose the angles' forward
    kinematics reaches from a guess near it (leg lengths from the base anchors would be another mechanism's)."""
    g = load_preset("servo-hexapod")
    pose = np.array([0.01, 0.0, 0.0, 0.05, 0.02, 0.1])
    angles = inverse_kinematics(g, pose).servo_angles
    modes = assembly_modes(g, servo_angles=angles, guesses=1500)
    assert len(modes) >= 2 and np.min(np.abs(modes - pose).max(axis=1)) < 1e-8
    anchors = inverse_kinematics(g, modes).leg_vectors + g.base_anchors
    assert np.allclose(np.linalg.norm(anchors - horn_tips(g, angles), axis=-1), g.rod_length, atol=1e-9)
    again = forward_kinematics(g, servo_angles=np.broadcast_to(angles, (len(modes), 6)), guess=modes + 1e-4).pose
    assert np.allclose(again, modes, atol=1e-9)
    with pytest.raises(ValueError, match="exactly one"):
        assembly_modes(g, inverse_kinematics(g, pose).leg_lengths, servo_angles=angles)


def test_assembly_on_a_rotary_build_takes_a_pose_not_leg_lengths(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["assembly", "--geometry", "servo-hexapod", "--guesses", "300", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert len(out["servo_angles_deg"]) == 6 and "leg_lengths_mm" not in out and out["count"] >= 2
    assert main(["assembly", "--geometry", "servo-hexapod", "--legs", *["300"] * 6]) == 1
    assert "rotary build" in capsys.readouterr().err
    assert main(["assembly", "--geometry", "servo-hexapod", "--pose", "0", "0", "80", "0", "0", "0"]) == 1
    assert "unreachable" in capsys.readouterr().err


# ----------------------------------------------------------------------- CLI
@pytest.mark.parametrize("args", [
    ["workspace", "--geometry", "mathcad-micro", "--n", "30", "--samples", "5000"],
    ["trajectory", "--geometry", "senilov2018", "--samples", "50"],
    ["sensitivity", "--n", "11", "--fd-samples", "10"],
    ["conditioning", "--n", "11"],
    ["planar", "--geometry", "sauer", "--p2", "7"],
    ["assembly", "--geometry", "senilov2018", "--guesses", "300"],
])  # fmt: skip
def test_analysis_cli_json_and_plot(args: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plot = tmp_path / "p.png"
    extra = ["--plot", str(plot)] if args[0] != "assembly" else []
    # source 001's 0.2 m circle leaves the stroke: the trajectory check reports it with exit code 1
    assert main([*args, "--json", *extra]) == (1 if args[0] == "trajectory" else 0)
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert isinstance(out, dict) and out
    if extra:
        assert plot.stat().st_size > 10_000
    if args[0] == "planar":
        assert out["count"] == 6


def _bad_analysis_calls() -> list[tuple[str, object]]:
    g, lin = load_preset("servo-hexapod"), load_preset("senilov2018")
    lengths = inverse_kinematics(lin, np.zeros(6)).leg_lengths
    home = np.zeros((1, 6))
    levels = np.linspace(-0.02, 0.02, 41)
    return [
        ("guesses", lambda: assembly_modes(lin, lengths, guesses=-3)),
        ("leg_lengths", lambda: assembly_modes(lin, np.full(6, np.nan))),
        ("leg_lengths", lambda: assembly_modes(lin, -lengths)),
        ("leg_lengths", lambda: assembly_modes(lin, np.zeros((2, 6)))),
        ("leg_lengths", lambda: assembly_modes(g, inverse_kinematics(g, np.zeros(6)).leg_lengths)),  # a rotary build
        ("step", lambda: sensitivity(g, home, -0.01)),  # a negative step size back
        ("step", lambda: sensitivity(g, home, 0.0)),
        ("poses", lambda: fd_check(g, np.full((2, 6), 1.0))),  # none reachable
        ("singular_threshold", lambda: conditioning(g, home, singular_threshold=float("nan"))),
        ("z_levels", lambda: height_map(g, x=[0.0], y=[0.0], z_levels=levels[::-1])),  # z_max and z_min swapped
        ("z_levels", lambda: height_map(g, x=[0.0], y=[0.0], z_levels=[])),
        ("stride", lambda: height_map(g, x=[0.0], y=[0.0], z_levels=levels, stride=0)),
        ("orientation", lambda: height_map(g, (0.0, 0.0), x=[0.0], y=[0.0], z_levels=levels)),
        ("samples", lambda: reachable_volume(g, samples=0)),
        ("samples", lambda: solve_planar(**PLANAR_PRESETS["sauer"], samples=1)),  # "no poses"
        ("values", lambda: sweep_strut(PLANAR_PRESETS["sauer"], "p2", np.linspace(12, 0.5, 50))),  # no bisection
    ]


@pytest.mark.parametrize("index", range(16))
def test_a_bad_analysis_argument_is_one_clear_error_naming_it(index: int) -> None:
    """Each call that gave a wrong answer silently (a negative step, swapped heights, no poses) or a deep NumPy
    error raises :class:`ConfigError` (a ``ValueError``) naming its argument."""
    name, call = _bad_analysis_calls()[index]
    with pytest.raises(ConfigError, match=name):
        call()


def test_workspace_widens_its_height_search_until_the_heights_end_inside_it(tmp_path: Path,
                                                                           capsys: pytest.CaptureFixture) -> None:
    """A small build whose reachable heights off the centre pass 1.2 times its reach along z (where the search
    started): the search widens, and the lowest height is found rather than a note that it lies beyond."""
    path = tmp_path / "small.toml"
    path.write_text('name = "small"\nlength_unit = "mm"\nangle_unit = "deg"\nhorn_length = 15\nrod_length = 90\n'
                    "servo_angle_range = [-30, 60]\nplate_size = [180, 180]\n[symmetric]\nbase_radius = 70\n"
                    "base_pair_angle = 25\nplatform_radius = 55\nplatform_pair_angle = 16\n")  # fmt: skip
    assert main(["workspace", "--geometry", str(path), "--samples", "2000", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    from stewart_gym.presets import load_geometry

    reach_z = -axis_ranges(load_geometry(str(path)))[2, 0]
    assert out["height_map"]["min_z_mm"] < -1.2 * reach_z * 1e3 and not out["height_map"]["z_limited_by_grid"]
