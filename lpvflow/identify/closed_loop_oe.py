"""Closed-loop output-error refinement of a least-squares LPV-ARX model (``[identify] refine =
"closed-loop-oe"``).

From the least-squares estimate θ₀ (:func:`lpvflow.identify.arx.identify_arx`, shifted form) a few
trust-region Gauss–Newton steps (``scipy.optimize.least_squares``, method "trf", finite-difference
Jacobian) minimize

    V(θ) = Σ_records Σ_k Σ_i e_eq,i(k, θ)² / σ̂_i²  +  Σ_loops Σ_k Σ_i ((y_sim,i(k, θ) − y_i(k)) / s_i)²

* e_eq(k, θ) = y(k) − ŷ(k | k−1, θ), the least-squares problem's own one-step equation errors on its
  (prefiltered) estimation records (:func:`~lpvflow.identify.arx.prediction_residuals`), σ̂_i their RMS
  per output at θ₀: the term that holds the frozen dynamics the least-squares fit found;
* y_sim(θ) the model simulated in the loop of the controller each record was made under, fed the
  record's excitation and set-points from rest (:func:`lpvflow.validate.closed_loop.simulate_in_loop`,
  compiled), y the record's measured outputs, s_i the scale of output i (the trajectory goal: the error
  that matters where the model is used).

This is the direct closed-loop prediction-error method with an output-error predictor (Ljung, *System
Identification*, 2nd ed., §13.4 and §7.3 (output-error models)); weighing the error the way the model is
used is identification for control (Gevers, "Identification for control: from the early achievements to
the revival of experiment design", Eur. J. Control 11, 2005). The free coefficients are those the
least-squares fit estimated (the nonzero entries of θ₀; the structural zeros of na, nb, nk stay zero).
A step whose loop diverges gets residuals of :data:`DIVERGED_RESIDUAL`, so the trust region rejects it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.optimize

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.arx import prediction_residuals
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import Loop, simulate_in_loop

#: The residual given to every sample of a loop that diverged (the simulated output is inf there).
DIVERGED_RESIDUAL = 1e6


@dataclass(frozen=True)
class LoopRecord:
    """A record of the simulation term: ``data`` (the model's inputs and scheduling, the plant's measured
    outputs y) and its ``loop`` (:class:`~lpvflow.validate.closed_loop.Loop`)."""

    data: Dataset
    loop: Loop


@dataclass(frozen=True)
class Refinement:
    """The refined model and the criterion's terms at the start and at the end (module docstring)."""

    model: LPVIO
    cost_start: float
    cost_end: float
    equation_rms_start: np.ndarray  # (ny,) RMS of e_eq at θ₀
    equation_rms_end: np.ndarray
    simulation_rms_start: np.ndarray  # (ny,) RMS of y_sim − y over the loops at θ₀
    simulation_rms_end: np.ndarray
    evaluations: int

    def summary(self) -> dict:
        """JSON-ready numbers for a stage's outputs."""
        return {"cost": [self.cost_start, self.cost_end], "evaluations": self.evaluations,
                "equation_rms": [self.equation_rms_start.tolist(), self.equation_rms_end.tolist()],
                "simulation_rms": [self.simulation_rms_start.tolist(), self.simulation_rms_end.tolist()]}


def refine_closed_loop_oe(model: LPVIO, equation_records: Sequence[Dataset], loops: Sequence[LoopRecord],
                          scales: np.ndarray, iterations: int, integrated: tuple[str, ...] = (),
                          progress: Callable[[int], None] | None = None) -> Refinement:
    """The model minimizing V(θ) (module docstring) from ``model`` (θ₀), with at most ``iterations``
    trust-region steps (``max_nfev``; the Jacobian's finite differences, one loop simulation per free
    coefficient, are not counted).

    Args:
        model: the least-squares estimate, shifted form.
        equation_records: the estimation records of the least-squares problem (as it saw them).
        loops: the records of the simulation term with their loops.
        scales: (ny,) s_i, in the units of the outputs.
        iterations: the number of trust-region steps, ≥ 1.
        integrated: outputs the model gives as increments (``[identify] increments``), summed in the loop.
        progress: called with the number of loop simulations done so far.
    """
    scales = np.asarray(scales, dtype=float).reshape(-1)
    if model.form != "shifted":
        raise DataError("the closed-loop output-error refinement needs the shifted (LPR) form; use "
                        "[identify] method = \"lpr-arx\"")
    if scales.shape != (model.ny,) or not np.all(scales > 0):
        raise DataError(f"refine scales {scales.tolist()}: give one positive scale per output "
                        f"{model.y_names}")
    if iterations < 1:
        raise DataError(f"refine_iterations = {iterations}: give at least 1")
    if not loops:
        raise DataError("the closed-loop output-error refinement needs at least one record with its loop")
    free_a, free_b = model.A != 0, model.B != 0
    theta0 = np.concatenate([model.A[free_a], model.B[free_b]])

    def model_of(theta: np.ndarray) -> LPVIO:
        A, B = model.A.copy(), model.B.copy()
        A[free_a], B[free_b] = theta[: free_a.sum()], theta[free_a.sum():]
        return replace(model, A=A, B=B)

    def equation_errors(m: LPVIO) -> np.ndarray:
        return np.concatenate([prediction_residuals(m, record) for record in equation_records])

    sigma = np.sqrt(np.mean(equation_errors(model) ** 2, axis=0))
    runs = [0]

    def simulation_errors(m: LPVIO) -> list[np.ndarray]:
        errors = [simulate_in_loop(m, record.data, record.loop, integrated=integrated) - record.data.y
                  for record in loops]
        runs[0] += len(loops)
        if progress is not None:
            progress(runs[0])
        return errors

    def residuals(theta: np.ndarray) -> np.ndarray:
        m = model_of(theta)
        simulated = np.concatenate([(e / scales).ravel() for e in simulation_errors(m)])
        simulated = np.where(np.isfinite(simulated), simulated, DIVERGED_RESIDUAL)
        return np.concatenate([(equation_errors(m) / sigma).ravel(), simulated])

    def rms(errors: list[np.ndarray]) -> np.ndarray:
        return np.sqrt(np.mean(np.concatenate(errors) ** 2, axis=0))

    start_sim = simulation_errors(model)
    if not all(np.all(np.isfinite(e)) for e in start_sim):
        raise DataError("the least-squares model's loop diverges on a record: the closed-loop output-error "
                        "refinement starts from a model that stays in the loop; turn [identify] refine off")
    fit = scipy.optimize.least_squares(residuals, theta0, method="trf", max_nfev=iterations)
    refined = model_of(fit.x)
    end_sim = simulation_errors(refined)
    cost_start = float(np.sum(residuals(theta0) ** 2))
    return Refinement(refined, cost_start, float(2 * fit.cost),
                      sigma, np.sqrt(np.mean(equation_errors(refined) ** 2, axis=0)),
                      rms(start_sim), rms(end_sim), int(fit.nfev))
