"""The batched vector env split over worker processes (``workers=k``, :mod:`stewart_gym.envs.split_vector`): the
same copies, to the last bit, as one process's; its arguments checked at the edge; a failing or dying worker is one
clear error; closing ends the workers."""

from __future__ import annotations

import os
import signal

import gymnasium as gym
import numpy as np
import pytest

import stewart_gym  # noqa: F401  (registers the ids)
from stewart_gym.envs.split_vector import SplitVectorEnv, WorkerTraceback
from stewart_gym.envs.tasks.balance import BalanceTask
from stewart_gym.envs.vector import StewartBallVectorEnv
from stewart_gym.errors import ConfigError

pytestmark = pytest.mark.xdist_group("split_vector")  # worker processes: not two of these tests at once


class FailingTask(BalanceTask):
    """A task that fails in its first step (importable: a worker makes it from its module)."""

    def before_step(self, t: float, backend: object) -> None:
        raise ValueError("the task failed on purpose")


def make(num_envs: int, **kwargs) -> gym.vector.VectorEnv:
    return gym.make_vec("StewartBallBalance-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
                        **kwargs)  # fmt: skip


def assert_same_info(got: dict, want: dict) -> None:
    assert list(got) == list(want)
    for key, value in want.items():
        if isinstance(value, dict):
            assert_same_info(got[key], value)
        elif value.dtype == object:
            assert got[key].dtype == object and len(got[key]) == len(value)
            for a, b in zip(got[key], value):
                assert (a is None) == (b is None)
                if b is not None:
                    np.testing.assert_array_equal(a, b)
        else:
            assert got[key].dtype == value.dtype, key
            np.testing.assert_array_equal(got[key], value)


@pytest.mark.parametrize(("num_envs", "workers", "extra"), [(7, 3, {}), (4, 2, {}), (4, 2, {"max_episode_steps": 13})],
                         ids=["7-on-3", "4-on-2", "time-limit"])  # fmt: skip
