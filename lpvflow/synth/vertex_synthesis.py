"""H∞ output-feedback synthesis by LMIs on discrete vertex plants with one common Lyapunov matrix (the
method behind :func:`lpvflow.synth.hinf.hinfsyn`; LTI: one vertex).

A polytopic design with one common Lyapunov matrix (Apkarian, Gahinet & Becker 1995, Thm. 5.1 / Gahinet
& Apkarian 1994, Thm. 4.3). Generalized plant at vertex i, inputs [w, u], outputs [z, y]:

    x⁺ = A_i x + B1_i w + B2 u,   z = C1_i x + D11_i w + D12 u,   y = C2 x + D21 w + D22 u,

with B2, C2, D12, D21 the same at every vertex and D22 = 0 for a polytope
(:func:`lpvflow.synth.plant.check_a3`), so the vertex controllers interpolated with the plant's convex
coordinates λ give a closed loop affine in λ. One call ends in one of two ways: a result whose certificate
passed, or one :class:`lpvflow.errors.SynthesisError` whose ``category`` says why (``"assumption"``,
``"infeasible"``, ``"accuracy"``). The steps, each taken once:

1. **Assumptions** (:func:`check_assumptions`): at every vertex (A, B2) stabilizable and (C2, A) detectable
   (PBH rank test at every mode with |z| ≥ 1) and no pole at z = −1 (where the bilinear map of step 2 does
   not exist); otherwise no controller of any kind exists, and the error names the mode.
2. **Coordinates.** Every LMI is posed on the bilinear (Cayley) image of each vertex, in the coordinates
   of :func:`lpvflow.synth.bilinear.initial_coordinates` (no SDP: the LQG-balanced state of the mean vertex,
   a frequency scale and u/y scalings), so the state basis the plant was given in does not matter.
3. **Estimate** by the eliminated continuous conditions (Gahinet & Apkarian 1994, Thm. 4.3), per vertex
   with its own null-space bases N_R,i of [B2_iᵀ D12_iᵀ] and N_S,i of [C2_i D21_i]:

       N_R,iᵀ [A_iR + RA_iᵀ   RC1_iᵀ   B1_i ;  C1_iR   −γI   D11_i ;  B1_iᵀ   D11_iᵀ   −γI] N_R,i ⪯ 0,
       N_S,iᵀ [A_iᵀS + SA_i   SB1_i   C1_iᵀ ;  B1_iᵀS   −γI   D11_iᵀ ;  C1_i   D11_i   −γI] N_S,i ⪯ 0,
       [R I; I S] ⪰ 0,

   minimise γ → γ̂. γ̂ starts the level search of step 5; when the solver reached full accuracy it is
   reported as ``gamma_estimate``. It is not a lower bound (:mod:`lpvflow.synth.eliminated`: the infimum
   is not attained, and "optimal" solves were measured up to 0.8 % above SB10DD's level), so the search
   also tries levels below it.
4. **Balancing, validated.** The γ-optimal R, S are singular (RS − I loses rank); the matrices of step 3
   at :data:`lpvflow.synth.eliminated.BALANCING_FACTOR`·γ̂ with the largest margin t (projected LMIs
   ⪯ −t·D_k, D_k their Jacobi diagonals at the estimate; [R I; I S] ⪰ t·I) give a centred pair, and
   x = T x̃ with R = LLᵀ, LᵀSL = VΣ²Vᵀ, T = LVΣ^(−1/2) makes T⁻¹RT⁻ᵀ = TᵀST = Σ (Moore's balancing
   applied to R, S). T is used only when that solve was accurate, R and S are positive definite and T is
   finite and well conditioned (:func:`lpvflow.synth.bilinear.balancing_transform`); otherwise step 5 is
   posed in step 2's coordinates. Step 3 is solved again in the balanced coordinates
   (:func:`lpvflow.synth.eliminated.preconditioned`): ``gamma_estimate`` is the lower accurate minimum.
5. **Certified level.** The change-of-variables LMIs of Scherer, Gahinet & Chilali (1997, eq. (33)),
   per vertex with common R, S and vertex variables (Â_i, B̂_i, Ĉ_i, D̂_i),

       ⎡ He[A_iR + B2_iĈ_i   A_i + B2_iD̂_iC2_i ; Â_i   SA_i + B̂_iC2_i]   Ψ_i    Ω_iᵀ ⎤
       ⎢ ⋆                                                          −γI     Δ_iᵀ ⎥ ≺ 0,
       ⎣ ⋆                                                          ⋆       −γI  ⎦
       Ψ_i = [B1_i + B2_iD̂_iD21_i; SB1_i + B̂_iD21_i],  Ω_i = [C1_iR + D12_iĈ_i   C1_i + D12_iD̂_iC2_i],
       Δ_i = D11_i + D12_iD̂_iD21_i,   [R I; I S] ≻ 0,

   are solved **homogenized**: every term that does not multiply a variable (A_i in the (1, 2) block,
   B1_i, C1_i, D11_i, the −γI blocks and the identities of [R I; I S]) is multiplied by a variable
   τ ≥ 0, the variables are normalised by R ⪯ I, S ⪯ I, and t is maximised with the matrices ⪯ −t·I and
   [R τI; τI S] ⪰ t·I. Both sides are linear in (R, S, Â, B̂, Ĉ, D̂, τ), so with τ > 0 the point
   divided by τ satisfies the LMIs above with margin t/τ, and conversely any solution scaled by τ small
   enough satisfies the normalisation; t > 0 forces τ > 0 (at τ = 0 the −γI blocks vanish). So the
   homogenized problem has a solution with t > 0 exactly when the LMIs above are feasible, while R, S, τ
   stay bounded — unlike max t of the LMIs as written, whose supremum near the optimal level is
   approached only as R, S grow without bound (measured ‖R‖ ≈ 1e5 and cond(I − RS) up to 1e11 on
   12-state mass chains, where Clarabel stalled at t < 0 up to 1.6 % above SB10DD's level; the same levels
   solved homogenized end ``optimal`` in 15–19 iterations at Clarabel's default settings). Maximising t
   there is maximising the margin relative to the size of R, S.
   Compiled once with γ a cvxpy parameter; the levels are those of
   :func:`lpvflow.synth.levels.lowest_certified_level` from γ̂ up to ``gamma_max`` (upwards until one
   passes, downwards from a first passing level until one fails, then bisected): a level passes when its
   controller passes the certificate of step 7.
6. **Controller** per vertex (Scherer et al. 1997, eq. (35)) from the point of step 5: MNᵀ = I − RS by a
   balanced SVD, D_K = D̂, C_K = (Ĉ − D_KC2R)M⁻ᵀ, B_K = N⁻¹(B̂ − SB2D_K),
   A_K = N⁻¹(Â − NB_KC2R − SB2C_KMᵀ − S(A + B2D_KC2)R)M⁻ᵀ, designed for D22 = 0 while the Cayley image
   has D22_c = D22 − C2(I + A)⁻¹B2, so K_c = K(I + D22_cK)⁻¹ (loop shifting: the same closed loop); then
   the scalings are undone and the inverse Cayley map gives the discrete vertex controller. Closed-loop
   Lyapunov matrix 𝒳 = Π₂Π₁⁻¹, Π₁ = [R I; Mᵀ 0], Π₂ = [I S; 0 Nᵀ], in the original discrete coordinates.
7. **Certificate** (:func:`lpvflow.synth.bilinear.certificate_margin`): every vertex closed loop rebuilt
   from the returned discrete numbers satisfies the bounded-real inequality with 𝒳 with a Jacobi-scaled
   margin above round-off.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import control
import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError, SynthesisError
from lpvflow.synth.bilinear import (
    Coordinates,
    cayley_vertex,
    certificate_margin,
    inverse_cayley,
)
from lpvflow.synth.controller import LPVController, mix
from lpvflow.synth.eliminated import Preconditioned, infeasible_at, preconditioned, sym
from lpvflow.synth.levels import GAMMA_MAX, lowest_certified_level
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant, check_a3
from lpvflow.synth.riccati import riccati_judgement, riccati_witness
from lpvflow.synth.sdp import SolveReport, solve

#: Default relative width δ of the final level bracket (step 5).
SUBOPTIMALITY = 2.5e-3


@dataclass
class VertexController:
    """Vertex controllers (Ak_i, Bk_i, Ck_i, Dk_i) from y to u, interpolated with convex coordinates λ."""

    vertices: list[tuple[np.ndarray, ...]]
    Ts: float

    def __call__(self, lam: Sequence[float]) -> control.StateSpace:
        """The controller frozen at λ: Σ λ_i K_i."""
        return control.ss(*mix(self.vertices, lam), self.Ts)


@dataclass
class HinfResult:
    """γ-optimal (to ``suboptimality``) controller, its certified γ and the certificate.

    Attributes:
        gamma: level certified at every vertex by the closed-loop Lyapunov matrix 𝒳 = FᵀF
            (``lyapunov_factor``).
        gamma_estimate: the lowest minimum of the eliminated LMIs (step 3) among the solves that reported
            full accuracy, None when none did; an estimate of the optimum, not a bound (step 3).
        K_vertices: discrete (Ak_i, Bk_i, Ck_i, Dk_i) from y to u.
        vertex_controllers: the same as ``control.StateSpace`` objects (dt = Ts).
        controller: one ``StateSpace`` for an LTI design, else a :class:`VertexController`; from
            :func:`lpvflow.synth.hinf.synthesize`, the implementable :class:`LPVController` (W_B in series).
        certificate: per-vertex margins of :func:`lpvflow.synth.bilinear.certificate_margin` (all > 0).
        lyapunov_factor: F with 𝒳 = FᵀF the common closed-loop Lyapunov matrix, state [x_plant; x_K],
            original discrete coordinates.
        report: the solver and status of the passing level's SDP, the total time, and every SDP solved
            (``attempts``: solver, status, seconds).
        plant: the :class:`GeneralizedPlant` of :func:`lpvflow.synth.hinf.synthesize` (None from
            :func:`lpvflow.synth.hinf.hinfsyn`).
        preconditioning: steps 2–4 (coordinates, estimate) of :func:`synthesize_vertices`; they do not
            depend on the level, so :func:`lpvflow.synth.central.central_vertices` reuses them for the same
            vertices (None from other syntheses).
    """

    gamma: float
    gamma_estimate: float | None
    K_vertices: list[tuple[np.ndarray, ...]]
    vertex_controllers: list[control.StateSpace]
    controller: control.StateSpace | VertexController | LPVController
    certificate: list[float]
    lyapunov_factor: np.ndarray
    vertices: list[VertexPlant]
    Ts: float
    report: SolveReport
    plant: GeneralizedPlant | None = None
    preconditioning: Preconditioned | None = None



# ------------------------------------------------------------------------------------ assumptions
def _uncontrollable_mode(A: np.ndarray, B: np.ndarray) -> complex | None:
    """An eigenvalue z of A with |z| ≥ 1 at which rank [A − zI, B] < n (PBH test), else None."""
    n = A.shape[0]
    scale = max(1.0, float(np.linalg.norm(np.hstack([A, B]), 2)))
    for z in np.linalg.eigvals(A):
        if abs(z) >= 1.0 - 1e-9:
            sv = scipy.linalg.svdvals(np.hstack([A - z * np.eye(n), B]))
            if sv[n - 1] <= 1e-9 * scale:
                return complex(z)
    return None


def check_assumptions(vertices: list[VertexPlant]) -> None:
    """Step 1: raise SynthesisError (category ``"assumption"``) naming the vertex and the mode when (A, B2)
    is not stabilizable, (C2, A) not detectable or A has a pole at z = −1; for a polytope also
    :func:`lpvflow.synth.plant.check_a3`."""
    if len(vertices) > 1:
        try:
            check_a3(vertices)
        except ModelError as exc:
            raise SynthesisError(str(exc), category="assumption") from None
    for i, v in enumerate(vertices):
        where = "the plant" if len(vertices) == 1 else f"vertex {i}"
        mode = _uncontrollable_mode(v.A, v.B2)
        if mode is not None:
            raise SynthesisError(f"{where} has a mode at z = {mode:.6g} that the control input cannot "
                                 "stabilize ((A, B2) not stabilizable): no controller exists; check the "
                                 "weights for an unstable pole u does not reach", category="assumption")
        mode = _uncontrollable_mode(v.A.T, v.C2.T)
        if mode is not None:
            raise SynthesisError(f"{where} has a mode at z = {mode:.6g} that the measurement does not see "
                                 "((C2, A) not detectable): no controller exists; check the weights for an "
                                 "unstable pole y does not see", category="assumption")
        if np.min(np.abs(np.linalg.eigvals(v.A) + 1.0)) < 1e-9:
            raise SynthesisError(f"{where} has a pole at z = −1 (the Nyquist frequency), where the bilinear "
                                 "map the LMIs are posed on does not exist: move it (e.g. a weight pole) "
                                 "inside the unit circle", category="assumption")


# ------------------------------------------------------------------------------------------- LMIs
def homogenizing_scale(tau: cp.Variable) -> float:
    """τ of a solved homogenized level problem (step 5): the point of the LMIs as written is the solution
    divided by τ. Raises LinAlgError when τ is not positive (the solve found no point of the level LMIs)."""
    value = float(tau.value)
    if not value > 0:
        raise np.linalg.LinAlgError("τ ≤ 0: no point of the level LMIs")
    return value


class _LevelProblem:
    """Step 5 at a γ given as a cvxpy Parameter (compiled once, solved at each level), in the homogenized
    form of the module docstring; :meth:`point` is the solution of the LMIs of step 5 it stands for."""

    def __init__(self, verts: list[VertexPlant]) -> None:
        n = verts[0].dims[0]
        self.verts = verts
        self.gamma, self.t, self.tau = cp.Parameter(pos=True), cp.Variable(), cp.Variable()
        self.R = cp.Variable((n, n), symmetric=True)
        self.S = cp.Variable((n, n), symmetric=True)
        R, S, g, t, tau = self.R, self.S, self.gamma, self.t, self.tau
        identity = np.eye(n)
        constraints = [cp.bmat([[R, tau * identity], [tau * identity, S]]) >> t * np.eye(2 * n),
                       R << identity, S << identity]
        self.hats = []
        for v in verts:
            _, nw, nu, nz, ny = v.dims
            Ah, Bh = cp.Variable((n, n)), cp.Variable((n, ny))
            Ch, Dh = cp.Variable((nu, n)), cp.Variable((nu, ny))
            self.hats.append((Ah, Bh, Ch, Dh))
            Phi = cp.bmat([[v.A @ R + v.B2 @ Ch, tau * v.A + v.B2 @ Dh @ v.C2], [Ah, S @ v.A + Bh @ v.C2]])
            Psi = cp.vstack([tau * v.B1 + v.B2 @ Dh @ v.D21, S @ v.B1 + Bh @ v.D21])
            Omega = cp.hstack([v.C1 @ R + v.D12 @ Ch, tau * v.C1 + v.D12 @ Dh @ v.C2])
            Delta = tau * v.D11 + v.D12 @ Dh @ v.D21
            M = cp.bmat([[Phi + Phi.T, Psi, Omega.T],
                         [Psi.T, -g * tau * np.eye(nw), Delta.T],
                         [Omega, Delta, -g * tau * np.eye(nz)]])
            constraints.append(sym(M) << -t * np.eye(M.shape[0]))
        self.problem = cp.Problem(cp.Maximize(t), constraints)

    def solve(self, gamma: float, solver: str) -> SolveReport:
        """The SDP at γ (raises SynthesisError when the solver returns no point)."""
        self.gamma.value = gamma
        return solve(self.problem, solver, f"the H∞ controller LMIs at γ = {gamma:.6g}", refined=True)

    def point(self) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, ...]]]:
        """(R, S, per-vertex (Â, B̂, Ĉ, D̂)) of step 5's LMIs: the solution divided by τ (R, S symmetrized;
        raises LinAlgError when τ is not positive, i.e. the solve found no controller at this level)."""
        tau = homogenizing_scale(self.tau)
        R, S = (0.5 * (V.value + V.value.T) / tau for V in (self.R, self.S))
        return R, S, [tuple(h.value / tau for h in hats) for hats in self.hats]


def reconstruct_controller(v: VertexPlant, R: np.ndarray, S: np.ndarray, M: np.ndarray, N: np.ndarray,
                           hats: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """Step 6's reconstruction (D22 = 0) of the continuous vertex controller."""
    Ah, Bh, Ch, Dh = hats
    Dk = Dh
    Ck = np.linalg.solve(M, (Ch - Dk @ v.C2 @ R).T).T
    Bk = np.linalg.solve(N, Bh - S @ v.B2 @ Dk)
    core = Ah - N @ Bk @ v.C2 @ R - S @ v.B2 @ Ck @ M.T - S @ (v.A + v.B2 @ Dk @ v.C2) @ R
    Ak = np.linalg.solve(N, np.linalg.solve(M, core.T).T)
    return Ak, Bk, Ck, Dk


