"""PPO on StewartBallBalance-v0 with RLlib: the env by its Gymnasium id (``stewart_gym:`` makes each worker
import the package that registers it), env runners in this process, and RLlib's default model; it prints the mean
episode return of each iteration and, at the end, the success rate of the greedy policy.

    python examples/rllib_ppo.py --iterations 50

Needs ``pip install "ray[rllib]"`` beside ``stewart_gym[train]``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import ray
import torch
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.core.columns import Columns

from stewart_gym.cli.common import Parser, int_at_least

ENV_ID = "stewart_gym:StewartBallBalance-v0"


def main(argv: list[str] | None = None) -> None:
    parser = Parser.for_script(__doc__)
    parser.add_argument("--iterations", type=int_at_least(1), default=50, help="training iterations")
    parser.add_argument("--batch", type=int_at_least(1), default=4000, help="env steps per iteration")
    parser.add_argument("--episodes", type=int_at_least(1), default=10, help="evaluation episodes at the end")
    parser.add_argument("--seed", type=int_at_least(0), default=0, help="random seed")
    args = parser.parse_args(argv)
    # docs: config start (docs/src/libraries.md shows the lines to the end mark; a test keeps them equal)
    config = (
        PPOConfig()
        .environment(ENV_ID)
        .env_runners(num_env_runners=0)  # sample in this process: a laptop's cores go to the physics
        .training(train_batch_size_per_learner=args.batch, minibatch_size=min(256, args.batch), num_epochs=10,
                  gamma=0.98, lr=3e-4)
        .debugging(seed=args.seed, log_level="ERROR")
    )  # fmt: skip
    algo = config.build_algo()
    # docs: config end
    for i in range(args.iterations):
        result = algo.train()
        mean_return = result["env_runners"].get("episode_return_mean", float("nan"))
        print(f"iteration {i + 1}: mean episode return {mean_return:.1f}")

    module = algo.get_module()
    env = gym.make(ENV_ID)
    successes = 0
    for episode in range(args.episodes):
        obs, info = env.reset(seed=args.seed + episode)
        done = False
        while not done:
            with torch.no_grad():
                out = module.forward_inference({Columns.OBS: torch.as_tensor(obs[None], dtype=torch.float32)})
            mean = out[Columns.ACTION_DIST_INPUTS][0, : env.action_space.shape[0]].numpy()  # the Gaussian's mean
            obs, _, terminated, truncated, info = env.step(np.clip(mean, env.action_space.low, env.action_space.high))
            done = terminated or truncated
        successes += bool(info["is_success"])
    print(f"success {successes}/{args.episodes}")
    env.close()
    algo.stop()
    ray.shutdown()


if __name__ == "__main__":
    main()
