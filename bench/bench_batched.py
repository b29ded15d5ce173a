"""Platform-steps per second (one control step of one platform with its ball), in one run: one PyBullet
simulator, one MuJoCo simulator, and the batched NumPy simulator at N = 1, 64, 1,024 and 4,096.

Run: ``.venv/bin/python bench/bench_batched.py [--json]``. Each figure is the best of three timed runs of
a tilt command alternating every step; the ratio column is against the PyBullet simulator of the same run.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from stewart_gym.sim.batched import BatchedSim  # noqa: E402
from stewart_gym.sim.engines import make_backend  # noqa: E402


def rate(step, platforms: int, seconds: float = 1.0) -> float:
    """Best of three: platform-steps per second of ``step()`` run for about ``seconds``."""
    best = 0.0
    for _ in range(3):
        count, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            step(count)
            count += 1
        best = max(best, count * platforms / (time.perf_counter() - start))
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()
    results: dict[str, float] = {}
    for engine in ("pybullet", "mujoco"):
        sim = make_backend(engine, "servo-hexapod", ball=True)
        sim.reset()
        pulses = [sim.calibration.neutral_us + d for d in (0.0, 20.0)]

        def one(i: int, sim=sim, pulses=pulses) -> None:
            sim.command(pulses[i % 2])
            sim.step()

        results[f"{engine}, one simulator"] = rate(one, 1)
        sim.close()
    for n in (1, 64, 1024, 4096):
        batched = BatchedSim("servo-hexapod", n=n)
        pulses = [np.broadcast_to(batched.calibration.neutral_us + d, (n, 6)) for d in (0.0, 20.0)]

        def many(i: int, batched=batched, pulses=pulses) -> None:
            batched.command(pulses[i % 2])
            batched.step()

        results[f"batched, N = {n:,}"] = rate(many, n)
    if args.json:
        print(json.dumps({k: round(v) for k, v in results.items()}))
        return
    reference = results["pybullet, one simulator"]
    print(f"{'simulator':<26}{'platform-steps/s':>18}{'× PyBullet':>12}")
    for name, value in results.items():
        print(f"{name:<26}{value:>18,.0f}{value / reference:>12.1f}")


if __name__ == "__main__":
    main()
