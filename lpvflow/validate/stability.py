"""Lyapunov certificates of stability for discrete-time LPV systems x(k+1) = A(θ(k)) x(k).

Two LMI certificates, both solved with cvxpy (Clarabel, SCS as fallback) and then re-checked by
eigenvalues with the returned numbers (`check_common_lyapunov`, `check_rate_bounded`):

1. Quadratic stability, arbitrarily fast scheduling (θ anywhere in the box at every step). With
   A(θ) affine in θ, the frozen A's lie in the polytope co{A_i} of the box corners, and a common
   P with
       P ≻ 0,   A_iᵀ P A_i − P ≺ 0   for every vertex i
   proves V(x) = xᵀPx decreases for every A in the polytope (the condition is convex in A by a
   Schur complement; Boyd, El Ghaoui, Feron, Balakrishnan, "LMIs in System and Control Theory",
   SIAM 1994, §5.1).

2. Bounded rate of variation |θ_j(k+1) − θ_j(k)| ≤ r_j, with P(θ) = P_0 + Σ_j θ_j P_j and a slack
   matrix G (de Oliveira, Bernussou, Geromel, "A new discrete-time robust stability condition",
   Syst. Control Lett. 37, 1999, Thm 1, with parameter-dependent P):
       M(θ, θ⁺) = [[P(θ), A(θ)ᵀGᵀ], [G A(θ), G + Gᵀ − P(θ⁺)]] ⪰ δ I,   P(θ) ⪰ I.
   M ≻ 0 implies P(θ) − A(θ)ᵀ P(θ⁺) A(θ) ≻ 0 (as G + Gᵀ − P⁺ ⪯ GᵀP⁺⁻¹G). M is affine in the pair
   (θ, θ⁺), so imposing it at the vertices of the admissible set
       S = {(θ, θ⁺): θ, θ⁺ in the box, |θ⁺ − θ| ≤ r}
   suffices; S is the product over j of polygons {(a, b) ∈ [lo, hi]²: |b − a| ≤ r_j} (a hexagon
   when r_j < hi − lo), so its vertices are the products of the polygon corners.

Both are solved in balanced coordinates Ã = T⁻¹AT (scipy's matrix_balance of Σ|A_i|) and the
certificate is returned in the original ones: P = T⁻ᵀ P̃ T⁻¹, G = T⁻ᵀ G̃ T⁻¹. The quadratic certificate
is accepted by a rule relative to the scale of each block (Jacobi-scaled margin above a round-off
bound, :func:`quadratic_stability`); the rate-bounded re-check demands every block eigenvalue ≤ −ε, with
ε = ½ δ σ_min(T⁻¹)², the margin its LMI imposes.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cvxpy as cp
import numpy as np
from scipy.linalg import matrix_balance

from lpvflow.errors import ModelError

#: Margin δ of the rate-bounded LMI in the balanced coordinates (relative to the normalisation P̃ ⪰ I).
LMI_MARGIN = 1e-4
#: A quadratic certificate's Jacobi-scaled margin must exceed ROUNDOFF_FACTOR·m·ε·‖D⁻¹|N|D⁻¹‖₂
#: (:func:`scaled_margin`); the H∞ certificates of lpvflow.synth use the same rule.
ROUNDOFF_FACTOR = 1e3


@dataclass(frozen=True)
class LyapunovCheck:
    """Eigenvalue re-check of a certificate: `passed` iff every block's largest eigenvalue ≤ −eps."""

    passed: bool
    eps: float
    worst_eigenvalue: float
    block_eigenvalues: np.ndarray
    reason: str


@dataclass(frozen=True)
class MarginCheck:
    """Re-check of a common Lyapunov matrix by :func:`check_quadratic_certificate`: ``margins`` of the
    blocks [P, P − A_0ᵀPA_0, …] (:func:`scaled_margin`), ``passed`` iff every one is > 0."""

    passed: bool
    margins: np.ndarray
    worst_margin: float
    reason: str


@dataclass(frozen=True)
class StabilityCertificate:
    """Outcome of a stability LMI: certified or not, why, and the numbers that prove it.

    `P` is the common Lyapunov matrix (quadratic) or the list [P_0, P_1, …] of P(θ) (rate-bounded);
    `G` the slack matrix of the rate-bounded LMI; `check` the independent re-check (Jacobi-scaled
    margins for the quadratic certificate, eigenvalues for the rate-bounded one).
    """

    certified: bool
    kind: str
    reason: str
    P: np.ndarray | list[np.ndarray] | None = None
    G: np.ndarray | None = None
    check: LyapunovCheck | MarginCheck | None = None
    solver: str = ""


