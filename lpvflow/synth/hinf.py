"""Discrete-time H∞ output-feedback synthesis by LMIs, LTI and polytopic, in python-control's idiom.

``hinfsyn(P, nmeas, ncon)`` takes one discrete ``control.StateSpace`` (an LTI design) or a sequence of
vertex ``StateSpace``s with the same partition (a polytopic design with one common Lyapunov matrix,
Apkarian, Gahinet & Becker 1995, Thm. 5.1 / Gahinet & Apkarian 1994, Thm. 4.3; thesis §6.3, notes_002).
Generalized plant at vertex i, inputs [w, u], outputs [z, y]:

    x⁺ = A_i x + B1_i w + B2 u,   z = C1_i x + D11_i w + D12 u,   y = C2 x + D21 w,

B2, C2, D12, D21 the same at every vertex and D22 = 0 (:func:`lpvflow.synth.plant.check_a3`), so the
vertex controllers interpolated with the plant's convex coordinates λ give a closed loop affine in λ.

**Why not the shift-form LMIs.** With Ts = 2–5 ms every pole sits within 1e-4…4e-2 of z = 1; the discrete
bounded-real LMI then carries its information in O(Ts) differences of O(‖P‖) blocks, and an interior-point
solver resolves them only to ~1e-8/Ts (``../shared/reference/synthesis_numerics.md``). Every LMI here
is therefore posed on the **bilinear (Cayley) image** of each vertex (:func:`cayley`), z = (1 + s)/(1 − s),

    A_c = (A − I)(I + A)⁻¹,  B_c = √2 (I + A)⁻¹B,  C_c = √2 C(I + A)⁻¹,  D_c = D − C(I + A)⁻¹B,

which preserves ‖·‖∞ and maps the discrete bounded-real inequality with Lyapunov matrix 𝒳 onto the
continuous one with the *same* 𝒳 (the two are exact images of each other; tested). The synthesis is one
straight chain:

1. **Coordinates.** Frequency normalisation s = ω₀s' (A_c/ω₀, B_c/√ω₀, C_c/√ω₀: the continuous LMIs are
   invariant under it with the same 𝒳), diagonal balancing of the mean |A_c|, diagonal scalings of u and
   y (unit columns of B2, rows of C2 — of D21 for a zero row of C2, a 2-DOF reference; w and z are not
   scaled per channel: that would change ‖T_zw‖∞),
   then state transforms x = T x̄ that balance R, S of interior points: a γ-minimisation (step 2) gives
   γ₀; the matrices of step 2 at f·γ₀ with the largest margin relative to their diagonals at the γ₀
   minimiser (slow and fast directions get margins in proportion to their size) give a strictly
   feasible, centred R, S, for f = 2 and then, in the new coordinates, f = 1.15
   (:data:`INTERIOR_FACTORS`; the γ-optimal pair itself is singular, RS − I loses rank, and balancing
   on it is unstable); R = LLᵀ, LᵀSL = VΣ²Vᵀ, T = LVΣ^(−1/2), so T⁻¹RT⁻ᵀ = TᵀST = Σ (Moore's balancing
   applied to R, S). Step 2 is solved again after each balancing. Controllers map y to u, so none of
   this changes the closed loop's transfer function.
2. **γ lower bound** by the eliminated continuous conditions (Gahinet & Apkarian 1994, Thm. 4.3), per
   vertex with its own null-space bases N_R,i of [B2_iᵀ D12_iᵀ] and N_S,i of [C2_i D21_i] (the Cayley
   images have vertex-dependent B2, C2; the conditions are per vertex, so that is exact):

       N_R,iᵀ [A_iR + RA_iᵀ   RC1_iᵀ   B1_i ;  C1_iR   −γI   D11_i ;  B1_iᵀ   D11_iᵀ   −γI] N_R,i ≺ 0,
       N_S,iᵀ [A_iᵀS + SA_i   SB1_i   C1_iᵀ ;  B1_iᵀS   −γI   D11_iᵀ ;  C1_i   D11_i   −γI] N_S,i ≺ 0,
       [R I; I S] ⪰ 0,

   minimise γ: γ_lower (no Lyapunov bound, no margin).
3. **Certified level.** The change-of-variables LMIs of Scherer, Gahinet & Chilali (1997, eq. (33)),
   per vertex with common R, S and vertex variables (Â_i, B̂_i, Ĉ_i, D̂_i),

       ⎡ He[A_iR + B2_iĈ_i   A_i + B2_iD̂_iC2_i ; Â_i   SA_i + B̂_iC2_i]   Ψ_i    Ω_iᵀ ⎤
       ⎢ ⋆                                                          −γI     Δ_iᵀ ⎥ ⪯ −t·I,
       ⎣ ⋆                                                          ⋆       −γI  ⎦
       Ψ_i = [B1_i + B2_iD̂_iD21_i; SB1_i + B̂_iD21_i],  Ω_i = [C1_iR + D12_iĈ_i   C1_i + D12_iD̂_iC2_i],
       Δ_i = D11_i + D12_iD̂_iD21_i,   [R I; I S] ⪰ t·I,  t ≤ 1,

   maximise t at γ_k = γ_lower·(1 + δ·2^k), k = 0, 1, …, until a level has t > 0 and its controller
   passes the certificate of step 5; then geometric bisection between that level and the one below it
   to a relative width δ (δ = ``suboptimality``): the lowest passing level is the certified γ. In the
   balanced coordinates R ≈ S ≈ Σ and every block is O(1), so t·I is a margin relative to block scale,
   and no bound on R, S is needed.
4. **Controller** per vertex (Scherer et al. 1997, eq. (35)): MNᵀ = I − RS by a balanced SVD,
   D_K = D̂, C_K = (Ĉ − D_KC2R)M⁻ᵀ, B_K = N⁻¹(B̂ − SB2D_K),
   A_K = N⁻¹(Â − NB_KC2R − SB2C_KMᵀ − S(A + B2D_KC2)R)M⁻ᵀ; it is designed for D22 = 0, while the Cayley
   image has D22_c = −C2(I + A)⁻¹B2, so K_c = K(I + D22_cK)⁻¹ (loop shifting: the same closed loop,
   state by state); then the frequency scaling is undone and the inverse Cayley map gives the discrete
   vertex controller. Closed-loop Lyapunov matrix 𝒳 = Π₂Π₁⁻¹, Π₁ = [R I; Mᵀ 0], Π₂ = [I S; 0 Nᵀ],
   returned in the original discrete coordinates.
5. **Certificate** (:func:`certificate_margin`): every vertex closed loop is rebuilt from the returned
   discrete plant and controller numbers, mapped by :func:`cayley`, and its bounded-real matrix with 𝒳
   must be negative definite, in the coordinates where 𝒳 = I and after Jacobi scaling, with a margin above
   the round-off bound (:func:`lpvflow.validate.stability.scaled_margin`); a level whose controller fails it
   does not pass.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import control
import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError
from lpvflow.synth.controller import LPVController, mix, series_input_filter
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant, check_a3
from lpvflow.synth.sdp import SolveReport, SynthesisError, solve
from lpvflow.validate.stability import scaled_margin

#: Relative γ steps of the certified-level search (step 3): γ_lower·(1 + suboptimality·2^k), k < this.
LEVEL_STEPS = 9
#: Levels, relative to the γ-minimisation before each, of the interior points whose R, S balance the
#: coordinates (step 1), in turn: a central point first (the unbalanced coordinates' solves are
#: inaccurate near the optimum), then one near the optimum, where R, S have its spread. Measured (certified
#: γ / reference: SB10DD for a two-mass augw example and ADIP 75.5°, the discrete-form common-Lyapunov
#: optimum for the dead-time tanks design's 2 vertices): (2.0,) → 1.20, 1.000, 1.005; (1.15,) → 1.003,
#: none up to 6γ_lower, 1.006; (2.0, 1.15) → 1.029, 0.998, 1.003. Clarabel at 1e-10 did not help: it
#: then fails outright on some of these SDPs.
INTERIOR_FACTORS = (2.0, 1.15)
def cayley(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, ...]:
    """Bilinear image (A_c, B_c, C_c, D_c) of a discrete system, z = (1 + s)/(1 − s) (module docstring)."""
    n = A.shape[0]
    M = np.linalg.inv(np.eye(n) + A)
    return (A - np.eye(n)) @ M, np.sqrt(2.0) * M @ B, np.sqrt(2.0) * C @ M, D - C @ M @ B


def inverse_cayley(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, ...]:
    """The discrete system whose :func:`cayley` image is (A, B, C, D)."""
    n = A.shape[0]
    M = np.linalg.inv(np.eye(n) - A)
    return (np.eye(n) + A) @ M, np.sqrt(2.0) * M @ B, np.sqrt(2.0) * C @ M, D + C @ M @ B


def closed_loop(v: VertexPlant, K: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """(𝒜, ℬ, 𝒞, 𝒟) of the vertex plant (D22 = 0) with u = K y, state [x; x_K]."""
    Ak, Bk, Ck, Dk = K
    A = np.block([[v.A + v.B2 @ Dk @ v.C2, v.B2 @ Ck], [Bk @ v.C2, Ak]])
    B = np.vstack([v.B1 + v.B2 @ Dk @ v.D21, Bk @ v.D21])
    C = np.hstack([v.C1 + v.D12 @ Dk @ v.C2, v.D12 @ Ck])
    return A, B, C, v.D11 + v.D12 @ Dk @ v.D21


def bounded_real_matrix(loop: tuple[np.ndarray, ...], X: np.ndarray, gamma: float) -> np.ndarray:
    """[𝒜ᵀ𝒳 + 𝒳𝒜  𝒳ℬ  𝒞ᵀ; ℬᵀ𝒳  −γI  𝒟ᵀ; 𝒞  𝒟  −γI] of a continuous loop: ≺ 0 ⟺ stable with ‖·‖∞ < γ
    certified by V = ξᵀ𝒳ξ (bounded-real lemma, Gahinet & Apkarian 1994, Lemma 2.1)."""
    A, B, C, D = loop
    nw, nz = B.shape[1], C.shape[0]
    return np.block([[A.T @ X + X @ A, X @ B, C.T],
                     [B.T @ X, -gamma * np.eye(nw), D.T],
                     [C, D, -gamma * np.eye(nz)]])


def certificate_margin(v: VertexPlant, K: tuple[np.ndarray, ...], F: np.ndarray, gamma: float) -> float:
    """Jacobi-scaled margin of the vertex certificate 𝒳 = FᵀF minus its round-off bound (> 0: accepted).

    The discrete closed loop of ``v`` and ``K`` is rebuilt from their numbers and mapped by :func:`cayley`
    (exact: the discrete bounded-real inequality with 𝒳 holds iff the continuous one holds for the image
    with the same 𝒳), then written in the coordinates ξ̃ = Fξ where 𝒳 becomes I (𝒜̃ = F𝒜F⁻¹, ℬ̃ = Fℬ,
    𝒞̃ = 𝒞F⁻¹: a congruence, so definiteness is unchanged, while the small and large directions of 𝒳 no
    longer share one floating-point scale). With M = :func:`bounded_real_matrix` there, M̃ = D⁻¹(−M)D⁻¹
    (D² = |diag M|) and the margin is :func:`lpvflow.validate.stability.scaled_margin` of −M with its own
    absolute values as the size of its terms: λ_min(M̃) − ROUNDOFF_FACTOR·m·ε·‖|M̃|‖₂.
    """
    A, B, C, D = cayley(*closed_loop(v, K))
    Fi = np.linalg.inv(F)
    M = bounded_real_matrix((F @ A @ Fi, F @ B, C @ Fi, D), np.eye(len(F)), gamma)
    return scaled_margin(-M, np.abs(M))


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
        gamma_lower: minimum of the eliminated LMIs (step 2): no controller of this class does better.
        K_vertices: discrete (Ak_i, Bk_i, Ck_i, Dk_i) from y to u.
        vertex_controllers: the same as ``control.StateSpace`` objects (dt = Ts).
        controller: one ``StateSpace`` for an LTI design, else a :class:`VertexController`; from
            :func:`synthesize`, the implementable :class:`LPVController` (W_B in series).
        plant: the :class:`GeneralizedPlant` of :func:`synthesize` (None from :func:`hinfsyn`).
        certificate: per-vertex margins of :func:`certificate_margin` (all > 0).
        lyapunov_factor: F with 𝒳 = FᵀF the common closed-loop Lyapunov matrix, state [x_plant; x_K],
            original discrete coordinates.
    """

    gamma: float
    gamma_lower: float
    K_vertices: list[tuple[np.ndarray, ...]]
    vertex_controllers: list[control.StateSpace]
    controller: control.StateSpace | VertexController
    certificate: list[float]
    lyapunov_factor: np.ndarray
    vertices: list[VertexPlant]
    Ts: float
    report: SolveReport
    plant: GeneralizedPlant | None = None


