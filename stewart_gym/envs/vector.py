"""The batched vector env: N copies of an env id whose platforms advance together in one
:class:`~stewart_gym.sim.batched.BatchedSim`, as Gymnasium's ``vector_entry_point``.

``gym.make_vec("StewartBallBalance-v0", num_envs=1024, vectorization_mode="vector_entry_point")`` returns it.
Each copy is the same :class:`~stewart_gym.envs.ball_env.StewartBallEnv` as ``gym.make`` gives, with its task,
sensor, observer, action mode and randomisation, on a :class:`~stewart_gym.sim.batched.BatchedPlatform`, and
steps exactly as that env would alone. Every step, the shared simulator advances every platform at once, the
copies' actions are mapped in one IK pass, their sensors (touch panels or cameras) and observers are rows of
:class:`~stewart_gym.sensing_arrays.PanelArray` or :class:`~stewart_gym.sensing_arrays.CameraArray` and
:class:`~stewart_gym.sensing_arrays.ObserverArray`, advanced together, and every copy's step ends as arrays
(:class:`~stewart_gym.envs.copies.CopySteps`), its task's target, reward and info included
(:class:`~stewart_gym.envs.task_array.TaskArray`: as arrays where the task uses the built-in hooks, else copy by
copy). An episode that ends is reset in the same step (Gymnasium's ``AutoresetMode.SAME_STEP``): ``info["final_obs"]``
and ``info["final_info"]`` hold its last observation and info. The copies reset together: each draws its episode
from its own generator, as its env's reset would, and their physics, sensors, observers, first observations and
infos are then set as arrays.
"""

from __future__ import annotations

import copy
import math
import reprlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.error import ClosedEnvironmentError, ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from stewart_gym.camera import CameraSpec
from stewart_gym.envs.arguments import check_engine_arguments
from stewart_gym.envs.ball_env import StewartBallEnv, check_ball_geometry
from stewart_gym.envs.copies import CopySteps
from stewart_gym.errors import ConfigError
from stewart_gym.sensing import TouchPanelSpec
from stewart_gym.sensing_arrays import CameraArray, CameraRow, ObserverArray, ObserverRow, PanelArray, PanelRow
from stewart_gym.sim.batched import BatchedPlatform, BatchedSim
from stewart_gym.sim.engines import PYBULLET_ENV_HZ, multiple_at_least

__all__ = ["MAX_NUM_ENVS", "ArrayVectorEnv", "Finals", "StewartBallVectorEnv", "check_num_envs", "copy_seeds",
           "whole_number"]

#: The most copies one vector env holds.
MAX_NUM_ENVS = 1_000_000


