"""The batched vector env's copies stepped as arrays, where they sense with touch panels or cameras as arrays.

:class:`CopySteps` does, for every copy of a :class:`~stewart_gym.envs.vector.StewartBallVectorEnv` at once, what
:meth:`StewartBallEnv.step <stewart_gym.envs.ball_env.StewartBallEnv.step>` does for one env: map the actions (one
IK pass), let each task act, send every copy's pulses, advance the shared simulator, record and read the sensors
(:class:`~stewart_gym.sensing_arrays.PanelArray` or :class:`~stewart_gym.sensing_arrays.CameraArray`), observe
(:class:`~stewart_gym.sensing_arrays.ObserverArray`), and end the step: reward, success, termination and truncation,
and the info as arrays. It carries, per copy, what the env carries from step to step (the last action, the commanded
tilt, the steps taken and the steps in a row within the success radius); the copies' tasks are asked through a
:class:`~stewart_gym.envs.task_array.TaskArray`. The copies reset in a step start together: their first observations
and infos as arrays (:meth:`CopySteps.reset_rows`). The results equal
each copy's own :meth:`~stewart_gym.envs.ball_env.StewartBallEnv.step` to the last bit, but for
``info["pulse_widths_us"]`` without numba, which the batched IK then gives to rounding (``tests/envs/test_vector.py``)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from stewart_gym.envs.ball_env import StewartBallEnv
from stewart_gym.envs.task_array import TaskArray
from stewart_gym.rows import put_rows
from stewart_gym.sensing import ball_contact
from stewart_gym.sensing_arrays import CameraArray, ObserverArray, PanelArray
from stewart_gym.sim.batched import BatchedSim

__all__ = ["CopySteps", "StepArrays"]

#: A step of every copy: observations, rewards, terminated, truncated (a row each) and the info, name → (n, …)
#: array, in the order an env's info has them.
StepArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]


class CopySteps:
    """Every copy's step at once, for copies on one batched simulator with sensors and observers as arrays.

    Args:
        envs: The copies; env i runs on platform i of ``sim`` with row i of ``sensors`` and ``observers``.
        sim: Their shared simulator.
        sensors: Their touch panels or cameras.
        observers: Their observers.
    """

    def __init__(self, envs: Sequence[StewartBallEnv], sim: BatchedSim, sensors: PanelArray | CameraArray,
                 observers: ObserverArray) -> None:  # fmt: skip
        first = envs[0]
        self.envs, self.sim, self.sensors, self.observers = list(envs), sim, sensors, observers
        self.n = len(self.envs)
        self.tasks = TaskArray([env.task for env in self.envs])
        self.platforms = [env.sim for env in self.envs]  # each copy's platform of ``sim``, which its task acts on
        self.mapper = first.mapper
        self.half_extent = first.plate_half_extent
        self.success_radius, self.success_steps = first.success_radius, first.success_steps
        self.episode_steps = first.episode_steps
        self.rows = np.arange(self.n)
        self.steps = np.zeros(self.n, dtype=np.int64)
        self.inside = np.zeros(self.n, dtype=np.int64)  # steps in a row on the plate within the success radius
        self.previous_action = np.zeros((self.n, self.mapper.size))
        self.roll_pitch = np.zeros((self.n, 2))
        self.unreachable = np.zeros(self.n, dtype=np.int64)
        self.pulses = np.tile(sim.calibration.neutral_us, (self.n, 1))
        self.last_obs = np.zeros((self.n, *first.observation_space.shape), dtype=np.float32)

    def reset_rows(self, rows: np.ndarray, start_xy: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Copies ``rows`` start an episode with their balls at ``start_xy`` (rows × 2, m), their physics, sensors and
        observers just reset: their first observations (rows × size) and infos (arrays, a row each), what each env's
        own :meth:`~stewart_gym.envs.ball_env.StewartBallEnv.reset` gives at time 0, for all of them at once."""
        k = len(rows)
        t = np.zeros(k)
        reading, sample_t, has = self.sensors.read(t, rows)
        targets, target_velocities = self.tasks.targets(t, rows)
        observations = self.observers.observe(rows, has, reading, sample_t, targets, target_velocities,
                                              np.zeros((k, 2)), np.zeros((k, self.mapper.size)), t)  # fmt: skip
        self.steps[rows] = self.inside[rows] = self.unreachable[rows] = 0
        self.previous_action[rows] = 0.0
        self.roll_pitch[rows] = 0.0
        self.pulses[rows] = self.sim.calibration.neutral_us
        put_rows(self.last_obs, rows, observations)
        offset = start_xy - targets
        distances = np.sqrt(offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1])
        info = {
            "is_success": np.zeros(k, dtype=bool),
            "distance_mm": distances * 1e3,
            "ball_xy_m": start_xy.copy(),
            "target_xy_m": targets,
            "pulse_widths_us": self.pulses[rows],
            "commanded_tilt_rad": np.zeros((k, 2)),
            "action_scaled": np.zeros(k, dtype=bool),
            "unreachable_count": np.zeros(k, dtype=np.int64),
            "physics_error": np.zeros(k, dtype=bool),
        }
        info.update(self.tasks.infos(rows))
        return observations, info

    def step(self, actions: np.ndarray) -> StepArrays:
        """Every copy's step with its action (n × action size): observations, rewards, terminated, truncated and
        the info as arrays. A copy whose episode ends is left for the caller to reset (then :meth:`reset_rows`)."""
        sim = self.sim
        mapped = self.mapper.map_arrays(actions)
        self.tasks.before_step(sim.platform_times(), self.platforms)
        sim.command(mapped.pulses)
        sim.step()
        t = sim.platform_times()
        difference = mapped.actions - self.previous_action
        squares = difference * difference
        # (the sum of a row of two, column by column: NumPy's reduction along a short row is several times slower)
        rates = (squares[:, 0] + squares[:, 1] if self.mapper.size == 2 else squares.sum(axis=1)) / self.mapper.size
        self.previous_action = mapped.actions
        self.pulses = mapped.pulses
        self.unreachable += mapped.scaled
        if self.mapper.mode != "pulse":
            self.roll_pitch = mapped.poses[:, 3:5].copy()
        xy = sim.ball_xy.copy()
        z = sim.plate_top + sim.ball_radius
        sound = np.isfinite(xy[:, 0]) & np.isfinite(xy[:, 1]) & np.isfinite(z) & (np.abs(z) < 1.0)  # else the
        # physics blew up
        on_plate, touching = ball_contact(xy[:, 0], xy[:, 1], z, self.half_extent, sim.plate_top, sim.ball_radius)
        on_plate &= sound
        targets, target_velocities = self.tasks.targets(t)
        every = bool(sound.all())  # (nearly always: then every row as it is, without the gathers)
        good = self.rows if every else self.rows[sound]

        def sound_rows(a: np.ndarray) -> np.ndarray:
            return a if every else a.take(good, axis=0)

        self.sensors.record(sound_rows(t), sound_rows(xy), sound_rows(touching), good)
        reading, sample_t, has = self.sensors.read(sound_rows(t), good)
        observed = self.observers.observe(good, has, reading, sample_t, sound_rows(targets),
                                          sound_rows(target_velocities), sound_rows(self.roll_pitch),
                                          sound_rows(mapped.actions), sound_rows(t))  # fmt: skip
        if every:
            obs = observed
        else:  # a blown-up copy keeps its last observation
            obs = self.last_obs.copy()
            put_rows(obs, good, observed)
        self.last_obs = obs
        lost = 2 * self.half_extent[0]  # the distance a step whose physics blew up is scored at
        offset = np.where(sound[:, None], xy - targets, 0.0)  # (a blown-up row: inf or NaN, never inf − inf)
        distances = np.where(sound, np.sqrt(offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1]), math.nan)
        rewards = self.tasks.rewards(np.where(sound, distances, lost), np.where(sound, rates, 0.0), ~on_plate)
        within = on_plate & (distances <= self.success_radius)
        self.inside = np.where(sound, np.where(within, self.inside + 1, 0), self.inside)
        self.steps += sound
        terminated = ~on_plate
        truncated = sound & on_plate & (self.steps >= self.episode_steps)
        ball_xy = np.where(sound[:, None], xy, math.nan)
        info = {
            "is_success": on_plate & (self.inside >= self.success_steps),
            "distance_mm": distances * 1e3,
            "ball_xy_m": ball_xy,
            "target_xy_m": np.where(sound[:, None], targets, math.nan),
            "pulse_widths_us": self.pulses.copy(),
            "commanded_tilt_rad": self.roll_pitch.copy(),
            "action_scaled": mapped.scaled,
            "unreachable_count": self.unreachable.copy(),
            "physics_error": ~sound,
        }
        info.update(self.tasks.infos())
        return obs, rewards, terminated, truncated, info
