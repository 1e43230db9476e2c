"""Closed-loop verification scenarios and the loop wiring, read from TOML.

Loop convention (as :class:`lpvflow.synth.controller.LPVController`): at every sample k

    y(k)  = plant outputs ``measured`` at t_k (+ output disturbance d_o(k))
    p(k)  = scheduling expressions of the plant outputs (all of them, ``diag_*`` included) and of the
            exogenous plant inputs at t_k, e.g. ``sin(arm_angle)``; or exogenous ones (``engine_speed``)
    w(k)  = r(k) − y(k) (1-DOF) or [r(k); y(k)] (2-DOF)   controller input, in ``measured`` order
    u_c(k) = u_op + K(w, p)(k)                            commanded, in ``actuated`` order (K includes
                                                          the controller's trim feed-forward u_eq(p))
    u(k)  = clip(u_c(k), actuator limits) + d_i(k)        held on the plant inputs from t_k to t_k + Ts

``u_op`` defaults to the FMU's start values of the actuated inputs, the references r default to
``y_operating_point`` (zero if not given). Plant inputs the controller does not drive are exogenous:
they follow their ``exogenous`` signal or stay at their start value.

TOML layout: the ``[verify]`` table of a design file (docs/design_file.md), read by ``lpvflow design``
and ``lpvflow verify --scenario`` alike::

    [verify.loop]
    measured = ["arm_angle", "pendulum_angle"]   # controller inputs e = r − y, in this order
    actuated = ["voltage"]                        # controller outputs u, in this order
    scheduling = ["sin(arm_angle)"]               # one expression per scheduling signal p
    u_operating_point = [0.0]                     # optional
    y_operating_point = [0.0, 0.0]                # optional: default references
    actuator_limits = { voltage = [-10.0, 10.0] } # optional
    plant_parameters = { effect_noise_std = 1e-4 }  # optional, FMU parameters for every scenario

    [[verify.scenario]]
    name = "arm to +75 deg"
    duration = 3.0
    reference = { arm_angle = { steps = [[0.5, 1.309]] } }
    input_disturbance = { voltage = { steps = [[2.0, 0.5]] } }     # optional
    output_disturbance = { arm_angle = 0.0 }                       # optional
    exogenous = { engine_speed = { initial = 2000.0, ramps = [[1.0, 3.0, 1000.0]] } }  # optional
    plant_parameters = { x0_pendulum_angle = 0.02 }                # optional, on top of [loop]'s
    parameter_factors = { pendulum_mass = 1.1, arm_damping = 2.0 } # optional perturbed plant: each
                                               # Real FMU parameter = factor × its value (plant_parameters,
                                               # else the FMU's start value)
    settling_band = { arm_angle = 0.0175 }     # optional absolute band; default 2 % of the last step
    output_bounds = { pendulum_angle = [-0.5, 0.5] }   # optional; leaving them is "unbounded"
    tracked = ["arm_angle"]                    # optional; default: outputs whose reference changes
    requirements = { settling_time = 1.5, overshoot = 0.035, after_settling = { pendulum_angle = 0.0175 } }
                                               # optional specification, checked besides the verdict:
                                               # every tracked output settles within settling_time (s)
                                               # with at most overshoot (output units); after they have
                                               # settled, |y − r| of each after_settling output stays
                                               # within its bound

A signal is a number (constant) or ``{ initial = V, steps = [[t, size], ...],
ramps = [[t_start, t_stop, size], ...] }``: s(t) = initial + Σ size·[t ≥ t_step] +
Σ size·clip((t − t_start)/(t_stop − t_start), 0, 1).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from lpvflow.errors import DataError
from lpvflow.intervals import interval

#: Scheduling given as a function of the current plant signals (name -> value) returning p (n_p,).
SchedulingFunction = Callable[[Mapping[str, float]], Sequence[float]]

#: Tolerance (s) when comparing a sample time k·Ts with a step or ramp time.
_TIME_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Signal:
    """s(t) = initial + Σ size·[t ≥ t_step] + Σ size·clip((t − t_start)/(t_stop − t_start), 0, 1)."""

    initial: float = 0.0
    steps: tuple[tuple[float, float], ...] = ()
    ramps: tuple[tuple[float, float, float], ...] = ()

    def sample(self, t: np.ndarray) -> np.ndarray:
        """Values at the times t (s)."""
        t = np.asarray(t, dtype=float)
        s = np.full(t.shape, self.initial)
        for at, size in self.steps:
            s += size * (t >= at - _TIME_TOLERANCE)
        for start, stop, size in self.ramps:
            s += size * np.clip((t - start) / (stop - start), 0.0, 1.0)
        return s

    @property
    def change_times(self) -> list[float]:
        """Times at which the signal starts to change (step times, ramp starts)."""
        return [at for at, _ in self.steps] + [start for start, _, _ in self.ramps]


@dataclass(frozen=True)
class Loop:
    """How the controller is wired to the plant FMU (module docstring)."""

    measured: tuple[str, ...]
    actuated: tuple[str, ...]
    scheduling: tuple[str, ...] | SchedulingFunction
    u_operating_point: tuple[float, ...] | None = None
    y_operating_point: tuple[float, ...] | None = None
    actuator_limits: dict[str, tuple[float, float]] = field(default_factory=dict)
    plant_parameters: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key in ("measured", "actuated"):
            names = getattr(self, key)
            if not names or len(set(names)) != len(names):
                raise DataError(f"loop {key} must list distinct signal names, got {list(names)}")
        if not callable(self.scheduling) and not self.scheduling:
            raise DataError(
                "loop scheduling must give one expression per scheduling signal, "
                'e.g. scheduling = ["sin(arm_angle)"]'
            )
        for key, names in (("u_operating_point", self.actuated), ("y_operating_point", self.measured)):
            value = getattr(self, key)
            if value is not None and len(value) != len(names):
                raise DataError(f"loop {key} has {len(value)} values for {len(names)} signals {list(names)}")
        for name, pair in self.actuator_limits.items():
            interval(pair, f"actuator limit of {name}")

    def to_dict(self) -> dict:
        return {
            "measured": list(self.measured),
            "actuated": list(self.actuated),
            "scheduling": "<python function>" if callable(self.scheduling) else list(self.scheduling),
            "u_operating_point": None if self.u_operating_point is None else list(self.u_operating_point),
            "y_operating_point": None if self.y_operating_point is None else list(self.y_operating_point),
            "actuator_limits": {k: list(v) for k, v in self.actuator_limits.items()},
            "plant_parameters": dict(self.plant_parameters),
        }


@dataclass(frozen=True)
class Requirements:
    """A specification a run must meet besides the stability verdict (module docstring, ``requirements``):
    ``settling_time`` (s) and ``overshoot`` (output units) bound every tracked output; ``after_settling``
    bounds |y − r| of the named outputs from the moment every tracked output has settled."""

    settling_time: float | None = None
    overshoot: float | None = None
    after_settling: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"settling_time": self.settling_time, "overshoot": self.overshoot,
                "after_settling": dict(self.after_settling)}


def run_passed(metrics: Mapping) -> bool:
    """A run's verdict from its metrics (:func:`lpvflow.pipeline.loop_metrics.run_metrics`): stable and no
    requirement missed (``requirements_failed`` empty or absent)."""
    return bool(metrics["stable"]) and not metrics.get("requirements_failed")


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run: references, disturbances, exogenous inputs, plant parameters, checks."""

    name: str
    duration: float
    reference: dict[str, Signal] = field(default_factory=dict)
    input_disturbance: dict[str, Signal] = field(default_factory=dict)
    output_disturbance: dict[str, Signal] = field(default_factory=dict)
    exogenous: dict[str, Signal] = field(default_factory=dict)
    plant_parameters: dict[str, float] = field(default_factory=dict)
    parameter_factors: dict[str, float] = field(default_factory=dict)
    settling_band: dict[str, float] = field(default_factory=dict)
    output_bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    tracked: tuple[str, ...] | None = None
    requirements: Requirements | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise DataError(
                f"scenario {self.name!r}: duration = {self.duration} must be a positive number of s"
            )
        for name, band in self.settling_band.items():
            if not band > 0:
                raise DataError(f"scenario {self.name!r}: settling_band of {name} = {band} must be > 0")
        for name, factor in self.parameter_factors.items():
            if not (math.isfinite(factor) and factor > 0):
                raise DataError(f"scenario {self.name!r}: parameter_factors.{name} = {factor} must be a "
                                "factor > 0 on the parameter's value (1.1 = +10 %)")


