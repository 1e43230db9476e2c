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
   also the search's floor (no level below it is tried) and is reported as ``gamma_estimate``. It is not
   a lower bound (:mod:`lpvflow.synth.eliminated`: the infimum is not attained, and "optimal" solves were
   measured up to 0.8 % above SB10DD's level), so the certified γ is within 1 + δ of a failing level or
   of that estimate, not necessarily of the optimum.
4. **Balancing, validated.** The γ-optimal R, S are singular (RS − I loses rank); the matrices of step 3
   at :data:`lpvflow.synth.eliminated.BALANCING_FACTOR`·γ̂ with the largest margin t (projected LMIs
   ⪯ −t·D_k, D_k their Jacobi diagonals at the estimate; [R I; I S] ⪰ t·I) give a centred pair, and
   x = T x̃ with R = LLᵀ, LᵀSL = VΣ²Vᵀ, T = LVΣ^(−1/2) makes T⁻¹RT⁻ᵀ = TᵀST = Σ (Moore's balancing
   applied to R, S), so every block of step 5 is O(1). T is used only when that solve was accurate, R
   and S are positive definite and T is finite and well conditioned
   (:func:`lpvflow.synth.bilinear.balancing_transform`); otherwise step 5 starts in step 2's
   coordinates. Step 3 is solved again in the balanced coordinates. The first level of step 5 that passes
   gives another strictly feasible pair; when its T is further from the identity than cond
   :data:`REBALANCE_CONDITION`, the search stops there and is repeated below that level in the
   coordinates it balances, starting from step 3 solved there (a bound when accurate, else only a start),
   at most :data:`MAX_REBALANCE` times. There step 5's strictness is relative: ⪯ −t·D_i, D_i = |diag| of
   that level's matrix i written in the new coordinates (the congruence diag(T⁻¹, Tᵀ, I) of its rows
   [R-side; S-side; w, z]), floored at 1e-9 of its largest entry, so a lightly damped direction whose
   diagonal is small is not held to the margin of the largest one. When no other coordinates give a lower
   passing level, the bracket of the starting coordinates (their highest failing level, the passing one)
   is bisected there (:func:`lpvflow.synth.levels.bisect_levels`).
5. **Certified level.** The change-of-variables LMIs of Scherer, Gahinet & Chilali (1997, eq. (33)),
   per vertex with common R, S and vertex variables (Â_i, B̂_i, Ĉ_i, D̂_i),

       ⎡ He[A_iR + B2_iĈ_i   A_i + B2_iD̂_iC2_i ; Â_i   SA_i + B̂_iC2_i]   Ψ_i    Ω_iᵀ ⎤
       ⎢ ⋆                                                          −γI     Δ_iᵀ ⎥ ⪯ −t·I,
       ⎣ ⋆                                                          ⋆       −γI  ⎦
       Ψ_i = [B1_i + B2_iD̂_iD21_i; SB1_i + B̂_iD21_i],  Ω_i = [C1_iR + D12_iĈ_i   C1_i + D12_iD̂_iC2_i],
       Δ_i = D11_i + D12_iD̂_iD21_i,   [R I; I S] ⪰ t·I,  t ≤ 1,

   compiled once with γ a cvxpy parameter and solved to a duality gap of 1e-12 (near the optimal level t
   must be resolved far below 1e-8 of ‖R‖, ‖S‖; :func:`lpvflow.synth.sdp.solve`); maximise t at the levels of
   :func:`lpvflow.synth.levels.lowest_certified_level` from γ̂ up to ``gamma_max``: a level passes when
   its controller passes the certificate of step 7.
