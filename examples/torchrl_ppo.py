"""PPO on StewartBallBalance-v0 with TorchRL: the env through ``GymEnv``, a tanh-Gaussian actor and a critic of
two 64-unit layers, GAE and the clipped PPO loss; it prints the mean reward of each batch and, at the end, the
success rate of the deterministic policy.

    python examples/torchrl_ppo.py --frames 200000

Needs ``pip install torchrl`` beside ``stewart_gym[train]``.
"""

from __future__ import annotations

import logging

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
from torchrl.envs import GymEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

import stewart_gym  # noqa: F401  (registers the env ids)
from stewart_gym.cli.common import Parser, int_at_least


def mlp(n_in: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, n_out))


def main(argv: list[str] | None = None) -> None:
    parser = Parser.for_script(__doc__)
    parser.add_argument("--frames", type=int_at_least(1), default=200_000, help="env steps in all")
    parser.add_argument("--batch", type=int_at_least(1), default=2048, help="env steps per update")
    parser.add_argument("--episodes", type=int_at_least(1), default=10, help="evaluation episodes at the end")
    parser.add_argument("--seed", type=int_at_least(0), default=0, help="random seed")
    args = parser.parse_args(argv)
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # its set-up notes; this script prints its own lines
    torch.manual_seed(args.seed)
    # docs: setup start (docs/src/libraries.md shows the lines to the end mark; a test keeps them equal)
    env = GymEnv("StewartBallBalance-v0", estimator="kalman")  # any env keyword, as gym.make takes it
    env.auto_register_info_dict()  # each info entry as a key of the step (is_success among them)
    env.set_seed(args.seed)
    n_obs, n_act = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]

    actor = ProbabilisticActor(
        TensorDictModule(nn.Sequential(mlp(n_obs, 2 * n_act), NormalParamExtractor()), in_keys=["observation"],
                         out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], spec=env.action_spec, distribution_class=TanhNormal,
        distribution_kwargs={"low": env.action_spec.space.low, "high": env.action_spec.space.high},
        return_log_prob=True)  # fmt: skip
    critic = ValueOperator(mlp(n_obs, 1), in_keys=["observation"])
    advantage = GAE(gamma=0.98, lmbda=0.95, value_network=critic, average_gae=True)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=0.0)
    optimiser = torch.optim.Adam(loss.parameters(), lr=1e-3)
    buffer = ReplayBuffer(storage=LazyTensorStorage(args.batch), sampler=SamplerWithoutReplacement())
    collector = Collector(env, actor, frames_per_batch=args.batch, total_frames=args.frames,
                          auto_register_policy_transforms=True)
    # docs: setup end

    frames = 0
    for data in collector:
        frames += data.numel()
        for _ in range(10):  # epochs
            with torch.no_grad():
                advantage(data)
            buffer.extend(data.reshape(-1))
            for _ in range(max(args.batch // 256, 1)):
                out = loss(buffer.sample(min(256, args.batch)))
                (out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]).backward()
                optimiser.step()
                optimiser.zero_grad()
        print(f"frames {frames}: mean reward {data['next', 'reward'].mean().item():.3f}")
    collector.shutdown()

    successes = 0
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for _ in range(args.episodes):
            episode = env.rollout(10_000, actor)
            successes += bool(episode["next", "is_success"][-1])
    print(f"success {successes}/{args.episodes}")
    env.close()


if __name__ == "__main__":
    main()
