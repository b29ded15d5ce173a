"""Does a low-pass filter on the action help the `make train` recipe? Trained with the filter in the loop, and
evaluated as every controller.

Trains PPO with the balance section of ``stewart_gym/hyperparams/ppo.yml`` (behind the Kalman observer,
action-rate penalty 10, 2 envs in this process, VecNormalize) for ``--steps`` env steps, with a first-order
low-pass filter between the policy and the env: the env is sent y ← y + ``alpha`` · (a − y) each control step
(y starts at 0 each episode, as the env's previous action does; ``--alpha 1`` is the recipe as it is). The
observation's "previous action" is then the filtered action, the filter's state, so the policy sees it. The
action-rate penalty is charged on the filtered action, what reaches the servos. Then evaluates the final model,
filter included, on ``--episodes`` randomised seeds with :func:`stewart_gym.evaluation.evaluate` (the same code
as every controller on the Control page) and prints one JSON line (also written to ``--out``). The docs'
Control page quotes its results.

Run: ``.venv/bin/python -m train.experiments.action_filter --alpha 0.5 [--seed 0] [--steps 150000] [--episodes 100]``
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import gymnasium as gym
import numpy as np

from train.experiments.common import balance_recipe, check_paths, learn, report


class ActionLowPass(gym.ActionWrapper):
    """The env's action, low-pass filtered: y ← y + alpha · (a − y), y = 0 at each reset."""

    def __init__(self, env: gym.Env, alpha: float) -> None:
        super().__init__(env)
        self.alpha = alpha
        self.y = np.zeros(env.action_space.shape, dtype=np.float32)

    def reset(self, **kwargs: Any) -> Any:
        self.y[:] = 0.0
        return self.env.reset(**kwargs)

    def action(self, action: np.ndarray) -> np.ndarray:
        a = np.clip(np.asarray(action, dtype=np.float32), self.action_space.low, self.action_space.high)
        self.y = (self.y + self.alpha * (a - self.y)).astype(np.float32)
        return self.y.copy()


class FilteredPolicy:
    """The trained model as an evaluation policy: normalises as in training (``normalizer``: the run's
    VecNormalize), then filters as the wrapper did."""

    def __init__(self, model: Any, normalizer: Any, alpha: float) -> None:
        self.model, self.normalizer, self.alpha = model, normalizer, alpha
        self.y: np.ndarray | None = None

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        o = np.asarray(obs, dtype=np.float32).reshape(1, -1)
        x = np.asarray(self.normalizer.normalize_obs(o), dtype=np.float32)  # VecNormalize's, as in training
        action, _ = self.model.predict(x, deterministic=True)
        a = np.clip(np.asarray(action, dtype=np.float32).reshape(1, -1), -1.0, 1.0)
        if self.y is None or (episode_start is not None and bool(np.any(episode_start))):
            self.y = np.zeros_like(a)
        self.y = (self.y + self.alpha * (a - self.y)).astype(np.float32)
        return self.y.copy(), None


def run(argv: list[str] | None = None) -> None:
    """Run the experiment with the options of its command line (``argv``; default ``sys.argv[1:]``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--alpha", type=float, default=1.0, help="the filter's step, in (0, 1] (1: no filter)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=150_000)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--out", help="also write the JSON line here")
    args = ap.parse_args(argv)
    if not (math.isfinite(args.alpha) and 0 < args.alpha <= 1):
        ap.error(f"--alpha must be in (0, 1], got {args.alpha}")
    if args.steps < 1 or args.episodes < 1 or args.seed < 0:
        ap.error("--steps and --episodes must be at least 1, --seed at least 0")
    check_paths(ap, args.out)
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from stewart_gym.evaluation import evaluate
    from stewart_gym.training import InProcessVecEnv

    torch.set_num_threads(1)  # as `train` does: small MLPs
    hp, kwargs = balance_recipe()
    env = make_vec_env("StewartBallBalance-v0", n_envs=hp["n_envs"], seed=args.seed, env_kwargs=hp["env_kwargs"],
                       vec_env_cls=InProcessVecEnv, wrapper_class=ActionLowPass,
                       wrapper_kwargs={"alpha": args.alpha})  # fmt: skip
    env = VecNormalize(env, norm_obs=True, norm_reward=True)
    model = PPO("MlpPolicy", env, seed=args.seed, device="cpu", policy_kwargs=hp["policy_kwargs"], **kwargs)
    wall = learn(model, args.steps)
    env.close()
    metrics = evaluate("StewartBallBalance-v0", FilteredPolicy(model, env, args.alpha), episodes=args.episodes,
                       env_kwargs={"estimator": hp["env_kwargs"]["estimator"]})  # fmt: skip
    report({"alpha": args.alpha, "seed": args.seed, "steps": args.steps, "train_wall_s": round(wall, 1)}, metrics,
           args.out)  # fmt: skip


if __name__ == "__main__":
    run()
