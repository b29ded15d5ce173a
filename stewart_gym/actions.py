"""Actions → platform pose → servo pulse widths: the one path for simulation and hardware.

An action is a vector in [-1, 1]. :class:`ActionMapper` turns it into a pose
(``"tilt"``: roll and pitch; ``"pose"``: all six axes) and through
:func:`~stewart_gym.kinematics.inverse_kinematics` and
:meth:`~stewart_gym.calibration.ServoCalibration.pulse_widths` into pulses (µs); or,
in ``"pulse"`` mode, scales it straight to each channel's pulse range.

An unreachable commanded pose is replaced by the **nearest reachable pose along
the ray from home** (the largest fraction s ∈ [0, 1) of it that is reachable),
and the result says so (``scaled``, ``scale``). Nothing is clipped silently.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import numpy as np

from stewart_gym.calibration import ServoCalibration, servo_pulses_one
from stewart_gym.errors import ConfigError, UnreachableError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import axis_ranges, inverse_kinematics, pulses_many
from stewart_gym.presets import load_geometry

__all__ = ["ACTION_MEANINGS", "ACTION_MODES", "ACTION_SIZES", "ActionMapper", "MappedAction", "MappedActions",
           "action_table", "default_max_tilt"]  # fmt: skip

ActionMode = Literal["tilt", "pose", "pulse"]
ACTION_MODES: tuple[str, ...] = ("tilt", "pose", "pulse")
#: Number of action values of each mode.
ACTION_SIZES: dict[str, int] = {"tilt": 2, "pose": 6, "pulse": 6}
#: What an action in [-1, 1] means in each mode, and in what unit (the docs' table is generated from it).
ACTION_MEANINGS: dict[str, tuple[str, str]] = {
    "tilt": ("roll, pitch = action · `max_tilt` (default 10°, less where the geometry reaches less)", "rad"),
    "pose": ("x, y, z, roll, pitch, yaw = action · 0.9 · the reach from home along each axis", "m, rad"),
    "pulse": ("pulse widths, −1…1 across each channel's calibrated range", "µs"),
}


def action_table() -> str:
    """The action modes as a Markdown table (generated from :data:`ACTION_SIZES` and :data:`ACTION_MEANINGS`)."""
    rows = ["| `action_mode` | n | meaning of the action | unit |", "|---|---|---|---|"]
    rows += [f"| `{m}` | {ACTION_SIZES[m]} | {ACTION_MEANINGS[m][0]} | {ACTION_MEANINGS[m][1]} |" for m in ACTION_MODES]
    return "\n".join(rows)
#: Default largest tilt (roll or pitch) of the "tilt" mode, rad, where the geometry reaches it (see default_max_tilt).
DEFAULT_MAX_TILT = math.radians(10.0)
#: The "tilt" mode keeps this margin inside the geometry's own roll and pitch reach.
TILT_REACH_MARGIN = 0.9


def default_max_tilt(geometry: PlatformGeometry | str) -> float:
    """rad: 10°, or 90 % of the smallest roll or pitch the geometry reaches from home, whichever is smaller."""
    reach = axis_ranges(load_geometry(geometry))
    return float(min(DEFAULT_MAX_TILT, TILT_REACH_MARGIN * float(np.min(np.abs(reach[3:5])))))


#: The ray search: scan steps from home, then bisections (1/16 / 2⁸ = 1/4096 of the pose).
_RAY_SCAN, _RAY_BISECT = 16, 8
#: Unreachable poses whose ray search :meth:`ActionMapper.reachable_pose` remembers (a saturated action repeats
#: one of a few, such as a diagonal tilt's corner): the answer is the same, without its 25 IK passes.
_RAY_ENDS_KEPT = 256


class MappedAction(NamedTuple):
    """The result of mapping one action.

    Attributes:
        pose: (6,) m, rad: the pose sent (after ray scaling); NaN in "pulse" mode.
        pulses: (6,) µs: what goes to the servos, always within the channel limits.
        scaled: True if the commanded pose was unreachable and was scaled back.
        scale: the fraction of the commanded pose that was sent (1.0 if reachable).
        action: the action as applied, clipped to [-1, 1] (Python floats).
    """

    pose: np.ndarray
    pulses: np.ndarray
    scaled: bool
    scale: float
    action: tuple[float, ...]


class MappedActions(NamedTuple):
    """The result of mapping many actions (:meth:`ActionMapper.map_arrays`): row i is what
    :class:`MappedAction` holds for action i.

    Attributes:
        poses: (n, 6) m, rad: the poses sent (after ray scaling); NaN in "pulse" mode.
        pulses: (n, 6) µs: what goes to the servos, always within the channel limits.
        scaled: (n,) True where the commanded pose was unreachable and was scaled back.
        scales: (n,) the fraction of each commanded pose that was sent.
        actions: (n, size) the actions as applied, clipped to [-1, 1].
    """

    poses: np.ndarray
    pulses: np.ndarray
    scaled: np.ndarray
    scales: np.ndarray
    actions: np.ndarray


class ActionMapper:
    """Maps actions in [-1, 1] to servo pulses.

    Args:
        geometry: The platform (rotary).
        calibration: Pulse mapping; default :meth:`ServoCalibration.default`.
        mode: ``"tilt"`` (2-D: roll, pitch), ``"pose"`` (6-D: x, y, z, roll,
            pitch, yaw) or ``"pulse"`` (6-D: pulse widths).
        max_tilt: rad, roll/pitch at action ±1 in "tilt" mode (default
            :func:`default_max_tilt` of the geometry: 10° where it reaches that).
        pose_scale: (6,) m, rad, the pose at action +1 per axis in "pose" mode;
            default 90 % of the smaller of each axis' reach from home.
    """

    def __init__(self, geometry: PlatformGeometry | str = "servo-hexapod", calibration: ServoCalibration | None = None,
                 mode: ActionMode = "tilt", *, max_tilt: float | None = None,
                 pose_scale: np.ndarray | None = None) -> None:  # fmt: skip
        if mode not in ACTION_MODES:
            raise ConfigError(f"action mode must be one of {ACTION_MODES}, got {mode!r}")
        self.geometry = load_geometry(geometry)
        self.calibration = calibration or ServoCalibration.default(self.geometry)
        self.mode = mode
        self.max_tilt = default_max_tilt(self.geometry) if max_tilt is None else float(max_tilt)
        if not (math.isfinite(self.max_tilt) and 0 < self.max_tilt < math.pi / 2):
            raise ConfigError(f"max_tilt must be in (0, π/2) rad, got {max_tilt!r}")
        if pose_scale is None:
            reach = axis_ranges(self.geometry)
            pose_scale = 0.9 * np.minimum(-reach[:, 0], reach[:, 1])
        self.pose_scale = np.asarray(pose_scale, dtype=np.float64).reshape(6)
        self._pose_scale = self.pose_scale.tolist()
        self.size = ACTION_SIZES[mode]
        self._offset: list[float] | None = None
        self._ray_ends: dict[tuple[float, ...], tuple[float, list[float]]] = {}  # unreachable pose → (scale, pulses)

    @property
    def offset(self) -> np.ndarray:
        """(6,) m, rad: the pose added to every commanded pose ("tilt" and "pose" modes); zeros unless set."""
        return np.zeros(6) if self._offset is None else np.array(self._offset)

    def set_offset(self, pose: np.ndarray | None) -> None:
        """Add ``pose`` (6,) (x, y, z, roll, pitch, yaw; m, rad) to every commanded pose from now on; None: none.
        ``identify`` moves the plate's height and yaw this way while its controller tilts the plate."""
        if pose is None:
            self._offset = None
            return
        values = [float(v) for v in np.asarray(pose, dtype=np.float64).reshape(6)]
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"the pose offset must be finite, got {values}")
        self._offset = values if any(values) else None

    def pose(self, action: np.ndarray) -> np.ndarray:
        """The commanded pose (6,) for an action ("tilt" or "pose" mode); actions are clipped to [-1, 1]."""
        if self.mode == "pulse":
            raise ValueError("'pulse' mode has no pose")
        return np.array(self._pose_list(_clip_unit(np.asarray(action, dtype=np.float64).reshape(self.size).tolist())))

    def _pose_list(self, clipped: list[float]) -> list[float]:
        """:meth:`pose` of a clipped "tilt" or "pose" action, in and out as Python floats."""
        if self.mode == "tilt":
            pose = [0.0, 0.0, 0.0, clipped[0] * self.max_tilt, clipped[1] * self.max_tilt, 0.0]
        else:
            pose = [v * k for v, k in zip(clipped, self._pose_scale)]
        return pose if self._offset is None else [p + o for p, o in zip(pose, self._offset)]

    def reachable_pose(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(pose, pulses, scale): ``pose`` if feasible, else the farthest feasible point on the ray from home.

        Feasible means reachable by the IK and within the calibration's pulse
        limits. The ray is scanned at 1/16 steps from home to the first
        infeasible fraction, then bisected 8 times (resolution 1/4096 of the
        pose), each test one scalar IK pass (:func:`servo_pulses_one`, ~6 µs). The
        last 256 unreachable poses' answers are kept: a saturated action repeats
        a few poses (a diagonal tilt's corner), each then found without a search.
        """
        target = [float(v) for v in np.asarray(pose, dtype=np.float64).reshape(6)]
        known = self._ray_ends.get(tuple(target))
        if known is not None:  # searched before: the same answer
            return known[0] * np.array(target), np.array(known[1]), known[0]

        def pulses_at(frac: float) -> list[float] | None:
            return servo_pulses_one(self.geometry, self.calibration, [frac * v for v in target])

        best = pulses_at(1.0)
        if best is not None:
            return np.array(target), np.array(best), 1.0
        lo, best = 0.0, pulses_at(0.0)
        if best is None:
            raise UnreachableError(f"{self.geometry.name}: the home pose itself cannot be commanded with this "
                                   "calibration")  # fmt: skip
        hi = 1.0
        for k in range(1, _RAY_SCAN + 1):  # the first infeasible step from home
            got = pulses_at(k / _RAY_SCAN)
            if got is None:
                hi = k / _RAY_SCAN
                break
            lo, best = k / _RAY_SCAN, got
        for _ in range(_RAY_BISECT):
            mid = 0.5 * (lo + hi)
            got = pulses_at(mid)
            if got is None:
                hi = mid
            else:
                lo, best = mid, got
        if len(self._ray_ends) >= _RAY_ENDS_KEPT:
            self._ray_ends.clear()
        self._ray_ends[tuple(target)] = (float(lo), best)
        return lo * np.array(target), np.array(best), float(lo)

    def __call__(self, action: np.ndarray) -> MappedAction:
        """Map one action (size :attr:`size`) to pulses; non-finite actions raise ``ValueError``.

        A feasible pose takes the scalar path (:func:`servo_pulses_one`, ~6 µs);
        only an unreachable one pays for the batched ray search.
        """
        if type(action) is np.ndarray and action.shape == (self.size,) and action.dtype.kind == "f":
            values = action.tolist()  # the common case, without an array conversion
        else:
            values = np.asarray(action, dtype=np.float64).reshape(self.size).tolist()
        if not math.isfinite(sum(values)):  # NaN for NaN or ±inf
            raise ValueError(f"action must be finite, got {values}")
        clipped = _clip_unit(values)
        if self.mode == "pulse":
            pulses = []
            for v, (_, _, _, low, high) in zip(clipped, self.calibration.pulse_map):
                w = low + (v + 1.0) * 0.5 * (high - low)  # at +1 rounding can land a hair outside: keep it on the limit
                pulses.append(low if w < low else high if w > high else w)
            return MappedAction(np.full(6, np.nan), np.array(pulses), False, 1.0, tuple(clipped))
        pose = self._pose_list(clipped)
        fast = servo_pulses_one(self.geometry, self.calibration, pose)
        if fast is not None:
            return MappedAction(np.array(pose), np.array(fast), False, 1.0, tuple(clipped))
        best, pulses, scale = self.reachable_pose(np.array(pose))
        return MappedAction(best, pulses, scale < 1.0, scale, tuple(clipped))

    def map_arrays(self, actions: np.ndarray) -> MappedActions:
        """:meth:`__call__` of many actions (rows × :attr:`size`) at once, as arrays: one compiled IK pass for the
        feasible poses (:func:`~stewart_gym.kinematics.pulses_many`; without numba, the batched
        :func:`~stewart_gym.kinematics.inverse_kinematics`), the scalar path for the rest (and for "pulse" mode).
        Row by row the same results as one call per action (without numba, the pulses to rounding)."""
        values = np.asarray(actions, dtype=np.float64).reshape(-1, self.size)
        if not np.isfinite(values).all():
            row = int(np.flatnonzero(~np.isfinite(values).all(axis=1))[0])
            raise ValueError(f"action must be finite, got {values[row].tolist()} (row {row})")
        clipped = np.clip(values, -1.0, 1.0)
        n = len(values)
        if self.mode == "pulse" or n == 0:
            ones = [self(row) for row in values]
            return MappedActions(np.array([m.pose for m in ones]).reshape(n, 6),
                                 np.array([m.pulses for m in ones]).reshape(n, 6), np.zeros(n, dtype=bool),
                                 np.ones(n), clipped)  # fmt: skip
        if self.mode == "tilt":
            poses = np.zeros((n, 6))
            poses[:, 3:5] = clipped * self.max_tilt
        else:
            poses = clipped * self.pose_scale
        if self._offset is not None:
            poses = poses + self._offset
        each = pulses_many(self.geometry, poses, self.calibration.pulse_map)  # compiled: the scalar path's numbers
        if each is not None:
            pulses, usable = each
        else:  # pragma: no cover - the dev install has numba
            ik = inverse_kinematics(self.geometry, poses)
            pulses = self.calibration.pulse_widths(ik.servo_angles, out_of_range="nan")
            usable = ik.reachable & np.isfinite(pulses).all(axis=1)
        scaled, scales = np.zeros(n, dtype=bool), np.ones(n)
        for row in np.flatnonzero(~usable):
            one = self(values[row])
            poses[row], pulses[row], scaled[row], scales[row] = one.pose, one.pulses, one.scaled, one.scale
        return MappedActions(poses, pulses, scaled, scales, clipped)


def _clip_unit(values: list[float]) -> list[float]:
    """Python floats clipped to [-1, 1]."""
    return [1.0 if v > 1.0 else -1.0 if v < -1.0 else v for v in values]
