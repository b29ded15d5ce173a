"""The batched vector env's tasks as arrays (:class:`~stewart_gym.envs.task_array.TaskArray`): every hook gives,
row for row and to the last bit, what each copy's own task gives, whether it is done as arrays or asked copy by
copy."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stewart_gym.envs.task import BallTask, load_task
from stewart_gym.envs.task_array import TaskArray
from stewart_gym.sim.batched import BatchedPlatform, BatchedSim

REWARD_KWARGS = [{}, {"settled_rate_penalty": 0.5, "outside_penalty": 0.2, "near_scale": 0.01},
                 {"success_radius": 0.02, "rate_penalty": 0.0}, {"outside_penalty": 0.3, "charge_until_settled": True}]


class OwnReward(BallTask):
    """A task with its own reward: asked copy by copy."""

    def reward(self, distance: float, action_rate: float, fell: bool) -> float:
        return -distance - action_rate - (1.0 if fell else 0.0)


class HardFall(BallTask):
    """BallTask's reward with a heavier fall."""

    FALL_PENALTY = 100.0


def test_the_built_in_hooks_are_arrays_and_the_others_are_asked() -> None:
    balance = TaskArray([load_task("balance") for _ in range(3)])
    assert (balance.disturbs, balance.fixed_target, balance.adds_info, balance.ball_rewards) == (False, True, False, True)
    track = TaskArray([load_task("track", trajectory="mixed") for _ in range(3)])
    assert (track.disturbs, track.fixed_target, track.ball_rewards) == (False, False, True)
    disturbance = TaskArray([load_task("disturbance") for _ in range(3)])
    assert disturbance.disturbs and disturbance.adds_info and disturbance.fixed_target
    assert not TaskArray([load_task("balance"), OwnReward()]).ball_rewards
    patched = load_task("balance")
    patched.reward = lambda distance, action_rate, fell: 7.0  # a hook set on the instance is the task's own
    array = TaskArray([load_task("balance"), patched])
    assert not array.ball_rewards
    assert array.rewards(np.array([0.0, 0.0]), np.zeros(2), np.array([False, True]))[1] == 7.0


@pytest.mark.parametrize("kwargs", REWARD_KWARGS, ids=["default", "penalties", "track-radius", "charged"])
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_rewards_are_each_tasks_own(kwargs: dict, data: st.DataObject) -> None:
    """Over a few steps (the charged reward counts steps inside), distances on and around the success radius; the
    copies' tasks differ (each row its own parameters: one with ``kwargs``, the others drawn, one falling harder)."""
    n = 5
    tasks = [load_task("balance", **kwargs), HardFall()]
    for _ in range(n - 2):
        tasks.append(load_task("balance", near_scale=data.draw(st.floats(0.005, 0.03)),
                               success_radius=data.draw(st.sampled_from([0.01, 0.02])),
                               settled_rate_penalty=data.draw(st.sampled_from([0.0, 0.5])),
                               outside_penalty=data.draw(st.sampled_from([0.0, 0.2]))))  # fmt: skip
    own = copy.deepcopy(tasks)
    array = TaskArray(tasks)
    radius = tasks[0].success_radius
    near = st.sampled_from([0.0, radius, np.nextafter(radius, 1.0), 0.01, 0.02, 0.3, 1e-9])
    distance = st.one_of(near, st.floats(0.0, 0.35, allow_nan=False))
    for _ in range(data.draw(st.integers(1, 4))):
        d = np.array(data.draw(st.lists(distance, min_size=n, max_size=n)))
        rate = np.array(data.draw(st.lists(st.floats(0.0, 4.0), min_size=n, max_size=n)))
        fell = np.array(data.draw(st.lists(st.booleans(), min_size=n, max_size=n)))
        expected = [task.reward(a, b, c) for task, a, b, c in zip(own, d.tolist(), rate.tolist(), fell.tolist())]
        np.testing.assert_array_equal(array.rewards(d, rate, fell), expected)


def test_a_reward_parameter_changed_between_steps_counts_at_once() -> None:
    """As for one env (a curriculum sharpens ``near_scale`` between rollouts): the next step's reward uses it."""
    tasks = [load_task("balance", settled_rate_penalty=0.5) for _ in range(3)]
    array = TaskArray(tasks)
    d, rate, fell = np.array([0.004, 0.02, 0.05]), np.array([0.1, 0.0, 0.3]), np.zeros(3, dtype=bool)
    before = array.rewards(d, rate, fell)
    tasks[0].near_scale, tasks[1].outside_penalty, tasks[2].success_radius = 0.005, 1.0, 0.06
    after = array.rewards(d, rate, fell)
    assert (after != before).all()
    np.testing.assert_array_equal(after, [t.reward(a, b, False) for t, a, b in zip(tasks, d.tolist(), rate.tolist())])
    tasks[1].charge_until_settled = True  # now counted per copy: asked copy by copy
    np.testing.assert_array_equal(array.rewards(d, rate, fell),
                                  [t.reward(a, b, False) for t, a, b in zip(copy.deepcopy(tasks), d.tolist(),
                                                                            rate.tolist())])  # fmt: skip


