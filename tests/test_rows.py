"""``put_rows`` writes what NumPy's ``table[rows] = values`` writes, bit for bit, whatever the rows (few, or many:
through its void view)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stewart_gym.rows import VOID_FROM, put_rows

SHAPES = [(2,), (11,), (3, 3), (6,), ()]
DTYPES = [np.float64, np.float32, np.int64, np.bool_]


@settings(max_examples=300, deadline=None)
@given(n=st.integers(1, 40) | st.integers(VOID_FROM, 3 * VOID_FROM), shape=st.sampled_from(SHAPES),
       dtype=st.sampled_from(DTYPES), data=st.data())  # fmt: skip
def test_put_rows_writes_what_fancy_indexing_writes(n: int, shape: tuple[int, ...], dtype: type, data) -> None:
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    kind = data.draw(st.sampled_from(["all", "some", "repeats", "reversed", "none"]))
    rows = {"all": np.arange(n), "some": np.sort(rng.choice(n, rng.integers(1, n + 1), replace=False)),
            "repeats": rng.integers(0, n, rng.integers(1, 2 * n)), "reversed": np.arange(n)[::-1].copy(),
            "none": np.zeros(0, dtype=np.int64)}[kind]  # fmt: skip
    table = (rng.normal(size=(n, *shape)) * 1e3).astype(dtype)
    table[0, ...] = np.nan if dtype in (np.float64, np.float32) else table[0, ...]  # NaNs move as they are
    values = (rng.normal(size=(len(rows), *shape)) * 1e3).astype(dtype)
    expected, got = table.copy(), table.copy()
    expected[rows] = values
    put_rows(got, rows, values)
    assert got.tobytes() == expected.tobytes()


@pytest.mark.parametrize("n", [5, 3 * VOID_FROM])
@pytest.mark.parametrize("value", [0.5, np.array([1.0, -2.0]), np.array([[[3.0, 4.0]]])])
def test_put_rows_broadcasts_one_value_to_every_row(value, n: int) -> None:
    rows = np.arange(1, n, 2)  # every other row: a few, or many
    table, expected = np.zeros((n, 2)), np.zeros((n, 2))
    put_rows(table, rows, value)
    expected[rows] = value
    assert np.array_equal(table, expected)


def test_put_rows_of_a_strided_table_writes_through_to_it() -> None:
    base = np.zeros((6, 4))
    view = base[:, :2]  # not C-contiguous: NumPy's own indexing writes it
    put_rows(view, np.array([0, 5]), np.ones((2, 2)))
    assert base[[0, 5], :2].tolist() == [[1.0, 1.0], [1.0, 1.0]] and base[:, 2:].sum() == 0.0


@pytest.mark.parametrize("rows", [np.array([False, True, True]), np.array([True, True, True]), 1, np.int64(2),
                                  np.array([[0, 2]]), slice(0, 2), [2, 0]])  # fmt: skip
def test_put_rows_of_any_other_index_does_what_numpy_does(rows) -> None:
    """A mask (one that picks every row too), a row number, a 2-D index, a slice or a list: NumPy's own meaning."""
    expected, got = np.zeros((3, 2)), np.zeros((3, 2))
    expected[rows] = 7.0
    put_rows(got, rows, 7.0)
    assert np.array_equal(got, expected)


@pytest.mark.parametrize("rows", [np.arange(3.0), np.array([3]), np.array([0, 1, 2, 5])])
def test_put_rows_refuses_what_numpy_refuses(rows: np.ndarray) -> None:
    """Row numbers that are not whole numbers, or past the table's end: NumPy's IndexError, and nothing written."""
    table = np.zeros((3, 2))
    with pytest.raises(IndexError):
        put_rows(table, rows, 1.0)
    assert not table.any()
