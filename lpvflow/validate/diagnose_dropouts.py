"""Was the commanded input held in short windows? Actuator dropouts in a closed-loop record (step 6 of
:mod:`lpvflow.validate.diagnose`).

A closed-loop record holds the *commanded* plant input u. An actuator that drops out for a while keeps
applying its last value u_i(k0−1) during a window k0 ≤ t < k0 + L, while the controller's command moves
on; after the window the plant again gets the command. The model's one-step prediction error
ε(k) = y(k) − ŷ(k | k−1) (recorded outputs and commanded inputs,
:func:`~lpvflow.identify.arx.prediction_residuals`) is then, inside the window and its n_b lags after
it, the model's response to the difference:

    ê(k) = Σ_j B_j(ψ(p)) [:, i] · (u_i(k0−1) − u_i(k−j)),   summed over the j with k0 ≤ k−j < k0 + L,

a signature fixed by the hypothesis (input i held from k0 for L samples) with no free parameter. The loop
hides such windows from the simulation error (the controller corrects the departure), but the one-step
error localises them. No cause of the vocabulary holds the input at its last value for a while.

The test is the generalized likelihood ratio for a change of known signature and unknown onset and
duration (Basseville & Nikiforov, *Detection of Abrupt Changes*, 1993, ch. 7, additive changes in linear
models): with the outputs' residuals scaled by their RMS σ_o,

    Λ(i, k0, L) = Σ_k Σ_o [ε_o(k)² − (ε_o(k) − ê_o(k))²] / σ_o² = 2·Σ ε·ê/σ² − S,   S = Σ ê²/σ².

For white Gaussian ε and a fixed window, Λ = 2√S·Z − S with Z standard normal, so P(Λ > z²) ≤ P(Z > z)
whatever S (2√S·z − S is at most z²): a window is *significant* when Λ > z² with z at α/m, Bonferroni over
the m = inputs · N · (MAX_HOLD − MIN_HOLD + 1) windows scanned. Significant windows are taken greedily,
largest Λ first, without overlap; the record has held inputs when at least MIN_WINDOWS of them are
significant on one input (a dropout recurs; one window alone is an accident of the record).

Measured on the closed-loop records of ``tests/diagnosis_fmu_cases.py`` (the verdict's model, validation
split; bench seeds 0–4, clean 0–9): ADIP actuator dropouts (4 samples) 34–48 significant windows,
every ADIP clean record ≤ 1 (seed 2: one window of 4 samples at Λ = 62, bound 35.5), the noise-free
ADIP record of ``tests/test_diagnose_fmu.py`` none; maglev dropouts (100 samples) 1–4 windows of 85–107
samples at Λ = 44–782 (bound 38.7; seeds 2 and 4 only one, so not found), every maglev clean record
none (Λ ≤ 1). The ADIP's one-step error is heavy-tailed, so the Gaussian bound is not a level there (the
one clean window): hence MIN_WINDOWS. MIN_HOLD = 3: on the noise-free, quantization-dominated ADIP record
holds of 2 samples reach Λ = 167 (three windows), holds of 3 or more Λ ≤ 5 — a hold of one or two
samples is an input a sample or two late once, not a dropout.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.stats import norm

from lpvflow.data import Dataset
from lpvflow.identify.arx import prediction_residuals
from lpvflow.lpvio import LPVIO
from lpvflow.validate.diagnose_summary import NOISE
from lpvflow.validate.extensions import Context, Fit

#: Shortest and longest held window scanned, in samples.
MIN_HOLD, MAX_HOLD = 3, 200
#: Significant disjoint windows on one input that make the record's input held.
MIN_WINDOWS = 2


def input_gains(io: LPVIO, data: Dataset) -> np.ndarray:
    """B_j(ψ) at each row of :func:`~lpvflow.identify.arx.prediction_residuals`: (rows, lags, ny, nu)."""
    start = io.max_lag
    psi = io.basis.eval(data.p, check_range=False)
    shifted = io.form == "shifted"
    gains = np.zeros((data.N - start, io.B.shape[0], io.ny, io.nu))
    for j in range(io.B.shape[0]):
        coeff = psi[start - j : data.N - j] if shifted else psi[start:]
        gains[:, j] = np.einsum("tl,lrc->trc", coeff, io.B[j])
    return gains


@numba.njit(cache=True)
def _scan(e: np.ndarray, g: np.ndarray, u: np.ndarray, start: int, min_hold: int,
          max_hold: int) -> tuple[np.ndarray, np.ndarray]:
    """Largest Λ over the lengths min_hold … max_hold of a hold starting at each k0, and its length;
    ``e`` (rows, ny) and ``g`` (rows, lags, ny) already divided by σ_o (module docstring)."""
    rows, lags, ny = g.shape
    n = u.shape[0]
    best = np.zeros(n)
    length = np.zeros(n, np.int64)
    for k0 in range(1, n):
        e_hat = np.zeros((max_hold + lags, ny))
        ratio = 0.0
        for hold in range(1, max_hold + 1):
            t = k0 + hold - 1
            if t >= n:
                break
            d = u[k0 - 1] - u[t]
            for j in range(lags):
                r = t + j - start
                if r < 0 or r >= rows:
                    continue
                for o in range(ny):
                    c = g[r, j, o] * d
                    old = e_hat[hold - 1 + j, o]
                    ratio += 2.0 * (e[r, o] - old) * c - c * c
                    e_hat[hold - 1 + j, o] = old + c
            if hold >= min_hold and ratio > best[k0]:
                best[k0], length[k0] = ratio, hold
    return best, length


def held_windows(io: LPVIO, data: Dataset, alpha: float) -> dict:
    """The test of the module docstring for ``io`` on ``data`` (the record's commanded inputs): per input
    the significant disjoint windows; the input with the most, its count, largest Λ, the bound z² and the
    windows' lengths; ``significant`` when that count reaches MIN_WINDOWS."""
    e = prediction_residuals(io, data)
    sigma = np.sqrt(np.mean(e**2, axis=0))
    sigma[sigma == 0] = 1.0
    gains = input_gains(io, data) / sigma[None, None, :, None]
    bound = float(norm.isf(alpha / (io.nu * data.N * (MAX_HOLD - MIN_HOLD + 1))) ** 2)
    found = []
    for i in range(io.nu):
        best, length = _scan(np.ascontiguousarray(e / sigma), np.ascontiguousarray(gains[..., i]),
                             np.ascontiguousarray(data.u[:, i], dtype=float), io.max_lag, MIN_HOLD, MAX_HOLD)
        taken = np.zeros(data.N, bool)
        windows = []
        for k0 in np.argsort(-best):
            if best[k0] <= bound:
                break
            if not taken[k0 : k0 + length[k0]].any():
                taken[k0 : k0 + length[k0]] = True
                windows.append((float(best[k0]), int(length[k0])))
        found.append((i, windows, float(best.max(initial=0.0))))
    i, windows, largest = max(found, key=lambda f: (len(f[1]), f[2]))
    return {"input": data.u_names[i], "windows": len(windows), "min_windows": MIN_WINDOWS,
            "largest_ratio": largest, "bound": bound, "lengths": sorted(w[1] for w in windows),
            "alpha": alpha, "significant": len(windows) >= MIN_WINDOWS}


def dropout_verdict(ctx: Context, cause: str, final: Fit, adequacy: dict | None,
                    alpha: float) -> tuple[str, dict | None]:
    """Closed loop: ``unexplained`` when the model of a ``none`` or noise verdict (``final``) finds the
    commanded input held in short windows (:func:`held_windows` on the validation split), the test in
    ``adequacy["held_input"]``; otherwise the verdict unchanged. Not run in open loop, on a named cause or
    on a diverged model."""
    noise_verdict = cause in ("none", NOISE, "colored_noise")
    if ctx.loop is None or not noise_verdict or final.diverged or adequacy is None:
        return cause, adequacy
    test = held_windows(final.model, ctx.val, alpha)
    if not test["significant"]:
        return cause, adequacy
    return "unexplained", adequacy | {"held_input": test | {"cause": cause}}
