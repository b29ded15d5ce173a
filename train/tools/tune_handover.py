"""Tune where the LQR hands the ball over to the PID + Kalman (``--policy lqr-pid``), by grid search.

The hand-over (:class:`stewart_gym.control.HandoverDesign`) keeps today's LQR design and PID + Kalman gains
(``policies/lqr.json``, ``policies/pid_kalman_gains.json``) and varies where the PID takes over: within
``handover_mm`` of the target and slower than ``handover_mm_s``. Each set runs ``--episodes`` seeded,
randomised episodes of StewartBallBalance-v0 (seeds 10000…, disjoint from the evaluation seeds 0…99) and as
many settling tests from 100 mm. A hand-over close in lets the LQR hold longer (faster settling, a looser
hold); a wide one hands a moving ball to the PID's slow approach. The best set has the highest success, then
the fastest settling among the sets whose RMS error is within ``--rms-margin`` (default 5 %) of the lowest.
Writes ``policies/lqr_pid.json`` (``--out`` elsewhere) and prints the table.

Run: ``.venv/bin/python train/tools/tune_handover.py [--episodes 30] [--handover-mm 1,2,3,5] [--handover-mm-s 10,20,50]``
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import asdict, replace
from pathlib import Path

from stewart_gym.control import checked_design, classical_controller, shipped_design
from stewart_gym.evaluation import evaluate
from stewart_gym.registry import POLICY_DIR


def floats(text: str) -> list[float]:
    """A comma-separated list of numbers: ``1,1.5,2``."""
    return [float(v) for v in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--out", default=str(POLICY_DIR / "lqr_pid.json"))
    parser.add_argument("--handover-mm", type=floats, default=[1.0, 2.0, 3.0, 5.0])
    parser.add_argument("--handover-mm-s", type=floats, default=[10.0, 20.0, 50.0])
    parser.add_argument("--release-mm", type=float, default=20.0)
    parser.add_argument("--rms-margin", type=float, default=0.05, help="fraction of the lowest RMS (default 0.05)")
    args = parser.parse_args()
    if args.episodes < 1 or not args.rms_margin >= 0:
        parser.error("--episodes must be at least 1 and --rms-margin 0 or more")
    base = shipped_design("lqr-pid")
    base = replace(base, lqr=shipped_design("lqr"), pid=shipped_design("pid-kalman"), release_mm=args.release_mm)
    designs = []
    for mm, mm_s in itertools.product(args.handover_mm, args.handover_mm_s):
        try:  # every set checked before the first evaluation
            designs.append(checked_design(asdict(replace(base, handover_mm=mm, handover_mm_s=mm_s)), "handover"))
        except ValueError as exc:
            parser.error(f"hand-over {mm} mm, {mm_s} mm/s: {exc}")
    rows = []
    for design in designs:
        mm, mm_s = design.handover_mm, design.handover_mm_s
        m = evaluate("StewartBallBalance-v0", classical_controller("handover", design), episodes=args.episodes,
                     seed=10_000, env_kwargs={"estimator": "kalman"})  # fmt: skip
        m["settling_time_s"] = m["settling_time_s"] if m["settling_time_s"] is not None else float("inf")  # none settled
        rows.append((design, m))
        print(f"handover {mm:3.1f} mm, {mm_s:4.1f} mm/s  success {m['success_rate']:.0%}  RMS {m['rms_error_mm']:.2f} mm"
              f"  final {m['final_error_mm']:.2f} mm  settling {m['settling_time_s']:.2f} s  settled "
              f"{m['settled_pulse_rate_us_per_s']:.0f} us/s, p2p {m['settled_pulse_p2p_us']:.0f} us", flush=True)
    top = max(m["success_rate"] for _, m in rows)
    lowest = min(m["rms_error_mm"] for _, m in rows if m["success_rate"] == top)
    near = [r for r in rows if r[1]["success_rate"] == top and r[1]["rms_error_mm"] <= (1 + args.rms_margin) * lowest]
    design, m = min(near, key=lambda r: (r[1]["settling_time_s"], r[1]["rms_error_mm"]))
    Path(args.out).write_text(json.dumps(asdict(design), indent=2) + "\n")
    print(f"best: handover {design.handover_mm} mm, {design.handover_mm_s} mm/s → {args.out}: success "
          f"{m['success_rate']:.0%}, RMS {m['rms_error_mm']:.2f} mm, settling {m['settling_time_s']:.2f} s")


if __name__ == "__main__":
    main()
