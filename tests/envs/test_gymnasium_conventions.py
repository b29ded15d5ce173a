"""The conventions Gymnasium's own environments keep, and the clients that rely on them: both env checkers with
the render check, ``deepcopy`` mid-episode, ``close()`` then ``reset()``, ``TypeError`` for an unknown keyword,
the episode as a duration, ndarray info values that batch, ``reward_threshold`` and ``RecordVideo``."""

from __future__ import annotations

import copy
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import stewart_gym  # noqa: F401  (registers the ids)
from stewart_gym.envs import ENV_IDS, reward_threshold

BACKENDS = ("pybullet", "mujoco")


def test_both_checkers_pass_with_the_render_check() -> None:
    """Gymnasium's and Stable-Baselines3's checkers, rendering included: SB3's closes the env and resets it
    again, which a closed PyBullet engine could not do before it learned to start again."""
    env = gym.make("StewartBallBalance-v0", render_mode="rgb_array")
    try:
        check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(env.unwrapped, warn=True, skip_render_check=False)
    finally:
        env.close()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("env_id", list(ENV_IDS))
def test_a_deepcopy_mid_episode_steps_as_the_original(env_id: str, backend: str) -> None:
    """A copy made 60 steps in is another env (its own engine) in the same state: the same observations,
    rewards and ends, to the last bit, for the next 80 steps; stepping one does not move the other."""
    env = gym.make(env_id, randomize=True, backend=backend, estimator="kalman")
    rng = np.random.default_rng(1)
    env.reset(seed=5)
    for _ in range(60):
        env.step(rng.uniform(-0.4, 0.4, 2).astype(np.float32))
    twin = copy.deepcopy(env)
    try:
        assert twin.unwrapped.sim is not env.unwrapped.sim
        for action in rng.uniform(-0.4, 0.4, (80, 2)).astype(np.float32):
            a, b = env.step(action), twin.step(action)
            assert np.array_equal(a[0], b[0]) and a[1:4] == b[1:4]
            assert np.array_equal(a[4]["ball_xy_m"], b[4]["ball_xy_m"])
            if a[2] or a[3]:
                break
        before = env.unwrapped.sim.ball_position()
        twin.step(np.ones(2, dtype=np.float32))
        assert env.unwrapped.sim.ball_position() == before  # independent
    finally:
        env.close()
        twin.close()


def test_a_deepcopy_keeps_what_was_changed_on_the_env_its_generator_and_its_own_options() -> None:
    """What a copy replays is what the episode had: a start box and a reward scale set on the live env (as the
    curriculum sets them) before the reset, reset options the caller changes afterwards, and a draw taken from the
    env's generator by someone else; the copy steps and resets as the original, to the last bit, and says the
    same seed."""
    env = gym.make("StewartBallBalance-v0", backend="mujoco")
    try:
        env.unwrapped.START_FRACTION = 0.1
        env.unwrapped.task.near_scale = 0.005
        where = {"ball_velocity": [0.05, 0.0]}
        env.reset(seed=0, options=where)
        where["ball_velocity"][0] = -0.05  # the caller's dict, changed after the reset
        for _ in range(3):
            env.step(np.zeros(2, dtype=np.float32))
        env.unwrapped.np_random.random()  # a draw by someone else
        env.unwrapped.task.near_scale = 0.004  # changed mid-episode: the copy takes it too
        twin = copy.deepcopy(env)
        try:
            assert twin.unwrapped.START_FRACTION == 0.1 and twin.unwrapped.task.near_scale == 0.004
            assert twin.unwrapped.np_random_seed == env.unwrapped.np_random_seed == 0
            for _ in range(5):
                a, b = env.step(np.full(2, 0.2, dtype=np.float32)), twin.step(np.full(2, 0.2, dtype=np.float32))
                assert np.array_equal(a[0], b[0]) and a[1] == b[1], (a[4]["ball_xy_m"], b[4]["ball_xy_m"])
            assert np.array_equal(env.reset()[0], twin.reset()[0])  # the generators agree
            assert np.max(np.abs(env.unwrapped.sim.ball_position()[:2])) <= 0.1 * 0.15 + 1e-9  # the small start box
        finally:
            twin.close()
    finally:
        env.close()


