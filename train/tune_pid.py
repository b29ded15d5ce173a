"""Tune the cascaded PID baseline by grid search, on the same randomised task the RL policy faces.

Each gain set runs ``--episodes`` seeded episodes of StewartBallBalance-v0 with
randomisation (seeds 10000…, disjoint from the evaluation seeds 0…99). The best
set maximises the success rate, then minimises the RMS error. Writes
``stewart_gym/policies/pid_gains.json`` (or ``--out``) and prints the table.

Run: ``.venv/bin/python train/tune_pid.py [--episodes 30]``
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import asdict
from pathlib import Path

from stewart_gym.classical import CascadedPID, PIDGains
from stewart_gym.evaluation import evaluate
from stewart_gym.registry import POLICY_DIR


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--out", default=str(POLICY_DIR / "pid_gains.json"))
    args = parser.parse_args()
    grid = itertools.product([1.0, 1.5, 2.0], [3.0, 4.0, 5.0], [2.0, 3.0, 4.0])
    rows = []
    for kp_pos, kp_vel, ki_vel in grid:
        gains = PIDGains(kp_pos=kp_pos, kp_vel=kp_vel, ki_vel=ki_vel)
        m = evaluate("StewartBallBalance-v0", CascadedPID(gains), episodes=args.episodes, seed=10_000, settling=False)
        rows.append((m["success_rate"], -m["rms_error_mm"], gains, m))
        print(f"kp_pos={kp_pos:4.1f} kp_vel={kp_vel:4.1f} ki_vel={ki_vel:3.1f}  success {m['success_rate']:.0%}  "
              f"RMS {m['rms_error_mm']:.2f} mm", flush=True)  # fmt: skip
    best = max(rows, key=lambda r: (r[0], r[1]))
    Path(args.out).write_text(json.dumps(asdict(best[2]), indent=2) + "\n")
    m = best[3]
    print(f"best: {asdict(best[2])} → {args.out}: success {m['success_rate']:.0%}, RMS {m['rms_error_mm']:.2f} mm")


if __name__ == "__main__":
    main()
