"""The design file's signal names checked against each other and the plant FMU, before anything runs.

Every table names signals: ``[experiment]`` the FMU inputs it drives and the outputs it reads, the
columns it adds (``scheduling``); ``[identify]`` and ``[diagnose]`` columns of the experiment record;
``[validate]`` and ``[synth]`` values per model signal or scheduling signal; ``[verify.loop]`` the FMU
signals the controller is wired to and, per scheduling signal, the expression that computes it. One
wrong name anywhere is one DataError line naming the key and what exists, raised by
:func:`lpvflow.pipeline.config.load_config` before any file or lock is written.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from types import SimpleNamespace
from typing import Any

import numpy as np

from lpvflow.errors import DataError
from lpvflow.experiment.run import DIAGNOSTIC_PREFIX, default_scheduling
from lpvflow.experiment.scheduling import evaluate
from lpvflow.pipeline.scheduling_values import SignalValues


def _unknown(where: str, given: Iterable[str], known: Iterable[str], what: str) -> None:
    known = list(known)
    missing = [name for name in given if name not in known]
    if missing:
        raise DataError(f"{where}: {missing[0]!r} is not {what}; known: {', '.join(known) or 'none'}")


def _same_expression(a: str, b: str) -> bool:
    return re.sub(r"\s+", "", a) == re.sub(r"\s+", "", b)


def recorded_columns(experiment: Mapping[str, Any], inputs: list[str], outputs: list[str],
                     model_name: str) -> dict[str, str | None]:
    """The columns the ``[experiment]`` table records: column → its scheduling expression (None for a
    plant signal, an excitation or a set-point), as :func:`lpvflow.experiment.run.run_experiment` writes
    them (``diag_*`` outputs left out; the plant's default scheduling columns when none are given)."""
    columns: dict[str, str | None] = {"time": None}
    columns |= {name: None for name in [*inputs, *outputs] if not name.startswith(DIAGNOSTIC_PREFIX)}
    columns |= {f"{name}_excitation": None for name in experiment["excitation"]}
    columns |= {f"{name}_setpoint": None for name in experiment["setpoint"]}
    plant = SimpleNamespace(model_name=model_name, output_names=outputs)
    columns |= dict(experiment["scheduling"] or default_scheduling(plant))
    return columns


def check_signals(config: Mapping[str, Any], description: Any) -> None:
    """Cross-check the signal names of a whole checked design file (module docstring); ``description``
    is the plant FMU's model description (:func:`lpvflow.fmu.check_fmu`)."""
    variables = [v.name for v in description.modelVariables]
    inputs = [v.name for v in description.modelVariables if v.causality == "input"]
    outputs = [v.name for v in description.modelVariables if v.causality == "output"]
    experiment = config["experiment"]
    _unknown("[experiment] inputs", experiment["inputs"], inputs, "an input of the plant FMU")
    for key in ("excitation", "iterate_excitation"):
        _unknown(f"[experiment] {key}", experiment[key], inputs, "an input of the plant FMU")
    for key in ("setpoint", "iterate_setpoint", "quantization", "noise", "output_bounds"):
        _unknown(f"[experiment] {key}", experiment[key], outputs, "an output of the plant FMU")
    _unknown("[experiment] parameters", experiment["parameters"], variables, "a variable of the plant FMU")
    zeros = {name: np.zeros(1) for name in [*inputs, *outputs]}
    for name, expression in experiment["scheduling"].items():
        try:
            evaluate(expression, zeros)
        except DataError as exc:
            raise DataError(f"[experiment] scheduling.{name}: {exc} (the plant FMU's signals: "
                            f"{', '.join([*inputs, *outputs])})") from None
    columns = recorded_columns(experiment, inputs, outputs, description.modelName)
    identify = config["identify"]
    for key in ("u", "y", "p"):
        _unknown(f"[identify] {key}", identify[key], columns, "a column the experiment records")
    if identify["excitation"]:
        _unknown("[identify] excitation", [identify["excitation"]], columns,
                 "a column the experiment records")
    _unknown("[identify] increments", identify["increments"], identify["y"], "an [identify] y column")
    if config["diagnose"]:
        _unknown("[diagnose] candidates", config["diagnose"]["candidates"], columns,
                 "a column the experiment records")
    _check_validate(config["validate"], identify, variables)
    if config["synth"]:
        _check_synth(config["synth"], identify)
    if config["verify"]:
        _check_verify(config["verify"], identify, columns, inputs, outputs, variables)


def _check_validate(validate: Mapping[str, Any], identify: Mapping[str, Any], variables: list[str]) -> None:
    _unknown("[validate] operating_point", validate["operating_point"], variables,
             "a variable of the plant FMU")
    _unknown("[validate] hold", validate["hold"], variables, "a variable of the plant FMU")
    if isinstance(validate["scaling"], dict):
        signals = [*identify["u"], *identify["y"]]
        _unknown("[validate] scaling", validate["scaling"], signals, "a model input or output")
        _unknown("[validate] scaling lacks a scale for", signals, validate["scaling"], "given")
    n_p = len(identify["p"])
    given = validate["points"]
    if not isinstance(given, SignalValues) and any(len(point) != n_p for point in given):
        raise DataError(f"[validate] points: each point needs {n_p} value(s), one per [identify] p "
                        f"{identify['p']}")


def _check_synth(synth: Mapping[str, Any], identify: Mapping[str, Any]) -> None:
    n_p, n_u = len(identify["p"]), len(identify["u"])
    if isinstance(synth["box"], list) and len(synth["box"]) != n_p:
        raise DataError(f"[synth] box has {len(synth['box'])} interval(s); give one per [identify] p "
                        f"{identify['p']}")
    if isinstance(synth["baseline_at"], list) and len(synth["baseline_at"]) != n_p:
        raise DataError(f"[synth] baseline_at has {len(synth['baseline_at'])} value(s); give one per "
                        f"[identify] p {identify['p']}")
    if synth["trim"] is not None and len(synth["trim"]["u"][0]) != n_u:
        raise DataError(f"[synth] trim.u rows have {len(synth['trim']['u'][0])} value(s); give one per "
                        f"[identify] u {identify['u']} in each row")


def _check_verify(
    verify: Mapping[str, Any], identify: Mapping[str, Any], columns: Mapping[str, str | None],
    inputs: list[str], outputs: list[str], variables: list[str],
) -> None:
    loop = verify["loop"]
    for key, model_key in (("measured", "y"), ("actuated", "u")):
        if list(getattr(loop, key)) != list(identify[model_key]):
            raise DataError(f"[verify.loop] {key} = {list(getattr(loop, key))} must list the model's "
                            f"[identify] {model_key} = {identify[model_key]} in the same order (the "
                            "controller's ports are the model's signals)")
    _unknown("[verify.loop] measured", loop.measured, outputs, "an output of the plant FMU")
    _unknown("[verify.loop] actuated", loop.actuated, inputs, "an input of the plant FMU")
    _unknown("[verify.loop] actuator_limits", loop.actuator_limits, loop.actuated, "an actuated input")
    _unknown("[verify.loop] plant_parameters", loop.plant_parameters, variables,
             "a variable of the plant FMU")
    if len(loop.scheduling) != len(identify["p"]):
        raise DataError(f"[verify.loop] scheduling gives {len(loop.scheduling)} expression(s); give one per "
                        f"[identify] p {identify['p']}")
    for name, expression in zip(identify["p"], loop.scheduling, strict=True):
        recorded = columns.get(name) or name
        if not _same_expression(expression, recorded):
            raise DataError(f"[verify.loop] scheduling computes {name} as {expression!r} but the experiment "
                            f"recorded it as {recorded!r}; use the same expression (or leave [verify.loop] "
                            "scheduling out: it is then taken from [experiment] scheduling)")
    for scenario in verify["scenario"]:
        where = f"[[verify.scenario]] {scenario.name!r}"
        for key, known, what in (("reference", loop.measured, "a measured output"),
                                 ("output_disturbance", loop.measured, "a measured output"),
                                 ("input_disturbance", loop.actuated, "an actuated input"),
                                 ("exogenous", [n for n in inputs if n not in loop.actuated],
                                  "a plant input the controller does not drive")):
            _unknown(f"{where} {key}", getattr(scenario, key), known, what)
        _unknown(f"{where} plant_parameters", scenario.plant_parameters, variables,
                 "a variable of the plant FMU")