def _partition(P: control.StateSpace, nmeas: int, ncon: int) -> VertexPlant:
    if not isinstance(P, control.StateSpace):
        raise ModelError(f"hinfsyn needs control.StateSpace plants, got {type(P).__name__}")
    if not P.isdtime(strict=True):
        raise ModelError("hinfsyn is discrete-time: give a StateSpace with dt = Ts > 0")
    if not (0 < nmeas < P.noutputs and 0 < ncon < P.ninputs):
        raise ModelError(f"nmeas = {nmeas} and ncon = {ncon} must leave exogenous inputs and performance "
                         f"outputs (plant has {P.ninputs} inputs, {P.noutputs} outputs)")
    return VertexPlant.from_ss(P, nw=P.ninputs - ncon, nz=P.noutputs - nmeas)


def hinfsyn(P: control.StateSpace | Sequence[control.StateSpace], nmeas: int, ncon: int, *,
            suboptimality: float | None = None, gamma_max: float | None = None, solver: str = "CLARABEL",
            breakpoints: Sequence[float] | None = None, rate_bound: float | None = None):
    """H∞ controller for the discrete generalized plant ``P`` (one StateSpace: LTI; a sequence: vertices).

    As ``control.hinfsyn(P, nmeas, ncon)``: the last ``nmeas`` outputs are measured, the last ``ncon``
    inputs are controlled. The steps are those of the module docstring. With ``breakpoints`` (the values
    of one scheduling signal at which the plants of ``P`` are given, ascending), the design is the
    rate-bounded one of :mod:`lpvflow.synth.rate_bounded` instead — a parameter-dependent Lyapunov
    function, |p(k+1) − p(k)| ≤ ``rate_bound`` (None: any rate), the plant and the controller linear in p
    between breakpoints — and the result a :class:`lpvflow.synth.rate_bounded.ScheduledResult`
    (``.controller(p)`` the controller frozen at p).

    Args:
        suboptimality: δ of step 3: the certified γ is within a factor 1 + δ of the lowest level found
            to fail, which is ≥ γ_lower (default 2.5e-3; 1e-2 for the rate-bounded design, whose SDPs are
            larger).
        gamma_max: demand γ ≤ gamma_max (infeasible otherwise, with the reason; common-Lyapunov design).
        solver: the SDP solver, ``"CLARABEL"`` (default) or ``"SCS"``.
        breakpoints, rate_bound: the rate-bounded design (above).

    Raises:
        ModelError: a plant that is not discrete, partitions that differ, or B2, C2, D12, D21 not constant.
        SynthesisError: infeasible LMIs (with the reason) or a certificate that fails.
    """
    plants = [P] if isinstance(P, control.StateSpace) else list(P)
    if not plants:
        raise ModelError("hinfsyn needs at least one plant")
    vertices = [_partition(G, nmeas, ncon) for G in plants]
    if len({v.dims for v in vertices}) > 1 or len({float(G.dt) for G in plants}) > 1:
        raise ModelError("the vertex plants differ in size, partition or sampling time")
    check_a3(vertices)
    Ts = float(plants[0].dt)
    if breakpoints is not None:
        from lpvflow.synth.rate_bounded import synthesize_scheduled

        delta = 1e-2 if suboptimality is None else suboptimality
        return synthesize_scheduled(vertices, breakpoints, Ts, rate_bound=rate_bound, suboptimality=delta,
                                    solver=solver)
    if rate_bound is not None:
        raise ModelError("rate_bound needs breakpoints: the scheduling value of each plant in P")
    delta = 2.5e-3 if suboptimality is None else suboptimality
    return synthesize_vertices(vertices, Ts, delta, gamma_max, solver)


