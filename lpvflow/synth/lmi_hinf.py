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
The code holds γ (not γ²) in the w and z blocks (:func:`_result`); γ is the SDP objective; strictness
is imposed as ⪰ margin·I.

Controller elimination for ``"common"`` (issue 6: the full LMIs cost 105 s on the issue's n = 12 plant).
With Θ_i = [L_i R_i; Q_i F_i] the vertex LMI is M_i(Θ_i) = M_i(0) + 𝒰Θ_i𝒱 + (𝒰Θ_i𝒱)ᵀ, where 𝒰 has
[B2 0; 0 I] in the first 2n rows and [D12 0] in the z rows, and 𝒱 has [I 0; 0 C2] in the second 2n
columns and [0; D21] in the w columns — constant because B2, C2, D12, D21 are (A3). By the projection
lemma (Gahinet & Apkarian 1994, IJRNC 4, Lemma 3.1) a Θ_i exists iff W_𝒰ᵀM_i(0)W_𝒰 ≻ 0 and
W_𝒱ᵀM_i(0)W_𝒱 ≻ 0 (W bases of ker 𝒰ᵀ, ker 𝒱). Written out,

    W_𝒰ᵀM_i(0)W_𝒰 = ⎡ N_Xᵀdiag(X, γI)N_X   N_Xᵀ[A_i; C1_i][X I]   N_Xᵀ[B1_i; D11_i] ⎤
                    ⎢ ⋆                    P̄                      0                 ⎥,
                    ⎣ ⋆                    0                      γI                ⎦

    W_𝒱ᵀM_i(0)W_𝒱 = ⎡ P̄   [I; Y][A_i B1_i]N_Y       0                    ⎤
                    ⎢ ⋆   N_Yᵀdiag(Y, γI)N_Y        N_Yᵀ[C1_iᵀ; D11_iᵀ]  ⎥,
                    ⎣ ⋆   ⋆                          γI                   ⎦

and since [X I] = [I 0]P̄ and [I; Y] = P̄[0; I], their Schur complements on P̄ ≻ 0 are those of the
following LMIs on diag(X, γI) and on Y: per vertex, the two LMIs of the discrete-time theorem of Gahinet
& Apkarian (1994, Thm. 5.3; polytopic use: Apkarian, Gahinet & Becker 1995) in X, Y only,

    (X_i)  ⎡ N_Xᵀ diag(X, γI_nz) N_X    N_Xᵀ [A_iX  B1_i; C1_iX  D11_i] ⎤ ≻ 0,   N_X basis of ker [B2ᵀ D12ᵀ],
           ⎣ ⋆                           diag(X, γI_nw)                  ⎦

           ⎡ Y   [Y A_i  Y B1_i] N_Y          0                     ⎤
    (Y_i)  ⎢ ⋆   N_Yᵀ diag(Y, γI_nw) N_Y      N_Yᵀ [C1_iᵀ; D11_iᵀ]  ⎥ ≻ 0,        N_Y basis of ker [C2 D21],
           ⎣ ⋆   ⋆                             γI_nz                 ⎦

    (C)    P̄ = [X I; I Y] ≻ 0   (once),

of (n + nz − nu) + (n + nw) and n + (n + nw − ny) + nz rows instead of 4n + nw + nz (28, 28 instead of
54 for the issue's plant, and 2·n(n+1)/2 variables instead of N·(n + nu)(n + ny) more). γ-minimisation,
margin maximisation and bisection (:func:`synthesize`) run on these; the margin t is that of (X_i),
(Y_i), (C) ⪰ t·I. The controller variables are then recovered vertex by vertex at the returned X, Y, γ
(:func:`_controller_variables`) with the explicit solution of Iwasaki & Skelton (1994, Automatica 30(8),
Thm. 2): after a Jacobi scaling of M_i(0), 𝒰, 𝒱, any ρ with Φ = (M_i(0) + ρ𝒰𝒰ᵀ)⁻¹ ≻ 0 gives
Θ_i = ρ𝒰ᵀΦ𝒱ᵀ(𝒱Φ𝒱ᵀ)⁻¹ with M_i(Θ_i) ≻ 0 (such ρ > ρ_min exist iff W_𝒰ᵀM_i(0)W_𝒰 ≻ 0); ρ is taken from a
logarithmic grid above ρ_min as the one with the largest Jacobi-scaled smallest eigenvalue. Strict
feasibility of (X_i), (Y_i), (C) therefore gives a reconstructed controller that passes the independent
re-check, up to round-off. Where round-off wins — weights with poles near z = 1 make X and Y reach
1e4–1e5 while the margin is 1e-5, and S − YX = I − YX then has condition > 1e12, e.g. the bundled
ADIP design and its LTI baseline, where the full LMIs also pass the re-check with a max eigenvalue of
only −7e-11 and −5e-13 — and where the eliminated margin problem loses its sign at a larger γ than the
full one (it needed the bisection: maglev_like stopped at 2.26 against the full LMIs' 1.70),
``"common"`` also solves the full change-of-variables LMIs above and returns the lower certified γ
(:func:`_synthesize_common`, said in the report's status). The full LMIs remain what ``"dilated"`` solves.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError
from lpvflow.synth.controller import LPVController, series_input_filter
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant
from lpvflow.synth.sdp import COARSE, SolveReport, SynthesisError, psd, solve

METHODS = ("common", "dilated")
LYAPUNOV_BOUND = 1e6  # default β: P̄_i, sym 𝒢 ⪯ β·I in the scaled coordinates (synthesize, steps 1 and 2)


@dataclass
class HinfResult:
    """A synthesized controller with its γ and the certificate in closed-loop coordinates.

    Attributes:
        K_vertices: (Ak_i, Bk_i, Ck_i, Dk_i) from e to u (before the input filter W_B).
        gamma: the γ the returned controller is certified for; gamma_opt: the minimum found by the SDP.
        P: closed-loop Lyapunov matrices 𝒫_i (one, repeated, for ``"common"``); G: slack 𝒢.
        controller: the implementable controller (W_B in series when the design has one).
        bisected: γ_opt came from the bisection fallback, not from the γ minimisation.
        gamma_min_exact: the γ minimisation ended ``optimal`` (not inaccurate, not failed).
    """

    method: str
    gamma: float
    K_vertices: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    P: list[np.ndarray]
    G: np.ndarray
    report: SolveReport
    plant: GeneralizedPlant
    gamma_opt: float = float("nan")
    lmi_max_eig: float = float("nan")
    controller: LPVController | None = None
    bisected: bool = False
    gamma_min_exact: bool = True


def _scalings(vertices: list[VertexPlant]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Diagonal state, control and measurement scalings (s, d_u, d_y) of the generalized plant.

    s balances the mean |A_i| (Parlett–Reinsch), clipped to [1e-6, 1e6]; then d_u makes every column
    of [S⁻¹B2; D12 d_u] and d_y every row of d_y⁻¹[C2 S, D21] have unit largest entry. The exogenous w
    and performance z are not scaled per channel: that would change ‖T_zw‖∞ (a common scalar
    would only rescale γ).
    """
    mean_abs = np.mean([np.abs(v.A) for v in vertices], axis=0)
    _, (s, _) = scipy.linalg.matrix_balance(mean_abs, permute=False, separate=True)
    s = np.clip(s, 1e-6, 1e6)
    v = vertices[0]
    du = 1.0 / np.maximum(np.max(np.abs(np.vstack([v.B2 / s[:, None], v.D12])), axis=0), 1e-12)
    dy = np.maximum(np.max(np.abs(np.hstack([v.C2 * s[None, :], v.D21])), axis=1), 1e-12)
    return s, du, dy


#: γ tried, in turn, by :func:`_balancing_transform` when no earlier γ is known (the separate (X_i), (Y_i)
#: LMIs only get easier as γ grows). Starting at 1e2, not 1e1: on the ADIP ±60° box (bench_adip_reach,
#: W_S arm hf_gain 0.5) X, Y at γ = 1e2 balance to a certified γ of 108, those at γ = 1e1 to 1277.
_BALANCING_GAMMAS = (1e2, 1e3, 1e4, 1e1)


def _balancing_transform(plant: GeneralizedPlant, gammas: tuple[float, ...],
                         bound: float = LYAPUNOV_BOUND) -> np.ndarray | None:
    """A full state transform x = T x̄ that balances X and Y of the eliminated LMIs; None if none found.

    On the :func:`_scalings` coordinates, the (X_i) and (Y_i) LMIs are solved *separately* (no coupling
    (C), so they stay solvable where the coupled problem is reported infeasible by round-off), each
    ⪰ t·I with t·I ⪯ X, Y ⪯ β·I (β = ``bound``, as in :func:`synthesize`), t ≤ 1 maximised, at the first γ
    of ``gammas`` with t > 0. Then with X = L Lᵀ
    and LᵀYL = V Σ² Vᵀ, T = S L V Σ^(−1/2) (S the diagonal scaling) makes T⁻¹XT⁻ᵀ = TᵀYT = Σ
    (Moore's balancing applied to the Lyapunov matrices instead of Gramians).

    Why it is exact: a state transform of the generalized plant (A → T⁻¹AT, B → T⁻¹B, C → CT) leaves
    every controller's closed-loop transfer from w to z unchanged (controllers map y to u, which are not
    transformed); a certificate (𝒫, 𝒢) found in x̄ is one in x after the congruence D = diag(T, I):
    𝒫 = D𝒫̄Dᵀ, 𝒢 = D𝒢̄Dᵀ (:func:`_untransformed`), and the re-check runs in x. What changes is only the
    conditioning: with ADIP-like weights (plant poles at |z| ≈ 1.04, a W_S pole at 1 − 1e-4) X and Y of
    the :func:`_scalings` coordinates have eigenvalues spread over 1e-7…1 and [X I; I Y] ≻ 0 is nearly
    singular in directions where X is small and Y is not.
    """
    s, du, dy = _scalings(plant.vertices)
    verts = [_scaled(v, s, du, dy) for v in plant.vertices]
    n = verts[0].dims[0]
    I = np.eye(n)
    for gamma in gammas:
        lmis = _eliminated_lmis(verts, gamma)
        t = cp.Variable()
        constraints = [psd(M, t) for M in lmis.matrices[1:]]  # (X_i), (Y_i) without (C)
        constraints += [psd(lmis.X, t), psd(lmis.Y, t), lmis.X << bound * I, lmis.Y << bound * I, t <= 1]
        try:
            solve(cp.Problem(cp.Maximize(t), constraints), "CLARABEL", "the separate (X_i), (Y_i) LMIs")
        except SynthesisError:
            continue
        if t.value is None or not t.value > 0:
            continue
        X, Y = (0.5 * (M.value + M.value.T) for M in (lmis.X, lmis.Y))
        try:
            Lx = np.linalg.cholesky(X)
        except np.linalg.LinAlgError:
            continue
        w, V = np.linalg.eigh(Lx.T @ Y @ Lx)
        if not w[0] > 0:
            continue
        return s[:, None] * (Lx @ V / w[None, :] ** 0.25)
    return None


def _transformed(plant: GeneralizedPlant, T: np.ndarray) -> GeneralizedPlant:
    """The generalized plant in x̄ = T⁻¹x (every vertex; controllers from y to u are unaffected)."""
    Ti = np.linalg.inv(T)
    return replace(plant, vertices=[VertexPlant(Ti @ v.A @ T, Ti @ v.B1, Ti @ v.B2, v.C1 @ T, v.C2 @ T, v.D11,
                                                v.D12, v.D21, v.D22) for v in plant.vertices])


def _untransformed(result: HinfResult, plant: GeneralizedPlant, T: np.ndarray) -> HinfResult:
    """A result on :func:`_transformed` ``(plant, T)`` as one on ``plant``, re-checked there (its
    controller is built by :func:`synthesize`, once the status is final)."""
    from lpvflow.synth.certify import vertex_lmi_max_eig

    nk = result.P[0].shape[0] - T.shape[0]
    D = scipy.linalg.block_diag(T, np.eye(nk))
    out = replace(result, plant=plant, P=[D @ P @ D.T for P in result.P], G=D @ result.G @ D.T)
    out.lmi_max_eig = vertex_lmi_max_eig(out)
    return out


def _scaled(v: VertexPlant, s: np.ndarray, du: np.ndarray, dy: np.ndarray) -> VertexPlant:
    """The plant in x̃ = S⁻¹x, ũ = D_u⁻¹u, ỹ = D_y⁻¹y (S = diag s, D_u = diag du, D_y = diag dy)."""
    return VertexPlant(v.A * s[None, :] / s[:, None], v.B1 / s[:, None], v.B2 / s[:, None] * du[None, :],
                       v.C1 * s[None, :], v.C2 * s[None, :] / dy[:, None], v.D11, v.D12 * du[None, :],
                       v.D21 / dy[:, None], v.D22 * du[None, :] / dy[:, None])


def _unscaled_controller(K: tuple[np.ndarray, ...], du: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, ...]:
    """K from y to u given K̃ from ỹ to ũ: Bk = B̃k D_y⁻¹, Ck = D_u C̃k, Dk = D_u D̃k D_y⁻¹ (exact)."""
    Ak, Bk, Ck, Dk = K
    return Ak, Bk / dy[None, :], du[:, None] * Ck, du[:, None] * Dk / dy[None, :]


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
        [Psi.T, np.zeros((nw, n2)), g * np.eye(nw), Delta.T],
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


@dataclass
class _Lmis:
    """cvxpy variables and vertex LMIs of one method (module docstring), before a margin is chosen."""

    X: cp.Variable
    Y: cp.Variable
    S: cp.Variable | np.ndarray
    Q: list[cp.Variable]
    L: list[cp.Variable]
    F: list[cp.Variable]
    R: list[cp.Variable]
    Pbar: list
    matrices: list
    bounds: list[cp.Expression]


def _lmis(verts: list[VertexPlant], method: str, g: cp.Expression) -> _Lmis:
    """The vertex LMI matrices (E_ij) with γ = g, and the blocks bounded by β (P̄_i, 𝒢 sym)."""
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
    I = np.eye(n)
    if dilated:
        Pbar = [cp.Variable((2 * n, 2 * n), symmetric=True) for _ in range(N)]
        Gsym = cp.bmat([[X + X.T, I + S.T], [I + S, Y + Y.T]])
        bounds = [*Pbar, 0.5 * Gsym]
    else:
        Pbar = [cp.bmat([[X, I], [I, Y]])] * N
        bounds = [Pbar[0]]
    matrices = []
    for i, v in enumerate(verts):
        Phi, Psi, Omega, Delta = _vertex_blocks(v, X, Y, Q[i], L[i], F[i], R[i])
        for j in range(N) if dilated else (i,):
            cur = Gsym - Pbar[i] if dilated else Pbar[i]
            matrices.append(_lmi(Pbar[j], Phi, cur, Psi, Omega, Delta, g, nw, nz))
    return _Lmis(X, Y, S, Q, L, F, R, Pbar, matrices, bounds)


def _bounded(lmis: _Lmis, bound: float) -> list[cp.Constraint]:
    n2 = lmis.bounds[0].shape[0]
    return [0.5 * (B + B.T) << bound * np.eye(n2) for B in lmis.bounds]


def _values(lmis: _Lmis) -> dict:
    """The numbers of a solved LMI set (copied: the variables are overwritten by the next solve).

    The eliminated ``"common"`` LMIs have no Q_i, L_i, F_i, R_i: :func:`_result` adds them
    (:func:`_controller_variables`).
    """
    val = {k: np.array(getattr(lmis, k).value, dtype=float) for k in ("X", "Y")}
    val["S"] = np.array(lmis.S.value, dtype=float) if isinstance(lmis.S, cp.Variable) else lmis.S
    if lmis.Q:
        for k in ("Q", "L", "F", "R"):
            val[k] = [np.array(v.value, dtype=float) for v in getattr(lmis, k)]
    val["Pbar"] = [np.array(P.value, dtype=float) for P in lmis.Pbar]
    return val


def _diag(P: cp.Expression, g: cp.Expression, m: int) -> cp.Expression:
    """diag(P, g·I_m)."""
    n = P.shape[0]
    return cp.bmat([[P, np.zeros((n, m))], [np.zeros((m, n)), g * np.eye(m)]])


def _eliminated_lmis(verts: list[VertexPlant], g: cp.Expression) -> _Lmis:
    """The controller-free ``"common"`` LMIs (X_i), (Y_i), (C) of the module docstring with γ = g."""
    n, nw, _, nz, _ = verts[0].dims
    X = cp.Variable((n, n), symmetric=True)
    Y = cp.Variable((n, n), symmetric=True)
    I = np.eye(n)
    NX = scipy.linalg.null_space(np.hstack([verts[0].B2.T, verts[0].D12.T]))  # orthonormal, (A3): one for all
    NY = scipy.linalg.null_space(np.hstack([verts[0].C2, verts[0].D21]))
    Pbar = cp.bmat([[X, I], [I, Y]])
    matrices = [Pbar]
    for v in verts:
        out = NX.T @ cp.bmat([[v.A @ X, v.B1], [v.C1 @ X, v.D11]])
        matrices.append(cp.bmat([[NX.T @ _diag(X, g, nz) @ NX, out], [out.T, _diag(X, g, nw)]]))
        inp = cp.hstack([Y @ v.A, Y @ v.B1]) @ NY
        right = NY.T @ np.vstack([v.C1.T, v.D11.T])
        matrices.append(cp.bmat([[Y, inp, np.zeros((n, nz))],
                                 [inp.T, NY.T @ _diag(Y, g, nw) @ NY, right],
                                 [np.zeros((nz, n)), right.T, g * np.eye(nz)]]))
    return _Lmis(X, Y, I, [], [], [], [], [Pbar] * len(verts), matrices, [Pbar])


def _lmi_set(verts: list[VertexPlant], method: str, g: cp.Expression, eliminate: bool) -> _Lmis:
    """The LMIs of the SDPs: (X_i), (Y_i), (C) if ``eliminate`` (``"common"`` only), else (E_ij)."""
    return _eliminated_lmis(verts, g) if eliminate else _lmis(verts, method, g)


def _theta_factors(v: VertexPlant) -> tuple[np.ndarray, np.ndarray]:
    """𝒰, 𝒱 with M_i(Θ) = M_i(0) + 𝒰Θ𝒱 + (𝒰Θ𝒱)ᵀ, Θ = [L R; Q F] (module docstring)."""
    n, nw, nu, nz, ny = v.dims
    U = np.zeros((4 * n + nw + nz, nu + n))
    U[:n, :nu], U[n:2 * n, nu:], U[4 * n + nw:, :nu] = v.B2, np.eye(n), v.D12
    V = np.zeros((n + ny, 4 * n + nw + nz))
    V[:n, 2 * n:3 * n], V[n:, 3 * n:4 * n], V[n:, 4 * n:4 * n + nw] = np.eye(n), v.C2, v.D21
    return U, V


def _vertex_lmi_at_zero(v: VertexPlant, X: np.ndarray, Y: np.ndarray, gamma: float) -> np.ndarray:
    """M_i(0): the ``"common"`` vertex LMI (:func:`_lmi` of :func:`_vertex_blocks`) with
    Q_i = L_i = F_i = R_i = 0 (module docstring), as numbers."""
    n, nw, nu, nz, ny = v.dims
    Pbar = np.block([[X, np.eye(n)], [np.eye(n), Y]])
    Phi, Psi, Omega, Delta = _vertex_blocks(v, X, Y, np.zeros((n, n)), np.zeros((nu, n)),
                                            np.zeros((n, ny)), np.zeros((nu, ny)))
    M = np.asarray(_lmi(Pbar, Phi, Pbar, Psi, Omega, Delta, gamma, nw, nz).value, dtype=float)
    return 0.5 * (M + M.T)


#: ρ − ρ_min, in units of max(ρ_min, 1), tried by the Iwasaki–Skelton reconstruction (module docstring).
_RHO_GRID = np.logspace(-6, 6, 37)


def _controller_variables(verts: list[VertexPlant], val: dict, gamma: float) -> dict:
    """Q_i, L_i, F_i, R_i with M_i(Θ_i) ≻ 0 at the solved X, Y and γ (Iwasaki & Skelton; module docstring).

    Raises:
        SynthesisError: no ρ makes M_i(0) + ρ𝒰𝒰ᵀ positive definite (W_𝒰ᵀM_i(0)W_𝒰 is not).
    """
    n, _, nu, _, _ = verts[0].dims
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("Q", "L", "F", "R")}
    for v in verts:
        M = _vertex_lmi_at_zero(v, val["X"], val["Y"], gamma)
        U, V = _theta_factors(v)
        d = 1.0 / np.sqrt(np.clip(np.abs(np.diag(M)), 1e-300, None))  # Jacobi congruence D M D
        M, U, V = M * d[:, None] * d[None, :], d[:, None] * U, V * d[None, :]
        QU, RU = np.linalg.qr(U)
        WU = scipy.linalg.null_space(U.T)
        schur = QU.T @ M @ QU - QU.T @ M @ WU @ np.linalg.solve(WU.T @ M @ WU, WU.T @ M @ QU)
        RUi = np.linalg.inv(RU)
        rho_min = max(float(np.linalg.eigvalsh(-RUi.T @ schur @ RUi)[-1]), 0.0)  # M + ρUUᵀ ≻ 0 ⟺ ρ > ρ_min
        best, best_eig = None, -np.inf
        for rho in rho_min + max(rho_min, 1.0) * _RHO_GRID:
            try:
                Li = np.linalg.inv(np.linalg.cholesky(M + rho * U @ U.T))
            except np.linalg.LinAlgError:
                continue
            Phi = Li.T @ Li
            Theta = rho * U.T @ Phi @ V.T @ np.linalg.inv(V @ Phi @ V.T)
            T = U @ Theta @ V
            eig = float(np.linalg.eigvalsh(M + T + T.T)[0])
            if eig > best_eig:
                best, best_eig = Theta, eig
        if best is None:
            raise SynthesisError("controller reconstruction failed: no ρ makes M_i(0) + ρ𝒰𝒰ᵀ positive "
                                 "definite (the eliminated LMIs hold too loosely); increase suboptimality")
        out["L"].append(best[:nu, :n])
        out["R"].append(best[:nu, n:])
        out["Q"].append(best[nu:, :n])
        out["F"].append(best[nu:, n:])
    return out


class _MarginProblem:
    """max t s.t. every vertex LMI ⪰ t·I at a fixed γ (a cvxpy Parameter: compiled once)."""

    def __init__(self, verts: list[VertexPlant], method: str, solver: str, what: str,
                 eliminate: bool, bound: float) -> None:
        self.gamma = cp.Parameter(pos=True)
        self.t = cp.Variable()
        self.lmis = _lmi_set(verts, method, self.gamma, eliminate)
        constraints = [psd(M, self.t) for M in self.lmis.matrices] + _bounded(self.lmis, bound)
        self.problem = cp.Problem(cp.Maximize(self.t), constraints)
        self.solver, self.what = solver, what
        self.tolerance = COARSE if eliminate else None
        self.reports: list[SolveReport] = []

    def margin(self, gamma: float) -> tuple[float, dict | None]:
        """(t, numbers) at γ; t = −inf when no solver returned a point."""
        self.gamma.value = gamma
        try:
            self.reports.append(solve(self.problem, self.solver, f"{self.what} at γ = {gamma:.6g}",
                                      self.tolerance))
        except SynthesisError:
            return -np.inf, None
        return float(self.t.value), _values(self.lmis)


#: Relative γ increases tried, in turn, when the returned point fails the independent re-check by
#: round-off (max eigenvalue ~1e-12 ≥ 0): the margin problem at a larger γ has a strictly feasible point
#: further inside. The certified γ is the one reported.
BACK_OFF = (1.02, 1.1)


def _bisect(
    mp: _MarginProblem, start: float, rel_tol: float, gamma_max: float | None,
) -> tuple[float, float, dict]:
    """Smallest γ with a positive margin, by geometric bisection: (lower estimate, γ, numbers at γ)."""
    lo, hi, best = None, start, None
    for _ in range(6):  # up to 4⁶ ≈ 4000·start: beyond that the margin only tends to 0⁻ (infeasible)
        t, val = mp.margin(hi)
        if t > 0:
            best = val
            break
        lo, hi = hi, 4.0 * hi
        if gamma_max is not None and lo >= gamma_max:
            break
    if best is None:
        raise SynthesisError(f"{mp.what} are infeasible: no strictly feasible point up to γ = {lo:.6g}")
    while lo is None:
        t, val = mp.margin(hi / 4.0)
        if t > 0:
            hi, best = hi / 4.0, val
        else:
            lo = hi / 4.0
    while hi / lo > 1.0 + rel_tol:
        mid = np.sqrt(lo * hi)
        t, val = mp.margin(mid)
        if t > 0:
            hi, best = mid, val
        else:
            lo = mid
    return lo, hi, best


def synthesize(
    plant: GeneralizedPlant, method: str = "dilated", solver: str = "CLARABEL", margin: float = 1e-7,
    gamma_max: float | None = None, suboptimality: float = 1e-2, lyapunov_bound: float = LYAPUNOV_BOUND,
) -> HinfResult:
    """γ-optimal vertex controllers of ``method`` (``"common"`` or ``"dilated"``).

    ``"dilated"`` also solves ``"common"`` and returns the better certified point: a common solution is
    a dilated one (𝒢 = 𝒫_i = 𝒫), so γ_dilated ≤ γ_common holds for the returned numbers too, not only
    in exact arithmetic (near the optimum the larger dilated margin problem loses its sign earlier:
    adip_like ±0.3 gave 27.65 against 25.83). Either solve may fail if the other one succeeds.

    1. minimise γ subject to the vertex LMIs ⪰ margin·I, with P̄_i (and sym 𝒢) ⪯ β·I (β =
       ``lyapunov_bound`` in the scaled coordinates, which keeps the near-singular H∞ optimum bounded): γ_opt;
    2. fix γ = (1 + suboptimality)·γ_opt and maximise the common margin t of every LMI ⪰ t·I under the
       same bounds: a strictly feasible, well-conditioned point (the controller's certified γ).
    When step 1 fails (H∞-optimal LMIs are degenerate at the optimum, e.g. weights with poles near
    z = 1) or step 2 finds no positive margin, γ_opt is found by geometric bisection on the margin of
    step 2 to a relative width suboptimality/2 instead. Both run on the scaled plant (:func:`_scalings`);
    the controller is unscaled exactly. Whatever the solver status (optimal or optimal_inaccurate),
    the vertex LMIs are re-evaluated in closed-loop coordinates with the returned numbers
    (:func:`lpvflow.synth.certify.vertex_lmi_max_eig`); a point that fails by round-off is replaced by
    the margin problem's point at γ·1.02, then γ·1.1 (:data:`BACK_OFF`), and the result is refused
    unless every vertex LMI is negative definite.

    For ``"common"`` steps 1 and 2 and the bisection solve the eliminated LMIs (X_i), (Y_i), (C) of the
    module docstring (Clarabel tolerance :data:`lpvflow.synth.sdp.COARSE`) and the vertex controllers are
    reconstructed at the returned X, Y, γ; if that path fails, needs the bisection or its γ minimisation
    is inexact, the full LMIs are solved too and the lower certified γ is returned (and, if still
    ill-conditioned, balanced state coordinates are tried: :func:`_synthesize_common`; the status says
    which).

    Args:
        margin: strictness of step 1, every LMI ⪰ margin·I.
        gamma_max: demand γ ≤ gamma_max (a design spec ‖·‖∞ ≤ 1 is gamma_max = 1); infeasible then means
            the weights ask for more than the plant allows.
        suboptimality: relative distance of the returned controller's γ from γ_opt.
        lyapunov_bound: β above. In exact arithmetic a larger β only enlarges the feasible set; on
            ill-conditioned plants the returned γ can move either way with it (benchmarks/README.md,
            "ADIP synthesis on the exact model").

    Raises:
        ModelError: an unknown ``method`` or a non-positive ``lyapunov_bound``.
        SynthesisError: infeasible LMIs (with the reason), a failed solve or a failed re-check.
    """
    if method not in METHODS:
        raise ModelError(f"unknown output-feedback method {method!r}; use one of {', '.join(METHODS)}")
    if not lyapunov_bound > 0:
        raise ModelError(f"lyapunov_bound must be positive, got {lyapunov_bound!r}")
    result = _best_certified(plant, method, (solver, margin, gamma_max, suboptimality, lyapunov_bound))
    result.controller = implementable_controller(result)  # once, so its info carries the final status
    return result


def _best_certified(plant: GeneralizedPlant, method: str, args: tuple) -> HinfResult:
    """The returned point of :func:`synthesize`, without its implementable controller."""
    if method == "common":
        return _synthesize_common(plant, *args)
    try:
        common = _synthesize_common(plant, *args)
    except SynthesisError:
        return _synthesize_one(plant, "dilated", *args)
    try:
        dilated = _synthesize_one(plant, "dilated", *args)
    except SynthesisError:
        dilated = None
    if dilated is not None and dilated.gamma <= common.gamma:
        return dilated
    return _common_as_dilated(common)


def _common_as_dilated(common: HinfResult) -> HinfResult:
    """The common-Lyapunov result read as a dilated certificate (𝒫_i = 𝒢 = 𝒫), re-checked as such."""
    from lpvflow.synth.certify import vertex_lmi_max_eig

    result = replace(common, method="dilated")
    result.lmi_max_eig = vertex_lmi_max_eig(result)
    if not result.lmi_max_eig < 0:
        raise SynthesisError(f"the common point fails the dilated vertex-pair re-check "
                             f"(max eigenvalue {result.lmi_max_eig:.3g} ≥ 0)")
    result.report = replace(common.report, status=common.report.status + "; dilated: the common point "
                            "(𝒢 = 𝒫) is the better dilated certificate")
    return result


def _synthesize_common(plant: GeneralizedPlant, *args) -> HinfResult:
    """``"common"`` by the eliminated LMIs when their two steps agree; else also by the full LMIs.

    The eliminated result is returned when γ minimisation ended ``optimal`` and the margin problem gave a
    certified point without the bisection fallback. When the eliminated path raised (ill-conditioned
    S − YX, a failed re-check, infeasible), needed the bisection — where its smaller SDP loses the
    margin's sign at a larger γ than the full LMIs on badly scaled plants (maglev_like: 2.26 against
    1.70) — or its γ minimisation ended inexact (``optimal_inaccurate``: the margin problem then accepts
    a γ far above the optimum, tanks design with a 3 s dead time 8.18 against 3.56) the full LMIs
    are solved too, and the lower certified γ of the two is returned (both are common-Lyapunov
    certificates, re-checked independently); the status says what happened. When the better of these
    is still ill-conditioned — the eliminated one (it bisected or was inexact), full LMIs that needed
    the bisection, or both failed — the plant is solved once more in balanced state coordinates
    (:func:`_balanced_common`), and that result is returned if its certified γ is lower.
    """
    try:
        eliminated = _synthesize_one(plant, "common", *args, eliminate=True)
    except SynthesisError as exc:
        eliminated, reason = None, str(exc)[:120]
    else:
        if not eliminated.bisected and eliminated.gamma_min_exact:
            return eliminated
        why = "bisection used" if eliminated.bisected else "γ minimisation inexact"
        reason = f"{why}, γ = {eliminated.gamma:.6g}"
    first_error = None
    try:
        result = _synthesize_one(plant, "common", *args, eliminate=False)
    except SynthesisError as exc:
        first_error, result = exc, None
    ill_conditioned = True  # the better point is the eliminated one (bisected or inexact), or there is none
    if eliminated is not None and (result is None or eliminated.gamma < result.gamma):
        result, eliminated.report.status = eliminated, eliminated.report.status + "; full LMIs: " + (
            "failed" if result is None else f"γ = {result.gamma:.6g}")
    elif result is not None:
        ill_conditioned = result.bisected
        result.report.status += f"; full LMIs (eliminated: {reason})"
    balanced = None
    if ill_conditioned:
        gammas = _BALANCING_GAMMAS if result is None else (result.gamma, 2.0 * result.gamma)
        balanced = _balanced_common(plant, gammas, *args)
    if balanced is not None and (result is None or balanced.gamma < result.gamma):
        unbalanced = "failed" if result is None else f"γ = {result.gamma:.6g}"
        balanced.report.status += f"; unbalanced: {unbalanced}"
        return balanced
    if result is None:
        raise first_error
    return result


def _balanced_common(plant: GeneralizedPlant, gammas: tuple[float, ...], solver: str, margin: float,
                     gamma_max: float | None, suboptimality: float, bound: float) -> HinfResult | None:
    """``"common"`` (eliminated, then full LMIs as in :func:`_synthesize_common`) in the balanced state
    coordinates of :func:`_balancing_transform`, returned in the original ones; None if it fails.

    Used only when the unbalanced attempt bisected, was inexact or failed (ill-conditioned LMIs), so
    well-conditioned plants are solved exactly as before. The returned γ is the lower certified one of
    the two attempts, so it can only improve. ADIP (bench_adip_reach.affine_model, adip.toml
    weights), certified γ unbalanced → balanced: θ = cos φ1 ∈ [0.85, 1] 5.429 → 1.795, [0.7, 1] 30.76 →
    4.089, [0.6, 1] 240.7 → 14.62, [0.5, 1] infeasible → 117.1; [0.25, 1] stays infeasible.
    """
    T = _balancing_transform(plant, gammas, bound)
    if T is None:
        return None
    moved = _transformed(plant, T)
    candidates = []
    for eliminate in (True, False):  # the full LMIs only if the eliminated ones failed or needed bisection
        try:
            candidates.append(_synthesize_one(moved, "common", solver, margin, gamma_max, suboptimality,
                                              bound, eliminate=eliminate))
        except SynthesisError:
            continue
        if not candidates[-1].bisected:
            break
    candidates = [_untransformed(r, plant, T) for r in candidates]
    candidates = [r for r in candidates if r.lmi_max_eig < 0]
    if not candidates:
        return None
    best = min(candidates, key=lambda r: r.gamma)
    best.report = replace(best.report, status=best.report.status + "; balanced state coordinates")
    return best


def _synthesize_one(
    plant: GeneralizedPlant, method: str, solver: str, margin: float, gamma_max: float | None,
    suboptimality: float, bound: float, eliminate: bool = False,
) -> HinfResult:
    """One method's γ-optimal vertex controllers (:func:`synthesize` describes the steps)."""
    s, du, dy = _scalings(plant.vertices)
    verts = [_scaled(v, s, du, dy) for v in plant.vertices]
    what = f"{method} output-feedback H∞ LMIs at {len(verts)} vertices" + (
        f" with γ ≤ {gamma_max:g}" if gamma_max is not None else "")
    g = cp.Variable(nonneg=True)
    first = _lmi_set(verts, method, g, eliminate)
    constraints = [psd(M, margin) for M in first.matrices] + _bounded(first, bound)
    if gamma_max is not None:
        constraints.append(g <= gamma_max)
    gamma_opt = None
    try:
        report1 = solve(cp.Problem(cp.Minimize(g), constraints), solver, what, COARSE if eliminate else None)
        gamma_opt = float(g.value)
    except SynthesisError as exc:
        if "infeasible" in str(exc):
            raise SynthesisError(f"{exc}: {_infeasibility_hint(plant, method, gamma_max)}") from None
        report1 = SolveReport(solver, str(exc), 0.0, [])
    mp = _MarginProblem(verts, method, solver, what, eliminate, bound)
    result = None
    if gamma_opt is not None:
        gamma = gamma_opt * (1.0 + suboptimality)
        t, val = mp.margin(gamma)
        result = _result(plant, method, verts, s, du, dy, gamma, gamma_opt, val) if t > 0 else None
    if result is None or not result.lmi_max_eig < 0:
        try:
            lo, hi, val = _bisect(mp, gamma_opt or 1.0, 0.5 * suboptimality, gamma_max)
        except SynthesisError as exc:
            raise SynthesisError(f"{exc}: {_infeasibility_hint(plant, method, gamma_max)}") from None
        t, val_final = mp.margin(hi * (1.0 + suboptimality))  # room for a margin, as in step 2
        gamma, val = (hi * (1.0 + suboptimality), val_final) if t > 0 else (hi, val)
        result = _result(plant, method, verts, s, du, dy, gamma, lo, val)
    for back_off in BACK_OFF:  # a point at the re-check's edge: give the margin more room in γ
        if result.lmi_max_eig < 0:
            break
        t, val = mp.margin(result.gamma * back_off)
        if t > 0:
            result = _result(plant, method, verts, s, du, dy, result.gamma * back_off, result.gamma_opt, val)
    if gamma_max is not None and result.gamma > gamma_max:
        raise SynthesisError(f"{what} are infeasible (smallest γ found {result.gamma:.4g}): "
                             f"{_infeasibility_hint(plant, method, gamma_max)}")
    attempts = report1.attempts + [a for r in mp.reports for a in r.attempts]
    status = mp.reports[-1].status
    result.bisected, result.gamma_min_exact = result.gamma_opt != gamma_opt, report1.status == cp.OPTIMAL
    if not result.gamma_min_exact or result.bisected:
        status += f"; γ minimisation: {report1.status[:60]}" + (", bisection used" if result.bisected else "")
    result.report = SolveReport(mp.reports[-1].solver, status, sum(a[2] for a in attempts), attempts)
    if not result.lmi_max_eig < 0:
        raise SynthesisError(f"{what}: the solver's point ({status}) fails the independent vertex-LMI "
                             f"re-check (max eigenvalue {result.lmi_max_eig:.3g} ≥ 0); "
                             "increase suboptimality")
    return result


def _result(plant: GeneralizedPlant, method: str, verts: list[VertexPlant], s: np.ndarray, du: np.ndarray,
            dy: np.ndarray, gamma: float, gamma_opt: float, val: dict) -> HinfResult:
    """Controller reconstruction, certificate in the original closed-loop coordinates, LMI re-check.

    The LMIs hold γ·I in both the w and z blocks; the congruence diag(√γ I, √γ I, I/√γ, √γ I) turns
    them into (E) with I and γ²I, so the returned 𝒫_i, 𝒢 are γ times the solved ones.
    """
    from lpvflow.synth.certify import vertex_lmi_max_eig

    n = verts[0].dims[0]
    I = np.eye(n)
    Xv, Yv, Sv = val["X"], val["Y"], val["S"]
    W, sig, Zt = np.linalg.svd(Sv - Yv @ Xv)
    if sig[-1] <= 1e-12 * sig[0]:
        raise SynthesisError(f"controller reconstruction is ill-conditioned (S − YX has condition "
                             f"{sig[0] / max(sig[-1], 1e-300):.2g}); increase suboptimality")
    if "Q" not in val:  # eliminated "common" LMIs
        val = {**val, **_controller_variables(verts, val, gamma)}
    Vt, U = W * np.sqrt(sig), np.sqrt(sig)[:, None] * Zt
    K = [_unscaled_controller(reconstruct(v, Xv, Yv, Sv, val["Q"][i], val["L"][i], val["F"][i], val["R"][i],
                                          U, Vt), du, dy) for i, v in enumerate(verts)]
    T = np.block([[I, Yv.T], [np.zeros((n, n)), Vt.T]])
    back = np.diag(np.concatenate([s, np.ones(n)])) @ np.linalg.inv(T).T  # ξ = diag(s, I) ξ̃
    G = gamma * back @ np.block([[Xv, I], [Sv, Yv]]) @ back.T
    P = [gamma * back @ Pb @ back.T for Pb in val["Pbar"]]
    result = HinfResult(method, gamma, K, P, G, SolveReport("", "", 0.0), plant, gamma_opt=gamma_opt)
    result.lmi_max_eig = vertex_lmi_max_eig(result)
    return result


def implementable_controller(result: HinfResult) -> LPVController:
    """The LPVController from e to the plant input: vertex K, with W_B in series when designed with one."""
    plant = result.plant
    K = result.K_vertices
    if plant.input_filter is not None:
        K = [series_input_filter(k, plant.input_filter) for k in K]
    stacks = [np.array([k[m] for k in K]) for m in range(4)]
    info = {"method": result.method, "gamma": result.gamma, "gamma_opt": result.gamma_opt,
            "solver": result.report.solver, "status": result.report.status,
            "solve_seconds": result.report.seconds, "polytope": plant.polytope.kind}
    return LPVController(*stacks, plant.polytope, plant.basis, plant.Ts, info=info)


def _infeasibility_hint(plant: GeneralizedPlant, method: str, gamma_max: float | None) -> str:
    """Why the LMIs may be infeasible, in terms of the plant (the LMIs are sufficient conditions: what
    is excluded is a controller with this method's Lyapunov certificate, not every controller)."""
    n_g = plant.n_plant_states
    radius = max(np.max(np.abs(np.linalg.eigvals(v.A[:n_g, :n_g]))) for v in plant.vertices)
    unstable = f"the plant has vertex poles up to |z| = {radius:.4g}" + (" (unstable)" if radius >= 1 else "")
    if gamma_max is not None:
        return (f"no controller reaches γ ≤ {gamma_max:g}; {unstable}: lower the W_S bandwidth/gain or the "
                "W_K penalty, or drop gamma_max")
    certificate = "a common Lyapunov matrix" if method == "common" else "vertex Lyapunov matrices"
    return (f"no vertex controllers with {certificate} stabilize all vertices; {unstable}: shrink the "
            "scheduling box")
