"""Solving the synthesis SDPs: Clarabel through cvxpy first, SCS as fallback, honest status.

``optimal`` is accepted. ``optimal_inaccurate`` is returned as such (never silently): the caller must
re-check the numbers independently (:func:`lpvflow.synth.hinf.certificate_margin`) and refuse
when the re-check fails. ``infeasible``/``unbounded`` and solver errors (after the fallback) raise
:class:`SynthesisError` with the solver's word and what it means for the design.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from lpvflow.errors import ModelError, SynthesisError

__all__ = ["ACCEPTED", "SOLVERS", "SolveReport", "SynthesisError", "psd", "solve"]

SOLVERS = ("CLARABEL", "SCS")
ACCEPTED = (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)
# Clarabel's own accuracy (1e-8); the "reduced" tolerances decide when a stalled solve is reported as
# optimal_inaccurate (then re-checked).
# One thread: on a loaded 2-core machine Clarabel's threaded factorisation was 3-5x slower (measured).
_CLARABEL_SETTINGS = {"tol_gap_abs": 1e-8, "tol_gap_rel": 1e-8, "tol_feas": 1e-8, "max_iter": 200,
                      "reduced_tol_gap_abs": 1e-5, "reduced_tol_gap_rel": 1e-4, "reduced_tol_feas": 1e-6,
                      "max_threads": 1, "chordal_decomposition_enable": False}
_SCS_SETTINGS = {"max_iters": 20000, "eps_abs": 1e-6, "eps_rel": 1e-6}


@dataclass
class SolveReport:
    """What the SDP solver did: solver used, status, wall time, attempts (solver, status, seconds)."""

    solver: str
    status: str
    seconds: float
    attempts: list[tuple[str, str, float]] = field(default_factory=list)


def psd(M: cp.Expression, margin: float | cp.Expression) -> cp.Constraint:
    """The strict LMI M ≻ 0 imposed as (M + Mᵀ)/2 ⪰ margin·I (M is symmetric by construction)."""
    n = M.shape[0]
    return 0.5 * (M + M.T) - margin * np.eye(n) >> 0


def solve(problem: cp.Problem, solver: str = "CLARABEL", what: str = "the LMIs") -> SolveReport:
    """Solve with ``solver``, then with the other one if it fails (status not in :data:`ACCEPTED`).

    Raises:
        SynthesisError: infeasible (naming ``what``), or no solver returned a solution.
    """
    solver = solver.upper()
    if solver not in SOLVERS:
        raise ModelError(f"unknown SDP solver {solver!r}; use one of {', '.join(SOLVERS)}")
    order = [solver] + [s for s in SOLVERS if s != solver]
    attempts: list[tuple[str, str, float]] = []
    total = 0.0
    for name in order:
        start = time.perf_counter()
        try:
            kwargs = _SCS_SETTINGS if name == "SCS" else _CLARABEL_SETTINGS
            problem.solve(solver=name, **kwargs)
            status = str(problem.status)
        except (cp.error.SolverError, ValueError) as exc:  # SCS raises ValueError when its KKT setup fails
            status = f"solver error ({str(exc).splitlines()[0][:80]})"
        elapsed = time.perf_counter() - start
        total += elapsed
        attempts.append((name, status, elapsed))
        if status in ACCEPTED:
            return SolveReport(name, status, total, attempts)
        if status in (cp.INFEASIBLE, cp.UNBOUNDED, cp.INFEASIBLE_INACCURATE):
            break
    tried = "; ".join(f"{n}: {s}" for n, s, _ in attempts)
    if attempts[-1][1] == cp.INFEASIBLE:
        raise SynthesisError(f"{what} are infeasible ({tried})", category="infeasible")
    raise SynthesisError(f"no solver returned a solution of {what} ({tried})", category="accuracy")
