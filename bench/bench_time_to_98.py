"""Wall time to a ≥ 98 % policy, from scratch, for each training recipe: the first checkpoint that succeeds on
≥ 98 % of held-out randomised episodes in PyBullet and in MuJoCo.

Run: ``.venv/bin/python bench/bench_time_to_98.py [--env balance|track] [--recipes ppo_batched,ppo]
[--seeds 0,1,2] [--eval-freq 25000] [--episodes 100] [--max-minutes 6] [--budget-s S] [--json]``.

For each recipe and seed it runs ``python -m stewart_gym train`` as a user types it (no TensorBoard), with a
checkpoint at every evaluation. The training's own evaluations (the recipe's ``eval_episodes``, in its own
backend) point at the candidates: each checkpoint whose evaluation reached 98 %, in order, is evaluated with
``stewart-gym evaluate`` on ``--episodes`` randomised seeds in PyBullet and then in MuJoCo. The time reported is
the training's wall time when the first checkpoint that passes both was taken (the training's own evaluations
running beside it, in a second process on 2 cores), with the time its in-training evaluation came back at; the
held-out evaluations are not timed. A run that has none within ``--max-minutes`` reports ``none``.

The track env is evaluated on ``--trajectory mixed`` (circle, figure-8 and waypoints, one drawn per episode).

``--budget-s S`` asks the other way round, as a user with S seconds would: each run trains with
``--max-minutes S/60`` and the model it ends with is evaluated on the held-out episodes in both engines (its
steps, success rates and RMS errors are reported).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ENVS = {"balance": "StewartBallBalance-v0", "track": "StewartBallTrack-v0"}
TARGET = 0.98


def stewart_gym(*args: str) -> str:
    """Run ``python -m stewart_gym ARGS``; its stdout (exits with its last error line if it fails)."""
    proc = subprocess.run([sys.executable, "-m", "stewart_gym", *args], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"error: stewart-gym {' '.join(args[:3])} … failed: "
                 f"{(proc.stderr.strip().splitlines() or ['no message'])[-1]}")  # fmt: skip
    return proc.stdout


def evaluated(model: Path, env: str, episodes: int, backend: str) -> dict:
    """``stewart-gym evaluate --json`` of a policy on ``episodes`` randomised seeds in one engine."""
    extra = ["--trajectory", "mixed"] if env == "track" else []
    return json.loads(stewart_gym("evaluate", "--policy", str(model), "--backend", backend, "--episodes",
                                  str(episodes), "--json", *extra))  # fmt: skip


def held_out(model: Path, env: str, episodes: int) -> dict[str, float]:
    """Success rate of a checkpoint on ``episodes`` randomised seeds in each engine."""
    out = {}
    for backend in ("pybullet", "mujoco"):
        out[backend] = float(evaluated(model, env, episodes, backend)["success_rate"])
        if out[backend] < TARGET:
            break  # no need for the second engine
    return out


def time_to_target(recipe: str, env: str, seed: int, eval_freq: int, episodes: int, max_minutes: float,
                   run: Path) -> dict:  # fmt: skip
    stewart_gym("train", "--env", ENVS[env], "--hyperparams", recipe, "--seed", str(seed), "--run-dir", str(run),
                "--eval-freq", str(eval_freq), "--checkpoint-freq", str(eval_freq), "--max-minutes", str(max_minutes),
                "--no-progress", "--no-tensorboard", "--overwrite")  # fmt: skip
    with (run / "eval.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    tried = []
    for row in rows:
        if float(row["success_rate"]) < TARGET:
            continue
        steps = int(row["timesteps"])
        model = run / "checkpoints" / f"rl_model_{steps}_steps.zip"
        if not model.is_file():
            continue
        rates = held_out(model, env, episodes)
        tried.append({"timesteps": steps, "wall_s": float(row["wall_s"]), **rates})
        if all(rates.get(b, 0.0) >= TARGET for b in ("pybullet", "mujoco")):
            return {"recipe": recipe, "seed": seed, "wall_s": float(row["wall_s"]),
                    "evaluated_s": float(row["evaluated_s"]), "timesteps": steps, **rates, "candidates": tried}  # fmt: skip
    return {"recipe": recipe, "seed": seed, "wall_s": None, "timesteps": None, "candidates": tried,
            "trained_s": json.loads((run / "metrics.json").read_text())["wall_time_s"]}


def within_budget(recipe: str, env: str, seed: int, budget_s: float, episodes: int, run: Path) -> dict:
    """Train for ``budget_s`` of wall time; the final model's held-out success and RMS error in each engine."""
    stewart_gym("train", "--env", ENVS[env], "--hyperparams", recipe, "--seed", str(seed), "--run-dir", str(run),
                "--max-minutes", str(budget_s / 60), "--no-progress", "--no-tensorboard", "--overwrite")  # fmt: skip
    metrics = json.loads((run / "metrics.json").read_text())
    row = {"recipe": recipe, "seed": seed, "budget_s": budget_s, "timesteps": metrics["timesteps"]}
    for backend in ("pybullet", "mujoco"):
        got = evaluated(run, env, episodes, backend)
        row[backend] = float(got["success_rate"])
        row[f"{backend}_rms_mm"] = got.get("rms_error_mm")
    return row


