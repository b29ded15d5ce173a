"""Evaluation wall time: ``stewart-gym evaluate`` with its episodes in one process and split over several.

Run: ``.venv/bin/python bench/bench_evaluate.py [--policy shipped-residual] [--episodes 40] [--workers 1 2]
[--json]``.

Each setting runs the command as a user types it, in a subprocess (``python -m stewart_gym evaluate --policy P
--episodes N --workers W --json``), so the figure includes what a user waits for: Python's start, loading the
policy, and with W > 1 starting W worker processes that each load it again. Reported per setting: the wall
time, episodes per second, and whether the JSON equals the first setting's (an episode depends only on its
seed, so splitting must not change a figure).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time


def run_evaluate(policy: str, episodes: int, workers: int, env: str | None) -> tuple[float, dict]:
    """(wall seconds, the printed JSON) of one ``evaluate`` run."""
    cmd = [sys.executable, "-m", "stewart_gym", "evaluate", "--policy", policy, "--episodes", str(episodes),
           "--workers", str(workers), "--json"]  # fmt: skip
    if env:
        cmd += ["--env", env]
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"error: {' '.join(cmd[1:])} failed: {(done.stderr.strip().splitlines() or ['no message'])[-1]}")
    return wall, json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--policy", default="shipped-residual")
    parser.add_argument("--env", default=None, help="default: the policy's own")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.episodes < 2 or min(args.workers) < 1:
        sys.exit("error: --episodes must be 2 or more and each --workers 1 or more")
    rows = []
    first = None
    for workers in args.workers:
        wall, metrics = run_evaluate(args.policy, args.episodes, workers, args.env)
        first = metrics if first is None else first
        rows.append({"workers": workers, "wall_s": round(wall, 1), "episodes_per_s": round(args.episodes / wall, 2),
                     "same_figures": metrics == first})  # fmt: skip
    if args.json:
        print(json.dumps({"policy": args.policy, "episodes": args.episodes, "cores": os.cpu_count(), "runs": rows}))
        return
    print(f"stewart-gym evaluate --policy {args.policy} --episodes {args.episodes} on {os.cpu_count()} cores")
    print(f"{'workers':>8} {'wall s':>8} {'episodes/s':>11}  figures")
    for row in rows:
        same = f"the same as --workers {rows[0]['workers']}" if row["same_figures"] else "DIFFERENT"
        print(f"{row['workers']:>8} {row['wall_s']:>8.1f} {row['episodes_per_s']:>11.2f}  {same}")


if __name__ == "__main__":
    main()
