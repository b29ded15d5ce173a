"""The Gymnasium environments: API contracts, determinism, termination, randomisation and ball physics."""


from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from conftest import uniform_draw
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.vec_env import SubprocVecEnv

import stewart_gym
from stewart_gym.actions import ACTION_MODES
from stewart_gym.envs.ball_env import StewartBallEnv
from stewart_gym.envs.tasks.disturbance import DisturbanceTask
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.sim import BallSpec
from stewart_gym.sim.engines import BACKEND_NAMES, make_backend

ENV_IDS = sorted(stewart_gym.ENV_IDS)


CASES = [(env_id, mode) for env_id in ENV_IDS for mode in ACTION_MODES]
#: Every env test that touches physics runs on every engine.
on_every_backend = pytest.mark.parametrize("backend", BACKEND_NAMES)


@on_every_backend
@pytest.mark.parametrize(("env_id", "mode"), CASES)
def test_env_checkers(env_id: str, mode: str, backend: str) -> None:
    env = gym.make(env_id, action_mode=mode, randomize=True, backend=backend)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped)
        assert env.action_space.dtype == np.float32 and np.all(env.action_space.low == -1)
        assert env.observation_space.shape == (10 + (2 if mode == "tilt" else 6),)
        assert np.all(np.isfinite(env.observation_space.low)) and np.all(np.isfinite(env.observation_space.high))
    finally:
        env.close()


@on_every_backend
@pytest.mark.parametrize(("env_id", "mode"), CASES)
def test_reset_is_deterministic_under_randomization(env_id: str, mode: str, backend: str) -> None:
    def rollout() -> tuple[np.ndarray, list[float]]:
        env = gym.make(env_id, action_mode=mode, randomize=True, backend=backend)
        obs, _ = env.reset(seed=123)
        rng = np.random.default_rng(0)
        out, rewards = [obs], []
        for _ in range(40):
            obs, r, term, trunc, info = env.step(rng.uniform(-0.5, 0.5, env.action_space.shape).astype(np.float32))
            out.append(obs)
            rewards.append(r)
            if term:
                break
        env.close()
        return np.array(out), rewards

    a, b = rollout(), rollout()
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]
    env = gym.make(env_id, action_mode=mode, randomize=True, backend=backend)
    other, _ = env.reset(seed=124)
    env.close()
    assert not np.array_equal(other, a[0][0])


def test_registration_without_import_prefix_and_metadata() -> None:
    env = gym.make("stewart_gym:StewartBallBalance-v0", render_mode="rgb_array")
    try:
        assert env.unwrapped.episode_steps == 500 and env.spec.kwargs["episode_s"] == 10.0
        assert env.metadata["render_fps"] == round(1 / env.unwrapped.sim.dt) == 50
        env.reset(seed=0)
        frame = env.render()
        assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    finally:
        env.close()
    with pytest.raises(ValueError, match="action mode"):
        gym.make("StewartBallBalance-v0", action_mode="joystick")


@on_every_backend
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_pickle_and_double_close(env_id: str, backend: str) -> None:
    env = gym.make(env_id, action_mode="pose", randomize=True, backend=backend)
    env.reset(seed=1)
    clone = pickle.loads(pickle.dumps(env))
    clone.reset(seed=1)
    assert clone.unwrapped.action_mode == "pose" and clone.unwrapped.randomize
    assert type(clone.unwrapped.sim) is type(env.unwrapped.sim)
    for e in (env, clone):
        e.close()
        e.close()


