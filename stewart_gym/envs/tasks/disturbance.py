"""``StewartBallDisturbance-v0``: balance the ball while it is pushed and the plate is loaded mid-episode."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from stewart_gym.envs.arguments import MAX_EPISODE_S, number_range, real_number
from stewart_gym.envs.task import BallTask
from stewart_gym.sim.twin import TWIN_FIELDS

if TYPE_CHECKING:
    from stewart_gym.sim.backend import PhysicsBackend

__all__ = ["DisturbanceTask"]

#: N·s: the largest push (1 N·s sends the default ball off at 15 m/s).
MAX_PUSH_NS = 1.0
#: kg: the heaviest plate load (a platform's twin's).
MAX_LOAD_KG = TWIN_FIELDS[("plate", "load_kg")][2]
#: m: how far from the centre the plate load may land by default (the plate's half-width where that is less).
LOAD_RADIUS_M = 0.10


class DisturbanceTask(BallTask):
    """Hold the ball at the plate centre while random pushes hit it.

    Each episode draws, from the env's random generator:

    * **pushes**: impulses on the ball along the plate, the first 1.0–2.0 s in,
      then every 1.5–3.0 s until ``last_push_s``; each of ``push_impulse``
      (N·s, uniform; 0.003–0.010 N·s is 0.045–0.15 m/s of sudden speed for the
      default 66.8 g ball) in a uniformly random direction;
    * a **plate load** that appears at a uniform time in ``load_time_s``: a mass
      of ``load_kg`` (uniform) placed uniformly within ``load_radius`` of the
      centre (default 0.10 m, or the plate's half-width where that is less). It
      replaces the small load that domain randomisation may have put there, and
      stays to the end.

    ``push_impulse``, ``load_kg`` and ``load_time_s`` are (low, high) pairs: pushes
    of up to 1 N·s, loads of up to 2 kg, times of up to an hour; ``load_radius`` is
    within ``plate_half`` (the env gives its plate's half-width).

    Success: as for balance, within 10 mm of the centre for the last second;
    the pushes stop ``last_push_s`` (7.5 s) into the 10 s episode, so there is
    time to settle. ``info["pushes"]`` counts the pushes so far and
    ``info["plate_load_kg"]`` gives the load now on the plate.
    """

    name = "disturbance"

    def __init__(self, push_impulse: tuple[float, float] = (0.003, 0.010), last_push_s: float = 7.5,
                 load_kg: tuple[float, float] = (0.05, 0.20), load_time_s: tuple[float, float] = (2.0, 6.0),
                 load_radius: float | None = None, **kwargs: Any) -> None:  # fmt: skip
        super().__init__(**kwargs)
        self.push_impulse = number_range("push_impulse", push_impulse, 0.0, MAX_PUSH_NS)
        self.last_push_s = float(real_number("last_push_s", last_push_s, low=0.0, high=MAX_EPISODE_S))
        self.load_kg = number_range("load_kg", load_kg, 0.0, MAX_LOAD_KG)
        self.load_time_s = number_range("load_time_s", load_time_s, 0.0, MAX_EPISODE_S)
        self.load_radius = (min(LOAD_RADIUS_M, self.plate_half) if load_radius is None
                            else float(real_number("load_radius", load_radius, low=0.0, high=self.plate_half)))
        self._pushes: list[tuple[float, tuple[float, float]]] = []
        self._load: tuple[float, float, np.ndarray] | None = None
        self._next = 0
        self._load_on = False

    def reset(self, rng: np.random.Generator, backend: PhysicsBackend) -> None:
        super().reset(rng, backend)
        pushes, t = [], float(rng.uniform(1.0, 2.0))
        while t <= self.last_push_s:
            angle, size = rng.uniform(0, 2 * math.pi), rng.uniform(*self.push_impulse)
            pushes.append((t, (size * math.cos(angle), size * math.sin(angle))))
            t += float(rng.uniform(1.5, 3.0))
        self._pushes, self._next = pushes, 0
        angle, dist = rng.uniform(0, 2 * math.pi), self.load_radius * math.sqrt(rng.uniform(0, 1))
        self._load = (float(rng.uniform(*self.load_time_s)), float(rng.uniform(*self.load_kg)),
                      np.array([dist * math.cos(angle), dist * math.sin(angle), 0.012]))  # fmt: skip
        self._load_on = False

    def before_step(self, t: float, backend: PhysicsBackend) -> None:
        while self._next < len(self._pushes) and self._pushes[self._next][0] <= t:
            backend.push_ball(self._pushes[self._next][1])
            self._next += 1
        if not self._load_on and self._load is not None and self._load[0] <= t:
            backend.set_plate_load((self._load[1], self._load[2]))
            self._load_on = True

    def info(self) -> dict[str, Any]:
        return {"pushes": np.int64(self._next),
                "plate_load_kg": np.float64(self._load[1] if self._load_on and self._load else 0.0)}  # fmt: skip
