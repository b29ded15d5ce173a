"""The batched vector env (``gym.make_vec(..., vectorization_mode="vector_entry_point")``) and its SB3 VecEnv:
each copy is exactly the env ``gym.make(id, backend="batched")`` gives, autoreset included, and a residual recipe
mixes each copy's action as :class:`~stewart_gym.sb3_models.ResidualAction` does."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import stewart_gym  # noqa: F401  (registers the ids)
from stewart_gym.compiled import AVAILABLE
from stewart_gym.envs.tasks.balance import BalanceTask
from stewart_gym.envs.vector import StewartBallVectorEnv
from stewart_gym.errors import ConfigError
from stewart_gym.sensing_arrays import CameraArray, PanelArray

KWARGS = {"randomize": True, "estimator": "kalman"}


def test_make_vec_returns_the_batched_vector_env() -> None:
    env = gym.make_vec("StewartBallBalance-v0", num_envs=3, vectorization_mode="vector_entry_point", **KWARGS)
    assert isinstance(env, StewartBallVectorEnv)
    obs, info = env.reset(seed=0)
    assert obs.shape == (3, 12) and env.action_space.shape == (3, 2)
    assert info["ball_xy_m"].shape == (3, 2) and info["_ball_xy_m"].all()
    env.close()


@pytest.mark.parametrize("env_id", ["StewartBallBalance-v0", "StewartBallTrack-v0", "StewartBallDisturbance-v0"])
def test_each_copy_is_the_single_batched_env(env_id: str) -> None:
    """Copy i, seeded seed + i, steps exactly as ``gym.make(id, backend="batched")`` with the same seed and
    actions, through an episode's end and its reset in the same step; the copies sense and observe as arrays."""
    vector = assert_copies_are_single_envs(env_id, KWARGS)
    assert isinstance(vector.unwrapped.sensors, PanelArray)


@pytest.mark.parametrize("kwargs", [{"randomize": True, "estimator": "lowpass", "integral": True},
                                    {"randomize": True, "estimator": "kalman", "integral": True, "action_mode": "pose"},
                                    {"randomize": True, "action_mode": "pulse"},
                                    {"randomize": True, "sensor": "pixy2"},
                                    {"randomize": True, "sensor": "camera", "estimator": "kalman"},
                                    {"sensor": "global90", "estimator": "lowpass"},
                                    {"randomize": True, "outside_penalty": 0.2, "charge_until_settled": True},
                                    {"randomize": True, "max_episode_steps": 7},
                                    {"randomize": True, "start_distance": (0.02, 0.09)},
                                    {"randomize": True, "randomization": {"ball_mass_scale": [0.5, 2.0],
                                                                          "servo_trim_us": 30.0,
                                                                          "plate_load_kg": [0.01, 0.08]}}],
                         ids=["lowpass", "pose", "pulse", "pixy2", "cameras", "global90", "charged",
                              "time-limit", "start-distance", "ranges"])  # fmt: skip
def test_each_copy_is_the_single_batched_env_behind_any_observer(kwargs: dict) -> None:
    """The same with the low-pass observer, the error integral, the pose and the pulse actions, with a camera (one
    preset, or a preset drawn per episode; its frames come faster than the steps on ``global90``), all sensed and
    observed as arrays, and with a reward whose count of steps inside is per copy (each copy's task rewards on its
    own); with ``max_episode_steps``, which truncates each copy as ``gym.make``'s truncates one env; with the
    ball's start drawn at a distance (``start_distance``); and with ranges of the user's (``randomization``)."""
    vector = assert_copies_are_single_envs("StewartBallTrack-v0", kwargs)
    assert isinstance(vector.unwrapped.sensors, CameraArray if "sensor" in kwargs else PanelArray)


