"""The PyBullet model against the analytic kinematics, and the hobby-servo behaviour measured from simulation."""

from __future__ import annotations

import math
import multiprocessing
import pickle
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
from conftest import (
    linear_pose_errors,
    random_reachable_poses,
    servo_step_response,
    settled_pose_errors,
    xml_differences,
)
from urdf_parser_py.urdf import URDF

from stewart_gym.analysis import aggressive_moves
from stewart_gym.calibration import PulseRangeError
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.presets import load_preset
from stewart_gym.sim import MechanismSpec, ServoSpec, StewartSim, mechanism_urdf, plate_urdf

ROOT = Path(__file__).resolve().parents[2]
GEO = load_preset("servo-hexapod")


@pytest.fixture(scope="module")
def sim() -> StewartSim:
    s = StewartSim(ball=True)
    yield s
    s.close()


# ---------------------------------------------------------------------- URDF
def test_committed_urdf_matches_generator() -> None:
    """The committed files equal what the generator writes, compared as numbers (tolerance 1e-8)."""
    assert not xml_differences((ROOT / "urdf/servo_hexapod.urdf").read_text(), mechanism_urdf("servo-hexapod")), \
        "urdf/servo_hexapod.urdf is stale: run `stewart-gym urdf`"  # fmt: skip
    assert not xml_differences((ROOT / "urdf/servo_hexapod_plate.urdf").read_text(), plate_urdf("servo-hexapod"))


def test_urdf_generation_does_not_depend_on_numpy_simd() -> None:
    """Regenerated with every SIMD path numpy dispatches at run time switched off (as on an older CPU), the
    URDF still matches the committed file; and no coordinate is printed as rounding noise."""
    import os
    import subprocess
    import sys

    core = getattr(np, "_core", None) or np.core  # numpy 2 / numpy 1
    dispatched = core._multiarray_umath.__cpu_dispatch__
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(dispatched)}
    code = "import sys; from stewart_gym.sim import mechanism_urdf; sys.stdout.write(mechanism_urdf('servo-hexapod'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert not xml_differences((ROOT / "urdf/servo_hexapod.urdf").read_text(), out.stdout)
    import re

    tiny = re.findall(r"[-+]?\d\.?\d*e-(?:1[2-9]|[2-9]\d)", (ROOT / "urdf/servo_hexapod.urdf").read_text())
    assert not tiny, f"rounding noise written to the URDF: {tiny[:5]}"


def test_urdf_comparison_catches_a_real_change() -> None:
    text = mechanism_urdf("servo-hexapod")
    assert xml_differences(text, text.replace('effort="', 'effort="1', 1))
    assert not xml_differences(text, text.replace('rpy="0 0 0"', 'rpy="0 -0 6e-18"', 1))


def test_urdf_parses_with_standard_parser() -> None:
    robot = URDF.from_xml_string(mechanism_urdf("servo-hexapod"))
    joints = {j.name: j for j in robot.joints}
    servos = [joints[f"servo_{i}"] for i in range(6)]
    lo, hi = GEO.servo_angle_range
    alpha0 = inverse_kinematics(GEO, np.zeros(6)).servo_angles
    for i, j in enumerate(servos):
        assert j.type == "revolute" and j.parent == "base" and j.child == f"horn_{i}"
        assert j.limit.lower == pytest.approx(lo - alpha0[i], abs=1e-8)
        assert j.limit.upper == pytest.approx(hi - alpha0[i], abs=1e-8)
        assert j.limit.effort == pytest.approx(ServoSpec().stall_torque, rel=1e-6)
        assert j.limit.velocity == pytest.approx(math.radians(60) / 0.17, rel=1e-6)
    assert sum(j.type == "continuous" for j in robot.joints) == 12  # two per universal joint
    assert all(link.inertial.mass > 0 for link in robot.links)
    assert len(robot.links) == 1 + 6 * 3
    plate = URDF.from_xml_string(plate_urdf("servo-hexapod"))
    assert [link.name for link in plate.links] == ["plate"]