def check_common_lyapunov(A_vertices: Sequence[np.ndarray], P: np.ndarray, eps: float) -> LyapunovCheck:
    """Re-check A_iᵀ P A_i − P ⪯ −eps I at every vertex and P ⪰ eps I, by symmetric eigenvalues."""
    P = 0.5 * (P + P.T)
    blocks = [-P] + [A.T @ P @ A - P for A in A_vertices]
    largest = np.array([np.linalg.eigvalsh(0.5 * (M + M.T))[-1] for M in blocks])
    return _verdict(largest, eps, ["P"] + [f"vertex {i}" for i in range(len(A_vertices))])


def check_rate_bounded(
    A_of: Callable[[np.ndarray], np.ndarray],
    box: np.ndarray,
    rate: np.ndarray,
    P_terms: Sequence[np.ndarray],
    G: np.ndarray,
    eps: float,
) -> LyapunovCheck:
    """Re-check −M(θ, θ⁺) ⪯ −eps I and −P(θ) ⪯ −eps I at every vertex of S (module docstring)."""
    pairs = rate_bounded_vertices(box, rate)
    largest, names = [], []
    for k, (theta, theta_next) in enumerate(pairs):
        M = _slack_block(A_of(theta), _affine(P_terms, theta), _affine(P_terms, theta_next), G)
        largest.append(np.linalg.eigvalsh(-0.5 * (M + M.T))[-1])
        names.append(f"vertex pair {k}")
    for theta in _corners(box):
        Pt = _affine(P_terms, theta)
        largest.append(np.linalg.eigvalsh(-0.5 * (Pt + Pt.T))[-1])
        names.append(f"P at corner {theta.tolist()}")
    return _verdict(np.array(largest), eps, names)


def quadratic_stability(system: object, box: object = None) -> StabilityCertificate:
    """Common quadratic Lyapunov function over the scheduling polytope (arbitrarily fast scheduling).

    `system`: a list of vertex A matrices, a list of discrete StateSpace vertices, or an LPVSS (its
    `vertices(box)` are used; the basis must be affine in p). Refuses with the reason when a vertex
    is unstable or the LMI is infeasible; never passes without the re-check.

    Solved in balanced coordinates Ã_i = T⁻¹A_iT (module docstring) and in difference form: with
    E_i = Ã_i − I and s = max_i ‖E_i‖₂, the decrease condition Ã_iᵀPÃ_i − P ≺ 0 is
    L_i(P) = s·ÊᵢᵀPÊᵢ + ÊᵢᵀP + PÊᵢ ≺ 0 (Ê_i = E_i/s), whose terms are of the size of P even when every
    pole is within Ts·ω of z = 1. Two solves: (1) P ⪰ I, L_i(P) ⪯ 0, P ⪯ τI, minimal τ; (2) from the
    scales D_0 = |diag P|, D_i = |diag L_i(P)| of that solution, the P with the largest relative
    margin t ≤ 1: D_0^-½ P D_0^-½ ⪰ tI and D_i^-½ L_i(P) D_i^-½ ⪯ −tI.

    **Acceptance rule** (:func:`check_quadratic_certificate`, on the returned P in the original
    coordinates): every block N of [P, P − A_0ᵀPA_0, …] must be positive definite in Jacobi-scaled
    coordinates by more than a round-off bound, λ_min(D⁻¹ND⁻¹) > ROUNDOFF_FACTOR·m·ε·‖D⁻¹|N|D⁻¹‖₂
    (D² = |diag N|, m the size of N, ε the machine epsilon, |N| the sum of the absolute values of the
    terms N is formed from). A margin that only holds in absolute terms, e.g. −1e-12 on blocks of size
    1e4, is refused.
    """
    A_vertices = _vertex_matrices(system, box)
    unstable = _first_unstable(A_vertices)
    if unstable:
        return StabilityCertificate(False, "quadratic", unstable)
    T = _balancing(A_vertices)
    Ti = np.linalg.inv(T)
    n = T.shape[0]
    E = [Ti @ A @ T - np.eye(n) for A in A_vertices]
    s = max(np.linalg.norm(Ei, 2) for Ei in E)  # > 0: a vertex equal to I is not stable
    E = [Ei / s for Ei in E]
    P, tau = cp.Variable((n, n), symmetric=True), cp.Variable()
    decrease = [_sym(s * Ei.T @ P @ Ei + Ei.T @ P + P @ Ei) for Ei in E]
    constraints = [P >> np.eye(n), P << tau * np.eye(n)] + [L << 0 for L in decrease]
    solver, status = _solve(cp.Problem(cp.Minimize(tau), constraints))
    if P.value is None:
        return StabilityCertificate(
            False, "quadratic", f"no common Lyapunov matrix over the {len(A_vertices)} vertices "
            f"(solver {solver}: {status}); the system may still be stable for slow scheduling", solver=solver)
    roots = [1.0 / np.sqrt(_jacobi_scale(M.value)) for M in [P, *decrease]]
    t = cp.Variable()
    constraints = [_sym(cp.multiply(np.outer(roots[0], roots[0]), P)) >> t * np.eye(n), t <= 1]
    constraints += [_sym(cp.multiply(np.outer(r, r), L)) << -t * np.eye(n)
                    for r, L in zip(roots[1:], decrease, strict=True)]
    solver, status = _solve(cp.Problem(cp.Maximize(t), constraints))
    if P.value is None or t.value is None or t.value <= 0:
        return StabilityCertificate(
            False, "quadratic", f"no common Lyapunov matrix with a margin over the {len(A_vertices)} "
            f"vertices (solver {solver}: {status}); at best on the boundary of quadratic stability",
            solver=solver)
    P_original = Ti.T @ P.value @ Ti
    check = check_quadratic_certificate(A_vertices, P_original)
    return StabilityCertificate(check.passed, "quadratic", check.reason, P_original, None, check, solver)


