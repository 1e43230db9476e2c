"""The robustness stage's moving-parameter answer: up to which scheduling rate the shipped loop's stability is
certified, next to how fast the verify scenarios move the scheduling signal.

For a controller on a piecewise polytope whose scheduling columns are all ``[experiment] scheduling``
expressions of one measured output y_s (e.g. sin φ1, 1/(1 − κcos²φ1), … of the arm angle), the loop is
x⁺ = 𝒜(y_s)x: the reduced model frozen at θ(y_s) with u = K_fb(θ(y_s)) y
(:func:`lpvflow.pipeline.robustness.measurement_feedback`), and
:func:`lpvflow.validate.scheduled_stability.largest_certified_rate` tries the ladder (1/16, 1/4, 1) × the
largest per-sample change of y_s in the plant-in-the-loop runs of the trajectory validation (those runs,
not new ones), then any rate, stopping at the first rate not certified. The storage's breakpoints are the
controller's, in y_s as the design file gives them (``[synth] breakpoints = { signal = y_s, values = … }``,
:class:`lpvflow.pipeline.scheduling_values.SignalImages`, with the synth stage's ``inserted_breakpoints``,
:mod:`lpvflow.pipeline.breakpoint_refinement`); breakpoints given as scheduling rows, or
rows that are not the controller's, are a note saying so.

It runs where the controller's polytope has ``breakpoints`` (a piecewise polytope). A box over one
signal (the tanks designs) is left out although its two ends would do as breakpoints: ``[synth]`` gives
it no breakpoints in the measured signal.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Any

import control
import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment.scheduling import evaluate
from lpvflow.pipeline.breakpoint_refinement import design_breakpoints
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.scheduling_values import SignalImages
from lpvflow.validate.scheduled_stability import largest_certified_rate

#: The ladder, as fractions of the verify scenarios' peak rate (then any rate).
FRACTIONS = (1 / 16, 1 / 4, 1.0)


def scheduling_signal(expressions: list[str], outputs: list[str]) -> str | None:
    """The one output every expression is a function of (an expression may be the output's name), or None."""
    for name in outputs:
        try:
            for expression in expressions:
                evaluate(expression, {name: np.zeros(1)})
        except DataError:
            continue
        return name
    return None


def rate_certificate(ctx: StageContext, model: Any, controller: Any, trajectory: list[dict],
                     feedback: Callable[[np.ndarray], control.StateSpace]) -> dict:
    """``{"rate_certificate": {...}}`` (module docstring) or ``{"rate_certificate_note": why not}``, with
    ``feedback(θ)`` the controller's K_fb (u = K_fb y):
    the signal, its per-sample peak and the scenario, every rate tried (per sample; None: any), whether
    each was certified, the largest certified (0.0: none; None: any) and the wall time."""
    definitions = ctx.config["experiment"]["scheduling"] or {}
    expressions = [definitions.get(name, name) for name in model.p_names]
    signal = scheduling_signal(expressions, list(model.y_names))
    polytope = controller.polytope
    if polytope.breakpoints is None or signal is None:
        return {"rate_certificate_note": "not assessed: needs a controller on breakpoints (a piecewise "
                                         "polytope) scheduled by expressions of one measured output"}
    if not trajectory:
        return {"rate_certificate_note": "not assessed: no plant-in-the-loop runs to take the peak rate from"}
    inserted = ctx.outputs.get("synth", {}).get("inserted_breakpoints", [])
    given = design_breakpoints(ctx.config["synth"]["breakpoints"], inserted, list(model.p_names), definitions)
    breakpoints = _breakpoints(given, signal, polytope.breakpoints)
    if isinstance(breakpoints, str):
        return {"rate_certificate_note": f"not assessed: {breakpoints}"}
    theta = _curve(expressions, signal)
    fastest = max(trajectory, key=lambda row: row["largest_step"][signal])
    peak = float(fastest["largest_step"][signal])
    rates: list[float | None] = [f * peak for f in FRACTIONS] + [None]
    start = time.perf_counter()
    with warnings.catch_warnings():  # the controller's breakpoints may reach past the model's box
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        try:
            ladder = largest_certified_rate(_loop(model, feedback, theta), breakpoints, rates)
        except ModelError as exc:  # e.g. a frozen loop between the breakpoints that is unstable
            return {"rate_certificate_note": f"not assessed: {exc}"}
    return {"rate_certificate": {
        "signal": signal, "peak_per_sample": peak, "peak_scenario": fastest["scenario"],
        "Ts": float(model.Ts),
        "rates": rates, "certified": [r.certified for r in ladder.results], "largest": ladder.largest,
        "reason": next((r.reason for r in ladder.results if not r.certified), ""),
        "breakpoints": [float(b) for b in breakpoints], "seconds": time.perf_counter() - start}}


def _curve(expressions: list[str], signal: str) -> Callable[[np.ndarray], np.ndarray]:
    """values of y_s ↦ θ rows."""
    return lambda values: np.column_stack([np.broadcast_to(evaluate(e, {signal: values}), values.shape)
                                           for e in expressions])


def _breakpoints(given: Any, signal: str, controller_breakpoints: np.ndarray) -> np.ndarray | str:
    """The values of y_s at the controller's breakpoints: ``[synth] breakpoints`` as the design file gives
    them in ``signal``, when their images' first column is the controller's breakpoints (to 1e-9
    relative); else why not, in words."""
    if not (isinstance(given, SignalImages) and given.source.signal == signal):
        return (f"give [synth] breakpoints as values of {signal} ({{ signal = \"{signal}\", values = [...] "
                "}) so the controller's breakpoints are known along it")
    first = np.asarray(given, dtype=float)[:, 0]
    controller = np.asarray(controller_breakpoints, dtype=float)
    if first.shape != controller.shape or not np.allclose(first, controller, rtol=1e-9, atol=1e-12):
        return ("the controller's breakpoints are not those of [synth] breakpoints (a controller of "
                "another design)")
    return np.asarray(given.source.values, dtype=float)


def _loop(model: Any, feedback: Callable, theta: Callable) -> Callable[[float], np.ndarray]:
    """y_s ↦ 𝒜 of the frozen model under u = K_fb y (module docstring)."""

    def loop_at(value: float) -> np.ndarray:
        p = theta(np.array([value]))[0]
        G = model.frozen(p)
        plant = control.ss(G.A, G.B, G.C, G.D, model.Ts)
        return np.asarray(control.feedback(plant, feedback(p), sign=+1).A)

    return loop_at