def test_a_task_that_holds_the_env_its_engine_or_its_generator_is_copied_with_the_copys() -> None:
    """A user's task that keeps the env, the engine it was reset on and the generator it drew from (and draws from
    it each step): the env resets, closes and resets again; a copy's task holds the copy's own, and the two go on
    alike, their generators included. A task that cannot be copied (a lock) resets all the same, and a copy is
    refused in one TypeError that says why."""
    import threading

    from stewart_gym.envs.ball_env import StewartBallEnv
    from stewart_gym.envs.tasks.balance import BalanceTask

    class Keeping(BalanceTask):
        def reset(self, rng, backend):
            super().reset(rng, backend)
            self.rng, self.backend = rng, backend

        def before_step(self, t, backend):
            self.rng.random()  # a draw each step from the env's generator

    env = StewartBallEnv(task=Keeping(), backend="mujoco")
    env.task.env = env
    try:
        env.reset(seed=0)
        env.close()
        env.reset(seed=1)
        for _ in range(3):
            env.step(np.zeros(2, dtype=np.float32))
        twin = copy.deepcopy(env)
        try:
            task = twin.task
            assert task.env is twin and task.backend is twin.sim and task.rng is twin.np_random
            for _ in range(5):
                assert np.array_equal(env.step(np.full(2, 0.1, np.float32))[0], twin.step(np.full(2, 0.1, np.float32))[0])
            assert env.np_random.bit_generator.state == twin.np_random.bit_generator.state
        finally:
            twin.close()
        env.task.lock = threading.Lock()
        env.reset(seed=2)  # a task that cannot be copied: the env resets all the same
        with pytest.raises(TypeError, match=r"^copy.deepcopy: this env's task \(Keeping\) cannot be copied \(TypeError"):
            copy.deepcopy(env)
    finally:
        env.close()


def test_a_deepcopy_replays_the_episode_with_the_task_it_had_at_the_reset() -> None:
    """Pushes drawn at the reset with a push size set on the live task, which is set back after the first push: a
    copy made then has had the push the original had (its ball moves on as the original's), and its task has the
    push size of now."""
    env = gym.make("StewartBallDisturbance-v0", backend="mujoco")
    try:
        env.unwrapped.task.push_impulse = (0.012, 0.012)
        env.reset(seed=3, options={"ball_position": [0.0, 0.0], "ball_velocity": [0.0, 0.0]})
        while env.step(np.zeros(2, dtype=np.float32))[4]["pushes"] == 0:  # the first push comes 1 to 2 s in
            pass
        env.unwrapped.task.push_impulse = (0.003, 0.010)
        twin = copy.deepcopy(env)
        try:
            assert twin.unwrapped.task.push_impulse == (0.003, 0.010)
            for _ in range(5):
                a, b = env.step(np.zeros(2, dtype=np.float32)), twin.step(np.zeros(2, dtype=np.float32))
                assert np.array_equal(a[4]["ball_xy_m"], b[4]["ball_xy_m"]) and a[1:4] == b[1:4]
        finally:
            twin.close()
    finally:
        env.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_close_then_reset_starts_the_engine_again(backend: str) -> None:
    env = gym.make("StewartBallBalance-v0", backend=backend)
    first, _ = env.reset(seed=2)
    env.close()
    again, _ = env.reset(seed=2)
    try:
        assert np.array_equal(first, again)  # the same episode
        env.step(np.zeros(2, dtype=np.float32))
    finally:
        env.close()
        env.close()  # twice is fine


def test_an_unknown_keyword_is_a_type_error_naming_it() -> None:
    """TorchRL and other clients probe an env's keywords by catching ``TypeError`` (Python's own for a keyword a
    function does not take); a bad value of a known keyword stays a one-line ``ConfigError``."""
    from stewart_gym.errors import ConfigError

    with pytest.raises(TypeError, match="unexpected keyword argument 'frameskip'"):
        gym.make("StewartBallBalance-v0", frameskip=4)
    with pytest.raises(TypeError, match="'trajectory'"):  # the balance task has no trajectory
        gym.make("StewartBallBalance-v0", trajectory="circle")
    gym.make("StewartBallTrack-v0", trajectory="circle").close()  # the track task has one
    with pytest.raises(ConfigError):
        gym.make("StewartBallBalance-v0", estimator="particle")


@pytest.mark.parametrize("control_hz,steps", [(50, 500), (25, 250), (100, 1000)])
def test_an_episode_is_a_duration(control_hz: int, steps: int) -> None:
    """10 s of balance at any control rate: truncated at the step that completes it, not before."""
    env = gym.make("StewartBallBalance-v0", control_hz=control_hz)
    try:
        env.reset(seed=0, options={"ball_position": (0.0, 0.0), "ball_velocity": (0.0, 0.0)})
        for k in range(1, steps + 1):
            _, _, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.float32))
            assert not terminated and truncated == (k == steps)
        assert env.unwrapped.episode_steps == steps
    finally:
        env.close()
    short = gym.make("StewartBallBalance-v0", max_episode_steps=5)  # Gymnasium's own limit still applies on top
    try:
        short.reset(seed=0)
        assert [short.step(np.zeros(2, dtype=np.float32))[3] for _ in range(5)] == [False] * 4 + [True]
    finally:
        short.close()


