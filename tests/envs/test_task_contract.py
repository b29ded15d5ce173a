"""The task seam: checks every task must pass, and the disturbance task proving it (a task file + a registration line)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from stewart_gym.envs import ENV_IDS
from stewart_gym.envs.task import BallTask, Task, load_task
from stewart_gym.errors import ConfigError

TASKS = sorted({task for task, _ in ENV_IDS.values()})
#: Each task's longest episode among the ids that run it, s.
EPISODE_S = {task: max(seconds for t, seconds in ENV_IDS.values() if t == task) for task in TASKS}


class _RecordingBackend:
    """Enough of a backend to watch what a task does to the physics."""

    def __init__(self) -> None:
        self.pushes: list[tuple[float, tuple[float, float]]] = []
        self.loads: list[tuple[float, object]] = []
        self.t = 0.0

    def push_ball(self, impulse_xy: tuple[float, float]) -> None:
        self.pushes.append((self.t, impulse_xy))

    def set_plate_load(self, load: object) -> None:
        self.loads.append((self.t, load))


def _episode(path: str, seconds: float, seed: int) -> tuple[list, list, list]:
    """A fresh task of ``path`` reset with a generator seeded ``seed``, run for ``seconds``: its targets, and the
    pushes and loads it gave."""
    task, backend = load_task(path), _RecordingBackend()
    task.reset(np.random.default_rng(seed), backend)  # type: ignore[arg-type]
    targets = []
    for k in range(round(seconds / 0.02)):
        backend.t = k * 0.02
        task.before_step(backend.t, backend)  # type: ignore[arg-type]
        targets.append(task.target(backend.t))
    return targets, backend.pushes, [(t, repr(load)) for t, load in backend.loads]


@pytest.mark.parametrize("path", TASKS)
def test_task_contract(path: str) -> None:
    task = load_task(path)
    assert isinstance(task, Task)
    assert task.success_radius > 0 and task.success_window_s > 0 and isinstance(task.name, str)
    backend = _RecordingBackend()
    task.reset(np.random.default_rng(0), backend)  # type: ignore[arg-type]
    for k in range(round(EPISODE_S[path] / 0.02) + 50):  # its longest episode, and 1 s more
        backend.t = k * 0.02
        task.before_step(backend.t, backend)  # type: ignore[arg-type]
        (x, y), (vx, vy) = task.target(backend.t)
        assert all(isinstance(v, float) and math.isfinite(v) for v in (x, y, vx, vy))
        assert abs(x) < 0.15 and abs(y) < 0.15, (backend.t, x, y)  # on the reference plate
    # the reward is finite wherever the ball can be (to beyond the plate's corner), and falls with the distance
    distances = np.linspace(0.0, 0.5, 101).tolist()
    rewards = [task.reward(d, 0.0, False) for d in distances]
    assert all(math.isfinite(r) for r in rewards) and all(a >= b for a, b in zip(rewards, rewards[1:])), rewards
    assert math.isfinite(task.reward(0.5, 1.0, True))
    # the reward prefers the target, punishes servo wear and a fall
    assert task.reward(0.0, 0.0, False) > task.reward(0.01, 0.0, False) > task.reward(0.1, 0.0, False)
    assert task.reward(0.0, 1.0, False) <= task.reward(0.0, 0.0, False)
    assert task.reward(0.0, 0.0, True) < -40
    assert isinstance(task.info(), dict)
    # the same seed draws the same episode: its targets, pushes and loads
    first, again = (_episode(path, EPISODE_S[path], seed) for seed in (0, 0))
    assert first == again


def test_every_registered_id_builds_its_task() -> None:
    for env_id, (path, _) in ENV_IDS.items():
        env = gym.make(env_id)
        try:
            assert type(env.unwrapped.task).__module__ + ":" + type(env.unwrapped.task).__name__ == path
        finally:
            env.close()


def test_unknown_task_is_a_clear_error() -> None:
    with pytest.raises(ConfigError, match="unknown task"):
        load_task("nope")
    with pytest.raises(ConfigError, match="trajectory"):
        load_task("track", trajectory="square")
    with pytest.raises(ConfigError, match="success_radius"):
        BallTask(success_radius=-1.0)


def test_reward_shape_options() -> None:
    """``near_scale`` sharpens the near-target term; ``settled_rate_penalty`` weighs the action rate only within
    the success radius; ``outside_penalty`` costs each step beyond it; all are checked."""
    base, sharp = BallTask(), BallTask(near_scale=0.004)
    assert base.reward(0.0, 0.0, False) == pytest.approx(sharp.reward(0.0, 0.0, False)) == pytest.approx(2.0)
    assert base.reward(0.004, 0.0, False) - sharp.reward(0.004, 0.0, False) == pytest.approx(
        math.exp(-0.004 / 0.015) - math.exp(-1.0))
    quiet = BallTask(rate_penalty=1.0, settled_rate_penalty=100.0)
    assert quiet.reward(0.005, 0.01, False) == pytest.approx(BallTask(rate_penalty=101.0).reward(0.005, 0.01, False))
    assert quiet.reward(0.02, 0.01, False) == pytest.approx(BallTask(rate_penalty=1.0).reward(0.02, 0.01, False))
    timed = BallTask(outside_penalty=0.5)
    assert timed.reward(0.009, 0.0, False) == pytest.approx(base.reward(0.009, 0.0, False))
    assert base.reward(0.011, 0.0, False) - timed.reward(0.011, 0.0, False) == pytest.approx(0.5)
    for bad in ({"near_scale": 0.0}, {"settled_rate_penalty": -1.0}, {"settled_rate_penalty": math.nan},
                {"outside_penalty": -0.1}, {"outside_penalty": math.inf}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            BallTask(**bad)


def test_charge_until_settled_makes_the_outside_cost_the_settling_time() -> None:
    """With ``charge_until_settled`` a ball that leaves the success radius again is charged ``outside_penalty``
    for every step it had spent inside since it entered, so an episode's outside cost is ``outside_penalty`` ×
    the steps until the ball entered for good (the settling time); without it, only the steps outside; a new
    episode (``reset``) starts the count again; a non-boolean is refused."""
    from stewart_gym.evaluation import EpisodeLog

    distances_mm = [40, 20, 9, 5, 8, 12, 11, 7, 3, 2, 2, 2]  # overshoots out after 3 steps in; in for good at 7
    log = EpisodeLog(dt=1.0, distance_mm=[float(d) for d in distances_mm])

    def outside_cost(task: BallTask) -> float:
        plain = BallTask()
        return sum(plain.reward(d / 1e3, 0.0, False) - task.reward(d / 1e3, 0.0, False) for d in distances_mm)

    charged, plain = BallTask(outside_penalty=2.0, charge_until_settled=True), BallTask(outside_penalty=2.0)
    assert outside_cost(charged) == pytest.approx(2.0 * log.settling_time(10.0)) == pytest.approx(14.0)
    assert outside_cost(plain) == pytest.approx(2.0 * 4)  # the four steps beyond 10 mm only
    charged.reward(0.005, 0.0, False)  # inside at the end of the last episode ...
    charged.reset(np.random.default_rng(0), None)  # ... forgotten by the next
    assert charged.reward(0.011, 0.0, False) == pytest.approx(plain.reward(0.011, 0.0, False))
    track = load_task("track", outside_penalty=1.0, charge_until_settled=True)
    track.reward(0.005, 0.0, False)
    track.reset(np.random.default_rng(0), None)  # a task that draws its target resets the count too
    assert track.reward(0.03, 0.0, False) == pytest.approx(load_task("track", outside_penalty=1.0).reward(0.03, 0.0, False))
    with pytest.raises(ConfigError, match="charge_until_settled"):
        BallTask(charge_until_settled="yes")
    env = gym.make("StewartBallBalance-v0", outside_penalty=1.0, charge_until_settled=True)  # an env keyword
    try:
        assert env.unwrapped.task.charge_until_settled is True
    finally:
        env.close()


def test_disturbance_task_pushes_and_loads_on_schedule() -> None:
    task = load_task("disturbance")
    backend = _RecordingBackend()
    task.reset(np.random.default_rng(3), backend)  # type: ignore[arg-type]
    for k in range(500):
        backend.t = k * 0.02
        task.before_step(backend.t, backend)  # type: ignore[arg-type]
    times = [t for t, _ in backend.pushes]
    assert 2 <= len(times) <= 5 and 1.0 <= times[0] <= 2.02 and times[-1] <= 7.5 + 0.02
    assert all(1.5 - 0.02 <= b - a <= 3.0 + 0.02 for a, b in zip(times, times[1:]))
    sizes = [math.hypot(*imp) for _, imp in backend.pushes]
    assert all(0.003 <= s <= 0.010 for s in sizes)
    (t_load, (mass, offset)), = backend.loads
    assert 2.0 <= t_load <= 6.02 and 0.05 <= mass <= 0.20 and math.hypot(offset[0], offset[1]) <= 0.10
    assert task.info() == {"pushes": len(times), "plate_load_kg": mass}


def test_disturbance_env_pushes_the_ball() -> None:
    """In the env, a push changes the ball's course: the same seed without pushes ends elsewhere."""
    def final_xy(env_id: str) -> np.ndarray:
        env = gym.make(env_id)
        env.reset(seed=5, options={"ball_position": (0.0, 0.0), "ball_velocity": (0.0, 0.0)})
        for _ in range(150):
            _, _, terminated, _, info = env.step(np.zeros(2, dtype=np.float32))
            if terminated:
                break
        env.close()
        return np.asarray(info["ball_xy_m"]), info

    quiet, _ = final_xy("StewartBallBalance-v0")
    pushed, info = final_xy("StewartBallDisturbance-v0")
    assert info["pushes"] >= 1
    assert np.linalg.norm(pushed - quiet) > 0.01