6. **Controller** per vertex (Scherer et al. 1997, eq. (35)): MNᵀ = I − RS by a balanced SVD,
   D_K = D̂, C_K = (Ĉ − D_KC2R)M⁻ᵀ, B_K = N⁻¹(B̂ − SB2D_K),
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import control
import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError, SynthesisError
from lpvflow.synth.bilinear import (
    Coordinates,
    balancing_transform,
    cayley_vertex,
    certificate_margin,
    inverse_cayley,
)
from lpvflow.synth.controller import LPVController, mix
from lpvflow.synth.eliminated import estimate, infeasible_at, preconditioned, sym
from lpvflow.synth.levels import GAMMA_MAX, bisect_levels, lowest_certified_level
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant, check_a3
from lpvflow.synth.riccati import riccati_gamma
from lpvflow.synth.sdp import SolveReport, solve

#: A first passing level's R, S further from balanced than this (cond T) repeat step 5 balanced on them;
#: at most MAX_REBALANCE times. Measured on the 63 random plants of tests/hinf_cases.py (seed 2027)
#: against SB10DD: once at cond 10 left 52 within 1 %, up to 4 times at cond 3 left 56, and with the
#: relative strictness there (step 4) 58 (SDPs per synthesis: median 6 → 8, worst 34 → 28).
REBALANCE_CONDITION = 3.0
MAX_REBALANCE = 4
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
class _LevelProblem:
    """Step 5 at a γ given as a cvxpy Parameter (compiled once, solved at each level); strictness
    ⪯ −t·diag(scales[i]) for vertex i (−t·I when ``scales`` is None)."""

    def __init__(self, verts: list[VertexPlant], scales: list[np.ndarray] | None) -> None:
        n = verts[0].dims[0]
        self.verts = verts
        self.matrices = []
        self.gamma, self.t = cp.Parameter(pos=True), cp.Variable()
        self.R = cp.Variable((n, n), symmetric=True)
        self.S = cp.Variable((n, n), symmetric=True)
        R, S, g, t = self.R, self.S, self.gamma, self.t
        constraints = [cp.bmat([[R, np.eye(n)], [np.eye(n), S]]) >> t * np.eye(2 * n), t <= 1]
        self.hats = []
        for v in verts:
            _, nw, nu, nz, ny = v.dims
            Ah, Bh = cp.Variable((n, n)), cp.Variable((n, ny))
            Ch, Dh = cp.Variable((nu, n)), cp.Variable((nu, ny))
            self.hats.append((Ah, Bh, Ch, Dh))
            Phi = cp.bmat([[v.A @ R + v.B2 @ Ch, v.A + v.B2 @ Dh @ v.C2], [Ah, S @ v.A + Bh @ v.C2]])
            Psi = cp.vstack([v.B1 + v.B2 @ Dh @ v.D21, S @ v.B1 + Bh @ v.D21])
            Omega = cp.hstack([v.C1 @ R + v.D12 @ Ch, v.C1 + v.D12 @ Dh @ v.C2])
            Delta = v.D11 + v.D12 @ Dh @ v.D21
            M = cp.bmat([[Phi + Phi.T, Psi, Omega.T],
                         [Psi.T, -g * np.eye(nw), Delta.T],
                         [Omega, Delta, -g * np.eye(nz)]])
            self.matrices.append(sym(M))
            D = np.eye(M.shape[0]) if scales is None else np.diag(scales[len(self.matrices) - 1])
            constraints.append(sym(M) << -t * D)
        self.problem = cp.Problem(cp.Maximize(t), constraints)

    def solve(self, gamma: float, solver: str) -> SolveReport:
        """The SDP at γ (raises SynthesisError when the solver returns no point)."""
        self.gamma.value = gamma
        return solve(self.problem, solver, f"the H∞ controller LMIs at γ = {gamma:.6g}", fine=True)


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
    R, S = (0.5 * (V.value + V.value.T) for V in (level.R, level.S))
    n = R.shape[0]
    W, sig, Zt = np.linalg.svd(np.eye(n) - R @ S)
    M, N = W * np.sqrt(sig), Zt.T * np.sqrt(sig)
    K_vertices = []
    for v, hats in zip(level.verts, level.hats, strict=True):
        K = loop_shift(reconstruct_controller(v, R, S, M, N, tuple(h.value for h in hats)), v.D22)
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
    failed_levels: list[float] = field(default_factory=list)  # of the latest run

    def run(self, coords: Coordinates, start: float, suboptimality: float, gamma_max: float,
            rebalance: bool, scales: list[np.ndarray] | None) -> tuple[HinfResult | None, _Rebalance | None]:
        """:func:`lowest_certified_level` in ``coords`` (strictness ``scales``, :class:`_LevelProblem`):
        the lowest passing result, or with ``rebalance`` the first passing one whose R, S are further from
        balanced than cond REBALANCE_CONDITION, with the state transform that balances them and the scales
        there (else None): the levels below it are better searched there. ``failed_levels`` holds the
        levels of this run that did not pass."""
        self.failed_levels = []
        certified = self._certifier(coords, rebalance, scales)
        try:
            return (lowest_certified_level(certified, start, suboptimality, gamma_max, self.gamma_estimate),
                    None)
        except _Unbalanced as found:
            return found.result, found.rebalance

    def bisect(self, coords: Coordinates, floor: float, best: HinfResult, suboptimality: float,
               scales: list[np.ndarray] | None) -> HinfResult:
        """:func:`bisect_levels` in ``coords`` between the failing level ``floor`` and ``best``."""
        return bisect_levels(self._certifier(coords, False, scales), floor, best, suboptimality)

    def _certifier(self, coords: Coordinates, rebalance: bool, scales: list[np.ndarray] | None
                   ) -> Callable[[float], HinfResult | None]:
        """γ ↦ the certified result of the level SDP in ``coords``, or None (recorded as failed); with
        ``rebalance`` a passing level whose R, S call for other coordinates raises :class:`_Unbalanced`."""
        level = _LevelProblem([coords.apply(vc) for vc in self.cayleys], scales)

        def certified(gamma: float) -> HinfResult | None:
            result = self._level(level, coords, gamma)
            if result is None:
                self.failed_levels.append(gamma)
                return None
            T = balancing_transform(level.R.value, level.S.value) if rebalance else None
            if T is not None and np.linalg.cond(T) > REBALANCE_CONDITION:
                raise _Unbalanced(result, _Rebalance(T, _scales_in(level, T)))
            return result

        return certified

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