def test_a_task_class_fall_penalty_changed_between_steps_counts_at_once(monkeypatch) -> None:
    """The array keeps the parameters it read until one may have changed: a class's ``FALL_PENALTY`` too."""
    from stewart_gym.envs.tasks.balance import BalanceTask

    tasks = [load_task("balance") for _ in range(2)]
    array = TaskArray(tasks)
    d, rate, fell = np.array([0.004, 0.02]), np.zeros(2), np.array([True, False])
    before = array.rewards(d, rate, fell)
    monkeypatch.setattr(BalanceTask, "FALL_PENALTY", 80.0)
    after = array.rewards(d, rate, fell)
    assert after[0] == before[0] - 30.0 and after[1] == before[1]
    np.testing.assert_array_equal(after, [t.reward(a, 0.0, f) for t, a, f in zip(tasks, d.tolist(), fell.tolist())])


def test_a_deleted_override_and_a_computed_parameter_count_at_once() -> None:
    """An instance's override deleted between steps, and a parameter a task class computes (a property, here a
    success radius that widens with a curriculum's stage): the next step's rewards are the tasks' own."""
    from stewart_gym.envs.task import BallTask

    class Staged(BallTask):
        stage = 0

        @property
        def success_radius(self) -> float:
            return 0.01 if Staged.stage == 0 else 0.08

        @success_radius.setter
        def success_radius(self, value: float) -> None:
            pass

    d, rate, fell = np.array([0.05, 0.05]), np.zeros(2), np.array([True, False])

    def own(tasks: list) -> list[float]:
        return [t.reward(a, 0.0, f) for t, a, f in zip(tasks, d.tolist(), fell.tolist())]

    tasks = [BallTask(), BallTask()]
    array = TaskArray(tasks)
    tasks[0].FALL_PENALTY = 100.0
    np.testing.assert_array_equal(array.rewards(d, rate, fell), own(tasks))
    del tasks[0].FALL_PENALTY
    np.testing.assert_array_equal(array.rewards(d, rate, fell), own(tasks))
    staged = [Staged(outside_penalty=1.0), Staged(outside_penalty=1.0)]
    array = TaskArray(staged)
    before = array.rewards(d, rate, fell)
    Staged.stage = 1
    after = array.rewards(d, rate, fell)
    assert array.computed_parameters and (after > before).all()
    np.testing.assert_array_equal(after, own(staged))


def test_targets_pushes_and_infos_are_each_tasks_own() -> None:
    """Moving targets (track) and pushes with their info (disturbance), each copy's at its own time."""
    rng = np.random.default_rng(3)
    sim = BatchedSim(n=3)
    platforms = [BatchedPlatform(sim, i, owns_steps=False) for i in range(3)]
    tracks = [load_task("track", trajectory="mixed") for _ in range(3)]
    for task, platform in zip(tracks, platforms):
        task.reset(rng, platform)
    times = np.array([0.0, 1.3, 7.9])
    targets, velocities = TaskArray(tracks).targets(times)
    for i, task in enumerate(tracks):
        assert (tuple(targets[i]), tuple(velocities[i])) == tuple(map(tuple, task.target(float(times[i]))))
    pushed = [load_task("disturbance") for _ in range(3)]
    own = [load_task("disturbance") for _ in range(3)]
    for task, mine in zip(pushed, own):
        state = rng.bit_generator.state
        task.reset(rng, platforms[0])
        rng.bit_generator.state = state
        mine.reset(rng, platforms[0])
    array = TaskArray(pushed)
    before = sim.ball_velocity.copy()
    array.before_step(np.array([0.0, 5.0, 9.0]), platforms)
    for task, t in zip(own, (0.0, 5.0, 9.0)):
        task.before_step(t, BatchedPlatform(BatchedSim(n=1), 0))
    infos = array.infos()
    assert infos["pushes"].tolist() == [task.info()["pushes"] for task in own] and infos["pushes"][2] >= 2
    assert infos["plate_load_kg"].tolist() == [task.info()["plate_load_kg"] for task in own]
    moved = np.any(sim.ball_velocity != before, axis=1)
    assert moved.tolist() == [False, True, True]
