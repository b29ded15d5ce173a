"""Simulator speed on one core, and (``--solvers``) the measurements behind the constraint settings.

Run: ``.venv/bin/python bench/bench_sim.py [--solvers] [--json]``.

* control steps/s at 50 Hz control with and without the ball (ball resting on the
  plate, so its contact is solved every step), physics steps/s, real-time factor;
* ``--solvers``: for each solver / physics rate / erp, the worst loop gap during
  full-range steps and 2 Hz sinusoids along every pose axis, and the speed.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from stewart_gym.analysis import aggressive_moves  # noqa: E402
from stewart_gym.kinematics import inverse_kinematics  # noqa: E402
from stewart_gym.sim import PhysicsSpec, StewartSim  # noqa: E402


def control_rate(sim: StewartSim, steps: int = 1500, repeats: int = 5) -> float:
    """Best-of-``repeats`` control steps per second."""
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step()
        best = max(best, steps / (time.perf_counter() - t0))
    return best


def worst_gap(sim: StewartSim) -> float:
    """Worst loop gap (m) over :func:`aggressive_moves`: full-range steps and 2 Hz sinusoids on every axis."""
    sim.reset()
    worst = 0.0
    for pose in aggressive_moves(sim.geometry, sim.control_hz):
        sim.command(sim.calibration.pulse_widths(inverse_kinematics(sim.geometry, pose).servo_angles))
        sim.step()
        worst = max(worst, sim.constraint_error())
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--solvers", action="store_true", help="compare solver settings")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    res: dict = {}
    with StewartSim(ball=True) as sim:
        sim.place_ball(np.zeros(2))
        res["control_steps_per_s_ball"] = round(control_rate(sim))
        res["physics_hz"], res["control_hz"] = sim.physics_hz, sim.control_hz
    with StewartSim(ball=False) as sim:
        res["control_steps_per_s_no_ball"] = round(control_rate(sim))
        res["physics_steps_per_s_no_ball"] = res["control_steps_per_s_no_ball"] * sim.substeps
    res["physics_steps_per_s_ball"] = res["control_steps_per_s_ball"] * (res["physics_hz"] // res["control_hz"])
    res["real_time_factor_ball"] = round(res["control_steps_per_s_ball"] / res["control_hz"], 1)
    if args.solvers:
        rows = []
        for solver, hz, erp in [("si", 200, 0.2), ("si", 250, 0.2), ("dantzig", 200, 0.2), ("dantzig", 100, 0.9),
                                ("dantzig", 150, 0.9), ("dantzig", 200, 0.9), ("dantzig", 250, 0.9)]:  # fmt: skip
            with StewartSim(ball=True, physics_hz=hz, physics=PhysicsSpec(solver=solver, erp=erp)) as sim:
                gap = worst_gap(sim)
                sim.reset()
                sim.place_ball(np.zeros(2))
                rows.append({"solver": solver, "physics_hz": hz, "erp": erp, "worst_gap_mm": round(gap * 1e3, 4),
                             "control_steps_per_s": round(control_rate(sim, 800, 3))})  # fmt: skip
        res["solvers"] = rows
    if args.json:
        print(json.dumps(res))
        return
    print(f"StewartSim, one core, {res['physics_hz']} Hz physics / {res['control_hz']} Hz control")
    print(f"  with ball     {res['control_steps_per_s_ball']:>7,} control steps/s  "
          f"({res['physics_steps_per_s_ball']:,} physics steps/s, {res['real_time_factor_ball']}× real time; "
          "target ≥ 4,000)")  # fmt: skip
    print(f"  without ball  {res['control_steps_per_s_no_ball']:>7,} control steps/s  "
          f"({res['physics_steps_per_s_no_ball']:,} physics steps/s)")  # fmt: skip
    if args.solvers:
        print("\nsolver    physics_hz  erp   worst loop gap   control steps/s")
        for r in res["solvers"]:
            print(f"{r['solver']:8s}  {r['physics_hz']:>10}  {r['erp']:.1f}  {r['worst_gap_mm']:>11.4f} mm  "
                  f"{r['control_steps_per_s']:>10,}")  # fmt: skip


if __name__ == "__main__":
    main()
