"""Solving the synthesis SDPs with one solver, reporting exactly what it said.

Every SDP is solved once, by the solver asked for (Clarabel through cvxpy by default, SCS on request);
there is no fallback to another solver. The status is kept as the solver returned it: ``optimal`` is an
accurate point; ``optimal_inaccurate`` is a point the caller may use only through an independent numpy
re-check (:func:`lpvflow.synth.bilinear.certificate_margin`), and never as a bound; ``infeasible`` (and
``unbounded``) and solver errors raise :class:`SynthesisError` naming the LMIs, the solver and its word.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from lpvflow.errors import ModelError, SynthesisError

SOLVERS = ("CLARABEL", "SCS")
#: Statuses that come with a point.
WITH_POINT = (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)
# Clarabel's own accuracy (1e-8); the "reduced" tolerances decide when a stalled solve is reported as
# optimal_inaccurate (then re-checked). A solve that ends "InsufficientProgress" with a point is reported
# optimal_inaccurate as well (cvxpy's accept_unknown), so its point is re-checked like any other instead of
# being discarded: the widest point of a held-out ADIP shaped plant's eliminated LMIs (order 8, γ 10.41;
# benchmarks/README.md, "The iterate experiment's coverage") stalled at iteration 59 with the duality gap
# at 7e-13 and the primal residual at 1.03e-6, just outside the reduced 1e-6, while t = 7.03e-4 > 0 (the
# default tolerances solve it: t = 7.01e-4). One thread: on a loaded 2-core machine Clarabel's threaded
# factorisation was 3-5x slower (measured).
_SETTINGS = {
    "CLARABEL": {"tol_gap_abs": 1e-8, "tol_gap_rel": 1e-8, "tol_feas": 1e-8, "max_iter": 200,
                 "reduced_tol_gap_abs": 1e-5, "reduced_tol_gap_rel": 1e-4, "reduced_tol_feas": 1e-6,
                 "max_threads": 1, "chordal_decomposition_enable": False, "accept_unknown": True},
    "SCS": {"max_iters": 20000, "eps_abs": 1e-6, "eps_rel": 1e-6},
}
#: Clarabel's settings for the H∞ level SDPs (:mod:`lpvflow.synth.vertex_synthesis` step 5): iterative
#: refinement of each KKT solve to 1e-16 (up to 50 steps; Clarabel's default 1e-13/1e-12, 10 steps). With
#: Clarabel 0.11.1 the level SDPs of a 2×2 plant near its optimum (tests/test_hinf_random.py seed 2047
#: case 26) ended NumericalError at every level within 1.6× SB10DD's optimum, the primal and dual residuals
#: at 1e-9 and 1e-6; refined, 0.9997×, and the 63-plant draws of seeds 2027, 2035 and 2047 each within 1 %
#: (refining every SDP: 2031 and 2039 as well, worst 1.008×). Not for every SDP: the preconditioning's
#: estimate of the polytopic test plant then ended inaccurate (tests/test_synth_hinf.py).
_REFINED = {"CLARABEL": {"iterative_refinement_max_iter": 50, "iterative_refinement_reltol": 1e-16,
                         "iterative_refinement_abstol": 1e-16},
            "SCS": {}}
#: Clarabel's settings for SDPs whose optimum is approached only as the variables grow (the central
#: controller's largest R, S, :mod:`lpvflow.synth.central`): duality gap 1e-12, no Ruiz equilibration (its
#: row scalings of the PSD blocks stalled such iterates), up to 600 interior-point iterations and iterative
#: refinement of each KKT solve to 1e-16 (up to 50 steps). Measured first on the H∞ controller LMIs at one
#: level as they were written before (max t with R, S free: ‖R‖ ≈ 1e4–1e5, I − RS of condition up to 1e11
#: near the optimum); those are now homogenized (:mod:`lpvflow.synth.vertex_synthesis` step 5: R, S
#: bounded) and run with the default settings above and :data:`_REFINED`. A solve that stalls is
#: reported ``optimal_inaccurate`` by the reduced tolerances and re-checked like any other.
_FINE = {"CLARABEL": {**_REFINED["CLARABEL"], "tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12,
                      "equilibrate_enable": False, "max_iter": 600},
         "SCS": {}}

__all__ = ["SOLVERS", "SolveReport", "SynthesisError", "psd", "solve"]


@dataclass
class SolveReport:
    """What the SDP solver did: solver used, status, wall time, and every solve (solver, status, seconds)
    that led to the result."""

    solver: str
    status: str
    seconds: float
    attempts: list[tuple[str, str, float]] = field(default_factory=list)

    @property
    def accurate(self) -> bool:
        """The solver reached its full accuracy (status ``optimal``)."""
        return self.status == cp.OPTIMAL


def psd(M: cp.Expression, margin: float | cp.Expression) -> cp.Constraint:
    """The strict LMI M ≻ 0 imposed as (M + Mᵀ)/2 ⪰ margin·I (M is symmetric by construction)."""
    n = M.shape[0]
    return 0.5 * (M + M.T) - margin * np.eye(n) >> 0


def solve(problem: cp.Problem, solver: str = "CLARABEL", what: str = "the LMIs", fine: bool = False,
          refined: bool = False) -> SolveReport:
    """Solve ``problem`` once with ``solver`` and report its status (module docstring); ``fine``: with
    Clarabel, duality-gap tolerances 1e-12 instead of 1e-8 (:data:`_FINE`); ``refined``: with Clarabel,
    KKT solves refined to 1e-16 (:data:`_REFINED`); SCS unchanged by either.

    Raises:
        ModelError: an unknown solver name.
        SynthesisError: the solver found ``what`` infeasible (category ``"infeasible"`` when it says so
            accurately) or returned no point (category ``"accuracy"``), with its status.
    """
    name = solver.upper()
    if name not in SOLVERS:
        raise ModelError(f"unknown SDP solver {solver!r}; use one of {', '.join(SOLVERS)}")
    start = time.perf_counter()
    try:
        with warnings.catch_warnings():  # cvxpy's "Solution may be inaccurate": the status says it
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=name, **{**_SETTINGS[name], **(_REFINED[name] if refined else {}),
                                          **(_FINE[name] if fine else {})})
        status = str(problem.status)
    except (cp.error.SolverError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        first = str(exc).split(".")[0].strip() or type(exc).__name__
        status = f"solver error ({first[:80]})"
    elapsed = time.perf_counter() - start
    if status in WITH_POINT:
        return SolveReport(name, status, elapsed, [(name, status, elapsed)])
    if status == cp.INFEASIBLE:
        raise SynthesisError(f"{what} are infeasible ({name}: {status})", category="infeasible")
    raise SynthesisError(f"{name} returned no solution of {what} (status: {status})", category="accuracy")
