"""The port record of a synthesized controller (``info["signals"]``): the named, unit-carrying signals it
reads and drives, shared by the design's synth stage, ``lpvflow synth``, the experiment, verify and export."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import fmpy
import numpy as np

from lpvflow.errors import DataError, ModelError
from lpvflow.models import LPVSS
from lpvflow.pipeline.scenarios import Loop

if TYPE_CHECKING:  # the port record is read from a controller's info; synth is not imported for it
    from lpvflow.synth.controller import LPVController

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


#: Controller port roles in ``info["signals"]``: measured outputs (read with their references),
#: scheduling signals, actuated plant inputs.
ROLES = ("measured", "scheduling", "actuated")


_DEFAULT_PREFIX = {"measured": "y", "scheduling": "p", "actuated": "u"}


@dataclass(frozen=True)
class Port:
    """One named controller signal. ``operating_point``: for a measured output its value at the design's
    operating point (start value of the ``y`` and ``y_ref`` ports), for an actuated input the trim the
    controller adds to its output, for a scheduling signal its start value. ``expression``: how a
    scheduling signal is computed from plant signals (its own name when it is one)."""
    name: str
    unit: str = ""
    description: str = ""
    operating_point: float = 0.0
    expression: str = ""

    def to_dict(self) -> dict:
        return {"name": self.name, "unit": self.unit, "description": self.description,
                "operating_point": self.operating_point, "expression": self.expression}


@dataclass(frozen=True)
class ControllerSignals:
    """The ports of a controller: measured outputs, scheduling signals, actuated inputs (module docstring)."""
    measured: tuple[Port, ...]
    scheduling: tuple[Port, ...]
    actuated: tuple[Port, ...]

    def to_dict(self) -> dict:
        """The ``info["signals"]`` layout: role → list of port dictionaries."""
        return {role: [port.to_dict() for port in getattr(self, role)] for role in ROLES}


def controller_signals(
    controller: LPVController, names: Mapping[str, Sequence[str]] | None = None
) -> ControllerSignals:
    """The ports recorded in ``controller.info["signals"]`` (default names ``y1``, ``p1``, ``u1``…), with
    the names of ``names`` (role → names) replacing the recorded ones; one DataError line for a wrong
    count, a name that is not an identifier or a name used twice."""
    recorded = controller.info.get("signals") or {}
    sizes = {"measured": controller.n_measured, "scheduling": controller.basis.n_p,
             "actuated": controller.n_out}
    unknown = sorted(set(names or {}) - set(ROLES))
    if unknown:
        raise DataError(f"unknown signal role(s) {unknown}; use {', '.join(ROLES)}")
    ports = {}
    for role, n in sizes.items():
        entries = recorded.get(role) or [{"name": f"{_DEFAULT_PREFIX[role]}{i + 1}"} for i in range(n)]
        if names and role in names:
            given = list(names[role])
            if len(given) != len(entries):
                raise DataError(f"{role} names list {len(given)} names for {n} signals: {given}")
            entries = [{**entry, "name": name} for entry, name in zip(entries, given, strict=True)]
        if len(entries) != n:
            raise DataError(f"the controller has {n} {role} signals but its record names {len(entries)}")
        try:
            ports[role] = tuple(Port(**entry) for entry in entries)
        except TypeError as exc:
            raise ModelError(f"controller info['signals'][{role!r}] has a malformed entry ({exc})") from None
        bad = [port.name for port in ports[role]
               if not isinstance(port.name, str) or not _NAME.match(port.name)]
        if bad:
            raise DataError(f"{role}: {bad[0]!r} is not a valid signal name (letters, digits, _)")
    every = [*(f"{port.name}_ref" for port in ports["measured"]),
             *(port.name for role in ROLES for port in ports[role])]
    if len(set(every)) != len(every):
        raise DataError(f"controller port names must be distinct, got {every}")
    return ControllerSignals(ports["measured"], ports["scheduling"], ports["actuated"])


def describe_signals(
    model: LPVSS,
    expressions: Mapping[str, str] | None = None,
    plant_fmu: str | Path | None = None,
    operating_point: Mapping[str, float] | None = None,
) -> dict:
    """``info["signals"]`` of a controller synthesized for ``model`` (measured outputs and their references
    the model's outputs, whatever the controller's structure; outputs the model's inputs, scheduling its
    p): names from the model, scheduling expressions from ``expressions`` (name → expression; the name
    itself otherwise), units and descriptions from the plant FMU's variables of the same name (a name that
    is not an identifier, e.g. a data column ``level (m)``, becomes ``level__m_``), operating points
    (signal name → value) from ``operating_point``, else the FMU's start values for the actuated inputs
    (as :mod:`lpvflow.pipeline.verify` does) and zero for the outputs."""
    variables = {}
    if plant_fmu is not None:
        variables = {v.name: v for v in fmpy.read_model_description(str(plant_fmu)).modelVariables}
    expressions = dict(expressions or {})

    def port(name: str, operating_point: float, expression: str = "") -> Port:
        variable = variables.get(expression or name)
        declared = getattr(variable, "declaredType", None)
        unit = (getattr(variable, "unit", None) or getattr(declared, "unit", None) or "") if variable else ""
        description = (variable.description or "") if variable is not None else ""
        port_name = re.sub(r"\W", "_", name)
        if not _NAME.match(port_name):
            port_name = f"s_{port_name}"
        if port_name != name:  # a data column such as "level (m)": the port keeps the column in its text
            description = f"column {name!r}" + (f"; {description}" if description else "")
        return Port(port_name, unit, description, float(operating_point), expression)

    given = dict(operating_point or {})
    start = {n: float(v.start) for n, v in variables.items()
             if v.causality == "input" and v.start is not None}
    measured = tuple(port(n, given.get(n, 0.0)) for n in model.y_names)
    actuated = tuple(port(n, given.get(n, start.get(n, 0.0))) for n in model.u_names)
    at_rest = {n: p.operating_point for n, p in zip([*model.y_names, *model.u_names], measured + actuated,
                                                    strict=True)}
    scheduling = tuple(port(n, scheduling_at(expressions.get(n, n), at_rest, c), expressions.get(n, n))
                       for n, c in zip(model.p_names, scheduling_centre(model), strict=True))
    return ControllerSignals(measured, scheduling, actuated).to_dict()


def scheduling_at(expression: str, signals: Mapping[str, float], otherwise: float) -> float:
    """A scheduling expression's value with the plant signals at ``signals`` (their operating point: the
    controller FMU's scheduling inputs then start where its measured inputs start, e.g. sin(arm_angle) = 0
    with the arm at 0°); ``otherwise`` when it reads a signal that has no operating point."""
    from lpvflow.experiment.scheduling import evaluate

    try:
        return float(evaluate(expression, {n: np.array([v]) for n, v in signals.items()})[0])
    except DataError:
        return otherwise


def scheduling_centre(model: LPVSS) -> list[float]:
    """Middle of the model's recorded scheduling range (zero where it records none)."""
    basis = model.basis
    if basis.p_min is None:
        return [0.0] * basis.n_p
    return [0.5 * (lo + hi) for lo, hi in zip(basis.p_min, basis.p_max, strict=True)]


def design_signals(
    model: LPVSS, scheduling: Mapping[str, str] | None, plant_fmu: str | Path | None, loop: Loop | None
) -> dict:
    """The port record of a controller designed for ``model`` in a design file (:func:`describe_signals`):
    the model's signal names, the experiment's ``scheduling`` expressions, units and descriptions from the
    plant FMU, operating points from the verification ``loop`` (else the FMU's input start values, as
    verify uses)."""
    operating_point: dict[str, float] = {}
    if loop is not None:
        pairs = ((loop.measured, loop.y_operating_point), (loop.actuated, loop.u_operating_point))
        for names, values in pairs:
            operating_point |= dict(zip(names, values, strict=True)) if values is not None else {}
    return describe_signals(model, scheduling, plant_fmu, operating_point)
