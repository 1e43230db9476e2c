"""What every model extension of the diagnosis is made of: the user's structure, a fitted variant
with its scores (:class:`Fit`), the extension it belongs to (:class:`Candidate`), the splits and
nominal fit it starts from (:class:`Context`), and the whole-record simulations that score it
(open loop, or in the identification loop: :func:`loop_simulator`). The vocabulary itself is
:mod:`lpvflow.validate.extensions`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import ModelError
from lpvflow.identify.arx import identify_arx
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import Loop
from lpvflow.validate.extended_model import ModelMap, simulate_mapped_in_loop


@dataclass(frozen=True)
class Structure:
    """The user's model structure: orders, delay, basis, form (see :func:`identify_arx`)."""

    na: int | np.ndarray
    nb: int | np.ndarray
    nk: int | np.ndarray
    basis: str | Basis = "affine"
    form: str = "shifted"

    def orders(self, ny: int, nu: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """na (ny, ny), nb and nk (ny, nu) as integer matrices."""
        return (np.broadcast_to(np.asarray(self.na, int), (ny, ny)).copy(),
                np.broadcast_to(np.asarray(self.nb, int), (ny, nu)).copy(),
                np.broadcast_to(np.asarray(self.nk, int), (ny, nu)).copy())

    @classmethod
    def of_model(cls, model: LPVIO) -> Structure:
        """The structure of an identified input-output model (its orders, delays, basis and form)."""
        if model.na is None or model.nb is None or model.nk is None:
            raise ModelError("the model file records no orders (na, nb, nk): diagnose needs the input-output "
                             "model `lpvflow identify` saves with an IO method such as lpr-arx")
        return cls(np.asarray(model.na), np.asarray(model.nb), np.asarray(model.nk), model.basis, model.form)

    def basis_for(self, n_p: int) -> Basis:
        return Basis.from_spec(self.basis, n_p) if isinstance(self.basis, str) else self.basis


@dataclass
class Fit:
    """A fitted model and its scores: one-step loss and BIC on estimation data, validation simulation.

    ``simulate(model)`` gives the validation part of the model's simulation; it runs on first use of
    :attr:`y_val` or :attr:`diverged` (only the variant an extension selects is ever simulated).
    """

    model: LPVIO
    loss: float  # log det of the one-step residual covariance (estimation data)
    n_params: int
    bic: float
    simulate: Callable[[LPVIO], np.ndarray] = field(repr=False)
    reference: np.ndarray = field(repr=False)  # measured validation outputs, to bound the simulation
    data: Dataset | None = field(default=None, repr=False)  # the estimation data it was fitted on

    @classmethod
    def scored(cls, model: LPVIO, loss: float, n_params: int, n_samples: int,
               simulate: Callable[[LPVIO], np.ndarray], reference: np.ndarray,
               data: Dataset | None = None) -> Fit:
        """The fit with BIC = n_eff·loss + k·ln n_eff (n_eff = n_samples − max_lag, k = n_params)."""
        n_eff = n_samples - model.max_lag
        return cls(model, float(loss), n_params, float(n_eff * loss + n_params * np.log(n_eff)), simulate,
                   reference, data)

    @classmethod
    def of_model(cls, model: LPVIO, est: Dataset, val: Dataset,
                 simulate: Callable[[LPVIO], np.ndarray] | None = None) -> Fit:
        """A given (already identified) model scored like a fit: loss the log det of its one-step
        residual covariance on ``est`` (:func:`~lpvflow.identify.arx.prediction_residuals`), its
        parameter count the nonzero coefficients of A and B."""
        from lpvflow.identify.arx import prediction_residuals

        residual = prediction_residuals(model, est)
        n_params = int(np.count_nonzero(model.A) + np.count_nonzero(model.B))
        return cls.scored(model, log_det(np.cov(residual.T)), n_params, est.N,
                          simulate or (lambda m: simulate_validation(m, est, val)), val.y, est)

    @cached_property
    def _validation(self) -> tuple[np.ndarray, bool]:
        with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            return bounded(self.simulate(self.model), self.reference)

    @property
    def y_val(self) -> np.ndarray:
        """Validation simulation (a bounded copy if it blew up)."""
        return self._validation[0]

    @property
    def diverged(self) -> bool:
        """The validation simulation blew up (:func:`bounded` had to clip it)."""
        return self._validation[1]


@dataclass
class Candidate:
    """An extension addressing one cause."""

    cause: str
    parameters: dict
    fit: Fit
    description: str
    inputs_added: list[str] = field(default_factory=list)
    #: Structural values the extension chose from the data (a level, a delay per input, a channel):
    #: each counts as one parameter in the BIC/AIC changes of the ranking.
    choices: int = 0
    #: The input or output map the extended model runs with (None: the model alone); open-loop fits
    #: are scored by its :meth:`~lpvflow.validate.extended_model.ModelMap.simulate_validation`.
    model_map: ModelMap | None = None


@dataclass
class Context:
    """Everything an extension needs: splits, structure, nominal fit, candidate channels."""

    est: Dataset
    val: Dataset
    structure: Structure
    nominal: Fit
    channels: dict[str, tuple[np.ndarray, np.ndarray]]  # name → (estimation, validation) values
    loop: Loop | None = None  # closed-loop data: the identification loop the models are simulated in
    estimator: str = "arx"  # "oe": every variant refined by output error (diagnose's noise round)
    #: cause → why the data cannot determine its parameter (an extension states it instead of guessing)
    not_identifiable: dict[str, str] = field(default_factory=dict)

    @property
    def ny(self) -> int:
        return self.est.y.shape[1]

    @property
    def nu(self) -> int:
        return self.est.u.shape[1]

    def fit(self, est: Dataset, val: Dataset, na, nb, nk, basis: Basis,
            simulate: Callable[[LPVIO], np.ndarray] | None = None) -> Fit:
        """:func:`fit` with this context's form and estimator."""
        return fit(est, val, na, nb, nk, basis, self.structure.form, simulate, self.estimator)

    def in_loop(self, model_map: ModelMap | None = None, p: np.ndarray | None = None,
                p_names: list[str] | None = None) -> Callable[[LPVIO], np.ndarray] | None:
        """:func:`loop_simulator` of this context (None on open-loop data)."""
        return loop_simulator(self.est, self.val, self.loop, model_map, p, p_names)


def loop_simulator(est: Dataset, val: Dataset, loop: Loop | None, model_map: ModelMap | None = None,
                   p: np.ndarray | None = None, p_names: list[str] | None = None,
                   ) -> Callable[[LPVIO], np.ndarray] | None:
    """Validation part of a model's whole-record simulation in ``loop`` (None without a loop), with the
    extension's ``model_map`` (None: the model alone) as its drive.

    ``p``/``p_names`` replace the scheduling of the whole record (an added scheduling channel).
    """
    if loop is None:
        return None
    whole = joined(est, val)
    if p is not None:
        whole = replace(whole, p=p, p_names=p_names)
    return LoopSimulation(whole, loop, model_map, est.N, rescheduled=p is not None)


@dataclass
class LoopSimulation:
    """``model`` → the validation part (from sample ``start``) of its simulation over ``whole`` in
    ``loop`` with the extension's ``model_map``, by
    :func:`~lpvflow.validate.extended_model.simulate_mapped_in_loop` — the function the saved extended
    model runs with; :func:`refit_in_loop` reads the map's :attr:`drive` back."""

    whole: Dataset
    loop: Loop
    model_map: ModelMap | None
    start: int
    rescheduled: bool = False  # the scheduling of the record was replaced (an added channel)

    @property
    def drive(self) -> dict:
        """The map's drive of :func:`~lpvflow.validate.closed_loop.simulate_in_loop` over ``whole``."""
        if self.model_map is None:
            return {}
        return self.model_map.loop_drive(self.whole.u, self.whole.u_names, self.whole.y_names)

    def __call__(self, model: LPVIO) -> np.ndarray:
        return simulate_mapped_in_loop(model, self.model_map, self.whole, self.loop)[self.start :]


def fit(est: Dataset, val: Dataset, na, nb, nk, basis: Basis | str, form: str = "shifted",
        simulate: Callable[[LPVIO], np.ndarray] | None = None, estimator: str = "arx") -> Fit:
    """Fit LPV-ARX on ``est``; one-step loss and BIC; its simulation on ``val`` (open loop on the
    whole record, or with ``simulate``) runs on first use.

    ``estimator="oe"``: the ARX fit is refined by output error (:func:`output_error`); loss and BIC
    are then those of the estimation-data simulation error.
    """
    model = identify_arx(est, na, nb, nk, basis, form=form)
    n_params = int(sum(c.shape[0] for c in model.param_cov))
    if estimator == "oe":
        model = output_error(est, model)
    return Fit.scored(model, log_det(model.noise_cov), n_params, est.N,
                      simulate or (lambda m: simulate_validation(m, est, val)), val.y, est)


#: Function evaluations of the output-error refinement (from the ARX fit, which is close).
OE_EVALUATIONS = 30


def output_error(est: Dataset, start: LPVIO) -> LPVIO:
    """The output-error (simulation-error) estimate of ``start``'s structure on ``est``, started from it.

    Consistent under white output (sensor) noise, where least squares is biased (the equation error
    is then A(q)·e, coloured); ``noise_cov`` is the covariance of the simulation error.
    """
    from lpvflow.identify.oe import identify_oe

    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        return identify_oe(est, start.na, start.nb, start.nk, start.basis, start.form, init=start,
                           max_nfev=OE_EVALUATIONS)


def log_det(cov: np.ndarray) -> float:
    """log det of a (residual) covariance: −inf when it is singular (an exact fit), +inf when it is
    not finite (a fit or simulation that overflowed — never the best of a comparison)."""
    cov = np.atleast_2d(cov)
    if not np.all(np.isfinite(cov)):
        return np.inf
    sign, logdet = np.linalg.slogdet(cov)
    return float(logdet) if sign > 0 else -np.inf


def joined(est: Dataset, val: Dataset) -> Dataset:
    """The whole record: the estimation split followed by the validation split."""
    return replace(est, u=np.vstack([est.u, val.u]), y=np.vstack([est.y, val.y]), p=np.vstack([est.p, val.p]))


def simulate_validation(model: LPVIO, est: Dataset, val: Dataset) -> np.ndarray:
    """Simulation of the whole record from a zero past, validation part (module docstring)."""
    whole = joined(est, val)
    return model.simulate(whole.u, whole.p)[est.N :]


def bounded(y_sim: np.ndarray, y: np.ndarray, factor: float = 10.0) -> tuple[np.ndarray, bool]:
    """Clip a simulation to ``factor`` times the data's extent around its mean; report if it had to.

    An unstable model's simulation overflows; its bounded copy still scores (badly) without inf/NaN.
    """
    centre = y.mean(axis=0)
    extent = factor * np.maximum(np.abs(y - centre).max(axis=0), 1e-12)
    finite = np.nan_to_num(y_sim, nan=np.inf)
    diverged = bool(np.any(np.abs(finite - centre) > extent))
    return np.clip(finite, centre - extent, centre + extent), diverged


def with_inputs(data: Dataset, extra: np.ndarray, names: list[str]) -> Dataset:
    return replace(data, u=np.hstack([data.u, extra]), u_names=[*data.u_names, *names])


def extend_orders(nb: np.ndarray, nk: np.ndarray, nb_new: int, nk_new: int, count: int):
    ny = nb.shape[0]
    return (np.hstack([nb, np.full((ny, count), nb_new)]), np.hstack([nk, np.full((ny, count), nk_new)]))


