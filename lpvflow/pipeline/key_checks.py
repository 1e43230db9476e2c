"""The value checkers of the design file's keys: each takes a value and its place (``[identify] na``),
refuses a wrong value with one line naming the key and what it must be, and returns the value to use.

:data:`lpvflow.pipeline.config.SCHEMA` pairs every key with one of these checkers, its default and
a one-line description.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import Any

from lpvflow import intervals
from lpvflow.basis import Basis
from lpvflow.errors import DataError, LpvflowError, ModelError
from lpvflow.experiment.specs import parse_spec
from lpvflow.identify.methods import method_names
from lpvflow.identify.prefilter import parse_prefilter
from lpvflow.pipeline.scenarios import Loop, Scenario, parse_loop, parse_scenario
from lpvflow.pipeline.scheduling_values import SignalValues, signal_values
from lpvflow.synth.weights import CHANNELS, Weight, Weights, weight_entries

#: Marks a key without a default.
REQUIRED = object()

#: A checker takes the value and its place (``[identify] na``) and returns the value to use.
Check = Callable[[Any, str], Any]


@dataclass(frozen=True)
class Key:
    """One key of a table: its default (or :data:`REQUIRED`), its checker and a one-line description."""

    default: Any
    check: Check
    doc: str


# ------------------------------------------------------------------------------------------ checkers
def _fail(where: str, value: Any, expected: str) -> DataError:
    return DataError(f"{where} = {value!r} must be {expected}")


def integer(low: int) -> Check:
    """An integer ≥ ``low``."""
    def check(value: Any, where: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise _fail(where, value, f"an integer ≥ {low}")
        return value
    return check


def number(low: float = -math.inf, high: float = math.inf, *, open_low: bool = False,
           open_high: bool = False) -> Check:
    """A finite number in the interval given (closed unless ``open_low``/``open_high``)."""
    left, right = "(" if open_low else "[", ")" if open_high else "]"
    interval = f"in {left}{low:g}, {high:g}{right}"
    def check(value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise _fail(where, value, f"a number {interval}")
        too_low = value <= low if open_low else value < low
        too_high = value >= high if open_high else value > high
        if too_low or too_high:
            raise _fail(where, value, f"a number {interval}")
        return float(value)
    return check


def string(choices: Collection[str] = (), upper: bool = False) -> Check:
    """A non-empty string; with ``choices``, one of them (``upper``: compared in upper case); a live view
    (a registry's keys) is read at each check."""
    def check(value: Any, where: str) -> str:
        if not isinstance(value, str) or not value:
            raise _fail(where, value, "a non-empty string" + (f": one of {', '.join(choices)}"
                                                              if choices else ""))
        value = value.upper() if upper else value
        if choices and value not in choices:
            raise _fail(where, value, f"one of {', '.join(choices)}")
        return value
    return check


def folder_name(value: Any, where: str) -> str:
    """A name usable as one folder (no path separators, not ``.`` or ``..``)."""
    name = string()(value, where)
    if "/" in name or "\\" in name or name in (".", ".."):
        raise _fail(where, value, "a folder name without / (the design's folder inside output_dir)")
    return name


def boolean(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise _fail(where, value, "true or false")
    return value


def interval(value: Any, where: str) -> list[float]:
    """``[lo, hi]``: two finite numbers with lo < hi (:func:`lpvflow.intervals.interval`)."""
    return list(intervals.interval(value, where))


def names(empty: bool = False) -> Check:
    """A list of distinct non-empty strings (signal or column names)."""
    def check(value: Any, where: str) -> list[str]:
        if (not isinstance(value, list) or not all(isinstance(v, str) and v for v in value)
                or len(set(value)) != len(value) or (not value and not empty)):
            raise _fail(where, value, 'a list of distinct names, e.g. ["voltage"]')
        return value
    return check


def mapping(of: Check, what: str) -> Check:
    """A table ``{ name = value }`` whose values pass ``of``."""
    def check(value: Any, where: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise _fail(where, value, f"a table {{ name = {what} }}")
        return {k: of(v, f"{where}.{k}") for k, v in value.items()}
    return check


def numbers(value: Any, where: str) -> list[float]:
    if not isinstance(value, list) or not value:
        raise _fail(where, value, "a list of numbers, one per scheduling signal")
    return [number()(v, where) for v in value]


def point(value: Any, where: str) -> list[float] | SignalValues:
    """One scheduling point (a number per scheduling signal), or one value of a plant signal
    (:mod:`lpvflow.pipeline.scheduling_values`)."""
    if isinstance(value, dict):
        return signal_values(value, where)
    return numbers(value, where)


def box(value: Any, where: str) -> list[list[float]] | SignalValues:
    """``[[lo, hi], ...]``, one interval with lo < hi per scheduling signal, or a range of one plant
    signal (:mod:`lpvflow.pipeline.scheduling_values`)."""
    if isinstance(value, dict):
        return signal_values(value, where, box=True)
    if not (isinstance(value, list) and value and all(isinstance(r, list) and len(r) == 2 for r in value)):
        raise _fail(where, value, "a list of [lo, hi] intervals, one per scheduling signal, e.g. [[-1, 1]]")
    rows = [[number()(v, where) for v in row] for row in value]
    if not all(lo < hi for lo, hi in rows):
        raise _fail(where, value, "intervals [lo, hi] with lo < hi")
    return rows


def basis(value: Any, where: str) -> str:
    """A scheduling basis spec (``affine``, ``poly:D``, ``poly:D:nocross``, ``spline:K1,K2,…``)."""
    spec = string()(value, where)
    try:
        Basis.from_spec(spec, 1)
    except LpvflowError as exc:
        raise DataError(f"{where}: {exc}") from None
    return spec


def method(value: Any, where: str) -> str:
    """An estimator of ``lpvflow identify`` with a state-space result (static-arx has none)."""
    return string(method_names(realizable=True))(value, where)


def prefilter(value: Any, where: str) -> str:
    """``none``, ``lowpass:F`` or ``bandpass:F1,F2`` (Hz)."""
    spec = string()(value, where)
    if spec != "none":
        try:
            parse_prefilter(spec)
        except DataError:
            expected = '"none", "lowpass:F" or "bandpass:F1,F2" with 0 < F1 < F2 in Hz'
            raise _fail(where, value, expected) from None
    return spec


def scaling(value: Any, where: str) -> str | dict[str, float]:
    """``"data"``, ``"none"`` or a table of positive scales per signal."""
    if isinstance(value, dict):
        return mapping(number(0.0, open_low=True), "scale > 0")(value, where)
    return string(("data", "none"))(value, where)


def points(value: Any, where: str) -> list[list[float]] | SignalValues:
    """A list of scheduling points, each a list of numbers, or values of one plant signal
    (:mod:`lpvflow.pipeline.scheduling_values`)."""
    if isinstance(value, dict):
        return signal_values(value, where)
    if not (isinstance(value, list) and all(isinstance(v, list) and v for v in value)):
        raise _fail(where, value, "a list of scheduling points, e.g. [[-0.966, 0.259], [0.0, 1.0]]")
    return [[number()(v, where) for v in point] for point in value]


def formats(value: Any, where: str) -> list[str]:
    chosen = names()(value, where)
    unknown = [f for f in chosen if f not in ("fmu", "json", "mat")]
    if unknown:
        raise _fail(where, value, 'a list of formats from "fmu", "json", "mat"')
    return chosen


#: The keys of a weights table (:class:`lpvflow.synth.weights.Weights`).
WEIGHT_KEYS = (*CHANNELS, "integrator_shift")


def weights(value: Any, where: str) -> Weights:
    """``{ S = …, K = …, [B, T, R, N], [integrator_shift] }``; each weight a table or a list of tables;
    parsed once into :class:`lpvflow.synth.weights.Weights`."""
    if not isinstance(value, dict):
        raise _fail(where, value, "a table of weights (weights.S = …, weights.K = …)")
    _weight_keys(value, where)
    missing = [k for k in ("S", "K") if k not in value]
    if missing:
        raise DataError(f"{where} lacks {missing} (W_S on the error and W_K on the control are required)")
    try:
        return Weights.parse(value)
    except ModelError as exc:
        raise DataError(f"{where}: {exc}") from None


def _weight_keys(value: dict, where: str) -> None:
    """Unknown keys, weights that are not tables and an integrator_shift outside (0, 0.5), each one line
    naming the key."""
    unknown = sorted(set(value) - set(WEIGHT_KEYS))
    if unknown:
        raise DataError(f"{where} has unknown key(s) {unknown}; known: {list(WEIGHT_KEYS)}")
    for key in set(value) - {"integrator_shift"}:
        weight = value[key]
        if not (isinstance(weight, dict) or (isinstance(weight, list) and weight
                                            and all(isinstance(w, dict) for w in weight))):
            raise _fail(f"{where}.{key}", weight, "a table { num, den } or { bandwidth, dc_gain, hf_gain }, "
                        "or a list of them (one per channel)")
    if "integrator_shift" in value:
        shift = number(0.0, 0.5, open_low=True, open_high=True)
        shift(value["integrator_shift"], f"{where}.integrator_shift")


def breakpoints(value: Any, where: str) -> list | SignalValues:
    """Values of the one scheduling signal, rows of scheduling points (one value per signal), or values of
    one plant signal (:mod:`lpvflow.pipeline.scheduling_values`)."""
    if isinstance(value, dict):
        return signal_values(value, where)
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        return [numbers(row, f"{where}[{i}]") for i, row in enumerate(value)]
    return numbers(value, where)


def largest_step(value: Any, where: str) -> dict[str, str]:
    """``{ scenario = "name of a step scenario", criterion = "bounded" | "passes" }`` (criterion optional,
    default "bounded": the run stays within its output_bounds)."""
    if not isinstance(value, dict) or "scenario" not in value or set(value) - {"scenario", "criterion"}:
        raise _fail(where, value, '{ scenario = "arm to +75 deg", criterion = "bounded" }')
    criterion = string(("bounded", "passes"))(value.get("criterion", "bounded"), f"{where}.criterion")
    return {"scenario": string()(value["scenario"], f"{where}.scenario"), "criterion": criterion}


def vertex_weights(value: Any, where: str) -> list[dict[str, Weight | float]]:
    """A list of partial weight tables, one per vertex (breakpoint) of the design polytope: each replaces
    entries of ``[synth] weights`` at its vertex (scheduled weights); parsed once
    (:func:`lpvflow.synth.weights.weight_entries`)."""
    if not isinstance(value, list) or not value or not all(isinstance(v, dict) for v in value):
        raise _fail(where, value, "a list of weight tables, one per vertex: [{ S = … }, { }, { S = … }]")
    parsed = []
    for i, table in enumerate(value):
        _weight_keys(table, f"{where}[{i}]")
        try:
            parsed.append(weight_entries(table))
        except ModelError as exc:
            raise DataError(f"{where}[{i}]: {exc}") from None
    return parsed


def observer(value: Any, where: str) -> dict[str, float]:
    """``{ input, state, disturbance, noise }`` (each optional, > 0): the Kalman filter's noise model of the
    observer design (:class:`lpvflow.synth.observer.ObserverSettings`)."""
    keys = ("input", "state", "disturbance", "noise")
    if not isinstance(value, dict) or set(value) - set(keys):
        raise _fail(where, value, "a table with some of the keys input, state, disturbance, noise, e.g. "
                    "{ input = 1.0, state = 1e-6, disturbance = 1.0, noise = 1e-3 }")
    return {k: number(0.0, open_low=True)(v, f"{where}.{k}") for k, v in value.items()}


def reference_filter(value: Any, where: str) -> dict[str, float]:
    """``{ bandwidth = ω [rad/s], damping = ζ }`` (damping optional, default 1): the observer design's
    reference filter ω²/(s² + 2ζωs + ω²)."""
    if not isinstance(value, dict) or "bandwidth" not in value or set(value) - {"bandwidth", "damping"}:
        raise _fail(where, value, "{ bandwidth = 2.2, damping = 1.0 } (rad/s; damping optional)")
    return {k: number(0.0, open_low=True)(v, f"{where}.{k}") for k, v in value.items()}


def margin_goal(value: Any, where: str) -> dict[str, float]:
    """``{ nugap_factor = f, at_least = b }``, either or both: f > 0, b in (0, 1)."""
    if not isinstance(value, dict) or not value or set(value) - {"nugap_factor", "at_least"}:
        raise _fail(where, value, "{ nugap_factor = 1.5, at_least = 0.05 } (either or both)")
    checks = {"nugap_factor": number(0.0, open_low=True), "at_least": number(0.0, 1.0, open_low=True,
                                                                            open_high=True)}
    return {k: checks[k](v, f"{where}.{k}") for k, v in value.items()}


def reference_model(value: Any, where: str) -> dict[str, float]:
    """``{ control_weight = ρ }`` with ρ > 0."""
    table = mapping(number(0.0, open_low=True), "number > 0")(value, where)
    if set(table) != {"control_weight"}:
        raise _fail(where, value, "{ control_weight = ρ } with ρ > 0")
    return table


def trim(value: Any, where: str) -> dict[str, list]:
    """``{ p = [p_1, …, p_M], u = [[u_11, …, u_1nu], …] }``: breakpoints of the first scheduling signal,
    strictly ascending, and one row of plant inputs per breakpoint (the trim feed-forward u_eq(p))."""
    if not isinstance(value, dict) or set(value) != {"p", "u"}:
        raise _fail(where, value, "a table { p = [p_1, …], u = [[u_1 …], …] } with exactly the keys p and u")
    p = value["p"]
    if not isinstance(p, list) or not p:
        raise _fail(f"{where}.p", p, "a list of breakpoints of the first scheduling signal")
    p = [number()(v, f"{where}.p") for v in p]
    if any(p[i + 1] <= p[i] for i in range(len(p) - 1)):
        raise _fail(f"{where}.p", value["p"], "strictly ascending breakpoints of the first scheduling signal")
    u = value["u"]
    width = len(u[0]) if isinstance(u, list) and u and isinstance(u[0], list) else 0
    if (not isinstance(u, list) or len(u) != len(p) or width == 0
            or not all(isinstance(row, list) and len(row) == width for row in u)):
        raise _fail(f"{where}.u", u, f"{len(p)} rows (one per breakpoint of {where}.p) of the same number "
                    "of plant inputs, e.g. [[4.21], [0.0], [-4.21]]")
    return {"p": p, "u": [[number()(v, f"{where}.u") for v in row] for row in u]}


def signal_spec(value: Any, where: str) -> str:
    """An experiment signal ``KIND:key=value,…`` (:func:`lpvflow.experiment.specs.parse_spec`): the kind
    known and every key it needs given, so an incomplete spec is refused before the experiment runs."""
    text = string()(value, where)
    try:
        parse_spec(text)
    except DataError as exc:
        raise DataError(f"{where}: {exc}") from None
    return text


def loop(value: Any, where: str) -> Loop:
    """The ``[verify.loop]`` table, parsed once into a :class:`~lpvflow.pipeline.scenarios.Loop`."""
    if not isinstance(value, dict):
        raise _fail(where, value, "a table (write it as [verify.loop])")
    return parse_loop(value)


def scenarios(value: Any, where: str) -> list[Scenario]:
    """The ``[[verify.scenario]]`` tables, parsed once into :class:`~lpvflow.pipeline.scenarios.Scenario`
    objects with distinct names."""
    if not isinstance(value, list) or not value or not all(isinstance(s, dict) for s in value):
        raise DataError(f"{where}: give at least one [[verify.scenario]] table")
    parsed = [parse_scenario(doc, i) for i, doc in enumerate(value)]
    names_seen = [scenario.name for scenario in parsed]
    if len(set(names_seen)) != len(names_seen):
        raise DataError(f"{where}: scenario names must be distinct, got {names_seen}")
    return parsed
