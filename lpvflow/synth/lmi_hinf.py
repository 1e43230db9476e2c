"""Polytopic dynamic output-feedback H∞ synthesis by LMIs, discrete time (issue 6, items 3b and 3c).

Plant at vertex i (:mod:`lpvflow.synth.plant`), with B2, C2, D12, D21 the same at every vertex and
D22 = 0 (Apkarian, Gahinet & Becker 1995, (A1)–(A2); checked by ``check_a3``):

    x⁺ = A_i x + B1_i w + B2 u,   z = C1_i x + D11_i w + D12 u,   y = C2 x + D21 w.

Controller of full order n with vertex matrices (Ak_i, Bk_i, Ck_i, Dk_i), interpolated with the plant's
convex coordinates λ(θ). The closed loop (𝒜, ℬ, 𝒞, 𝒟)(θ) is then affine in λ.

Extended bounded-real lemma (de Oliveira, Geromel & Bernussou 2002, IJC 75(9), Thm. 3; the form of
notes_002 §7, verified here by Schur complements): ‖T_zw‖_∞ < γ if there are 𝒫 ≻ 0 and 𝒢 with

    ⎡ 𝒫     𝒜𝒢          ℬ    0    ⎤
    ⎢ ⋆     𝒢 + 𝒢ᵀ − 𝒫   0    𝒢ᵀ𝒞ᵀ ⎥ ≻ 0.                                              (E)
    ⎢ ⋆     ⋆            I    𝒟ᵀ   ⎥
    ⎣ ⋆     ⋆            ⋆    γ²I  ⎦

(𝒢ᵀ𝒫⁻¹𝒢 ⪰ 𝒢 + 𝒢ᵀ − 𝒫, then a congruence with 𝒢⁻¹𝒫 gives the dual bounded-real LMI with V = ξᵀ𝒫⁻¹ξ.)
For a time-varying θ(k) the (1,1) block holds the Lyapunov matrix at the *next* sample and the (2,2)
block the current one: with 𝒫(θ) = Σ λ_i 𝒫_i and a common 𝒢, (E) is affine in λ(k) and in λ(k+1)
separately, so it holds for every trajectory if it holds at every vertex pair (i, j):

    (E_ij):  𝒫 → 𝒫_j in (1,1), 𝒫 → 𝒫_i in (2,2), (𝒜, ℬ, 𝒞, 𝒟) → vertex i

(Daafouz & Bernussou 2001 poly-quadratic stability; the LPV use of the dilation follows Ali & Werner 2011,
whose exact variant the thesis does not print — this is the arbitrary-rate version).

Change of variables (Scherer, Gahinet & Chilali 1997 / de Oliveira et al. 2002 Sec. 4): write
𝒢 = [X ⋆; U ⋆], 𝒢⁻¹ = [Ỹ ⋆; Ṽ ⋆], T = [I Ỹ; 0 Ṽ], Y = Ỹᵀ, S = YX + ṼᵀU. Then Tᵀ𝒢T = [X I; S Y],
P̄_i = Tᵀ𝒫_iT, and the congruence diag(T, T, I, I) of (E_ij) is the LMI in
(X, Y, S, P̄_i, Q_i, L_i, F_i, R_i, γ²):

    ⎡ P̄_j       Φ_i                          Ψ_i    0    ⎤
    ⎢ ⋆         [X+Xᵀ  I+Sᵀ; I+S  Y+Yᵀ] − P̄_i  0      Ω_iᵀ ⎥ ≻ 0,
    ⎢ ⋆         ⋆                            I      Δ_iᵀ ⎥
    ⎣ ⋆         ⋆                            ⋆      γ²I  ⎦

    Φ_i = [A_iX + B2L_i   A_i + B2R_iC2;  Q_i   YA_i + F_iC2],   Ψ_i = [B1_i + B2R_iD21; YB1_i + F_iD21],
    Ω_i = [C1_iX + D12L_i   C1_i + D12R_iC2],                     Δ_i = D11_i + D12R_iD21,

with R_i = Dk_i, L_i = Dk_iC2X + Ck_iU, F_i = YB2Dk_i + ṼᵀBk_i,
Q_i = Y(A_i + B2Dk_iC2)X + YB2Ck_iU + ṼᵀBk_iC2X + ṼᵀAk_iU — all affine in the vertex data, so
λ-interpolated variables give the λ-interpolated controller. Reconstruction (:func:`reconstruct`):
ṼᵀU = S − YX by a balanced SVD, then Dk = R, Ck = (L − RC2X)U⁻¹, Bk = Ṽ⁻ᵀ(F − YB2R),
Ak = Ṽ⁻ᵀ(Q − YAX − YB2L − FC2X + YB2RC2X)U⁻¹. S − YX is non-singular because the (2,2) block forces
[X I; S Y] to have a positive definite symmetric part.

Method ``"common"`` (item 3b, Gahinet & Apkarian 1994 / Apkarian et al. 1995 in discrete time) is the
special case 𝒢 = 𝒫_i = 𝒫: X, Y symmetric, S = I, P̄ = [X I; I Y], one LMI per vertex. Every feasible
point of ``"common"`` is feasible for ``"dilated"`` (item 3c), so γ_dilated ≤ γ_common.
γ² is the SDP objective; strictness is imposed as ⪰ margin·I.
"""