def assert_copies_are_single_envs(env_id: str, kwargs: dict) -> gym.vector.VectorEnv:
    n, steps = 3, 60
    kwargs = {**kwargs, "episode_s": 0.6}  # 30 steps: every copy ends and resets once
    vector = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    limit = kwargs.pop("max_episode_steps", None)
    singles = [gym.make(env_id, backend="batched", **kwargs) for _ in range(n)]
    if limit is not None:  # Gymnasium's own TimeLimit: importing rl_zoo3 (tests/test_rl_libraries.py) swaps in its
        # own in this process, which marks a time limit in the info and not on an episode that ends anyway
        genuine = next(c for c in gym.wrappers.TimeLimit.__mro__ if c.__module__.startswith("gymnasium."))
        singles = [genuine(env, limit) for env in singles]
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1, 1, (steps, n, vector.single_action_space.shape[0])).astype(np.float32)
    ended = 0
    for k, a in enumerate(actions):
        if k in (0, steps // 2):  # a reset with new seeds, also after a run (each copy's generator is a new one)
            seed = 10 if k == 0 else 70
            obs, info = vector.reset(seed=seed)
            for i, env in enumerate(singles):
                o, inf = env.reset(seed=seed + i)
                np.testing.assert_array_equal(obs[i], o)
                assert_info_row(info, i, inf)
        obs, reward, terminated, truncated, info = vector.step(a)
        for i, env in enumerate(singles):
            o, r, te, tr, inf = env.step(a[i])
            assert (r, te, tr) == (reward[i], terminated[i], truncated[i])
            if te or tr:
                ended += 1
                np.testing.assert_array_equal(info["final_obs"][i], o)
                assert_info_row(info["final_info"], i, inf)
                o, inf = env.reset()
            np.testing.assert_array_equal(obs[i], o)
            assert_info_row(info, i, inf)
    assert ended >= n
    for copy, single in zip(vector.unwrapped.envs, singles):  # each copy's own objects hold its episode too
        single = single.unwrapped
        assert (copy.params.ball, copy.params.servo, copy.params.sensor) == (single.params.ball, single.params.servo,
                                                                             single.params.sensor)  # fmt: skip
        for env in (copy, single):
            assert (env.sim.servo_spec, env.sim.ball_spec) == (env.params.servo, env.params.ball)
            assert env.sensor_model.spec == env.params.sensor
            load, drawn = env.sim.batch.plate_loads[env.sim.index], env.params.plate_load
            assert (load is None) == (drawn is None)
            if drawn is not None:
                assert load[0] == drawn[0] and np.array_equal(load[1], drawn[1])
        assert copy.np_random.bit_generator.state == single.np_random.bit_generator.state
    vector.close()
    return vector


def assert_info_row(batched: dict, i: int, single: dict) -> None:
    """Row ``i`` of a vector env's info holds exactly what the single env's info holds, key by key; the pulses the
    actions map to (one IK pass of them all against one scalar pass per action) to the last bit too where the IK
    pass is compiled (numba), else to rounding."""
    assert set(single) <= set(batched)
    for key, value in single.items():
        if key == "pulse_widths_us":
            np.testing.assert_allclose(batched[key][i], value, rtol=0, atol=0.0 if AVAILABLE else 1e-9)
        else:
            np.testing.assert_array_equal(batched[key][i], value, err_msg=key)
        if not isinstance(value, dict):  # the same NumPy type (a nested entry's values are Gymnasium's)
            assert np.asarray(batched[key][i]).dtype == np.asarray(value).dtype, key
        assert batched[f"_{key}"][i]


class NestedInfoTask(BalanceTask):
    """A task whose info has a nested entry (``tests.envs.test_vector:NestedInfoTask``)."""

    def info(self) -> dict:
        return {"stage": {"level": 2.0, "name": "start"}}


@pytest.mark.parametrize("task", ["balance", "tests.envs.test_vector:NestedInfoTask"])
def test_ended_episodes_are_reported_as_gymnasium_reports_them(task: str) -> None:
    """``info["final_obs"]``, ``info["final_info"]`` and their masks: keys, dtypes, shapes and values as Gymnasium's
    own ``VectorEnv._add_info`` makes them, copy by copy, from the same step's ended copies (a task's nested info
    entry too)."""
    from gymnasium.vector import VectorEnv

    kwargs = {"num_envs": 6, "vectorization_mode": "vector_entry_point", "episode_s": 0.3, "randomize": True,
              "task": task}  # fmt: skip
    ours, reference = (gym.make_vec("StewartBallBalance-v0", **kwargs) for _ in range(2))
    ours.reset(seed=3)
    reference.reset(seed=3)
    actions = np.random.default_rng(2).uniform(-1, 1, (20, 6, 2)).astype(np.float32)
    checked = 0
    for a in actions:
        info = ours.step(a)[4]
        finals = reference.step_arrays(a)[5]
        expected: dict = {}
        for i, (final_obs, final_info) in finals.items():
            expected = VectorEnv._add_info(reference, expected, {"final_obs": final_obs, "final_info": final_info}, i)
        assert set(expected) == {key for key in info if "final" in key}
        for key in ("_final_obs", "_final_info"):
            np.testing.assert_array_equal(info.get(key), expected.get(key))
        if not finals:
            continue
        checked += len(finals)
        for i in range(6):
            assert (info["final_obs"][i] is None) == (expected["final_obs"][i] is None)
            if expected["final_obs"][i] is not None:
                np.testing.assert_array_equal(info["final_obs"][i], expected["final_obs"][i])
        assert list(info["final_info"]) == list(expected["final_info"])
        for key, column in expected["final_info"].items():
            got = info["final_info"][key]
            if isinstance(column, dict):
                assert list(got) == list(column), key
                for inner, values in column.items():
                    assert got[inner].dtype == values.dtype
                    np.testing.assert_array_equal(got[inner], values)
                continue
            assert got.dtype == column.dtype and got.shape == column.shape, key
            np.testing.assert_array_equal(got, column)
    assert checked >= 6  # every copy ended at least once (15-step episodes)


def test_a_nested_task_info_is_batched_as_gymnasium_batches_it() -> None:
    """A task's nested info entry reaches each step's info as Gymnasium's ``_add_info`` makes it from each copy's
    info (a dict of arrays, each with its mask), as in ``SyncVectorEnv``; the other entries stay one array each."""
    from gymnasium.vector import VectorEnv

    kwargs = {"num_envs": 3, "task": "tests.envs.test_vector:NestedInfoTask"}
    ours = gym.make_vec("StewartBallBalance-v0", vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec("StewartBallBalance-v0", vectorization_mode="sync", backend="batched", **kwargs)
    for info in (ours.reset(seed=0)[1], ours.step(np.zeros((3, 2), np.float32))[4]):
        want: dict = {}
        for i in range(3):
            want = VectorEnv._add_info(ours, want, {"stage": {"level": 2.0, "name": "start"}}, i)
        assert list(info["stage"]) == list(want["stage"]) == ["level", "_level", "name", "_name"]
        for key, column in want["stage"].items():
            assert info["stage"][key].dtype == column.dtype, key
            np.testing.assert_array_equal(info["stage"][key], column)
        assert info["_stage"].all() and info["distance_mm"].shape == (3,)
    synced = sync.reset(seed=0)[1]
    assert list(synced["stage"]) == list(info["stage"]) and synced["stage"]["level"].dtype == np.float64
    for env in (ours, sync):
        env.close()


def test_final_info_columns_take_their_type_from_the_values() -> None:
    """A task info column of mixed Python objects (NumPy scalars and arrays among ``None``, say) reaches
    ``final_info`` as Gymnasium's ``_add_info`` makes it from the ended copies' own values."""
    from gymnasium.vector import VectorEnv

    from stewart_gym.envs.vector import Finals

    env = gym.make_vec("StewartBallBalance-v0", num_envs=4, vectorization_mode="vector_entry_point")
    objects = np.empty(2, dtype=object)
    objects[:] = [np.float32(0.5), np.float32(1.5)]
    arrays = np.empty(2, dtype=object)
    arrays[0], arrays[1] = np.array([0.0, 1.0]), np.array([2.0, 3.0])
    info = {"score": objects, "pair": arrays, "flag": np.array([True, False]), "x": np.array([1.0, 2.0]),
            "count": np.array([3, 4]), "xy": np.array([[1.0, 2.0], [3.0, 4.0]], dtype=np.float32)}  # fmt: skip
    finals = Finals(np.array([1, 3]), np.zeros((2, *env.single_observation_space.shape), np.float32), info)
    got = env._final_infos(finals)["final_info"]
    want: dict = {}
    for i, (_, final_info) in finals.items():
        want = VectorEnv._add_info(env, want, final_info, i)
    assert list(got) == list(want)
    for key, column in want.items():
        assert got[key].dtype == column.dtype and got[key].shape == column.shape, key
        for a, b in zip(got[key], column):
            assert type(a) is type(b), key
            np.testing.assert_array_equal(a, b)
    env.close()


def test_bad_arguments_are_one_clear_error() -> None:
    with pytest.raises(ConfigError, match="num_envs"):
        gym.make_vec("StewartBallBalance-v0", num_envs=0, vectorization_mode="vector_entry_point")
    with pytest.raises(ConfigError, match="batched"):
        gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode="vector_entry_point", backend="pybullet")
    with pytest.raises(ConfigError, match="render"):
        gym.make("StewartBallBalance-v0", backend="batched", render_mode="rgb_array")
    from stewart_gym.sb3_vec import BatchedVecEnv

    with pytest.raises(ConfigError, match="env_kwargs.workers: training steps its batched copies in one process"):
        BatchedVecEnv("StewartBallBalance-v0", 4, {"backend": "batched", "workers": 2})
    vector = gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(ConfigError, match=r"got shape \(2, 2\) \(every copy of a vector env resets with these same "
                                          r"options: one value each, not one per copy\)"):  # fmt: skip
        vector.reset(options={"ball_position": [(0.01, 0.02), (0.03, 0.0)]})
    vector.reset(seed=0, options={"ball_position": (0.01, 0.02)})  # one value: every copy's
    np.testing.assert_allclose(vector.unwrapped.sim.ball_xy, [(0.01, 0.02)] * 2)
    vector.close()


def test_the_single_batched_env_passes_the_env_checkers() -> None:
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("StewartBallBalance-v0", backend="batched", **KWARGS)
    assert env.metadata["render_modes"] == []  # the reduced model draws nothing: the render check has no mode to try
    check_env(env.unwrapped)
    sb3_check_env(env.unwrapped)


def test_the_sb3_vec_env_reports_ended_episodes_as_dummy_vec_env_does() -> None:
    from stewart_gym.sb3_vec import BatchedVecEnv

    venv = BatchedVecEnv("StewartBallBalance-v0", 2, {**KWARGS, "episode_s": 0.2, "backend": "batched"})
    venv.seed(3)
    obs = venv.reset()
    assert obs.shape == (2, 12)
    for _ in range(10):
        venv.step_async(np.zeros((2, 2), dtype=np.float32))
        obs, rewards, dones, infos = venv.step_wait()
    assert dones.all()  # 10 steps: the 0.2 s episodes end together
    for info in infos:
        assert info["terminal_observation"].shape == (12,)
        assert info["TimeLimit.truncated"] is True and "is_success" in info
    venv.close()


def test_the_sb3_vec_env_takes_options_a_step_limit_and_reports_reset_infos_as_dummy_vec_env_does() -> None:
    """SB3's ``set_options`` places the balls at the next reset (only that one), as DummyVecEnv's does; the reset
    infos are each copy's; a recipe's ``max_episode_steps`` truncates the copies; another backend, or options that
    differ between copies, are one clear error."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from stewart_gym.sb3_vec import BatchedVecEnv

    kwargs = {**KWARGS, "max_episode_steps": 4, "episode_s": 5.0}
    venv = BatchedVecEnv("StewartBallBalance-v0", 2, {**kwargs, "backend": "batched"})
    dummy = DummyVecEnv([lambda: gym.make("StewartBallBalance-v0", backend="batched", **kwargs)] * 2)
    try:
        for env in (venv, dummy):
            env.seed(5)
            env.set_options({"ball_position": (0.05, -0.02)})
        obs, want = venv.reset(), dummy.reset()
        np.testing.assert_array_equal(obs, want)
        assert [info["ball_xy_m"].tolist() for info in venv.reset_infos] == [[0.05, -0.02]] * 2
        assert [sorted(info) for info in venv.reset_infos] == [sorted(info) for info in dummy.reset_infos]
        assert not np.allclose(venv.reset()[:, :2], obs[:, :2])  # the options were for one reset
        for step in range(1, 5):
            venv.step_async(np.zeros((2, 2), np.float32))
            _, _, dones, infos = venv.step_wait()
            assert dones.all() == (step == 4)
        assert all(info["TimeLimit.truncated"] for info in infos)
        venv.set_options([{"ball_position": (0.05, 0.0)}, {}])
        with pytest.raises(ConfigError, match="one set of options"):
            venv.reset()
    finally:
        venv.close()
        dummy.close()
    with pytest.raises(ConfigError, match="env_kwargs.backend: this VecEnv steps the batched backend"):
        BatchedVecEnv("StewartBallBalance-v0", 2, {"backend": "pybullet"})


def test_a_residual_copy_moves_as_the_residual_wrapper() -> None:
    """The SB3 VecEnv's residual mixing equals ResidualAction around the single batched env."""
    from stewart_gym.sb3_models import ResidualAction
    from stewart_gym.sb3_vec import BatchedVecEnv

    residual = {"base": "lqr-pid", "scale": 0.3}
    venv = BatchedVecEnv("StewartBallBalance-v0", 1, {**KWARGS, "backend": "batched"}, residual)
    venv.seed(5)
    obs = venv.reset()
    single = ResidualAction(gym.make("StewartBallBalance-v0", backend="batched", **KWARGS), residual)
    o, _ = single.reset(seed=5)
    np.testing.assert_array_equal(obs[0], o)
    rng = np.random.default_rng(2)
    for _ in range(40):
        a = rng.uniform(-1, 1, 2).astype(np.float32)
        venv.step_async(a[None])
        obs, _, _, _ = venv.step_wait()
        o, *_ = single.step(a)
        np.testing.assert_array_equal(obs[0], o)


def test_a_task_object_gives_each_copy_its_own() -> None:
    """``task=`` an object: each copy draws its own episodes with a copy of it, as single envs each given their own."""
    from stewart_gym.envs.tasks.track import TrackTask

    vector = gym.make_vec("StewartBallTrack-v0", num_envs=3, vectorization_mode="vector_entry_point",
                          task=TrackTask(trajectory="mixed"))  # fmt: skip
    singles = [gym.make("StewartBallTrack-v0", backend="batched", task=TrackTask(trajectory="mixed")) for _ in range(3)]
    assert len({id(env.task) for env in vector.unwrapped.envs}) == 3
    obs, info = vector.reset(seed=4)
    for i, env in enumerate(singles):
        o, inf = env.reset(seed=4 + i)
        np.testing.assert_array_equal(obs[i], o)
        assert_info_row(info, i, inf)
    assert len({tuple(row) for row in info["target_xy_m"].tolist()}) == 3  # each copy's own drawn path
    vector.close()


def test_copies_whose_settings_differ_draw_as_their_own_envs() -> None:
    """A curriculum sets some copies' start distance or randomisation (SB3's ``set_attr``): each copy's episode is
    then its own env's with those settings, seeded alike, whatever the others' settings (the copies that draw
    together share theirs)."""
    from stewart_gym.sb3_vec import BatchedVecEnv

    venv = BatchedVecEnv("StewartBallBalance-v0", 5, {"randomize": True})
    far = {"start_distance": (0.08, 0.09)}
    settings = [{}, {"randomize": False}, far, far, {}]
    for i, extra in enumerate(settings):
        for key, value in extra.items():
            venv.set_attr(key, value, indices=[i])
    venv.seed(5)
    venv.reset()
    for i, extra in enumerate(settings):
        env = gym.make("StewartBallBalance-v0", backend="batched", **{"randomize": True, **extra})
        _, info = env.reset(seed=5 + i)
        np.testing.assert_array_equal(venv.reset_infos[i]["ball_xy_m"], info["ball_xy_m"])
        copy, single = venv.get_attr("params", [i])[0], env.unwrapped.params
        assert (copy.ball, copy.servo, copy.sensor, copy.plate_friction) == (single.ball, single.servo, single.sensor,
                                                                             single.plate_friction), i  # fmt: skip
        env.close()
    distances = [float(np.hypot(*venv.reset_infos[i]["ball_xy_m"])) for i in range(5)]
    assert all(0.08 <= d <= 0.09 for d in distances[2:4]) and venv.get_attr("params", [1])[0].plate_load is None
    venv.close()


def test_a_copy_refuses_a_deepcopy_that_would_share_its_platform() -> None:
    """A copy runs on the vector env's shared simulator: ``copy.deepcopy`` of it is a clear ``TypeError``, and the
    vector env's platforms are left as they were."""
    import copy

    vector = gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode="vector_entry_point")
    vector.reset(seed=0)
    vector.step(np.full((2, 2), 0.3, dtype=np.float32))
    sim = vector.unwrapped.sim
    before = sim.ball_xy.copy(), sim.platform_times()
    with pytest.raises(TypeError, match="backend object"):
        copy.deepcopy(vector.unwrapped.envs[1])
    np.testing.assert_array_equal(sim.ball_xy, before[0])
    np.testing.assert_array_equal(sim.platform_times(), before[1])
    vector.close()


