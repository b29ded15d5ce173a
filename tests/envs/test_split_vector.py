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
from stewart_gym.envs.split_vector import SplitVectorEnv
from stewart_gym.envs.vector import StewartBallVectorEnv
from stewart_gym.errors import ConfigError

pytestmark = pytest.mark.xdist_group("split_vector")  # worker processes: not two of these tests at once


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


@pytest.mark.parametrize(("num_envs", "workers"), [(7, 3), (4, 2)])
def test_the_copies_are_one_process_copies(num_envs: int, workers: int) -> None:
    """Observations, rewards, ends and infos (ended episodes' final observations and infos included) equal those of
    one process's vector env to the last bit, through resets, with shares of unequal sizes."""
    kwargs = {"randomize": True, "estimator": "kalman", "episode_s": 0.4}  # 20-step episodes: every copy resets
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


def test_an_action_the_env_refuses_leaves_the_workers_in_step() -> None:
    """A NaN action, refused by the env in this process and in the workers: the error, then the next step's
    answers are the next step's (the refused step's are not read in their place)."""
    split, one = make(4, workers=2), make(4)
    try:
        split.reset(seed=1)
        one.reset(seed=1)
        bad = np.full((4, 2), np.nan, np.float32)
        with pytest.raises(Exception) as refused:
            split.step(bad)
        with pytest.raises(type(refused.value)):
            one.step(bad)
        a = np.full((4, 2), 0.2, np.float32)
        for x, y in zip(split.step(a)[:4], one.step(a)[:4]):
            np.testing.assert_array_equal(x, y)
    finally:
        split.close()
        one.close()
