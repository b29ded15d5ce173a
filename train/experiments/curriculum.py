"""Does a curriculum help the `make train` recipe? The recipe trained with one, and evaluated as every controller.

Trains PPO with the balance section of ``stewart_gym/hyperparams/ppo.yml`` (behind the Kalman observer,
action-rate penalty 10, 2 envs) for ``--steps`` env steps through :func:`stewart_gym.training.train`, with an
SB3 callback that sets each training env's difficulty before every rollout, from the fraction p of the steps
done:

- ``start``: the box the ball starts in (uniform, ±``START_FRACTION`` of the half plate; 100 mm on the
  reference plate) grows from 10 % of its size to all of it over the first 60 % of the steps;
- ``precision``: the reward's near-target scale (``near_scale``, 15 mm by default) shrinks to 5 mm over the
  steps: precision near the target pays more and more steeply;
- ``none``: the recipe as it is, for the paired comparison.

The evaluation env is the standard one throughout. Then evaluates the final model on ``--episodes`` randomised
seeds with ``stewart-gym evaluate``'s code (:func:`stewart_gym.evaluation.evaluate`, the same as every
controller on the Control page) and prints one JSON line (also written to ``--out``), with the difficulty at the
first and the last rollout. The docs' Control page quotes its results.

Run: ``.venv/bin/python -m train.experiments.curriculum --curriculum start [--seed 0] [--steps 150000]
[--episodes 100] [--run-dir runs/curriculum_start_s0]``
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

from train.experiments.common import check_paths, report

CURRICULA = ("none", "start", "precision")
START_FROM, START_OVER = 0.1, 0.6  # the start box: from 10 % of its size, all of it after 60 % of the steps
NEAR_TO = 0.005  # m, the reward's near-target scale at the end (from the task's own)


def curriculum_callback(kind: str, total_steps: int) -> Any:
    """An SB3 callback that sets the training envs' difficulty (``kind``, of :data:`CURRICULA`) before each
    rollout, and records it in ``.seen`` (the first and the last setting)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Curriculum(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.seen: list[float] = []
            self.start_fraction: float | None = None
            self.near_scale: float | None = None

        def _set(self) -> None:
            p = min(1.0, self.num_timesteps / total_steps)
            venv = self.training_env
            while hasattr(venv, "venv"):  # under VecNormalize
                venv = venv.venv
            for monitored in venv.envs:
                env = monitored.unwrapped
                if kind == "start":
                    if self.start_fraction is None:
                        self.start_fraction = type(env).START_FRACTION
                    env.START_FRACTION = self.start_fraction * (START_FROM + (1 - START_FROM) * min(1.0, p / START_OVER))
                    value = env.START_FRACTION
                elif kind == "precision":
                    if self.near_scale is None:
                        self.near_scale = env.task.near_scale
                    env.task.near_scale = self.near_scale + (NEAR_TO - self.near_scale) * p
                    value = env.task.near_scale
                else:
                    return
            self.seen = [self.seen[0] if self.seen else value, value]

        def _on_training_start(self) -> None:
            self._set()

        def _on_rollout_start(self) -> None:
            self._set()

        def _on_step(self) -> bool:
            return True

    return Curriculum()


def run(argv: list[str] | None = None) -> None:
    """Run the experiment with the options of its command line (``argv``; default ``sys.argv[1:]``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--curriculum", choices=CURRICULA, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=150_000)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--run-dir", help="keep the run here (default: a temporary folder, removed after)")
    ap.add_argument("--out", help="also write the JSON line here")
    args = ap.parse_args(argv)
    if args.steps < 1 or args.episodes < 1 or args.seed < 0:
        ap.error("--steps and --episodes must be at least 1, --seed at least 0")
    check_paths(ap, args.out, args.run_dir)

    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation
    from stewart_gym.training import TrainConfig, train

    with tempfile.TemporaryDirectory() as tmp:
        run = Path(args.run_dir or Path(tmp) / "run")
        callback = curriculum_callback(args.curriculum, args.steps)
        done = train(TrainConfig(env_id="StewartBallBalance-v0", algo="ppo", run_dir=str(run), seed=args.seed,
                                 n_timesteps=args.steps, progress_bar=False, tensorboard=False),
                     callbacks=[callback])  # fmt: skip
        _, policy, env_kwargs = load_for_evaluation(str(run), "StewartBallBalance-v0", None, None)
        metrics = evaluate("StewartBallBalance-v0", policy, episodes=args.episodes, env_kwargs=env_kwargs)
    report({"curriculum": args.curriculum, "seed": args.seed, "steps": done["timesteps"],
            "train_wall_s": done["wall_time_s"], "difficulty_first_last": [round(v, 4) for v in callback.seen]},
           metrics, args.out)  # fmt: skip


if __name__ == "__main__":
    run()
