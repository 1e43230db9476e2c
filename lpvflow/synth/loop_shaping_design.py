"""``[synth] method = "loop-shaping"``: H∞ loop-shaping designs (McFarlane & Glover 1990) by LMIs at the
vertices of the design's polytope, interpolated.

At every vertex i (a breakpoint of a piecewise polytope, else a box corner) with frozen model G_i:

* W1_i = W1/σ_max(G_i W1)(e^{jω_c Ts}), W1 the integrator-plus-lead weight of
  :func:`lpvflow.synth.loop_shaping.integrator_lead_weight` at the crossover ω_c = ``crossover``
  (:func:`lpvflow.synth.loop_shaping.crossover_normalized`), W2 = I;
* K∞_i by :func:`lpvflow.synth.hinf.hinfsyn` on the four-block normalized-coprime-factor plant of the shaped
  plant Gs_i = W2·G_i·W1_i (one LTI LMI design per vertex, :func:`lpvflow.synth.loop_shaping.loop_shaping`):
  ‖[I; K∞](I − Gs K∞)⁻¹[I  Gs]‖∞ ≤ γ_i, so b(Gs_i, K∞_i) ≥ 1/γ_i with γ_i → 1/b_opt(Gs_i);
* the feedback K_i = W1_i·K∞_i·W2 (u = K y, positive feedback as in
  :mod:`lpvflow.validate.robust_stability`).

The controller is Σλ_i(p)K_i with the plant's own convex coordinates. The vertex controllers are realized in
the coordinates each LMI solve chose, so between vertices the interpolation is not certified by the LMIs:
:func:`frozen_margin_check` evaluates the shaped loop b(G(p)·W1(p), K∞(p)) on a grid ten times finer than the
vertices and requires b ≥ 1/(1.1·γ_i) of the nearest vertex (b = 0 when the frozen loop is unstable); the
margin b(G(p), K(p)) of the unshaped loop is reported beside it. The mixed-sensitivity ``weights`` of the
table are not used (the generalized plant is still built from them). The reference enters as
e = r − y (u = −K e, the 1-DOF loop; a ``2dof`` controller reads [r; y] with the same loop).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.synth.certify import design_coordinates
from lpvflow.synth.controller import LPVController, mix
from lpvflow.synth.design import Design
from lpvflow.synth.loop_shaping import crossover_normalized, integrator_lead_weight, loop_shaping
from lpvflow.synth.plant import GeneralizedPlant
from lpvflow.synth.polytope import vertex_matrices
from lpvflow.validate.robust_stability import generalized_margin

#: Frozen-check grid: points per breakpoint interval (ten times finer than the breakpoints).
FROZEN_PER_SEGMENT = 11
#: The frozen check requires b(G(p), K(p)) ≥ 1/(MARGIN_FACTOR·γ_i) of the nearest vertex i.
MARGIN_FACTOR = 1.1
#: Default crossover as a fraction of the Nyquist frequency π/Ts.
DEFAULT_CROSSOVER_FRACTION = 0.05


@dataclass
class FrozenMarginCheck:
    """The interpolated design on a grid ten times finer than the vertices. The shaped loop at λ is
    Gs(λ) = G(λ)·W1(λ) with K∞(λ) (W1(λ) = Σλ_iW1_i: the W1_i share A, B and D = 0, so
    Σλ_i(W1_i·K∞_i) = W1(λ)·K∞(λ) exactly, and the shaped loop and the exported loop G(λ), K(λ) have the
    same closed-loop matrix). ``worst_ratio`` = min over the grid of b(Gs, K∞)·MARGIN_FACTOR·γ_nearest
    (≥ 1 passes; b = 0 when the frozen loop is unstable), ``worst_at`` its grid index, ``b_min`` the
    smallest b(Gs, K∞), ``b_plant_min`` the smallest b(G, K) of the unshaped loop (reported, not judged)."""

    b_min: float
    b_plant_min: float
    worst_ratio: float
    worst_at: int
    points: int
    gammas: list[float]

    @property
    def ok(self) -> bool:
        """Every frozen loop is stable with b(Gs, K∞) ≥ 1/(1.1·γ) of its nearest vertex."""
        return self.worst_ratio >= 1.0

    def lines(self) -> list[str]:
        return [f"loop-shaping vertex levels γ_i {min(self.gammas):.4g} … {max(self.gammas):.4g} "
                f"(b(Gs_i, K∞_i) ≥ 1/γ_i)",
                f"frozen shaped loops at {self.points} points (10× the vertices): smallest b(Gs, K∞) "
                f"{self.b_min:.4g}; worst b·{MARGIN_FACTOR}·γ_nearest {self.worst_ratio:.4g} at point "
                f"{self.worst_at} (must be ≥ 1; b = 0 is an unstable loop)",
                f"unshaped loops: smallest b(G, K) {self.b_plant_min:.4g} (K = W1·K∞)",
                "no LMI certificate between vertices or for a moving scheduling signal: the FMU runs are the "
                "witness"]


def _matrices(M: control.StateSpace) -> tuple[np.ndarray, ...]:
    return tuple(np.asarray(X, dtype=float) for X in (M.A, M.B, M.C, M.D))


def modal_form(K: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """K in real modal coordinates fixed up to nothing, so that controllers of nearby plants realized by
    different solves get nearby matrices: eigenvalues in ascending (real, imaginary) order, a real mode
    scaled so its row of B has the norm of its column of C and a positive first nonzero entry, a complex
    pair σ ± jω as the block [σ ω; −ω σ] rotated and scaled (which commutes with it) so its two rows of B
    start along [1, 0]ᵀ and have the norm of its two columns of C. Assumes distinct eigenvalues (a
    diagonalizable K). Interpolating these forms is still not the frozen design between vertices: the
    check measures what it loses."""
    A, B, C, D = K
    values, vectors = np.linalg.eig(A)
    order = np.lexsort((values.imag, values.real))
    columns, i = [], 0
    while i < len(order):
        lam, v = values[order[i]], vectors[:, order[i]]
        if abs(lam.imag) > 1e-12 * max(1.0, abs(lam)):
            columns += [v.real, v.imag]
            i += 2  # the conjugate follows in the sorted order
        else:
            columns.append(v.real)
            i += 1
    T = np.column_stack(columns)
    A, B, C = np.linalg.solve(T, A @ T), np.linalg.solve(T, B), C @ T
    S = np.eye(A.shape[0])
    i = 0
    while i < A.shape[0]:
        if i + 1 < A.shape[0] and abs(A[i, i + 1]) > 1e-12 * max(1.0, abs(A[i, i])):
            b = B[i:i + 2]
            first = b[:, int(np.argmax(np.linalg.norm(b, axis=0) > 1e-12))]
            angle = np.arctan2(first[1], first[0])
            R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
            S[i:i + 2, i:i + 2] = R * _balance(np.linalg.norm(b), np.linalg.norm(C[:, i:i + 2]))
            i += 2
        else:
            row = B[i]
            nonzero = row[np.abs(row) > 1e-12 * max(1.0, np.abs(row).max())]
            sign = np.sign(nonzero[0]) if nonzero.size else 1.0
            S[i, i] = _balance(np.linalg.norm(row), np.linalg.norm(C[:, i])) * sign
            i += 1
    return np.linalg.solve(S, A @ S), np.linalg.solve(S, B), C @ S, D


def _balance(b: float, c: float) -> float:
    """The scale s of a mode after which its B row(s) and C column(s) have equal norms, ‖b‖/s = s‖c‖."""
    return float(np.sqrt(b / c)) if b > 0 and c > 0 else 1.0


def frozen_margin_check(model_vertices: list[tuple[np.ndarray, ...]], weights: list[tuple[np.ndarray, ...]],
                        K_inf: list[tuple[np.ndarray, ...]], gammas: list[float], lams: list[np.ndarray],
                        Ts: float) -> FrozenMarginCheck:
    """:class:`FrozenMarginCheck` of K∞(λ) = Σλ_iK∞_i on Gs(λ) = G(λ)·W1(λ) and of K(λ) = W1(λ)·K∞(λ) on
    G(λ) (u = K y) at every λ of ``lams``; the nearest vertex is the one with the largest λ_i."""
    b, b_plant = [], []
    for lam in lams:
        G, W1, K = (control.ss(*mix(M, lam), Ts) for M in (model_vertices, weights, K_inf))
        b.append(generalized_margin(G * W1, K))
        b_plant.append(generalized_margin(G, W1 * K))
    ratio = np.array(b) * MARGIN_FACTOR * np.array([gammas[int(np.argmax(lam))] for lam in lams])
    worst = int(np.argmin(ratio))
    return FrozenMarginCheck(min(b), min(b_plant), float(ratio[worst]), worst, len(lams), list(gammas))


def controller_matrices(K: tuple[np.ndarray, ...], structure: str) -> tuple[np.ndarray, ...]:
    """The feedback u = K y as the controller of ``structure``: 1dof reads e = r − y, so u = −K e
    (B, D negated); 2dof reads [r; y], so u = K(y − r) (B = [−B_K  B_K], D = [−D_K  D_K])."""
    A, B, C, D = K
    if structure == "2dof":
        return A, np.hstack([-B, B]), C, np.hstack([-D, D])
    return A, -B, C, -D


def design(model: LPVSS, plant: GeneralizedPlant, settings: Mapping[str, Any],
           frozen_model: LPVSS | None) -> Design:
    """The loop-shaping controller of the module docstring at the vertices of ``plant``'s polytope;
    ``Design.gamma`` the largest vertex level γ_i (1/γ_i the guaranteed b of the shaped loop), no
    ``gamma_lower``. ``frozen_model`` is not used: the check runs on the model interpolated like the plant.

    Raises:
        ModelError: a crossover above the weight's usable band, or a model with feed-through.
        SynthesisError: from ``hinfsyn`` at a vertex.
    """
    start = time.perf_counter()
    Ts = model.Ts
    crossover = settings.get("crossover") or DEFAULT_CROSSOVER_FRACTION * np.pi / Ts
    model_vertices = vertex_matrices(model, plant.polytope)
    if any(np.max(np.abs(D), initial=0.0) > 0 for _, _, _, D in model_vertices):
        raise ModelError("loop-shaping needs a strictly proper model (D = 0): identify it with an input "
                         "delay nk >= 1")
    W1 = integrator_lead_weight(Ts, crossover, model.nu)
    W2 = control.ss([], [], [], np.eye(model.ny), Ts)
    solver = settings.get("solver", "CLARABEL")
    gammas, weights, K_inf, feedback = [], [], [], []
    for mats in model_vertices:
        G = control.ss(*mats, Ts)
        W1_i = crossover_normalized(G, W1, crossover)
        shaped = loop_shaping([G], [W1_i], W2, solver=solver)
        gammas.append(shaped.gamma)
        weights.append(_matrices(W1_i))
        K_inf.append(modal_form(_matrices(shaped.K_inf[0])))
        feedback.append(_matrices(W1_i * control.ss(*K_inf[-1], Ts)))
    lams = design_coordinates(plant.polytope, plant.basis, FROZEN_PER_SEGMENT)
    check = frozen_margin_check(model_vertices, weights, K_inf, gammas, lams, Ts)
    exported = [controller_matrices(K, plant.structure) for K in feedback]
    stacks = [np.array([k[m] for k in exported]) for m in range(4)]
    info = {"method": "loop-shaping", "gamma": max(gammas), "vertex_gammas": gammas,
            "crossover": float(crossover), "b_min": check.b_min,
            "b_plant_min": check.b_plant_min}
    if plant.polytope.breakpoints is not None:
        info["breakpoints"] = [float(b) for b in plant.polytope.breakpoints]
    controller = LPVController(*stacks, plant.polytope, plant.basis, Ts, info=info, structure=plant.structure)
    return Design(controller, max(gammas), None, check, plant, time.perf_counter() - start)
