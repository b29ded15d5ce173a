"""stewart_gym: simulator, RL environments, kinematics and hardware tools for servo Stewart platforms.

Quick start::

    import numpy as np
    from stewart_gym import load_preset, inverse_kinematics, ServoCalibration

    geo = load_preset("servo-hexapod")
    ik = inverse_kinematics(geo, np.array([0.01, 0, 0, 0, np.radians(5), 0]))
    pulses = ServoCalibration.default(geo).pulse_widths(ik.servo_angles)
"""

import importlib.util

from stewart_gym.calibration import CalibrationError, PulseRangeError, ServoCalibration
from stewart_gym.envs import ENV_IDS, register_envs
from stewart_gym.geometry import GeometryError, PlatformGeometry
from stewart_gym.kinematics import (
    FKResult,
    IKResult,
    LegStatus,
    actuator_jacobian,
    forward_kinematics,
    inverse_kinematics,
    rotation_matrix,
)
from stewart_gym.presets import load_geometry, load_preset, preset_names

__version__ = "0.1.0"

if importlib.util.find_spec("gymnasium") is not None:  # without the [sim] extra: kinematics, analyses, deploy
    register_envs()

__all__ = [
    "ENV_IDS",
    "CalibrationError",
    "FKResult",
    "GeometryError",
    "IKResult",
    "LegStatus",
    "PlatformGeometry",
    "PulseRangeError",
    "ServoCalibration",
    "actuator_jacobian",
    "forward_kinematics",
    "inverse_kinematics",
    "load_geometry",
    "load_preset",
    "preset_names",
    "rotation_matrix",
]