@dataclass(frozen=True)
class ScenarioFile:
    """A parsed scenario file: the loop and its scenarios."""

    loop: Loop
    scenarios: list[Scenario]


# ------------------------------------------------------------------------------------------ parsing
def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise DataError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _rows(value: object, width: int, where: str) -> tuple[tuple[float, ...], ...]:
    if not isinstance(value, list) or not all(isinstance(row, list) and len(row) == width for row in value):
        raise DataError(
            f"{where} must be a list of {'[t, size]' if width == 2 else '[t_start, t_stop, size]'} rows"
        )
    return tuple(tuple(_number(v, where) for v in row) for row in value)


def parse_signal(value: object, where: str) -> Signal:
    """A number or ``{initial, steps, ramps}`` table -> :class:`Signal`."""
    if not isinstance(value, dict):
        return Signal(initial=_number(value, where))
    unknown = sorted(set(value) - {"initial", "steps", "ramps"})
    if unknown:
        raise DataError(f"{where}: unknown key {unknown[0]!r}; a signal takes initial, steps, ramps")
    ramps = _rows(value.get("ramps", []), 3, f"{where}.ramps")
    for start, stop, _ in ramps:
        if not stop > start:
            raise DataError(f"{where}.ramps: t_stop = {stop} must be after t_start = {start}")
    return Signal(
        _number(value.get("initial", 0.0), f"{where}.initial"),
        _rows(value.get("steps", []), 2, f"{where}.steps"),
        ramps,
    )


