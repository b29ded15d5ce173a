"""Regenerate the docs' results page: learned vs PID vs LQR on every task and metric, with robustness.

Run: ``.venv/bin/python train/results.py [--runs runs/seed0 runs/seed1 runs/seed2] [--episodes 100]
[--robust-episodes 50] [--workers 2] [--out docs/src/results.md]``

Every controller goes through :func:`stewart_gym.evaluation.evaluate` on the same seeded, domain-randomised
episodes (seeds 0…N−1). Rows:

* ``shipped PPO``: the shipped learned policy of the task (behind the low-pass observer it was trained with);
* ``residual PPO``: the shipped residual policy (``--policy shipped-residual``: a learned correction of the LQR);
* ``PID``: the tuned cascaded PID behind the low-pass observer (its tuning), and ``PID + Kalman``;
* ``LQR``: the LQR behind the Kalman observer;
* ``--runs``: run folders of one recipe trained with different seeds (e.g. ``make train`` with ``SEED=0,1,2``):
  each is evaluated on the balance task, and the page gives their mean and range (the spread over
  training seeds, not the best run).

Robustness: success on the balance task with the touch panel's latency, then its noise, fixed at each value
(the rest of the randomisation as usual). Writes the page (Markdown), ``results.json`` beside it and
``images/robustness.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
BALANCE, TRACK = "StewartBallBalance-v0", "StewartBallTrack-v0"
TRAJECTORIES = ("circle", "figure8", "waypoints")
#: label → (policy, estimator or None for the policy's own)
CONTROLLERS = {"shipped PPO": ("shipped", None), "residual PPO": ("shipped-residual", None), "PID": ("pid", None),
               "PID + Kalman": ("pid", "kalman"), "LQR": ("lqr", None)}  # fmt: skip
ROBUST = ("shipped PPO", "residual PPO", "PID", "LQR")
METRICS = [("success_rate", "success", "{:.0%}"), ("rms_error_mm", "RMS error, last 5 s (mm)", "{:.2f}"),
           ("final_error_mm", "final error (mm)", "{:.2f}"), ("settling_time_s", "settling time from 100 mm (s)",
                                                              "{:.2f}"),
           ("settled_pulse_rate_us_per_s", "settled pulse rate (µs/s per servo)", "{:.0f}"),
           ("settled_pulse_p2p_us", "settled peak-to-peak (µs, largest channel)", "{:.0f}"),
           ("fell_rate", "ball fell off", "{:.0%}")]  # fmt: skip
LATENCIES_MS = (5, 25, 50, 75, 100)
NOISES_MM = (0.5, 2.0, 4.0, 8.0)


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """One evaluation (in a worker process): load the policy there, evaluate, return the metrics."""
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    source, policy, env_kwargs = load_for_evaluation(job["policy"], job["env"], None, job["estimator"])
    env_kwargs = {**env_kwargs, **job.get("env_kwargs", {})}
    metrics = evaluate(job["env"], policy, episodes=job["episodes"], seed=0, env_kwargs=env_kwargs)
    return {**job, "metrics": {k: v for k, v in metrics.items() if isinstance(v, (int, float)) or v is None}}


def jobs_for(args: argparse.Namespace) -> list[dict[str, Any]]:
    jobs = []
    for label, (policy, estimator) in CONTROLLERS.items():
        jobs.append({"table": "balance", "row": label, "policy": policy, "estimator": estimator, "env": BALANCE,
                     "episodes": args.episodes})  # fmt: skip
        for trajectory in TRAJECTORIES:
            jobs.append({"table": f"track {trajectory}", "row": label, "policy": policy, "estimator": estimator,
                         "env": TRACK, "episodes": args.episodes, "env_kwargs": {"trajectory": trajectory}})  # fmt: skip
    for run in args.runs:
        jobs.append({"table": "balance", "row": f"seed:{run}", "policy": run, "estimator": None, "env": BALANCE,
                     "episodes": args.episodes})  # fmt: skip
    for label in ROBUST:
        policy, estimator = CONTROLLERS[label]
        for ms in LATENCIES_MS:
            jobs.append({"table": "latency", "row": label, "value": ms, "policy": policy, "estimator": estimator,
                         "env": BALANCE, "episodes": args.robust_episodes,
                         "env_kwargs": {"randomization": {"sensor_latency_s": [ms / 1e3, ms / 1e3]}}})  # fmt: skip
        for mm in NOISES_MM:
            jobs.append({"table": "noise", "row": label, "value": mm, "policy": policy, "estimator": estimator,
                         "env": BALANCE, "episodes": args.robust_episodes,
                         "env_kwargs": {"randomization": {"sensor_noise_mm": [mm, mm]}}})  # fmt: skip
    return jobs


def fmt(value: Any, pattern: str) -> str:
    return "–" if value is None or value != value else pattern.format(value)


def spread(values: list[float], pattern: str) -> str:
    """Mean and range over training seeds."""
    if not values:
        return "–"
    return f"{fmt(statistics.mean(values), pattern)} ({fmt(min(values), pattern)}–{fmt(max(values), pattern)})"


def tables(results: list[dict[str, Any]], runs: list[str]) -> str:
    out = []
    for table in ["balance", *(f"track {t}" for t in TRAJECTORIES)]:
        rows = {r["row"]: r["metrics"] for r in results if r["table"] == table}
        columns = list(CONTROLLERS)
        metrics = METRICS if table == "balance" else [m for m in METRICS if m[0] != "settling_time_s"]
        seeds = [rows[f"seed:{run}"] for run in runs if f"seed:{run}" in rows]
        header = "| metric | " + " | ".join(columns) + (f" | recipe, {len(seeds)} training seeds |" if seeds else " |")
        out += [f"### {table.capitalize()}", "", header, "|---" * (len(columns) + 1 + bool(seeds)) + "|"]
        for key, name, pattern in metrics:
            cells = [fmt(rows[c].get(key), pattern) if c in rows else "–" for c in columns]
            if seeds:
                cells.append(spread([s[key] for s in seeds if s.get(key) is not None], pattern))
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        out.append("")
    for table, unit, values in (("latency", "ms", LATENCIES_MS), ("noise", "mm", NOISES_MM)):
        rows = {(r["row"], r["value"]): r["metrics"]["success_rate"] for r in results if r["table"] == table}
        out += [f"### Success against the panel's {table} (balance, {unit})", "",
                "| controller | " + " | ".join(f"{v:g} {unit}" for v in values) + " |",
                "|---" * (len(values) + 1) + "|"]  # fmt: skip
        for label in ROBUST:
            out.append(f"| {label} | " + " | ".join(fmt(rows.get((label, v)), "{:.0%}") for v in values) + " |")
        out.append("")
    return "\n".join(out)


def plot(results: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, (table, unit, values) in zip(axes, (("latency", "ms", LATENCIES_MS), ("noise", "mm", NOISES_MM))):
        for label in ROBUST:
            ys = [next((100 * r["metrics"]["success_rate"] for r in results if r["table"] == table
                        and r["row"] == label and r["value"] == v), None) for v in values]  # fmt: skip
            ax.plot(values, ys, marker="o", label=label)
        ax.set(xlabel=f"touch-panel {table} [{unit}]", ylabel="success [%]", ylim=(-5, 105))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("StewartBallBalance-v0: success against sensing latency and noise (randomised episodes)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", nargs="*", default=[], help="run folders of one recipe, trained with different seeds")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--robust-episodes", type=int, default=50)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--out", default=str(ROOT / "docs/src/results.md"))
    ap.add_argument("--from-json", action="store_true", help="rebuild the page from results.json beside it (after "
                                                             "editing train/results_intro.md), evaluating nothing")
    args = ap.parse_args()
    out = Path(args.out)
    jobs = jobs_for(args)
    if args.from_json:
        results = json.loads((out.parent / "results.json").read_text())
        args.runs = list(dict.fromkeys(r["row"][5:] for r in results if r["row"].startswith("seed:")))
        jobs = results
    else:
        with ProcessPoolExecutor(args.workers) as pool:
            results = list(pool.map(run_job, jobs))
        (out.parent / "results.json").write_text(json.dumps(results, indent=1, default=str) + "\n")
    plot(results, out.parent / "images" / "robustness.png")
    intro = (ROOT / "train" / "results_intro.md").read_text()
    text = intro.rstrip() + "\n\n" + tables(results, args.runs) + "\n![robustness](images/robustness.png)\n"
    out.write_text(f"<!-- generated by train/results.py on {len(jobs)} evaluations; edit train/results_intro.md -->\n"
                   + text.lstrip())  # fmt: skip
    print(f"wrote {out}, {out.parent / 'results.json'} and {out.parent / 'images' / 'robustness.png'}")


if __name__ == "__main__":
    main()
