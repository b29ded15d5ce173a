"""The MuJoCo twin: its MJCF, its fidelity against the analytic model (as for PyBullet), and its agreement with
PyBullet on the same pulses and the same tilts."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import (
    Board,
    FakeDevice,
    linear_pose_errors,
    random_reachable_poses,
    servo_step_response,
    settled_pose_errors,
    sg,
    sg_in,
    xml_differences,
)

from stewart_gym.analysis import aggressive_moves
from stewart_gym.calibration import ServoCalibration
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.presets import load_preset, preset_names
from stewart_gym.sim import ServoSpec, StewartSim
from stewart_gym.sim.mjcf import mechanism_mjcf
from stewart_gym.sim.mujoco_sim import MujocoSim

ROOT = Path(__file__).resolve().parents[2]
GEO = load_preset("servo-hexapod")


# ---------------------------------------------------------------------- MJCF
@pytest.mark.parametrize("name", preset_names())
def test_mjcf_of_every_preset_compiles_with_its_loops_closed_at_home(name: str) -> None:
    from stewart_gym.sim import BallSpec

    model = mujoco.MjModel.from_xml_string(mechanism_mjcf(name, ball=BallSpec()))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.neq == 6 and model.nu == 6
    tops = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"rod_{i}_top") for i in range(6)]
    anchors = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"anchor_{i}") for i in range(6)]
    assert np.abs(data.site_xpos[tops] - data.site_xpos[anchors]).max() < 1e-9
    kinds = {int(model.jnt_type[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"servo_{i}")]) for i in range(6)}
    assert kinds == {int(mujoco.mjtJoint.mjJNT_HINGE if load_preset(name).is_rotary else mujoco.mjtJoint.mjJNT_SLIDE)}


def test_committed_mjcf_matches_generator_and_loads_from_file() -> None:
    """``urdf/servo_hexapod.xml`` is what ``stewart-gym mjcf`` writes (numbers within 1e-8), and MuJoCo (and so its
    viewer, ``python -m mujoco.viewer --mjcf``) loads it from the file."""
    path = ROOT / "urdf/servo_hexapod.xml"
    from stewart_gym.sim import BallSpec

    assert not xml_differences(path.read_text(), mechanism_mjcf("servo-hexapod", ball=BallSpec())), \
        "urdf/servo_hexapod.xml is stale: run `stewart-gym mjcf --out urdf/servo_hexapod.xml`"  # fmt: skip
    model = mujoco.MjModel.from_xml_path(str(path))
    assert model.nbody == 1 + 12 + 2  # world, horns and rods, plate, ball


def test_mjcf_command_writes_a_model_for_any_geometry(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    out = tmp_path / "lin.xml"
    proc = sg_in(capfd, "mjcf", "--geometry", "senilov2018", "--out", str(out))
    assert proc.returncode == 0 and "mujoco.viewer" in proc.stdout, proc.stderr
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.nu == 6 and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "ball") >= 0
    bad = sg_in(capfd, "mjcf", "--out", str(tmp_path / "m.txt"))
    errors = [ln for ln in bad.stderr.splitlines() if ln.startswith("error:")]
    assert bad.returncode != 0 and len(errors) == 1 and ".xml" in errors[0], bad.stderr


# ------------------------------------------------------------------ fidelity
def test_home_state_satisfies_ik_and_holds() -> None:
    with MujocoSim(ball=True) as sim:
        assert sim.constraint_error() < 1e-8 and np.abs(sim.platform_pose()).max() < 1e-8
        assert sim.servo_angles() == pytest.approx(inverse_kinematics(GEO, np.zeros(6)).servo_angles, abs=1e-12)
        for _ in range(50):  # holds the loaded plate against gravity
            sim.step()
        assert np.abs(sim.platform_pose()[:3]).max() < 5e-5 and np.abs(sim.platform_pose()[3:]).max() < 1e-4


def test_commanded_poses_are_reached() -> None:
    """100 random reachable poses through IK → pulses settle within 0.5 mm and 0.1° with the dead band off; with
    the 5 µs dead band, the pose is FK of the pulses the servos hold (within 0.1 mm and 0.05°)."""
    poses = random_reachable_poses(100, seed=11)
    assert len(poses) == 100
    with MujocoSim(ball=True, servo_spec=ServoSpec(deadband_us=0.0)) as sim:
        worst, _ = settled_pose_errors(sim, poses)
    print(f"MuJoCo fidelity, no dead band: worst {worst[0]:.4f} mm, {worst[1]:.4f}°")
    assert worst[0] <= 0.5 and worst[1] <= 0.1
    with MujocoSim(ball=True) as sim:
        _, worst_fk = settled_pose_errors(sim, poses)
    print(f"MuJoCo fidelity, 5 µs dead band: {worst_fk[0]:.4f} mm, {worst_fk[1]:.4f}° against FK of the held pulses")
    # PyBullet's motor is a hard constraint (0.01 mm here); MuJoCo's velocity servo slips by ~0.03° under the plate
    assert worst_fk[0] <= 0.1 and worst_fk[1] <= 0.05


def test_loops_stay_closed_during_aggressive_moves() -> None:
    """Full-range steps and 2 Hz sinusoids along every pose axis: the worst loop gap is under 0.1 mm."""
    with MujocoSim(ball=True) as sim:
        gaps = []
        for pose in aggressive_moves(GEO, sim.control_hz):
            sim.command(sim.calibration.pulse_widths(inverse_kinematics(GEO, pose).servo_angles))
            sim.step()
            gaps.append(sim.constraint_error())
    print(f"MuJoCo worst loop gap at {sim.physics_hz} Hz: {max(gaps) * 1e3:.4f} mm")
    assert max(gaps) < 0.1e-3


@pytest.mark.parametrize("name", ["senilov2018", "mathcad-micro"])
def test_linear_platforms_reach_their_commanded_poses(name: str) -> None:
    """6-UPS in MuJoCo: 100 random reachable poses within 0.5 % of the stroke and 0.1°; loops within 0.1 mm."""
    lo, hi = load_preset(name).leg_length_range
    worst_pos, worst_ang, worst_gap = linear_pose_errors(MujocoSim, name)
    print(f"MuJoCo {name}: worst {worst_pos * 1e3:.4f} mm ({worst_pos / (hi - lo):.3%} of the stroke), "
          f"{worst_ang:.4f}°, gap {worst_gap * 1e3:.4f} mm")  # fmt: skip
    assert worst_pos <= 0.005 * (hi - lo) and worst_ang <= 0.1 and worst_gap < 1e-4


def test_servo_speed_lag_and_deadband_come_from_the_shared_front_end() -> None:
    """A +300 µs step on every servo: the 20 ms lag, the no-load speed within 8 %, and a 4 µs change ignored."""
    spec = ServoSpec(lag_s=0.020, deadband_us=5.0)

    t, ang = servo_step_response(MujocoSim, spec, 300.0, 0.3)
    lag = t[np.argmax(np.abs(ang).max(axis=1) > 1e-3)]
    assert 0.019 <= lag <= 0.023, lag
    a = ang.mean(axis=1) / ang[-1].mean()
    i20, i80 = np.argmax(a > 0.2), np.argmax(a > 0.8)
    speed = (a[i80] - a[i20]) * ang[-1].mean() / (t[i80] - t[i20])
    print(f"MuJoCo servo: lag {lag * 1e3:.1f} ms, speed {speed:.2f} rad/s (spec {spec.max_speed:.2f})")
    assert speed == pytest.approx(spec.max_speed, rel=0.08)
    assert ang[-1] == pytest.approx(np.full(6, 300 / (1600 / math.pi)), abs=0.01)
    _, small = servo_step_response(MujocoSim, spec, 4.0, 0.1)
    assert np.abs(small).max() < 2e-4


def test_random_full_range_pulses_never_blow_up() -> None:
    rng = np.random.default_rng(13)
    with MujocoSim(ball=True) as sim:
        cal = sim.calibration
        for _ in range(300):
            sim.command(rng.uniform(cal.min_us, cal.max_us))
            sim.step()
            assert np.all(np.isfinite(sim.platform_pose())) and np.all(np.isfinite(sim.servo_angles()))


def test_domain_randomisation_reaches_the_model() -> None:
    """Per-episode ball, friction and servo changes land in MuJoCo's model (where MuJoCo can express them)."""
    from stewart_gym.sim import BallSpec

    with MujocoSim(ball=True) as sim:
        sim.reset(ball_spec=BallSpec(radius=0.015, mass=0.05, rolling_friction=3e-5), plate_friction=0.5,
                  servo_spec=ServoSpec(stall_torque=0.5))  # fmt: skip
        ball = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_GEOM, "ball")
        assert sim.model.geom_size[ball, 0] == 0.015 and sim.model.body_mass[sim.model.geom_bodyid[ball]] == 0.05
        assert sim.model.geom_friction[ball] == pytest.approx([0.6 * 0.5, 1e-5 * 0.5, 3e-5 * 0.5])
        assert np.all(sim.model.actuator_forcerange == [-0.5, 0.5])
        for _ in range(25):
            sim.step()
        assert sim.ball_position()[2] == pytest.approx(sim.plate_top + 0.015, abs=2e-4)


