"""Does the simulation error depend on the direction of the output's motion? (step 6 of
:mod:`lpvflow.validate.diagnose`).

A sensor with play (hysteresis of total width w: the reading moves only once the output has pushed it
past ±w/2) reads y − (w/2)·sign(ẏ) while the output moves and stays put for a while after each reversal:
the error of a model that simulates y steps by up to w at every reversal of the motion. No cause of the
vocabulary is a function of the output's direction of motion (friction and backlash act on the input,
before the plant's dynamics smooth them), and a linear model cannot form it from the input history, so
a verdict whose model leaves that step is not the cause: it is ``unexplained``.

The test, per output of the model's validation simulation ŷ and error e = y − ŷ:

* the direction of motion d(k) ∈ {−1, +1} is that of ŷ's last move beyond a dead band b (a play operator
  of width 2b on ŷ: :func:`held_direction`), so that a settling ŷ keeps the direction of its last move as
  a sensor with play does, for b in DEAD_BANDS times the standard deviation of ŷ (the play's width is
  not known);
* e is regressed by least squares on d and on nuisance regressors — a constant and lags 0 … NUISANCE_LAGS
  of ŷ and of every input, so that a dynamic misfit linear in the input history (a lag or gain error,
  which also correlates with the direction of motion) is not counted — with e and all regressors
  prewhitened by the AR filter of the nuisance regression's residual (order
  :data:`~lpvflow.validate.residuals.WHITENING_ORDER`; Box & Jenkins, *Time Series Analysis*, §11.2:
  the error of a simulation is strongly coloured, and a t statistic of white residuals is then valid);
* the coefficient c of d is significant when its t statistic exceeds z at α/(2·m) (two-sided,
  Bonferroni over the m = outputs × dead bands tested), and material when the step it implies, 2|c|, is
  at least DIRECTION_STEP standard deviations of the prewhitened residual — the reading jumps at a
  reversal by more than the error's unpredictable part at one sample.

Measured on the plant records of ``tests/diagnosis_fmu_cases.py`` (seeds 0–4, clean 0–9; the verdict's
model as the diagnosis tests it): sensor hysteresis on the tanks, airpath and ADIP 2|c|/σ = 1.93–3.63 at
t = 9.8–49; every clean record below 1.28 (airpath, t = 5.8: the approximate poly:2 structure leaves a
small, significant direction dependence), every in-vocabulary record below 0.83 (dead times, input
maps, offsets, sensor noise, friction). The step found is a fraction of the play's width (seed 0: tanks 5 mm:
0.8 mm; airpath 3 kPa: 1.1 kPa; ADIP 2 mrad: 0.2 / 0.5 mrad on arm / pendulum): the model,
fitted to the played reading, takes up part of it. The maglev's play (0.2 mm) is not material: its
controller holds the *measured* positions on their set-points, so the loop moves the play into the
coil currents and the position error steps by 2.5 / 3.4 µm (seed 1; seeds 0–4: t = 9.4–12.6,
2|c|/σ = 0.75–0.92, where the maglev friction's extended model is 0.49 at t = 8.0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal
from scipy.stats import norm

from lpvflow.validate.diagnose_summary import NOISE
from lpvflow.validate.extensions import Candidate, Context, Fit
from lpvflow.validate.residuals import WHITENING_ORDER, whitening_filter

#: Dead bands of the direction of motion, in standard deviations of the simulated output.
DEAD_BANDS = (0.005, 0.01, 0.02, 0.04)
#: Lags of the simulated output and of every input among the nuisance regressors.
NUISANCE_LAGS = 10
#: Smallest step 2|c| at a reversal, in standard deviations of the prewhitened residual, that is material.
DIRECTION_STEP = 1.5


def held_direction(y_sim: np.ndarray, band: float) -> np.ndarray:
    """The direction of ŷ's last move beyond ``band`` (+1 up, −1 down, 0 before the first such move): the
    direction of motion of a play operator of width 2·``band`` driven by ``y_sim``."""
    direction = np.zeros(len(y_sim))
    state, last = float(y_sim[0]), 0.0
    for k, value in enumerate(y_sim):
        if value > state + band:
            state, last = value - band, 1.0
        elif value < state - band:
            state, last = value + band, -1.0
        direction[k] = last
    return direction


def lagged(x: np.ndarray, lags: int) -> np.ndarray:
    """Columns x(k), x(k−1), …, x(k−lags), zero before the start."""
    return np.column_stack([np.r_[np.zeros(lag), x[: len(x) - lag]] for lag in range(lags + 1)])


@dataclass(frozen=True)
class LastCoefficient:
    """The coefficient c of the last regressor in the prewhitened regression of e on [nuisance, x]:
    its t statistic, σ of the prewhitened residual, and the prewhitened regressors f."""

    c: float
    t: float
    sigma: float
    f: np.ndarray


def prewhitened_last_coefficient(e: np.ndarray, nuisance: np.ndarray, x: np.ndarray) -> LastCoefficient:
    """e and [``nuisance``, ``x``] filtered by the AR(WHITENING_ORDER) whitening filter of the nuisance
    regression's residual, then regressed by least squares (module docstring); t = 0 where σ or the
    variance of c vanishes."""
    residual = e - nuisance @ np.linalg.lstsq(nuisance, e, rcond=None)[0]
    whitening = whitening_filter(residual, WHITENING_ORDER)
    f = scipy.signal.lfilter(whitening, 1.0, np.column_stack([nuisance, x]), axis=0)[WHITENING_ORDER:]
    g = scipy.signal.lfilter(whitening, 1.0, e)[WHITENING_ORDER:]
    coef = np.linalg.lstsq(f, g, rcond=None)[0]
    left = g - f @ coef
    sigma = float(np.sqrt(left @ left / (len(g) - f.shape[1])))
    variance = sigma**2 * np.linalg.pinv(f.T @ f)[-1, -1]
    if sigma == 0 or variance <= 0:
        return LastCoefficient(float(coef[-1]), 0.0, sigma, f)
    return LastCoefficient(float(coef[-1]), float(coef[-1] / np.sqrt(variance)), sigma, f)


def _direction_coefficient(e: np.ndarray, nuisance: np.ndarray, direction: np.ndarray) -> tuple[float, float]:
    """(t statistic, step 2|c| over the prewhitened residual's standard deviation) of the coefficient c
    of ``direction`` (:func:`prewhitened_last_coefficient`)."""
    fit = prewhitened_last_coefficient(e, nuisance, direction)
    if fit.t == 0.0:
        return 0.0, 0.0
    return fit.t, 2 * abs(fit.c) / fit.sigma


def direction_dependence(y: np.ndarray, y_sim: np.ndarray, u: np.ndarray, alpha: float) -> dict:
    """The test of the module docstring on the error ``y`` − ``y_sim`` (N, outputs) with the inputs
    ``u`` (N, inputs) among the nuisance regressors: the largest material step among the significant
    coefficients, its t statistic, output and dead band; ``significant`` when one is material."""
    start = NUISANCE_LAGS + 1
    tests = []
    for i in range(y.shape[1]):
        y_hat = y_sim[:, i]
        nuisance = np.column_stack([np.ones(len(y_hat)), lagged(y_hat, NUISANCE_LAGS),
                                    *(lagged(x, NUISANCE_LAGS) for x in u.T)])[start:]
        e = (y[:, i] - y_hat)[start:]
        for band in DEAD_BANDS:
            direction = held_direction(y_hat, band * np.std(y_hat))[start:]
            if np.std(direction) > 0:
                tests.append((i, band, *_direction_coefficient(e, nuisance, direction)))
    bound = float(norm.isf(alpha / (2 * max(len(tests), 1))))
    significant = [t for t in tests if abs(t[2]) > bound]
    output, band, t_stat, step = max(significant, key=lambda t: t[3], default=(0, 0.0, 0.0, 0.0))
    return {"step_over_sigma": step, "t": t_stat, "bound": bound, "output": int(output), "dead_band": band,
            "threshold": DIRECTION_STEP, "alpha": alpha, "significant": bool(step >= DIRECTION_STEP)}


def direction_verdict(ctx: Context, cause: str, final: Fit, pool: dict[str, Candidate], adequacy: dict | None,
                      alpha: float) -> tuple[str, dict | None]:
    """``unexplained`` when the verdict's model — ``final`` for ``none`` or a noise verdict, the named
    extension's otherwise — leaves an error that depends on the direction of the output's motion
    (:func:`direction_dependence` on the validation split), the test in ``adequacy["motion_direction"]``;
    otherwise the verdict unchanged. Not run on ``unexplained``, ``ambiguous`` or a diverged model."""
    noise_verdict = cause in ("none", NOISE, "colored_noise")
    model = final if noise_verdict else (pool[cause].fit if cause in pool else None)
    if model is None or model.diverged or adequacy is None:
        return cause, adequacy
    test = direction_dependence(ctx.val.y, model.y_val, ctx.val.u, alpha)
    if not test["significant"]:
        return cause, adequacy
    return "unexplained", adequacy | {"motion_direction": test | {"cause": cause}}
