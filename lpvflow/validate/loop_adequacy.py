"""Adequacy of a model simulated in the identification loop (the diagnosis' step 6 on closed-loop data,
:mod:`lpvflow.validate.diagnose`).

In a loop the plant input u is not exogenous: the controller feeds the output error back, so the
simulation error of even an adequate model is correlated with u. The signals that are exogenous are
those the loop simulation (:func:`~lpvflow.validate.closed_loop.simulate_in_loop`) takes as given:
the excitation r on the driven inputs, the recorded values of the other inputs, the controller's
set-points and the recorded scheduling columns that are not recomputed from the outputs
(:func:`exogenous_signals`). The output noise and its response through the loop are independent of
them, and so is the in-loop simulation error e = y − ŷ of an adequate model: no function of their
history explains it (Ljung, System Identification, 2nd ed., §16.6, cross-correlation test against
the exogenous input of a closed-loop experiment, here generalised to the nonlinear features of
:func:`~lpvflow.validate.noise_analysis.features`). The model's own in-loop simulation ŷ is a
function of that history too, so :func:`~lpvflow.validate.noise_analysis.output_features` of ŷ
join the regressors.

The lags reach the loop's settling time (:func:`loop_settling_samples`), measured on the model's own
loop: the response of its in-loop simulation to a pulse added to the excitation.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.signal
from scipy.stats import norm

from lpvflow.data import Dataset
from lpvflow.lpvio import LPVIO
from lpvflow.validate import residuals
from lpvflow.validate.closed_loop import Loop, loop_signals, simulate_in_loop
from lpvflow.validate.metrics import bfr
from lpvflow.validate.noise_analysis import FEATURE_LAGS, SETTLING_LAGS, features, output_features

#: The pulse added to the excitation to measure the loop's settling time, in standard deviations of
#: the excitation (small, so that the loop's response stays in its linear range).
PULSE_SCALE = 0.1
#: Settled: the pulse response below this share of its peak (the 2 % of a settling time).
SETTLED = 0.02


def exogenous_signals(whole: Dataset, loop: Loop) -> tuple[np.ndarray, np.ndarray]:
    """(inputs, scheduling) that the loop simulation takes as given over ``whole``: the excitation
    on the driven inputs, the recorded undriven inputs and the finite, varying set-points; the recorded
    scheduling columns without an expression in the loop (module docstring)."""
    driven = set(loop.controller.outputs)
    undriven = [whole.u[:, j] for j, name in enumerate(whole.u_names) if name not in driven]
    references = np.zeros((whole.N, 0)) if loop.references is None else np.asarray(loop.references, float)
    given = [s for s in references[: whole.N].T if np.all(np.isfinite(s)) and np.std(s) > 0]
    inputs = np.column_stack([loop.excitation[: whole.N], *undriven, *given])
    kept = [i for i, name in enumerate(whole.p_names) if name not in loop.scheduling]
    return inputs, whole.p[:, kept]


@dataclass(frozen=True)
class LoopReference:
    """What the adequacy tests of a closed-loop diagnosis take from the final model's loop (module
    docstring): the loop's settling time in samples and the functions of the exogenous history the
    error is regressed on (whole record): ``inputs`` — :func:`exogenous_signals` and the plant input
    the model's loop produced — and ``scheduling`` — the recorded columns the loop takes as given and
    those it recomputed from the model's outputs."""

    settling: int
    inputs: np.ndarray
    scheduling: np.ndarray


