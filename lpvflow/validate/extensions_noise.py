"""Consistent re-estimation of a structure under output noise, for the diagnosis' noise round: output
error (open loop), and extensions refitted by closed-loop IV (:mod:`lpvflow.validate.closed_loop_iv`,
instruments from the model's own loop simulation) with their own drive in the loop."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import LpvflowError
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import Loop, simulate_in_loop
from lpvflow.validate.closed_loop_iv import closed_loop_iv
from lpvflow.validate.extension_core import (
    Candidate,
    Context,
    Fit,
    LoopSimulation,
    output_error,
    simulate_validation,
)
from lpvflow.validate.extensions_maps import coulomb_level
from lpvflow.validate.extensions_structural import MAX_DELAY_SHIFT, delay_candidate, offset_parameters
from lpvflow.validate.residuals import WHITENING_ORDER, prewhitened_log_det


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
                                     fallback=fallback, sensor_offset=drive.get("sensor_offset"))
    except (LpvflowError, np.linalg.LinAlgError):
        return None
    refit = Fit.scored(model, loss, cand.fit.n_params, est.N, run, cand.fit.reference, cand.fit.data)
    params = dict(cand.parameters)
    if cand.cause == "friction":
        level = coulomb_level(model, drive["sign_of"])
        params |= {"coulomb_level_input_units": level, "level_in_extended_model": level}
    elif cand.cause == "offset" and params.get("kind") != "sensor":
        params = offset_parameters(model, est.p, est.u.shape[1], "trend" in cand.inputs_added)
    return Candidate(cand.cause, params, refit, cand.description + " (refitted by closed-loop IV)",
                     cand.inputs_added, model_map=cand.model_map)


def input_delay_in_loop(cand: Candidate, ctx: Context,
                        fallback: np.ndarray | None = None) -> Candidate | None:
    """Closed loop: the dead time of ``cand`` re-chosen by the closed-loop IV loss, its model refitted
    by :func:`refit_in_loop` (diagnose's noise round); None when that loss prefers the modelled nk.

    Least squares on closed-loop data is biased by the sensor noise the controller feeds back, and so
    is the delay its one-step loss chooses: maglev FMU with a 6 ms (3-sample) actuator dead time,
    Ts = 2 ms, seeds 1–2: nk = 7 for the true 4, whose closed-loop IV refit then gains nothing
    (−0.2 points) while nk = 4 gains +4.5. The delays of every input are shifted together from the LS
    choice, one sample at a time, while the loss of the shifted structure's IV refit decreases — a
    discrete descent within nk ≥ 0 and MAX_DELAY_SHIFT samples of the modelled delay.

    The loss is the log det of that refit's estimation-data loop-simulation error whitened by its own
    AR(WHITENING_ORDER) fit (:func:`~lpvflow.validate.residuals.prewhitened_log_det`), not the
    raw error's that :func:`closed_loop_iv` minimises: the raw error is dominated by the slow response
    to the set-points, the dead time is seen at the excitation's high frequencies. Maglev, seeds 0–9,
    nk = 1 … 7 refitted: the whitened loss is lowest at the true nk = 4 on every seed, the raw one on
    6 (seed 4: −36.522 / −36.517 / −36.518 at nk = 3 / 4 / 5, the descent from 6 stopping at 5; whitened
    −51.528 / −51.532 / −51.530); ADIP, 15 ms (3 samples at 5 ms), seeds 0–9: both at nk = 4.
    """
    na, nb, modelled = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    start = np.broadcast_to(np.asarray(cand.parameters["nk"], int), (ctx.ny, ctx.nu))
    refits: dict[int, Candidate | None] = {}
    losses: dict[int, float] = {}

    def loss(shift: int) -> float:
        if shift not in refits:
            try:
                ls = ctx.fit(ctx.est, ctx.val, na, nb, start + shift, basis, ctx.in_loop())
            except LpvflowError:
                ls = None
            refits[shift] = refit = None if ls is None else refit_in_loop(
                replace(cand, fit=ls), ctx.est, ctx.loop, fallback)
            losses[shift] = np.inf if refit is None else _whitened_loop_loss(refit.fit.model, ctx)
        return losses[shift]

    def allowed(shift: int) -> bool:
        return (start + shift).min() >= 0 and (start + shift - modelled).max() <= MAX_DELAY_SHIFT

    shift = 0
    for step in (-1, 1):
        while allowed(shift + step) and loss(shift + step) < loss(shift):
            shift += step
    best = refits[shift]
    found = None if best is None else delay_candidate(ctx, start + shift, best.fit)
    return None if found is None else replace(found, description=found.description
                                              + " (refitted by closed-loop IV)")


def _whitened_loop_loss(model: LPVIO, ctx: Context) -> float:
    """:func:`~lpvflow.validate.residuals.prewhitened_log_det` of ``model``'s loop-simulation error on
    the estimation data; ∞ when the loop diverges there."""
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        y_sim = simulate_in_loop(model, ctx.est, ctx.loop)
    if not np.all(np.isfinite(y_sim)):
        return np.inf
    return prewhitened_log_det(ctx.est.y - y_sim, WHITENING_ORDER)


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


