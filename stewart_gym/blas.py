"""numpy's BLAS held to one thread while a hot loop runs.

OpenBLAS splits a large enough matrix product over every core, and its threads then spin while they wait for
the next one. On the products of the batched loops here (the batched simulator's NumPy kernel: a few thousand
3 × 3 rotations times the six plate anchors, many times a second; the fits) the second thread gains next to
nothing, and it takes a core that the training, an evaluation worker or another process wanted: it would keep both
cores of a 2-core machine busy for the steps that one core gives alone. :class:`OneBlasThread` limits the BLAS to one
thread for the duration of a ``with`` (:func:`one_blas_thread`: of a function); a thread computes every
element alike, so the results are the same to the last bit.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["OneBlasThread", "one_blas_thread"]

F = TypeVar("F", bound=Callable[..., Any])


class OneBlasThread:
    """A ``with`` during which every BLAS loaded (numpy's, and any other, such as SciPy's own) runs on one thread
    (threadpoolctl). Its controller, which finds the loaded libraries, is made again only after a module has been
    imported since it was last made (an import is what loads another BLAS), so that entering and leaving costs a
    few microseconds; nested uses keep the one thread."""

    controller: Any = None
    #: ``len(sys.modules)`` when the controller was made
    modules_seen = -1

    def __enter__(self) -> None:
        if len(sys.modules) != OneBlasThread.modules_seen:
            import numpy  # noqa: F401  (the controller finds the BLAS numpy has loaded)
            from threadpoolctl import ThreadpoolController

            OneBlasThread.controller = ThreadpoolController()
            OneBlasThread.modules_seen = len(sys.modules)
        self._limit = OneBlasThread.controller.limit(limits=1, user_api="blas")
        self._limit.__enter__()

    def __exit__(self, *exc: object) -> None:
        self._limit.__exit__(*exc)


def one_blas_thread(func: F) -> F:
    """``func`` run inside :class:`OneBlasThread` (a decorator, for a fit whose every step is a hot loop)."""

    @functools.wraps(func)
    def on_one_thread(*args: Any, **kwargs: Any) -> Any:
        with OneBlasThread():
            return func(*args, **kwargs)

    return on_one_thread  # type: ignore[return-value]
