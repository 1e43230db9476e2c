"""Model extensions, one per cause the diagnosis can name.

Each extension is fitted on the estimation split (its own free choice — a delay, a degree, a width
— selected by the one-step loss or BIC on the estimation data only) and simulated on the
validation split, where :mod:`lpvflow.validate.diagnose` scores it against the nominal model.
Every simulation runs over the whole record from a zero past and is scored on its validation part
(:func:`simulate_validation`): the estimation split is the warm-up, so the validation part starts
from the model's own state instead of from zero (on a slow plant far from y = 0 the zero-start
transient would dominate every validation error).

Static input maps (Hammerstein extension, applied before the LPV dynamics):

    dead zone   f_w(u) = sign(u) · max(|u| − w, 0)
    saturation  f_s(u) = clip(u, −s, s)
    backlash    x(k) = min(max(x(k−1), u(k) − w/2), u(k) + w/2)   (a dead band ±w/2 with memory)

A clipping sensor is an output map: y_meas = clip(y, lo, hi) (:func:`sensor_saturation`).
Coulomb friction enters as an extra input sign(v(k)) with the input's lags, v(k) = y(k) − y(k−1)
for a position output or v(k) = y(k) for a velocity output; its validation simulation takes v
from the model's *own* simulated output, sample by sample (:func:`friction_simulation`), never
from the measured output.
Offset adds the inputs 1 and t/N with a lag-0 constant coefficient: c₀ + c₁·t/N.

Closed-loop data (``Context.loop`` set, :mod:`lpvflow.validate.closed_loop`): every model is
simulated in the identification loop instead, with the extension's input map, extra inputs and
velocity sign applied to the input the loop produces; the choices made on estimation data stay the
same (one-step loss and BIC), except the model order's simulation BIC, also run in the loop.
Simulations run on first use of a fit's validation output (:class:`Fit`): a diagnosis fits about a
hundred variants and scores one per cause.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property

import numba
import numpy as np
import scipy.optimize

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import LpvflowError
from lpvflow.identify.arx import identify_arx
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import Loop, simulate_in_loop, velocity_sign

CAUSES = (
    "input_delay", "model_order", "scheduling_dependence", "scheduling_variable",
    "input_nonlinearity", "backlash", "sensor_saturation", "friction", "output_noise_bias",
    "colored_noise", "offset", "unexplained", "none",
)


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
    #: each counts as one parameter in the BIC/AIC changes of the ranking (issue 26, item 4).
    choices: int = 0


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

    def in_loop(self, **drive) -> Callable[[LPVIO], np.ndarray] | None:
        """:func:`loop_simulator` of this context (None on open-loop data)."""
        return loop_simulator(self.est, self.val, self.loop, **drive)


def loop_simulator(est: Dataset, val: Dataset, loop: Loop | None, p: np.ndarray | None = None,
                   p_names: list[str] | None = None, **drive) -> Callable[[LPVIO], np.ndarray] | None:
    """Validation part of a model's whole-record simulation in ``loop`` (None without a loop).

    ``p``/``p_names`` replace the scheduling of the whole record (an added scheduling channel);
    ``drive`` holds the extension's ``input_map``, ``exogenous`` inputs or ``sign_of`` output
    (:func:`~lpvflow.validate.closed_loop.simulate_in_loop`).
    """
    if loop is None:
        return None
    whole = joined(est, val)
    if p is not None:
        whole = replace(whole, p=p, p_names=p_names)
    return LoopSimulation(whole, loop, drive, est.N, rescheduled=p is not None)


@dataclass
class LoopSimulation:
    """``model`` → the validation part (from sample ``start``) of its simulation over ``whole`` in
    ``loop`` with the extension's ``drive``; :func:`refit_in_loop` reads the drive back."""

    whole: Dataset
    loop: Loop
    drive: dict
    start: int
    rescheduled: bool = False  # the scheduling of the record was replaced (an added channel)

    def __call__(self, model: LPVIO) -> np.ndarray:
        return simulate_in_loop(model, self.whole, self.loop, **self.drive)[self.start :]


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
    sign, logdet = np.linalg.slogdet(model.noise_cov)
    loss = logdet if sign > 0 else -np.inf
    return Fit.scored(model, loss, n_params, est.N, simulate or (lambda m: simulate_validation(m, est, val)),
                      val.y, est)


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


def _with_inputs(data: Dataset, extra: np.ndarray, names: list[str]) -> Dataset:
    return replace(data, u=np.hstack([data.u, extra]), u_names=[*data.u_names, *names])


def _extend_orders(nb: np.ndarray, nk: np.ndarray, nb_new: int, nk_new: int, count: int):
    ny = nb.shape[0]
    return (np.hstack([nb, np.full((ny, count), nb_new)]), np.hstack([nk, np.full((ny, count), nk_new)]))


# ------------------------------------------------------------------------------------- causes
def input_delay(ctx: Context) -> Candidate | None:
    """Dead time differing from nk: nk' chosen per input by the estimation loss (same parameter count)."""
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    best_nk = nk.copy()
    best: Fit | None = None
    for j in range(ctx.nu):
        scores = {}
        for d in range(max(0, int(nk[0, j]) - 3), int(nk[0, j]) + 11):
            trial = best_nk.copy()
            trial[:, j] = d
            try:
                scores[d] = ctx.fit(ctx.est, ctx.val, na, nb, trial, basis, ctx.in_loop())
            except LpvflowError:
                continue
        d_best = min(scores, key=lambda d: scores[d].loss)
        best_nk[:, j] = d_best
        best = scores[d_best]
    if best is None or np.array_equal(best_nk, nk):
        return None
    found = best_nk[0].tolist() if ctx.nu > 1 else int(best_nk[0, 0])
    modelled = nk[0].tolist() if ctx.nu > 1 else int(nk[0, 0])
    return Candidate("input_delay", {"nk": found, "modelled_nk": modelled}, best,
                     f"modelled dead time {modelled}, data says {found}; extending nk to {found}",
                     choices=ctx.nu)


