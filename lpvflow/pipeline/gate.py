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
    solver instead of naming the model)."""
    if not enabled:
        return {"passed": None, "reason": "gate off ([validate] gate = false)"}
    if "nugap_below_b_everywhere" not in outputs:
        return {"passed": None, "reason": "not evaluated: the ν-gap test needs [validate] reference = "
                                          "\"linearization\" or \"local\" and an [experiment] controller"}
    gaps, margins, theta = outputs["nugap"], outputs["b_P_Kid"], outputs["theta"]
    worst = int(np.argmax(np.asarray(gaps) - np.asarray(margins)))
    where = ", ".join(f"{v:.3g}" for v in theta[worst])
    if outputs["nugap_below_b_everywhere"]:
        return {"passed": True, "reason": f"ν-gap < b(P, K_id) at all {len(gaps)} frozen points (closest at "
                                          f"θ = {where}: ν-gap {gaps[worst]:.3g} < b {margins[worst]:.3g})"}
    failing = sum(g >= b for g, b in zip(gaps, margins, strict=True))
    reason = (f"the identified model fails the ν-gap test at {failing} of {len(gaps)} frozen points "
              f"(worst θ = {where}: ν-gap {gaps[worst]:.3g} ≥ b(P, K_id) {margins[worst]:.3g})")
    unstable = sum(b <= 0 for b in margins)
    deferred = judged_by_robustness and not unstable
    reason += NOT_APPLIED if deferred else "; it is not used for synthesis"
    if unstable:
        reason += (f"; the experiment controller does not stabilize the model's frozen loop at {unstable} of "
                   f"{len(gaps)} points (b = 0): the model does not describe the plant in that loop")
    if outputs.get("fit_failure"):
        reason += f"; validation fit: {outputs['fit_failure']}"
    if experiment and experiment.get("left_design_box"):
        reason += f"; the experiment record {experiment['left_design_box']}"
    return {"passed": None if deferred else False, "reason": reason}
