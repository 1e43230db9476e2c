"""Discrete-time H∞ output-feedback synthesis by LMIs, LTI, polytopic and rate-bounded, in python-control's
idiom.

``hinfsyn(P, nmeas, ncon)`` takes one discrete ``control.StateSpace`` (an LTI design) or a sequence of
vertex ``StateSpace``s with the same partition (a polytopic design with one common Lyapunov matrix: the
method of :mod:`lpvflow.synth.vertex_synthesis`), or with ``breakpoints`` the rate-bounded design of
:mod:`lpvflow.synth.rate_bounded`. :func:`synthesize` runs the polytopic design on a mixed-sensitivity
:class:`lpvflow.synth.plant.GeneralizedPlant` and returns the implementable controller.
"""

from __future__ import annotations

from collections.abc import Sequence

import control
import numpy as np

from lpvflow.errors import CentralLevelError, ModelError, SynthesisError
from lpvflow.synth.central import central_vertices
from lpvflow.synth.controller import LPVController, series_input_filter
from lpvflow.synth.levels import GAMMA_MAX
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant, check_a3
from lpvflow.synth.rate_bounded import synthesize_scheduled
from lpvflow.synth.vertex_synthesis import SUBOPTIMALITY, HinfResult, synthesize_vertices

__all__ = ["HinfResult", "central_hinfsyn", "hinfsyn", "synthesize"]


def _partition(P: control.StateSpace, nmeas: int, ncon: int) -> VertexPlant:
    if not isinstance(P, control.StateSpace):
        raise ModelError(f"hinfsyn needs control.StateSpace plants, got {type(P).__name__}")
    if not P.isdtime(strict=True):
        raise ModelError("hinfsyn is discrete-time: give a StateSpace with dt = Ts > 0")
    if not (0 < nmeas < P.noutputs and 0 < ncon < P.ninputs):
        raise ModelError(f"nmeas = {nmeas} and ncon = {ncon} must leave exogenous inputs and performance "
                         f"outputs (plant has {P.ninputs} inputs, {P.noutputs} outputs)")
    v = VertexPlant.from_ss(P, nw=P.ninputs - ncon, nz=P.noutputs - nmeas)
    if not all(np.all(np.isfinite(M)) for M in (v.A, v.B1, v.B2, v.C1, v.C2, v.D11, v.D12, v.D21, v.D22)):
        raise ModelError("the generalized plant has NaN or infinite entries")
    return v


def _vertices(P: control.StateSpace | Sequence[control.StateSpace], nmeas: int, ncon: int, caller: str
              ) -> tuple[list[VertexPlant], float]:
    """The partitioned vertex plants of ``P`` (one StateSpace or a sequence) and their sampling time."""
    plants = [P] if isinstance(P, control.StateSpace) else list(P)
    if not plants:
        raise ModelError(f"{caller} needs at least one plant")
    vertices = [_partition(G, nmeas, ncon) for G in plants]
    if len({v.dims for v in vertices}) > 1 or len({float(G.dt) for G in plants}) > 1:
        raise ModelError("the vertex plants differ in size, partition or sampling time")
    return vertices, float(plants[0].dt)


def hinfsyn(P: control.StateSpace | Sequence[control.StateSpace], nmeas: int, ncon: int, *,
            suboptimality: float | None = None, gamma_max: float = GAMMA_MAX, solver: str = "CLARABEL",
            breakpoints: Sequence[float] | None = None, rate_bound: float | None = None):
    """H∞ controller for the discrete generalized plant ``P`` (one StateSpace: LTI; a sequence: vertices).

    As ``control.hinfsyn(P, nmeas, ncon)``: the last ``nmeas`` outputs are measured, the last ``ncon``
    inputs are controlled. The steps are those of :mod:`lpvflow.synth.vertex_synthesis`. With
    ``breakpoints`` (the values of one scheduling signal at which the plants of ``P`` are given,
    ascending), the design is the rate-bounded one of :mod:`lpvflow.synth.rate_bounded` instead — a
    parameter-dependent Lyapunov
    function, |p(k+1) − p(k)| ≤ ``rate_bound`` (None: any rate), the plant and the controller linear in p
    between breakpoints — and the result a :class:`lpvflow.synth.rate_bounded.ScheduledResult`
    (``.controller(p)`` the controller frozen at p).

    Args:
        suboptimality: δ of its step 5: the certified γ is within a factor 1 + δ of the highest level that
            failed (default 2.5e-3); for the rate-bounded design, of a failing level or of its
            ``gamma_estimate``, below which no level is tried (default 1e-2).
        gamma_max: the largest level tried (default :data:`lpvflow.synth.levels.GAMMA_MAX`, 1e6).
        solver: the SDP solver for every SDP, ``"CLARABEL"`` (default) or ``"SCS"``; no fallback.
        breakpoints, rate_bound: the rate-bounded design (above).

    Raises:
        ModelError: a plant that is not discrete, has non-finite entries, or partitions that differ.
        SynthesisError: with ``category`` ``"assumption"`` (an unstabilizable or undetectable mode, a pole
            at z = −1, or B2, C2, D12, D21 not constant over the vertices), ``"infeasible"`` (no level up
            to ``gamma_max``; for one plant the message says whether SB10DD finds one) or ``"accuracy"``
            (the solver's statuses, when it could not reach the accuracy a certificate needs).
    """
    vertices, Ts = _vertices(P, nmeas, ncon, "hinfsyn")
    if not gamma_max > 0:
        raise ModelError(f"gamma_max must be positive, got {gamma_max!r}")
    if breakpoints is not None:
        check_a3(vertices)
        delta = 1e-2 if suboptimality is None else suboptimality
        return synthesize_scheduled(vertices, breakpoints, Ts, rate_bound=rate_bound, suboptimality=delta,
                                    solver=solver)
    if rate_bound is not None:
        raise ModelError("rate_bound needs breakpoints: the scheduling value of each plant in P")
    delta = SUBOPTIMALITY if suboptimality is None else suboptimality
    return synthesize_vertices(vertices, Ts, delta, gamma_max, solver)