def simulation_bic(ctx: Context, candidate: Fit) -> float:
    """BIC of the estimation-data *simulation*: N log det(cov of the simulation error) + k log N.

    On closed-loop data the simulation runs in the identification loop over the estimation part:
    an unstable plant's model cannot be simulated open loop.
    """
    with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        if ctx.loop is None:
            y_sim = candidate.model.simulate(ctx.est.u, ctx.est.p)
        else:
            y_sim = simulate_in_loop(candidate.model, ctx.est, ctx.loop)  # the loop's r starts with est
        y_sim = bounded(y_sim, ctx.est.y)[0]
    sign, logdet = np.linalg.slogdet(np.atleast_2d(np.cov((ctx.est.y - y_sim).T)))
    n = ctx.est.N
    return float(n * logdet if sign > 0 else -np.inf) + candidate.n_params * np.log(n)


def model_order(ctx: Context) -> Candidate | None:
    """Orders too low: na/nb raised by 1–2, the variant with the best :func:`simulation_bic`.

    Not the one-step BIC: on nearly noise-free data it keeps rewarding more lags even when the
    model's own simulation fails (tanks FMU, na = nb = 1 raised to 3/3: one-step BIC best, simulation
    BFR 32 % on the estimation data, against 98 % for na = 3, nb = 2).
    """
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    trials = {(da, db): ctx.fit(ctx.est, ctx.val, na + da, nb + db, nk, basis, ctx.in_loop())
              for da, db in ((1, 0), (0, 1), (1, 1), (2, 1), (2, 2))}
    (da, db), best = min(trials.items(), key=lambda item: simulation_bic(ctx, item[1]))
    new = {"na": int(na.max() + da), "nb": int(nb.max() + db)}
    return Candidate("model_order", new, best, f"raising na to {new['na']} and nb to {new['nb']}")


def scheduling_dependence(ctx: Context) -> Candidate | None:
    """Coefficients need a richer basis in the given p: polynomial degree +1/+2, or a cubic spline."""
    base = ctx.structure.basis_for(ctx.est.p.shape[1])
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    options: dict[str, Basis] = {}
    if base.kind in ("affine", "poly"):
        for extra in (1, 2):
            deg = base.degree + extra
            options[f"poly:{deg}"] = Basis.poly(deg, base.n_p, cross=base.cross)
    if base.n_p == 1:
        for n_knots in (1, 2, 3):
            knots = np.quantile(ctx.est.p[:, 0], np.linspace(0, 1, n_knots + 2)[1:-1]).round(6).tolist()
            options["spline:" + ",".join(f"{k:g}" for k in knots)] = Basis.spline(knots)
    trials = {}
    for spec, basis in options.items():
        try:
            trials[spec] = ctx.fit(ctx.est, ctx.val, na, nb, nk, basis, ctx.in_loop())
        except LpvflowError:
            continue
    if not trials:
        return None
    spec, best = min(trials.items(), key=lambda item: item[1].bic)
    params: dict = {"basis": spec}
    if spec.startswith("poly"):
        params["degree"] = int(spec.split(":")[1])
    return Candidate("scheduling_dependence", params, best, f"using the basis {spec}", choices=1)


def scheduling_variable(ctx: Context) -> Candidate | None:
    """Another recorded channel as an additional scheduling signal (same basis family)."""
    base = ctx.structure.basis_for(ctx.est.p.shape[1])
    if base.kind == "spline" or not ctx.channels:
        return None
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    trials = {}
    for name, (c_est, c_val) in ctx.channels.items():
        est = replace(ctx.est, p=np.column_stack([ctx.est.p, c_est]), p_names=[*ctx.est.p_names, name])
        val = replace(ctx.val, p=np.column_stack([ctx.val.p, c_val]), p_names=[*ctx.val.p_names, name])
        basis = Basis(base.kind, base.n_p + 1, degree=base.degree, cross=base.cross)
        try:
            whole = joined(est, val)
            trials[name] = ctx.fit(est, val, na, nb, nk, basis,
                               ctx.in_loop(p=whole.p, p_names=whole.p_names))
        except LpvflowError:
            continue
    if not trials:
        return None
    name, best = min(trials.items(), key=lambda item: item[1].bic)
    return Candidate("scheduling_variable", {"channel": name}, best,
                     f"scheduling also on the recorded channel {name!r}", choices=1)


def dead_zone(u: np.ndarray, width: float) -> np.ndarray:
    return np.sign(u) * np.maximum(np.abs(u) - width, 0.0)


def saturation(u: np.ndarray, limit: float) -> np.ndarray:
    return np.clip(u, -limit, limit)


