"""Small-array arithmetic for the controllers' 2-vectors.

A control step works on (…, 2) arrays, where numpy's ``clip``, ``linalg.norm`` and ``stack`` wrappers cost
several times the arithmetic they wrap. These three give numpy's values bit for bit (but for the sign of a zero:
−0 clipped at a bound of 0 comes out +0) at a ufunc's cost.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["bounded", "paired", "planar_length"]


def bounded(x: Any, low: Any, high: Any) -> Any:
    """``np.clip(x, low, high)``'s values (NaN stays NaN) without its wrapper: ``min(max(x, low), high)``."""
    return np.minimum(np.maximum(x, low), high)


def planar_length(v: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """``np.linalg.norm(v, axis=-1, keepdims=keepdims)`` of 2-vectors (…, 2), the same values: √(x·x + y·y)."""
    x, y = v[..., 0], v[..., 1]
    length = np.sqrt(x * x + y * y)
    return length[..., None] if keepdims else length


def paired(x: Any, y: Any) -> np.ndarray:
    """``np.stack([x, y], axis=-1)`` of two float arrays of one shape: (…, 2), float64."""
    out = np.empty(np.shape(x) + (2,))
    out[..., 0] = x
    out[..., 1] = y
    return out