def test_array_valued_info_batches_as_float_arrays_in_a_vector_env() -> None:
    envs = gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode="sync")
    try:
        envs.reset(seed=0)
        _, _, _, _, info = envs.step(np.zeros((2, 2), dtype=np.float32))
        for key in ("commanded_tilt_rad", "pulse_widths_us", "ball_xy_m", "target_xy_m"):
            assert info[key].dtype == np.float64 and info[key].shape[0] == 2, key
    finally:
        envs.close()


def test_reward_threshold_is_the_return_of_a_ball_held_at_the_success_radius() -> None:
    """Balance and track have one (the return of an episode at the success radius, no servo motion); the pushes
    do not: a pushed ball costs return while every episode succeeds."""
    from stewart_gym.envs.task import load_task

    for env_id in ENV_IDS:
        spec = gym.spec(env_id)
        assert spec.reward_threshold == reward_threshold(env_id)
    assert reward_threshold("StewartBallDisturbance-v0") is None
    task = load_task(ENV_IDS["StewartBallBalance-v0"][0])
    assert reward_threshold("StewartBallBalance-v0") == pytest.approx(500 * task.reward(0.010, 0.0, False), abs=0.05)
    track = load_task(ENV_IDS["StewartBallTrack-v0"][0])
    assert reward_threshold("StewartBallTrack-v0") == pytest.approx(1000 * track.reward(0.020, 0.0, False), abs=0.05)


def test_record_video_writes_a_file(tmp_path: Path) -> None:
    """Gymnasium's RecordVideo with the ``video`` extra (moviepy): one episode's MP4."""
    from gymnasium.wrappers import RecordVideo

    env = RecordVideo(gym.make("StewartBallBalance-v0", render_mode="rgb_array", max_episode_steps=20),
                      str(tmp_path / "videos"), episode_trigger=lambda k: k == 0, disable_logger=True)  # fmt: skip
    try:
        env.reset(seed=0)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.float32))
            done = terminated or truncated
    finally:
        env.close()
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000


BAD_ARGUMENTS = [
    ({"ball": 5}, "ball must be a BallSpec"), ({"servo": "x"}, "servo must be a ServoSpec"),
    ({"geometry": 5}, "geometry must be a preset name, a TOML path or a PlatformGeometry"),
    ({"control_hz": "50"}, "control_hz must be a whole number"), ({"control_hz": True}, "control_hz must be a whole"),
    ({"control_hz": 0}, r"control_hz must be a whole number in \[1, 1000\]"),
    ({"physics_hz": 0}, "physics_hz must be a whole number in"), ({"physics_hz": 300.5}, "physics_hz must be a whole"),
    ({"max_tilt": True}, "max_tilt must be a number"), ({"max_tilt": "0.1"}, "max_tilt must be a number"),
    ({"success_radius": "x"}, "success_radius must be a number"), ({"rate_penalty": "x"}, "rate_penalty must be a"),
    ({"randomization": 5}, "randomization must be RandomizationRanges or a mapping"),
    ({"episode_s": "5"}, "episode_s must be a number"), ({"integral": 1}, "integral must be true or false"),
]  # fmt: skip


@pytest.mark.parametrize("vector", [False, True], ids=["make", "make_vec"])
@pytest.mark.parametrize("kwargs,says", BAD_ARGUMENTS, ids=[next(iter(k)) + "=" + repr(v) for k, v in
                                                            ((a, next(iter(a.values()))) for a, _ in BAD_ARGUMENTS)])
def test_a_bad_argument_is_a_config_error_naming_it(kwargs: dict, says: str, vector: bool) -> None:
    """A constructor argument of the wrong type or out of range is refused before anything is built, naming the
    argument (a bool is not a number; an AttributeError from deep inside was the answer to ``ball=5``)."""
    from stewart_gym.errors import ConfigError

    with pytest.raises(ConfigError, match=says):
        if vector:
            gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
        else:
            gym.make("StewartBallBalance-v0", backend="batched", **kwargs)


