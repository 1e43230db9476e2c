"""The robustness stage: the shipped controller's robust stability at the validate stage's frozen points.

At every frozen scheduling point θ of the validate stage, with Ĝ(θ) the frozen reduced model and K_fb(θ)
the feedback part of the synthesized controller (:func:`measurement_feedback`), both in the validate
stage's signal scaling (:func:`lpvflow.pipeline.frozen_references.signal_scaling`: D_y⁻¹ Ĝ D_u and
D_u⁻¹ K_fb D_y), it reports

* b(Ĝ, K_fb) = 1/‖[I; K](I − ĜK)⁻¹[I  Ĝ]‖∞ for u = K_fb y (0 if the loop is unstable),
* the ν-gap δν(G_FMU(θ), Ĝ(θ)) the validate stage computed there, and whether b > δν,
* the input delay margin in samples and the balanced disk margin at the plant input

(:mod:`lpvflow.validate.robust_stability`). Vinnicombe's theorem (*Uncertainty and Feedback: H∞
loop-shaping and the ν-gap metric*, 2001): K_fb stabilizes every plant G with
δν(G, Ĝ) < b(Ĝ, K_fb), so b > δν at θ guarantees that the controller frozen at θ stabilizes the plant
frozen there. With ``[synth] robustness_gate = true`` it is also a gate (:func:`robustness_verdict`): a
controller with b ≤ δν at a point ends the design there, as the validate stage's ν-gap gate does; without
it the stage only reports.

Frozen points say nothing about the moves between them. With ``[verify]`` scenarios the stage also runs
the model in the loop of the same controller against the plant FMU in that loop on every scenario and
reports the largest difference of each measured output (:mod:`lpvflow.pipeline.trajectory_validation`);
that is never part of the gate. With ``[synth] rate_certificate = true`` it also reports up to which rate
of the scheduling signal the loop's stability is certified, next to the fastest move of those runs
(:mod:`lpvflow.pipeline.rate_certificate`).
"""

from __future__ import annotations

import warnings
from typing import Any

import control
import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.models import load
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.coordinates import read_data
from lpvflow.pipeline.frozen_references import signal_scaling
from lpvflow.pipeline.gate import shortfall
from lpvflow.pipeline.rate_certificate import rate_certificate
from lpvflow.pipeline.trajectory_validation import trajectory_validation
from lpvflow.validate.robust_stability import delay_margin_samples, generalized_margin, input_disk_margin
from lpvflow.validate.scaling import SignalScaling


def measurement_feedback(controller: Any, p: np.ndarray) -> control.StateSpace:
    """K_fb(p) with u = K_fb y: the controller frozen at p, from the measurements y to its output u.

    A ``"1dof"`` controller reads e = r − y, so u = K(p)(r − y) and K_fb = −K(p). A ``"2dof"`` controller
    reads w = [r; y], u = K_r r + K_y y, so K_fb = K_y, the columns that read y
    (:class:`lpvflow.synth.controller.LPVController`). The trim u_eq(p) is a feed-forward of the
    scheduling signal and not part of K_fb.
    """
    K = controller.frozen(np.asarray(p, dtype=float))
    if controller.structure == "1dof":
        return -K
    ny = controller.n_measured
    return control.ss(K.A, K.B[:, ny:], K.C, K.D[:, ny:], K.dt)


def robustness_rows(model: Any, controller: Any, scale: SignalScaling, thetas: list[list[float]],
                    nugaps: list[float] | None) -> list[dict]:
    """One row per frozen point θ: θ, b(Ĝ, K_fb), the ν-gap there (when given) and b > δν, the input delay
    margin (samples; −1 when the loop is unstable) and the balanced input disk margin α with its gain (dB)
    and phase (deg) margins, Ĝ and K_fb scaled by ``scale`` (module docstring)."""
    rows = []
    for i, theta in enumerate(thetas):
        G = scale.plant(model.frozen(np.asarray(theta, dtype=float)))
        K = scale.controller(measurement_feedback(controller, theta))
        alpha, gain_db, phase_deg = input_disk_margin(G, K)
        row = {"theta": list(theta), "b": generalized_margin(G, K)}
        if nugaps is not None:
            row |= {"nugap": nugaps[i], "b_above_nugap": row["b"] > nugaps[i]}
        rows.append(row | {"delay_margin_samples": delay_margin_samples(G, K), "input_disk_margin": alpha,
                           "input_disk_gain_margin_db": gain_db, "input_disk_phase_margin_deg": phase_deg})
    return rows


