"""The largest reference step a controller holds on the plant FMU, by bisection over the step size.

A template scenario with one reference step (e.g. ``arm to +75 deg``: the arm reference steps by
+1.309 rad at 0.5 s) is rerun with the step scaled to an amplitude a ∈ (0, a_max], everything else
unchanged (duration, disturbances, plant parameters, bounds, requirements). A run at amplitude a is
*held* when it meets the criterion:

* ``"passes"``: the run is stable and meets the scenario's requirements
  (:func:`lpvflow.pipeline.loop_metrics.run_metrics`: ``stable`` and no ``requirements_failed``);
* ``"bounded"``: the run finishes with finite signals inside the scenario's ``output_bounds`` (e.g. the
  pendulum is not lost), settled or not.

Assuming that a controller which holds a step also holds every smaller one, bisection finds the largest
held amplitude to within ``resolution``: the returned a is held (or 0: no tried step was held) and
a + resolution is not, unless a = a_max. The design report shows the result when the verify stage
records it as ``largest_held_step`` (:func:`lpvflow.pipeline.report_card.summary_card`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from lpvflow.errors import DataError
from lpvflow.pipeline.loop_metrics import run_metrics
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal, run_passed
from lpvflow.pipeline.verify import Baseline, simulate_loop

#: Criteria a run can be judged by (module docstring).
CRITERIA = ("passes", "bounded")
#: Default resolution of the bisection: 2.5° in rad.
DEFAULT_RESOLUTION = math.radians(2.5)


def step_output(template: Scenario, output: str | None = None) -> tuple[str, float, float]:
    """(output, step time, signed step size) of the template's one reference step; DataError otherwise."""
    stepped = {name: signal for name, signal in template.reference.items() if signal.steps}
    if output is None:
        if len(stepped) != 1:
            raise DataError(f"scenario {template.name!r}: the step sweep needs exactly one output with a "
                            f"reference step, found {len(stepped)}; name the output")
        output = next(iter(stepped))
    signal = template.reference.get(output)
    if signal is None or len(signal.steps) != 1 or signal.ramps:
        raise DataError(f"scenario {template.name!r}: the reference of {output!r} must be one step "
                        "(no ramps) for the step sweep")
    at, size = signal.steps[0]
    if size == 0.0:
        raise DataError(f"scenario {template.name!r}: the reference step of {output!r} is zero")
    return output, at, size


def scaled_step(template: Scenario, output: str, amplitude: float) -> Scenario:
    """The template with its reference step on ``output`` replaced by one of size ``amplitude`` (same
    sign and time as the template's step)."""
    _, at, size = step_output(template, output)
    signal = template.reference[output]
    stepped = Signal(signal.initial, ((at, math.copysign(amplitude, size)),))
    return replace(template, name=f"{template.name} (step {amplitude:.4g})",
                   reference={**template.reference, output: stepped})


def step_is_held(controller: Baseline, plant_fmu: str | Path, loop: Loop, scenario: Scenario,
                 criterion: str = "passes") -> bool:
    """One run of ``scenario`` judged by ``criterion`` (module docstring)."""
    if criterion not in CRITERIA:
        raise DataError(f"unknown step-sweep criterion {criterion!r}; choose one of {', '.join(CRITERIA)}")
    run = simulate_loop(controller, plant_fmu, scenario, loop, "step sweep")
    if criterion == "bounded":
        return run.failure is None
    return run_passed(run_metrics(run, scenario, loop))


def largest_held_step(
    controller: Baseline,
    plant_fmu: str | Path,
    loop: Loop,
    template: Scenario,
    *,
    output: str | None = None,
    max_step: float | None = None,
    resolution: float = DEFAULT_RESOLUTION,
    criterion: str = "passes",
    held: Callable[[Scenario], bool] | None = None,
) -> float:
    """The largest step amplitude (output units, ≥ 0) in (0, ``max_step``] that ``controller`` holds.

    ``template`` is a scenario with one reference step on ``output`` (default: its only stepped output);
    ``max_step`` defaults to |that step|. Bisection to within ``resolution`` (module docstring): the
    largest step is tried first, then the midpoint of the bracket [held, not held] until it is narrower
    than ``resolution``; about log2(max_step/resolution) + 1 runs. ``held`` replaces the FMU run (a
    function of the scaled scenario, for tests and other judges); by default
    :func:`step_is_held` with ``criterion``.
    """
    output, _, size = step_output(template, output)
    top = abs(size) if max_step is None else float(max_step)
    if not (math.isfinite(top) and top > 0):
        raise DataError(f"max_step = {max_step} must be a positive step size")
    if not (math.isfinite(resolution) and resolution > 0):
        raise DataError(f"resolution = {resolution} must be a positive step size")
    if criterion not in CRITERIA:
        raise DataError(f"unknown step-sweep criterion {criterion!r}; choose one of {', '.join(CRITERIA)}")
    judge = held or (lambda scenario: step_is_held(controller, plant_fmu, loop, scenario, criterion))
    if judge(scaled_step(template, output, top)):
        return top
    lo, hi = 0.0, top
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        if judge(scaled_step(template, output, mid)):
            lo = mid
        else:
            hi = mid
    return lo


def largest_steps(spec: dict, scenarios: list[Scenario], plant: str, loop: Loop, controllers: dict) -> dict:
    """``[verify] largest_step``: for each controller, the largest step of the named scenario it holds
    (:func:`largest_held_step`, bisection to its default resolution)."""
    template = next((s for s in scenarios if s.name == spec["scenario"]), None)
    if template is None:
        raise DataError(f"[verify] largest_step.scenario = {spec['scenario']!r} names no scenario; "
                        f"known: {[s.name for s in scenarios]}")
    output = step_output(template, None)[0]
    record = {"output": output, "criterion": spec["criterion"], "resolution": DEFAULT_RESOLUTION}
    for key, law in controllers.items():
        record[key] = largest_held_step(law, plant, loop, template, criterion=spec["criterion"])
    return record
