"""Numbers and arrays given as arguments, checked at the edge: a number is a real number (a Python or NumPy int or
float, not a bool or a string), finite and in its range; an array has its shape and finite entries. A bad one is a
:class:`~stewart_gym.errors.ConfigError` (a ``ValueError``) naming the argument, not a hang, a deep NumPy error or a
silently wrong answer. The envs' constructors, the kinematics and the analyses use them."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from stewart_gym.errors import ConfigError

__all__ = ["finite_array", "real_number"]


def real_number(name: str, value: Any, *, optional: bool = False, whole: bool = False, low: float = -math.inf,
                high: float = math.inf, low_open: bool = False) -> Any:  # fmt: skip
    """``value`` as a Python int (``whole``: a real number of no fraction) or float, checked: a real number (None
    where ``optional``), not a bool, finite, within [``low``, ``high``] (``(low, high]`` with ``low_open``); else
    a ConfigError naming ``name``."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ConfigError(f"{name} must be {'a whole number' if whole else 'a number'}, got {value!r} "
                          f"({type(value).__name__})")  # fmt: skip
    number = float(value)
    if whole and math.isfinite(number) and not number.is_integer():
        raise ConfigError(f"{name} must be a whole number, got {value!r}")
    if not math.isfinite(number) or number > high or number < low or (low_open and number == low):
        kind = "a whole number" if whole else "a finite number"
        raise ConfigError(f"{name} must be {kind}{_bounds(low, high, low_open)}, got {value!r}")
    return int(number) if whole else number


def _bounds(low: float, high: float, low_open: bool) -> str:
    """The range [``low``, ``high``] (``(low, high]`` with ``low_open``) in words: " above 0", " at least 0",
    " at most 1", " in [1, 1000]", or nothing for every finite number."""
    if high == math.inf:
        return "" if low == -math.inf else f" {'above' if low_open else 'at least'} {low:g}"
    if low == -math.inf:
        return f" at most {high:g}"
    return f" in {'(' if low_open else '['}{low:g}, {high:g}]"


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