def check_quadratic_certificate(A_vertices: Sequence[np.ndarray], P: np.ndarray) -> MarginCheck:
    """The acceptance rule of :func:`quadratic_stability` for a common Lyapunov matrix P of the vertices
    A_i: the blocks N_0 = P and N_i = P − A_iᵀPA_i, the latter formed as −(E_iᵀPE_i + E_iᵀP + PE_i)
    with E_i = A_i − I (no cancellation of O(1) terms when A_i is close to I), each judged by
    :func:`scaled_margin`; accepted iff every margin is > 0."""
    P = 0.5 * (P + P.T)
    n = P.shape[0]
    blocks = [(P, np.abs(P))]
    for A in A_vertices:
        Ei = np.asarray(A, dtype=float) - np.eye(n)
        N = -(Ei.T @ P @ Ei + Ei.T @ P + P @ Ei)
        magnitude = np.abs(Ei).T @ np.abs(P) @ np.abs(Ei) + np.abs(Ei).T @ np.abs(P) + np.abs(P) @ np.abs(Ei)
        blocks.append((N, magnitude))
    margins = np.array([scaled_margin(N, magnitude) for N, magnitude in blocks])
    names = ["P"] + [f"vertex {i}" for i in range(len(A_vertices))]
    worst = int(np.argmin(margins))
    if margins[worst] > 0:
        return MarginCheck(True, margins, float(margins[worst]), "")
    return MarginCheck(False, margins, float(margins[worst]),
                       f"re-check failed: {names[worst]} has Jacobi-scaled margin {margins[worst]:.3g} "
                       "(the smallest eigenvalue less the round-off bound must be > 0)")


def scaled_margin(N: np.ndarray, magnitude: np.ndarray) -> float:
    """λ_min(D⁻¹ N D⁻¹) − ROUNDOFF_FACTOR·m·ε·‖D⁻¹ magnitude D⁻¹‖₂ with D² = |diag N| (> 0: N is positive
    definite by more than round-off in forming it, ``magnitude`` being the sum of the absolute values of
    its terms); −inf for a block with non-finite entries."""
    N = 0.5 * (N + N.T)
    if not np.all(np.isfinite(N)):
        return -np.inf
    d = np.sqrt(np.maximum(np.abs(np.diag(N)), np.finfo(float).tiny))
    scaled = N / d[:, None] / d[None, :]
    size = np.linalg.norm(magnitude / d[:, None] / d[None, :], 2)
    bound = ROUNDOFF_FACTOR * len(N) * np.finfo(float).eps * size
    return float(np.linalg.eigvalsh(scaled)[0] - bound)


def _jacobi_scale(M: np.ndarray) -> np.ndarray:
    """|diag M| floored at 1e-9 of its largest entry (and above zero): the scale of a block's margin."""
    d = np.abs(np.diag(0.5 * (M + M.T)))
    return np.maximum(d, max(1e-9 * d.max(), np.finfo(float).tiny))