# ------------------------------------------------------------ cross-engine
def _pulse_sequence(seconds: float, control_hz: int, seed: int) -> np.ndarray:
    """Random reachable poses held 0.2…0.5 s each, as pulses (one row per control step)."""
    rng = np.random.default_rng(seed)
    poses = random_reachable_poses(200, seed)
    rows: list[np.ndarray] = []
    k = 0
    while len(rows) < seconds * control_hz:
        rows += [poses[k]] * int(rng.integers(10, 26))
        k += 1
    poses = np.array(rows[: int(seconds * control_hz)])
    return ServoCalibration.default(GEO).pulse_widths(inverse_kinematics(GEO, poses).servo_angles)


def test_engines_agree_on_plate_poses() -> None:
    """The same 10 s random pulse sequence in both engines: plate poses within 1 mm and 0.3° RMS."""
    pulses = _pulse_sequence(10.0, 50, seed=5)
    poses = {}
    for name, sim in (("pybullet", StewartSim(ball=True, physics_hz=150)), ("mujoco", MujocoSim(ball=True))):
        with sim:
            out = []
            for p in pulses:
                sim.command(p)
                sim.step()
                out.append(sim.platform_pose())
            poses[name] = np.array(out)
    d = poses["pybullet"] - poses["mujoco"]
    rms_mm = float(np.sqrt((d[:, :3] ** 2).sum(axis=1).mean()) * 1e3)
    rms_deg = float(np.degrees(np.sqrt((d[:, 3:] ** 2).sum(axis=1).mean())))
    print(f"PyBullet vs MuJoCo plate pose, 10 s of random pulses: RMS {rms_mm:.3f} mm, {rms_deg:.3f}°")
    assert rms_mm <= 1.0 and rms_deg <= 0.3