def loop_shift(K: tuple[np.ndarray, ...], D22: np.ndarray) -> tuple[np.ndarray, ...]:
    """K(I + D22 K)⁻¹ in state space (same controller state): the loop of the D22 ≠ 0 plant."""
    Ak, Bk, Ck, Dk = K
    E = np.linalg.inv(np.eye(Dk.shape[0]) + Dk @ D22)
    C, D = E @ Ck, E @ Dk
    return Ak - Bk @ D22 @ C, Bk - Bk @ D22 @ D, C, D


def closed_loop_lyapunov(R: np.ndarray, S: np.ndarray, M: np.ndarray, N: np.ndarray) -> np.ndarray:
    """𝒳 = Π2Π1⁻¹, Π1 = [R I; Mᵀ 0], Π2 = [I S; 0 Nᵀ]: the closed-loop Lyapunov matrix of step 6, whose
    blocks are 𝒳₁₁ = S, (𝒳⁻¹)₁₁ = R (Scherer, Gahinet & Chilali 1997, §IV)."""
    n = R.shape[0]
    Pi1 = np.block([[R, np.eye(n)], [M.T, np.zeros((n, n))]])
    Pi2 = np.block([[np.eye(n), S], [np.zeros((n, n)), N.T]])
    X = np.linalg.solve(Pi1.T, Pi2.T).T
    return 0.5 * (X + X.T)


