"""Repeated ``NAME=VALUE`` command-line options (``lpvflow experiment --set``, ``lpvflow validate
--fmu-hold``, …) read into a dict, each defect one DataError line naming the option."""

from __future__ import annotations

import math

from lpvflow.errors import DataError


def assignments(items: list[str] | None, option: str, example: str) -> dict[str, str]:
    """Repeated ``NAME=VALUE`` options -> dict; the value may itself contain '='."""
    result: dict[str, str] = {}
    for item in items or []:
        name, eq, value = item.partition("=")
        name, value = name.strip(), value.strip()
        if not eq or not name or not value:
            raise DataError(f"{option} {item!r} must read NAME=VALUE, e.g. {example}")
        if name in result:
            raise DataError(f"{option} for {name!r} given twice")
        result[name] = value
    return result


def numbers(items: dict[str, str], option: str) -> dict[str, float]:
    """The values of :func:`assignments` as finite numbers."""
    values = {}
    for name, text in items.items():
        try:
            values[name] = float(text)
        except ValueError:
            raise DataError(f"{option} {name}={text!r}: the value is not a number") from None
        if not math.isfinite(values[name]):
            raise DataError(f"{option} {name}={text}: the value must be finite")
    return values


def intervals(items: dict[str, str], option: str) -> dict[str, tuple[float, float]]:
    """The values of :func:`assignments` as ``MIN,MAX`` pairs of finite numbers with MIN < MAX."""
    values = {}
    for name, text in items.items():
        try:
            lo, hi = (float(part) for part in text.split(","))
        except ValueError:
            lo = hi = math.nan
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise DataError(f"{option} {name}={text!r} must read MIN,MAX with MIN < MAX, e.g. "
                            f"{name}=-0.5,0.5")
        values[name] = (lo, hi)
    return values