def whole_number(value: object, low: int, high: float = math.inf) -> bool:
    """Whether ``value`` is a whole number (a Python or NumPy integer, not a bool) from ``low`` to ``high``."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)) and low <= value <= high


def check_num_envs(num_envs: object) -> None:
    """Raise :class:`ConfigError` unless ``num_envs`` is a whole number from 1 to :data:`MAX_NUM_ENVS`."""
    if not whole_number(num_envs, 1, MAX_NUM_ENVS):
        raise ConfigError(f"num_envs must be a whole number from 1 to {MAX_NUM_ENVS:,}, got {num_envs!r}")


def copy_seeds(seed: object, num_envs: int) -> list[int | None]:
    """Each copy's seed from a vector env's ``reset(seed=…)``: None (none), a whole number s (copy i: s + i), or a
    sequence of ``num_envs`` whole numbers or Nones; :class:`ConfigError` otherwise."""
    if isinstance(seed, np.ndarray) and seed.ndim == 0:
        seed = seed.item()
    if seed is None:
        return [None] * num_envs
    if whole_number(seed, 0):
        return [int(seed) + i for i in range(num_envs)]
    if isinstance(seed, (list, tuple, np.ndarray)) and len(seed) == num_envs and all(
            s is None or whole_number(s, 0) for s in seed):  # fmt: skip
        return [None if s is None else int(s) for s in seed]
    raise ConfigError(f"reset: seed must be a whole number ≥ 0, None, or a list of {num_envs:,} of them (one per "
                      f"copy), got {reprlib.repr(seed)}")  # fmt: skip


@dataclass
class Finals:
    """The copies whose episode ended in a step, as they were before their reset: their rows, their last
    observations (a row each) and their last infos (one array per key, a row each)."""

    rows: np.ndarray
    observations: np.ndarray
    info: dict[str, np.ndarray]

    @classmethod
    def of(cls, rows: np.ndarray, observations: np.ndarray, info: dict[str, np.ndarray]) -> Finals:
        """Copies of ``rows`` of a step's ``observations`` and ``info`` (before the rows are reset)."""
        return cls(rows.copy(), observations[rows], {key: value[rows] for key, value in info.items()})

    @classmethod
    def joined(cls, parts: Sequence[Finals], starts: Sequence[int]) -> Finals:
        """Shares' finals as one, share k's rows offset by ``starts[k]``."""
        return cls(np.concatenate([part.rows + start for part, start in zip(parts, starts)]),
                   np.concatenate([part.observations for part in parts]),
                   {key: np.concatenate([part.info[key] for part in parts]) for key in parts[0].info})  # fmt: skip

    def __len__(self) -> int:
        return len(self.rows)

    def items(self) -> Iterator[tuple[int, tuple[np.ndarray, dict[str, Any]]]]:
        """Each ended copy's (row, (last observation, last info)), the info as one env's step gives it."""
        keys = list(self.info)
        for j, i in enumerate(self.rows.tolist()):
            yield i, (self.observations[j], {key: self.info[key][j] for key in keys})


