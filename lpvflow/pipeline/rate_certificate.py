"""The robustness stage's moving-parameter answer: up to which scheduling rate the shipped loop's stability is
certified, next to how fast the verify scenarios move the scheduling signal.

For a controller on a piecewise polytope whose scheduling columns are all ``[experiment] scheduling``
expressions of one measured output y_s (e.g. sin φ1, 1/(1 − κcos²φ1), … of the arm angle), the loop is
x⁺ = 𝒜(y_s)x: the reduced model frozen at θ(y_s) with u = K_fb(θ(y_s)) y
(:func:`lpvflow.pipeline.robustness.measurement_feedback`), and
:func:`lpvflow.validate.scheduled_stability.largest_certified_rate` tries the ladder (1/16, 1/4, 1) × the
largest per-sample change of y_s in the plant-in-the-loop runs of the trajectory validation (those runs,
not new ones), then any rate, stopping at the first rate not certified. The storage's breakpoints are the
controller's, mapped to y_s on (a widening of) the recorded range of y_s.
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
from lpvflow.pipeline.context import StageContext
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
    if polytope.kind != "piecewise" or signal is None:
        return {"rate_certificate_note": "not assessed: needs a controller on breakpoints (a piecewise "
                                         "polytope) scheduled by expressions of one measured output"}
    if not trajectory:
        return {"rate_certificate_note": "not assessed: no plant-in-the-loop runs to take the peak rate from"}
    theta = _curve(expressions, signal)
    breakpoints = _breakpoints(ctx, signal, theta, np.asarray(polytope.psi_vertices)[:, 1:])
    if breakpoints is None:
        return {"rate_certificate_note": f"not assessed: the controller's breakpoints are not on the curve "
                                         f"of {signal} over its recorded range"}
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


def _breakpoints(ctx: StageContext, signal: str, theta: Callable, vertices: np.ndarray) -> np.ndarray | None:
    """The values of y_s whose θ are the polytope's vertices: the nearest of 40001 values over its recorded
    range widened by half its width on either side (breakpoints may lie past the recorded moves); None
    when one misses by more than 10⁻³ of the span of θ or they are not ascending."""
    ranges = ctx.outputs.get("experiment", {}).get("ranges", {})  # the experiment stage's, in this pass
    if signal not in ranges:
        return None
    lo, hi = ranges[signal]
    grid = np.linspace(lo - (hi - lo) / 2, hi + (hi - lo) / 2, 40001)
    curve = theta(grid)
    span = np.ptp(curve, axis=0) + 1e-12
    miss = np.abs((curve[None, :, :] - vertices[:, None, :]) / span).max(axis=2)
    nearest = miss.argmin(axis=1)
    if miss[np.arange(len(vertices)), nearest].max() > 1e-3 or np.any(np.diff(nearest) <= 0):
        return None
    return grid[nearest]


def _loop(model: Any, feedback: Callable, theta: Callable) -> Callable[[float], np.ndarray]:
    """y_s ↦ 𝒜 of the frozen model under u = K_fb y (module docstring)."""

    def loop_at(value: float) -> np.ndarray:
        p = theta(np.array([value]))[0]
        G = model.frozen(p)
        plant = control.ss(G.A, G.B, G.C, G.D, model.Ts)
        return np.asarray(control.feedback(plant, feedback(p), sign=+1).A)

    return loop_at