def _reconstruct(vertices: list[VertexPlant], level: _LevelProblem, coords: Coordinates, gamma: float,
                 gamma_estimate: float | None, Ts: float, report: SolveReport) -> HinfResult:
    """Steps 6 and 7 in the original discrete coordinates (raises LinAlgError when I − RS or 𝒳 is
    singular in floating point)."""
    R, S, hats_all = level.point()
    n = R.shape[0]
    W, sig, Zt = np.linalg.svd(np.eye(n) - R @ S)
    M, N = W * np.sqrt(sig), Zt.T * np.sqrt(sig)
    K_vertices = []
    for v, hats in zip(level.verts, hats_all, strict=True):
        K = loop_shift(reconstruct_controller(v, R, S, M, N, hats), v.D22)
        K_vertices.append(inverse_cayley(*coords.controller(K)))
    back = scipy.linalg.block_diag(np.linalg.inv(coords.T), np.eye(n))
    F = np.linalg.cholesky(closed_loop_lyapunov(R, S, M, N)).T @ back  # 𝒳 = FᵀF in the original coordinates
    certificate = [certificate_margin(v, K, F, gamma) for v, K in zip(vertices, K_vertices, strict=True)]
    ss = [control.ss(*K, Ts) for K in K_vertices]
    controller = ss[0] if len(ss) == 1 else VertexController(K_vertices, Ts)
    return HinfResult(gamma, gamma_estimate, K_vertices, ss, controller, certificate, F, vertices, Ts, report)


