"""Balanced truncation of a polytopic LPVSS with generalized (common) Gramians from LMIs.

On the polytope of the model, conv{(A_v, B_v, C_v)} with A_v = Σ_l ψ_l(v) A_l at the vertices v of
the ψ-box, find P, Q ≻ 0 with (Wood, Goddard & Glover, CDC 1996; Beck, Doyle & Glover, IEEE TAC 1996)

    A_v P A_vᵀ − P + B_v B_vᵀ ≼ 0,     A_vᵀ Q A_v − Q + C_vᵀ C_v ≼ 0     for every vertex v.

For P ≻ 0 each is equivalent to [[−P, AP, B], [PAᵀ, −P, 0], [Bᵀ, 0, −I]] ≼ 0 (Schur complement),
which is affine in (A, B), so the vertices cover every convex combination. Minimise trace(P) and
trace(Q) (two SDPs, cvxpy + Clarabel), after a quadratic-stability certificate Y (A_vYA_vᵀ − Y ≼ −I)
that is also used to remove the solver's round-off violation exactly (see :func:`_gramian`). Balance with
P = LLᵀ, LᵀQL = WΣ²Wᵀ, T = LWΣ^{−1/2}: then T⁻¹PT⁻ᵀ = TᵀQT = Σ = diag(σ_1 ≥ … ≥ σ_nx). Keep the
first n balanced states. Because P and Q satisfy the inequalities for every (A, B, C) the scheduling
can take at every sample, the time-varying bound of Sandberg & Rantzer (IEEE TAC 49(2), 2004,
Thm. 1) applies to every scheduling trajectory in the box:

    ‖y − ŷ‖_ℓ2 ≤ 2 Σ_{k>n} σ_k ‖u‖_ℓ2      (zero initial states; D is kept, so it cancels).

A model without a common Lyapunov matrix (not quadratically stable on the box, e.g. an unstable
identified model) is refused; reduce it with :func:`lpvflow.identify.reduce.reduce` instead.
The box is the basis's recorded scheduling range (affine bases), a ``box`` in p, or a ``psi_box``
bounding ψ_1 … ψ_{nψ−1} for bases that are not affine in p (conservative).
"""

from __future__ import annotations

import itertools
import warnings

import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError
from lpvflow.identify.order_selection import ENERGY, select_order
from lpvflow.models import LPVSS

#: Relative positive-definiteness floor added to each Gramian (keeps unreachable/unobservable states).
FLOOR = 1e-9
#: The least-trace Gramian is singular in unreachable (unobservable) directions, so its small eigenvalues,
#: and the σ of such states, are the solver's tolerance: at Clarabel's default gap tolerances (1e-8) a
#: 6-state model with 2 unreachable states left 2Σσ = 2.5e-3·σ₁ for them (Clarabel 0.11.1), at these
#: 6.8e-4·σ₁ (tests/test_balanced.py, seed 6).
CLARABEL_SETTINGS = {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "equilibrate_enable": False, "max_iter": 600,
                     "iterative_refinement_max_iter": 50, "iterative_refinement_reltol": 1e-16,
                     "iterative_refinement_abstol": 1e-16}

def scheduling_vertices(ss: LPVSS, box: np.ndarray | None = None, psi_box: np.ndarray | None = None
                        ) -> np.ndarray:
    """ψ at the vertices of the scheduling polytope, shape (n_vertices, nψ), ψ_0 = 1."""
    if psi_box is not None:
        psi_box = np.asarray(psi_box, dtype=float)
        if psi_box.shape != (ss.basis.n_psi - 1, 2) or np.any(psi_box[:, 0] > psi_box[:, 1]):
            raise ModelError(f"psi_box must be ({ss.basis.n_psi - 1}, 2) rows [min, max] for ψ_1 … ψ_nψ-1")
        corners = np.array(list(itertools.product(*psi_box)))
        return np.hstack([np.ones((len(corners), 1)), corners])
    if not ss.basis.is_affine:
        raise ModelError(
            f"the {ss.basis.kind} basis (degree {ss.basis.degree}) is not affine in p: pass psi_box, "
            "bounds on each basis function, for balanced truncation"
        )
    if box is None:
        if ss.basis.p_min is None:
            raise ModelError("no scheduling range recorded in the basis; pass box=[[min, max], ...]")
        box = np.column_stack([ss.basis.p_min, ss.basis.p_max])
    box = np.asarray(box, dtype=float)
    if box.shape != (ss.basis.n_p, 2) or np.any(box[:, 0] > box[:, 1]):
        raise ModelError(f"box must be {ss.basis.n_p} rows [min, max], one per scheduling signal")
    corners = np.array(list(itertools.product(*box)))
    return ss.basis.eval(corners, check_range=False)


def _solve(problem: cp.Problem, what: str) -> None:
    """Solve with Clarabel at duality-gap tolerances 1e-12 (:data:`CLARABEL_SETTINGS`); "optimal_inaccurate"
    is accepted because every solution is verified after."""
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Solution may be inaccurate")
            problem.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
        status = problem.status
    except cp.SolverError:
        status = "solver_error"
    if status not in ("optimal", "optimal_inaccurate"):
        raise ModelError(
            f"no {what} exists on the scheduling box (LMI status {status}): the model is not "
            "quadratically stable there; use reduce(method='ho-kalman') for unstable models"
        )