def _search_level(loss: Callable[[float], float], grid: np.ndarray, maxiter: int = 500) -> float:
    """The level minimising ``loss``: the best point of ``grid``, refined by a bounded scalar search
    between its neighbours (``scipy.optimize.minimize_scalar``)."""
    losses = []
    for level in grid:
        try:
            losses.append(loss(level))
        except LpvflowError:
            losses.append(np.inf)
    i = int(np.argmin(losses))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if hi <= lo:
        return float(grid[i])
    res = scipy.optimize.minimize_scalar(loss, bounds=(lo, hi), method="bounded",
                                         options={"xatol": 1e-4 * hi, "maxiter": maxiter})
    return float(res.x)


#: Output-error fits allowed for refining a level in the noise round (``ctx.estimator == "oe"``).
OE_LEVEL_EVALUATIONS = 6


def _mapped_input_fit(ctx: Context, j: int, nonlin: Callable[[np.ndarray, float], np.ndarray], level: float,
                      estimator: str, stateless: bool = True) -> Fit:
    """The structure fitted with input j replaced by ``nonlin(u_j, level)`` (applied to the whole
    record, so a map with memory runs on continuously into the validation part)."""
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    whole = joined(ctx.est, ctx.val)
    u = whole.u.copy()
    u[:, j] = nonlin(u[:, j], level)
    est, val = replace(ctx.est, u=u[: ctx.est.N]), replace(ctx.val, u=u[ctx.est.N :])

    def mapped(row: np.ndarray) -> np.ndarray:  # the map on the input the loop produces
        out = row.copy()
        out[j] = nonlin(row[j : j + 1], level)[0]
        return out

    return fit(est, val, na, nb, nk, basis, ctx.structure.form,
               ctx.in_loop(input_map=mapped) if stateless else None, estimator)


def _level_of(ctx: Context, j: int, nonlin: Callable, grid: np.ndarray, stateless: bool = True
              ) -> tuple[Fit, float]:
    """Level of ``nonlin`` on input j and its fit: chosen by the LS one-step loss; in the noise round
    (``ctx.estimator == "oe"``) refined by the output-error loss between the LS grid's neighbours of
    that choice, the unbiased criterion under output noise (issue 26, item 4)."""
    def loss(level: float, estimator: str = "arx") -> float:
        return _mapped_input_fit(ctx, j, nonlin, level, estimator, stateless).loss

    level = _search_level(loss, grid)
    if ctx.estimator == "oe":
        step = float(np.median(np.diff(grid)))
        bracket = np.array([max(level - step, float(grid[0]) / 2), level, level + step])
        level = _search_level(lambda w: loss(w, "oe"), bracket, maxiter=OE_LEVEL_EVALUATIONS)
    return _mapped_input_fit(ctx, j, nonlin, level, ctx.estimator, stateless), level


def input_nonlinearity(ctx: Context) -> Candidate | None:
    """Dead zone or saturation at one actuator: width/limit by :func:`_level_of`; the kinds and
    channels compete on the loss of their chosen level."""
    results = []
    for j in range(ctx.nu):
        mag = np.abs(ctx.est.u[:, j])
        for kind, nonlin, grid in (("dead_zone", dead_zone, np.quantile(mag, np.linspace(0.02, 0.6, 15))),
                                   ("saturation", saturation, np.quantile(mag, np.linspace(0.4, 0.98, 15)))):
            best, level = _level_of(ctx, j, nonlin, grid)
            results.append((best, kind, level, j))
    best, kind, level, j = min(results, key=lambda r: r[0].loss)
    what = "width" if kind == "dead_zone" else "limit"
    channel = ctx.est.u_names[j]
    return Candidate("input_nonlinearity", {"kind": kind, what: level, "channel": channel}, best,
                     f"a {kind.replace('_', ' ')} of {what} {level:.4g} on {channel}", choices=1)


@numba.njit(cache=True)
def play(u: np.ndarray, width: float) -> np.ndarray:
    """Backlash (play operator) of total width w: x(k) = min(max(x(k−1), u(k) − w/2), u(k) + w/2),
    x(−1) = 0 — a dead band of ±w/2 with memory: the output moves only when the input pushes it."""
    out = np.empty_like(u)
    state = 0.0
    for k in range(u.shape[0]):
        state = min(max(state, u[k] - width / 2), u[k] + width / 2)
        out[k] = state
    return out


def backlash(ctx: Context) -> Candidate | None:
    """Backlash in one actuator: input j replaced by :func:`play` of width w, chosen by
    :func:`_level_of` over twice the 2–60 % quantiles of |u_j|. Open loop only (the loop's input
    map is memoryless)."""
    if ctx.loop is not None:
        raise LpvflowError("backlash has memory; the identification loop applies memoryless input maps")
    results = []
    for j in range(ctx.nu):
        grid = 2 * np.quantile(np.abs(ctx.est.u[:, j]), np.linspace(0.02, 0.6, 15))
        best, width = _level_of(ctx, j, play, grid, stateless=False)
        results.append((best, width, j))
    best, width, j = min(results, key=lambda r: r[0].loss)
    channel = ctx.est.u_names[j]
    return Candidate("backlash", {"width": width, "channel": channel}, best,
                     f"backlash (dead band with memory) of total width {width:.4g} on {channel}", choices=1)


def sign_feature(y: np.ndarray, i: int, kind: str) -> np.ndarray:
    """The friction input of output i, (N, 1): sign of its backward difference y_i(k) − y_i(k−1)
    when the output is a position, sign of the output itself when it is a velocity."""
    v = np.diff(y[:, i], prepend=y[0, i]) if kind == "position" else y[:, i]
    return np.sign(v)[:, None]


