"""Gymnasium environments of the servo hexapod; registered on ``import stewart_gym`` (when gymnasium is there).

Every id is :class:`~stewart_gym.envs.ball_env.StewartBallEnv` with a task; adding
a task is a task file (see :mod:`stewart_gym.envs.task`) and one line in
:data:`ENV_IDS`.
"""

from __future__ import annotations

__all__ = ["ENV_ENTRY_POINT", "ENV_IDS", "env_table", "register_envs", "trajectory_env_ids"]

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


def trajectory_env_ids() -> tuple[str, ...]:
    """The ids whose task follows a moving target: its constructor takes ``trajectory`` (one of
    :data:`~stewart_gym.envs.targets.TRACK_TRAJECTORIES`)."""
    import inspect

    from stewart_gym.envs.task import task_class

    return tuple(env_id for env_id, (path, _) in ENV_IDS.items()
                 if "trajectory" in inspect.signature(task_class(path)).parameters)  # fmt: skip


def env_table() -> str:
    """The registered ids as a Markdown table (the README's and the docs' env table are this text)."""
    from stewart_gym.envs.task import load_task

    rows = ["| id | the task | episode | success |", "|---|---|---|---|"]
    for env_id, (path, steps) in ENV_IDS.items():
        task = load_task(path)
        what = (type(task).__doc__ or "").strip().split("\n")[0].split(". Success")[0].rstrip(".")
        rows.append(f"| `{env_id}` | {what} | {steps} steps ({steps / 50:g} s at 50 Hz) | within "
                    f"{task.success_radius * 1e3:g} mm for the last {task.success_window_s:g} s |")  # fmt: skip
    return "\n".join(rows)
