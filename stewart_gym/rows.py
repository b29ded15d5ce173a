"""Writing rows of a 2-D array at the speed of 1-D indexing.

NumPy copies ``table[rows] = values`` for a 2-D ``table`` item by item, several times slower than a 1-D array of as
many numbers; :func:`put_rows` writes the same rows as one run where ``rows`` are all of them, in order, and
otherwise, for many rows, as whole rows (each row one item of a void view), with the same bits. (To read rows,
``table.take(rows, axis=0)`` and ``table.compress(mask, axis=0)`` are NumPy's own fast paths.)
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["VOID_FROM", "put_rows"]

#: From this many rows (of any table), :func:`put_rows` writes them through a void view: below it NumPy's own row
#: indexing is as fast or faster (about 1,000 rows of 11 float32: 9 µs either way).
VOID_FROM = 1024


def put_rows(table: np.ndarray, rows: Any, values: Any) -> None:
    """``table[rows] = values``, faster where ``table`` (n, …) is C-contiguous and ``rows`` is a 1-D array of
    many row numbers; anything else (a mask, a slice, an object table, a few rows, …) goes to NumPy's own
    indexing, with its results and errors."""
    index = np.asarray(rows)
    if (index.ndim == 1 and index.dtype.kind in "iu" and table.ndim >= 2 and table.flags.c_contiguous
            and not table.dtype.hasobject and table.size and len(index) >= VOID_FROM):  # fmt: skip
        n = table.shape[0]
        if len(index) == n and np.array_equal(index, np.arange(n)):
            table[...] = values
            return
        values = np.asarray(values, dtype=table.dtype)
        if values.ndim <= table.ndim:
            items = np.ascontiguousarray(np.broadcast_to(values, (len(index), *table.shape[1:])))
            row = np.dtype((np.void, table.dtype.itemsize * (table.size // n)))
            table.reshape(n, -1).view(row).reshape(n)[index] = items.reshape(len(index), -1).view(row).reshape(-1)
            return
    table[rows] = values