def test_engines_roll_the_ball_alike_under_the_same_tilts() -> None:
    """The same ±2° tilt sequence (2 s) in both engines, ball starting at rest at the centre: the paths differ
    by a few per cent of the distance travelled (the difference is printed; the docs explain it)."""
    rng = np.random.default_rng(3)
    tilts = np.repeat(rng.uniform(-1, 1, (5, 2)) * math.radians(2.0), 20, axis=0)
    paths = {}
    for name, sim in (("pybullet", StewartSim(ball=True, physics_hz=150)), ("mujoco", MujocoSim(ball=True))):
        with sim:
            for _ in range(10):
                sim.step()
            sim.place_ball(np.zeros(2))
            path = []
            for roll, pitch in tilts:
                pose = np.array([0, 0, 0, roll, pitch, 0])
                sim.command(sim.calibration.pulse_widths(inverse_kinematics(GEO, pose).servo_angles))
                sim.step()
                path.append(sim.ball_position()[:2])
            paths[name] = np.array(path)
    diff = np.linalg.norm(paths["pybullet"] - paths["mujoco"], axis=1)
    travel = float(np.linalg.norm(paths["pybullet"], axis=1).max())
    print(f"ball paths, PyBullet vs MuJoCo: travel {travel * 1e3:.1f} mm, difference RMS "
          f"{np.sqrt(np.mean(diff**2)) * 1e3:.2f} mm, worst {diff.max() * 1e3:.2f} mm, "
          f"at the end {diff[-1] * 1e3:.2f} mm")  # fmt: skip
    assert travel > 0.03 and diff.max() < 0.05 * travel


