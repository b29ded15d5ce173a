"""Does memory help the `make train` recipe? Frame stacking or an LSTM policy, trained and evaluated alike.

Trains PPO with the balance settings of ``stewart_gym/hyperparams/ppo.yml`` (2 envs in worker processes,
VecNormalize, behind the Kalman observer, action-rate penalty 10) for ``--steps`` env steps, with the last
``--stack`` observations as the input (SB3's ``VecFrameStack``; 1 is the recipe as it is), or with an LSTM
policy (``--lstm``: sb3-contrib's RecurrentPPO, 64 units after the 64-64 layers; sb3-contrib comes with
the ``train`` extra). Then evaluates the final model on ``--episodes``
randomised seeds with :func:`stewart_gym.evaluation.evaluate` (the same code as every controller on the
Control page), keeping the stack or the LSTM state through each episode, and prints one JSON line (also
written to ``--out``). The docs' Control page quotes its results.

Run: ``.venv/bin/python -m train.experiments.memory --stack 4 [--seed 0] [--steps 150000] [--episodes 100]``
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from train.experiments.common import balance_recipe, check_paths, learn, report


class MemoryPolicy:
    """The trained model as an evaluation policy: normalises like training, stacks or carries the LSTM state."""

    def __init__(self, model: Any, obs_rms: Any, stack: int, recurrent: bool) -> None:
        self.model, self.obs_rms, self.stack, self.recurrent = model, obs_rms, stack, recurrent
        self.frames: np.ndarray | None = None
        self.state: Any = None

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
        o = np.asarray(obs, dtype=np.float32).reshape(1, -1)
        start = episode_start is not None and bool(np.any(episode_start))
        if start or self.frames is None:  # VecFrameStack starts an episode with zeros before the first frame
            self.frames, self.state = np.zeros((1, o.shape[1] * self.stack), np.float32), None
        self.frames = np.concatenate([self.frames[:, o.shape[1]:], o], axis=1)
        x = np.clip((self.frames - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + 1e-8), -10, 10).astype(np.float32)
        if self.recurrent:
            action, self.state = self.model.predict(x, state=self.state, episode_start=np.array([start]),
                                                    deterministic=True)  # fmt: skip
        else:
            action, _ = self.model.predict(x, deterministic=True)
        return action, None


def run(argv: list[str] | None = None) -> None:
    """Run the experiment with the options of its command line (``argv``; default ``sys.argv[1:]``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stack", type=int, default=1, help="observations stacked as the input (default 1: none)")
    ap.add_argument("--lstm", action="store_true", help="an LSTM policy (RecurrentPPO; needs sb3-contrib)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=150_000)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--out", help="also write the JSON line here")
    args = ap.parse_args(argv)
    if args.stack < 1 or args.steps < 1 or args.episodes < 1:
        ap.error("--stack, --steps and --episodes must be at least 1")
    if args.lstm and args.stack != 1:
        ap.error("--lstm carries its own memory: leave --stack at 1")
    check_paths(ap, args.out)
    if args.lstm:
        try:
            from sb3_contrib import RecurrentPPO
        except ImportError:
            print("error: --lstm needs sb3-contrib (the train extra): pip install -e '.[train]'", file=sys.stderr)
            sys.exit(2)
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    torch.set_num_threads(1)  # as `train` does: extra threads only fight the env workers for the cores

    from stewart_gym.evaluation import evaluate
    from stewart_gym.training import make_env

    hp, kwargs = balance_recipe()
    env = make_env("StewartBallBalance-v0", hp["n_envs"], args.seed, hp["env_kwargs"])
    if args.stack > 1:
        env = VecFrameStack(env, args.stack)
    env = VecNormalize(env, norm_obs=True, norm_reward=True)
    if args.lstm:
        model = RecurrentPPO("MlpLstmPolicy", env, seed=args.seed, device="cpu",
                             policy_kwargs={**hp["policy_kwargs"], "lstm_hidden_size": 64}, **kwargs)  # fmt: skip
    else:
        model = PPO("MlpPolicy", env, seed=args.seed, device="cpu", policy_kwargs=hp["policy_kwargs"], **kwargs)
    wall = learn(model, args.steps)
    env.close()
    policy = MemoryPolicy(model, env.obs_rms, args.stack, args.lstm)
    metrics = evaluate("StewartBallBalance-v0", policy, episodes=args.episodes,
                       env_kwargs={"estimator": hp["env_kwargs"]["estimator"]})  # fmt: skip
    report({"stack": args.stack, "lstm": args.lstm, "seed": args.seed, "steps": args.steps,
            "train_wall_s": round(wall, 1)}, metrics, args.out)  # fmt: skip


if __name__ == "__main__":
    run()