def _table(doc: dict, key: str, where: str) -> dict:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise DataError(f"{where}.{key} must be a table {{ name = ... }}")
    return value


def _names(value: object, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise DataError(f'{where} must be a list of names, e.g. ["arm_angle"]')
    return tuple(value)


def _limits(doc: dict, key: str, where: str) -> dict[str, tuple[float, float]]:
    out = {}
    for name, pair in _table(doc, key, where).items():
        out[name] = interval(pair, f"{where}.{key}.{name}")
    return out


def _parameters(doc: dict, where: str) -> dict[str, float]:
    return {
        k: _number(v, f"{where}.plant_parameters.{k}")
        for k, v in _table(doc, "plant_parameters", where).items()
    }


def _check_keys(doc: dict, allowed: set[str], where: str) -> None:
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise DataError(f"{where}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(allowed))}")


def parse_loop(doc: dict) -> Loop:
    """The [loop] table -> :class:`Loop`."""
    _check_keys(
        doc,
        {
            "measured",
            "actuated",
            "scheduling",
            "u_operating_point",
            "y_operating_point",
            "actuator_limits",
            "plant_parameters",
        },
        "[loop]",
    )
    for key in ("measured", "actuated", "scheduling"):
        if key not in doc:
            raise DataError(f"[loop] lacks {key!r}; layout: docs/design_file.md, [verify.loop]")
    ops = {}
    for key in ("u_operating_point", "y_operating_point"):
        if key in doc:
            if not isinstance(doc[key], list):
                raise DataError(f"[loop].{key} must be a list of numbers")
            ops[key] = tuple(_number(v, f"[loop].{key}") for v in doc[key])
    return Loop(
        _names(doc["measured"], "[loop].measured"),
        _names(doc["actuated"], "[loop].actuated"),
        _names(doc["scheduling"], "[loop].scheduling"),
        actuator_limits=_limits(doc, "actuator_limits", "[loop]"),
        plant_parameters=_parameters(doc, "[loop]"),
        **ops,
    )


def _positive(value: object, where: str) -> float:
    number = _number(value, where)
    if not number > 0:
        raise DataError(f"{where} = {number} must be > 0")
    return number


def parse_requirements(doc: object, where: str) -> Requirements:
    """A ``requirements`` table -> :class:`Requirements`; every bound must be a positive number."""
    if not isinstance(doc, dict):
        raise DataError(f"{where} must be a table {{ settling_time = S, overshoot = O, after_settling = … }}")
    _check_keys(doc, {"settling_time", "overshoot", "after_settling"}, where)
    optional = {key: _positive(doc[key], f"{where}.{key}")
                for key in ("settling_time", "overshoot") if key in doc}
    after = {name: _positive(bound, f"{where}.after_settling.{name}")
             for name, bound in _table(doc, "after_settling", where).items()}
    return Requirements(**optional, after_settling=after)


def parse_scenario(doc: dict, index: int) -> Scenario:
    """One [[scenario]] table -> :class:`Scenario`."""
    name = doc.get("name", f"scenario {index + 1}")
    where = f"scenario {name!r}"
    _check_keys(
        doc,
        {
            "name",
            "duration",
            "reference",
            "input_disturbance",
            "output_disturbance",
            "exogenous",
            "plant_parameters",
            "parameter_factors",
            "settling_band",
            "output_bounds",
            "tracked",
            "requirements",
        },
        where,
    )
    if "duration" not in doc:
        raise DataError(f"{where} lacks duration (s)")
    signals = {
        key: {k: parse_signal(v, f"{where}.{key}.{k}") for k, v in _table(doc, key, where).items()}
        for key in ("reference", "input_disturbance", "output_disturbance", "exogenous")
    }
    bands = {
        k: _number(v, f"{where}.settling_band.{k}") for k, v in _table(doc, "settling_band", where).items()
    }
    tracked = _names(doc["tracked"], f"{where}.tracked") if "tracked" in doc else None
    return Scenario(
        str(name),
        _number(doc["duration"], f"{where}.duration"),
        **signals,
        plant_parameters=_parameters(doc, where),
        parameter_factors={k: _number(v, f"{where}.parameter_factors.{k}")
                           for k, v in _table(doc, "parameter_factors", where).items()},
        settling_band=bands,
        output_bounds=_limits(doc, "output_bounds", where),
        tracked=tracked,
        requirements=(parse_requirements(doc["requirements"], f"{where}.requirements")
                      if "requirements" in doc else None),
    )