from __future__ import annotations

from dataclasses import dataclass

import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError
from lpvflow.synth.controller import LPVController, series_input_filter
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant
from lpvflow.synth.sdp import SolveReport, SynthesisError, psd, solve

METHODS = ("common", "dilated")


@dataclass
class HinfResult:
    """A synthesized controller with its γ and the certificate in closed-loop coordinates.

    Attributes:
        K_vertices: (Ak_i, Bk_i, Ck_i, Dk_i) from e to u (before the input filter W_B).
        P: closed-loop Lyapunov matrices 𝒫_i (one, repeated, for ``"common"``); G: slack 𝒢.
        controller: the implementable controller (W_B in series when the design has one).
    """

    method: str
    gamma: float
    K_vertices: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    P: list[np.ndarray]
    G: np.ndarray
    report: SolveReport
    plant: GeneralizedPlant
    controller: LPVController | None = None


def _state_scaling(vertices: list[VertexPlant]) -> np.ndarray:
    """Diagonal s with diag(s)⁻¹ A diag(s) balanced (Parlett–Reinsch) for the mean |A_i|."""
    mean_abs = np.mean([np.abs(v.A) for v in vertices], axis=0)
    _, (s, _) = scipy.linalg.matrix_balance(mean_abs, permute=False, separate=True)
    return s


def _scaled(v: VertexPlant, s: np.ndarray) -> VertexPlant:
    return VertexPlant(v.A * s[None, :] / s[:, None], v.B1 / s[:, None], v.B2 / s[:, None],
                       v.C1 * s[None, :], v.C2 * s[None, :], v.D11, v.D12, v.D21, v.D22)


def _vertex_blocks(v, X, Y, Qi, Li, Fi, Ri):
    """Φ_i, Ψ_i, Ω_i, Δ_i of the transformed LMI (module docstring)."""
    Phi = cp.bmat([[v.A @ X + v.B2 @ Li, v.A + v.B2 @ Ri @ v.C2],
                   [Qi, Y @ v.A + Fi @ v.C2]])
    Psi = cp.vstack([v.B1 + v.B2 @ Ri @ v.D21, Y @ v.B1 + Fi @ v.D21])
    Omega = cp.hstack([v.C1 @ X + v.D12 @ Li, v.C1 + v.D12 @ Ri @ v.C2])
    Delta = v.D11 + v.D12 @ Ri @ v.D21
    return Phi, Psi, Omega, Delta


def _lmi(Pnext, Phi, Pcur_block, Psi, Omega, Delta, g, nw, nz):
    n2 = Phi.shape[0]
    return cp.bmat([
        [Pnext, Phi, Psi, np.zeros((n2, nz))],
        [Phi.T, Pcur_block, np.zeros((n2, nw)), Omega.T],
        [Psi.T, np.zeros((nw, n2)), np.eye(nw), Delta.T],
        [np.zeros((nz, n2)), Omega, Delta, g * np.eye(nz)],
    ])


def reconstruct(v: VertexPlant, X, Y, S, Q, L, F, R, U, Vt) -> tuple[np.ndarray, ...]:
    """Vertex controller (Ak, Bk, Ck, Dk) from the LMI variables (module docstring formulas)."""
    Dk = R
    Ck = np.linalg.solve(U.T, (L - R @ v.C2 @ X).T).T
    Bk = np.linalg.solve(Vt, F - Y @ v.B2 @ R)
    core = Q - Y @ v.A @ X - Y @ v.B2 @ L - F @ v.C2 @ X + Y @ v.B2 @ R @ v.C2 @ X
    Ak = np.linalg.solve(U.T, np.linalg.solve(Vt, core).T).T
    return Ak, Bk, Ck, Dk