def rate_bounded_stability(
    system: object, box: object, rate: Sequence[float]
) -> StabilityCertificate:
    """Parameter-dependent Lyapunov certificate for |θ(k+1) − θ(k)| ≤ rate (module docstring, 2.).

    `system`: an LPVSS with a basis affine in p, or a callable θ ↦ A(θ) that is affine in θ (checked
    at the box corners). `box`: [[lo, hi], …] per scheduling signal (an LPVSS defaults to its range).
    """
    A_of, box = _affine_map(system, box)
    rate = np.asarray(rate, dtype=float).ravel()
    if rate.size != box.shape[0] or np.any(rate < 0):
        raise ModelError(f"rate needs {box.shape[0]} non-negative bound(s), got {rate.tolist()}")
    corners = _corners(box)
    unstable = _first_unstable([A_of(c) for c in corners], corners)
    if unstable:
        return StabilityCertificate(False, "rate-bounded", unstable)
    T = _balancing([A_of(c) for c in corners])
    Ti = np.linalg.inv(T)
    n, n_p = T.shape[0], box.shape[0]
    P_terms = [cp.Variable((n, n), symmetric=True) for _ in range(n_p + 1)]
    G = cp.Variable((n, n))
    t = cp.Variable()
    constraints = []
    for theta in corners:
        Pt = _affine(P_terms, theta)
        constraints += [Pt >> np.eye(n), Pt << t * np.eye(n)]
    for theta, theta_next in rate_bounded_vertices(box, rate):
        M = _slack_block(Ti @ A_of(theta) @ T, _affine(P_terms, theta), _affine(P_terms, theta_next), G)
        constraints.append(_sym(M) >> LMI_MARGIN * np.eye(2 * n))
    solver, status = _solve(cp.Problem(cp.Minimize(t), constraints))
    if G.value is None:
        return StabilityCertificate(
            False, "rate-bounded",
            f"no affine parameter-dependent Lyapunov matrix for rates {rate.tolist()} "
            f"(solver {solver}: {status})",
            solver=solver)
    P_original = [Ti.T @ Pj.value @ Ti for Pj in P_terms]
    G_original = Ti.T @ G.value @ Ti
    check = check_rate_bounded(A_of, box, rate, P_original, G_original, _guaranteed_margin(Ti))
    return StabilityCertificate(
        check.passed, "rate-bounded", check.reason, P_original, G_original, check, solver
    )