class _Unbalanced(Exception):  # a control-flow signal of _Search.run, never raised to users
    """A passing level of :meth:`_Search.run` whose R, S call for other coordinates."""

    def __init__(self, result: HinfResult, rebalance: _Rebalance) -> None:
        super().__init__()
        self.result, self.rebalance = result, rebalance


@dataclass
class _Rebalance:
    """Step 4's state transform x = T x̃ from a passing level, and step 5's strictness scales there."""

    T: np.ndarray
    scales: list[np.ndarray]


def _scales_in(level: _LevelProblem, T: np.ndarray) -> list[np.ndarray]:
    """|diag| of each vertex matrix of ``level`` at its solution, written in the coordinates x = T x̃
    (x̃-rows: T⁻¹ on the R-side block, Tᵀ on the S-side block, w and z unchanged), floored at 1e-9 of the
    largest entry."""
    n, T_inv = T.shape[0], np.linalg.inv(T)
    out = []
    for M in level.matrices:
        W = scipy.linalg.block_diag(T_inv, T.T, np.eye(M.shape[0] - 2 * n))
        d = np.abs(np.diag(W @ M.value @ W.T))
        out.append(np.maximum(d, 1e-9 * d.max()))
    return out


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
        raise SynthesisError(_failure(exc.category, str(exc), vertices, Ts, gamma_max),
                             category=exc.category) from None
    estimate = pre.estimate
    search = _Search(vertices, cayleys, Ts, solver, estimate.gamma if estimate.accurate else None,
                     list(pre.attempts))
    coords = pre.coordinates
    best, rebalance = search.run(coords, min(estimate.gamma, gamma_max), suboptimality, gamma_max, True, None)
    first_coords, first_best, interrupted = coords, best, rebalance is not None
    first_floor = max((g for g in search.failed_levels if best is not None and g < best.gamma), default=0.0)
    for round_ in range(MAX_REBALANCE):
        if rebalance is None:
            break
        coords = coords.transformed(rebalance.T)
        guess, accurate = estimate_in([coords.apply(vc) for vc in cayleys], gamma_max, solver, search)
        if accurate and (search.gamma_estimate is None or guess < search.gamma_estimate):
            search.gamma_estimate = guess
        start_again = search.gamma_estimate if search.gamma_estimate is not None else (guess or best.gamma)
        again, rebalance = search.run(coords, min(start_again, best.gamma), suboptimality, best.gamma,
                                      round_ + 1 < MAX_REBALANCE, rebalance.scales)
        best = again if again is not None and again.gamma < best.gamma else best
    if interrupted and best is first_best and first_floor > 0:  # no other coordinates did better
        best = search.bisect(first_coords, first_floor, best, suboptimality, None)
    if best is None:
        if infeasible_at(pre.vertices, gamma_max, solver):
            category = "infeasible"
            what = f"the H∞ LMIs are infeasible at γ ≤ {gamma_max:g} (proven by the eliminated conditions)"
        else:
            category = "accuracy"
            what = (f"no level up to γ = {gamma_max:g} gave a controller that passes the certificate "
                    f"({search.infeasible} levels infeasible, {len(search.no_point)} without a solution, "
                    f"{search.rejected} rejected by the re-check; estimate γ̂ = {estimate.gamma:.4g}, "
                    f"{estimate.report.status})")
        raise SynthesisError(_failure(category, what, vertices, Ts, gamma_max), category=category)
    best.report = SolveReport(best.report.solver, best.report.status, time.perf_counter() - start,
                              search.attempts)
    return best