def model_loop(model: LPVIO, whole: Dataset, loop: Loop, start: int,
               y_from_start: np.ndarray) -> LoopReference:
    """The :class:`LoopReference` of ``model`` over ``whole`` (``y_from_start``: its in-loop simulation from
    sample ``start`` on). One more loop simulation, with a pulse of PULSE_SCALE excitation standard
    deviations added to every driven input at ``start``: before ``start`` it is the model's in-loop
    simulation itself, from ``start`` on its change is the loop's pulse response, and the settling time
    is the last sample at which that change exceeds SETTLED of its peak on some output (the samples
    left when it has not settled by the record's end). The model's loop signals (plant input and
    recomputed scheduling, :func:`~lpvflow.validate.closed_loop.loop_signals`) are rebuilt from its
    simulation: functions of the exogenous history, so no output noise correlates with them, while the
    excitation alone, seen through polynomials of its lags, misses much of an input map the loop's
    input passes through (an actuator map f(u) = u + 0.1u³ in a first-order loop, seeds 0–2: with the
    loop input 13.6–15.6 points explained, p ≤ 5·10⁻⁶; the excitation alone 4.6–8.3, p ≥ 0.005)."""
    pulse = np.zeros_like(loop.excitation)
    pulse[start] = PULSE_SCALE * np.where((s := loop.excitation.std(axis=0)) > 0, s, 1.0)
    pulsed = simulate_in_loop(model, whole, replace(loop, excitation=loop.excitation + pulse))
    change = np.abs(pulsed[start:] - y_from_start)
    if np.all(np.isfinite(change)):
        peak = change.max(axis=0)
        above = np.flatnonzero(np.any(change > SETTLED * np.where(peak > 0, peak, np.inf), axis=1))
        settling = int(above[-1]) + 1 if above.size else 0
    else:
        settling = len(change)
    u_loop, p_loop = loop_signals(np.vstack([pulsed[:start], y_from_start]), whole, loop)
    exo_inputs, exo_scheduling = exogenous_signals(whole, loop)
    driven = [whole.u_names.index(name) for name in loop.controller.outputs]
    computed = [i for i, name in enumerate(whole.p_names) if name in loop.scheduling]
    return LoopReference(settling, np.column_stack([exo_inputs, u_loop[:, driven]]),
                         np.column_stack([exo_scheduling, p_loop[:, computed]]))