def _lyapunov_residual(A: list[np.ndarray], X: np.ndarray, B: list[np.ndarray] | None = None) -> float:
    """max_v λ_max(A_v X A_vᵀ − X [+ B_v B_vᵀ])."""
    return max(
        np.linalg.eigvalsh(A_v @ X @ A_v.T - X + (0 if B is None else B[v] @ B[v].T)).max()
        for v, A_v in enumerate(A)
    )


def _stability_certificate(A: list[np.ndarray]) -> np.ndarray:
    """Y ⪰ I with A_v Y A_vᵀ − Y ≼ −I at every vertex: exists iff the polytope is quadratically stable."""
    nx = A[0].shape[0]
    Y = cp.Variable((nx, nx), symmetric=True)
    constraints = [Y >> np.eye(nx)] + [A_v @ Y @ A_v.T - Y << -np.eye(nx) for A_v in A]
    _solve(cp.Problem(cp.Minimize(cp.trace(Y)), constraints), "common Lyapunov matrix")
    Y = (Y.value + Y.value.T) / 2
    if _lyapunov_residual(A, Y) >= 0 or np.linalg.eigvalsh(Y).min() <= 0:
        raise ModelError("the model is at the edge of quadratic stability on the box: shrink the box "
                         "or use reduce(method='ho-kalman')")
    return Y


def _gramian(A: list[np.ndarray], B: list[np.ndarray], Y: np.ndarray) -> np.ndarray:
    """Least-trace X ≻ 0 with A_v X A_vᵀ − X + B_vB_vᵀ ≼ 0 at every vertex.

    The solver's small violation r (≈ its tolerance times ‖X‖) is removed exactly: with
    A_v Y A_vᵀ − Y ≼ −μI, X + δY with δ = r/μ satisfies the inequality; a further FLOOR·‖X‖/‖Y‖ · Y
    makes X definite.
    """
    nx = A[0].shape[0]
    X = cp.Variable((nx, nx), symmetric=True)
    constraints = [A_v @ X @ A_v.T - X + B_v @ B_v.T << 0 for A_v, B_v in zip(A, B, strict=True)]
    _solve(cp.Problem(cp.Minimize(cp.trace(X)), [*constraints, X >> 0]), "generalized Gramian")
    X = (X.value + X.value.T) / 2
    mu = -_lyapunov_residual(A, Y)
    violation = max(_lyapunov_residual(A, X, B), 0.0)
    X = X + (1.01 * violation / mu + FLOOR * np.linalg.norm(X, 2) / np.linalg.norm(Y, 2)) * Y
    if _lyapunov_residual(A, X, B) > 0:
        raise ModelError("could not make the generalized Gramian satisfy its inequality; rescale the model")
    return X


def balanced_truncation(
    ss: LPVSS, order: int | None = None, tol: float = 1e-9, energy: float = ENERGY,
    box: np.ndarray | None = None, psi_box: np.ndarray | None = None,
) -> LPVSS:
    """Generalized-Gramian balanced truncation (module docstring) with the a-priori ℓ2 error bound.

    Args:
        ss: a quadratically stable affine LPVSS (its K, if any, is projected like B but does not
            enter the Gramians or the bound).
        order: the reduced order; None selects it from σ by
            :func:`lpvflow.identify.order_selection.select_order`.
        tol, energy: as in :func:`lpvflow.identify.reduce.reduce`.
        box, psi_box: the scheduling region (see :func:`scheduling_vertices`).

    Returns:
        The reduced LPVSS; ``.reduction`` holds σ, the order and ``"error_bound"`` = 2 Σ_{k>n} σ_k,
        the bound on the induced ℓ2 gain of the error for any scheduling in the box.
    """
    if order is not None and (int(order) != order or not 1 <= order <= ss.nx):
        raise ModelError(f"order must be a whole number in [1, {ss.nx}], got {order!r}")
    psi = scheduling_vertices(ss, box, psi_box)
    A = list(np.tensordot(psi, ss.A, axes=1))
    B = list(np.tensordot(psi, ss.B, axes=1))
    C = list(np.tensordot(psi, ss.C, axes=1))
    Y = _stability_certificate(A)
    P = _gramian(A, B, Y)
    Q = _gramian([A_v.T for A_v in A], [C_v.T for C_v in C], np.linalg.inv(Y))
    L = scipy.linalg.cholesky(P, lower=True)
    sigma2, W = scipy.linalg.eigh(L.T @ Q @ L)
    sigma2, W = sigma2[::-1], W[:, ::-1]
    sigma = np.sqrt(np.maximum(sigma2, 0))
    selection = select_order(sigma, tol, energy)
    n = selection["order"] if order is None else int(order)
    T = L @ W / np.sqrt(sigma)
    T_inv = (np.sqrt(sigma)[:, None] * W.T) @ scipy.linalg.solve_triangular(L, np.eye(ss.nx), lower=True)
    T, T_left = T[:, :n], T_inv[:n]
    record = {
        "method": "balanced",
        "singular_values": sigma.tolist(),
        "order": n,
        "original_order": ss.nx,
        "error_bound": float(2 * sigma[n:].sum()),
        "n_vertices": len(psi),
        "selection": {k: v for k, v in selection.items() if k != "order"},
    }
    return LPVSS(
        T_left @ ss.A @ T, T_left @ ss.B, ss.C @ T, ss.D.copy(), ss.basis, ss.Ts,
        K=None if ss.K is None else T_left @ ss.K, u_names=list(ss.u_names), y_names=list(ss.y_names),
        p_names=list(ss.p_names), io=ss.io, reduction=record,
    )