def synthesize(plant: GeneralizedPlant, solver: str = "CLARABEL", gamma_max: float | None = None,
               suboptimality: float = 2.5e-3) -> HinfResult:
    """:func:`hinfsyn` on the vertices of a mixed-sensitivity design (:mod:`lpvflow.synth.plant`); the
    result's ``controller`` is the implementable :class:`LPVController` from e to the plant input,
    interpolated with the polytope's convex coordinates, W_B in series when the design has one."""
    result = synthesize_vertices(plant.vertices, plant.Ts, suboptimality, gamma_max, solver)
    K = result.K_vertices
    if plant.input_filter is not None:
        K = [series_input_filter(k, plant.input_filter) for k in K]
    info = {"method": "common", "gamma": result.gamma, "gamma_lower": result.gamma_lower,
            "solver": result.report.solver, "status": result.report.status,
            "solve_seconds": result.report.seconds, "polytope": plant.polytope.kind}
    stacks = [np.array([k[m] for k in K]) for m in range(4)]
    result.plant = plant
    result.controller = LPVController(*stacks, plant.polytope, plant.basis, plant.Ts, info=info,
                                      structure=plant.structure)
    return result


# ------------------------------------------------------------------------------------ coordinates
@dataclass
class _Coordinates:
    """x = T x̄, s = ω₀s', u = D_u ū, y = D_y ȳ of step 1, applied to the Cayley image of every vertex
    (D_u, D_y diagonal: every column of B2 and row of C2 of unit norm at the first vertex)."""

    T: np.ndarray
    omega: float
    du: np.ndarray
    dy: np.ndarray

    def apply(self, vc: VertexPlant) -> VertexPlant:
        Ti, r, du, dy = np.linalg.inv(self.T), np.sqrt(self.omega), self.du, self.dy
        return VertexPlant(Ti @ vc.A @ self.T / self.omega, Ti @ vc.B1 / r, Ti @ vc.B2 * du / r,
                           vc.C1 @ self.T / r, (vc.C2 @ self.T / r) / dy[:, None], vc.D11, vc.D12 * du,
                           vc.D21 / dy[:, None], vc.D22 * du / dy[:, None])

    def controller(self, K: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        """The continuous controller from y to u of one designed from ȳ to ū in s' (same state)."""
        Ak, Bk, Ck, Dk = K
        r, du, dy = np.sqrt(self.omega), self.du, self.dy
        return self.omega * Ak, r * Bk / dy[None, :], r * du[:, None] * Ck, du[:, None] * Dk / dy[None, :]


def _cayley_vertex(v: VertexPlant) -> VertexPlant:
    nw, nz = v.dims[1], v.dims[3]
    B, C = np.hstack([v.B1, v.B2]), np.vstack([v.C1, v.C2])
    D = np.block([[v.D11, v.D12], [v.D21, v.D22]])
    Ac, Bc, Cc, Dc = cayley(v.A, B, C, D)
    return VertexPlant(Ac, Bc[:, :nw], Bc[:, nw:], Cc[:nz], Cc[nz:], Dc[:nz, :nw], Dc[:nz, nw:],
                       Dc[nz:, :nw], Dc[nz:, nw:])


def _lyapunov_balancing(R: np.ndarray, S: np.ndarray) -> np.ndarray:
    """T with T⁻¹RT⁻ᵀ = TᵀST = Σ (step 1); R = LLᵀ by its eigenvalues (clipped at 1e-12 of the largest:
    the first solve is only a guide to scaling, not a certificate)."""
    r, U = np.linalg.eigh(0.5 * (R + R.T))
    L = U * np.sqrt(np.clip(r, 1e-12 * r[-1], None))[None, :]
    w, V = np.linalg.eigh(L.T @ (0.5 * (S + S.T)) @ L)
    return L @ V / np.clip(w, 1e-12 * w[-1], None)[None, :] ** 0.25


# ------------------------------------------------------------------------------------------- LMIs
def _eliminated(verts: list[VertexPlant], gamma: cp.Expression, R: cp.Variable, S: cp.Variable
                ) -> list[cp.Expression]:
    """The matrices of step 2: [R I; I S] (must be ⪰ 0), then per vertex the two projected LMIs (⪯ 0)."""
    n = R.shape[0]
    out = [cp.bmat([[R, np.eye(n)], [np.eye(n), S]])]
    for v in verts:
        nw, nz = v.dims[1], v.dims[3]
        NR = scipy.linalg.block_diag(scipy.linalg.null_space(np.hstack([v.B2.T, v.D12.T])), np.eye(nw))
        NS = scipy.linalg.block_diag(scipy.linalg.null_space(np.hstack([v.C2, v.D21])), np.eye(nz))
        MR = cp.bmat([[v.A @ R + R @ v.A.T, R @ v.C1.T, v.B1],
                      [v.C1 @ R, -gamma * np.eye(nz), v.D11],
                      [v.B1.T, v.D11.T, -gamma * np.eye(nw)]])
        MS = cp.bmat([[v.A.T @ S + S @ v.A, S @ v.B1, v.C1.T],
                      [v.B1.T @ S, -gamma * np.eye(nw), v.D11.T],
                      [v.C1, v.D11, -gamma * np.eye(nz)]])
        out += [_sym(NR.T @ MR @ NR), _sym(NS.T @ MS @ NS)]
    return out


def _strict(matrices: list[cp.Expression], t: cp.Expression | float, scales: list[np.ndarray] | None
            ) -> list[cp.Constraint]:
    """matrices[0] ⪰ t·D_0, matrices[k] ⪯ −t·D_k (k ≥ 1), D_k = diag(scales[k]) (identity if None)."""
    D = [np.diag(d) for d in scales] if scales is not None else [np.eye(M.shape[0]) for M in matrices]
    return [matrices[0] >> t * D[0]] + [M << -t * Dk for M, Dk in zip(matrices[1:], D[1:], strict=True)]


def _jacobi_scales(matrices: list[cp.Expression]) -> list[np.ndarray]:
    """|diag M| of each matrix at the variables' current values, floored at 1e-9 of its largest entry:
    the scale a margin is measured against (step 3)."""
    out = []
    for M in matrices:
        d = np.abs(np.diag(np.asarray(M.value, dtype=float)))
        out.append(np.maximum(d, 1e-9 * max(d.max(), 1e-300)))
    return out


def _sym(M: cp.Expression) -> cp.Expression:
    return 0.5 * (M + M.T)


def _gamma_lower(verts: list[VertexPlant], gamma_max: float | None, solver: str
                 ) -> tuple[float, list[np.ndarray], SolveReport]:
    """γ_lower of step 2 and the Jacobi scales of every matrix at its minimiser."""
    n = verts[0].dims[0]
    g = cp.Variable()
    R, S = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True)
    matrices = _eliminated(verts, g, R, S)
    constraints = _strict(matrices, 0.0, None)
    if gamma_max is not None:
        constraints.append(g <= gamma_max)
    what = f"the eliminated H∞ LMIs at {len(verts)} vertices" + (
        f" with γ ≤ {gamma_max:g}" if gamma_max is not None else "")
    report = solve(cp.Problem(cp.Minimize(g), constraints), solver, what)
    return float(g.value), _jacobi_scales(matrices), report