def robustness_verdict(outputs: dict, enabled: bool) -> dict:
    """The robust-stability gate: ``{"passed": bool | None, "reason": str}`` from the stage's ``rows`` and
    ``guaranteed``. None when off or not evaluated (no ν-gap); False when b(Ĝ, K_fb) ≤ δν at a point, the
    reason naming the point with the smallest b − δν."""
    if not enabled:
        return {"passed": None, "reason": "gate off ([synth] robustness_gate = false)"}
    if outputs["guaranteed"] is None:
        return {"passed": None, "reason": "not evaluated: the validate stage computed no ν-gap ([validate] "
                                          "reference = \"linearization\" or \"local\")"}
    rows = outputs["rows"]
    failing, index, where = shortfall([row["nugap"] for row in rows], [row["b"] for row in rows],
                                      [row["theta"] for row in rows])
    worst = rows[index]
    if outputs["guaranteed"]:
        return {"passed": True, "reason": f"b(Ĝ, K_fb) > ν-gap at all {len(rows)} points (closest at θ = "
                                          f"{where}: b {worst['b']:.3g} > ν-gap {worst['nugap']:.3g})"}
    return {"passed": False,
            "reason": f"the controller's robust stability is not guaranteed at {failing} of {len(rows)} "
                      f"points (worst θ = {where}: b(Ĝ, K_fb) {worst['b']:.3g} ≤ ν-gap "
                      f"{worst['nugap']:.3g}); "
                      "[synth] robustness_gate = true stops the design here"}


def robustness(ctx: StageContext) -> tuple[dict, list[str]]:
    """The rows of :func:`robustness_rows` at the validate stage's points (``theta``, ``nugap``) for the
    synth stage's controller and the reduced model, in the validate stage's scaling; ``guaranteed`` is
    whether b > δν at every point (None without a ν-gap), ``not_guaranteed_at`` the points where not and
    ``gate`` the :func:`robustness_verdict` of ``[synth] robustness_gate``. With ``[verify]`` scenarios
    and a plant FMU, also the model-in-the-loop against the plant-in-the-loop under the same controller
    on each scenario (:func:`~lpvflow.pipeline.trajectory_validation.trajectory_validation`: ``trajectory``
    or ``trajectory_note``), reported only."""
    validate = ctx.outputs["validate"]
    model, controller = load(ctx.path("model.json")), load(ctx.path("controller.json"))
    est, _ = read_data(ctx)
    scale = signal_scaling(ctx.config["validate"]["scaling"], est, model)
    with warnings.catch_warnings():  # the validate stage's points, which it checked against the box
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        rows = robustness_rows(model, controller, scale, validate.get("theta") or [], validate.get("nugap"))
    outputs: dict[str, Any] = {"rows": rows, "guaranteed": None}
    if rows and "nugap" in rows[0]:
        outputs["not_guaranteed_at"] = [row["theta"] for row in rows if not row["b_above_nugap"]]
        outputs["guaranteed"] = not outputs["not_guaranteed_at"]
    if ctx.config["verify"] is not None and ctx.config["design"]["plant"]:
        outputs |= trajectory_validation(ctx, model, controller)
    if ctx.config["synth"].get("rate_certificate"):
        outputs |= rate_certificate(ctx, model, controller, outputs.get("trajectory", []),
                                    lambda p: measurement_feedback(controller, p))
    outputs["gate"] = robustness_verdict(outputs, bool(ctx.config["synth"].get("robustness_gate")))
    return outputs, []
