"""Sweep throughput on Ray: aggregate env steps per second with 1, 2, … concurrent trials on this machine, and
what a 100-trial sweep would take on a cluster.

Run: ``.venv/bin/python bench/bench_sweep.py [--trials 4] [--steps 20000] [--concurrency 1 2] [--json]``.

Each setting runs one sweep of ``--trials`` identical PPO trials on the balance task (``n_envs`` 1: one CPU per
trial, one evaluation of 5 episodes at the end) through :func:`stewart_gym.sweep.run_sweep`, on a local Ray
started for it. Reported: the sweep's wall time from start to results (Ray's start included), the trials'
env steps summed and divided by that wall time (aggregate throughput), and each trial's own rate (its
training steps over its training time). The estimate for a cluster scales the measured per-trial time by
the trials that fit at once (``cores // n_envs`` per node).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import tempfile
import time

from stewart_gym.sweep import SweepSpec, run_sweep


def one_sweep(trials: int, steps: int, concurrent: int) -> dict[str, float]:
    spec = SweepSpec(env="StewartBallBalance-v0", algo="ppo", n_timesteps=steps, n_envs=1, seeds=list(range(trials)),
                     fixed={"n_steps": 1024, "batch_size": 128}, scheduler="fifo", eval_freq=steps, eval_episodes=5,
                     max_concurrent=concurrent, name=f"bench_{concurrent}")  # fmt: skip
    with tempfile.TemporaryDirectory() as out:
        started = time.perf_counter()
        rows = run_sweep(spec, out, echo=lambda _: None)
        wall = time.perf_counter() - started
    done = [r for r in rows if r["status"] == "finished"]
    total = sum(int(r["timesteps"]) for r in done)
    return {"concurrent": concurrent, "trials": len(done), "wall_s": round(wall, 1),
            "aggregate_steps_per_s": round(total / wall), "per_trial_steps_per_s": round(
                statistics.median(float(r["env_steps_per_s"]) for r in done)),
            "trial_wall_s": round(statistics.median(float(r["wall_s"]) for r in done), 1)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=4)
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--concurrency", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    results = [one_sweep(args.trials, args.steps, k) for k in args.concurrency]
    if args.json:
        print(json.dumps(results, indent=2))
        return
    print(f"{args.trials} PPO trials of {args.steps} steps (balance, n_envs 1) on {os.cpu_count()} cores")
    print(f"{'concurrent':>10} {'sweep wall s':>12} {'aggregate steps/s':>18} {'per-trial steps/s':>18}")
    for r in results:
        print(f"{r['concurrent']:>10} {r['wall_s']:>12} {r['aggregate_steps_per_s']:>18} {r['per_trial_steps_per_s']:>18}")
    base = results[0]
    for r in results[1:]:
        print(f"{r['concurrent']} concurrent: {r['aggregate_steps_per_s'] / base['aggregate_steps_per_s']:.2f}× the "
              f"aggregate throughput of {base['concurrent']}")  # fmt: skip
    # on paper: one trial's time at the measured per-trial rate, for the balance recipe's 150k steps
    trial_s = 150_000 / max(r["per_trial_steps_per_s"] for r in results[:1])
    print("\nOn paper, 100 trials of 150k steps (n_envs 1, a trial's rate as measured with 1 at a time):")
    for nodes in (1, 2, 4, 8):
        slots = nodes * 16
        print(f"  {nodes} × 16-core node(s): {slots} trials at once, {math.ceil(100 / slots)} round(s), about "
              f"{math.ceil(100 / slots) * trial_s / 60:.0f} min")  # fmt: skip


if __name__ == "__main__":
    main()