def test_leg_urdfs_are_the_whole_tree_split() -> None:
    """The simulator's one-leg bodies hold exactly the joints and links of the committed tree."""
    whole = URDF.from_xml_string(mechanism_urdf("servo-hexapod"))
    parts = [URDF.from_xml_string(mechanism_urdf("servo-hexapod", legs=[i], base_plate=i == 0)) for i in range(6)]

    def joint_key(j: object) -> tuple:
        return (j.name, j.type, j.parent, j.child, tuple(j.origin.xyz), tuple(j.origin.rpy),  # type: ignore[attr-defined]
                None if j.axis is None else tuple(j.axis))  # type: ignore[attr-defined]  # fmt: skip

    assert sorted(joint_key(j) for p in parts for j in p.joints) == sorted(joint_key(j) for j in whole.joints)
    links = {link.name for p in parts for link in p.links if link.name != "base"}
    assert links == {link.name for link in whole.links if link.name != "base"}
    assert sum(len(p.links) for p in parts) == len(whole.links) + 5  # each part has its own base
    with pytest.raises(ValueError, match="legs"):
        mechanism_urdf("servo-hexapod", legs=[0, 0])
    with pytest.raises(ValueError, match="legs"):
        mechanism_urdf("servo-hexapod", legs=[6])


def test_urdf_loads_in_pybullet() -> None:
    cid = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(ROOT / "urdf/servo_hexapod.urdf"), useFixedBase=True, physicsClientId=cid)
        assert pb.getNumJoints(body, physicsClientId=cid) == 18
        plate = pb.loadURDF(str(ROOT / "urdf/servo_hexapod_plate.urdf"), physicsClientId=cid)
        assert pb.getDynamicsInfo(plate, -1, physicsClientId=cid)[0] == pytest.approx(0.43)
    finally:
        pb.disconnect(cid)


def test_linear_geometry_urdf_and_bad_rates() -> None:
    """A linear platform's URDF has prismatic actuator joints with the stroke as limits (and parses); a physics
    rate that is not a multiple of the control rate is refused."""
    robot = URDF.from_xml_string(mechanism_urdf("senilov2018"))
    servos = [j for j in robot.joints if j.name.startswith("servo_")]
    assert len(servos) == 6 and all(j.type == "prismatic" for j in servos)
    home = inverse_kinematics(load_preset("senilov2018"), np.zeros(6)).leg_lengths
    assert servos[0].limit.lower == pytest.approx(0.2 - home[0]) and servos[0].limit.upper == pytest.approx(0.5 - home[0])
    with pytest.raises(ValueError, match="multiple"):
        StewartSim(physics_hz=120, control_hz=50)


# ------------------------------------------------------------------ fidelity
def test_home_state_satisfies_ik(sim: StewartSim) -> None:
    sim.reset()
    assert sim.constraint_error() < 1e-7
    assert np.abs(sim.platform_pose()).max() < 1e-9
    assert sim.servo_angles() == pytest.approx(inverse_kinematics(GEO, np.zeros(6)).servo_angles, abs=1e-9)
    for _ in range(50):  # holds the loaded plate against gravity
        sim.step()
    assert np.abs(sim.platform_pose()[:3]).max() < 2e-5 and np.abs(sim.platform_pose()[3:]).max() < 1e-4