@pytest.mark.slow
def test_a_mujoco_gif_renders_or_is_refused_before_any_episode(tmp_path: Path) -> None:
    """MuJoCo draws with OpenGL. Where it can start (a GPU with MUJOCO_GL=egl, or OSMesa), ``evaluate --gif`` writes
    the GIF; where it cannot (a headless CPU machine), the command says so in one line before running anything."""
    from stewart_gym.errors import ConfigError
    from stewart_gym.sim.mujoco_sim import check_rendering

    try:
        check_rendering()
        can_render = True
    except ConfigError:
        can_render = False
    gif = tmp_path / "m.gif"
    proc = sg("evaluate", "--backend", "mujoco", "--episodes", "1", "--gif", str(gif), timeout=300)  # a GL crash: its own
    if can_render:
        assert proc.returncode == 0 and gif.stat().st_size > 1000, proc.stderr
    else:
        errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
        assert proc.returncode == 1 and len(errors) == 1 and "MUJOCO_GL" in errors[0] and "Traceback" not in proc.stderr
        assert "success rate" not in proc.stdout and not gif.exists()


@pytest.mark.slow
def test_evaluate_train_and_deploy_take_the_mujoco_backend(tmp_path: Path, device: FakeDevice,
                                                          capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """Through the CLI: a shipped policy evaluated in MuJoCo, a short run trained in MuJoCo with a camera (its config
    records both, and ``evaluate`` runs it in that engine with that sensor unless told otherwise), and ``deploy
    --sensor sim --backend mujoco`` on a fake Maestro."""
    import json

    def cli_here(*args: str) -> subprocess.CompletedProcess:
        return sg_in(capfd, *args, cwd=tmp_path)

    ev = cli_here("evaluate", "--backend", "mujoco", "--episodes", "2", "--json")
    assert ev.returncode == 0, ev.stderr
    assert json.loads(ev.stdout.strip().splitlines()[-1])["success_rate"] == 1.0
    hp = tmp_path / "hp.yml"
    hp.write_text("StewartBallBalance-v0:\n  n_envs: 1\n  n_timesteps: 64\n  normalize: true\n  policy: MlpPolicy\n"
                  "  n_steps: 32\n  batch_size: 16\n  n_epochs: 1\n  policy_kwargs:\n    net_arch: [8]\n")  # fmt: skip
    run = cli_here("train", "--backend", "mujoco", "--sensor", "webcam30", "--hyperparams", str(hp), "--run-dir",
                  str(tmp_path / "run"), "--eval-freq", "32", "--eval-episodes", "1", "--no-progress",
                  "--no-tensorboard")  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "backend: mujoco" in (tmp_path / "run" / "config.yaml").read_text()
    for extra, world in (((), ("mujoco", "webcam30")), (("--backend", "pybullet", "--sensor", "panel"),
                                                         ("pybullet", "panel"))):  # fmt: skip
        ev = cli_here("evaluate", "--policy", "run", "--episodes", "1", "--json", *extra)
        assert ev.returncode == 0, ev.stderr
        got = json.loads(ev.stdout.strip().splitlines()[-1])
        assert (got["backend"], got["sensor"]) == world and got["episodes"] == 1
    drain = Board(device)
    dep = sg("deploy", "--policy", "pid", "--backend", "mujoco", "--port", device.path, "--duration", "1",
             "--log", str(tmp_path / "d.csv"), cwd=tmp_path)  # fmt: skip
    data = drain.stop()
    assert dep.returncode == 0, dep.stdout + dep.stderr
    assert "simulated ball" in dep.stdout and len(data) >= 24 * 40  # ~50 Maestro frames of 6 × 4 bytes in 1 s
