"""The excitation experiment of ``stewart-gym identify``: a stabilising controller plus designed tilt steps.

:class:`Excitation` wraps a deployable policy (the PID + Kalman by default): every tick it adds a tilt offset to
the policy's action. The offset is a multilevel pseudo-random sequence: it holds each level for
``hold_s`` (drawn uniformly), and each level is drawn uniformly within ``± amplitude`` of the action range, with
the odd hold at zero. About every two seconds comes a doublet: a large tilt one way then the other, each for
``doublet_s``, which asks the servos for moves large enough to show their speed and leaves the ball's velocity
as it was. The controller keeps the ball on the plate while the steps make it roll.

With a camera (:meth:`Excitation.move_plate`), the plate also moves in height and yaw: a level of each, drawn
uniformly within ``± PLATE_MOVES`` of the pose action's range, held for 1–2 s, through the mapper's pose offset
(:meth:`~stewart_gym.actions.ActionMapper.set_offset`). Height and yaw change how each servo's angle moves the
plate, which is what separates each servo's trim from the camera's unknown pose in ``sysid``. The plate goes from
one level to the next along a half cosine over ``PLATE_RAMP_S``: a step would drive all six servos at full speed
at once, the moves where the batched model that ``sysid`` replays the log through strays most from the
platform. The tilt is then kept within what the platform reaches at every such offset, so that no tick's pose is
out of reach. Half the tilt levels become triplets: a large tilt (60–100 % of that reach) one way for
0.10–0.16 s, the other way for twice as long, then the first way again. A triplet leaves the ball where it was
and as fast, and large tilts are what pins each servo's trim down most.

The run itself is a deploy run
(:class:`~stewart_gym.hardware.deploy_setup.DeploySetup`): the same safety layer, the same channel limits, the
same drive home on every stop, and the same log, which ``stewart-gym sysid`` reads.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from stewart_gym.errors import ConfigError

__all__ = ["IDENTIFY_MAX_STEP_US_PER_S", "PLATE_MOVES", "PLATE_RAMP_S", "PLATE_TRIPLETS", "Excitation"]

#: ``identify``'s default rate limit, µs/s per channel: a step may move a servo as fast as about 3× the reference
#: servos' speed, so that the log shows how fast the servos really are (a limit under their speed would hide it).
IDENTIFY_MAX_STEP_US_PER_S = 10_000.0
#: The plate's height and yaw moves with a camera: the largest of each, as a fraction of the pose action's range
#: (90 % of the platform's reach along the axis), and how long each level is held (s).
PLATE_MOVES = {"z": 0.35, "yaw": 0.3}
PLATE_HOLD_S = (1.0, 2.0)
#: s: how long the plate takes from one height and yaw level to the next (a half cosine: on the reference build
#: at most about 1.4 m/s² up or down, a seventh of gravity). Slow servos still reach their full speed on it, so
#: that the plate poses show their speed.
PLATE_RAMP_S = 0.2
#: With a camera, this fraction of the tilt levels are triplets instead (see the module's description): their
#: size as a fraction of the tilt reached at every height and yaw, and the time of their first part (s).
PLATE_TRIPLETS = 0.5
TRIPLET_SIZE = (0.6, 1.0)
TRIPLET_S = (0.10, 0.16)
#: The least tilt action (its length) the platform must reach at every such move for the controller to work.
MIN_TILT_ACTION = 0.3


class Excitation:
    """``policy``'s action plus a pseudo-random multilevel tilt offset (see the module's description).

    Args:
        policy: the stabilising policy (its action is a tilt: ``action_mode`` ``"tilt"``).
        rate_hz: the loop's rate (one call per tick).
        amplitude: the offset's largest value, as a fraction of the action range (0 < amplitude ≤ 0.6).
        hold_s: (shortest, longest) time a level is held, s.
        doublet: (smallest, largest) amplitude of a doublet, a fraction of the action range.
        doublet_s: (shortest, longest) time of each half of a doublet, s.
        seed: the sequence's seed.
    """

    def __init__(self, policy: Any, rate_hz: float = 50.0, amplitude: float = 0.3,
                 hold_s: tuple[float, float] = (0.1, 0.5), doublet: tuple[float, float] = (0.4, 0.7),
                 doublet_s: tuple[float, float] = (0.06, 0.1), seed: int = 0) -> None:  # fmt: skip
        if getattr(policy, "action_mode", "tilt") != "tilt":
            raise ConfigError(f"identify excites the plate's tilt: its controller must act in 'tilt' mode, not "
                              f"{policy.action_mode!r}")  # fmt: skip
        if not (math.isfinite(amplitude) and 0.0 < amplitude <= 0.6):
            raise ConfigError(f"the excitation amplitude must be in (0, 0.6] of the tilt range, got {amplitude!r}")
        lo, hi = hold_s
        if not (0.0 < lo <= hi <= 10.0):
            raise ConfigError(f"the excitation's hold times must be 0 < shortest ≤ longest ≤ 10 s, got {hold_s!r}")
        self.policy, self.rate_hz, self.amplitude, self.hold_s = policy, float(rate_hz), float(amplitude), (lo, hi)
        self.doublet, self.doublet_s = doublet, doublet_s
        self._rng = np.random.default_rng(seed)
        self._left = 0
        self._queue: list[np.ndarray] = []  # the doublet's ticks still to come
        self.offset = np.zeros(2)
        self._mapper: Any = None  # with move_plate: the mapper whose pose offset moves the plate
        self._plate_left = self._plate_hold = 0
        self._plate_from = self._plate_to = np.zeros(2)  # (height, yaw) offsets: the level before and the next
        self._max_tilt_action = math.inf  # with move_plate: the longest tilt action reached at every offset

    def move_plate(self, mapper: Any) -> None:
        """Move the plate in height and yaw too, through ``mapper``'s pose offset (a "tilt"-mode
        :class:`~stewart_gym.actions.ActionMapper`, the one the run sends with); see the module's description."""
        from stewart_gym.actions import ActionMapper

        if mapper.mode != "tilt":
            raise ConfigError(f"identify moves the plate about the controller's tilt: its mapper must be in 'tilt' "
                              f"mode, not {mapper.mode!r}")  # fmt: skip
        scale = ActionMapper(mapper.geometry, mapper.calibration, "pose").pose_scale
        self._lift, self._turn = PLATE_MOVES["z"] * scale[2], PLATE_MOVES["yaw"] * scale[5]
        reach = self._reachable_tilt(mapper)
        if reach < MIN_TILT_ACTION:
            raise ConfigError(f"{mapper.geometry.name} reaches a tilt of only {reach:g} of its range at the plate's "
                              f"height and yaw moves (±{PLATE_MOVES['z']:g} and ±{PLATE_MOVES['yaw']:g} of their "
                              f"reach); the controller needs {MIN_TILT_ACTION:g}: identify it with the panel")  # fmt: skip
        self._mapper, self._max_tilt_action = mapper, reach

    @property
    def max_tilt_action(self) -> float:
        """The longest tilt action (its length) the excitation sends: with plate moves, the one reached at every
        height and yaw; without, unbounded (the mapper clips)."""
        return self._max_tilt_action

    def _reachable_tilt(self, mapper: Any) -> float:
        """The largest tilt action (its length) that the mapper reaches in every direction at the four corners
        of the height and yaw moves (0.05 steps)."""
        best = 0.0
        try:
            for size in np.arange(0.05, 1.0001, 0.05):
                for z, yaw in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
                    mapper.set_offset([0.0, 0.0, z * self._lift, 0.0, 0.0, yaw * self._turn])
                    if any(mapper(size * np.array([math.cos(a), math.sin(a)])).scaled
                           for a in np.linspace(0.0, 2 * math.pi, 24, endpoint=False)):  # fmt: skip
                        return best
                best = float(size)
        finally:
            mapper.set_offset(None)
        return best

    def __getattr__(self, name: str) -> Any:  # the policy's own description: geometry, env id, observer, …
        if name == "policy":  # not set yet (copying): no recursion
            raise AttributeError(name)
        return getattr(self.policy, name)

    def reset(self) -> None:
        """The policy's state cleared; the sequence goes on."""
        self.policy.reset()

    def _next_level(self) -> None:
        if self._mapper is not None and self._rng.random() < PLATE_TRIPLETS:
            angle = self._rng.uniform(0.0, 2.0 * math.pi)
            size = self._rng.uniform(*TRIPLET_SIZE) * min(self._max_tilt_action, 1.0)
            tilt = size * np.array([math.cos(angle), math.sin(angle)])
            part = max(1, int(round(self._rng.uniform(*TRIPLET_S) * self.rate_hz)))
            self._queue = [tilt] * part + [-tilt] * (2 * part) + [tilt] * part
            self._left = len(self._queue)
            return
        lo, hi = self.hold_s
        hold = self._rng.uniform(lo, hi)
        self._left = max(1, int(round(hold * self.rate_hz)))
        if self._rng.random() < hold / 2:  # a doublet about every two seconds
            angle = self._rng.uniform(0.0, 2.0 * math.pi)
            size = self._rng.uniform(*self.doublet) * np.array([math.cos(angle), math.sin(angle)])
            half = max(1, int(round(self._rng.uniform(*self.doublet_s) * self.rate_hz)))
            self._queue = [size] * half + [-size] * half
        if self._rng.random() < 0.15:  # now and then a rest at zero, so that the log holds small moves too
            self.offset = np.zeros(2)
        else:
            self.offset = self._rng.uniform(-self.amplitude, self.amplitude, 2)

    def _next_plate_level(self) -> None:
        self._plate_hold = self._plate_left = max(1, int(round(self._rng.uniform(*PLATE_HOLD_S) * self.rate_hz)))
        z, yaw = self._rng.uniform(-1.0, 1.0, 2)
        self._plate_from, self._plate_to = self._plate_to, np.array([z * self._lift, yaw * self._turn])

    def _move_plate_on(self) -> None:
        """This tick's height and yaw offset: along the half cosine from the last level to the next, then held."""
        ramp = max(1, int(round(PLATE_RAMP_S * self.rate_hz)))
        done = min((self._plate_hold - self._plate_left) / ramp, 1.0)
        z, yaw = self._plate_from + (self._plate_to - self._plate_from) * 0.5 * (1.0 - math.cos(math.pi * done))
        self._mapper.set_offset([0.0, 0.0, z, 0.0, 0.0, yaw])

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if self._left <= 0:
            self._next_level()
        self._left -= 1
        if self._mapper is not None:
            if self._plate_left <= 0:
                self._next_plate_level()
            self._plate_left -= 1
            self._move_plate_on()
        action = np.asarray(self.policy(obs), dtype=np.float64)
        action = np.clip(action + (self._queue.pop(0) if self._queue else self.offset), -1.0, 1.0)
        size = float(np.hypot(*action))
        if size > self._max_tilt_action:  # with plate moves: within reach at every height and yaw
            action = action * (self._max_tilt_action / size)
        return action