def test_commanded_poses_are_reached() -> None:
    """100 random reachable poses through IK → pulse widths → command settle within 0.5 mm and 0.1°.

    Servos without dead band (0.25 µs command resolution kept): the pose is the
    commanded one. With the default 5 µs dead band a servo keeps its old pulse
    when the new one is within 5 µs; the pose then matches FK of the pulses the
    servos hold, which is what the simulation must get right.
    """
    poses = random_reachable_poses(100, seed=11)
    assert len(poses) == 100
    with StewartSim(ball=True, servo_spec=ServoSpec(deadband_us=0.0)) as s:
        worst, worst_fk = settled_pose_errors(s, poses)
    print(f"fidelity, no dead band: worst {worst[0]:.4f} mm, {worst[1]:.4f}° against the commanded pose")
    assert worst[0] <= 0.5 and worst[1] <= 0.1
    with StewartSim(ball=True) as s:
        worst, worst_fk = settled_pose_errors(s, poses)
    print(f"fidelity, 5 µs dead band: worst {worst[0]:.4f} mm, {worst[1]:.4f}° against the commanded pose, "
          f"{worst_fk[0]:.5f} mm, {worst_fk[1]:.5f}° against FK of the held pulses")  # fmt: skip
    assert worst_fk[0] <= 0.01 and worst_fk[1] <= 0.002
    assert worst[0] <= 1.0 and worst[1] <= 0.2  # bounded by the dead band


def _aggressive_gaps(s: StewartSim) -> np.ndarray:
    """Loop gap (m) at each control step of :func:`aggressive_moves`."""
    s.reset()
    gaps = []
    for pose in aggressive_moves(GEO, s.control_hz):
        s.command(s.calibration.pulse_widths(inverse_kinematics(GEO, pose).servo_angles))
        s.step()
        gaps.append(s.constraint_error())
    return np.array(gaps)


def test_loops_stay_closed_during_aggressive_moves(sim: StewartSim) -> None:
    """Full-range steps and 2 Hz sinusoids along every pose axis.

    At the default 200 Hz the worst gap is about 0.07 mm (full-range yaw and x
    moves); at the environments' 150 Hz it is about 0.12 mm.
    """
    assert sim.physics_hz == 200
    gaps = _aggressive_gaps(sim)
    print(f"worst loop gap at {sim.physics_hz} Hz: {gaps.max() * 1e3:.4f} mm")
    assert gaps.max() < 0.1e-3
    with StewartSim(ball=True, physics_hz=150) as coarse:
        gaps = _aggressive_gaps(coarse)
    print(f"worst loop gap at 150 Hz: {gaps.max() * 1e3:.4f} mm")
    assert gaps.max() < 0.15e-3


# ----------------------------------------------------------------- servos
def test_servo_step_response_shows_speed_lag_and_deadband() -> None:
    spec = ServoSpec(lag_s=0.020, deadband_us=5.0)
    t, ang = servo_step_response(StewartSim, spec, 300.0)  # +300 µs ≈ 33.75° on every servo (the plate rises)
    moving = np.abs(ang).max(axis=1) > 1e-3
    lag = t[np.argmax(moving)]
    assert 0.019 <= lag <= 0.023, lag
    # speed: slope between 20 % and 80 % of the travel
    final = ang[-1]
    assert final == pytest.approx(np.full(6, 300 / (1600 / math.pi)), abs=0.01)
    a = ang.mean(axis=1) / final.mean()
    i20, i80 = np.argmax(a > 0.2), np.argmax(a > 0.8)
    speed = (a[i80] - a[i20]) * final.mean() / (t[i80] - t[i20])
    print(f"measured lag {lag * 1e3:.1f} ms, speed {speed:.2f} rad/s (spec {spec.max_speed:.2f})")
    assert speed == pytest.approx(spec.max_speed, rel=0.08)
    # dead band: a 4 µs change is ignored, a 7 µs change moves the horn by 7 µs worth
    _, small = servo_step_response(StewartSim, spec, 4.0, seconds=0.1)
    assert np.abs(small).max() < 2e-4
    _, above = servo_step_response(StewartSim, spec, 7.0, seconds=0.1)
    assert above[-1] == pytest.approx(np.full(6, 7 / (1600 / math.pi)), abs=2e-4)


