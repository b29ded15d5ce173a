"""The control step's small-array helpers give numpy's values."""



import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

_FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)


@given(x=st.lists(_FLOATS, min_size=1, max_size=8), bounds=st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)))
@settings(max_examples=200, deadline=None)
def test_the_control_steps_small_array_helpers_give_numpys_values(x: list[float], bounds: tuple[float, float]) -> None:
    """``bounded``, ``planar_length`` and ``paired`` (the controllers' cheap stand-ins for ``np.clip``,
    ``np.linalg.norm(…, axis=-1)`` and ``np.stack(…, axis=-1)``) give numpy's values, bit for bit apart from a
    zero's sign, NaN and infinities included: the published figures were measured with numpy's."""
    from stewart_gym.control import bounded, paired, planar_length

    low, high = min(bounds), max(bounds)
    a = np.array(x)
    np.testing.assert_array_equal(bounded(a, low, high), np.clip(a, low, high))
    vectors = np.array(x + x[:1] if len(x) % 2 else x).reshape(-1, 2)
    with np.errstate(over="ignore", invalid="ignore"):
        np.testing.assert_array_equal(planar_length(vectors), np.linalg.norm(vectors, axis=-1))
        np.testing.assert_array_equal(planar_length(vectors, keepdims=True),
                                      np.linalg.norm(vectors, axis=-1, keepdims=True))  # fmt: skip
        np.testing.assert_array_equal(planar_length(vectors[0]), np.linalg.norm(vectors[0], axis=-1))
    np.testing.assert_array_equal(paired(vectors[:, 0], vectors[:, 1]), np.stack([vectors[:, 0], vectors[:, 1]], -1))
    assert paired(vectors[0, 0], vectors[0, 1]).shape == (2,)
