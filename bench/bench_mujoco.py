"""MuJoCo twin: the solver settings measured, as ``bench_sim.py --solvers`` does for PyBullet.

Run: ``.venv/bin/python bench/bench_mujoco.py [--json]``.

For each setting (physics rate, loop constraint solref and solimp) on the reference build with the ball, one
core: the worst loop gap over full-range steps and 2 Hz sinusoids along every pose axis
(:func:`~stewart_gym.analysis.aggressive_moves`), the worst settled pose error over 20 random reachable poses
(servos without dead band), the ball's acceleration on a 3° plate against (5/7)·g·sin θ, and µs per control
step during the moves. The default :class:`~stewart_gym.sim.mjcf.MujocoPhysics` is marked.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from stewart_gym.analysis import aggressive_moves  # noqa: E402
from stewart_gym.kinematics import inverse_kinematics  # noqa: E402
from stewart_gym.presets import load_preset  # noqa: E402
from stewart_gym.sim import ServoSpec  # noqa: E402
from stewart_gym.sim.mjcf import MujocoPhysics  # noqa: E402
from stewart_gym.sim.mujoco_sim import MujocoSim  # noqa: E402

GEO = load_preset("servo-hexapod")
DEFAULT = MujocoPhysics()
SOFT = (0.9, 0.95, 0.001)  # MuJoCo's default impedance
SETTINGS = [
    MujocoPhysics(physics_hz=150, loop_solref=(0.02, 1.0), loop_solimp=SOFT),
    MujocoPhysics(physics_hz=150, loop_solref=(0.02, 1.0)),
    MujocoPhysics(physics_hz=150, loop_solref=(0.0134, 0.5), contact_solref=(0.0134, 1.0)),
    MujocoPhysics(physics_hz=250, loop_solref=(0.008, 1.0)),
    DEFAULT,
    MujocoPhysics(physics_hz=500, loop_solref=(0.004, 1.0), loop_solimp=(0.99, 0.999, 0.001)),
]


def measure(phys: MujocoPhysics) -> dict:
    with MujocoSim(GEO, ball=True, physics=phys) as sim:
        moves = aggressive_moves(GEO, sim.control_hz)
        pulses = sim.calibration.pulse_widths(inverse_kinematics(GEO, moves).servo_angles)
        gaps = []
        t0 = time.perf_counter()
        for p in pulses:
            sim.command(p)
            sim.step()
            gaps.append(sim.constraint_error())
        us_per_step = (time.perf_counter() - t0) / len(pulses) * 1e6
        rng = np.random.default_rng(11)
        box = np.array([0.015, 0.015, 0.010, math.radians(9), math.radians(9), math.radians(12)])
        poses = rng.uniform(-1, 1, (400, 6)) * box
        poses = poses[inverse_kinematics(GEO, poses).reachable][:20]
        sim.reset(servo_spec=replace(ServoSpec(), deadband_us=0.0))
        worst = np.zeros(2)
        for pose in poses:
            sim.command(sim.calibration.pulse_widths(inverse_kinematics(GEO, pose).servo_angles))
            for _ in range(40):
                sim.step()
            err = np.abs(sim.platform_pose() - pose)
            worst = np.maximum(worst, [err[:3].max() * 1e3, math.degrees(err[3:].max())])
        sim.reset()
        tilt = np.array([0, 0, 0, 0, math.radians(3), 0])
        p = sim.calibration.pulse_widths(inverse_kinematics(GEO, tilt).servo_angles)
        for _ in range(25):
            sim.command(p)
            sim.step()
        sim.place_ball(np.array([-0.08, 0.0]))
        ts, xs = [], []
        for _ in range(20):
            sim.step()
            ts.append(sim.time)
            xs.append(sim.ball_position()[0])
        accel = 2 * np.polyfit(ts, xs, 2)[0] / (5 / 7 * 9.80665 * math.sin(sim.platform_pose()[4]))
    return {"physics_hz": phys.physics_hz, "loop_solref": list(phys.loop_solref), "loop_solimp": list(phys.loop_solimp),
            "default": phys == DEFAULT, "worst_gap_mm": round(max(gaps) * 1e3, 4),
            "settled_mm": round(float(worst[0]), 4), "settled_deg": round(float(worst[1]), 4),
            "rolling_vs_theory": round(float(accel), 4), "us_per_control_step": round(us_per_step)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = [measure(s) for s in SETTINGS]
    if args.json:
        print(json.dumps(rows))
        return
    print("MuJoCo settings on servo-hexapod with the ball (one core):")
    for r in rows:
        print(f"  {r['physics_hz']:>3} Hz  solref {r['loop_solref']}  solimp {r['loop_solimp'][:2]}  "
              f"gap {r['worst_gap_mm']:.3f} mm  settled {r['settled_mm']:.3f} mm {r['settled_deg']:.4f}°  "
              f"rolling {r['rolling_vs_theory']:.3f}× theory  {r['us_per_control_step']} µs/step"
              f"{'   <- default' if r['default'] else ''}")  # fmt: skip


if __name__ == "__main__":
    main()