@dataclass
class _Search:
    """The level search of step 5 over the vertices ``vertices`` (discrete) and their Cayley images, with
    every SDP's (solver, status, seconds) and the failures by kind."""

    vertices: list[VertexPlant]
    cayleys: list[VertexPlant]
    Ts: float
    solver: str
    gamma_estimate: float | None
    attempts: list[tuple[str, str, float]] = field(default_factory=list)
    no_point: list[str] = field(default_factory=list)
    infeasible: int = 0
    rejected: int = 0

    def run(self, coords: Coordinates, start: float, suboptimality: float, gamma_max: float
            ) -> HinfResult | None:
        """:func:`lowest_certified_level` of :class:`_LevelProblem` in ``coords`` from ``start``: the
        lowest passing result, or None when no level up to ``gamma_max`` passes."""
        level = _LevelProblem([coords.apply(vc) for vc in self.cayleys])
        return lowest_certified_level(lambda gamma: self._level(level, coords, gamma), start, suboptimality,
                                      gamma_max)

    def _level(self, level: _LevelProblem, coords: Coordinates, gamma: float) -> HinfResult | None:
        """The SDP at γ and the controller rebuilt from it when it passes the certificate, else None (the
        failure counted by kind)."""
        try:
            level_report = level.solve(gamma, self.solver)
        except SynthesisError as exc:
            self.attempts.append((self.solver.upper(), exc.category, 0.0))
            if exc.category == "infeasible":
                self.infeasible += 1
            else:
                self.no_point.append(str(exc))
            return None
        self.attempts += level_report.attempts
        try:
            result = _reconstruct(self.vertices, level, coords, gamma, self.gamma_estimate, self.Ts,
                                  level_report)
        except np.linalg.LinAlgError:
            self.rejected += 1
            return None
        if min(result.certificate) <= 0:
            self.rejected += 1
            return None
        return result


