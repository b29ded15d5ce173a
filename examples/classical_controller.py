"""A shipped classical controller (the LQR by default) balancing the ball in ``gym.make``'s env: the same
observation a learned policy gets, an SB3-style ``predict``, an episode loop.

    python examples/classical_controller.py --controller lqr-pid --episodes 5
"""

from __future__ import annotations

import gymnasium as gym

import stewart_gym  # noqa: F401  (registers the env ids)
from stewart_gym.cli.common import Parser, int_at_least
from stewart_gym.control import CLASSICAL, classical_controller, shipped_design


def main(argv: list[str] | None = None) -> None:
    parser = Parser.for_script(__doc__)
    parser.add_argument("--controller", choices=sorted(CLASSICAL), default="lqr", help="which controller")
    parser.add_argument("--episodes", type=int_at_least(1), default=5, help="seeded episodes")
    parser.add_argument("--seed", type=int_at_least(0), default=0, help="the first episode's seed")
    args = parser.parse_args(argv)

    kind, _, estimator = CLASSICAL[args.controller]  # the observer it was tuned behind: lowpass or kalman
    controller = classical_controller(kind, shipped_design(args.controller), geometry="servo-hexapod")
    env = gym.make("StewartBallBalance-v0", estimator=estimator, randomize=True)
    successes = 0
    for episode in range(args.episodes):
        obs, info = env.reset(seed=args.seed + episode)
        controller.reset()  # its filters and integrals start afresh with the episode
        done = False
        while not done:
            action, _ = controller.predict(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        successes += bool(info["is_success"])
        print(f"episode {episode}: {'held' if info['is_success'] else 'lost'}, {info['distance_mm']:.2f} mm from "
              "the centre at the end")  # fmt: skip
    print(f"success {successes}/{args.episodes}")
    env.close()


if __name__ == "__main__":
    main()