def _friction_kinds(y: np.ndarray, i: int) -> list[str]:
    """Position always; velocity only for an output that moves both ways about zero (≥ 10 % of the
    samples of each sign) — on a one-signed output sign(y) is a constant, i.e. an offset."""
    share = np.mean(y[:, i] > 0)
    return ["position", "velocity"] if 0.1 <= share <= 0.9 else ["position"]


def friction_simulation(model: LPVIO, u: np.ndarray, p: np.ndarray, i: int, velocity: bool) -> np.ndarray:
    """Simulation of a friction extension (its last input the friction sign) from a zero past, the
    sign taken sample by sample from its own output i: sign y_i(k) (velocity output) or
    sign(y_i(k) − y_i(k−1)) (position output). Causal because the friction input enters with a
    delay ≥ 1: y(k) = −Σᵢ Aᵢ y(k−i) + Σⱼ Bⱼ v(k−j), coefficients at ψ(p(k−i)) (shifted form) or
    ψ(p(k)) (static form), v = [u, sign]."""
    psi = model.basis.eval(p, check_range=False)
    a_at = np.einsum("kl,ilrc->kirc", psi, model.A)
    b_at = np.einsum("kl,jlrc->kjrc", psi, model.B)
    return _friction_recursion(np.ascontiguousarray(a_at), np.ascontiguousarray(b_at),
                               np.ascontiguousarray(u, dtype=float), i, velocity,
                               model.form == "shifted")


@numba.njit(cache=True)
def _friction_recursion(a_at: np.ndarray, b_at: np.ndarray, u: np.ndarray, i: int, velocity: bool,
                        shifted: bool) -> np.ndarray:
    n, n_a, ny = a_at.shape[0], a_at.shape[1], a_at.shape[2]
    n_b, nu = b_at.shape[1], u.shape[1]
    y = np.zeros((n, ny))
    sign = np.zeros(n)
    for k in range(n):
        for lag in range(1, n_a + 1):
            if k - lag >= 0:
                at = k - lag if shifted else k
                y[k] -= a_at[at, lag - 1] @ y[k - lag]
        for lag in range(n_b):
            if k - lag >= 0:
                at = k - lag if shifted else k
                y[k] += b_at[at, lag, :, :nu] @ u[k - lag] + b_at[at, lag, :, nu] * sign[k - lag]
        motion = y[k, i] if velocity else y[k, i] - (y[k - 1, i] if k > 0 else y[k, i])
        sign[k] = np.sign(motion)
    return y


def friction(ctx: Context) -> Candidate | None:
    """Coulomb friction: extra input sign(v) with the first input's lags, F = −Σb_f / Σb_u
    (:func:`_coulomb_level`), v the motion of one output — its backward difference (a position
    output) or the output itself (a velocity output, v(k+1) = a v(k) + b (u(k) − F_c sign v(k)));
    every output and kind is tried and the smallest one-step loss kept.

    Closed-loop data: position outputs only, the sign of the velocity over the next sample,
    extrapolated from the last three outputs (:func:`~lpvflow.validate.closed_loop.velocity_sign`),
    fitted on the measured output and simulated in the identification loop from the simulated
    output at each step (causal, no iterations). Open-loop data: :func:`friction_simulation`.
    """
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    nb_f, nk_f = _extend_orders(nb, nk, int(nb[:, 0].max()), max(int(nk[:, 0].min()), 1), 1)
    whole = joined(ctx.est, ctx.val)  # validation: the whole record simulated, its validation part scored
    if ctx.loop is None:
        with np.errstate(over="ignore", invalid="ignore"):
            y_whole = bounded(ctx.nominal.model.simulate(whole.u, whole.p), whole.y)[0]
    trials = []
    for i in range(ctx.ny):
        name = f"sign_d{ctx.est.y_names[i]}"
        if ctx.loop is not None:
            try:
                est = _with_inputs(ctx.est, velocity_sign(ctx.est.y[:, i])[:, None], [name])
                result = ctx.fit(est, ctx.val, na, nb_f, nk_f, basis, ctx.in_loop(sign_of=i))
            except LpvflowError:
                continue
            trials.append((result, i, "position", result.model))
            continue
        for kind in _friction_kinds(ctx.est.y, i):
            name = f"sign_d{ctx.est.y_names[i]}" if kind == "position" else f"sign_{ctx.est.y_names[i]}"

            def simulate_own(model: LPVIO, data: Dataset, i=i, kind=kind) -> np.ndarray:
                with np.errstate(over="ignore", invalid="ignore"):
                    return bounded(friction_simulation(model, data.u, data.p, i, kind == "velocity"),
                                   data.y)[0]

            # Extension (scored and saved): the sign in the estimation data is taken from the model's
            # own simulation, refitted twice from the nominal model; it simulates best. Its level is
            # attenuated (the simulated sign is wrong near zero speed), so the reported level comes
            # from a fit on the measured sign, the signal friction acted on.
            measured_est = _with_inputs(ctx.est, sign_feature(ctx.est.y, i, kind), [name])
            y_est = y_whole[: ctx.est.N]
            try:
                for _ in range(2):
                    est = _with_inputs(ctx.est, sign_feature(y_est, i, kind), [name])
                    result = ctx.fit(est, ctx.val, na, nb_f, nk_f, basis,
                                     lambda m, run=simulate_own: run(m, whole)[ctx.est.N :])
                    y_est = simulate_own(result.model, ctx.est)
                measured = identify_arx(measured_est, na, nb_f, nk_f, basis, form=ctx.structure.form)
            except LpvflowError:
                continue
            trials.append((result, i, kind, measured))
    if not trials:
        return None
    best, i, kind, measured = min(trials, key=lambda t: t[0].loss)
    name = ctx.est.y_names[i]
    level, model_level = _coulomb_level(measured, i), _coulomb_level(best.model, i)
    motion = f"the motion of {name}" if kind == "position" else f"the velocity {name}"
    return Candidate("friction", {"output": name, "output_kind": kind, "coulomb_level_input_units": level,
                                  "level_in_extended_model": model_level}, best,
                     f"Coulomb friction against {motion} (about {level:.3g} in input units)",
                     [f"sign_d{name}" if kind == "position" else f"sign_{name}"], choices=1)


