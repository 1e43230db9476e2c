"""``[synth] scheduling = "common"`` of the loop-shaping method: one shaping weight and one Lyapunov matrix
over every breakpoint, so that the certificate holds while the scheduling signal moves, at any rate.

Between breakpoints the loop is the model G(λ) = Σλ_iG_i with the controller W1(λ)·K∞(λ). With a weight
W1_i per breakpoint (``scheduling = "frozen"``) the shaped plant's A holds B_G(λ)·C_W1(λ) (the model is in
observable form, so B_G varies; the normalization moves C_W1), quadratic in λ: the shaped plant between two
breakpoints is not in the convex hull of the shaped vertex plants, and a vertex certificate says nothing
about it (measured on the bundled ADIP and maglev designs: benchmarks/README.md). With **one** weight W1 for
every breakpoint, Gs(λ) = G(λ)·W1 = Σλ_i Gs_i exactly (:func:`lpvflow.synth.loop_shaping.shaped_plant`: the
coupling block B_G(λ)C_W1 is affine), the four-block NCF plants share B2, C2, D12, D21, and one closed-loop
Lyapunov matrix 𝒳 for all vertices (:func:`lpvflow.synth.hinf.hinfsyn` over the polytope) proves
‖T_zw‖ < γ for every trajectory of λ in the polytope (Apkarian, Gahinet & Becker 1995, "Self-scheduled H∞
control of linear parameter-varying systems: a design example", Automatica 31(9): the closed loop is affine
in λ when B2, C2, D12, D21 are constant and the controller is Σλ_iK_i, and the discrete bounded-real
inequality with a fixed 𝒳 is convex in the closed-loop matrices), so in particular b(Gs(λ), K∞(λ)) ≥ 1/γ at
every frozen λ.

The weight is the nominal integrator-plus-lead weight normalized at the centre breakpoint
(:func:`common_weight`); K∞_i the central LMI controllers at γ = gamma_factor·γ_LMI of the polytope
(:func:`lpvflow.synth.hinf.central_hinfsyn`), written in the shaped plant's coordinates
(:func:`lpvflow.synth.loop_shaping.in_plant_coordinates`: one basis change for all vertices, since they share
𝒳), and the certificate re-checked in those coordinates at every vertex (:func:`certificate_margins`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import control
import numpy as np
import scipy.linalg

from lpvflow.errors import SynthesisError
from lpvflow.synth.bilinear import certificate_margin
from lpvflow.synth.hinf import central_near_optimum
from lpvflow.synth.loop_shaping import in_plant_coordinates, ncf_generalized_plant
from lpvflow.synth.margin_goal import Shaping
from lpvflow.synth.plant import VertexPlant


@dataclass
class CommonLoopShaping:
    """K∞_i of the shaped vertex plants under one certificate (:func:`common_central_controllers`).

    Attributes:
        K_inf: (A, B, C, D) per vertex, u_s = K∞_i y_s, in the shaped plant's state coordinates.
        gamma: the certified level γ = gamma_factor·γ_LMI (b(Gs(λ), K∞(λ)) ≥ 1/γ for every λ).
        lmi_gamma: hinfsyn's certified optimum γ_LMI over the polytope.
        lyapunov_factor: F with 𝒳 = FᵀF, state [x_Gs; x_K] in the coordinates of ``K_inf``.
        margins: :func:`certificate_margins` of ``K_inf`` with ``lyapunov_factor`` (all > 0).
    """

    K_inf: list[tuple[np.ndarray, ...]]
    gamma: float
    lmi_gamma: float
    lyapunov_factor: np.ndarray
    margins: list[float]


def common_weight(models: Sequence[control.StateSpace], shaping: Shaping) -> control.StateSpace:
    """The nominal W1 (lead ratio :data:`lpvflow.synth.loop_shaping.LEAD_RATIO`) normalized so that
    W2·G_c·W1 crosses 1 at the crossover, G_c the centre one of ``models`` (index len // 2)."""
    return shaping.weight(models[len(models) // 2])


def certificate_margins(shaped: Sequence[control.StateSpace], K_inf: Sequence[tuple[np.ndarray, ...]],
                        lyapunov_factor: np.ndarray, gamma: float) -> list[float]:
    """The margin of the discrete bounded-real inequality with 𝒳 = FᵀF at level γ for the NCF plant of
    every shaped vertex plant Gs_i under K∞_i (:func:`lpvflow.synth.bilinear.certificate_margin`, rebuilt
    in numpy; > 0 at every vertex certifies every λ and every rate, module docstring)."""
    out = []
    for Gs, K in zip(shaped, K_inf, strict=True):
        P = ncf_generalized_plant(Gs)
        vertex = VertexPlant.from_ss(P, nw=P.ninputs - Gs.ninputs, nz=P.noutputs - Gs.noutputs)
        out.append(certificate_margin(vertex, K, lyapunov_factor, gamma))
    return out


def common_central_controllers(shaped: Sequence[control.StateSpace], gamma_factor: float,
                               solver: str = "CLARABEL") -> CommonLoopShaping:
    """:class:`CommonLoopShaping` of the shaped vertex plants (one W1, so they share B and C): γ_LMI from
    hinfsyn over their NCF plants, the central controllers at gamma_factor·γ_LMI, the basis change of
    :func:`lpvflow.synth.loop_shaping.in_plant_coordinates` (x_K = T x̃_K, T = −X₂₂⁻¹Nᵀ) applied to the
    controllers and to the certificate (F ↦ F·blkdiag(I, T)), and the certificate re-checked there.

    Raises:
        SynthesisError: from hinfsyn or the central solution (e.g. the vertex plants differ in B or C,
            category ``"assumption"``), or the certificate fails after the basis change (``"accuracy"``).
    """
    plants = [ncf_generalized_plant(Gs) for Gs in shaped]
    p, m = shaped[0].noutputs, shaped[0].ninputs
    result, lmi_gamma = central_near_optimum(plants, p, m, gamma_factor, solver=solver)
    F = result.lyapunov_factor
    lyapunov = F.T @ F
    n = lyapunov.shape[0] // 2
    T = -np.linalg.solve(lyapunov[n:, n:], lyapunov[:n, n:].T)
    K_inf = [in_plant_coordinates(K, lyapunov) for K in result.K_vertices]
    F = F @ scipy.linalg.block_diag(np.eye(n), T)
    margins = certificate_margins(shaped, K_inf, F, result.gamma)
    if min(margins) <= 0:
        raise SynthesisError(f"the common loop-shaping certificate at γ = {result.gamma:.6g} fails in the "
                             f"shaped plant's coordinates (margin {min(margins):.3g}): round-off; raise the "
                             "level", category="accuracy")
    return CommonLoopShaping(K_inf, float(result.gamma), lmi_gamma, F, margins)