def synthesize_vertices(vertices: list[VertexPlant], Ts: float, suboptimality: float = SUBOPTIMALITY,
                        gamma_max: float = GAMMA_MAX, solver: str = "CLARABEL") -> HinfResult:
    """Steps 1–7 of the module docstring on partitioned discrete vertex plants."""
    if not suboptimality > 0:
        raise ModelError(f"suboptimality must be positive, got {suboptimality!r}")
    start = time.perf_counter()
    check_assumptions(vertices)
    cayleys = [cayley_vertex(v) for v in vertices]
    try:
        pre = preconditioned(cayleys, gamma_max, solver)
    except SynthesisError as exc:
        raise SynthesisError(*_failure(exc.category, str(exc), vertices, Ts, gamma_max)) from None
    estimate = pre.estimate
    search = _Search(vertices, cayleys, Ts, solver, estimate.gamma if estimate.accurate else None,
                     list(pre.attempts))
    best = search.run(pre.coordinates, min(estimate.gamma, gamma_max), suboptimality, gamma_max)
    if best is None:
        if infeasible_at(pre.vertices, gamma_max, solver):
            category = "infeasible"
            what = (f"no level up to γ = {gamma_max:g} passed, and the eliminated H∞ LMIs at {gamma_max:g} "
                    "have no strict solution in a solve the solver calls accurate")
        else:
            category = "accuracy"
            what = (f"no level up to γ = {gamma_max:g} gave a controller that passes the certificate "
                    f"({search.infeasible} levels infeasible, {len(search.no_point)} without a solution, "
                    f"{search.rejected} rejected by the re-check; estimate γ̂ = {estimate.gamma:.4g}, "
                    f"{estimate.report.status})")
        raise SynthesisError(*_failure(category, what, vertices, Ts, gamma_max))
    best.report = SolveReport(best.report.solver, best.report.status, time.perf_counter() - start,
                              search.attempts)
    best.preconditioning = pre
    return best