def estimate_in(verts: list[VertexPlant], gamma_max: float, solver: str, search: _Search
                ) -> tuple[float | None, bool]:
    """Step 3 in other coordinates: (γ̂, whether the solve was accurate) — an inaccurate γ̂ only starts
    the search there — or (None, False) without a point (the SDP is recorded in ``search``)."""
    try:
        found = estimate(verts, gamma_max, solver)
    except SynthesisError:
        return None, False
    search.attempts += found.report.attempts
    return (found.gamma, found.accurate) if found.scales else (None, False)


def _failure(category: str, what: str, vertices: list[VertexPlant], Ts: float, gamma_max: float) -> str:
    """The one line of a SynthesisError: what failed, and what it means for the design. For one plant the
    independent Riccati synthesis (SB10DD, bisected) says whether any controller reaches ``gamma_max``."""
    if len(vertices) == 1:
        try:
            optimum = riccati_gamma(vertices[0], Ts, rel=1e-3)
        except ModelError:
            optimum = np.inf
        witness = (f"SLICOT SB10DD reaches γ = {optimum:.4g}, so the LMI solve failed numerically: rescale "
                   "the weights (signals near 1, time constants within a few decades) or try solver='SCS'"
                   if optimum <= gamma_max else
                   f"SLICOT SB10DD finds no controller with γ ≤ {min(gamma_max, 1e6):g} either: relax the "
                   "weights (lower the W_S bandwidth or gain, or the W_K penalty) or raise gamma_max")
        return f"{what}; {witness}"
    radius = max(np.max(np.abs(np.linalg.eigvals(v.A))) for v in vertices)
    hint = ("no vertex controllers with one common Lyapunov matrix reach it" if category == "infeasible" else
            "the solver could not reach the accuracy a certificate needs with one common Lyapunov matrix")
    return (f"{what}; {hint} (vertex poles up to |z| = {radius:.4g}): shrink the scheduling box, add "
            "breakpoints, relax the weights or raise gamma_max")
