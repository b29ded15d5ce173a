"""Wall time of a short training run of StewartBallBalance-v0 under each other RL library (docs: Other RL
libraries): RL Zoo with ``stewart_gym/hyperparams/ppo.yml``, ``examples/torchrl_ppo.py`` and
``examples/rllib_ppo.py``, each in its own process, start-up included, one after another.

Run: ``.venv/bin/python bench/bench_libraries.py [--steps 4096]``. Needs the ``libraries`` extra (the dev
install has it). Prints one line per library: steps, wall seconds, steps per second.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from stewart_gym.cli.common import int_at_least

ROOT = Path(__file__).resolve().parents[1]


def commands(steps: int, folder: str) -> dict[str, list[str]]:
    py = sys.executable
    return {
        "RL Zoo (ppo.yml)": [py, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "StewartBallBalance-v0",
                             "--gym-packages", "stewart_gym", "-conf", str(ROOT / "stewart_gym/hyperparams/ppo.yml"),
                             "-n", str(steps), "--eval-freq", str(steps), "--eval-episodes", "2", "-f", folder,
                             "--seed", "0", "--device", "cpu"],
        "TorchRL (examples/torchrl_ppo.py)": [py, str(ROOT / "examples/torchrl_ppo.py"), "--frames", str(steps),
                                              "--batch", "2048", "--episodes", "2"],
        "RLlib (examples/rllib_ppo.py)": [py, str(ROOT / "examples/rllib_ppo.py"), "--iterations",
                                          str(max(steps // 2048, 1)), "--batch", "2048", "--episodes", "2"],
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int_at_least(1), default=4096,
                        help="env steps per library (whole batches of 2,048)")
    args = parser.parse_args()
    steps = max(args.steps // 2048, 1) * 2048
    with tempfile.TemporaryDirectory() as folder:
        for name, command in commands(steps, folder).items():
            start = time.perf_counter()
            # (SB3's logger folder and Ray's session folder in the temporary folder too, not left in the system's)
            proc = subprocess.run(command, capture_output=True, text=True, cwd=folder,
                                  env={**os.environ, "SB3_LOGDIR": folder, "RAY_TMPDIR": folder})  # fmt: skip
            wall = time.perf_counter() - start
            if proc.returncode != 0:
                sys.exit(f"error: {name} failed (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
            print(f"{name:36s} {steps:6d} steps  {wall:6.1f} s  {steps / wall:6.0f} steps/s")


if __name__ == "__main__":
    main()