def sensor_saturation(ctx: Context) -> Candidate | None:
    """A clipping sensor: y_meas = clip(y, lo, hi). Equations that hold a measured sample at or beyond
    a limit (as target or lag) are left out of the LS fit, the model's simulation is clipped, and the
    limits are chosen by the estimation-data simulation error: first hi (upper 70–100 % quantiles of
    the output), then lo (lower 0–30 %), each by :func:`_search_level`, and each kept only when it
    lowers that loss (log det) by more than the BIC price of one parameter, ln N / N, and the output
    piles up at that extreme (:func:`_piled_up`) — else that side does not clip (None). Noise added
    after the clip (a sensor that is noisy at its limit) is not covered: the pile-up test needs the
    limit value itself. In the noise round it stays this LS fit (no output-error refinement of the
    masked equations). One output (the best); open loop only. No output piling up at an extreme:
    the cause is untested (LpvflowError), and the search is not run."""
    if ctx.loop is not None:
        raise LpvflowError("sensor saturation is not simulated in the identification loop")
    results = []
    margin = np.log(ctx.est.N) / ctx.est.N  # BIC price of one limit per sample of the log-det loss
    for i in range(ctx.ny):
        y = ctx.est.y[:, i]

        def loss(lo: float, hi: float, i=i) -> float:
            return _clipped_fit(ctx, i, lo, hi)[1]

        hi = lo = None
        if _piled_up(y, y.max()):
            hi = _search_level(lambda h: loss(-np.inf, h), np.quantile(y, np.linspace(0.7, 1.0, 16)))
            if loss(-np.inf, hi) > loss(-np.inf, np.inf) - margin:
                hi = None
        hi_ = np.inf if hi is None else hi
        if _piled_up(y, y.min()):
            lo = _search_level(lambda b, hi=hi_: loss(b, hi), np.quantile(y, np.linspace(0.0, 0.3, 16)))
            if loss(lo, hi_) > loss(-np.inf, hi_) - margin:
                lo = None
        if hi is None and lo is None:
            continue
        lo_ = -np.inf if lo is None else lo
        results.append((_clipped_fit(ctx, i, lo_, hi_)[0], i, [lo, hi]))
    if not results:
        raise LpvflowError("no output piles up at an extreme of its range: no sensor clips")
    best, i, (lo, hi) = min(results, key=lambda r: r[0].loss)
    name = ctx.est.y_names[i]
    return Candidate("sensor_saturation", {"output": name, "lower_limit": lo, "upper_limit": hi}, best,
                     f"the sensor of {name} clips at [{lo if lo is not None else '−∞'}, "
                     f"{hi if hi is not None else '∞'}]", choices=2)


#: Smallest share of samples at an extreme of the output that makes it a clip (:func:`_piled_up`).
CLIP_SHARE = 0.002


def _piled_up(y: np.ndarray, extreme: float) -> bool:
    """Does the output pile up at ``extreme``: ≥ CLIP_SHARE of the samples (and ≥ 3) equal to it
    within 10⁻⁹ of the output's range? A clipping sensor reports its limit; a smooth distribution
    (the even input map of the synthetic out-of-vocabulary case, whose sensor_saturation fit gained
    2.5 points with p = 4·10⁻⁴ without this test) does not."""
    at = np.abs(y - extreme) <= 1e-9 * max(float(np.ptp(y)), 1e-300)
    return bool(at.sum() >= max(3, CLIP_SHARE * len(y)))


def _clipped_fit(ctx: Context, i: int, lo: float, hi: float) -> tuple[Fit, float]:
    """The LS fit without the equations that hold a clipped sample of output i, its clipped
    simulation, and the log det of its estimation-data simulation-error covariance."""
    from lpvflow.identify.iv import Structure as IvStructure

    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    struct = IvStructure.from_data(ctx.est, na, nb, nk, ctx.structure.basis_for(ctx.est.p.shape[1]),
                                   ctx.structure.form)
    psi = struct.basis.eval(ctx.est.p, check_range=False)
    y = ctx.est.y
    clipped = (y[:, i] <= lo) | (y[:, i] >= hi)  # a measured value at the limit is clipped
    window = np.lib.stride_tricks.sliding_window_view(np.r_[np.ones(struct.max_lag, bool), clipped],
                                                      struct.max_lag + 1).any(axis=1)
    keep = ~window
    if keep.sum() < 2 * sum(len(c) for c in struct.columns):
        raise LpvflowError("too few unclipped samples")
    thetas = [np.linalg.lstsq(struct.regressor(r, y, ctx.est.u, psi)[keep], y[keep, r], rcond=None)[0]
              for r in range(struct.ny)]
    model = struct.model(thetas)

    def clip(y_sim: np.ndarray) -> np.ndarray:
        out = y_sim.copy()
        out[:, i] = np.clip(out[:, i], lo, hi)
        return out

    with np.errstate(over="ignore", invalid="ignore"):
        y_est = bounded(clip(model.simulate(ctx.est.u, ctx.est.p)), y)[0]
    sign, logdet = np.linalg.slogdet(np.atleast_2d(np.cov((y - y_est).T)))
    loss = float(logdet) if sign > 0 else np.inf
    model.noise_cov = np.atleast_2d(np.cov((y - y_est).T))
    n_params = sum(len(t) for t in thetas)
    return Fit.scored(model, loss, n_params, ctx.est.N,
                      lambda m: clip(simulate_validation(m, ctx.est, ctx.val)), ctx.val.y, ctx.est), loss