@pytest.mark.slow
def test_make_vec_and_subproc_vec_env() -> None:
    # A process that has used PyBullet must not fork workers: use the spawn context.
    for mode, kwargs in (("sync", {}), ("async", {"context": "spawn"})):
        venv = gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode=mode, vector_kwargs=kwargs)
        obs, _ = venv.reset(seed=0)
        obs, rew, term, trunc, info = venv.step(venv.action_space.sample())
        assert obs.shape == (2, 12) and rew.shape == (2,)
        venv.close()
    # spawned workers have not imported stewart_gym: the "stewart_gym:" prefix imports it
    venv = SubprocVecEnv([lambda: gym.make("stewart_gym:StewartBallTrack-v0") for _ in range(2)], start_method="spawn")
    try:
        venv.seed(0)
        obs = venv.reset()
        obs, rew, done, info = venv.step(np.zeros((2, 2), dtype=np.float32))
        assert obs.shape == (2, 12) and "pulse_widths_us" in info[0]
    finally:
        venv.close()


@on_every_backend
def test_success_needs_a_full_second_inside_the_radius(backend: str) -> None:
    env = gym.make("StewartBallBalance-v0", backend=backend)
    env.reset(seed=0, options={"ball_position": (0.0, 0.0), "ball_velocity": (0.0, 0.0)})
    flags = [env.step(np.zeros(2, dtype=np.float32))[4]["is_success"] for _ in range(60)]
    env.close()
    assert not any(flags[:49]) and all(flags[50:])


@on_every_backend
def test_ball_leaving_the_plate_terminates_with_penalty(backend: str) -> None:
    env = gym.make("StewartBallBalance-v0", backend=backend)
    env.reset(seed=0, options={"ball_position": (0.13, 0.0), "ball_velocity": (0.4, 0.0)})
    for _ in range(100):
        _, reward, terminated, truncated, info = env.step(np.array([0.0, 0.5], dtype=np.float32))
        if terminated:
            break
    env.close()
    assert terminated and not truncated and reward < -40 and not info["is_success"]


def test_physics_blow_up_ends_the_episode_without_nan(monkeypatch: pytest.MonkeyPatch) -> None:
    env = gym.make("StewartBallBalance-v0")
    obs, _ = env.reset(seed=0)
    sim = env.unwrapped.sim
    monkeypatch.setattr(sim, "ball_position", lambda: (math.nan, math.nan, math.nan))
    obs, reward, terminated, _, info = env.step(np.zeros(2, dtype=np.float32))
    env.close()
    assert terminated and info["physics_error"] and np.all(np.isfinite(obs)) and math.isfinite(reward)


@on_every_backend
def test_info_reports_the_pulses_sent_and_the_sim_obeys(backend: str) -> None:
    env = gym.make("StewartBallBalance-v0", backend=backend)
    env.reset(seed=0)
    for _ in range(5):
        _, _, _, _, info = env.step(np.array([0.5, -0.3], dtype=np.float32))
    sim = env.unwrapped.sim
    pose = env.unwrapped.mapper.pose(np.array([0.5, -0.3]))
    expected = sim.calibration.pulse_widths(inverse_kinematics(sim.geometry, pose).servo_angles)
    assert info["pulse_widths_us"] == pytest.approx(expected)
    assert sim.held_pulses() == pytest.approx(expected, abs=0.13)  # quantised to 0.25 µs
    env.close()


