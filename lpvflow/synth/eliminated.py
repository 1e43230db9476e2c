"""The eliminated H∞ conditions: an estimate of the optimal level, and coordinates balanced on it.

Steps 2–4 of :mod:`lpvflow.synth.hinf` (the method is stated there), shared with the rate-bounded design
(:mod:`lpvflow.synth.rate_bounded`), which balances its coordinates on the breakpoint nearest the centre
and starts its level search at the largest frozen estimate (its floor when every one is accurate). The
eliminated conditions of Gahinet & Apkarian (1994, Thm. 4.3) are posed on the Cayley image of every vertex
(:mod:`lpvflow.synth.bilinear`).
Every preconditioning step is validated before it is used: a failed check leaves the coordinates plain.

The minimum γ̂ is an *estimate*, never a lower bound, even when the solver reports full accuracy: near the
optimal level the feasible R, S grow without bound and approach RS = I, the infimum is not attained, and
an interior-point solver stops where primal and dual agree to its tolerance although the iterates still
drift. Measured against controllers that SLICOT SB10DD returns and python-control / AB13DD verifies
(random plants of tests/hinf_cases.py, 12-state mass chains): γ̂ "optimal" at 1.0055 and 1.0081 times
such a controller's level (seed 2035, case 55), 1.0023 times (seed 2031, case 13).
"""

from __future__ import annotations

from dataclasses import dataclass

import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import SynthesisError
from lpvflow.synth.bilinear import Coordinates, balancing_transform, initial_coordinates
from lpvflow.synth.plant import VertexPlant
from lpvflow.synth.sdp import SolveReport, solve

#: Level of the interior point whose R, S balance the coordinates, relative to the estimate γ̂. Measured
#: on 14 random plants of an earlier draw of tests/hinf_cases.py and the ADIP at 75.5°, against SB10DD:
#: two rounds (2.0, then 1.15) left 3 of 14 more than 1 % above and the ADIP 0.47 % above; 3.0 left 1 and
#: the ADIP 1.09 %; 2.0 left 1 and the ADIP 0.74 %.
BALANCING_FACTOR = 2.0


def sym(M: cp.Expression) -> cp.Expression:
    """(M + Mᵀ)/2: the symmetric part cvxpy needs to read M as a matrix inequality."""
    return 0.5 * (M + M.T)


def projections(v: VertexPlant) -> tuple[np.ndarray, np.ndarray]:
    """N_R = blkdiag(null [B2ᵀ D12ᵀ], I_nw) and N_S = blkdiag(null [C2 D21], I_nz): the bases the conditions
    of :func:`eliminated_matrices` are projected on (Gahinet & Apkarian 1994, Thm. 4.3)."""
    nw, nz = v.dims[1], v.dims[3]
    return (scipy.linalg.block_diag(scipy.linalg.null_space(np.hstack([v.B2.T, v.D12.T])), np.eye(nw)),
            scipy.linalg.block_diag(scipy.linalg.null_space(np.hstack([v.C2, v.D21])), np.eye(nz)))


def eliminated_matrices(verts: list[VertexPlant], gamma: cp.Expression | float, R: cp.Variable,
                        S: cp.Variable) -> list[cp.Expression]:
    """The matrices of step 3: [R I; I S] (must be ⪰ 0), then per vertex the two projected LMIs (⪯ 0)."""
    n = R.shape[0]
    out = [cp.bmat([[R, np.eye(n)], [np.eye(n), S]])]
    for v in verts:
        nw, nz = v.dims[1], v.dims[3]
        NR, NS = projections(v)
        MR = cp.bmat([[v.A @ R + R @ v.A.T, R @ v.C1.T, v.B1],
                      [v.C1 @ R, -gamma * np.eye(nz), v.D11],
                      [v.B1.T, v.D11.T, -gamma * np.eye(nw)]])
        MS = cp.bmat([[v.A.T @ S + S @ v.A, S @ v.B1, v.C1.T],
                      [v.B1.T @ S, -gamma * np.eye(nw), v.D11.T],
                      [v.C1, v.D11, -gamma * np.eye(nz)]])
        out += [sym(NR.T @ MR @ NR), sym(NS.T @ MS @ NS)]
    return out


def strict_constraints(matrices: list[cp.Expression], t: cp.Expression | float,
                       scales: list[np.ndarray] | None) -> list[cp.Constraint]:
    """matrices[0] ⪰ t·D_0, matrices[k] ⪯ −t·D_k (k ≥ 1), D_k = diag(scales[k]) (identity if None)."""
    D = [np.diag(d) for d in scales] if scales is not None else [np.eye(M.shape[0]) for M in matrices]
    return [matrices[0] >> t * D[0]] + [M << -t * Dk for M, Dk in zip(matrices[1:], D[1:], strict=True)]


def jacobi_scales(matrices: list[cp.Expression]) -> list[np.ndarray]:
    """|diag M| of each matrix at the variables' current values, floored at 1e-9 of its largest entry:
    the scale a margin is measured against (step 4)."""
    out = []
    for M in matrices:
        d = np.abs(np.diag(np.asarray(M.value, dtype=float)))
        out.append(np.maximum(d, 1e-9 * max(d.max(), 1e-300)))
    return out


