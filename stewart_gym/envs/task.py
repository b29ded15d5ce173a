"""The task seam: what the ball should do, how it is rewarded, and what else happens to it.

In the style of panda-gym's ``Task`` / ``RobotTaskEnv`` split, an environment
(:class:`~stewart_gym.envs.ball_env.StewartBallEnv`) is a platform with a ball
(the physics backend), a sensor, an action mapping and a **task**. The task
gives the target, the reward and any disturbance; the env does everything
else the same way for every task (sensing, observation, termination when the
ball leaves the plate, success once the ball has stayed within
``success_radius`` of the target for ``success_window_s``).

A new task is one file with a class following :class:`Task` (usually a
subclass of :class:`BallTask`) and one line in
:data:`stewart_gym.envs.ENV_IDS`; ``docs/src/guides/add-a-task.md`` walks through
it. ``tests/envs/test_task_contract.py`` holds the checks every task must pass.
"""

from __future__ import annotations

import importlib
import math
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from stewart_gym.envs.arguments import real_number, true_or_false
from stewart_gym.errors import ConfigError

if TYPE_CHECKING:
    from stewart_gym.sim.backend import PhysicsBackend

__all__ = ["BallTask", "Task", "XY", "load_task", "task_class", "TASK_NAMES", "task_keywords"]

XY = tuple[float, float]

#: Short names for the built-in tasks (``StewartBallEnv(task="track")``); any "module:Class" path works too.
TASK_NAMES = {
    "balance": "stewart_gym.envs.tasks.balance:BalanceTask",
    "track": "stewart_gym.envs.tasks.track:TrackTask",
    "disturbance": "stewart_gym.envs.tasks.disturbance:DisturbanceTask",
}


@runtime_checkable
class Task(Protocol):
    """What the env asks of a task.

    Attributes:
        name: Short name (for reports).
        success_radius: m, how close to the target counts as there.
        success_window_s: s the ball must stay there for success.
        moving_target: False if the target stays put (the settling-time test applies).
    """

    name: str
    success_radius: float
    success_window_s: float
    moving_target: bool

    def reset(self, rng: np.random.Generator, backend: PhysicsBackend) -> None:
        """Start an episode: draw the target (and any disturbances) from ``rng``."""

    def target(self, t: float) -> tuple[XY, XY]:
        """Target position (x, y) m and velocity m/s in the plate frame at time ``t`` (Python floats)."""

    def before_step(self, t: float, backend: PhysicsBackend) -> None:
        """Act on the physics before the control period that starts at ``t`` (disturbances; usually nothing)."""

    def reward(self, distance: float, action_rate: float, fell: bool) -> float:
        """Reward of one step: ``distance`` (m) ball to target, ``action_rate`` mean squared action change."""

    def info(self) -> dict[str, Any]:
        """Task-specific entries for the step's ``info`` (may be empty)."""