def test_resolution_and_trim_error() -> None:
    spec = ServoSpec(resolution_us=4.88, trim_error_us=(20, 0, 0, 0, 0, -10), deadband_us=0.0)  # a PCA9685
    with StewartSim(servo_spec=spec) as s:
        sent = s.command(np.full(6, 1503.0))
        assert sent == pytest.approx(np.full(6, round(1503 / 4.88) * 4.88))
        for _ in range(50):
            s.step()
        r = 1600 / math.pi
        expected = s.calibration.angles(sent - np.array(spec.trim_error_us))
        assert s.servo_angles() == pytest.approx(expected, abs=3e-4)
        assert abs((s.servo_angles()[0] - s.calibration.angles(sent)[0]) * r) == pytest.approx(20, abs=0.5)


def test_torque_limit_matters() -> None:
    """A servo far weaker than an MG996R cannot hold the plate; the default holds it."""
    with StewartSim(servo_spec=ServoSpec(stall_torque=0.002)) as weak:
        for _ in range(50):
            weak.step()
        assert weak.platform_pose()[2] < -0.005


# ---------------------------------------------------------------- robustness
def test_random_full_range_pulses_never_blow_up() -> None:
    rng = np.random.default_rng(13)
    with StewartSim(ball=True) as s:
        cal = s.calibration
        worst = 0.0
        for k in range(10_000):
            if k % 5 == 0:
                s.command(rng.uniform(cal.min_us, cal.max_us))
            s.step()
            if k % 10 == 0:
                worst = max(worst, s.constraint_error())
                assert np.all(np.isfinite(s.platform_pose())) and np.all(np.isfinite(s.servo_angles()))
        print(f"random pulses: worst loop gap {worst * 1e3:.3f} mm")
        assert worst < 1e-3


def test_out_of_limit_commands_are_rejected(sim: StewartSim) -> None:
    sim.reset()
    before = sim.held_pulses()
    with pytest.raises(PulseRangeError, match="servo 2"):
        sim.command(np.array([1500, 1500, 2100, 1500, 1500, 1500.0]))
    with pytest.raises(PulseRangeError):
        sim.command(np.array([1500, 1500, np.nan, 1500, 1500, 1500.0]))
    sim.step()
    assert np.array_equal(sim.held_pulses(), before)


# ----------------------------------------------------------------- lifecycle
def test_reset_is_deterministic(sim: StewartSim) -> None:
    def run() -> np.ndarray:
        sim.reset()
        sim.place_ball(np.array([0.03, -0.02]), np.array([0.05, 0.0]))
        sim.command(sim.calibration.pulse_widths(inverse_kinematics(GEO, np.array([0, 0, 0, 0.05, 0.03, 0])).servo_angles))
        out = []
        for _ in range(60):
            sim.step()
            out.append(np.concatenate([sim.platform_pose(), sim.ball_state()[0]]))
        return np.array(out)

    a, b = run(), run()
    assert np.array_equal(a, b)
    assert sim.time == pytest.approx(60 / 50)


def test_ball_is_placed_in_plate_frame(sim: StewartSim) -> None:
    sim.reset()
    sim.place_ball(np.array([0.04, -0.03]), np.array([0.1, 0.2]))
    pos, vel = sim.ball_state()
    assert pos == pytest.approx([0.04, -0.03, MechanismSpec().plate_top + sim.ball_spec.radius], abs=1e-9)
    assert vel == pytest.approx([0.1, 0.2, 0.0], abs=1e-9)
    pose = np.array([0.01, -0.005, 0.004, math.radians(5), math.radians(-3), math.radians(8)])
    sim.command(sim.calibration.pulse_widths(inverse_kinematics(GEO, pose).servo_angles))
    for _ in range(3):
        sim.step()
        assert sim.ball_position() == pytest.approx(sim.ball_state()[0].tolist(), abs=1e-12)


