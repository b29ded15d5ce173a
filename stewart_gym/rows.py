"""Writing rows of a 2-D array at the speed of 1-D indexing.

NumPy copies ``table[rows] = values`` for a 2-D ``table`` item by item, about ten times slower than a 1-D array of
as many numbers; :func:`put_rows` writes the same rows as one run where ``rows`` are all of them, in order, and
otherwise as whole rows (each row one item of a void view), with the same bits. (To read rows, ``table.take(rows,
axis=0)`` and ``table.compress(mask, axis=0)`` are NumPy's own fast paths.)
"""

from __future__ import annotations

import numpy as np

__all__ = ["put_rows"]


def put_rows(table: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """``table[rows] = values`` for a C-contiguous ``table`` (n, …) and row numbers ``rows``, each row
    ``values[k]`` (broadcast to ``table``'s row shape), faster."""
    rows = np.asarray(rows)
    n = table.shape[0]
    if rows.shape == (n,) and n and np.array_equal(rows, np.arange(n)):
        table[...] = values
        return
    if not table.flags.c_contiguous or table.ndim < 2 or not len(rows):
        table[rows] = values
        return
    items = np.ascontiguousarray(np.broadcast_to(np.asarray(values, dtype=table.dtype), (len(rows), *table.shape[1:])))
    row = np.dtype((np.void, table.dtype.itemsize * (table.size // n)))
    table.reshape(n, -1).view(row).reshape(n)[rows] = items.reshape(len(rows), -1).view(row).reshape(len(rows))
