"""The controller a design file designs, as ``lpvflow synth --config`` and the design's synth stage both
write it: the ``[synth]`` method's controller (:func:`lpvflow.synth.design.synthesize_design`), its port
record (:func:`lpvflow.pipeline.ports.design_signals`: names, units, operating points, scheduling
expressions), its anti-windup law (:func:`lpvflow.pipeline.antiwindup.antiwindup`) and its check."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lpvflow.models import LPVSS
from lpvflow.pipeline.antiwindup import antiwindup
from lpvflow.pipeline.breakpoint_refinement import refined_design
from lpvflow.pipeline.ports import design_signals
from lpvflow.pipeline.scenarios import Loop
from lpvflow.synth.design import Design, synthesize_design
from lpvflow.synth.polytope import scheduling_box


def design_controller(
    model: LPVSS, settings: Mapping[str, Any], *, loop: Loop | None, scheduling: Mapping[str, str] | None,
    plant_fmu: str | Path | None,
) -> Design:
    """The design of the ``[synth]`` table ``settings`` for ``model`` with the controller's
    ``info["signals"]`` (from the experiment's ``scheduling`` expressions, the plant FMU and the
    verification ``loop``), its anti-windup for the loop's actuator limits and ``info["certificate"]``;
    breakpoints inserted where its frozen check failed between two
    (:mod:`lpvflow.pipeline.breakpoint_refinement`) in ``info["inserted_breakpoints"]``."""
    design, inserted = refined_design(lambda table: synthesize_design(model, table), settings,
                                      list(model.p_names), scheduling)
    controller = design.controller
    if inserted:
        controller.info["inserted_breakpoints"] = [float(v) for v in inserted]
    signals = design_signals(model, scheduling, plant_fmu, loop)
    controller.info["signals"] = signals
    check = design.certificate
    fields = dataclasses.asdict(check) if dataclasses.is_dataclass(check) else {}
    controller.info["certificate"] = fields | {"ok": bool(check.ok)}
    controller.antiwindup = antiwindup(controller, loop, signals, design.antiwindup_gains)
    return design


def extrapolation_note(model: LPVSS, box: list | None) -> str:
    """In words, where the ``[synth]`` box reaches past the scheduling range the model was identified on
    (the model is extrapolated there: the design's vertex models and its frozen checks use it as it is),
    or that it does not. The tolerance is the range warning's (1e-9 of the range)."""
    design_box = scheduling_box(model, box)
    if model.basis.p_min is None:
        return "the model records no identified range"
    beyond = []
    for name, (lo, hi), low, high in zip(model.p_names, design_box, model.basis.p_min, model.basis.p_max,
                                         strict=True):
        span = max(high - low, 1e-12)
        if lo < low - 1e-9 * span or hi > high + 1e-9 * span:
            beyond.append(f"{name} [{lo:.4g}, {hi:.4g}] against [{low:.4g}, {high:.4g}]")
    if not beyond:
        return "within the identified range"
    return (f"reaches past the identified range: {'; '.join(beyond)}; the model is extrapolated there "
            "(vertex models and frozen checks)")