def test_the_copies_are_one_process_copies(num_envs: int, workers: int, extra: dict) -> None:
    """Observations, rewards, ends and infos (ended episodes' final observations and infos included) equal those of
    one process's vector env to the last bit, through resets, with shares of unequal sizes, and with a step limit."""
    kwargs = {"randomize": True, "estimator": "kalman", "episode_s": 0.4, **extra}  # 20-step episodes: all reset
    split, one = make(num_envs, workers=workers, **kwargs), make(num_envs, **kwargs)
    try:
        assert isinstance(split, SplitVectorEnv) and isinstance(one, StewartBallVectorEnv)
        assert split.sizes == [num_envs // workers + (w < num_envs % workers) for w in range(workers)]
        assert len(split.pids) == workers - 1 and split.observation_space == one.observation_space
        obs, info = split.reset(seed=11)
        want_obs, want_info = one.reset(seed=11)
        np.testing.assert_array_equal(obs, want_obs)
        assert_same_info(info, want_info)
        actions = np.random.default_rng(3).uniform(-1, 1, (45, num_envs, 2)).astype(np.float32)
        ended = 0
        for a in actions:
            got, want = split.step(a), one.step(a)
            for x, y in zip(got[:4], want[:4]):
                assert x.dtype == y.dtype
                np.testing.assert_array_equal(x, y)
            assert_same_info(got[4], want[4])
            ended += int((want[2] | want[3]).sum())
        assert ended >= num_envs
    finally:
        split.close()
        one.close()


def test_bad_workers_are_one_clear_error() -> None:
    for bad, says in ((0, "workers must be a whole number from 1"), (1.5, "workers must be a whole number"),
                      (True, "workers must be a whole number"), (3, "workers must be from 1 to num_envs (2)")):  # fmt: skip
        with pytest.raises(ConfigError, match=says.replace("(", r"\(").replace(")", r"\)")):
            make(2, workers=bad)
    assert isinstance(make(2, workers=1), StewartBallVectorEnv)


def test_a_worker_that_fails_is_one_error_and_leaves_no_process() -> None:
    """A keyword the env refuses: the workers' error, once, and every worker ended."""
    before = set(os.listdir("/proc")) if os.path.isdir("/proc") else None
    with pytest.raises(ConfigError, match="unknown task 'no-such-task'"):
        make(4, workers=2, task="no-such-task")
    if before is not None:  # the worker process is gone (reaped), not left behind
        leftover = [p for p in set(os.listdir("/proc")) - before if p.isdigit()]
        for pid in leftover:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                assert b"stewart_gym.envs.split_vector" not in f.read()


def test_a_workers_error_is_raised_as_one_processs_env_raises_it() -> None:
    """An error in a worker's share is the error one process's env raises (its type, its message), the worker's
    traceback its cause; the shares then need a reset (they stepped apart). A task defined in the script itself,
    which the workers cannot import, is refused before they start."""
    one, split = make(4, task=FailingTask()), make(4, workers=2, task=FailingTask())
    try:
        for env in (one, split):
            env.reset(seed=0)
            with pytest.raises(ValueError, match="^the task failed on purpose$") as raised:
                env.step(np.zeros((4, 2), np.float32))
        assert isinstance(raised.value.__cause__, WorkerTraceback)
        assert "the task failed on purpose" in str(raised.value.__cause__)
        from gymnasium.error import ResetNeeded

        with pytest.raises(ResetNeeded):
            split.step(np.zeros((4, 2), np.float32))
    finally:
        one.close()
        split.close()
    script = type("ScriptTask", (BalanceTask,), {"__module__": "__main__"})
    with pytest.raises(ConfigError, match=r"task: ScriptTask is defined in the script itself \(__main__\), which the "
                                          "split vector env's workers cannot import"):  # fmt: skip
        make(4, workers=2, task=script())


def test_a_split_env_refuses_a_copy_and_stays_whole() -> None:
    """copy.deepcopy or pickle of a split env: one TypeError, before anything is copied (a half-made copy closed
    the env's pipes as it was collected); the env steps on, and closes once and again. One process's vector env
    copies: the copy steps as the env does."""
    import copy
    import gc
    import pickle

    split = make(4, workers=2)
    try:
        split.reset(seed=0)
        for attempt in (copy.deepcopy, pickle.dumps):
            with pytest.raises(TypeError, match="cannot be copied or pickled: its copies live in worker processes"):
                attempt(split)
        gc.collect()
        split.step(np.zeros((4, 2), np.float32))
    finally:
        split.close()
    split.close()
    one = make(3)
    one.reset(seed=2)
    twin = copy.deepcopy(one)
    a = np.full((3, 2), 0.3, np.float32)
    for x, y in zip(one.step(a)[:4], twin.step(a)[:4]):
        np.testing.assert_array_equal(x, y)
    one.close()
    twin.close()


def test_a_dead_worker_is_one_error_and_close_ends_the_others() -> None:
    env = make(6, workers=3)
    env.reset(seed=0)
    first, second = env.pids
    os.kill(first, signal.SIGKILL)
    with pytest.raises(ConfigError, match="stopped"):
        env.step(np.zeros((6, 2), np.float32))
    env.close()
    for pid in (first, second):  # both ended and reaped
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


@pytest.mark.parametrize("row", [0, 3], ids=["own-share", "worker-share"])
def test_an_action_the_env_refuses_moves_no_copy(row: int) -> None:
    """A NaN action in one copy's row, in this process's share or a worker's: the same error as one process's
    env, raised before any share moves, so that the next step's answers are still those of one process's env."""
    split, one = make(4, workers=2), make(4)
    try:
        split.reset(seed=1)
        one.reset(seed=1)
        bad = np.zeros((4, 2), np.float32)
        bad[row] = np.nan
        with pytest.raises(ValueError, match=rf"action must be finite, got \[nan, nan\] \(copy {row}\)"):
            split.step(bad)
        with pytest.raises(ValueError, match=rf"\(copy {row}\)"):
            one.step(bad)
        a = np.full((4, 2), 0.2, np.float32)
        for x, y in zip(split.step(a)[:4], one.step(a)[:4]):
            np.testing.assert_array_equal(x, y)
    finally:
        split.close()
        one.close()


@pytest.mark.parametrize("workers", [1, 2])
def test_a_step_before_reset_or_after_close_is_refused(workers: int) -> None:
    """A step before the first reset is Gymnasium's ``ResetNeeded``; a step or a reset after ``close`` its
    ``ClosedEnvironmentError``; a seed that is not a whole number ≥ 0, None or one per copy, one clear error."""
    from gymnasium.error import ClosedEnvironmentError, ResetNeeded

    env = make(4, workers=workers)
    with pytest.raises(ResetNeeded):
        env.step(np.zeros((4, 2), np.float32))
    for seed in ("a", [1, 2], True, 1.5, -1, [4, 5, 6, -7]):
        with pytest.raises(ConfigError, match="seed must be a whole number"):
            env.reset(seed=seed)
    for seed in (np.int64(4), np.array(4), np.arange(4, 8)):
        obs, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(obs, env.reset(seed=[4, 5, 6, 7])[0])
    env.reset(seed=np.int64(9))
    assert env.np_random_seed == 9  # a whole number seeds the vector env's own generator too, of any integer type
    with pytest.raises(ValueError, match="real numbers"):
        env.step(np.zeros((4, 2), complex))
    with pytest.raises(ValueError, match=r"expected actions of shape \(4, 2\)"):
        env.step(np.zeros(4, np.float32))
    env.close()
    with pytest.raises(ClosedEnvironmentError):
        env.step(np.zeros((4, 2), np.float32))
    with pytest.raises(ClosedEnvironmentError):
        env.reset()