def test_a_step_limit_counts_the_step_whose_physics_blew_up() -> None:
    """``max_episode_steps`` ends a copy whose physics blows up on the limit's step as truncated too, as Gymnasium's
    TimeLimit counts every step (the env's own count of steps leaves that one out)."""
    limit = 3
    vector = gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode="vector_entry_point",
                          max_episode_steps=limit, **KWARGS)  # fmt: skip
    genuine = next(c for c in gym.wrappers.TimeLimit.__mro__ if c.__module__.startswith("gymnasium."))
    single = genuine(gym.make("StewartBallBalance-v0", backend="batched", **KWARGS), limit)
    vector.reset(seed=4)
    single.reset(seed=5)
    action = np.zeros(2, dtype=np.float32)
    for _ in range(limit - 1):
        vector.step(np.stack([action, action]))
        single.step(action)
    vector.unwrapped.envs[1].sim.place_ball((math.nan, 0.0))
    single.unwrapped.sim.place_ball((math.nan, 0.0))
    _, _, terminated, truncated, info = vector.step(np.stack([action, action]))
    _, _, te, tr, single_info = single.step(action)
    assert single_info["physics_error"] and (te, tr) == (True, True)
    assert info["final_info"]["physics_error"][1] and (terminated[1], truncated[1]) == (te, tr)
    assert truncated[0] and not terminated[0]
    vector.close()