def _worker(seed: int) -> list[float]:
    with StewartSim() as s:
        pose = np.array([0.0, 0.0, 0.005 * seed, 0, 0, 0])
        s.command(s.calibration.pulse_widths(inverse_kinematics(s.geometry, pose).servo_angles))
        for _ in range(40):
            s.step()
        return s.platform_pose().tolist()


def test_several_instances_and_worker_processes() -> None:
    a, b = StewartSim(), StewartSim()
    try:
        a.command(a.calibration.pulse_widths(inverse_kinematics(GEO, np.array([0, 0, 0.005, 0, 0, 0])).servo_angles))
        for _ in range(40):
            a.step()
            b.step()
        assert a.platform_pose()[2] == pytest.approx(0.005, abs=2e-4)
        assert abs(b.platform_pose()[2]) < 1e-4  # independent worlds
    finally:
        a.close()
        b.close()
        b.close()  # closing twice is fine
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(2, mp_context=ctx) as pool:
        results = list(pool.map(_worker, [1, 2]))
    assert results[0][2] == pytest.approx(0.005, abs=2e-4) and results[1][2] == pytest.approx(0.010, abs=2e-4)


def test_rgb_array_render() -> None:
    with StewartSim(ball=True, render_mode="rgb_array", render_size=(160, 120)) as s:
        frame = s.render()
        assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
        assert frame.std() > 10  # not a blank image
    assert pickle.dumps(ServoSpec())  # specs are plain picklable data


# -------------------------------------------------------------- linear legs
@pytest.mark.parametrize("name", ["senilov2018", "mathcad-micro"])
def test_linear_platforms_reach_their_commanded_poses(name: str) -> None:
    """6-UPS platforms (RC linear actuators on prismatic legs): 100 random reachable poses, commanded through IK
    → leg lengths → pulses with the dead band off, settle within 0.5 % of the stroke and 0.1°; loops stay closed
    within 0.1 mm on the way."""
    lo, hi = load_preset(name).leg_length_range
    stroke = hi - lo
    worst_pos, worst_ang, worst_gap = linear_pose_errors(StewartSim, name)
    print(f"{name}: worst {worst_pos * 1e3:.4f} mm ({worst_pos / stroke:.3%} of the stroke), {worst_ang:.4f}°, "
          f"gap {worst_gap * 1e3:.4f} mm")  # fmt: skip
    assert worst_pos <= 0.005 * stroke and worst_ang <= 0.1 and worst_gap < 1e-4


def test_a_linear_platform_carries_the_ball_env() -> None:
    """senilov2018 in the ball env: its 500 mm plate, its leg-length pulses, and a ball that stays put at home."""
    import gymnasium as gym

    env = gym.make("StewartBallBalance-v0", geometry="senilov2018")
    try:
        obs, _ = env.reset(seed=0, options={"ball_position": (0.0, 0.0), "ball_velocity": (0.0, 0.0)})
        assert env.unwrapped.plate_half_extent == (0.25, 0.25)
        for _ in range(50):
            obs, _, terminated, _, info = env.step(np.zeros(2, dtype=np.float32))
        assert not terminated and np.linalg.norm(info["ball_xy_m"]) < 0.005
        assert np.all((info["pulse_widths_us"] > 1000) & (info["pulse_widths_us"] < 2000))
    finally:
        env.close()


def test_importing_the_simulator_prints_nothing_and_gives_stderr_back() -> None:
    """PyBullet prints its build time on stderr when imported; the simulator keeps it off, so a command's
    output (and a mistake's one `error: …` line) is the user's alone, and what is written after the import
    (through Python or straight to file descriptor 2) still reaches stderr."""
    code = ("import os, sys; import stewart_gym.sim.stewart_sim; sys.stderr.write('after\\n'); sys.stderr.flush(); "
            "os.write(2, b'fd2\\n'); print('out')")  # fmt: skip
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (proc.stdout, proc.stderr) == ("out\n", "after\nfd2\n")