def synthesize(
    plant: GeneralizedPlant, method: str = "dilated", solver: str = "CLARABEL", margin: float = 1e-7,
    gamma_max: float | None = None,
) -> HinfResult:
    """Minimise γ² subject to the vertex LMIs of ``method`` (``"common"`` or ``"dilated"``).

    Args:
        margin: strictness, every LMI ⪰ margin·I (the plant is state-balanced first).
        gamma_max: demand γ ≤ gamma_max (a design spec ‖·‖∞ ≤ 1 is gamma_max = 1); infeasible then means
            the weights ask for more than the plant allows.

    Raises:
        SynthesisError: infeasible LMIs (with the reason) or an inaccurate solve.
    """
    if method not in METHODS:
        raise ModelError(f"unknown output-feedback method {method!r}; use one of {', '.join(METHODS)}")
    s = _state_scaling(plant.vertices)
    verts = [_scaled(v, s) for v in plant.vertices]
    n, nw, nu, nz, ny = verts[0].dims
    N = len(verts)
    dilated = method == "dilated"
    X = cp.Variable((n, n), symmetric=not dilated)
    Y = cp.Variable((n, n), symmetric=not dilated)
    S = cp.Variable((n, n)) if dilated else np.eye(n)
    Q = [cp.Variable((n, n)) for _ in range(N)]
    L = [cp.Variable((nu, n)) for _ in range(N)]
    F = [cp.Variable((n, ny)) for _ in range(N)]
    R = [cp.Variable((nu, ny)) for _ in range(N)]
    g = cp.Variable(nonneg=True)
    I = np.eye(n)
    if dilated:
        Pbar = [cp.Variable((2 * n, 2 * n), symmetric=True) for _ in range(N)]
        Gsym = cp.bmat([[X + X.T, I + S.T], [I + S, Y + Y.T]])
    else:
        Pbar = [cp.bmat([[X, I], [I, Y]])] * N
    constraints = []
    for i, v in enumerate(verts):
        Phi, Psi, Omega, Delta = _vertex_blocks(v, X, Y, Q[i], L[i], F[i], R[i])
        for j in range(N) if dilated else (i,):
            cur = Gsym - Pbar[i] if dilated else Pbar[i]
            constraints.append(psd(_lmi(Pbar[j], Phi, cur, Psi, Omega, Delta, g, nw, nz), margin))
    if gamma_max is not None:
        constraints.append(g <= gamma_max**2)
    problem = cp.Problem(cp.Minimize(g), constraints)
    what = f"{method} output-feedback H∞ LMIs at {N} vertices" + (
        f" with γ ≤ {gamma_max:g}" if gamma_max is not None else "")
    try:
        report = solve(problem, solver, what)
    except SynthesisError as exc:
        raise SynthesisError(f"{exc}: {_infeasibility_hint(plant, gamma_max)}") from None

    Xv, Yv = np.asarray(X.value), np.asarray(Y.value)
    Sv = np.asarray(S.value) if dilated else I
    W, sig, Zt = np.linalg.svd(Sv - Yv @ Xv)
    Vt, U = W * np.sqrt(sig), np.sqrt(sig)[:, None] * Zt
    if sig[-1] <= 1e-12 * sig[0]:
        raise SynthesisError(f"controller reconstruction is ill-conditioned (S − YX has condition "
                             f"{sig[0] / max(sig[-1], 1e-300):.2g}); increase the margin")
    K_scaled = [reconstruct(v, Xv, Yv, Sv, Q[i].value, L[i].value, F[i].value, R[i].value, U, Vt)
                for i, v in enumerate(verts)]
    T = np.block([[I, Yv.T], [np.zeros((n, n)), Vt.T]])
    Tinv = np.linalg.inv(T)
    Tscale = np.diag(np.concatenate([s, np.ones(n)]))  # ξ = Tscale ξ_balanced
    back = Tscale @ Tinv.T
    Gbar = np.block([[Xv, I], [Sv, Yv]])
    G = back @ Gbar @ back.T
    P = [back @ np.asarray(Pb.value) @ back.T for Pb in Pbar]
    gamma = float(np.sqrt(g.value))
    # plant-state scaling does not change the controller: its input/output are e and u
    result = HinfResult(method, gamma, K_scaled, P, G, report, plant)
    result.controller = implementable_controller(result)
    return result


def implementable_controller(result: HinfResult) -> LPVController:
    """The LPVController from e to the plant input: vertex K, with W_B in series when designed with one."""
    plant = result.plant
    K = result.K_vertices
    if plant.input_filter is not None:
        K = [series_input_filter(k, plant.input_filter) for k in K]
    stacks = [np.array([k[m] for k in K]) for m in range(4)]
    info = {"method": result.method, "gamma": result.gamma, "solver": result.report.solver,
            "solve_seconds": result.report.seconds, "polytope": plant.polytope.kind}
    return LPVController(*stacks, plant.polytope, plant.basis, plant.Ts, info=info)


def _infeasibility_hint(plant: GeneralizedPlant, gamma_max: float | None) -> str:
    """Why the LMIs may be infeasible, in terms of the plant."""
    n_g = plant.n_plant_states
    radius = max(np.max(np.abs(np.linalg.eigvals(v.A[:n_g, :n_g]))) for v in plant.vertices)
    unstable = f"the plant has vertex poles up to |z| = {radius:.4g}" + (" (unstable)" if radius >= 1 else "")
    if gamma_max is not None:
        return (f"no controller reaches γ ≤ {gamma_max:g}; {unstable}: lower the W_S bandwidth/gain or the "
                "W_K penalty, or drop gamma_max")
    return f"no common controller stabilizes all vertices; {unstable}: shrink the scheduling box"
