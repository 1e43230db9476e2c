"""One ``[synth]`` table to one certified controller: the step shared by ``lpvflow synth`` and the design
pipeline's synth stage.

``method = "common"``: :func:`lpvflow.synth.hinf.synthesize` (one Lyapunov matrix, any polytope);
``method = "rate-bounded"``: :func:`lpvflow.synth.rate_bounded.synthesize_rate_bounded` (parameter-
dependent Lyapunov function, |p(k+1) − p(k)| ≤ ``rate_bound``); both on the generalized plant of
:func:`lpvflow.synth.plant.generalized_plant` with the table's weights, box, breakpoints, scheduled
weights and structure, and re-checked by :mod:`lpvflow.synth.certify`.
"""

from __future__ import annotations

from dataclasses import dataclass

from lpvflow.models import LPVSS
from lpvflow.synth.certify import Certificate, certify, certify_rate_bounded
from lpvflow.synth.controller import LPVController
from lpvflow.synth.hinf import synthesize
from lpvflow.synth.plant import GeneralizedPlant, generalized_plant
from lpvflow.synth.rate_bounded import synthesize_rate_bounded


@dataclass
class Design:
    """A certified controller and what the report states about it."""

    controller: LPVController
    gamma: float
    gamma_lower: float
    certificate: Certificate
    plant: GeneralizedPlant
    seconds: float


def synthesize_design(model: LPVSS, settings: dict, box: list | None = None) -> Design:
    """The controller of a ``[synth]`` table (module docstring); ``box`` overrides the table's box (the
    LTI baseline's degenerate box)."""
    weights, structure = settings["weights"], settings["structure"]
    point = box is not None
    plant = generalized_plant(model, weights, settings["box"] if box is None else box, structure,
                              None if point else settings["breakpoints"],
                              None if point else settings["vertex_weights"])
    if settings["method"] == "rate-bounded" and not point:
        result, controller = synthesize_rate_bounded(plant, settings["rate_bound"], settings["solver"])
        # scheduled weights, or scheduling signals tied along the breakpoints: the design's own plant
        frozen_model = None if settings["vertex_weights"] or model.basis.n_p > 1 else model
        certificate = certify_rate_bounded(result, frozen_model, weights, structure)
        return Design(controller, result.gamma, result.gamma_min, certificate, plant, result.report.seconds)
    result = synthesize(plant, settings["solver"])
    return Design(result.controller, result.gamma, result.gamma_lower, certify(result, model, weights), plant,
                  result.report.seconds)
