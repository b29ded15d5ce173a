"""Training wall time: where a run's env copies step (``train --vec-env``), and runs side by side.

Run: ``.venv/bin/python bench/bench_train.py [--hyperparams ppo] [--timesteps 30000] [--json]``.

Each setting runs ``python -m stewart_gym train`` as a user types it, in a subprocess (the balance env, the
recipe's ``n_envs``, no evaluation, no TensorBoard), and reports its wall time and env steps per second:

- ``--vec-env subproc``: a worker process per env copy;
- ``--vec-env dummy`` (the default): the copies one after another in the training process;
- two ``dummy`` runs side by side (seeds 0 and 1), as ``make train-residual`` runs them (``TRAIN_JOBS=2``):
  the steps of both over the wall time of both.

It also checks that ``subproc`` and ``dummy`` train the same network (the SHA-256 of the policy's weights in
``model.zip``), and that a run side by side trains the same network as alone. A recipe on the batched backend
(``--hyperparams ppo_batched``) runs ``dummy`` alone: its copies step together in the training process.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path


def train_command(hyperparams: str, timesteps: int, vec_env: str, seed: int, run_dir: Path) -> list[str]:
    return [sys.executable, "-m", "stewart_gym", "train", "--hyperparams", hyperparams, "--timesteps", str(timesteps),
            "--vec-env", vec_env, "--seed", str(seed), "--run-dir", str(run_dir), "--eval-freq", str(10 * timesteps),
            "--no-progress", "--no-tensorboard", "--overwrite"]  # fmt: skip


def run_together(commands: list[list[str]]) -> float:
    """Wall seconds until every command has finished (all started at once)."""
    start = time.perf_counter()
    procs = [subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for cmd in commands]
    for cmd, proc in zip(commands, procs):
        _, err = proc.communicate()
        if proc.returncode != 0:
            sys.exit(f"error: {' '.join(cmd[1:])} failed: {(err.strip().splitlines() or ['no message'])[-1]}")
    return time.perf_counter() - start


def weights(run_dir: Path) -> str:
    """SHA-256 of the policy's weights in the run's model.zip."""
    with zipfile.ZipFile(run_dir / "model.zip") as z:
        return hashlib.sha256(z.read("policy.pth")).hexdigest()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--hyperparams", default="ppo", help="a shipped recipe's name or a YAML file")
    parser.add_argument("--timesteps", type=int, default=30_000)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.timesteps < 1000:
        sys.exit("error: --timesteps must be 1000 or more")
    from stewart_gym.training import load_hyperparams

    recipe = load_hyperparams("ppo", "StewartBallBalance-v0", args.hyperparams)
    batched = (recipe.get("env_kwargs") or {}).get("backend") == "batched"  # its copies step together: no subproc
    reference = "dummy" if batched else "subproc"
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for vec_env in ("dummy",) if batched else ("subproc", "dummy"):
            run = root / vec_env
            wall = run_together([train_command(args.hyperparams, args.timesteps, vec_env, 0, run)])
            rows[vec_env] = {"runs": 1, "wall_s": round(wall, 1), "steps_per_s": round(args.timesteps / wall),
                             "weights": weights(run)}  # fmt: skip
        pair = [root / f"pair_{seed}" for seed in (0, 1)]
        wall = run_together([train_command(args.hyperparams, args.timesteps, "dummy", seed, run)
                             for seed, run in enumerate(pair)])  # fmt: skip
        rows["dummy, 2 side by side"] = {"runs": 2, "wall_s": round(wall, 1),
                                         "steps_per_s": round(2 * args.timesteps / wall), "weights": weights(pair[0])}
    same = {name: row["weights"] == rows[reference]["weights"] for name, row in rows.items()}
    if args.json:
        print(json.dumps({"hyperparams": args.hyperparams, "timesteps": args.timesteps, "cores": os.cpu_count(),
                          "runs": {name: {k: v for k, v in row.items() if k != "weights"} | {"same_network": same[name]}
                                   for name, row in rows.items()}}))  # fmt: skip
        return
    print(f"train --hyperparams {args.hyperparams}: {args.timesteps} steps per run (balance) on {os.cpu_count()} cores"
          + (" (the batched backend: its copies step together in one process, no subproc)" if batched else ""))
    print(f"{'vec_env':<24} {'runs':>4} {'wall s':>7} {'steps/s':>8}  network (seed 0)")
    for name, row in rows.items():
        print(f"{name:<24} {row['runs']:>4} {row['wall_s']:>7.1f} {row['steps_per_s']:>8}  "
              f"{'the same as ' + reference if same[name] else 'DIFFERENT'}")  # fmt: skip


if __name__ == "__main__":
    main()
