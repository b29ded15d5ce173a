"""Gymnasium environments of the servo hexapod; registered on ``import stewart_gym`` (when gymnasium is there).

Every id is :class:`~stewart_gym.envs.ball_env.StewartBallEnv` with a task; adding
a task is a task file (see :mod:`stewart_gym.envs.task`) and one line in
:data:`ENV_IDS`.
"""

from __future__ import annotations

__all__ = ["ENV_ENTRY_POINT", "ENV_IDS", "VECTOR_ENTRY_POINT", "env_table", "make_keywords", "register_envs",
           "reward_threshold", "trajectory_env_ids"]

ENV_ENTRY_POINT = "stewart_gym.envs.ball_env:StewartBallEnv"
#: ``gym.make_vec(id, num_envs, vectorization_mode="vector_entry_point")``: the batched vector env (``workers=k``: split
#: over k processes).
VECTOR_ENTRY_POINT = "stewart_gym.envs.split_vector:batched_vector_env"

#: id → (task, episode length in s): the task is a "module:Class" path (see stewart_gym.envs.task). An episode is a
#: duration: at the default 50 Hz, 500 steps for balance, 1000 for track; at ``control_hz=25``, half as many.
ENV_IDS: dict[str, tuple[str, float]] = {
    "StewartBallBalance-v0": ("stewart_gym.envs.tasks.balance:BalanceTask", 10.0),
    "StewartBallTrack-v0": ("stewart_gym.envs.tasks.track:TrackTask", 20.0),
    "StewartBallDisturbance-v0": ("stewart_gym.envs.tasks.disturbance:DisturbanceTask", 10.0),
}
#: The ids whose return says whether the task is solved (:func:`reward_threshold`): not the pushes, which cost a
#: held ball return (the PID + Kalman earns about 700 there, under balance's threshold, with every episode a success).
SOLVED_BY_RETURN = ("StewartBallBalance-v0", "StewartBallTrack-v0")


def make_keywords(env_id: str) -> set[str]:
    """The keywords ``gym.make(env_id, ...)`` takes: the env's own and its task's, and Gymnasium's
    ``max_episode_steps`` (not ``render_mode``)."""
    from stewart_gym.envs.ball_env import env_keywords

    return (env_keywords(ENV_IDS[env_id][0]) | {"max_episode_steps"}) - {"render_mode"}


def reward_threshold(env_id: str) -> float | None:
    """Gymnasium's ``reward_threshold`` of ``env_id`` at its defaults: the return of an episode in which the ball
    rests exactly at the success radius from the target the whole time, with no servo motion, i.e. the steps
    × (1 − r/h + exp(−r/near_scale)). A policy whose mean return is higher keeps the ball closer than that on
    average: 723.4 for balance (10 mm), 1130.3 for track (20 mm). None where the return is no such measure."""
    import math

    from stewart_gym.envs.task import load_task

    if env_id not in SOLVED_BY_RETURN:
        return None
    path, seconds = ENV_IDS[env_id]
    task = load_task(path)
    r, h = task.success_radius, task.plate_half
    return round(seconds * 50 * (1.0 - r / h + math.exp(-r / task.near_scale)), 1)


def register_envs() -> None:
    """Register every environment id with Gymnasium (idempotent). The env ends its episodes itself, after its
    ``episode_s`` at whatever ``control_hz`` (``gym.make(..., max_episode_steps=N)`` still adds a shorter limit)."""
    import gymnasium

    for env_id, (task, seconds) in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=ENV_ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT,
                               reward_threshold=reward_threshold(env_id),
                               kwargs={"task": task, "episode_s": seconds})  # fmt: skip


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
    for env_id, (path, seconds) in ENV_IDS.items():
        task = load_task(path)
        what = (type(task).__doc__ or "").strip().split("\n")[0].split(". Success")[0].rstrip(".")
        rows.append(f"| `{env_id}` | {what} | {seconds:g} s ({seconds * 50:g} steps at 50 Hz) | within "
                    f"{task.success_radius * 1e3:g} mm for the last {task.success_window_s:g} s |")  # fmt: skip
    return "\n".join(rows)
