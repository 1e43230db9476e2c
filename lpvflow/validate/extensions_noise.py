"""Consistent re-estimation of a structure under output noise: output error (open loop) and
closed-loop IV (instruments from the model's own loop simulation), for the diagnosis' noise round."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import LpvflowError
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import Loop, simulate_in_loop, velocity_sign
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

#: Iterations of :func:`closed_loop_iv` (each: one loop simulation and one IV solve).
CLOSED_LOOP_IV_ITERATIONS = 4


def closed_loop_iv(est: Dataset, loop: Loop, start: LPVIO, iterations: int = CLOSED_LOOP_IV_ITERATIONS,
                   data: Dataset | None = None, input_map: Callable | None = None,
                   exogenous: np.ndarray | None = None, sign_of: int | None = None,
                   fallback: np.ndarray | None = None,
                   sensor_offset: np.ndarray | None = None) -> tuple[LPVIO, float]:
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
    under 0.1 mrad of noise (0.35 V for 0.31 V; from the simulated sign 0.287 V). A sensor offset o
    (``sensor_offset``, ``data`` the outputs less o): the loop simulation gives y + o, which the
    controller read; the instruments and the scheduling are made from the model's own output y.
    ``fallback``: a loop simulation on ``est`` (of another model) whose signals serve as the first
    instruments when ``start`` itself diverges in the loop.
    """
    from lpvflow.identify.iv import Structure as IvStructure
    from lpvflow.identify.iv import solve_instrumental
    from lpvflow.validate.closed_loop import loop_scheduling, loop_signals

    data = est if data is None else data
    struct = IvStructure.from_data(data, start.na, start.nb, start.nk, start.basis, start.form)
    psi = struct.basis.eval(data.p, check_range=False)
    phis = [struct.regressor(r, data.y, data.u, psi)[struct.max_lag :] for r in range(struct.ny)]
    drive = {"input_map": input_map, "exogenous": exogenous, "sign_of": sign_of,
             "sensor_offset": sensor_offset}
    o = np.zeros(struct.ny) if sensor_offset is None else np.asarray(sensor_offset, float)

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
        u_sim = loop_signals(y_best, est, loop)[0]
        p_sim = loop_scheduling(y_best - o, est, loop)
        psi_sim = struct.basis.eval(p_sim, check_range=False)
        v_sim = model_inputs(u_sim, y_best)
        if sign_of is not None:  # the friction column of φ: the sign of the simulated motion too
            u_phi = data.u.copy()
            u_phi[:, -1] = v_sim[:, -1]
            phis = [struct.regressor(r, data.y, u_phi, psi)[struct.max_lag :] for r in range(struct.ny)]
        target = [solve_instrumental(struct.regressor(r, y_best - o, v_sim, psi_sim)[struct.max_lag :],
                                     phis[r], data.y[struct.max_lag :, r]) for r in range(struct.ny)]
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
    choice, one sample at a time, while the IV loss (log det of the loop-simulation error covariance
    on estimation data, as :func:`closed_loop_iv` minimises it) decreases — a discrete descent
    (seed 1: −36.43 at nk = 1, −36.71 at 4, −36.39 at 7), within nk ≥ 0 and MAX_DELAY_SHIFT samples
    of the modelled delay.
    """
    na, nb, modelled = ctx.structure.orders(ctx.ny, ctx.nu)
    basis = ctx.structure.basis_for(ctx.est.p.shape[1])
    start = np.broadcast_to(np.asarray(cand.parameters["nk"], int), (ctx.ny, ctx.nu))
    refits: dict[int, Candidate | None] = {}

    def loss(shift: int) -> float:
        if shift not in refits:
            try:
                ls = ctx.fit(ctx.est, ctx.val, na, nb, start + shift, basis, ctx.in_loop())
            except LpvflowError:
                ls = None
            refits[shift] = None if ls is None else refit_in_loop(
                replace(cand, fit=ls), ctx.est, ctx.loop, fallback)
        refit = refits[shift]
        return np.inf if refit is None else refit.fit.loss

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