def _interior_point(verts: list[VertexPlant], scales: list[np.ndarray], gamma: float, solver: str
                    ) -> tuple[np.ndarray, np.ndarray, SolveReport]:
    """R, S of step 1's interior point: the matrices of step 2 at γ with the largest margin relative to
    their scale, [R I; I S] ⪰ t·D₀, every projected LMI ⪯ −t·D_k, t ≤ 1 (D_k = diag(scales[k]))."""
    n = verts[0].dims[0]
    R, S, t = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True), cp.Variable()
    constraints = [*_strict(_eliminated(verts, gamma, R, S), t, scales), t <= 1]
    report = solve(cp.Problem(cp.Maximize(t), constraints), solver,
                   f"the eliminated H∞ LMIs at γ = {gamma:.6g}")
    return 0.5 * (R.value + R.value.T), 0.5 * (S.value + S.value.T), report


class _LevelProblem:
    """Step 3 at a γ given as a cvxpy Parameter (compiled once, solved at each level)."""

    def __init__(self, verts: list[VertexPlant]) -> None:
        n = verts[0].dims[0]
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
            constraints.append(_sym(M) << -t * np.eye(M.shape[0]))
        self.problem = cp.Problem(cp.Maximize(t), constraints)

    def margin(self, gamma: float, solver: str) -> tuple[float, SolveReport | None]:
        """(t, report) at γ; t = −inf when no solver returned a point."""
        self.gamma.value = gamma
        try:
            report = solve(self.problem, solver, f"the H∞ controller LMIs at γ = {gamma:.6g}")
        except SynthesisError:
            return -np.inf, None
        return float(self.t.value), report


