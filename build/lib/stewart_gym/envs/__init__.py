"""Gymnasium environments of the servo hexapod; registered on ``import stewart_gym`` (when gymnasium is there).

Every id is :class:`~stewart_gym.envs.ball_env.StewartBallEnv` with a task; adding
a task is a task file (see :mod:`stewart_gym.envs.task`) and one line in
:data:`ENV_IDS`.
"""

from __future__ import annotations

__all__ = ["ENV_ENTRY_POINT", "ENV_IDS", "register_envs"]

ENV_ENTRY_POINT = "stewart_gym.envs.ball_env:StewartBallEnv"

#: id → (task, max_episode_steps): the task is a "module:Class" path (see stewart_gym.envs.task).
ENV_IDS: dict[str, tuple[str, int]] = {
    "StewartBallBalance-v0": ("stewart_gym.envs.tasks.balance:BalanceTask", 500),
    "StewartBallTrack-v0": ("stewart_gym.envs.tasks.track:TrackTask", 1000),
    "StewartBallDisturbance-v0": ("stewart_gym.envs.tasks.disturbance:DisturbanceTask", 500),
}


def register_envs() -> None:
    """Register every environment id with Gymnasium (idempotent)."""
    import gymnasium

    for env_id, (task, steps) in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=ENV_ENTRY_POINT, max_episode_steps=steps, kwargs={"task": task})
