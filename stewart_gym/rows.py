"""Writing rows of a 2-D array at the speed of 1-D indexing.

NumPy copies ``table[rows] = values`` for a 2-D ``table`` item by item, several times slower than a 1-D array of as
many numbers; :func:`put_rows` writes the same rows as one run where ``rows`` are all of them, in order, and
otherwise as whole rows (each row one item of a void view), with the same bits. (To read rows, ``table.take(rows,
axis=0)`` and ``table.compress(mask, axis=0)`` are NumPy's own fast paths.)
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["put_rows"]


def put_rows(table: np.ndarray, rows: Any, values: Any) -> None:
    """``table[rows] = values``, faster where ``table`` (n, …) is C-contiguous and ``rows`` is a 1-D array of
    row numbers; anything else (a mask, a slice, an object table, …) goes to NumPy's own indexing, with its
    results and errors."""
    index = np.asarray(rows)
    values = np.asarray(values, dtype=table.dtype) if not table.dtype.hasobject else values
    n = table.shape[0] if table.ndim else 0
    if (index.ndim != 1 or index.dtype.kind not in "iu" or table.ndim < 2 or not table.flags.c_contiguous
            or table.dtype.hasobject or table.size == 0 or len(index) == 0 or values.ndim > table.ndim):  # fmt: skip
        table[rows] = values
        return
    if len(index) == n and np.array_equal(index, np.arange(n)):
        table[...] = values
        return
    items = np.ascontiguousarray(np.broadcast_to(values, (len(index), *table.shape[1:])))
    row = np.dtype((np.void, table.dtype.itemsize * (table.size // n)))
    table.reshape(n, -1).view(row).reshape(n)[index] = items.reshape(len(index), -1).view(row).reshape(len(index))
