"""How the design report writes values: display units (angles in degrees), numbers, stage outputs as
table cells, text that wraps in narrow columns, and the signal units of a design's controller."""

from __future__ import annotations

import html
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class DisplayUnit:
    """How a signal's values are shown: ``label`` in the column head, values multiplied by ``factor``."""

    label: str
    factor: float = 1.0

    @classmethod
    def of(cls, unit: str) -> DisplayUnit:
        """Angles in rad are shown in degrees; other units as they are ("" when the FMU gives none)."""
        return cls("°", 180.0 / math.pi) if unit == "rad" else cls(unit)

    def head(self, text: str) -> str:
        return f"{text} [{self.label}]" if self.label else f"{text} (output units)"

    def value(self, value: float | None) -> str:
        return number_text(None if value is None else value * self.factor)


def number_text(value: object, unit: str = "", digits: int = 3) -> str:
    """A number with ``digits`` significant digits and ``unit`` appended; "–" for None."""
    return "–" if value is None else f"{value:.{digits}g}{unit}"


def format_value(value: object) -> str:
    """A stage output as text for one table cell: numbers with 4 significant digits, lists joined, tables
    as ``key: value`` phrases (never JSON); nothing (None, an empty list or table) is "–"."""
    if value is None or (isinstance(value, dict | list) and not value):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict) and {"outputs", "bfr", "vaf"} <= set(value):  # a fit report
        return "; ".join(f"{n}: BFR {b:.1f} %, VAF {v:.1f} %"
                         for n, b, v in zip(value["outputs"], value["bfr"], value["vaf"], strict=True))
    if isinstance(value, dict):
        if all(is_numbers(v) for v in value.values()):  # e.g. signal ranges: "voltage: [-4.86, 4.41]"
            return "; ".join(f"{k}: [{format_value(v)}]" for k, v in value.items())
        return "; ".join(f"{k}: {format_value(v)}" for k, v in value.items())
    if isinstance(value, list):
        if all(isinstance(v, str) for v in value):
            return "; ".join(value)  # e.g. the certificate's lines
        if all(is_numbers(v) for v in value):  # rows of numbers, e.g. a grid of scheduling points
            return "; ".join(format_value(v) for v in value)
        separator = " | " if any(isinstance(v, dict) for v in value) else ", "
        return separator.join(format_value(v) for v in value)
    return str(value)


def is_numbers(value: object) -> bool:
    """A non-empty list of numbers (not booleans)."""
    return (isinstance(value, list) and bool(value)
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value))


def breakable(text: str) -> str:
    """``text`` escaped for HTML, with line-break opportunities after underscores (signal names such as
    upper_disk_position wrap there in a narrow column)."""
    return html.escape(text).replace("_", "_<wbr>")


def short_reason(reason: str) -> str:
    """A failed run's reason for a table cell: "unbounded: y left its output_bounds at t = 1.585 s" reads
    "y out of bounds at 1.59 s"; other reasons as they are."""
    lost = re.fullmatch(r"unbounded: (.+) left its output_bounds at t = (\S+) s", reason)
    return f"{lost[1]} out of bounds at {float(lost[2]):.3g} s" if lost else reason


def unit_of(name: str, units: dict[str, DisplayUnit]) -> DisplayUnit:
    """The display unit of a recorded signal: its own, or for an experiment's ``<signal>_excitation`` and
    ``<signal>_setpoint`` columns that of the signal; none for a scheduling signal."""
    for suffix in ("", "_excitation", "_setpoint"):
        if name.endswith(suffix) and name.removesuffix(suffix) in units:
            return units[name.removesuffix(suffix)] if suffix else units[name]
    return DisplayUnit("")


def signal_value(name: str, value: float, units: dict[str, DisplayUnit]) -> str:
    """One value of a named signal in its display unit, e.g. "70.2°", "6.02 V" (a plain number without
    one)."""
    unit = unit_of(name, units)
    return unit.value(value) + ("" if unit.label in ("°", "") else " ") + unit.label


def signal_range(name: str, bounds: list[float], units: dict[str, DisplayUnit]) -> str:
    lo, hi = (signal_value(name, v, units) for v in bounds)
    return f"{name} {lo} … {hi}"


def controller_ports(folder: Path) -> dict:
    """The synthesized controller's port record (``controller.json`` ``info["signals"]``,
    :func:`lpvflow.pipeline.export.describe_signals`); empty without one."""
    path = folder / "controller.json"
    if not path.exists():
        return {}
    try:
        return json.loads(path.read_text()).get("info", {}).get("signals", {}) or {}
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        return {}


def signal_units(folder: Path) -> dict[str, str]:
    """Unit of every measured and actuated signal, from the synthesized controller's port record
    (:func:`controller_ports`); empty without one."""
    signals = controller_ports(folder)
    return {port["name"]: port.get("unit", "") for kind in ("measured", "actuated")
            for port in signals.get(kind, [])}


#: A gate's ``passed`` in words: None is a gate that was off, not evaluated or not applied (its reason says).
GATE_WORDS = {True: "passed", False: "failed", None: "not applied"}
