"""What the experiment scripts of ``train/`` share: the `make train` recipe as PPO keywords, a quiet training run,
and the Control page's metrics reported as one JSON line.

They run as modules from the repository's root (``python -m train.experiments.<name>``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]

#: The Control page's metrics of one evaluation (``stewart_gym.evaluation.evaluate``), as every script reports them.
METRICS = ("success_rate", "rms_error_mm", "final_error_mm", "settling_time_s", "settled_pulse_rate_us_per_s",
           "settled_pulse_p2p_us")  # fmt: skip


def check_paths(ap: argparse.ArgumentParser, out: str | Path | None, run_dir: str | Path | None = None) -> None:
    """Before any training: ``out``'s folder must exist, and ``run_dir`` (made here) must be a folder that can be
    made; else one ``error:`` line (``ap.error``, exit 2) instead of a traceback after the run."""
    if out and not Path(out).resolve().parent.is_dir():
        ap.error(f"--out {out}: no folder {Path(out).resolve().parent}")
    if run_dir:
        try:
            Path(run_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            ap.error(f"--run-dir {run_dir}: cannot make it ({exc.strerror or exc})")


def report(row: dict[str, Any], metrics: dict[str, Any], out: str | Path | None, digits: int | None = None) -> str:
    """``row`` (what was run) with the evaluation's :data:`METRICS` (rounded to ``digits`` if given), printed as
    one JSON line and also written to ``out`` if given; returns the line."""
    def value(v: Any) -> Any:
        return v if v is None or digits is None else round(float(v), digits)

    line = json.dumps({**row, **{k: value(metrics[k]) for k in METRICS}})
    print(line)
    if out:
        Path(out).write_text(line + "\n")
    return line


def balance_recipe() -> tuple[dict[str, Any], dict[str, Any]]:
    """The balance section of ``stewart_gym/hyperparams/ppo.yml`` (what `make train` trains) and, of it, the PPO
    keywords the scripts pass on (rollout and update sizes, discount, learning rate, entropy, clipping)."""
    from stewart_gym.training import load_hyperparams

    hp = load_hyperparams("ppo", "StewartBallBalance-v0")
    keys = ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "learning_rate", "ent_coef", "clip_range")
    return hp, {k: hp[k] for k in keys}


def learn(model: Any, steps: int) -> float:
    """Train ``model`` (an SB3 algorithm) for ``steps`` env steps without logging; the wall time in s."""
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(folder=None, output_formats=[]))  # else SB3 leaves an empty tempdir/SB3-<time> folder
    started = time.time()
    model.learn(steps)
    return time.time() - started
