"""The batched vector env's tasks as arrays: each copy's target, reward, disturbance and info for every copy at once.

:class:`TaskArray` asks N copies' tasks (one :class:`~stewart_gym.envs.task.Task` per copy) what their envs ask
of them in a step. Where every copy's task uses :class:`~stewart_gym.envs.task.BallTask`'s own hook, that hook is
done as arrays: the fixed target at the centre, no disturbance, no info, and the reward (but with
``charge_until_settled``, whose count of steps inside is per copy). Any other hook (a moving target, a push, a
task's own reward or info) is asked of each copy's task in turn, as its env would ask it. The results are each
task's own to the last bit (the reward's exponential is the C library's ``exp``, as Python's ``math.exp`` in the
task's: :func:`~stewart_gym.compiled.exp_each`).

Which hooks a task overrides (in its class or on the instance) is looked up once, when the array is made. The
reward's parameters (:data:`BallTask.REWARD_PARAMETERS <stewart_gym.envs.task.BallTask.REWARD_PARAMETERS>`:
``success_radius``, ``near_scale``, the penalties, ``FALL_PENALTY``, ``charge_until_settled``) are read again
whenever one has been set or deleted on any ball task, or a task class's ``FALL_PENALTY`` has changed, since the
last read: a change made between steps (a curriculum's) counts at once, as it does for one env. Where a task's
class computes one of them (a property), they are read at every step. A change written into a task's
``__dict__`` directly is not seen until one of those happens.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import numpy as np

from stewart_gym.compiled import exp_each
from stewart_gym.envs.task import BallTask, Task

__all__ = ["TaskArray"]

#: A getter of the :class:`BallTask` attributes its reward reads, as a tuple.
_REWARD_PARAMETERS = operator.attrgetter(*BallTask.REWARD_PARAMETERS)


def _inherited(tasks: Sequence[Task], hook: str) -> bool:
    """Whether every task is a :class:`BallTask` that uses :class:`BallTask`'s own ``hook`` (not overridden in
    its class, nor set on the instance)."""
    return all(isinstance(task, BallTask) and getattr(type(task), hook) is getattr(BallTask, hook)
               and hook not in vars(task) for task in tasks)  # fmt: skip


class TaskArray:
    """``tasks[i]`` is copy i's task; each method takes and returns a row per copy.

    Args:
        tasks: The copies' tasks (each copy's env's own, redrawn at each of its episodes' start).
    """

    def __init__(self, tasks: Sequence[Task]) -> None:
        self.tasks = list(tasks)
        self.n = len(self.tasks)
        #: whether a task acts on the physics before a step (else :meth:`before_step` does nothing)
        self.disturbs = not _inherited(self.tasks, "before_step")
        #: whether every target is the fixed one at the centre
        self.fixed_target = _inherited(self.tasks, "target")
        #: whether the tasks add entries to the info
        self.adds_info = not _inherited(self.tasks, "info")
        #: whether every task rewards with :class:`BallTask`'s own reward: then :meth:`rewards` finds the rewards
        #: as arrays, unless a task counts its steps inside (``charge_until_settled``)
        self.ball_rewards = _inherited(self.tasks, "reward")
        self._task_classes = list({type(task) for task in self.tasks})
        #: whether a task's class computes a reward parameter (a property or other descriptor): then no cache
        self.computed_parameters = any(hasattr(getattr(cls, name, None), "__get__") for cls in self._task_classes
                                       for name in BallTask.REWARD_PARAMETERS)  # fmt: skip
        self._parameters_read: tuple[int, list[float]] | None = None  # (writes counted, class FALL_PENALTYs) then
        self._parameters: np.ndarray | None = None  # a row per parameter, a column per copy (:meth:`_columns`)

    def before_step(self, times: np.ndarray, backends: Sequence[Any]) -> None:
        """Let each task act on its copy's physics (``backends[i]``) before the period that starts at ``times[i]``."""
        if self.disturbs:
            for task, t, backend in zip(self.tasks, times.tolist(), backends):
                task.before_step(t, backend)

    def targets(self, times: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Each copy's target (n, 2) m and its velocity (n, 2) m/s at ``times[i]``; or those of the copies
        ``rows`` alone, at a time each."""
        count = self.n if rows is None else len(rows)
        targets, velocities = np.zeros((count, 2)), np.zeros((count, 2))
        if not self.fixed_target:
            tasks = self.tasks if rows is None else [self.tasks[i] for i in rows.tolist()]
            for k, (task, t) in enumerate(zip(tasks, times.tolist())):
                targets[k], velocities[k] = task.target(t)
        return targets, velocities

    def rewards(self, distances: np.ndarray, rates: np.ndarray, fell: np.ndarray) -> np.ndarray:
        """Each copy's reward (n,) for its ball-to-target distance (m), action rate and whether the ball fell."""
        if self.ball_rewards:
            radius, half, near_scale, rate_penalty, settled, outside_penalty, fall_penalty, charged = self._columns()
            if not charged.any():
                inside = distances <= radius
                weight = rate_penalty + np.where(inside, settled, 0.0)
                outside = np.where(inside, 0.0, outside_penalty)
                near = exp_each(-distances / near_scale)
                return (1.0 - np.minimum(distances, 2 * half) / half + near - weight * rates - outside
                        - np.where(fell, fall_penalty, 0.0))  # fmt: skip
        return np.array([task.reward(d, r, f) for task, d, r, f in zip(
            self.tasks, distances.tolist(), rates.tolist(), fell.tolist())], dtype=np.float64)  # fmt: skip

    def _columns(self) -> np.ndarray:
        """The tasks' reward parameters, a row per parameter and a column per copy: read again only where one may
        have changed since the last read (a parameter set on a task, or a class's ``FALL_PENALTY``)."""
        now = (BallTask.reward_parameter_writes, [cls.FALL_PENALTY for cls in self._task_classes])
        if now != self._parameters_read or self.computed_parameters:
            self._parameters = np.array(list(map(_REWARD_PARAMETERS, self.tasks)), dtype=np.float64).T
            self._parameters_read = now
        return self._parameters

    def infos(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The tasks' info entries, one array per key with a row per copy, or per copy of ``rows`` (none where the
        tasks add none)."""
        if not self.adds_info:
            return {}
        each = [task.info() for task in (self.tasks if rows is None else [self.tasks[i] for i in rows.tolist()])]
        return {key: np.array([entry[key] for entry in each]) for key in each[0]}
