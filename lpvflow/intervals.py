"""The one check of a ``[min, max]`` interval, shared by the design file's keys, the verify scenarios and
the experiment's API (output bounds, actuator limits, …)."""

from __future__ import annotations

import math

from lpvflow.errors import DataError


def interval(value: object, where: str) -> tuple[float, float]:
    """``value`` as (min, max): a list or tuple of two finite numbers (not booleans) with min < max.

    Raises:
        DataError: anything else, one line naming ``where`` and the value.
    """
    pair = value if isinstance(value, list | tuple) and len(value) == 2 else None
    if pair is None or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                               for v in pair) or not pair[0] < pair[1]:
        raise DataError(f"{where} = {value!r} must be [min, max] with min < max")
    return float(pair[0]), float(pair[1])