class ArrayVectorEnv(VectorEnv):
    """A vector env that finds its copies' resets and steps as arrays (:meth:`reset_arrays`, :meth:`step_arrays`)
    and batches their infos here in Gymnasium's ``SAME_STEP`` autoreset form: each key a row per copy with
    ``_key``, the copies that have it (all), and ``final_obs`` and ``final_info`` where a copy's episode ended, as
    Gymnasium's ``_add_info`` makes them."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    #: whether :meth:`reset_arrays` has run since the env was made: a step before it is refused
    ready = False

    def check_open(self) -> None:
        """Raise Gymnasium's ``ClosedEnvironmentError`` if the env is closed."""
        if self.closed:
            raise ClosedEnvironmentError("this vector env is closed: make a new one")

    def checked_actions(self, actions: np.ndarray) -> np.ndarray:
        """``actions`` as an array, checked before any copy moves: the env open and reset, one action of the single
        action space's shape per copy, every number finite; ``ValueError`` (or Gymnasium's ``ResetNeeded``,
        ``ClosedEnvironmentError``) otherwise."""
        self.check_open()
        if not self.ready:
            raise ResetNeeded("call reset() before step()")
        values = np.asarray(actions)
        wanted = (self.num_envs, *self.single_action_space.shape)
        if values.shape != wanted:
            raise ValueError(f"expected actions of shape {wanted} (one per copy), got an array of shape {values.shape}")
        if not (np.issubdtype(values.dtype, np.integer) or np.issubdtype(values.dtype, np.floating)):
            raise ValueError(f"actions must be real numbers, got an array of {values.dtype}")
        if not np.isfinite(values).all():  # (the copy, found only then: a row-wise check costs 20× more)
            row = int(np.flatnonzero(~np.isfinite(values).reshape(self.num_envs, -1).all(axis=1))[0])
            raise ValueError(f"action must be finite, got {values[row].tolist()} (copy {row})")
        return values

    def reset_arrays(self, *, seed: int | list[int | None] | None = None,
                     options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:  # fmt: skip
        """Reset every copy (copy i with ``seed + i``, or ``seed[i]``), each with ``options``: the first
        observations, and the infos as one array per key, a row per copy."""
        raise NotImplementedError

    def step_arrays(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                         dict[str, np.ndarray], Finals]:  # fmt: skip
        """:meth:`step` with the info as one array per key (a row per copy), and the :class:`Finals` of the copies
        whose episode ended (and which were reset in this step: their rows hold the new episode's first
        observation and info)."""
        raise NotImplementedError

    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:  # fmt: skip
        """Reset every copy: copy i with ``seed + i`` (or ``seed[i]``), each with ``options``."""
        seeds = copy_seeds(seed, self.num_envs)  # checked before anything is seeded
        one = seed is not None and np.ndim(seed) == 0  # a whole number s: this env's own generator is seeded s too
        super().reset(seed=seeds[0] if one else None)
        observations, columns = self.reset_arrays(seed=seed, options=options)
        return observations, self._gymnasium_info(columns)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Every copy's action (num_envs, …); a copy whose episode ended is reset in this step."""
        observations, rewards, terminations, truncations, info, finals = self.step_arrays(actions)
        batched = self._gymnasium_info(info)
        if len(finals):
            batched.update(self._final_infos(finals))
        return observations, rewards, terminations, truncations, batched

    def step_each(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                       list[dict[str, Any]], Finals]:  # fmt: skip
        """:meth:`step_arrays` with each copy's info as its own dict: the form Stable-Baselines3's VecEnv
        returns."""
        observations, rewards, terminations, truncations, info, finals = self.step_arrays(actions)
        keys = list(info)
        infos = [dict(zip(keys, row)) for row in zip(*(info[key] for key in keys))]
        return observations, rewards, terminations, truncations, infos, finals

    def _gymnasium_info(self, columns: dict[str, np.ndarray]) -> dict[str, Any]:
        """One array per key as Gymnasium batches infos: each key with ``_key``, the copies that have it (all); a
        task's nested entry (a dict per copy) as a dict of such arrays, as Gymnasium's ``_add_info`` makes it."""
        out: dict[str, Any] = {}
        for key, value in columns.items():
            if value.dtype == object and len(value) and isinstance(value[0], dict):
                value = self._nested(value, range(self.num_envs))
            out[key] = value
            out[f"_{key}"] = np.ones(self.num_envs, dtype=bool)
        return out

    def _nested(self, entries: np.ndarray, rows: Sequence[int]) -> dict[str, Any]:
        """A task's nested info entries (a dict each) of copies ``rows`` as Gymnasium batches them, copy by copy
        with its ``_add_info``: a dict of arrays, each with its mask."""
        nested: dict[str, Any] = {}
        for entry, i in zip(entries, rows):
            nested = self._add_info(nested, entry, i)
        return nested

    def _final_infos(self, finals: Finals) -> dict[str, Any]:
        """``final_obs`` and ``final_info`` of the copies whose episode ended, with their masks, all at once: what
        Gymnasium's ``_add_info`` makes of them one copy at a time (as its SyncVectorEnv in SAME_STEP mode)."""
        rows = finals.rows.tolist()
        mask = np.zeros(self.num_envs, dtype=np.bool_)
        mask[rows] = True
        final_obs = np.full(self.num_envs, None, dtype=object)
        for j, i in enumerate(rows):
            final_obs[i] = finals.observations[j]
        final_info: dict[str, Any] = {}
        for key, values in finals.info.items():
            first = values[0]
            if isinstance(first, dict):  # a task's nested entry
                final_info[key], final_info[f"_{key}"] = self._nested(values, rows), mask.copy()
                continue
            # the column as Gymnasium makes it from the first copy's value
            if type(first) in (int, float, bool) or isinstance(first, np.number):
                column = np.zeros(self.num_envs, dtype=type(first))
            elif isinstance(first, np.ndarray):
                column = np.zeros((self.num_envs, *first.shape), dtype=first.dtype)
            else:  # anything else (a NumPy bool among them) in an object array
                column = np.full(self.num_envs, None, dtype=object)
            if values.dtype != object and column.dtype != object:  # numbers or arrays: all rows at once
                column[rows] = values
            else:
                for j, i in enumerate(rows):
                    column[i] = values[j]
            final_info[key], final_info[f"_{key}"] = column, mask.copy()
        return {"final_obs": final_obs, "_final_obs": mask, "final_info": final_info, "_final_info": mask.copy()}


class StewartBallVectorEnv(ArrayVectorEnv):
    """``num_envs`` copies of one env id on one batched simulator.

    Args:
        num_envs: How many copies.
        backend: ``"batched"`` (the only one: the copies share its simulator).
        render_mode: None (the batched simulator does not render).
        max_episode_steps: Where given, a copy's episode is also truncated after this many steps, as ``gym.make``'s
            ``max_episode_steps`` truncates one env's (Gymnasium's ``TimeLimit``).
        **kwargs: The env's keywords, as ``gym.make`` takes them (``task``, ``action_mode``, ``randomize``,
            ``geometry``, ``sensor``, ``estimator``, …); each copy gets the same.
    """

    def __init__(self, num_envs: int = 1, *, backend: str = "batched", render_mode: str | None = None,
                 geometry: Any = "servo-hexapod", control_hz: int = 50, physics_hz: int | None = None,
                 ball: Any = None, servo: Any = None, max_episode_steps: int | None = None,
                 **kwargs: Any) -> None:  # fmt: skip
        check_num_envs(num_envs)
        if max_episode_steps is not None and not whole_number(max_episode_steps, 1):
            raise ConfigError(f"max_episode_steps must be a whole number ≥ 1, got {max_episode_steps!r}")
        #: the steps after which a copy's episode is truncated (None: its ``episode_s`` alone)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        if backend != "batched":
            raise ConfigError(f"the vector entry point steps the batched backend; got backend {backend!r} (for "
                              "PyBullet or MuJoCo copies use vectorization_mode='sync' or 'async')")  # fmt: skip
        if render_mode is not None:
            raise ConfigError("the batched backend does not render; make one env with backend 'pybullet' to watch")
        from stewart_gym.sim import BallSpec, ServoSpec

        control_hz, physics_hz = check_engine_arguments(geometry, control_hz, physics_hz, ball, servo)
        geo = check_ball_geometry(geometry, ball)
        self.num_envs = int(num_envs)
        self.sim = BatchedSim(geo, n=self.num_envs, control_hz=control_hz,
                              physics_hz=physics_hz or multiple_at_least(PYBULLET_ENV_HZ, control_hz),
                              ball_spec=ball or BallSpec(), servo_spec=servo or ServoSpec())  # fmt: skip
        task = kwargs.pop("task", "balance")  # a task object: a copy of it for each copy (its draws are per episode)
        self.envs = [StewartBallEnv(backend=BatchedPlatform(self.sim, i, owns_steps=False), ball=ball, servo=servo,
                                    control_hz=control_hz, task=task if isinstance(task, str) else copy.deepcopy(task),
                                    **kwargs) for i in range(self.num_envs)]  # fmt: skip
        first = self.envs[0]
        #: the copies' touch panels or cameras, and their observers, as arrays (:mod:`stewart_gym.sensing_arrays`)
        self.sensors = sensor_array(first, self.num_envs, 1.0 / control_hz)
        self.observers = ObserverArray(self.num_envs, first.mapper.size, first.plate_half_extent,
                                       first.observer.estimator, first.observer.builder.integral)  # fmt: skip
        for i, env in enumerate(self.envs):
            env.sensor_model = (PanelRow(self.sensors, i) if isinstance(self.sensors, PanelArray)
                                else CameraRow(self.sensors, i))  # fmt: skip
            env.observer = ObserverRow(self.observers, i)
        #: every copy's step as arrays
        self.copy_steps = CopySteps(self.envs, self.sim, self.sensors, self.observers)
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self.spec = None
        self.metadata = {**self.metadata, "render_fps": int(control_hz)}

    def reset_arrays(self, *, seed: int | list[int | None] | None = None,
                     options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:  # fmt: skip
        self.check_open()
        seeds = copy_seeds(seed, self.num_envs)
        try:
            out = self._reset_copies(np.arange(self.num_envs), seeds, options)
        except ConfigError as exc:  # an option one copy refuses: each copy takes the same options
            if options and str(exc).startswith("reset option "):
                raise ConfigError(f"{exc} (every copy of a vector env resets with these same options: one value "
                                  "each, not one per copy)") from None  # fmt: skip
            raise
        self.ready = True
        return out

    def step_arrays(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                         dict[str, np.ndarray], Finals]:  # fmt: skip
        observations, rewards, terminations, truncations, info = self.copy_steps.step(self.checked_actions(actions))
        if self.max_episode_steps is not None:  # as TimeLimit counts: every step, the one whose physics blew up too
            truncations |= self.copy_steps.steps + info["physics_error"] >= self.max_episode_steps
        ended = np.flatnonzero(terminations | truncations)
        finals = Finals.of(ended, observations, info)
        if ended.size:
            observations[ended], first_info = self._reset_copies(ended)
            for key, value in info.items():
                value[ended] = first_info[key]
        return observations, rewards, terminations, truncations, info, finals

    def _reset_copies(self, rows: np.ndarray, seeds: Sequence[int | None] | None = None,
                      options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:  # fmt: skip
        """Reset copies ``rows`` (copy ``rows[k]`` seeded ``seeds[k]``), each as its env's own :meth:`reset
        <stewart_gym.envs.ball_env.StewartBallEnv.reset>` would with ``options``: their first observations and infos
        (a row each). Each copy draws its episode from its own generator
        (:meth:`~stewart_gym.envs.ball_env.StewartBallEnv.draw_episodes`); then the platforms are reset for all of
        them at once, each copy's task draws (after the physics, as in an env's own reset: a task may act on it), and
        the sensors, the observers, the first observations and the infos are set for all of them at once."""
        envs = [self.envs[i] for i in rows.tolist()]
        xy, velocity = StewartBallEnv.draw_episodes(envs, seeds or [None] * len(envs), options)
        params = [env.params for env in envs]
        self.sim.reset_platforms(rows, [p.servo for p in params], [p.ball for p in params],
                                 [p.plate_load for p in params])  # fmt: skip
        self.sim.ball_xy[rows] = xy
        self.sim.ball_velocity[rows] = velocity
        for env in envs:  # after the physics, as an env's own reset: a task may act on it
            env.task.reset(env.np_random, env.sim)
        self.sensors.set_specs(rows, [p.sensor for p in params])
        if isinstance(self.sensors, CameraArray):
            self.sensors.ball_radius[rows] = [p.ball.radius for p in params]
        self.sensors.reset_rows(rows, 0.0, xy, [env.np_random for env in envs])
        self.observers.reset_rows(rows, 0.0, xy)
        return self.copy_steps.reset_rows(rows, xy)

    def close_extras(self, **kwargs: Any) -> None:
        for env in getattr(self, "envs", []):  # [] when the constructor refused its arguments
            env.close()

    def __deepcopy__(self, memo: dict) -> StewartBallVectorEnv:
        """An independent vector env in the same state: what a pickle round trip makes (the copies, their shared
        simulator, sensors and observers copied together)."""
        import pickle

        twin = pickle.loads(pickle.dumps(self))
        memo[id(self)] = twin
        return twin


def sensor_array(env: StewartBallEnv, n: int, control_dt: float) -> PanelArray | CameraArray:
    """``n`` copies of ``env``'s sensor as one array: touch panels, or cameras where it has a camera (every
    episode then has one: a preset, or one drawn from the presets)."""
    if isinstance(env.nominal_sensor, (CameraSpec, tuple)):
        return CameraArray(n, control_dt, env.sensor_model.spec, env.nominal_ball.radius)
    if not isinstance(env.nominal_sensor, TouchPanelSpec):
        raise ConfigError(f"the batched vector env holds touch panels and cameras as arrays, not a "
                          f"{type(env.nominal_sensor).__name__}: use a PyBullet or MuJoCo vector env "
                          "(vectorization_mode 'sync' or 'async'), or give the sensor an array class")  # fmt: skip
    return PanelArray(n, control_dt)


def make_vector_env(num_envs: int, env_id: str = "StewartBallBalance-v0", **kwargs: Any) -> StewartBallVectorEnv:
    """``gym.make_vec(env_id, num_envs, vectorization_mode="vector_entry_point", **kwargs)``."""
    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)
