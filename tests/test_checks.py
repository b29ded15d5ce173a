"""The checks every input goes through at the edge: one message each, naming the input and its range in words."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stewart_gym.checks import real_number
from stewart_gym.errors import ConfigError


@pytest.mark.parametrize(("kwargs", "value", "message"), [
    ({"low": 0.0, "low_open": True}, 0.0, "x must be a finite number above 0, got 0.0"),
    ({"low": 0.0}, -1.0, "x must be a finite number at least 0, got -1.0"),
    ({"high": 1.0}, 2.0, "x must be a finite number at most 1, got 2.0"),
    ({"low": 1, "high": 1000, "whole": True}, 0, "x must be a whole number in [1, 1000], got 0"),
    ({"low": 1, "whole": True}, 0, "x must be a whole number at least 1, got 0"),
    ({"low": 1, "whole": True}, 2.5, "x must be a whole number, got 2.5"),
    ({}, math.inf, "x must be a finite number, got inf"),
    ({}, True, "x must be a number, got True (bool)"),
    ({}, np.array([1.0]), "x must be a number, got array([1.]) (ndarray)"),
])  # fmt: skip
def test_a_number_out_of_its_range_is_named_with_the_range_in_words(kwargs: dict, value: object,
                                                                     message: str) -> None:  # fmt: skip
    with pytest.raises(ConfigError) as caught:
        real_number("x", value, **kwargs)
    assert str(caught.value) == message


def test_a_number_in_its_range_comes_back_as_a_python_number() -> None:
    assert real_number("x", np.float32(0.5), low=0.0, high=1.0) == 0.5
    assert type(real_number("x", np.int64(3), whole=True, low=1)) is int
    assert real_number("x", None, optional=True) is None
