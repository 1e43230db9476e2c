"""The validate stage's gate: the ν-gap of the model to the plant below the identification loop's margin."""

from __future__ import annotations

import numpy as np

#: The ``[validate]`` entry the design adds in the final pass of an identification-for-control design with
#: ``[synth] robustness_gate = true`` (not a design-file key): the robustness stage judges that pass's model.
JUDGED_BY_ROBUSTNESS = "judged_by_robustness"
#: What a failing K_id test says when :data:`JUDGED_BY_ROBUSTNESS` is set.
NOT_APPLIED = ("; not applied: K_id is the identification-for-control round's controller, not the one the "
               "design ships — the robustness stage judges the model against that ([synth] robustness_gate)")


def gate_verdict(outputs: dict, enabled: bool, experiment: dict | None = None,
                 judged_by_robustness: bool = False) -> dict:
    """The ν-gap/b(P, K) gate of the validate stage: ``{"passed": bool | None, "reason": str}``.

    The model passes when δν(G_FMU(θ), Ĝ(θ)) < b(Ĝ(θ), K_id) at every frozen grid point, i.e. the
    identification controller provably stabilizes every frozen plant as close to the model as the FMU
    is (Vinnicombe's robust-stability test; thesis Fig. 6.11). ``passed`` is False when it fails, with the
    worst point in the reason (the design then stops after validate when the gate is on), and None when
    it was not evaluated (gate off, or no FMU reference or no experiment controller to compute it). A failing
    reason also says where the record left the experiment controller's design box (``left_design_box`` of
    the ``experiment`` stage's outputs), which is what a lost loop looks like, at how many points the
    experiment controller does not stabilize the model (b = 0), and why the validation fit failed
    (``fit_failure``: e.g. the model's closed loop diverges).

    ``judged_by_robustness`` (the final pass of an ``[experiment] iterate`` design with ``[synth]
    robustness_gate = true``): K_id is then the controller of the last identification-for-control round,
    not the one the design ships, and the robustness stage applies the same test to the shipped controller,
    b(Ĝ(θ), K_fb(θ)) > δν(θ) at the same points — the test for the loop the model is identified for (thesis
    §6.1). A failing K_id test is then reported with ``passed`` None (not applied) instead of stopping the
    design — unless K_id does not stabilize the model's frozen loop somewhere (b = 0): the loop that recorded
    the data was stable, so such a model does not describe the plant whatever controller is shipped (held-out
    ADIP seed 5: a spurious unstable mode, b = 0 at all nine points; deferred, its synthesis failed on the
    solver instead of naming the model) or the model's own optimal margin is not above the ν-gap somewhere
    (``b_opt``, b_opt(Ĝ(θ)) = (1 + λmax(XZ))^{−1/2} of :mod:`lpvflow.validate.robust_stability` in the same
    scaling): b(Ĝ, K) ≤ b_opt(Ĝ) for every controller K, so no controller can pass the robustness stage's
    test there and the synthesis would be spent on a model already refused (held-out ADIP seed 12: b_opt
    0.178 ≤ ν-gap 0.179 at +75°; its synthesis took 813 s before the robustness gate stopped it)."""
    if not enabled:
        return {"passed": None, "reason": "gate off ([validate] gate = false)"}
    if "nugap_below_b_everywhere" not in outputs:
        return {"passed": None, "reason": "not evaluated: the ν-gap test needs [validate] reference = "
                                          "\"linearization\" or \"local\" and an [experiment] controller"}
    gaps, margins, theta = outputs["nugap"], outputs["b_P_Kid"], outputs["theta"]
    failing, worst, where = shortfall(gaps, margins, theta)
    if outputs["nugap_below_b_everywhere"]:
        return {"passed": True, "reason": f"ν-gap < b(P, K_id) at all {len(gaps)} frozen points (closest at "
                                          f"θ = {where}: ν-gap {gaps[worst]:.3g} < b {margins[worst]:.3g})"}
    reason = (f"the identified model fails the ν-gap test at {failing} of {len(gaps)} frozen points "
              f"(worst θ = {where}: ν-gap {gaps[worst]:.3g} ≥ b(P, K_id) {margins[worst]:.3g})")
    unstable = sum(b <= 0 for b in margins)
    beyond = _beyond_any_controller(outputs)
    deferred = judged_by_robustness and not unstable and not beyond
    reason += NOT_APPLIED if deferred else "; it is not used for synthesis"
    if judged_by_robustness and beyond:
        reason += f"; no controller can pass the robustness stage's test: {beyond}"
    if unstable:
        reason += (f"; the experiment controller does not stabilize the model's frozen loop at {unstable} of "
                   f"{len(gaps)} points (b = 0): the model does not describe the plant in that loop")
    if outputs.get("fit_failure"):
        reason += f"; validation fit: {outputs['fit_failure']}"
    if experiment and experiment.get("left_design_box"):
        reason += f"; the experiment record {experiment['left_design_box']}"
    return {"passed": None if deferred else False, "reason": reason}


def _beyond_any_controller(outputs: dict) -> str:
    """Where the model's optimal margin is not above the ν-gap (``b_opt`` ≤ ``nugap``, the worst point
    named), or "" when it is above at every point or was not computed."""
    if "b_opt" not in outputs:
        return ""
    gaps, optimal = outputs["nugap"], outputs["b_opt"]
    short, worst, where = shortfall(gaps, optimal, outputs["theta"])
    if not short:
        return ""
    return (f"b_opt(Ĝ) ≤ ν-gap at {short} of {len(gaps)} points (worst θ = {where}: b_opt "
            f"{optimal[worst]:.3g} ≤ ν-gap {gaps[worst]:.3g}), and b(Ĝ, K) ≤ b_opt(Ĝ) for every K")


def shortfall(gaps: list[float], margins: list[float], theta: list[list[float]]) -> tuple[int, int, str]:
    """Vinnicombe's test δν < b point by point: (how many points fail it, margin ≤ ν-gap; the index of the
    point with the largest δν − b, the first of equals; its θ as text "a, b, c")."""
    worst = int(np.argmax(np.asarray(gaps, dtype=float) - np.asarray(margins, dtype=float)))
    failing = sum(b <= g for g, b in zip(gaps, margins, strict=True))
    return failing, worst, ", ".join(f"{v:.3g}" for v in theta[worst])