def _failure(category: str, what: str, vertices: list[VertexPlant], Ts: float, gamma_max: float
             ) -> tuple[str, str]:
    """The one line of a SynthesisError and its category: what failed, and what it means for the design.
    For one plant the independent Riccati synthesis (SB10DD, bisected) says whether any controller reaches
    ``gamma_max``; where it does, the LMIs' "infeasible" was the solver's round-off (the LMIs are exact for
    one plant, Gahinet & Apkarian 1994), so the category is ``"accuracy"``."""
    if len(vertices) == 1:
        judgement, verdict = riccati_judgement(riccati_witness(vertices[0], Ts), gamma_max)
        if verdict == "accuracy":
            return (f"{what}; {judgement}: rescale the weights (signals near 1, time constants within a few "
                    "decades) or try solver='SCS'", verdict)
        return (f"{what}; {judgement}: relax the weights (lower the W_S bandwidth or gain, or the W_K "
                "penalty) or raise gamma_max", category)
    radius = max(np.max(np.abs(np.linalg.eigvals(v.A))) for v in vertices)
    hint = ("no vertex controllers with one common Lyapunov matrix reach it" if category == "infeasible" else
            "the solver could not reach the accuracy a certificate needs with one common Lyapunov matrix")
    return (f"{what}; {hint} (vertex poles up to |z| = {radius:.4g}): shrink the scheduling box, add "
            "breakpoints, relax the weights or raise gamma_max", category)