@pytest.mark.slow
@on_every_backend
def test_100k_random_steps_all_modes_no_nan(backend: str) -> None:
    """100,000 random actions over every env id and action mode, with randomisation: every observation, reward
    and pulse finite, no physics error. The batched backend takes them as 128 copies of its vector env, which
    steps each copy exactly as ``gym.make(id, backend="batched")`` would (``tests/envs/test_vector.py``)."""
    rng = np.random.default_rng(7)
    total = 0
    if backend == "batched":
        copies = 128
        for env_id, mode in CASES:
            env = gym.make_vec(env_id, num_envs=copies, vectorization_mode="vector_entry_point", action_mode=mode,
                               randomize=True)  # fmt: skip
            env.reset(seed=int(rng.integers(1000)))
            for _ in range(100_000 // len(CASES) // copies + 1):
                obs, reward, terminated, truncated, info = env.step(env.action_space.sample())  # resets as it ends
                assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward)) and not info["physics_error"].any()
                assert np.all(np.isfinite(info["pulse_widths_us"]))
                total += copies
            env.close()
        assert total >= 100_000
        return
    for env_id, mode in CASES:
        env = gym.make(env_id, action_mode=mode, randomize=True, backend=backend)
        obs, _ = env.reset(seed=int(rng.integers(1000)))
        for _ in range(100_000 // len(CASES) + 1):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert np.all(np.isfinite(obs)) and math.isfinite(reward) and not info["physics_error"]
            assert np.all(np.isfinite(info["pulse_widths_us"]))
            total += 1
            if terminated or truncated:
                obs, _ = env.reset()
        env.close()
    assert total >= 100_000


@on_every_backend
@pytest.mark.parametrize(("hollow", "factor"), [(False, 5 / 7), (True, 3 / 5)])
@pytest.mark.parametrize("tilt_deg", [3.0, 6.0])
def test_ball_acceleration_matches_rolling_theory(hollow: bool, factor: float, tilt_deg: float, backend: str) -> None:
    """On a plate held at pitch θ, a rolling ball accelerates at (5/7) g sin θ (solid) or (3/5) g sin θ (hollow)."""
    spec = BallSpec(radius=0.02, mass=0.0027, hollow=True) if hollow else BallSpec()
    with make_backend(backend, "servo-hexapod", ball=True, ball_spec=spec) as sim:
        pose = np.array([0, 0, 0, 0, math.radians(tilt_deg), 0])
        sim.command(sim.calibration.pulse_widths(inverse_kinematics(sim.geometry, pose).servo_angles))
        for _ in range(50):
            sim.step()
        sim.place_ball(np.array([-0.08, 0.0]))
        ts, xs = [], []
        for _ in range(20):
            sim.step()
            ts.append(sim.time)
            xs.append(sim.ball_state()[0][0])
    accel = 2 * np.polyfit(ts, xs, 2)[0]  # along the plate's x axis, downhill for positive pitch
    theory = factor * 9.80665 * math.sin(math.radians(tilt_deg))
    print(f"{backend} {'hollow' if hollow else 'solid'} {tilt_deg}°: {accel:.4f} m/s² vs {theory:.4f} "
          f"({accel / theory:.4f})")  # fmt: skip
    assert accel == pytest.approx(theory, rel=0.03)


def test_env_class_docstring_has_mujoco_sections() -> None:
    doc = StewartBallEnv.__doc__
    for section in ("## Description", "## Action Space", "## Observation Space", "## Rewards", "## Starting State",
                    "## Episode End", "## Arguments", "## Version History"):  # fmt: skip
        assert section in doc


@pytest.mark.parametrize("options,match", [
    ({"ball_position": (math.nan, 0.0)}, "finite"),
    ({"ball_position": (0.0, math.inf)}, "finite"),
    ({"ball_position": (0.01,)}, "two numbers"),
    ({"ball_position": (0.01, 0.0, 0.0)}, "two numbers"),
    ({"ball_position": "centre"}, "two numbers"),
    ({"ball_position": (0.2, 0.0)}, "off the plate"),
    ({"ball_position": (0.0, -0.145)}, "off the plate"),
    ({"ball_velocity": (math.nan, 0.0)}, "finite"),
    ({"ball_velocity": (5.0, 0.0)}, "faster"),
    ({"ball_positon": (0.0, 0.0)}, "unknown reset option"),
])  # fmt: skip
def test_reset_options_are_checked(options: dict, match: str) -> None:
    from stewart_gym.errors import ConfigError

    env = gym.make("StewartBallBalance-v0")
    try:
        with pytest.raises(ConfigError, match=match):
            env.reset(seed=0, options=options)
        obs, _ = env.reset(seed=0, options={"ball_position": (0.13, -0.13), "ball_velocity": (0.1, 0.0)})
        assert env.observation_space.contains(obs)  # a valid start near the edge still works after a refusal
    finally:
        env.close()


@pytest.mark.parametrize("env_id,kwargs,match", [
    ("StewartBallDisturbance-v0", {"last_push_s": math.inf}, "last_push_s must be a finite number"),
    ("StewartBallDisturbance-v0", {"last_push_s": "7"}, "last_push_s must be a number"),
    ("StewartBallDisturbance-v0", {"last_push_s": True}, "last_push_s must be a number"),
    ("StewartBallDisturbance-v0", {"last_push_s": -1.0}, "last_push_s must be a finite number in"),
    ("StewartBallDisturbance-v0", {"push_impulse": (math.nan, math.nan)}, r"push_impulse\[0\]"),
    ("StewartBallDisturbance-v0", {"push_impulse": (0.01, 0.003)}, "low ≤ high"),
    ("StewartBallDisturbance-v0", {"push_impulse": 0.005}, r"push_impulse must be a \(low, high\) pair"),
    ("StewartBallDisturbance-v0", {"push_impulse": (0.003,)}, r"push_impulse must be a \(low, high\) pair"),
    ("StewartBallDisturbance-v0", {"push_impulse": "ab"}, r"push_impulse must be a \(low, high\) pair"),
    ("StewartBallDisturbance-v0", {"push_impulse": (-1.0, -0.5)}, r"push_impulse\[0\]"),
    ("StewartBallDisturbance-v0", {"push_impulse": (1e6, 1e6)}, r"push_impulse\[0\] must be a finite number in \[0, 1\]"),
    ("StewartBallDisturbance-v0", {"load_kg": (1, 2, 3)}, r"load_kg must be a \(low, high\) pair"),
    ("StewartBallDisturbance-v0", {"load_kg": (-50.0, -50.0)}, r"load_kg\[0\]"),
    ("StewartBallDisturbance-v0", {"load_time_s": (math.inf, math.inf)}, r"load_time_s\[0\]"),
    ("StewartBallDisturbance-v0", {"load_radius": math.nan}, "load_radius"),
    ("StewartBallDisturbance-v0", {"load_radius": 10.0}, r"load_radius must be a finite number in \[0, 0.15\]"),
    ("StewartBallTrack-v0", {"success_window_s": 1e6}, "longer than the episode"),
    ("StewartBallBalance-v0", {"success_window_s": 11.0}, "longer than the episode"),
    ("StewartBallTrack-v0", {"charge_until_settled": "yes"}, "charge_until_settled must be true or false"),
    ("StewartBallBalance-v0", {"success_window_s": 1.0, "episode_s": 0.5}, "longer than the episode"),
    ("StewartBallBalance-v0", {"task": DisturbanceTask(success_window_s=20.0)}, "the task's success_window_s"),
    ("StewartBallDisturbance-v0", {"start_distance": {0.01, 0.02}}, r"start_distance must be a \(low, high\) pair"),
])  # fmt: skip
def test_task_keywords_are_checked_as_the_env_is_made(env_id: str, kwargs: dict, match: str) -> None:
    """Each task keyword is checked as the env is made, naming it: a push or load range is a (low, high) pair of
    finite numbers in its range, the last push within an hour, the load within the plate, a success window no
    longer than the episode. (An infinite last push used to hang the first reset.)"""
    from stewart_gym.errors import ConfigError

    with pytest.raises(ConfigError, match=match):
        gym.make(env_id, backend="batched", **kwargs)


def test_the_default_success_window_is_a_second_or_the_whole_of_a_shorter_episode() -> None:
    assert gym.make("StewartBallBalance-v0", backend="batched").unwrapped.success_steps == 50
    short = gym.make("StewartBallBalance-v0", backend="batched", episode_s=0.5).unwrapped
    assert short.success_steps == short.episode_steps == 25


def test_a_task_switch_takes_a_numpy_bool_and_the_default_load_stays_on_a_small_plate() -> None:
    env = gym.make("StewartBallTrack-v0", backend="batched", charge_until_settled=np.True_)
    assert env.unwrapped.task.charge_until_settled is True
    env = gym.make("StewartBallDisturbance-v0", backend="batched")
    assert env.unwrapped.task.load_radius == 0.10 and env.unwrapped.task.push_impulse == (0.003, 0.010)
    assert DisturbanceTask(plate_half=0.05).load_radius == 0.05


def test_mujoco_blowing_up_is_a_physics_error_not_a_ball_put_back() -> None:
    """MuJoCo starts its state again where it finds the simulation unstable; the env reports that step as a physics
    error (the ball NaN, the episode terminated), as PyBullet's NaN is, not as a ball back at the centre."""
    env = gym.make("StewartBallBalance-v0", backend="mujoco")
    try:
        env.reset(seed=0)
        sim = env.unwrapped.sim
        assert not sim.blew_up()
        sim.data.qvel[:] = 1e200  # (as a huge push would leave it)
        _, _, terminated, _, info = env.step(np.zeros(2, dtype=np.float32))
        assert terminated and info["physics_error"] and np.isnan(info["ball_xy_m"]).all()
        env.reset(seed=1)
        assert not sim.blew_up() and np.isfinite(sim.ball_position()).all()
    finally:
        env.close()


def test_start_distance_draws_the_start_on_a_ring_and_is_checked() -> None:
    """``start_distance=(low, high)`` starts the ball at a distance in that range from the centre, in varied
    directions; without it the start is the usual seeded draw; bad ranges are refused naming the keyword."""
    from stewart_gym.errors import ConfigError

    env = gym.make("StewartBallBalance-v0", start_distance=(0.05, 0.11))
    plain, again = gym.make("StewartBallBalance-v0"), gym.make("StewartBallBalance-v0")
    try:
        starts = np.array([env.reset(seed=s)[1]["ball_xy_m"] for s in range(30)])
        distance = np.linalg.norm(starts, axis=1)
        assert np.all((distance >= 0.05 - 1e-9) & (distance <= 0.11 + 1e-9)), distance
        assert np.ptp(np.arctan2(starts[:, 1], starts[:, 0])) > 4.0  # directions all round
        assert np.allclose(plain.reset(seed=3)[1]["ball_xy_m"], again.reset(seed=3)[1]["ball_xy_m"])
        for bad in ((0.11, 0.05), (-0.01, 0.05), (0.0, math.nan), (0.05, 0.2), (0.05,), "far"):
            with pytest.raises(ConfigError, match="start_distance"):
                gym.make("StewartBallBalance-v0", start_distance=bad)
    finally:
        for e in (env, plain, again):
            e.close()


def _trajectory_kind(env: gym.Env) -> str:
    """Which trajectory the episode's target follows, judged from its path over 8 s."""
    path = np.array([env.unwrapped.task.target(t)[0] for t in np.arange(0.0, 8.0, 0.1)])
    radius = np.linalg.norm(path, axis=1)
    if np.ptp(radius) < 1e-6:
        return "circle"
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    return "waypoints" if np.mean(steps < 1e-9) > 0.5 else "figure8"  # holds 2 s of every 3


def test_mixed_trajectory_draws_each_kind_and_is_seeded() -> None:
    kinds = {}
    env = gym.make("StewartBallTrack-v0", trajectory="mixed")
    for seed in range(30):
        env.reset(seed=seed)
        kinds[seed] = _trajectory_kind(env)
        assert env.unwrapped.task.current_trajectory == kinds[seed]  # what deploy prints
    assert set(kinds.values()) == {"circle", "figure8", "waypoints"}
    for seed in (0, 1, 2):  # the same seed draws the same trajectory
        env.reset(seed=seed)
        assert _trajectory_kind(env) == kinds[seed]
    for name in ("circle", "figure8", "waypoints"):  # the classifier itself
        single = gym.make("StewartBallTrack-v0", trajectory=name)
        single.reset(seed=3)
        assert _trajectory_kind(single) == name
    with pytest.raises(ValueError, match="mixed"):
        gym.make("StewartBallTrack-v0", trajectory="spiral")


def test_the_envs_that_take_a_trajectory_are_those_whose_task_follows_a_moving_target() -> None:
    """``trajectory_env_ids`` (what ``evaluate --trajectory`` accepts) is read from the registered tasks: the
    track env's target moves along what it is given; the others refuse a trajectory."""
    from stewart_gym.envs import ENV_IDS, trajectory_env_ids
    from stewart_gym.envs.targets import Fixed
    from stewart_gym.envs.task import load_task
    from stewart_gym.errors import ConfigError

    moving = trajectory_env_ids()
    assert moving == ("StewartBallTrack-v0",)
    for env_id, (path, _) in ENV_IDS.items():
        if env_id in moving:
            assert not isinstance(load_task(path, trajectory="waypoints").target, Fixed)
        else:
            with pytest.raises(ConfigError):
                load_task(path, trajectory="waypoints")


def test_rendered_frames_mark_the_target_on_the_plate() -> None:
    """A red disc on the plate where the target is: it moves with a moving target."""
    import gymnasium as gym

    env = gym.make("StewartBallTrack-v0", render_mode="rgb_array", trajectory="circle")
    env.reset(seed=0)

    def red_centre() -> np.ndarray:
        frame = env.render().astype(int)
        red = (frame[..., 0] > 180) & (frame[..., 1] < 60) & (frame[..., 2] < 60)
        assert red.sum() > 10
        return np.argwhere(red).mean(axis=0)

    first = red_centre()
    for _ in range(50):  # a second along the circle
        env.step(np.zeros(2, dtype=np.float32))
    assert np.linalg.norm(red_centre() - first) > 5  # pixels
    env.close()


def _reference_start(rng: np.random.Generator, env: StewartBallEnv, options: dict) -> tuple[np.ndarray, np.ndarray]:
    """The ball's start as one generator call per draw (``uniform_draw``: NumPy's ``rng.uniform`` up to its
    rounding), independently of ``StewartBallEnv.ball_starts``."""
    if "ball_position" in options:
        xy = np.asarray(options["ball_position"], dtype=float)
    elif env.start_distance is not None:
        radius, ang = uniform_draw(rng, *env.start_distance), uniform_draw(rng, 0, 2 * math.pi)
        xy = np.array([radius * math.cos(ang), radius * math.sin(ang)])
    else:
        square = np.array([uniform_draw(rng, -1.0, 1.0), uniform_draw(rng, -1.0, 1.0)])
        xy = square * env.START_FRACTION * np.array(env.plate_half_extent)
    if "ball_velocity" in options:
        vel = np.asarray(options["ball_velocity"], dtype=float)
    else:
        ang, speed = uniform_draw(rng, 0, 2 * math.pi), uniform_draw(rng, 0, 0.1)
        vel = np.array([speed * math.cos(ang), speed * math.sin(ang)])
    return xy, vel


@pytest.mark.parametrize("start_distance", [None, (0.02, 0.09)])
@pytest.mark.parametrize("options", [None, {"ball_position": (0.01, -0.02)}, {"ball_velocity": (0.05, 0.0)}])
def test_the_start_draws_are_one_generator_call_per_number(start_distance: tuple | None, options: dict | None) -> None:
    """The start's draws, taken in one generator call, are to the last bit those of one call per number
    (``uniform_draw``), with or without ``start_distance`` and either option, and use as many numbers."""
    from gymnasium.utils import seeding

    env = StewartBallEnv(backend="batched", start_distance=start_distance)
    try:
        for seed in range(20):
            env.reset(seed=seed, options=options)
            rng = seeding.np_random(seed)[0]
            xy, vel = _reference_start(rng, env, options or {})
            position, velocity = env.sim.ball_state()
            assert position[:2].tolist() == xy.tolist() and velocity[:2].tolist() == vel.tolist()
            xy, vel = env.draw_episode(seed=seed, options=options)  # the draws alone
            reference = seeding.np_random(seed)[0]
            want = _reference_start(reference, env, options or {})
            assert [xy.tolist(), vel.tolist()] == [v.tolist() for v in want]
            assert env.np_random.random() == reference.random()  # as many numbers used
    finally:
        env.close()