def rate_bounded_vertices(box: np.ndarray, rate: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Vertices (θ, θ⁺) of {θ, θ⁺ in the box, |θ⁺ − θ| ≤ rate}: products of per-signal polygons."""
    polygons = []
    for (lo, hi), r in zip(np.asarray(box, dtype=float), np.asarray(rate, dtype=float), strict=True):
        if r >= hi - lo:
            polygons.append([(lo, lo), (lo, hi), (hi, lo), (hi, hi)])
        else:
            polygons.append([(lo, lo), (lo, lo + r), (hi - r, hi), (hi, hi), (hi, hi - r), (lo + r, lo)])
    return [
        (np.array([v[0] for v in combo]), np.array([v[1] for v in combo]))
        for combo in itertools.product(*polygons)
    ]


def _slack_block(A: np.ndarray, P_now: object, P_next: object, G: object) -> object:
    """M = [[P(θ), AᵀGᵀ], [G A, G + Gᵀ − P(θ⁺)]] for numbers or cvxpy expressions."""
    if isinstance(G, np.ndarray):
        return np.block([[P_now, A.T @ G.T], [G @ A, G + G.T - P_next]])
    return cp.bmat([[P_now, A.T @ G.T], [G @ A, G + G.T - P_next]])


def _affine(terms: Sequence[object], theta: np.ndarray) -> object:
    """P(θ) = P_0 + Σ_j θ_j P_j."""
    out = terms[0]
    for value, term in zip(theta, terms[1:], strict=True):
        out = out + float(value) * term
    return out


def _sym(M: object) -> object:
    """Symmetric part, so cvxpy accepts an expression that is symmetric only mathematically."""
    return 0.5 * (M + M.T)


def _verdict(largest: np.ndarray, eps: float, names: list[str]) -> LyapunovCheck:
    worst = int(np.argmax(largest))
    if largest[worst] <= -eps:
        return LyapunovCheck(True, eps, float(largest[worst]), largest, "")
    return LyapunovCheck(
        False, eps, float(largest[worst]), largest,
        f"re-check failed: {names[worst]} has largest eigenvalue {largest[worst]:.3g} > -{eps:.3g}",
    )


def _solve(problem: cp.Problem) -> tuple[str, str]:
    """Solve with Clarabel, falling back to SCS when Clarabel fails; returns (solver, status). cvxpy's
    "Solution may be inaccurate" warning is not passed on: the status is returned, and every certificate
    built on the solution is re-checked in numpy (:func:`_verdict`)."""
    for solver in (cp.CLARABEL, cp.SCS):
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Solution may be inaccurate")
                problem.solve(solver=solver)
        except cp.error.SolverError:
            continue
        if problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            return solver, problem.status
        if problem.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
            for variable in problem.variables():
                variable.value = None
            return solver, problem.status
    for variable in problem.variables():
        variable.value = None
    return "none", str(problem.status)


def _balancing(A_vertices: Sequence[np.ndarray]) -> np.ndarray:
    """Diagonal similarity T that balances Σ|A_i| (powers of two, no permutation)."""
    _, T = matrix_balance(np.sum([np.abs(A) for A in A_vertices], axis=0), permute=False)
    return T


def _guaranteed_margin(T_inverse: np.ndarray) -> float:
    """½ δ σ_min(T⁻¹)²: what ⪯ −δI in balanced coordinates guarantees in the original ones."""
    return 0.5 * LMI_MARGIN * np.linalg.svd(T_inverse, compute_uv=False)[-1] ** 2


def _first_unstable(A_vertices: Sequence[np.ndarray], points: Sequence[np.ndarray] | None = None) -> str:
    """Reason naming the first vertex with spectral radius ≥ 1, or '' if all are stable."""
    for i, A in enumerate(A_vertices):
        radius = float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0
        if radius >= 1.0:
            where = f" (p = {np.asarray(points[i]).tolist()})" if points is not None else ""
            return f"vertex {i}{where} is unstable: spectral radius {radius:.4g}"
    return ""


def _vertex_matrices(system: object, box: object) -> list[np.ndarray]:
    """Vertex A matrices from a list of arrays, a list of discrete StateSpace, or an LPVSS."""
    if hasattr(system, "vertices") and hasattr(system, "frozen"):
        return [np.asarray(sys.A, dtype=float) for _, sys in system.vertices(box)]
    if isinstance(system, np.ndarray) and system.ndim == 3:
        system = list(system)
    if isinstance(system, Sequence) and len(system) > 0:
        mats = [np.asarray(getattr(v, "A", v), dtype=float) for v in system]
        shapes = {M.shape for M in mats}
        if len(shapes) != 1 or mats[0].ndim != 2 or mats[0].shape[0] != mats[0].shape[1]:
            raise ModelError(f"vertex A matrices must be square and of one size, got shapes {sorted(shapes)}")
        return mats
    raise ModelError(
        "quadratic_stability needs vertex A matrices, StateSpace vertices or an LPVSS, "
        f"got {type(system).__name__}"
    )


def _corners(box: np.ndarray) -> list[np.ndarray]:
    return [np.array(c) for c in itertools.product(*np.asarray(box, dtype=float))]


def _affine_map(system: object, box: object) -> tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]:
    """(θ ↦ A(θ), box) from an LPVSS or a callable; ModelError if A is not affine in θ over the box."""
    if hasattr(system, "matrices") and hasattr(system, "basis"):
        if not system.basis.is_affine:
            raise ModelError("rate-bounded certificates need a basis affine in p (affine or poly:1)")
        if box is None:
            if system.basis.p_min is None:
                raise ModelError("no scheduling range recorded; pass box=[[min, max], ...]")
            box = np.column_stack([system.basis.p_min, system.basis.p_max])
        A_of = lambda theta: np.asarray(system.matrices(theta)[0], dtype=float)  # noqa: E731
    elif callable(system):
        A_of = lambda theta: np.asarray(system(np.asarray(theta, dtype=float)), dtype=float)  # noqa: E731
    else:
        raise ModelError(
            f"rate_bounded_stability needs an LPVSS or a callable theta -> A, got {type(system).__name__}"
        )
    if box is None:
        raise ModelError("pass the scheduling box as [[min, max], ...] per scheduling signal")
    box = np.asarray(box, dtype=float).reshape(-1, 2)
    if np.any(box[:, 1] < box[:, 0]):
        raise ModelError(f"each box row must be [min, max], got {box.tolist()}")
    centre = box.mean(axis=1)
    A_centre = A_of(centre)
    for corner in _corners(box):
        midpoint = A_of(0.5 * (corner + centre))
        if not np.allclose(midpoint, 0.5 * (A_of(corner) + A_centre), rtol=1e-9, atol=1e-12):
            raise ModelError("A(theta) is not affine in theta over the box; use an affine basis")
    return A_of, box