def central_hinfsyn(P: control.StateSpace | Sequence[control.StateSpace], nmeas: int, ncon: int, gamma: float,
                    *, solver: str = "CLARABEL") -> HinfResult:
    """The central H∞ controller at the level ``gamma`` from the LMIs (:mod:`lpvflow.synth.central`): the
    largest R, S of the eliminated conditions at γ (kept a small margin inside) and the controller in closed
    form, certified like :func:`hinfsyn`'s. ``P``, ``nmeas``, ``ncon`` as there (vertices share one
    Lyapunov matrix); ``gamma`` above the optimum (e.g. 1.01 × :func:`hinfsyn`'s γ).

    Raises:
        ModelError: as :func:`hinfsyn`, or a level that is not positive.
        SynthesisError: ``"assumption"`` as :func:`hinfsyn`; ``"infeasible"`` no controller reaches γ
            (for one plant: SB10DD does not reach it either); ``"accuracy"`` a solve without a point, a
            solve SB10DD contradicts, or a controller that fails its certificate.
    """
    vertices, Ts = _vertices(P, nmeas, ncon, "central_hinfsyn")
    if not (np.isfinite(gamma) and gamma > 0):
        raise ModelError(f"gamma must be a positive level, got {gamma!r}")
    return central_vertices(vertices, Ts, float(gamma), solver)


def central_near_optimum(P: control.StateSpace | Sequence[control.StateSpace], nmeas: int, ncon: int,
                         factor: float, *, solver: str = "CLARABEL") -> tuple[HinfResult, float]:
    """(:func:`central_hinfsyn` at ``factor`` × γ_LMI, γ_LMI): γ_LMI the certified optimum of
    :func:`hinfsyn` on the same plants, whose preconditioning (steps 2–4 of
    :mod:`lpvflow.synth.vertex_synthesis`, independent of the level) the central solution reuses.

    Raises:
        ModelError: as :func:`hinfsyn`, or ``factor`` not above 1.
        SynthesisError: as :func:`hinfsyn` (the optimum search); the central controller's as
            :class:`~lpvflow.errors.CentralLevelError` (as :func:`central_hinfsyn`, with ``factor``).
    """
    if not factor > 1.0:
        raise ModelError(f"factor is {factor!r}; it must be > 1 (the level above the optimum the central "
                         "controller is built at), e.g. 1.01")
    vertices, Ts = _vertices(P, nmeas, ncon, "central_near_optimum")
    optimum = synthesize_vertices(vertices, Ts, SUBOPTIMALITY, GAMMA_MAX, solver)
    try:
        central = central_vertices(vertices, Ts, factor * optimum.gamma, solver, optimum.preconditioning)
    except SynthesisError as exc:
        raise CentralLevelError(str(exc), exc.category, factor) from None
    return central, float(optimum.gamma)


def synthesize(plant: GeneralizedPlant, solver: str = "CLARABEL", gamma_max: float = GAMMA_MAX,
               suboptimality: float = SUBOPTIMALITY) -> HinfResult:
    """:func:`hinfsyn` on the vertices of a mixed-sensitivity design (:mod:`lpvflow.synth.plant`); the
    result's ``controller`` is the implementable :class:`LPVController` from e to the plant input,
    interpolated with the polytope's convex coordinates, W_B in series when the design has one."""
    result = synthesize_vertices(plant.vertices, plant.Ts, suboptimality, gamma_max, solver)
    K = result.K_vertices
    if plant.input_filter is not None:
        K = [series_input_filter(k, plant.input_filter) for k in K]
    info = {"method": "common", "gamma": result.gamma, "gamma_estimate": result.gamma_estimate,
            "solver": result.report.solver, "status": result.report.status,
            "solve_seconds": result.report.seconds, "polytope": plant.polytope.kind}
    stacks = [np.array([k[m] for k in K]) for m in range(4)]
    result.plant = plant
    result.controller = LPVController(*stacks, plant.polytope, plant.basis, plant.Ts, info=info,
                                      structure=plant.structure)
    return result
