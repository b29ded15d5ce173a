"""Steps per second of the simulators and of the envs on them, in one run.

* simulators (one control step of one platform with its ball): one PyBullet simulator, one MuJoCo simulator,
  and the batched simulator at N = 1, 64, 1,024 and 4,096 (its compiled kernel, numba's; and its NumPy kernel at
  N = 4,096, for comparison);
* envs (``StewartBallBalance-v0``, randomised, behind the Kalman observer, random tilt actions of ±0.3, an
  episode reset when it ends): one PyBullet, one MuJoCo and one batched env (``gym.make``), and the batched
  vector env (``gym.make_vec(..., vectorization_mode="vector_entry_point")``) at N = 64, 1,024 and 4,096, at
  N = 1,024 with cameras (``sensor="camera"``: a preset drawn per episode) instead of touch panels, and split over
  2 processes (``workers=2``) at N = 4,096 and 8,192.

Run: ``.venv/bin/python bench/bench_batched.py [--json]``. Each figure is the best of three timed runs; the
ratio column is against the PyBullet simulator, or the PyBullet env, of the same run. The threads are left as a
user's program has them (no ``OMP_NUM_THREADS`` or ``OPENBLAS_NUM_THREADS`` set here), and the cores column is
this process's CPU time (and its worker processes', on Linux) over the wall time of the best run: a figure bought
with a second busy core shows there.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from stewart_gym.sim.batched import BatchedSim
from stewart_gym.sim.engines import make_backend


def worker_cpu(pids: list[int]) -> float:
    """CPU seconds the processes ``pids`` have used so far (Linux's ``/proc``; 0 elsewhere)."""
    total = 0.0
    for pid in pids:
        try:
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime
    return total


def rate(step, platforms: int, seconds: float = 1.0, pids: list[int] = ()) -> tuple[float, float]:
    """Best of three: platform-steps per second of ``step()`` run for about ``seconds``, and the cores that run
    used (its CPU time, and that of the worker processes ``pids``, over its wall time)."""
    best = (0.0, 0.0)
    for _ in range(3):
        count, start, cpu = 0, time.perf_counter(), time.process_time() + worker_cpu(pids)
        while time.perf_counter() - start < seconds:
            step(count)
            count += 1
        wall = time.perf_counter() - start
        best = max(best, (count * platforms / wall, (time.process_time() + worker_cpu(pids) - cpu) / wall))
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()
    results: dict[str, tuple[float, float]] = {}
    for engine in ("pybullet", "mujoco"):
        sim = make_backend(engine, "servo-hexapod", ball=True)
        sim.reset()
        pulses = [sim.calibration.neutral_us + d for d in (0.0, 20.0)]

        def one(i: int, sim=sim, pulses=pulses) -> None:
            sim.command(pulses[i % 2])
            sim.step()

        results[f"{engine}, one simulator"] = rate(one, 1)
        sim.close()
    for n, kernel in ((1, "auto"), (64, "auto"), (1024, "auto"), (4096, "auto"), (4096, "numpy")):
        batched = BatchedSim("servo-hexapod", n=n, kernel=kernel)
        pulses = [np.broadcast_to(batched.calibration.neutral_us + d, (n, 6)) for d in (0.0, 20.0)]

        def many(i: int, batched=batched, pulses=pulses) -> None:
            batched.command(pulses[i % 2])
            batched.step()

        many(0)  # the compiled kernel loads (or compiles, once per checkout) at its first step
        results[f"batched, N = {n:,}" + (", NumPy kernel" if kernel == "numpy" else "")] = rate(many, n)
    envs = env_rates()
    if args.json:
        both = {**results, **envs}
        cores = {k: round(c, 2) for k, (_, c) in both.items()}
        print(json.dumps({**{k: round(v) for k, (v, _) in both.items()}, "cores": cores}))
        return
    for title, table, reference in (("simulator", results, "pybullet, one simulator"),
                                    ("env", envs, "pybullet, one env")):  # fmt: skip
        print(f"{title:<40}{'steps/s':>12}{'× PyBullet':>12}{'cores':>8}")
        for name, value in table.items():
            print(f"{name:<40}{value[0]:>12,.0f}{value[0] / table[reference][0]:>12.1f}{value[1]:>8.2f}")
        print()


def env_rates() -> dict[str, tuple[float, float]]:
    """Env steps per second: one PyBullet env, one MuJoCo env, one batched env, and the batched vector env at a
    few sizes; random tilt actions (±0.3), each episode reset when it ends."""
    import gymnasium as gym

    import stewart_gym  # noqa: F401

    kwargs = {"randomize": True, "estimator": "kalman"}
    out: dict[str, tuple[float, float]] = {}
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (1000, 2)).astype(np.float32)
    for backend in ("pybullet", "mujoco", "batched"):
        env = gym.make("StewartBallBalance-v0", backend=backend, **kwargs)
        env.reset(seed=0)

        def single(i: int, env=env) -> None:
            _, _, terminated, truncated, _ = env.step(actions[i % 1000])
            if terminated or truncated:
                env.reset()

        out[f"{backend}, one env"] = rate(single, 1)
        env.close()
    for sensor, sizes, workers in (("panel", (64, 1024, 4096), 1), ("camera", (1024,), 1),
                                   ("panel", (4096, 8192), 2)):  # fmt: skip
        for n in sizes:
            vector = gym.make_vec("StewartBallBalance-v0", num_envs=n, vectorization_mode="vector_entry_point",
                                  sensor=sensor, workers=workers, **kwargs)  # fmt: skip
            vector.reset(seed=0)
            batch = np.random.default_rng(1).uniform(-0.3, 0.3, (8, n, 2)).astype(np.float32)
            name = (f"batched vector env, N = {n:,}" + (", cameras" if sensor == "camera" else "")
                    + (f", {workers} workers" if workers > 1 else ""))  # fmt: skip
            out[name] = rate(lambda i, v=vector, b=batch: v.step(b[i % 8]), n, seconds=2.0,
                             pids=getattr(vector, "pids", []))  # fmt: skip
            vector.close()
    return out


if __name__ == "__main__":
    main()
