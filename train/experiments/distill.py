"""Distil the LQR → PID into a network: can a plain 64-64 MLP hold the ball as the classical controllers do?

Behaviour cloning, then DAgger: ``--bc-episodes`` randomised balance episodes driven by the teacher
(``--policy lqr-pid`` behind the Kalman observer), each observation labelled with the teacher's action; then one
round per ``--dagger`` value β, ``--dagger-episodes`` episodes where each step is the teacher's with probability β
and the student's otherwise, every observation again labelled by the teacher (which keeps its own state, the
hand-over and the integrals, along the student's path), the data pooled and the network refitted (mean squared
error, Adam). The student sees the env's observation with the error integral (``integral=True``: what the PID's
integral term sees) and has no other memory; it acts deterministically, with no classical controller at run
time. Training seeds start at 1000; the evaluation, with :func:`stewart_gym.evaluation.evaluate` (the same code
as every controller on the Control page), uses seeds 0…``--episodes``−1. Prints one JSON line (also written to
``--out``). The docs' Control page quotes its results.

Run: ``.venv/bin/python -m train.experiments.distill [--bc-episodes 100] [--dagger 0.5,0.2,0,0] [--episodes 100]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from train.experiments.common import check_paths, report

ENV_ID = "StewartBallBalance-v0"


def run(argv: list[str] | None = None) -> None:
    """Run the experiment with the options of its command line (``argv``; default ``sys.argv[1:]``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bc-episodes", type=int, default=100, help="teacher-driven episodes (10 s each)")
    ap.add_argument("--dagger", default="0.5,0.2,0,0", help="β of each DAgger round, comma-separated ('' for none)")
    ap.add_argument("--dagger-episodes", type=int, default=40, help="episodes per DAgger round")
    ap.add_argument("--epochs", type=int, default=30, help="epochs of the first fit (half as many after each round)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--episodes", type=int, default=100, help="evaluation seeds 0…N−1")
    ap.add_argument("--out", type=Path, help="also write the JSON line here")
    args = ap.parse_args(argv)
    parts = [b.strip() for b in args.dagger.split(",") if b.strip()]
    betas = [float(b) for b in parts if b.replace(".", "", 1).isdigit()]
    if len(betas) != len(parts) or not all(b <= 1.0 for b in betas):
        print(f"error: --dagger must be comma-separated numbers in [0, 1], got {args.dagger!r}", file=sys.stderr)
        sys.exit(2)
    for name in ("bc_episodes", "dagger_episodes", "epochs", "episodes"):
        if getattr(args, name) < 1:
            print(f"error: --{name.replace('_', '-')} must be at least 1", file=sys.stderr)
            sys.exit(2)
    check_paths(ap, args.out)

    import gymnasium as gym
    import torch

    import stewart_gym  # noqa: F401  (registers the envs)
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    torch.set_num_threads(2)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    _, teacher, env_kwargs = load_for_evaluation("lqr-pid", ENV_ID, None, None)
    env_kwargs = {**env_kwargs, "integral": True}
    env = gym.make(ENV_ID, randomize=True, **env_kwargs)
    n_obs = int(env.observation_space.shape[0])
    n_teacher = n_obs - 2  # the integral is the observation's last group; the teacher reads the rest
    net = torch.nn.Sequential(torch.nn.Linear(n_obs, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64), torch.nn.Tanh(),
                              torch.nn.Linear(64, 2))  # fmt: skip

    def student(obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return np.clip(net(torch.as_tensor(obs, dtype=torch.float32)).numpy(), -1.0, 1.0)

    def rollout(episodes: int, first_seed: int, beta: float) -> tuple[np.ndarray, np.ndarray]:
        xs, ys = [], []
        for k in range(episodes):
            obs, _ = env.reset(seed=first_seed + k)
            teacher.reset()
            done = False
            while not done:
                label = np.asarray(teacher(obs[None, :n_teacher]))[0]
                xs.append(obs.copy())
                ys.append(label)
                action = label if rng.random() < beta else student(obs)
                obs, _, terminated, truncated, _ = env.step(np.asarray(action, dtype=np.float32))
                done = terminated or truncated
        return np.asarray(xs, dtype=np.float32), np.asarray(ys, dtype=np.float32)

    def fit(x: np.ndarray, y: np.ndarray, epochs: int) -> float:
        opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        xt, yt = torch.as_tensor(x), torch.as_tensor(y)
        loss = torch.zeros(())
        for _ in range(epochs):
            order = torch.randperm(len(xt))
            for i in range(0, len(xt), 256):
                batch = order[i:i + 256]
                loss = ((net(xt[batch]) - yt[batch]) ** 2).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
        return float(loss.detach())

    started = time.time()
    first_seed = 1000
    x, y = rollout(args.bc_episodes, first_seed, 1.0)
    losses = [fit(x, y, args.epochs)]
    for beta in betas:
        first_seed += 1000
        more_x, more_y = rollout(args.dagger_episodes, first_seed, beta)
        x, y = np.concatenate([x, more_x]), np.concatenate([y, more_y])
        losses.append(fit(x, y, max(args.epochs // 2, 1)))
    train_s = time.time() - started

    class Student:
        """The network as an evaluation policy."""

        obs_size, action_size = n_obs, 2

        def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                    deterministic: bool = True) -> tuple[np.ndarray, None]:  # fmt: skip
            return student(np.asarray(obs, dtype=np.float32)), None

    metrics = evaluate(ENV_ID, Student(), episodes=args.episodes, seed=0, env_kwargs=env_kwargs)
    row: dict[str, Any] = {"bc_episodes": args.bc_episodes, "dagger": betas, "samples": int(len(x)),
                           "train_s": round(train_s, 1), "final_loss": round(losses[-1], 6),
                           "episodes": args.episodes}  # fmt: skip
    report(row, metrics, args.out, digits=3)


if __name__ == "__main__":
    run()
