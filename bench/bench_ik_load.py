"""Batched IK on a busy machine: its speed against a hand-vectorised numpy reference, quiet and with two busy
processes, timed in one run (BLAS keeps its default threads here, as on a user's laptop).

Run: ``.venv/bin/python bench/bench_ik_load.py [--poses N] [--json]``. Prints poses/s of both and their ratio
(reference time / batched time: above 1, the batched IK is faster), quiet and loaded.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_kinematics import hand_vectorised_servo_ik  # noqa: E402

from stewart_gym.cli.common import int_at_least
from stewart_gym.kinematics import inverse_kinematics  # noqa: E402
from stewart_gym.presets import load_preset  # noqa: E402


def timings(geo: object, poses: np.ndarray, tries: int = 5) -> dict[str, float]:
    best = {"batched": math.inf, "reference": math.inf}
    for _ in range(tries):
        for name, run in (("batched", lambda: inverse_kinematics(geo, poses)),
                          ("reference", lambda: hand_vectorised_servo_ik(geo, poses))):  # fmt: skip
            t0 = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - t0)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--poses", type=int_at_least(1), default=100_000)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    geo = load_preset("servo-hexapod")
    poses = np.random.default_rng(0).uniform(-1, 1, (args.poses, 6)) * np.array([0.02, 0.02, 0.01, 0.14, 0.14, 0.26])
    out = {}
    for label in ("quiet", "two busy processes"):
        busy = [] if label == "quiet" else [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                                            for _ in range(2)]  # fmt: skip
        try:
            time.sleep(0.5 if busy else 0.0)
            best = timings(geo, poses)
        finally:
            for proc in busy:
                proc.kill()
                proc.wait()
        out[label] = {"batched_poses_per_s": round(args.poses / best["batched"]),
                      "reference_poses_per_s": round(args.poses / best["reference"]),
                      "ratio": round(best["reference"] / best["batched"], 2)}  # fmt: skip
    if args.json:
        print(json.dumps(out))
        return
    for label, r in out.items():
        print(f"{label:20s} batched {r['batched_poses_per_s']:>11,} poses/s   reference {r['reference_poses_per_s']:>11,}"
              f" poses/s   batched is {r['ratio']:.2f}× the reference")  # fmt: skip


if __name__ == "__main__":
    main()