def test_a_copy_whose_physics_blows_up_ends_alone() -> None:
    """A copy whose ball goes non-finite ends with ``physics_error`` and the reward a single env gives then; the
    other copies step on exactly as single envs."""
    vector = gym.make_vec("StewartBallBalance-v0", num_envs=2, vectorization_mode="vector_entry_point", **KWARGS)
    single, blown = (gym.make("StewartBallBalance-v0", backend="batched", **KWARGS) for _ in range(2))
    vector.reset(seed=4)
    single.reset(seed=4)
    blown.reset(seed=5)
    action = np.array([0.1, -0.2], dtype=np.float32)
    vector.unwrapped.envs[1].sim.place_ball((math.nan, 0.0))
    blown.unwrapped.sim.place_ball((math.nan, 0.0))
    obs, reward, terminated, _, info = vector.step(np.stack([action, action]))
    o, r, te, _, _ = single.step(action)
    _, r_blown, te_blown, _, info_blown = blown.step(action)
    assert terminated[1] and info["final_info"]["physics_error"][1] and not te and not terminated[0]
    assert te_blown and info_blown["physics_error"] and reward[1] == r_blown < -40 and reward[0] == r
    np.testing.assert_array_equal(obs[0], o)
    assert np.isfinite(obs).all()  # the ended copy was reset
    vector.close()


def test_a_sensor_with_no_array_class_is_refused_by_the_batched_vector_env() -> None:
    """A sensor spec of its own (``docs/src/guides/add-a-sensor.md``) has no array class here: one error, not a
    touch panel in its place."""
    from types import SimpleNamespace

    from stewart_gym.envs.vector import sensor_array
    from stewart_gym.errors import ConfigError

    class GridSensorSpec:
        pass

    with pytest.raises(ConfigError, match="holds touch panels and cameras as arrays, not a GridSensorSpec"):
        sensor_array(SimpleNamespace(nominal_sensor=GridSensorSpec()), 4, 0.02)
