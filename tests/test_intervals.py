"""The one [min, max] check (lpvflow.intervals) and that the design file, the verify scenarios and the
experiment API all refuse the same bad intervals with it."""

import math

import pytest

from lpvflow.errors import DataError
from lpvflow.intervals import interval
from lpvflow.pipeline.key_checks import interval as design_key_interval
from lpvflow.pipeline.scenarios import Loop

BAD = [[1.0, 0.0], [0.5, 0.5], [0.0, math.nan], [-math.inf, 1.0], [True, 2.0], [0.0, "1"], [0.0],
       [0.0, 1.0, 2.0], "0,1", None]


@pytest.mark.parametrize("value", [[-1, 2], (0.25, 0.5), [-1e-9, 1e-9]])
def test_interval_returns_the_floats_in_order(value):
    lo, hi = interval(value, "x")
    assert (lo, hi) == (float(value[0]), float(value[1])) and isinstance(lo, float)


@pytest.mark.parametrize("value", BAD)
def test_every_caller_refuses_a_bad_interval_with_one_line_naming_it(value):
    with pytest.raises(DataError, match=r"^where = .* must be \[min, max\] with min < max$"):
        interval(value, "where")
    with pytest.raises(DataError, match=r"^\[verify\.loop\] actuator_limits\.v = .* must be \[min, max\]"):
        design_key_interval(value, "[verify.loop] actuator_limits.v")
    with pytest.raises(DataError, match=r"^actuator limit of v = .* must be \[min, max\] with min < max$"):
        Loop(measured=("y",), actuated=("v",), scheduling=("y",), actuator_limits={"v": value})
