"""A named dead time must be one dead time: the same delay after small and after large input moves
(step 4 of :mod:`lpvflow.validate.diagnose`).

An in-vocabulary effect has one parameter whatever part of the record it is estimated on: a dead time
at the actuators delays every move by the same nk samples. A delay standing in for an effect outside
the vocabulary does not: the delay that best imitates an input rate limiter grows with the size of the
move (a step of size Δ under rate r lags by about |Δ|/(2r)). So the named delay is re-estimated on two
groups of least-squares equations chosen by the inputs alone — the rows whose input regressors span a
move (the range of an input, in units of its standard deviation, over the window the searched input
lags cover is above zero), split at the median of that range into *small* and *large* moves — and must
lie within the estimation uncertainty of both.

Test (profile likelihood of a discrete parameter; Raue et al., Bioinformatics 25(15), 2009, Sec. 2, the
construct of the sensor offset's identifiability in
:func:`~lpvflow.validate.extensions_structural._sensor_offset`): with every input delay shifted by a
common d from the named ones (d ∈ [−SHIFT_RANGE, SHIFT_RANGE], every delay ≥ 0), the LPV-ARX
coefficients are fitted by least squares on the rows of group g alone (the rows are chosen by the
inputs, so the selection does not bias the equation-error fit), V_g(d) = log det of the residual
covariance over its n_g rows, and

    Λ_g = n_g·(V_g(0) − min_d V_g(d))

is the likelihood-ratio statistic of the named delay on that group. The delay is inconsistent — the
cause ``unexplained`` with evidence ``inconsistent_parameter`` — when Λ_g > χ²₁(1 − α/2) for a group
(both groups at the diagnosis' α together, Bonferroni). The delays are shifted as the extension fitted
them (:func:`~lpvflow.validate.extensions_structural.input_delay`): the structure's nk, or, with an
``actuator_delay`` map, the inputs and their scheduling images delayed in the data.

Scope: open-loop records whose dead time was named among least-squares fits. After the noise round the
delay is named by output error, and least squares on a group is biased by the output noise (tanks FMU,
3 s dead time, named nk = 4 by output error: least squares gives nk = 5 on both groups, seed 0); in
closed loop the input is fed back from the noise, so the rows would be chosen by the noise.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.stats import chi2

from lpvflow.data import Dataset
from lpvflow.identify.arx import fill_regressor, row_columns
from lpvflow.validate.extension_core import joined
from lpvflow.validate.extensions import Candidate, Context
from lpvflow.validate.extensions_structural import actuator_delay_map, delayed_splits, scheduling_images

#: Common shifts d from the named delays that each group may choose (samples).
SHIFT_RANGE = 3


def delay_consistency(ctx: Context, delay: Candidate, alpha: float) -> dict | None:
    """The named dead time of ``delay`` tested on the rows after small and after large input moves
    (module docstring): each group's best delay, its statistic Λ_g and whether the named delay is
    rejected on a group at ``alpha``; None when a group has too few rows to fit."""
    na, nb, nk = ctx.structure.orders(ctx.ny, ctx.nu)
    named = np.asarray(delay.parameters["nk"]).reshape(1, -1) * np.ones((ctx.ny, 1), int)
    movable = named if delay.model_map is None else np.asarray(delay.model_map.values["input_delays"])
    shifts = list(range(-min(SHIFT_RANGE, int(movable.min())), SHIFT_RANGE + 1))
    trials = [_shifted(ctx, delay, nk, named, d) for d in shifts]
    first = max(max(int(na.max(initial=0)), int((t_nk + nb - 1).max())) for _, t_nk in trials)
    window = int((named + SHIFT_RANGE + nb).max())
    groups = _move_groups(ctx.est.u, first, window)
    if min(len(g) for g in groups) <= 2 * _n_columns(ctx, na, nb, nk):
        return None
    losses = np.array([_group_losses(ctx, est, na, nb, t_nk, first, groups) for est, t_nk in trials])
    zero = shifts.index(0)
    statistic = losses[zero] - losses.min(axis=0)
    best = [(named[0] + shifts[int(np.argmin(column))]).tolist() for column in losses.T]
    found = [b if ctx.nu > 1 else b[0] for b in best]
    return {"cause": "input_delay", "parameter": "nk", "named": delay.parameters["nk"],
            "small_moves": found[0], "large_moves": found[1],
            "likelihood_ratio": statistic.tolist(), "alpha": alpha,
            "inconsistent": bool(statistic.max() > chi2.ppf(1 - alpha / 2, 1))}


def _shifted(ctx: Context, delay: Candidate, nk: np.ndarray, named: np.ndarray,
             d: int) -> tuple[Dataset, np.ndarray]:
    """(estimation data, nk) of the named delays shifted by d, fitted as the extension fits them."""
    if delay.model_map is None:
        return ctx.est, named + d
    moved = np.asarray(delay.model_map.values["input_delays"]) + d
    model_map = actuator_delay_map(moved, scheduling_images(joined(ctx.est, ctx.val)), ctx.est.p.shape[1])
    return delayed_splits(ctx, model_map)[0], nk


def _move_groups(u: np.ndarray, first: int, window: int) -> list[np.ndarray]:
    """Rows k ≥ ``first`` (numbered from ``first``) whose inputs move within the ``window`` samples
    up to k, split at the median move size: [small moves, large moves]."""
    scaled = (u - u.mean(axis=0)) / np.where(u.std(axis=0) > 0, u.std(axis=0), 1.0)
    padded = np.vstack([np.repeat(scaled[:1], window - 1, axis=0), scaled])
    spans = sliding_window_view(padded, window, axis=0)  # (N, nu, window)
    size = (spans.max(axis=2) - spans.min(axis=2)).max(axis=1)[first:]
    moving = np.flatnonzero(size > 0)
    median = np.median(size[moving]) if len(moving) else 0.0
    return [moving[size[moving] <= median], moving[size[moving] > median]]


def _n_columns(ctx: Context, na: np.ndarray, nb: np.ndarray, nk: np.ndarray) -> int:
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    return max(len(row_columns(r, na, nb, nk, basis.n_psi, ctx.structure.form == "shifted"))
               for r in range(ctx.ny))


def _group_losses(ctx: Context, est: Dataset, na: np.ndarray, nb: np.ndarray, nk: np.ndarray, first: int,
                  groups: list[np.ndarray]) -> list[float]:
    """Per group of rows, n_g·log det of the residual covariance of the LPV-ARX least-squares fit on
    those rows alone (the regressors built once for all groups)."""
    basis = ctx.structure.basis_for(est.p.shape[1]).with_range(est.p)
    shifted = ctx.structure.form == "shifted"
    psi = basis.eval(est.p, check_range=False)
    residuals = [np.empty((len(rows), ctx.ny)) for rows in groups]
    for r in range(ctx.ny):
        cols = row_columns(r, na, nb, nk, basis.n_psi, shifted)
        phi = np.empty((est.N - first, len(cols)))
        fill_regressor(phi, cols, est.y, est.u, psi, first, est.N, 0, shifted)
        for rows, left in zip(groups, residuals, strict=True):
            target = est.y[first:, r][rows]
            theta = np.linalg.lstsq(phi[rows], target, rcond=None)[0]
            left[:, r] = target - phi[rows] @ theta
    return [len(left) * float(np.linalg.slogdet(left.T @ left / len(left))[1]) for left in residuals]
