"""Scheduling values given in the physical signal they come from, their numeric images derived once.

The scheduling map is declared once, in ``[experiment] scheduling`` (column → expression of plant
signals, e.g. ``sin_arm = "sin(arm_angle)"``). Keys that need points of the scheduling space —
``[validate] points``, ``[synth] breakpoints``, ``baseline_at`` and ``box`` — may give them as values of
one plant signal instead of hand-typed rows of images::

    points = { signal = "arm_angle", range = [-75, 75], count = 9, unit = "deg" }
    breakpoints = { signal = "arm_angle", values = [-80, -60, -30, 0, 30, 60, 80], unit = "deg" }
    baseline_at = { signal = "arm_angle", values = [0] }
    box = { signal = "arm_angle", range = [-80, 80], unit = "deg" }

Each value v (``unit = "deg"`` converts degrees to the signal's radians) maps to the row
[e_1(v), …, e_np(v)], e_i the ``[experiment] scheduling`` expression of the i-th ``[identify] p`` column
(the column itself when it is a plant signal) evaluated with the signal at v; a box is the smallest box
holding the images of 2001 values evenly spread over the range, ends included. An expression that uses
another signal is one DataError line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from lpvflow.errors import DataError
from lpvflow.experiment.scheduling import evaluate

#: Values a box's range is sampled at (ends included).
BOX_SAMPLES = 2001

#: The keys that accept physical values: (table, key).
KEYS = (("validate", "points"), ("synth", "breakpoints"), ("synth", "baseline_at"), ("synth", "box"))


@dataclass(frozen=True)
class SignalValues:
    """Values of one plant signal (in its own units, degrees already converted) at which the scheduling
    map is evaluated; ``is_range``: the two values are the ends of a range (a box); ``unit``: the unit they
    were given in (``"deg"``: shown in degrees again)."""

    signal: str
    values: tuple[float, ...]
    is_range: bool = False
    unit: str = "rad"

    def shown(self, value: float) -> str:
        """``value`` (in the signal's units) as the design file gave it: degrees with ``°`` for ``"deg"``."""
        return f"{math.degrees(value):.4g}°" if self.unit == "deg" else f"{value:.4g}"


class SignalImages(list):
    """Rows of scheduling points (the numeric form of a key, a list of rows) that keep the plant-signal
    values they are the images of (``source``): ``[synth] breakpoints`` given in the arm angle stay known
    in the arm angle (:mod:`lpvflow.pipeline.rate_certificate`)."""

    def __init__(self, rows: list[list[float]], source: SignalValues) -> None:
        super().__init__(rows)
        self.source = source


def signal_values(value: Any, where: str, *, box: bool = False) -> SignalValues:
    """The table form of the module docstring, checked: ``signal``, ``values`` or ``range`` (with ``count``,
    except for a box), optional ``unit`` ("rad" or "deg")."""
    allowed = {"signal", "values", "range", "count", "unit"} - ({"values", "count"} if box else set())
    example = ('{ signal = "arm_angle", range = [-80, 80], unit = "deg" }' if box else
               '{ signal = "arm_angle", range = [-75, 75], count = 9, unit = "deg" }')
    if not isinstance(value, dict) or set(value) - allowed or not isinstance(value.get("signal"), str):
        raise DataError(f"{where} = {value!r} must be a table like {example}")
    unit = value.get("unit", "rad")
    if unit not in ("rad", "deg"):
        raise DataError(f"{where}.unit = {unit!r} must be \"rad\" or \"deg\"")
    scale = math.pi / 180 if unit == "deg" else 1.0

    def finite(items: Any, what: str) -> list[float]:
        if (not isinstance(items, list) or not items
                or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                           for v in items)):
            raise DataError(f"{where}.{what} = {items!r} must be a non-empty list of numbers")
        return [scale * float(v) for v in items]

    if "range" in value:
        lo_hi = finite(value["range"], "range")
        if len(lo_hi) != 2 or not lo_hi[0] < lo_hi[1]:
            raise DataError(f"{where}.range = {value['range']!r} must be [lo, hi] with lo < hi")
        if box:
            return SignalValues(value["signal"], tuple(lo_hi), is_range=True, unit=unit)
        count = value.get("count")
        if isinstance(count, bool) or not isinstance(count, int) or count < 2 or "values" in value:
            raise DataError(f"{where}: a range needs count = N ≥ 2 (and no values), e.g. {example}")
        return SignalValues(value["signal"], tuple(np.linspace(*lo_hi, count).tolist()), unit=unit)
    if box or "values" not in value or "count" in value:
        raise DataError(f"{where} = {value!r} must be a table like {example}")
    return SignalValues(value["signal"], tuple(finite(value["values"], "values")), unit=unit)


def images(values: SignalValues, p_names: list[str], scheduling: Mapping[str, str], where: str) -> np.ndarray:
    """(M, n_p) rows [e_1(v), …, e_np(v)] for the values v (a range: :data:`BOX_SAMPLES` values over it)."""
    v = np.linspace(*values.values, BOX_SAMPLES) if values.is_range else np.array(values.values)
    rows = []
    for name in p_names:
        expression = scheduling.get(name, name)
        try:
            rows.append(np.broadcast_to(evaluate(expression, {values.signal: v}), v.shape))
        except DataError as exc:
            raise DataError(f"{where}: the scheduling column {name} = {expression!r} is not a function of "
                            f"{values.signal} alone ({exc})") from None
    return np.column_stack(rows)


def with_images(config: dict[str, Any], replace: Any) -> dict[str, Any]:
    """``config`` with every :data:`KEYS` value given as :class:`SignalValues` replaced by its numeric form
    (rows, one point, or a box); ``replace(table, **changes)`` builds the changed table."""
    for table, key in KEYS:
        value = config.get(table) and config[table][key]
        if not isinstance(value, SignalValues):
            continue
        where = f"[{table}] {key}"
        if config.get("identify") is None:
            raise DataError(f"{where} gives values of {value.signal}: the scheduling columns they map to are "
                            "the [identify] p columns, which this file lacks; give the scheduling values")
        experiment = config.get("experiment")
        rows = images(value, list(config["identify"]["p"]), experiment["scheduling"] if experiment else {},
                      where)
        if key == "box":
            numeric: Any = np.column_stack([rows.min(axis=0), rows.max(axis=0)]).tolist()
        elif key == "baseline_at":
            if len(rows) != 1:
                raise DataError(f"{where}: give one value of {value.signal} (the baseline's point)")
            numeric = rows[0].tolist()
        else:
            numeric = SignalImages(rows.tolist(), value)
        config[table] = replace(config[table], **{key: numeric})
    return config
