"""Does the simulation error follow the deficit of a rate-limited input? (step 7 of
:mod:`lpvflow.validate.diagnose`).

An actuator with a rate limit r applies u_a(k) = u_a(k−1) + clip(u(k) − u_a(k−1), −r·Ts, r·Ts): it lags
the command only after moves faster than r, by the deficit δ_r = u_a − u, which grows with the size of
the move and lasts |Δu|/r. No cause of the vocabulary forms δ_r (a dead time delays every move alike, an
input map acts on the level of u, not on its rate), so a verdict whose model leaves the plant's
response to δ_r in its error is not the cause: it is ``unexplained``.

The test, per output i of the verdict model's validation simulation ŷ, error e = y − ŷ, and input j:

* for r·Ts in :data:`RATE_FRACTIONS` times the median nonzero move |u_j(k) − u_j(k−1)| (the rate is not
  known), the deficit δ_r (:func:`rate_limited`) is filtered through the linear approximation of the
  model, the least-squares ARX fit of ŷ_i on lags 1 … :data:`ARX_ORDER` of itself and lags 0 …
  NUISANCE_LAGS of every input (:func:`deficit_response`): x_r, the output's response to the deficit;
* e is regressed on x_r and on the nuisance regressors of
  :mod:`~lpvflow.validate.diagnose_direction` (a constant, lags 0 … NUISANCE_LAGS of ŷ and of every
  input), prewhitened by the AR filter of the nuisance regression's residual (Box & Jenkins, *Time
  Series Analysis*, §11.2);
* the coefficient c of x_r is significant when its t statistic exceeds z at α/m (one-sided: a rate
  limiter adds its deficit, c > 0; Bonferroni over the m = outputs × inputs × rates tested), and material
  when the part of the prewhitened error it explains, c·std(x̃_r)/σ (x̃_r: the prewhitened x_r
  orthogonal to the nuisance regressors, σ: the prewhitened residual's standard deviation), is at least
  :data:`RATE_SIZE`.

Measured on the tanks and airpath records of ``tests/diagnosis_fmu_cases.py`` (seeds 0–4, clean 0–9,
the verdict's model as the diagnosis tests it): the rate limiters the diagnosis named as a cause
(tanks seeds 0, 1; airpath seeds 2, 4) at size 0.45 / — / 0.15 / 0.17, t = 20 / 3.3 (not significant) /
6.8 / 7.4; no clean or in-vocabulary record of the bench significant. Clean records without sensor noise
come close to the weaker ones: the noise-free tanks record of ``tests/test_diagnose_fmu.py`` (seed 2)
reaches 0.149 at t = 6.6, a clean airpath record 0.14 at t = 6.0 with r·Ts = ½ of the median move (not
tested), a clean synthetic twin of ``tests/test_diagnose_rate.py`` 0.093 at t = 4.1; hence RATE_SIZE =
0.3, twice the largest clean size, which finds the tanks limiter of seed 0 and not the airpath ones.
Closed-loop records are not tested: the plant input is fed back from the error, and the maglev friction's
extended model reaches 0.08–0.11 at t = 8–11 (seeds 0–2).
"""

from __future__ import annotations

import numpy as np
import scipy.signal
from scipy.stats import norm

from lpvflow.validate.diagnose_direction import NUISANCE_LAGS, lagged, prewhitened_last_coefficient
from lpvflow.validate.diagnose_summary import NOISE
from lpvflow.validate.extensions import Candidate, Context, Fit

#: Rate limits tested, as r·Ts over the input's median nonzero move per sample.
RATE_FRACTIONS = (1 / 4, 1 / 8, 1 / 16, 1 / 32, 1 / 64, 1 / 128)
#: Autoregressive order of the linear approximation of the model's simulation.
ARX_ORDER = 4
#: Smallest part of the prewhitened error, in its standard deviations, the deficit must explain.
RATE_SIZE = 0.3


def rate_limited(u: np.ndarray, step: float) -> np.ndarray:
    """u_a(k) = u_a(k−1) + clip(u(k) − u_a(k−1), −``step``, ``step``), u_a(0) = u(0)."""
    out = np.empty(len(u))
    previous = float(u[0])
    for k, value in enumerate(u):
        previous += min(max(value - previous, -step), step)
        out[k] = previous
    return out


