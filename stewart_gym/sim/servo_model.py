"""What a hobby servo does with a pulse before its motor moves.

:class:`HobbyServos` turns the pulse widths sent to six servos into the shaft
angle each servo aims for, as a hobby servo's electronics would:

1. **command resolution**: pulses are quantised to ``resolution_us``;
2. **response lag**: a pulse takes effect ``lag_s`` later (frame decode and
   electronics);
3. **dead band**: a servo ignores a new pulse within ``deadband_us`` of the one
   it is holding;
4. **trim error**: a physical servo's neutral differs from the calibration's by
   ``trim_error_us`` (the error a user removes with trims);
5. decoding through the same :class:`~stewart_gym.calibration.ServoCalibration` as
   the hardware.

The motor then turns towards that angle no faster than ``max_speed`` and with at
most ``stall_torque`` (applied by the simulator's joint motors).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from stewart_gym.calibration import ServoCalibration

__all__ = ["LINEAR_ACTUATOR", "HobbyServos", "ServoSpec"]


@dataclass(frozen=True)
class ServoSpec:
    """A hobby servo's behaviour; defaults are an MG996R at 4.8 V (the docs: Sources).

    Attributes:
        max_speed: rad/s, no-load speed (0.17 s/60° ≈ 6.16 rad/s); m/s for a linear actuator.
        stall_torque: N·m, the most the motor applies (9.4 kgf·cm ≈ 0.92 N·m); N for a linear actuator.
        deadband_us: µs, pulse changes this small are ignored.
        resolution_us: µs, command quantisation (0.25 µs: a Pololu Maestro's quarter-µs
            units; a PCA9685 at 50 Hz has 4.88 µs).
        lag_s: s, dead time from pulse to motion.
        trim_error_us: (6,) µs, physical neutral minus calibrated neutral, per servo.
        position_gain, velocity_gain: gains of the simulator's position motor.
    """

    max_speed: float = math.radians(60.0) / 0.17
    stall_torque: float = 9.4 * 9.80665 / 100.0
    deadband_us: float = 5.0
    resolution_us: float = 0.25
    lag_s: float = 0.010
    trim_error_us: tuple[float, ...] = field(default=(0.0,) * 6)
    position_gain: float = 0.3
    velocity_gain: float = 1.0

    def __post_init__(self) -> None:
        for key in ("max_speed", "stall_torque"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key}: must be positive, got {getattr(self, key)!r}")
        for key in ("deadband_us", "resolution_us", "lag_s"):
            if not getattr(self, key) >= 0:
                raise ValueError(f"{key}: must be non-negative, got {getattr(self, key)!r}")
        trim = self.trim_error_us
        if not (type(trim) is tuple and len(trim) == 6 and all(type(v) is float for v in trim)):  # else as it is
            trim = tuple(float(v) for v in np.broadcast_to(np.asarray(trim, dtype=float), (6,)))
            object.__setattr__(self, "trim_error_us", trim)


#: An RC linear actuator (Actuonix-style: 1000 µs retracted, 2000 µs extended): speed in m/s, force in N.
LINEAR_ACTUATOR = ServoSpec(max_speed=0.10, stall_torque=400.0, deadband_us=5.0, position_gain=0.3)


class HobbyServos:
    """Pulse-to-target logic of six hobby servos, advanced in physics steps.

    Args:
        spec: The servo behaviour.
        calibration: Decodes pulses (µs) into angles (rad).
        physics_dt: s, the physics step; the lag is rounded to whole steps.
    """

    def __init__(self, spec: ServoSpec, calibration: ServoCalibration, physics_dt: float) -> None:
        self.spec = spec
        self.calibration = calibration
        self.delay_steps = int(round(spec.lag_s / physics_dt))
        self._trim = list(spec.trim_error_us)
        self._queue: deque[tuple[int, list[float]]] = deque()
        self._held = calibration.neutral_us.tolist()

    @property
    def held_us(self) -> np.ndarray:
        """(6,) µs: the pulses the servos act on now (after lag and dead band)."""
        return np.array(self._held)

    def reset(self, pulses_us: np.ndarray | None = None) -> list[float]:
        """Forget pending commands and hold ``pulses_us`` (default neutral); return the target angles."""
        self._queue.clear()
        held = self.calibration.neutral_us if pulses_us is None else pulses_us
        self._held = np.asarray(held, dtype=np.float64).reshape(6).tolist()
        return self.target_angles()

    def command(self, pulses_us: np.ndarray, step: int) -> np.ndarray:
        """Accept pulses (6,) µs sent at physics step ``step``; return them as quantised.

        Raises :class:`~stewart_gym.calibration.PulseRangeError` if any pulse is outside
        the calibration's channel limits or not finite: nothing is sent then.
        """
        pulses = np.asarray(pulses_us, dtype=np.float64).reshape(6).tolist()
        if not self.calibration.in_range_one(pulses):
            self.calibration.check(np.array(pulses))  # raises, naming the channel
        res = self.spec.resolution_us
        quantised = [round(w / res) * res for w in pulses] if res > 0 else pulses
        self._queue.append((step + self.delay_steps, quantised))
        return np.array(quantised)

    def update(self, step: int) -> list[float] | None:
        """Apply commands due at ``step``; return new target angles (6,) rad, or None if unchanged."""
        changed = False
        band = self.spec.deadband_us
        while self._queue and self._queue[0][0] <= step:
            _, pulses = self._queue.popleft()
            held = [w if abs(w - h) > band else h for w, h in zip(pulses, self._held)]
            if held != self._held:
                self._held = held
                changed = True
        return self.target_angles() if changed else None

    def target_angles(self) -> list[float]:
        """(6,) rad: the shaft angles the servos aim for with the pulses they hold."""
        return self.calibration.angles_one([w - t for w, t in zip(self._held, self._trim)])