def test_numpy_numbers_and_switches_are_taken() -> None:
    """NumPy's scalars are numbers and switches as Python's are; a whole float is a whole number."""
    env = gym.make("StewartBallBalance-v0", backend="batched", episode_s=np.int64(5), control_hz=np.int64(50),
                   physics_hz=150.0, max_tilt=np.float32(0.1), integral=np.True_, randomize=np.True_)  # fmt: skip
    try:
        assert env.unwrapped.episode_steps == 250 and env.observation_space.shape == (14,)
        assert env.unwrapped.mapper.max_tilt == pytest.approx(0.1)
    finally:
        env.close()


def test_a_refused_reset_leaves_no_trace() -> None:
    """A reset refused for its options leaves the generator, the episode and what a copy replays as they were: the
    next reset draws what it would have drawn, and a deepcopy still works."""
    from stewart_gym.errors import ConfigError

    starts = []
    for refuse in (False, True):
        env = gym.make("StewartBallBalance-v0", randomize=True)
        env.reset(seed=0)
        for _ in range(5):
            env.step(np.array([0.3, -0.2], dtype=np.float32))
        if refuse:
            with pytest.raises(ConfigError, match="unknown reset option"):
                env.reset(seed=123, options={"foo": 1})
            with pytest.raises(ConfigError, match="ball_velocity"):
                env.reset(seed=123, options={"ball_velocity": (5, 0)})
            twin = copy.deepcopy(env)
            twin.close()
        _, info = env.reset()
        starts.append(info["ball_xy_m"])
        env.close()
    assert np.array_equal(starts[0], starts[1])


@pytest.mark.parametrize("env_id", list(ENV_IDS))
def test_every_info_value_is_a_numpy_value(env_id: str) -> None:
    """On reset and on every step, each info entry is a NumPy scalar or array (TorchRL registers info by dtype)."""
    env = gym.make(env_id, backend="batched")
    try:
        _, info = env.reset(seed=0)
        infos = [info]
        for _ in range(200):
            infos.append(env.step(env.action_space.sample())[4])
        for entry in infos:
            plain = {k: type(v).__name__ for k, v in entry.items() if not isinstance(v, (np.generic, np.ndarray))}
            assert not plain, plain
    finally:
        env.close()


def test_the_env_checks_an_action_as_the_vector_env_does() -> None:
    """An action of another shape, not real numbers, before reset() or after close() is refused before anything
    moves."""
    from gymnasium.error import ClosedEnvironmentError, ResetNeeded

    env = gym.make("StewartBallBalance-v0", backend="batched").unwrapped
    with pytest.raises(ResetNeeded, match=r"call reset\(\) before step\(\)"):  # the unwrapped env, no OrderEnforcing
        env.step(np.zeros(2, dtype=np.float32))
    env.reset(seed=0)
    t = env.sim.time
    for action, says in ((np.zeros((1, 2)), r"expected an action of shape \(2,\), got shape \(1, 2\)"),
                         (np.zeros(3), r"shape \(3,\)"), (np.zeros(2, complex), "real numbers"),
                         (np.array([True, False]), "real numbers"), ([0.0, float("nan")], "finite")):  # fmt: skip
        with pytest.raises(ValueError, match=says):
            env.step(action)
    assert env.sim.time == t
    env.step([0, 0])  # a list, of ints: real numbers of the right shape
    env.close()
    with pytest.raises(ClosedEnvironmentError, match="closed"):
        env.step(np.zeros(2, dtype=np.float32))
    env.reset(seed=0)  # starts it again
    env.step(np.zeros(2, dtype=np.float32))
    env.close()


def test_mujoco_that_cannot_render_says_so_each_time_without_aborting() -> None:
    """Where MuJoCo cannot start OpenGL, every render says so in one ConfigError; a second try used to abort the
    process (GLFW initialised twice). Where it can render, both give frames."""
    import subprocess
    import sys

    code = ("import gymnasium as gym, stewart_gym\nfrom stewart_gym.errors import ConfigError\n"
            "for k in range(2):\n"
            "    env = gym.make('StewartBallBalance-v0', backend='mujoco', render_mode='rgb_array')\n"
            "    env.reset(seed=0)\n"
            "    try:\n        print('frame', env.render().shape)\n"
            "    except ConfigError as exc:\n        print('refused', str(exc).split(':')[0])\n"
            "    env.close()\n")  # fmt: skip
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    assert len(lines) == 2 and lines[0] == lines[1], proc.stdout
    assert lines[0].startswith("frame (") or lines[0].startswith("refused MuJoCo cannot render on this machine")