def _coulomb_level(model: LPVIO, i: int) -> float:
    """F = −Σ_j b_f,j / Σ_j b_u,j at ψ_0 in the equation of output i (the moving one): the friction
    input's coefficients are −F times the first input's. Other outputs' equations are left out: in
    a MIMO model their gains differ (ADIP pendulum row), and summing over rows mixes them."""
    b = model.B[:, 0, i]  # ψ_0 components, (lags, nu+1)
    return float(-np.sum(b[:, -1]) / np.sum(b[:, 0])) if np.sum(b[:, 0]) else float("nan")


def offset(ctx: Context) -> Candidate | None:
    """Constant or drifting bias: extra inputs 1 (and t/N) with a lag-0 constant coefficient, or
    (SISO, open loop) a constant sensor offset (:func:`_sensor_offset`), whichever has the smaller
    BIC (the sensor offset's chosen value counted as a parameter).

    The constant-only and constant-plus-trend variants compete by estimation BIC, so a trend is kept
    only when the estimation data support it (a spurious one would be extrapolated into validation).
    On closed-loop data only the constant is tried: a trend fitted on the estimation part is
    extrapolated into the validation part of the loop, where the controller turns it into a drift.
    On the ADIP with a 0.01 rad sensor offset both the one-step and the loop-simulation BIC keep the
    trend, whose extrapolation walks the simulated arm to π (validation BFR 0 %); the constant
    alone simulates at 44/77 % (arm/pendulum).
    """
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    n_total = ctx.est.N + ctx.val.N
    features = {"const": (np.ones(ctx.est.N), np.ones(ctx.val.N)),
                "trend": (np.arange(ctx.est.N) / n_total, np.arange(ctx.est.N, n_total) / n_total)}
    trials = {}
    for names in (["const"],) if ctx.loop is not None else (["const"], ["const", "trend"]):
        est = _with_inputs(ctx.est, np.column_stack([features[f][0] for f in names]), names)
        val = _with_inputs(ctx.val, np.column_stack([features[f][1] for f in names]), names)
        nb_o, nk_o = _extend_orders(nb, nk, 1, 0, len(names))
        try:
            trials[tuple(names)] = ctx.fit(est, val, na, nb_o, nk_o, basis,
                                       ctx.in_loop(exogenous=joined(est, val).u[:, ctx.nu :]))
        except LpvflowError:
            continue
    if not trials:
        return None
    names, best = min(trials.items(), key=lambda item: item[1].bic)
    sensor = _sensor_offset(ctx) if ctx.loop is None and ctx.ny == 1 else None
    if sensor is not None and sensor[0].bic + np.log(ctx.est.N) < best.bic:  # + its one chosen value
        fitted, level = sensor
        return Candidate("offset", {"kind": "sensor", "output_offset": level}, fitted,
                         f"a sensor offset of {level:.4g} on {ctx.est.y_names[0]}", choices=1)
    params = _offset_parameters(best.model, ctx.est.p, ctx.nu, "trend" in names)
    what = "a bias and a trend" if "trend" in names else "a constant bias"
    return Candidate("offset", params, best,
                     f"adding {what} (output-equivalent {np.round(params['output_offset'], 4).tolist()})",
                     list(names))


def _sensor_offset(ctx: Context) -> tuple[Fit, float] | None:
    """A constant sensor offset o (SISO, open loop): the structure fitted to y − o, simulated + o.

    In a shifted LPV model an equation constant c acts on the output as c / A(1, ψ), which varies
    with the scheduling; a sensor offset is the same o at every scheduling value. o is chosen like
    a level (:func:`_search_level` on the LS loss over the output's 2–98 % quantiles; in the noise
    round refined by the output-error loss). Synthetic 0.5 offset, seed 1001: the equation constant
    gained 3.0 points with block p = 0.007 (transients at every scheduling step).
    """
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])

    def trial(o: float, estimator: str = "arx") -> Fit:
        est, val = replace(ctx.est, y=ctx.est.y - o), replace(ctx.val, y=ctx.val.y - o)
        return fit(est, val, na, nb, nk, basis, ctx.structure.form,
                   lambda m: simulate_validation(m, est, val) + o, estimator)

    try:
        level = _search_level(lambda o: trial(o).loss, np.quantile(ctx.est.y, np.linspace(0.02, 0.98, 15)))
        if ctx.estimator == "oe":
            step = 0.1 * float(np.std(ctx.est.y))
            bracket = np.array([level - step, level, level + step])
            level = _search_level(lambda o: trial(o, "oe").loss, bracket, maxiter=OE_LEVEL_EVALUATIONS)
        result = trial(level, ctx.estimator)
    except LpvflowError:
        return None
    result.reference = ctx.val.y
    return result, level