@dataclass
class Estimate:
    """Step 3's minimiser: γ̂, whether the solve was accurate, and the Jacobi scales of its matrices."""

    gamma: float
    accurate: bool
    scales: list[np.ndarray]
    report: SolveReport


def estimate(verts: list[VertexPlant], gamma_max: float, solver: str) -> Estimate:
    """Step 3. A solve without a usable point leaves γ̂ = 1 (or gamma_max if smaller), not accurate. A γ̂
    above gamma_max is kept, accurate or not: it is not a lower bound (module docstring), so it refuses no
    level — held-out draw tests/hinf_cases.py seed 3001 case 20 (a mass chain at Ts = 1.37 ms) has an
    "optimal" γ̂ = 2.216 where SB10DD reaches 2.165 and hinfsyn certifies 2.170 — and it still sets the
    balancing level.

    Raises:
        SynthesisError: the solver proves the LMIs infeasible at every γ (category ``"infeasible"``).
    """
    n = verts[0].dims[0]
    g = cp.Variable()
    R, S = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True)
    matrices = eliminated_matrices(verts, g, R, S)
    what = f"the eliminated H∞ LMIs at {len(verts)} vertices"
    try:
        report = solve(cp.Problem(cp.Minimize(g), strict_constraints(matrices, 0.0, None)), solver, what)
    except SynthesisError as exc:
        if exc.category == "infeasible":
            raise
        status = str(exc).rsplit("status: ", 1)[-1].rstrip(")")
        return Estimate(min(1.0, gamma_max), False, [], SolveReport(solver.upper(), status, 0.0,
                                                                     [(solver.upper(), status, 0.0)]))
    gamma = float(g.value)
    if not (np.isfinite(gamma) and gamma > 0):
        return Estimate(min(1.0, gamma_max), False, [], report)
    return Estimate(gamma, report.accurate, jacobi_scales(matrices), report)


def balancing(verts: list[VertexPlant], estimate: Estimate, solver: str
              ) -> tuple[np.ndarray | None, SolveReport | None]:
    """Step 4: the state transform T from the interior point at BALANCING_FACTOR·γ̂ — the projected LMIs
    ⪯ −t·D_k (D_k their Jacobi diagonals at the estimate), [R I; I S] ⪰ t·I, t maximised — or None when
    the solve was not accurate or :func:`balancing_transform` refuses R, S."""
    n = verts[0].dims[0]
    R, S, t = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True), cp.Variable()
    gamma = BALANCING_FACTOR * estimate.gamma
    scales = [np.ones_like(estimate.scales[0]), *estimate.scales[1:]]  # [R I; I S] ⪰ t·I: R, S ≻ 0
    constraints = [*strict_constraints(eliminated_matrices(verts, gamma, R, S), t, scales), t <= 1]
    try:
        report = solve(cp.Problem(cp.Maximize(t), constraints), solver,
                       f"the eliminated H∞ LMIs at γ = {gamma:.6g}")
    except SynthesisError:
        return None, None
    if not report.accurate:
        return None, report
    return balancing_transform(R.value, S.value), report


def infeasible_at(verts: list[VertexPlant], gamma: float, solver: str) -> bool:
    """Whether the solver proves the LMIs of step 3 infeasible at the level γ: the largest t with the
    projected LMIs ⪯ −t·I and [R I; I S] ⪰ t·I (t ≤ 1) is negative in an accurate solve, or the solver
    says infeasible. No controller of the class then reaches γ."""
    n = verts[0].dims[0]
    R, S, t = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True), cp.Variable()
    try:
        constraints = [*strict_constraints(eliminated_matrices(verts, gamma, R, S), t, None), t <= 1]
        report = solve(cp.Problem(cp.Maximize(t), constraints), solver,
                       f"the eliminated H∞ LMIs at γ = {gamma:.6g}")
    except SynthesisError as exc:
        return exc.category == "infeasible"
    return report.accurate and float(t.value) < 0


@dataclass
class Preconditioned:
    """Steps 2–4: the coordinates, the vertices in them, the estimate (the lowest accurate one, else the
    latest) and every SDP solved (solver, status, seconds)."""

    coordinates: Coordinates
    vertices: list[VertexPlant]
    estimate: Estimate
    attempts: list[tuple[str, str, float]]


def preconditioned(cayleys: list[VertexPlant], gamma_max: float, solver: str) -> Preconditioned:
    """Steps 2–4 on the Cayley images of the vertices (raises SynthesisError when the solver proves the
    eliminated LMIs infeasible at every γ)."""
    coords = initial_coordinates(cayleys)
    verts = [coords.apply(vc) for vc in cayleys]
    current = estimate(verts, gamma_max, solver)
    attempts = list(current.report.attempts)
    T, report = balancing(verts, current, solver) if current.scales else (None, None)
    attempts += report.attempts if report else []
    if T is not None:  # step 3 again where it is better conditioned
        coords = coords.transformed(T)
        verts = [coords.apply(vc) for vc in cayleys]
        balanced = estimate(verts, gamma_max, solver)
        attempts += balanced.report.attempts
        if balanced.accurate or not current.accurate:
            current = balanced if not current.accurate else min(current, balanced, key=lambda e: e.gamma)
    return Preconditioned(coords, verts, current, attempts)
