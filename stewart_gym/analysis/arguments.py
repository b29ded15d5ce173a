"""The analyses' arguments, checked before any work: a count is a whole number (not a bool) from its least value; a
size or tolerance a finite number above zero; a set of actuator values, poses or levels of its shape, finite. A bad
one is a :class:`~stewart_gym.errors.ConfigError` (a ``ValueError``) naming the argument, not a hang, a deep NumPy
error or a silently empty answer."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from stewart_gym.errors import ConfigError

__all__ = ["finite_array", "positive_number", "whole_number"]


def whole_number(name: str, value: Any, least: int) -> int:
    """``value`` as an int; raises :class:`ConfigError` unless it is a whole number of at least ``least``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
        raise ConfigError(f"{name} must be a whole number from {least}, got {value!r}")
    return int(value)


def positive_number(name: str, value: Any) -> float:
    """``value`` as a float; raises :class:`ConfigError` unless it is a finite number above zero."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0 < value < math.inf:
        raise ConfigError(f"{name} must be a finite number above zero, got {value!r}")
    return float(value)


def finite_array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (None: any length, at least one), every entry finite; raises
    :class:`ConfigError` otherwise."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be numbers, got {value!r}") from None
    if arr.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, arr.shape)) or arr.size == 0:
        wanted = "(" + ", ".join("n" if n is None else str(n) for n in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ConfigError(f"{name} must have shape {wanted}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite, got a NaN or infinite value")
    return arr
