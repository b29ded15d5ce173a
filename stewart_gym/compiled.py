"""Hot loops compiled with numba, where numba is installed (the ``sim`` extra has it).

:func:`compiled` compiles a function with numba (cached on disk, so only its first use in a checkout compiles it;
the GIL released while it runs), or gives None without numba: a caller then keeps its NumPy path.
:func:`exp_each` is ``math.exp`` of each element of an array at C speed, the same numbers as Python's
``math.exp`` gives (both are the C library's ``exp``), which ``np.exp``'s SIMD code does not always give.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from stewart_gym.errors import ConfigError

__all__ = ["AVAILABLE", "KERNELS", "compiled", "exp_each", "use_compiled"]

try:
    import numba
except ImportError:  # pragma: no cover - the dev install has numba
    numba = None

#: Whether numba imports, so that :func:`compiled` compiles.
AVAILABLE = numba is not None


#: The ways a hot loop can run (a ``kernel`` argument): ``"numba"``, compiled; ``"numpy"``, as arrays; ``"auto"``,
#: compiled where numba is installed.
KERNELS = ("auto", "numba", "numpy")


def use_compiled(kernel: str, available: bool) -> bool:
    """Whether a ``kernel`` argument (:data:`KERNELS`) runs the compiled loop, which is ``available`` or not;
    raises :class:`~stewart_gym.errors.ConfigError` for an unknown kernel, or ``"numba"`` where it is not."""
    if kernel not in KERNELS:
        raise ConfigError(f"kernel: one of {', '.join(KERNELS)}, got {kernel!r}")
    if kernel == "numba" and not available:
        raise ConfigError("kernel 'numba' needs numba: pip install numba (or use kernel 'numpy')")
    return kernel != "numpy" and available


def compiled(function: Callable[..., Any]) -> Callable[..., Any] | None:
    """``function`` compiled by numba, or None without numba: cached on disk (where numba finds nowhere writable
    to cache, such as a read-only install with no writable home, it compiles in each process instead), the GIL
    released while it runs, and floating-point arithmetic as NumPy's (a division by zero gives inf or NaN, as in
    the NumPy path, instead of raising ``ZeroDivisionError``)."""
    if not AVAILABLE:
        return None
    try:
        return numba.njit(cache=True, nogil=True, error_model="numpy")(function)
    except RuntimeError:  # "cannot cache function …: no locator available"
        return numba.njit(cache=False, nogil=True, error_model="numpy")(function)


def _exp_into(x: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        out[i] = math.exp(x[i])


_exp_compiled = compiled(_exp_into)


def exp_each(x: np.ndarray) -> np.ndarray:
    """``math.exp`` of each element of the 1-D float64 array ``x``, as a new array (to the last bit Python's)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    if _exp_compiled is None:  # pragma: no cover - the dev install has numba
        return np.array([math.exp(v) for v in x.tolist()], dtype=np.float64)
    out = np.empty_like(x)
    _exp_compiled(x, out)
    return out
