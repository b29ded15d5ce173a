"""The envs' constructor arguments, checked at the edge before anything is built.

A number must be a real number (a Python or NumPy int or float, not a bool or a string), finite and in its range;
a spec must be of its class; a switch must be true or false. A bad one is a
:class:`~stewart_gym.errors.ConfigError` naming the argument (``gym.make(id, control_hz="50")``, ``ball=5``), not an
``AttributeError`` from deep inside the engine, or a bool taken as 1.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from stewart_gym.checks import real_number
from stewart_gym.envs.randomization import RandomizationRanges
from stewart_gym.errors import ConfigError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.sim import BallSpec, ServoSpec

__all__ = ["MAX_CONTROL_HZ", "MAX_PHYSICS_HZ", "check_engine_arguments", "check_randomization", "real_number", "spec_of",
           "true_or_false"]  # fmt: skip

#: Hz: the highest control rate an env takes (a deploy loop's own limit is 500 Hz).
MAX_CONTROL_HZ = 1000
#: Hz: the highest physics rate an env takes.
MAX_PHYSICS_HZ = 100_000


def true_or_false(name: str, value: Any) -> bool:
    """``value`` as a bool: True or False (NumPy's too); else a ConfigError naming ``name``."""
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{name} must be true or false, got {value!r}")
    return bool(value)


#: s: the longest episode an env takes, and the latest time a task may schedule something in one.
MAX_EPISODE_S = 3600.0


def number_range(name: str, value: Any, low: float, high: float, unit: str = "") -> tuple[float, float]:
    """``value`` as a (low, high) pair of Python floats: a sequence (tuple, list, 1-D array) of two finite real
    numbers, the first at most the second, both within [``low``, ``high``] (in ``unit``); else a ConfigError
    naming ``name``."""
    pair = (f"{name} must be a (low, high) pair of numbers from {low:g} to {high:g}{unit and ' ' + unit}, "
            f"got {value!r}")  # fmt: skip
    if isinstance(value, np.ndarray):
        value = value.tolist() if value.ndim == 1 else None
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ConfigError(pair)
    first = real_number(f"{name}[0]", value[0], low=low, high=high)
    second = real_number(f"{name}[1]", value[1], low=low, high=high)
    if first > second:
        raise ConfigError(f"{name} must be a (low, high) pair with low ≤ high, got {value!r}")
    return float(first), float(second)


def spec_of(name: str, value: Any, classes: type | tuple[type, ...], what: str) -> Any:
    """``value`` where it is None or of ``classes``; else a ConfigError naming ``name`` and saying ``what`` it
    takes."""
    if value is not None and not isinstance(value, classes):
        raise ConfigError(f"{name} must be {what}, got {value!r} ({type(value).__name__})")
    return value


def check_engine_arguments(geometry: Any, control_hz: Any, physics_hz: Any, ball: Any, servo: Any) -> tuple[int, Any]:
    """The arguments an engine is built from, checked (:func:`real_number`, :func:`spec_of`): the geometry (a preset
    name, a TOML path or a :class:`~stewart_gym.geometry.PlatformGeometry`), the rates (whole numbers of Hz; the
    physics rate None for the engine's own), the ball and servo specs. Returns the rates as Python ints."""
    if not isinstance(geometry, (str, os.PathLike, PlatformGeometry)):
        raise ConfigError(f"geometry must be a preset name, a TOML path or a PlatformGeometry, got {geometry!r}")
    control = real_number("control_hz", control_hz, whole=True, low=1, high=MAX_CONTROL_HZ)
    physics = real_number("physics_hz", physics_hz, optional=True, whole=True, low=1, high=MAX_PHYSICS_HZ)
    spec_of("ball", ball, BallSpec, "a BallSpec")
    spec_of("servo", servo, ServoSpec, "a ServoSpec")
    return control, physics


def check_randomization(value: Any) -> Any:
    """``randomization``: None, the ranges (:class:`~stewart_gym.envs.randomization.RandomizationRanges`) or a
    mapping of the fields to change; else a ConfigError."""
    return spec_of("randomization", value, (RandomizationRanges, Mapping),
                   "RandomizationRanges or a mapping of its fields")  # fmt: skip