def _offset_parameters(model: LPVIO, p: np.ndarray, nu: int, trend: bool) -> dict:
    """Constant (and trend) coefficients of the offset inputs and the output-equivalent bias."""
    ny = model.ny
    const = model.B[0, 0, :, nu]
    slope = model.B[0, 0, :, nu + 1] if trend else np.zeros(ny)
    # Output-equivalent bias o = A(1, ψ̄)⁻¹ c with A(1, ψ̄) = I + Σ_i A_i(ψ̄) at the mean scheduling.
    psi_mean = model.basis.eval(p, check_range=False).mean(axis=0)
    a_sum = np.eye(ny) + np.einsum("l,ilrc->rc", psi_mean, model.A)
    output_bias = np.linalg.solve(a_sum, const)
    params = {"constant": const.tolist(), "trend": slope.tolist(), "output_offset": output_bias.tolist()}
    return {k: v[0] for k, v in params.items()} if ny == 1 else params


#: Iterations of :func:`closed_loop_iv` (each: one loop simulation and one IV solve).
CLOSED_LOOP_IV_ITERATIONS = 4


def closed_loop_iv(est: Dataset, loop: Loop, start: LPVIO, iterations: int = CLOSED_LOOP_IV_ITERATIONS,
                   data: Dataset | None = None, input_map: Callable | None = None,
                   exogenous: np.ndarray | None = None, sign_of: int | None = None,
                   fallback: np.ndarray | None = None) -> tuple[LPVIO, float]:
    """IV estimate of ``start``'s structure on closed-loop data, and its loss (log det of the
    covariance of its loop-simulation error on ``est``).

    The instruments are the regressors rebuilt from the model's own simulation in the loop
    (:func:`~lpvflow.validate.closed_loop.simulate_in_loop`): outputs, the plant input the
    controller makes of them plus the excitation, and the scheduling recomputed from them — functions
    of the excitation alone, so uncorrelated with the sensor noise, which in a loop also reaches the
    measured input (open-loop IV-OE or output error would take it for signal). Iterated from the LS
    fit; each IV step is halved (up to 4 times) until the loop-simulation error on ``est`` decreases,
    and the iteration stops when no step does.

    An extension's model: ``data`` is its estimation data (the model's inputs as it was fitted), and
    ``input_map``, ``exogenous`` (estimation rows) and ``sign_of`` its drive in the loop
    (:func:`~lpvflow.validate.closed_loop.simulate_in_loop`); the instruments then hold the same
    inputs made from the simulated loop. A velocity-sign input (``sign_of``) is taken from the
    simulated motion in the regressor as well: the sign of a noisy measured velocity is attenuated
    near zero speed (errors in variables), which inflated the Coulomb level by 11–12 % on the ADIP
    under 0.1 mrad of noise (0.35 V for 0.31 V; from the simulated sign 0.287 V).
    ``fallback``: a loop simulation on ``est`` (of another model) whose signals serve as the first
    instruments when ``start`` itself diverges in the loop.
    """
    from lpvflow.identify.iv import Structure as IvStructure
    from lpvflow.identify.iv import solve_instrumental
    from lpvflow.validate.closed_loop import loop_signals

    data = est if data is None else data
    struct = IvStructure.from_data(data, start.na, start.nb, start.nk, start.basis, start.form)
    psi = struct.basis.eval(data.p, check_range=False)
    phis = [struct.regressor(r, data.y, data.u, psi)[struct.max_lag :] for r in range(struct.ny)]
    drive = {"input_map": input_map, "exogenous": exogenous, "sign_of": sign_of}

    def model_inputs(u_sim: np.ndarray, y_sim: np.ndarray) -> np.ndarray:
        parts = [np.array([input_map(row) for row in u_sim]) if input_map is not None else u_sim]
        if exogenous is not None:
            parts.append(np.asarray(exogenous, float).reshape(len(u_sim), -1))
        if sign_of is not None:
            parts.append(velocity_sign(y_sim[:, sign_of])[:, None])
        return np.hstack(parts)

    def loop_loss(model: LPVIO) -> tuple[float, np.ndarray]:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            y_sim = simulate_in_loop(model, est, loop, **drive)
        if not np.all(np.isfinite(y_sim)):
            return np.inf, y_sim
        sign, logdet = np.linalg.slogdet(np.atleast_2d(np.cov((est.y - y_sim).T)))
        return (float(logdet) if sign > 0 else np.inf), y_sim

    best_theta: list[np.ndarray] | None = struct.thetas(start)
    best_loss, y_best = loop_loss(start)
    if not np.isfinite(best_loss):
        if fallback is None or not np.all(np.isfinite(fallback)):
            raise LpvflowError("closed-loop IV: the starting model diverges in the loop")
        best_theta, y_best = None, fallback
    for _ in range(iterations):
        u_sim, p_sim = loop_signals(y_best, est, loop)
        psi_sim = struct.basis.eval(p_sim, check_range=False)
        v_sim = model_inputs(u_sim, y_best)
        if sign_of is not None:  # the friction column of φ: the sign of the simulated motion too
            u_phi = data.u.copy()
            u_phi[:, -1] = v_sim[:, -1]
            phis = [struct.regressor(r, data.y, u_phi, psi)[struct.max_lag :] for r in range(struct.ny)]
        target = [solve_instrumental(struct.regressor(r, y_best, v_sim, psi_sim)[struct.max_lag :], phis[r],
                         est.y[struct.max_lag :, r]) for r in range(struct.ny)]
        step, improved = 1.0, False
        for _ in range(4):  # the IV step, halved until the loop-simulation error decreases
            theta = target if best_theta is None else [
                b + step * (t - b) for b, t in zip(best_theta, target, strict=True)]
            loss, y_sim = loop_loss(struct.model(theta))
            if loss < best_loss:
                best_theta, best_loss, y_best, improved = theta, loss, y_sim, True
                break
            step /= 2
        if not improved:
            break
    if best_theta is None:
        raise LpvflowError("closed-loop IV: every iterate diverged in the loop")
    return struct.model(best_theta), best_loss


