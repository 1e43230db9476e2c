"""Solving the synthesis SDPs: Clarabel through cvxpy first, SCS as fallback, honest status.

A solve is accepted only with status ``optimal``. ``infeasible``/``unbounded`` and any ``*_inaccurate``
status (after the fallback) raise :class:`SynthesisError` with the solver's word and what it means for
the design; a controller is never returned from an unreliable solve.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from lpvflow.errors import ModelError

SOLVERS = ("CLARABEL", "SCS")
# H∞-optimal LMIs are degenerate at the optimum: interior-point progress stalls near a relative gap of
# 1e-8 (Clarabel's default), so ask for 1e-7 — γ is then exact to ~1e-7 relative, far inside the
# tolerances of the independent re-check (:mod:`lpvflow.synth.certify`).
# One thread: on a loaded 2-core machine Clarabel's threaded factorisation was 3-5x slower (measured).
_CLARABEL_SETTINGS = {"tol_gap_abs": 1e-7, "tol_gap_rel": 1e-7, "tol_feas": 1e-8, "max_iter": 300,
                      "max_threads": 1}
_SCS_SETTINGS = {"max_iters": 50000, "eps_abs": 1e-7, "eps_rel": 1e-7}


class SynthesisError(ModelError):
    """No (reliable) solution: infeasible LMIs, an inaccurate solve or a failed re-check."""


@dataclass
class SolveReport:
    """What the SDP solver did: solver used, status, wall time, attempts (solver, status, seconds)."""

    solver: str
    status: str
    seconds: float
    attempts: list[tuple[str, str, float]] = field(default_factory=list)


def psd(M: cp.Expression, margin: float) -> cp.Constraint:
    """The strict LMI M ≻ 0 imposed as (M + Mᵀ)/2 ⪰ margin·I (M is symmetric by construction)."""
    n = M.shape[0]
    return 0.5 * (M + M.T) - margin * np.eye(n) >> 0


def solve(problem: cp.Problem, solver: str = "CLARABEL", what: str = "the LMIs") -> SolveReport:
    """Solve with ``solver``, then with the other one if it fails or is inaccurate.

    Raises:
        SynthesisError: infeasible (naming ``what``), or no solver reached an accurate optimum.
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
        except cp.error.SolverError as exc:
            status = f"solver error ({str(exc).splitlines()[0][:80]})"
        elapsed = time.perf_counter() - start
        total += elapsed
        attempts.append((name, status, elapsed))
        if status == cp.OPTIMAL:
            return SolveReport(name, status, total, attempts)
        if status in (cp.INFEASIBLE, cp.UNBOUNDED):
            break
    tried = "; ".join(f"{n}: {s}" for n, s, _ in attempts)
    if attempts[-1][1] == cp.INFEASIBLE:
        raise SynthesisError(f"{what} are infeasible ({tried})")
    raise SynthesisError(f"no solver reached an accurate optimum for {what} ({tried}); "
                         "check the scaling of the plant and weights")