def _controller(v: VertexPlant, R: np.ndarray, S: np.ndarray, M: np.ndarray, N: np.ndarray,
                hats: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """Step 4's reconstruction (D22 = 0) of the continuous vertex controller."""
    Ah, Bh, Ch, Dh = hats
    Dk = Dh
    Ck = np.linalg.solve(M, (Ch - Dk @ v.C2 @ R).T).T
    Bk = np.linalg.solve(N, Bh - S @ v.B2 @ Dk)
    core = Ah - N @ Bk @ v.C2 @ R - S @ v.B2 @ Ck @ M.T - S @ (v.A + v.B2 @ Dk @ v.C2) @ R
    Ak = np.linalg.solve(N, np.linalg.solve(M, core.T).T)
    return Ak, Bk, Ck, Dk


def _loop_shift(K: tuple[np.ndarray, ...], D22: np.ndarray) -> tuple[np.ndarray, ...]:
    """K(I + D22 K)⁻¹ in state space (same controller state): the loop of the D22 ≠ 0 plant."""
    Ak, Bk, Ck, Dk = K
    E = np.linalg.inv(np.eye(Dk.shape[0]) + Dk @ D22)
    C, D = E @ Ck, E @ Dk
    return Ak - Bk @ D22 @ C, Bk - Bk @ D22 @ D, C, D


def _lyapunov(R: np.ndarray, S: np.ndarray, M: np.ndarray, N: np.ndarray) -> np.ndarray:
    n = R.shape[0]
    Pi1 = np.block([[R, np.eye(n)], [M.T, np.zeros((n, n))]])
    Pi2 = np.block([[np.eye(n), S], [np.zeros((n, n)), N.T]])
    X = np.linalg.solve(Pi1.T, Pi2.T).T
    return 0.5 * (X + X.T)


def balanced_coordinates(cayleys: list[VertexPlant], gamma_max: float | None, solver: str
                         ) -> tuple[_Coordinates, list[VertexPlant], float, list]:
    """Step 1 on the Cayley images of the vertices: the coordinates, the vertices in them, the γ lower
    bound of step 2 there, and the solver attempts made."""
    omega = max(float(np.linalg.norm(vc.A, 2)) for vc in cayleys)
    _, (s, _) = scipy.linalg.matrix_balance(np.mean([np.abs(vc.A) for vc in cayleys], axis=0) + 1e-300,
                                            permute=False, separate=True)
    first = _Coordinates(np.diag(s), omega, np.ones(cayleys[0].dims[2]), np.ones(cayleys[0].dims[4]))
    v0 = first.apply(cayleys[0])
    du = 1.0 / np.maximum(np.linalg.norm(v0.B2, axis=0), 1e-300)
    # a measured channel with no state in it (the reference of a 2-DOF loop) is scaled by its D21 row
    dy = np.linalg.norm(v0.C2, axis=1)
    dy = np.maximum(np.where(dy > 0, dy, np.linalg.norm(v0.D21, axis=1)), 1e-300)
    coords = _Coordinates(np.diag(s), omega, du, dy)
    verts = [coords.apply(vc) for vc in cayleys]
    gamma_lower, scales, report = _gamma_lower(verts, gamma_max, solver)
    attempts = list(report.attempts)
    for factor in INTERIOR_FACTORS:
        R, S, report = _interior_point(verts, scales, factor * gamma_lower, solver)
        attempts += report.attempts
        coords = _Coordinates(coords.T @ _lyapunov_balancing(R, S), omega, du, dy)
        verts = [coords.apply(vc) for vc in cayleys]
        gamma_lower, scales, report = _gamma_lower(verts, gamma_max, solver)
        attempts += report.attempts
    return coords, verts, gamma_lower, attempts


def synthesize_vertices(vertices: list[VertexPlant], Ts: float, suboptimality: float = 2.5e-3,
                        gamma_max: float | None = None, solver: str = "CLARABEL") -> HinfResult:
    """Steps 1–5 of the module docstring on partitioned discrete vertex plants (checked by the caller)."""
    if not suboptimality > 0:
        raise ModelError(f"suboptimality must be positive, got {suboptimality!r}")
    start = time.perf_counter()
    cayleys = [_cayley_vertex(v) for v in vertices]
    try:
        coords, verts, gamma_lower, attempts = balanced_coordinates(cayleys, gamma_max, solver)
    except SynthesisError as exc:
        hint = _infeasibility_hint(vertices, gamma_max)
        raise SynthesisError(f"{exc}: {hint}", category=exc.category) from None
    level = _LevelProblem(verts)

    def certified(gamma: float) -> HinfResult | None:
        t, level_report = level.margin(gamma, solver)
        attempts.extend(level_report.attempts if level_report else [])
        if not np.isfinite(t):  # no point returned; a point with t ≤ 0 is still judged by the certificate
            return None
        try:
            result = _reconstruct(vertices, verts, level, coords, gamma, gamma_lower, Ts)
        except np.linalg.LinAlgError:  # 𝒳 or MNᵀ = I − RS singular in floating point: not certified
            return None
        if min(result.certificate) <= 0:
            return None
        result.report = level_report
        return result

    best = lowest_certified_level(certified, gamma_lower, suboptimality, gamma_max)
    if best is None:
        top = gamma_lower * (1 + suboptimality * 2 ** (LEVEL_STEPS - 1))
        top = top if gamma_max is None else min(top, gamma_max * (1 + suboptimality))
        raise SynthesisError(f"no certified H∞ controller up to γ = {top:.4g} (γ lower bound "
                             f"{gamma_lower:.4g}): {_infeasibility_hint(vertices, gamma_max)}", category="accuracy")
    best.report = SolveReport(solver, best.report.status, time.perf_counter() - start, attempts)
    return best


def lowest_certified_level(certified: Callable[[float], HinfResult | None], gamma_lower: float,
                           suboptimality: float, gamma_max: float | None):
    """Step 3's search: levels γ_lower·(1 + δ·2^k), k < LEVEL_STEPS (not above gamma_max), until
    ``certified`` returns a result, then geometric bisection between that level and the one below it to a
    relative width δ; the result at the lowest passing level, or None when no level passed."""
    lo, best = gamma_lower, None
    for k in range(LEVEL_STEPS):
        gamma = gamma_lower * (1.0 + suboptimality * 2**k)
        if gamma_max is not None and gamma > gamma_max * (1 + suboptimality):
            break
        best = certified(gamma)
        if best is not None:
            break
        lo = gamma
    if best is None:
        return None
    while best.gamma / lo > 1 + suboptimality:
        mid = float(np.sqrt(lo * best.gamma))
        better = certified(mid)
        lo, best = (lo, better) if better is not None else (mid, best)
    return best


def _reconstruct(vertices: list[VertexPlant], verts: list[VertexPlant], level: _LevelProblem,
                 coords: _Coordinates, gamma: float, gamma_lower: float, Ts: float) -> HinfResult:
    """Step 4 and the certificate of step 5, in the original discrete coordinates."""
    R, S = (0.5 * (V.value + V.value.T) for V in (level.R, level.S))
    n = R.shape[0]
    W, sig, Zt = np.linalg.svd(np.eye(n) - R @ S)
    M, N = W * np.sqrt(sig), Zt.T * np.sqrt(sig)
    K_vertices = []
    for v, hats in zip(verts, level.hats, strict=True):
        K = _loop_shift(_controller(v, R, S, M, N, tuple(h.value for h in hats)), v.D22)
        K_vertices.append(inverse_cayley(*coords.controller(K)))
    back = scipy.linalg.block_diag(np.linalg.inv(coords.T), np.eye(n))
    F = np.linalg.cholesky(_lyapunov(R, S, M, N)).T @ back  # 𝒳 = FᵀF in the original coordinates
    certificate = [certificate_margin(v, K, F, gamma) for v, K in zip(vertices, K_vertices, strict=True)]
    ss = [control.ss(*K, Ts) for K in K_vertices]
    controller = ss[0] if len(ss) == 1 else VertexController(K_vertices, Ts)
    return HinfResult(gamma, gamma_lower, K_vertices, ss, controller, certificate, F, vertices, Ts,
                      SolveReport("", "", 0.0))


def _infeasibility_hint(vertices: list[VertexPlant], gamma_max: float | None) -> str:
    """Why the LMIs may be infeasible, in terms of the plant (the LMIs are sufficient conditions: what
    is excluded is a controller with one common Lyapunov matrix, not every controller)."""
    radius = max(np.max(np.abs(np.linalg.eigvals(v.A))) for v in vertices)
    unstable = f"the generalized plant has vertex poles up to |z| = {radius:.4g}" + (
        " (unstable)" if radius >= 1 else "")
    if gamma_max is not None:
        return (f"no controller reaches γ ≤ {gamma_max:g}; {unstable}: lower the W_S bandwidth/gain or the "
                "W_K penalty, or drop gamma_max")
    return (f"no vertex controllers with a common Lyapunov matrix stabilize all vertices; {unstable}: "
            "shrink the scheduling box")