def refit_in_loop(cand: Candidate, est: Dataset, loop: Loop,
                  fallback: np.ndarray | None = None) -> Candidate | None:
    """``cand`` refitted by :func:`closed_loop_iv` with its own loop drive (diagnose's noise round on
    closed-loop data); None for an extension that changes the scheduling or cannot be refitted."""
    run = cand.fit.simulate
    if not isinstance(run, LoopSimulation) or run.rescheduled or cand.fit.data is None:
        return None
    drive = run.drive
    exogenous = drive.get("exogenous")
    try:
        model, loss = closed_loop_iv(est, loop, cand.fit.model, data=cand.fit.data,
                                     input_map=drive.get("input_map"), sign_of=drive.get("sign_of"),
                                     exogenous=None if exogenous is None else exogenous[: est.N],
                                     fallback=fallback)
    except (LpvflowError, np.linalg.LinAlgError):
        return None
    refit = Fit.scored(model, loss, cand.fit.n_params, est.N, run, cand.fit.reference, cand.fit.data)
    params = dict(cand.parameters)
    if cand.cause == "friction":
        level = _coulomb_level(model, drive["sign_of"])
        params |= {"coulomb_level_input_units": level, "level_in_extended_model": level}
    elif cand.cause == "offset":
        params = _offset_parameters(model, est.p, est.u.shape[1], "trend" in cand.inputs_added)
    return Candidate(cand.cause, params, refit, cand.description + " (refitted by closed-loop IV)",
                     cand.inputs_added)


def output_noise_bias(ctx: Context) -> Candidate | None:
    """Estimates biased by output noise: the same structure re-estimated consistently.

    Open loop: output error (:func:`output_error`) started from the nominal LS fit and from IV-OE
    (thesis Alg. 4.1) when IV-OE converges, the smaller estimation simulation error kept; the
    candidate's ``loss`` is then the log det of that simulation-error covariance, which
    :func:`lpvflow.validate.diagnose.diagnose` tests against the LS fit (:mod:`~lpvflow.validate.noise`).
    Closed loop: :func:`closed_loop_iv`, scored in the loop (an open-loop simulation error of an
    unstable plant has no meaning), its loss that of the estimation-data loop simulation.
    """
    from lpvflow.identify.iv import identify_iv_oe

    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    starts = []
    try:
        if ctx.loop is not None:
            raise LpvflowError("open-loop IV-OE is not used on closed-loop data")
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            iv_oe = identify_iv_oe(ctx.est, na, nb, nk, basis, form=ctx.structure.form)
        if np.all(np.isfinite(iv_oe.A)) and np.all(np.isfinite(iv_oe.B)):
            starts.append(("iv-oe", iv_oe))
    except (LpvflowError, np.linalg.LinAlgError):  # IV-OE did not converge
        pass
    simulate = ctx.in_loop() or (lambda m: simulate_validation(m, ctx.est, ctx.val))
    if ctx.loop is not None:
        try:
            model, loss = closed_loop_iv(ctx.est, ctx.loop, ctx.nominal.model)
        except (LpvflowError, np.linalg.LinAlgError):
            return None  # the cause stays untested
        refit = Fit.scored(model, loss, ctx.nominal.n_params, ctx.est.N, simulate, ctx.val.y, ctx.est)
        return Candidate("output_noise_bias", {"estimator": "closed-loop iv"}, refit,
                         "re-estimating the same structure by closed-loop IV (instruments from the "
                         "model's own loop simulation, driven by the excitation alone)")
    trials = []
    for label, start in [("ls", ctx.nominal.model), *starts]:
        try:
            model = output_error(ctx.est, start)
        except (LpvflowError, np.linalg.LinAlgError):
            continue
        sign, logdet = np.linalg.slogdet(model.noise_cov)
        if sign > 0 and np.isfinite(logdet):
            trials.append((float(logdet), label, model))
    if not trials:
        return None
    loss, label, model = min(trials, key=lambda t: t[0])
    refit = Fit.scored(model, loss, ctx.nominal.n_params, ctx.est.N, simulate, ctx.val.y)
    return Candidate("output_noise_bias", {"estimator": "output-error", "started_from": label}, refit,
                     "re-estimating the same structure by output error (simulation-error fit)")


EXTENSIONS: dict[str, Callable[[Context], Candidate | None]] = {
    "input_delay": input_delay,
    "model_order": model_order,
    "scheduling_dependence": scheduling_dependence,
    "scheduling_variable": scheduling_variable,
    "input_nonlinearity": input_nonlinearity,
    "backlash": backlash,
    "sensor_saturation": sensor_saturation,
    "friction": friction,
    "output_noise_bias": output_noise_bias,
    "offset": offset,
}
