"""Gymnasium environments of the servo hexapod; registered on ``import stewart_gym``."""

from __future__ import annotations

import gymnasium

__all__ = ["ENV_IDS", "register_envs"]

#: id → (entry point, max_episode_steps)
ENV_IDS: dict[str, tuple[str, int]] = {
    "StewartBallBalance-v0": ("stewart_gym.envs.ball_env:StewartBallBalanceEnv", 500),
    "StewartBallTrack-v0": ("stewart_gym.envs.ball_env:StewartBallTrackEnv", 1000),
}


def register_envs() -> None:
    """Register every environment id with Gymnasium (idempotent)."""
    for env_id, (entry_point, steps) in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, max_episode_steps=steps)
