"""Environment speed on one core, next to the bare simulator in the same run.

Run: ``.venv/bin/python bench/bench_env.py [--json]``.

For each registered env id (tilt actions, randomisation on and off): env steps/s
with random actions. The baseline is ``StewartSim`` stepping with a new pulse
command every step (the same servo traffic the env causes, without IK, sensing,
observation or reward): the env's cost is reported as a multiple of it.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import stewart_gym  # noqa: E402
from stewart_gym.actions import ActionMapper  # noqa: E402
from stewart_gym.sim import StewartSim  # noqa: E402


def env_rate(env_id: str, steps: int, randomize: bool, repeats: int = 3) -> float:
    env = gym.make(env_id, randomize=randomize).unwrapped  # no wrappers: the env's own cost
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, env.action_space.shape[0])).astype(np.float32) * 0.3
    best = 0.0
    for r in range(repeats):
        env.reset(seed=r)
        t0 = time.perf_counter()
        for a in actions:
            _, _, terminated, _, _ = env.step(a)
            if terminated:
                env.reset()
        best = max(best, steps / (time.perf_counter() - t0))
    env.close()
    return best


def sim_rate(steps: int, repeats: int = 3) -> float:
    """Bare simulator: command the pulses of a random tilt sequence, step."""
    rng = np.random.default_rng(0)
    with StewartSim(ball=True) as sim:
        mapper = ActionMapper(sim.geometry, sim.calibration, "tilt")
        pulses = [mapper(a).pulses for a in rng.uniform(-1, 1, (steps, 2)) * 0.3]
        best = 0.0
        for _ in range(repeats):
            sim.reset()
            sim.place_ball(np.zeros(2))
            t0 = time.perf_counter()
            for w in pulses:
                sim.command(w)
                sim.step()
            best = max(best, steps / (time.perf_counter() - t0))
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    base = sim_rate(args.steps)
    res = {"sim_command_step_per_s": round(base), "envs": []}
    for env_id in stewart_gym.ENV_IDS:
        for randomize in (False, True):
            rate = env_rate(env_id, args.steps, randomize)
            res["envs"].append({"id": env_id, "randomize": randomize, "steps_per_s": round(rate),
                                "cost_vs_sim": round(base / rate, 3)})  # fmt: skip
    if args.json:
        print(json.dumps(res))
        return
    print(f"bare StewartSim (command + step, ball): {base:,.0f} steps/s")
    for r in res["envs"]:
        print(f"  {r['id']:24s} randomize={r['randomize']!s:5s} {r['steps_per_s']:>6,} steps/s  "
              f"{r['cost_vs_sim']:.2f}× the sim's cost   (targets ≥ 3,000 and ≤ 1.3×)")  # fmt: skip


if __name__ == "__main__":
    main()
