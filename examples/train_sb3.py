"""Train PPO on StewartBallBalance-v0 with Stable-Baselines3 in plain Python, then evaluate it: the settings of
``stewart_gym/hyperparams/ppo.yml`` (behind the Kalman observer, with domain randomisation), about 150k steps
to a policy that holds the ball on every episode (2 to 3 minutes on 2 cores).

    python examples/train_sb3.py --timesteps 150000

``stewart-gym train`` does the same with checkpoints, evaluations and a run folder that ``evaluate``,
``export`` and ``deploy`` take; this is the bare loop.
"""

from __future__ import annotations

import gymnasium as gym
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import stewart_gym  # noqa: F401  (registers the env ids)
from stewart_gym.cli.common import Parser, int_at_least

ENV_ID = "StewartBallBalance-v0"
ENV_KWARGS = {"randomize": True, "estimator": "kalman", "rate_penalty": 10.0}


def main(argv: list[str] | None = None) -> None:
    parser = Parser.for_script(__doc__)
    parser.add_argument("--timesteps", type=int_at_least(1), default=150_000, help="env steps to train for")
    parser.add_argument("--episodes", type=int_at_least(1), default=10, help="evaluation episodes")
    parser.add_argument("--seed", type=int_at_least(0), default=0, help="random seed")
    args = parser.parse_args(argv)

    env = VecNormalize(make_vec_env(ENV_ID, n_envs=2, seed=args.seed, env_kwargs=ENV_KWARGS), gamma=0.98)
    model = PPO("MlpPolicy", env, n_steps=1024, batch_size=256, n_epochs=10, gamma=0.98, gae_lambda=0.95,
                learning_rate=1e-3, clip_range=0.2, policy_kwargs={"net_arch": [64, 64], "log_std_init": -1.0},
                seed=args.seed, device="cpu")  # fmt: skip
    model.learn(total_timesteps=args.timesteps)

    env.training = False  # evaluate with the statistics as learned
    test_env = gym.make(ENV_ID, **ENV_KWARGS)
    successes = 0
    for episode in range(args.episodes):
        obs, info = test_env.reset(seed=1000 + episode)
        done = False
        while not done:
            action, _ = model.predict(env.normalize_obs(obs), deterministic=True)
            obs, reward, terminated, truncated, info = test_env.step(action)
            done = terminated or truncated
        successes += bool(info["is_success"])
        print(f"episode {episode}: {'held' if info['is_success'] else 'lost'}, {info['distance_mm']:.1f} mm from "
              "the centre at the end")  # fmt: skip
    print(f"success {successes}/{args.episodes}")
    test_env.close()


if __name__ == "__main__":
    main()
