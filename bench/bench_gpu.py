"""PPO on the CPU against CUDA: where a training run's time goes, env rollout or network update.

Run: ``.venv/bin/python bench/bench_gpu.py [--timesteps 16384] [--json]``.

``stewart-gym train`` keeps the networks on the CPU. This bench shows why, on a machine that has a CUDA GPU
(without one it measures the CPU rows alone). For each setting, PPO learns ``--timesteps`` steps of the
randomised balance env behind the Kalman observer (VecNormalize, env copies in process), once with the
network on the CPU and once on CUDA, and reports the wall time split into the rollout (env steps, each with a
forward pass of the policy) and the update (the PPO epochs over the rollout):

- the shipped recipe's network: 64-64, minibatches of 256, 2 env copies (``ppo.yml``);
- a larger one, where a GPU could pay: 256-256, minibatches of 2,048, 8 env copies.

Torch uses one thread, as ``train`` does.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.vec_env import VecNormalize  # noqa: E402

from stewart_gym.training import make_env  # noqa: E402

ENV_KWARGS = {"randomize": True, "estimator": "kalman", "rate_penalty": 10.0}
SETTINGS = (  # (network, minibatch, env copies)
    ((64, 64), 256, 2),
    ((256, 256), 2048, 8),
)


class TimedPPO(PPO):
    """PPO that adds up the seconds of its updates (the rest of ``learn`` is the rollout)."""

    update_s = 0.0

    def train(self) -> None:
        start = time.perf_counter()
        super().train()
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        self.update_s += time.perf_counter() - start


def run(net: tuple[int, int], batch: int, n_envs: int, device: str, timesteps: int) -> dict:
    env = VecNormalize(make_env("StewartBallBalance-v0", n_envs, 0, ENV_KWARGS, None, "dummy"))
    model = TimedPPO("MlpPolicy", env, seed=0, device=device, n_steps=1024, batch_size=batch, n_epochs=10,
                     gamma=0.98, gae_lambda=0.95, learning_rate=1e-3,
                     policy_kwargs={"net_arch": list(net), "log_std_init": -1.0})  # fmt: skip
    start = time.perf_counter()
    model.learn(timesteps)
    wall = time.perf_counter() - start
    env.close()
    return {"net": "-".join(map(str, net)), "minibatch": batch, "n_envs": n_envs, "device": device,
            "steps": int(model.num_timesteps), "wall_s": round(wall, 2), "update_s": round(model.update_s, 2),
            "rollout_s": round(wall - model.update_s, 2)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=16_384)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.timesteps < 8192:
        sys.exit("error: --timesteps must be 8192 or more (one rollout of the larger setting)")
    torch.set_num_threads(1)
    devices = ("cpu", "cuda") if torch.cuda.is_available() else ("cpu",)
    rows = [run(net, batch, n_envs, device, args.timesteps) for net, batch, n_envs in SETTINGS for device in devices]
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    if args.json:
        print(json.dumps({"gpu": gpu, "cores": os.cpu_count(), "torch": torch.__version__, "runs": rows}))
        return
    print(f"PPO, balance env, {args.timesteps} steps per row; torch {torch.__version__}; "
          f"GPU: {gpu or 'none (CPU rows only)'}")  # fmt: skip
    print(f"{'network':<8} {'minibatch':>9} {'envs':>4} {'device':>6} {'wall s':>7} {'update s':>8} {'rollout s':>9}")
    for r in rows:
        print(f"{r['net']:<8} {r['minibatch']:>9} {r['n_envs']:>4} {r['device']:>6} {r['wall_s']:>7.2f} "
              f"{r['update_s']:>8.2f} {r['rollout_s']:>9.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