def loop_adequacy_lags(settling: int, n_est: int) -> np.ndarray:
    """Lags 0 … FEATURE_LAGS, then SETTLING_LAGS more spread geometrically up to ``settling`` samples
    (at most a tenth of the ``n_est`` estimation samples), as :func:`~lpvflow.validate.noise_analysis.
    adequacy_lags` does with an open-loop settling time."""
    settle = min(settling, n_est // 10)
    dense = np.arange(FEATURE_LAGS + 1)
    if settle <= FEATURE_LAGS:
        return dense
    spread = np.round(np.geomspace(FEATURE_LAGS, settle, SETTLING_LAGS + 1)).astype(int)
    return np.unique(np.r_[dense, spread])


def explained_in_loop(est: Dataset, val: Dataset, reference: LoopReference, y_val: np.ndarray,
                      min_gain: float, alpha: float) -> dict:
    """Is the in-loop simulation error y − ŷ on the validation split (``y_val``: ŷ, of the nominal model or
    an extended one) explained by the exogenous history (module docstring)? The correction F c is
    fitted by least squares on the first half of the validation split and scored on the second half,
    per output (BFR gain and block signed-rank p, :func:`_scored`), as
    :func:`~lpvflow.validate.noise_analysis.explained_within_validation` does for an extended model in
    open loop. F: :func:`features` of the ``reference``'s signals (:func:`model_loop`) at the lags of
    :func:`loop_adequacy_lags` and :func:`output_features` of ŷ without its level terms ŷ, ŷ²: the
    loop's operating point moves between the halves, and a correction in them fitted on one half lost
    19–22 points on the other (ADIP with a rate-limited actuator, seed 0), hiding what the other
    features explain.

    Fitting within the validation split is what finds a model that is wrong there: the nominal model
    is fitted on the estimation split, which absorbs part of a drifting actuator gain into its
    parameters; fitted on the estimation split and scored on the validation split, the correction found
    nothing on the ADIP with its voltage gain drifting to 1.4 (−0.6 and +0.7 points, seeds 0 and 1);
    fitted and scored within the validation split, +11.6 and +13.0."""
    lags = loop_adequacy_lags(reference.settling, est.N)
    feats = np.hstack([features(reference.inputs, reference.scheduling, lags)[est.N :],
                       output_features(y_val, start=est.N / (est.N + val.N), level=False)])
    half = val.N // 2
    coef = np.linalg.lstsq(feats[:half], (val.y - y_val)[:half], rcond=None)[0]
    return _scored(val.y[half:], y_val[half:], y_val[half:] + feats[half:] @ coef, val.y_names,
                   feats.shape[1], lags, min_gain, alpha) | {"loop_settling_samples": reference.settling}


def _scored(y: np.ndarray, y_sim: np.ndarray, corrected: np.ndarray, names: list[str], n_features: int,
            lags: np.ndarray, min_gain: float, alpha: float) -> dict:
    """BFR gain of ``corrected`` over ``y_sim`` and the block signed-rank p of their squared errors
    (:func:`residuals.block_signed_rank`), per output; ``significant``: on some output gain ≥
    ``min_gain`` and p < ``alpha``."""
    gains = bfr(y, corrected) - bfr(y, y_sim)
    p_values = [residuals.block_signed_rank((y - y_sim)[:, i] ** 2, (y - corrected)[:, i] ** 2)[1]
                for i in range(y.shape[1])]
    k = int(np.argmax(gains))
    return {"bfr_gain": float(gains[k]), "p_value": float(p_values[k]),
            "per_output": [{"output": name, "bfr_gain": float(g), "p_value": float(q)}
                           for name, g, q in zip(names, gains, p_values, strict=True)],
            "features": n_features, "lags": [int(lags.min()), int(lags.max())],
            "regressors": "excitation, set-points, recorded signals and the model's loop signals",
            "significant": any(g >= min_gain and q < alpha for g, q in zip(gains, p_values, strict=True))}


#: Lags 0 … CORRELATION_LAGS of the residual cross-correlation test (:func:`correlated_with_excitation`).
CORRELATION_LAGS = 20

def correlated_with_excitation(y: np.ndarray, y_sim: np.ndarray, exogenous: np.ndarray, alpha: float) -> dict:
    """The residual cross-correlation test of the in-loop simulation error ε = y − ŷ against the
    loop's exogenous signals x (``exogenous``: :func:`exogenous_signals` over the same samples), with
    the noise model in it (Ljung, System Identification, 2nd ed., §16.6; prewhitening: Box & Jenkins,
    Time Series Analysis, §11.2). Per output, Â(q) = 1 + â₁q⁻¹ + … + â_n q⁻ⁿ (n =
    :data:`~lpvflow.validate.residuals.WHITENING_ORDER`) is the least-squares AR fit of ε
    (:func:`~lpvflow.validate.residuals.whitening_filter`); ε̃ = Â(q)ε and x̃ = Â(q)x, and

        r̂(τ) = Σₜ x̃(t−τ) ε̃(t) / (Σ x̃² · Σ ε̃²)^½,   τ = 0 … CORRELATION_LAGS,

    is, for ε independent of x, approximately N(0, 1/N). ``significant``: max √N |r̂(τ)| over lags,
    outputs and signals above z at α / (2 (CORRELATION_LAGS + 1) m), m the output–signal pairs
    (Bonferroni). The error of an adequate model in the loop and its filtered form are independent of
    the excitation whatever their colour; a rate-limited actuator leaves a linear dependence on it that
    the regression of :func:`explained_in_loop`, with hundreds of regressors fitted on half the
    validation split, does not turn into a significant BFR gain (ADIP with a 150 V/s limit, seeds 0–2:
    √N |r̂| 7.8 / 6.5 / 7.3 against 1.0–3.6 on the clean records, seeds 0–4)."""
    n = residuals.WHITENING_ORDER
    taus = range(CORRELATION_LAGS + 1)
    x = exogenous - exogenous.mean(axis=0)
    largest, pairs = 0.0, 0
    for e in (y - y_sim).T:
        e = e - e.mean()
        whitening = residuals.whitening_filter(e, n)  # Â(q)
        e_w = scipy.signal.lfilter(whitening, 1.0, e)[n:]
        for column in x.T:
            x_w = scipy.signal.lfilter(whitening, 1.0, column)[n:]
            if not (np.any(x_w) and np.any(e_w)):
                continue
            pairs += 1
            r = np.abs(residuals.cross_correlation(e_w, x_w, taus)).max()
            largest = max(largest, float(np.sqrt(len(e_w)) * r))
    bound = float(norm.isf(alpha / (2 * len(taus) * pairs))) if pairs else np.inf
    return {"largest": largest, "bound": bound, "lags": [0, CORRELATION_LAGS], "pairs": pairs,
            "significant": largest > bound}