def budget_line(env: str, row: dict) -> str:
    """One budgeted run as a line: its steps and the final model's held-out results."""
    engines = ", ".join(f"{b} {row[b]:.0%} ({row[f'{b}_rms_mm']:.2f} mm RMS)" for b in ("pybullet", "mujoco"))
    return (f"{env} {row['recipe']:<14} seed {row['seed']}: {row['timesteps']:,} steps in {row['budget_s']:g} s; "
            f"the final model: {engines}")


def line(env: str, row: dict) -> str:
    """One run as a line: the time to the target, and each checkpoint tried (PyBullet / MuJoCo success)."""
    got = "none" if row["wall_s"] is None else (f"{row['wall_s']:.1f} s ({row['timesteps']:,} steps; its in-training "
                                                f"evaluation came back at {row['evaluated_s']:.1f} s)")  # fmt: skip
    tried = ", ".join(f"{c['timesteps']:,} steps " + " / ".join(f"{c[b]:.0%}" if b in c else "–"
                                                                for b in ("pybullet", "mujoco"))
                      for c in row["candidates"])  # fmt: skip
    return (f"{env} {row['recipe']:<14} seed {row['seed']}: ≥ {TARGET:.0%} in PyBullet and MuJoCo after {got}; "
            f"checkpoints tried (PyBullet / MuJoCo): {tried or 'none'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", choices=sorted(ENVS), default="balance")
    parser.add_argument("--recipes", default="ppo_batched,ppo", help="comma-separated recipe names or YAML files")
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated training seeds")
    parser.add_argument("--eval-freq", type=int, default=25_000, help="env steps between checkpoints")
    parser.add_argument("--episodes", type=int, default=100, help="held-out episodes per engine")
    parser.add_argument("--max-minutes", type=float, default=6.0, help="training wall time per run, at most")
    parser.add_argument("--budget-s", type=float, help="train each run this long, then test its final model")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        parser.error(f"--seeds must be whole numbers separated by commas, got {args.seeds!r}")
    if min(seeds) < 0 or args.eval_freq < 1 or args.episodes < 1 or not args.max_minutes > 0:
        parser.error("--seeds must be 0 or more; --eval-freq, --episodes and --max-minutes must be positive")
    if args.budget_s is not None and not 0 < args.budget_s < 3600:
        parser.error(f"--budget-s must be between 0 and 3600 seconds, got {args.budget_s:g}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for recipe in args.recipes.split(","):
            for seed in seeds:
                run = Path(tmp) / f"{Path(recipe).stem}_{seed}"
                if args.budget_s is not None:
                    row = within_budget(recipe, args.env, seed, args.budget_s, args.episodes, run)
                else:
                    row = time_to_target(recipe, args.env, seed, args.eval_freq, args.episodes, args.max_minutes, run)
                rows.append(row)
                if not args.json:
                    print((budget_line if args.budget_s is not None else line)(args.env, row), flush=True)
    if args.json:
        print(json.dumps({"env": args.env, "cores": os.cpu_count(), "episodes": args.episodes,
                          "eval_freq": None if args.budget_s is not None else args.eval_freq,
                          "budget_s": args.budget_s, "runs": rows}))


if __name__ == "__main__":
    main()
