"""One ``[synth]`` table to one certified controller: the step shared by ``lpvflow synth`` and the design
pipeline's synth stage.

The table's ``method`` picks a design function from the registry :mod:`lpvflow.synth.methods`
(:func:`design_common`, :func:`design_rate_bounded`, :func:`design_observer` here); each works on the
generalized plant of :func:`lpvflow.synth.plant.generalized_plant` with the table's weights, box,
breakpoints, scheduled weights and structure, and returns its controller with its check. The table's
``trim`` (feed-forward u_eq(p), :class:`lpvflow.synth.controller.Trim`) is part of the controller it
returns: a model identified with the trim removed (``[identify] remove_trim``) describes the plant with
that trim in the loop, so a controller without it would not be the one designed.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from lpvflow.errors import DataError
from lpvflow.models import LPVSS
from lpvflow.synth.certify import certify, certify_rate_bounded
from lpvflow.synth.controller import LPVController, Trim
from lpvflow.synth.hinf import synthesize
from lpvflow.synth.methods import SYNTHESIS_METHODS
from lpvflow.synth.observer import ObserverSettings, observer_design
from lpvflow.synth.plant import GeneralizedPlant, generalized_plant
from lpvflow.synth.rate_bounded import synthesize_rate_bounded


class Check(Protocol):
    """A design's check as the report and ``lpvflow synth`` read it: a verdict and the lines that say why
    (:class:`lpvflow.synth.certify.Certificate` of the LMI methods,
    :class:`lpvflow.synth.observer.FrozenCheck` of the observer design)."""

    @property
    def ok(self) -> bool: ...

    def lines(self) -> list[str]: ...


@dataclass
class Design:
    """A checked controller and what the report states about it: ``gamma`` the certified level (LMI
    methods) or the largest frozen ‖T_zw‖∞ (observer) — no method states a lower bound: the LMI
    syntheses' eliminated-conditions minimum is only an estimate (:mod:`lpvflow.synth.eliminated`),
    kept in ``controller.info["gamma_estimate"]``; ``antiwindup_gains`` the
    design's own anti-windup gains (observer), None for the generic
    :func:`lpvflow.synth.controller.observer_gains`."""

    controller: LPVController
    gamma: float
    certificate: Check
    plant: GeneralizedPlant
    seconds: float
    antiwindup_gains: np.ndarray | None = None


def synthesize_design(model: LPVSS, settings: Mapping[str, Any], box: list | None = None) -> Design:
    """The controller of a ``[synth]`` table: the design function its ``method`` names in
    :data:`lpvflow.synth.methods.SYNTHESIS_METHODS`, with the table's trim; ``box`` overrides the table's
    box (the LTI baseline's degenerate box: designed by the method itself when its ``point_design`` says
    so, else by :func:`design_common`)."""
    point = box is not None
    plant = generalized_plant(model, settings["weights"], settings["box"] if box is None else box,
                              settings["structure"], None if point else settings["breakpoints"],
                              None if point else settings["vertex_weights"])
    # scheduled weights, or scheduling signals tied along the breakpoints: the frozen check runs on the
    # design's own plant (the model's box corners lie off the curve the signals follow)
    tied = settings["breakpoints"] is not None and model.basis.n_p > 1
    frozen_model = None if not point and (settings["vertex_weights"] or tied) else model
    if settings["method"] not in SYNTHESIS_METHODS:
        raise DataError(f"[synth] method = {settings['method']!r} is unknown; use one of "
                        f"{', '.join(SYNTHESIS_METHODS)}")
    method = SYNTHESIS_METHODS[settings["method"]]
    if settings.get("margin_goal") and settings["method"] != "loop-shaping":
        raise DataError(f"[synth] margin_goal shapes the loop-shaping design only, not method = "
                        f"{settings['method']!r}: remove it or use method = \"loop-shaping\"")
    if settings.get("scheduling", "frozen") != "frozen" and settings["method"] != "loop-shaping":
        raise DataError(f"[synth] scheduling = {settings['scheduling']!r} schedules the loop-shaping design "
                        f"only, not method = {settings['method']!r}: remove it or use "
                        "method = \"loop-shaping\"")
    if point and not method.point_design:
        design = design_common(model, plant, settings, frozen_model)
    else:
        design = method.design_function()(model, plant, settings, frozen_model)
    design.controller.trim = trim(settings, design.controller)
    return design


def design_common(model: LPVSS, plant: GeneralizedPlant, settings: Mapping[str, Any],
                  frozen_model: LPVSS | None) -> Design:
    """``method = "common"``: :func:`lpvflow.synth.hinf.synthesize` (one Lyapunov matrix, any polytope),
    certified by :func:`lpvflow.synth.certify.certify`."""
    result = synthesize(plant, settings["solver"])
    return Design(result.controller, result.gamma, certify(result, frozen_model), plant,
                  result.report.seconds)


def design_rate_bounded(model: LPVSS, plant: GeneralizedPlant, settings: Mapping[str, Any],
                        frozen_model: LPVSS | None) -> Design:
    """``method = "rate-bounded"``: :func:`lpvflow.synth.rate_bounded.synthesize_rate_bounded`
    (parameter-dependent Lyapunov function, |p(k+1) − p(k)| ≤ ``rate_bound``), certified by
    :func:`lpvflow.synth.certify.certify_rate_bounded`."""
    result, controller = synthesize_rate_bounded(plant, settings["rate_bound"], settings["solver"])
    certificate = certify_rate_bounded(result, frozen_model, plant.weights, settings["structure"])
    return Design(controller, result.gamma, certificate, plant, result.report.seconds)


def design_observer(model: LPVSS, plant: GeneralizedPlant, settings: Mapping[str, Any],
                    frozen_model: LPVSS | None) -> Design:
    """``method = "observer"``: :func:`lpvflow.synth.observer.observer_design` (frozen LQG designs at the
    breakpoints, interpolated; checked at frozen points only, :class:`lpvflow.synth.observer.FrozenCheck`)."""
    start = time.perf_counter()
    filt = settings.get("reference_filter") or {}
    observer = observer_design(plant, model, ObserverSettings(
        **(settings.get("observer") or {}), filter_bandwidth=filt.get("bandwidth"),
        filter_damping=filt.get("damping", 1.0)))
    return Design(observer.controller, observer.check.hinf_max, observer.check, plant,
                  time.perf_counter() - start, observer.antiwindup_gains)


def trim(settings: Mapping[str, Any], controller: LPVController) -> Trim | None:
    """The trim feed-forward u_eq(p) of the table's ``trim`` (None without the key); a table whose rows do
    not have one value per controller output is one DataError line."""
    table = settings.get("trim")  # tables built in code may leave the key out
    if table is None:
        return None
    width = len(table["u"][0])
    if width != controller.n_out:
        raise DataError(f"[synth] trim.u rows have {width} value(s); the controller drives "
                        f"{controller.n_out} plant input(s): give one value per input in each row")
    return Trim(table["p"], table["u"])