def deficit_response(y_sim: np.ndarray, u: np.ndarray, j: int, deficit: np.ndarray) -> np.ndarray | None:
    """``deficit`` filtered through B_j(q)/A(q) of the least-squares ARX fit ŷ(k) = c + Σ a_i ŷ(k−i) +
    Σ_j Σ_l b_jl u_j(k−l) (i = 1 … ARX_ORDER, l = 0 … NUISANCE_LAGS); None if A(q) is unstable."""
    start = max(ARX_ORDER, NUISANCE_LAGS)
    past = np.column_stack([np.r_[np.zeros(i), y_sim[: len(y_sim) - i]] for i in range(1, ARX_ORDER + 1)])
    regressors = np.column_stack([np.ones(len(y_sim)), past, *(lagged(x, NUISANCE_LAGS) for x in u.T)])
    theta = np.linalg.lstsq(regressors[start:], y_sim[start:], rcond=None)[0]
    a = np.r_[1.0, -theta[1 : ARX_ORDER + 1]]
    if np.any(np.abs(np.roots(a)) >= 1):
        return None
    first = 1 + ARX_ORDER + j * (NUISANCE_LAGS + 1)
    return scipy.signal.lfilter(theta[first : first + NUISANCE_LAGS + 1], a, deficit)


def _deficit_coefficient(e: np.ndarray, nuisance: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """(t statistic of c, c·std(x̃)/σ) of the coefficient c of ``x`` in the prewhitened regression of
    ``e`` on [``nuisance``, ``x``]
    (:func:`~lpvflow.validate.diagnose_direction.prewhitened_last_coefficient`), x̃ the prewhitened x's part
    the nuisance regressors do not explain."""
    fit = prewhitened_last_coefficient(e, nuisance, x)
    if fit.t == 0.0:
        return 0.0, 0.0
    f = fit.f
    own = f[:, -1] - f[:, :-1] @ np.linalg.lstsq(f[:, :-1], f[:, -1], rcond=None)[0]
    return fit.t, float(fit.c * np.std(own) / fit.sigma)


def rate_dependence(y: np.ndarray, y_sim: np.ndarray, u: np.ndarray, alpha: float) -> dict:
    """The test of the module docstring on the error ``y`` − ``y_sim`` (N, outputs) with the inputs ``u``
    (N, inputs): the largest size among the significant coefficients, its t statistic, output, input and
    rate fraction; ``significant`` when it is material."""
    start = NUISANCE_LAGS + 1
    tests = []
    for i in range(y.shape[1]):
        y_hat = y_sim[:, i]
        nuisance = np.column_stack([np.ones(len(y_hat)), lagged(y_hat, NUISANCE_LAGS),
                                    *(lagged(x, NUISANCE_LAGS) for x in u.T)])[start:]
        e = (y[:, i] - y_hat)[start:]
        for j in range(u.shape[1]):
            moves = np.abs(np.diff(u[:, j]))
            moves = moves[moves > 0]
            if len(moves) == 0:
                continue
            for fraction in RATE_FRACTIONS:
                deficit = rate_limited(u[:, j], fraction * np.median(moves)) - u[:, j]
                x = deficit_response(y_hat, u, j, deficit)
                if x is not None and np.std(x[start:]) > 0:
                    tests.append((i, j, fraction, *_deficit_coefficient(e, nuisance, x[start:])))
    bound = float(norm.isf(alpha / max(len(tests), 1)))
    significant = [t for t in tests if t[3] > bound]
    output, channel, fraction, t_stat, size = max(significant, key=lambda t: t[4],
                                                  default=(0, 0, 0.0, 0.0, 0.0))
    return {"size_over_sigma": size, "t": t_stat, "bound": bound, "output": int(output),
            "input": int(channel), "rate_fraction": fraction, "threshold": RATE_SIZE, "alpha": alpha,
            "significant": bool(size >= RATE_SIZE)}


def rate_verdict(ctx: Context, cause: str, final: Fit, pool: dict[str, Candidate], adequacy: dict | None,
                 alpha: float) -> tuple[str, dict | None]:
    """``unexplained`` when the verdict's model — ``final`` for ``none`` or a noise verdict, the named
    extension's otherwise — leaves the response to a rate limiter's deficit in its error
    (:func:`rate_dependence` on the validation split), the test in ``adequacy["input_rate"]``; otherwise
    the verdict unchanged. Not run on ``unexplained``, ``ambiguous``, a diverged model or a closed-loop
    record (its input is fed back from the error, so any function of the input correlates with it)."""
    noise_verdict = cause in ("none", NOISE, "colored_noise")
    model = final if noise_verdict else (pool[cause].fit if cause in pool else None)
    if model is None or model.diverged or adequacy is None or ctx.loop is not None:
        return cause, adequacy
    test = rate_dependence(ctx.val.y, model.y_val, ctx.val.u, alpha)
    if not test["significant"]:
        return cause, adequacy
    return "unexplained", adequacy | {"input_rate": test | {"cause": cause}}