class BallTask:
    """The shared reward and defaults of the ball tasks.

    Per step, with d the true ball-to-target distance (m) and h the plate's half
    size: ``1 − min(d, 2h) / h + exp(−d / s) − (rate_penalty + [d ≤ r] · settled_rate_penalty) · rate
    − [d > r] · outside_penalty`` and ``−50`` on the step the ball leaves the plate: a distance term over the
    whole plate, a sharper one near the target (with the default s = 15 mm: 0.51 at 10 mm, 1 at 0), an
    action-rate penalty for servo wear, optionally heavier once the ball is within the success radius r (what
    buzzes a servo is jitter while holding), and optionally a cost per step outside the success radius. With
    ``charge_until_settled``, a ball that leaves the success radius again also costs ``outside_penalty`` for
    each step it had spent inside since it last entered: an episode then costs ``outside_penalty`` × the steps
    until the ball entered for good, which is what the settling time counts (an overshoot that comes back costs
    the whole time until it is back, as it does in the settling time, not only its steps outside).

    Args:
        success_radius: m (default: the class's ``default_success_radius``).
        success_window_s: s.
        rate_penalty: weight of the action-rate term.
        plate_half: m, h above.
        near_scale: m, s above: a smaller one rewards precision near the target more steeply.
        settled_rate_penalty: extra weight of the action-rate term within the success radius.
        outside_penalty: cost per step while the ball is farther than the success radius (default 0).
        charge_until_settled: also charge ``outside_penalty`` for the steps spent inside before leaving again.
    """

    name: ClassVar[str] = "ball"
    #: The attributes the reward reads.
    REWARD_PARAMETERS: ClassVar[tuple[str, ...]] = ("success_radius", "plate_half", "near_scale", "rate_penalty",
                                                    "settled_rate_penalty", "outside_penalty", "FALL_PENALTY",
                                                    "charge_until_settled")  # fmt: skip
    #: How many times an attribute of :data:`REWARD_PARAMETERS` has been set or deleted on any ball task: the batched
    #: vector env (:class:`~stewart_gym.envs.task_array.TaskArray`) reads its copies' parameters again when it
    #: changes.
    reward_parameter_writes: ClassVar[int] = 0
    moving_target: ClassVar[bool] = False
    default_success_radius: ClassVar[float] = 0.010
    FALL_PENALTY: ClassVar[float] = 50.0
    NEAR_SCALE: ClassVar[float] = 0.015  # m, the default near_scale

    def __init__(self, success_radius: float | None = None, success_window_s: float = 1.0, rate_penalty: float = 0.1,
                 plate_half: float = 0.15, near_scale: float | None = None,
                 settled_rate_penalty: float = 0.0, outside_penalty: float = 0.0,
                 charge_until_settled: bool = False) -> None:  # fmt: skip
        self.success_radius = real_number("success_radius", self.default_success_radius if success_radius is None
                                          else success_radius)  # fmt: skip
        self.success_window_s = real_number("success_window_s", success_window_s)
        self.rate_penalty = real_number("rate_penalty", rate_penalty)
        self.plate_half = real_number("plate_half", plate_half)
        self.near_scale = real_number("near_scale", self.NEAR_SCALE if near_scale is None else near_scale)
        for key, v in (("success_radius", self.success_radius), ("success_window_s", self.success_window_s),
                       ("plate_half", self.plate_half), ("near_scale", self.near_scale)):  # fmt: skip
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{key} must be a positive number, got {v!r}")
        self.settled_rate_penalty = real_number("settled_rate_penalty", settled_rate_penalty)
        self.outside_penalty = real_number("outside_penalty", outside_penalty)
        for key, v in (("rate_penalty", self.rate_penalty), ("settled_rate_penalty", self.settled_rate_penalty),
                       ("outside_penalty", self.outside_penalty)):  # fmt: skip
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{key} must be ≥ 0, got {v!r}")
        self.charge_until_settled = true_or_false("charge_until_settled", charge_until_settled)
        self._steps_inside = 0  # since the ball last entered the success radius (charge_until_settled)

    def __setattr__(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)
        if name in BallTask.REWARD_PARAMETERS:
            BallTask.reward_parameter_writes += 1

    def __delattr__(self, name: str) -> None:
        object.__delattr__(self, name)
        if name in BallTask.REWARD_PARAMETERS:
            BallTask.reward_parameter_writes += 1

    def reset(self, rng: np.random.Generator, backend: PhysicsBackend) -> None:
        """Nothing to draw for a fixed target at the centre; the reward's count of steps inside starts again.
        Subclasses that draw something call this too."""
        self._steps_inside = 0

    def target(self, t: float) -> tuple[XY, XY]:
        return (0.0, 0.0), (0.0, 0.0)

    def before_step(self, t: float, backend: PhysicsBackend) -> None:
        """No disturbance."""

    def reward(self, distance: float, action_rate: float, fell: bool) -> float:
        half = self.plate_half
        inside = distance <= self.success_radius
        weight = self.rate_penalty + (self.settled_rate_penalty if inside else 0.0)
        outside = 0.0 if inside else self.outside_penalty * (1 + (self._steps_inside if self.charge_until_settled
                                                                   else 0))  # fmt: skip
        if self.charge_until_settled:  # the count matters only then (the batched vector env keeps none otherwise)
            self._steps_inside = self._steps_inside + 1 if inside else 0
        return (1.0 - min(distance, 2 * half) / half + math.exp(-distance / self.near_scale)
                - weight * action_rate - outside - (self.FALL_PENALTY if fell else 0.0))  # fmt: skip

    def info(self) -> dict[str, Any]:
        return {}


def task_class(spec: str) -> type:
    """The task class that a short name (:data:`TASK_NAMES`) or a ``"module:Class"`` path names."""
    path = TASK_NAMES.get(spec, spec)
    module_name, _, class_name = path.partition(":")
    try:
        return getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError, ValueError):
        raise ConfigError(f"unknown task {spec!r}; use one of {sorted(TASK_NAMES)} or 'module:Class'") from None


def task_keywords(spec: str | Task) -> set[str]:
    """The keywords the constructor of the task ``spec`` names takes (its own and its bases')."""
    import inspect

    cls = task_class(spec) if isinstance(spec, str) else type(spec)
    names: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" in vars(klass):
            names |= set(inspect.signature(klass.__init__).parameters) - {"self", "args", "kwargs", "plate_half"}
    return names


def load_task(spec: str | Task, **kwargs: Any) -> Task:
    """A task from a short name (:data:`TASK_NAMES`), a ``"module:Class"`` path, or a task (returned as is)."""
    if not isinstance(spec, str):
        return spec
    cls = task_class(spec)
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"task {spec!r}: {exc}") from None
