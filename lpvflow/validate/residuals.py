"""Residual analysis with stated significance (Ljung, System Identification, 2nd ed., §16.6).

* Whiteness: Ljung–Box  Q = N(N+2) Σ_{τ=1}^{m} r̂_ee(τ)² / (N−τ)  ~ χ²(m) under whiteness.
* Cross-correlation r̂_eu(τ) = Σ_k e(k) u(k−τ) / (‖e‖ ‖u‖) with the 99 % band ±2.576/√N
  (white-residual approximation, as MATLAB's ``resid``).
* Comparison of two simulation-error sequences by a signed-rank test on block means (simulation
  errors are strongly autocorrelated and heavy-tailed when a model is badly wrong).
"""

from __future__ import annotations

import numpy as np
import scipy.signal
import scipy.stats

#: Two-sided 99 % normal quantile used for correlation bands.
Z99 = 2.5758


def _centred(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float).ravel()
    return x - x.mean()


def autocorrelation(e: np.ndarray, max_lag: int) -> np.ndarray:
    """r̂_ee(τ) for τ = 0 … max_lag (r̂_ee(0) = 1)."""
    e = _centred(e)
    full = scipy.signal.correlate(e, e, mode="full", method="fft")[len(e) - 1 : len(e) + max_lag]
    return full / full[0]


def ljung_box(e: np.ndarray, lags: int = 20) -> tuple[float, float]:
    """Ljung–Box statistic and its p-value (small p: the residuals are not white)."""
    n = len(e)
    r = autocorrelation(e, lags)[1:]
    q = n * (n + 2) * np.sum(r**2 / (n - np.arange(1, lags + 1)))
    return float(q), float(scipy.stats.chi2.sf(q, lags))


def cross_correlation(e: np.ndarray, u: np.ndarray, lags: range) -> np.ndarray:
    """r̂_eu(τ) = Σ_k e(k) u(k−τ) / (‖e‖‖u‖) for τ in ``lags`` (positive τ: past inputs)."""
    e, u = _centred(e), _centred(u)
    n = len(e)
    full = scipy.signal.correlate(e, u, mode="full", method="fft")  # index n−1+τ ↔ Σ e(k) u(k−τ)
    scale = np.linalg.norm(e) * np.linalg.norm(u)
    return np.array([full[n - 1 + t] for t in lags]) / (scale if scale > 0 else 1.0)


#: Order of the autoregressive filters that whiten a simulation error before it is scored or correlated
#: (:func:`prewhitened_log_det`, :func:`lpvflow.validate.loop_adequacy.correlated_with_excitation`).
WHITENING_ORDER = 20


def whitening_filter(e: np.ndarray, order: int) -> np.ndarray:
    """[1, −â₁, …, −â_n] of Â(q) = 1 − â₁q⁻¹ − … − â_n q⁻ⁿ (n = ``order``), the least-squares AR fit of the
    centred signal e (minimising Σ_{t ≥ n} (Â(q)e)(t)²): ``scipy.signal.lfilter(Â, 1, x)[n:]`` prewhitens x
    (Box & Jenkins, Time Series Analysis, §11.2)."""
    x = _centred(np.asarray(e, float))
    lags = np.column_stack([x[order - i : len(x) - i] for i in range(1, order + 1)])
    return np.r_[1.0, -np.linalg.lstsq(lags, x[order:], rcond=None)[0]]


def prewhitened_log_det(e: np.ndarray, order: int) -> float:
    """log det of the covariance of the error e (N, ny) with each column whitened by its own
    least-squares AR fit (:func:`whitening_filter`, n = ``order``), ε̃ = Â(q)e — the prediction-error
    criterion of e under an AR noise model (Ljung, System Identification, 2nd ed., §7.2). A raw log det of
    a coloured error weighs its low frequencies, where most of its variance is; the whitened one weighs
    every frequency by the error's own level there."""
    whitened = []
    for column in np.atleast_2d(np.asarray(e, float).T):
        x = _centred(column)
        whitened.append(scipy.signal.lfilter(whitening_filter(x, order), 1.0, x)[order:])
    sign, logdet = np.linalg.slogdet(np.atleast_2d(np.cov(np.array(whitened))))
    return float(logdet) if sign > 0 else np.inf


def band99(n: int) -> float:
    return Z99 / np.sqrt(n)


def error_spectrum(e: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Welch power spectral density of the error (frequency in Hz)."""
    e = _centred(e)
    return scipy.signal.welch(e, fs=1.0 / Ts, nperseg=min(1024, len(e)))


def binned_rms(e: np.ndarray, x: np.ndarray, bins: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """RMS of e in equally populated bins of x: (bin centres, RMS per bin)."""
    order = np.argsort(x)
    groups = np.array_split(order, bins)
    centres = np.array([np.median(x[g]) for g in groups])
    rms = np.array([np.sqrt(np.mean(e[g] ** 2)) for g in groups])
    return centres, rms


def drift(e: np.ndarray) -> tuple[float, float]:
    """Slope of e against normalised time t ∈ [0, 1] and its two-sided p-value (OLS, HAC-free)."""
    n = len(e)
    t = np.linspace(0.0, 1.0, n)
    X = np.column_stack([np.ones(n), t])
    coef, res, *_ = np.linalg.lstsq(X, e, rcond=None)
    dof = n - 2
    sigma2 = float(res[0]) / dof if len(res) else float(np.var(e))
    se = np.sqrt(sigma2 * np.linalg.inv(X.T @ X)[1, 1])
    tstat = coef[1] / se if se > 0 else 0.0
    return float(coef[1]), float(2 * scipy.stats.t.sf(abs(tstat), dof))


def block_signed_rank(loss_a: np.ndarray, loss_b: np.ndarray, blocks: int = 20) -> tuple[float, float]:
    """One-sided test that loss_b is smaller than loss_a, robust to autocorrelation and heavy tails.

    The loss differential d(k) = loss_a(k) − loss_b(k) is averaged over ``blocks`` contiguous blocks
    (block means of a strongly autocorrelated simulation error are nearly independent), and the
    block means are tested with the exact Wilcoxon signed-rank test (scipy.stats.wilcoxon,
    alternative "greater"). With 20 blocks the smallest attainable p is 2⁻²⁰ ≈ 9.5·10⁻⁷.
    Returns (mean improvement, p).
    """
    d = np.asarray(loss_a, dtype=float) - np.asarray(loss_b, dtype=float)
    means = np.array([chunk.mean() for chunk in np.array_split(d, blocks)])
    if np.all(means == 0):
        return 0.0, 1.0
    return float(d.mean()), float(scipy.stats.wilcoxon(means, alternative="greater").pvalue)


def noise_level(y: np.ndarray, y_sim: np.ndarray) -> dict:
    """Level of the output noise, per output, from the simulation ŷ of a consistent fit:
    σ̂ = std(y − ŷ), relative level σ̂ / std(ŷ) and SNR = 20 log₁₀(std(ŷ) / σ̂) dB.

    Under output noise, y = G(q, p) u + v with the structure right, the output-error estimate is
    consistent (Boonto's thesis Sec. 4.2.2 and 4.4.1–4.4.2: the OE predictor uses simulated, not
    measured, outputs), so
    y − ŷ → v and this measures the noise itself; with model error left it is an upper bound. The
    earlier ratio of the LS one-step residual to the OE simulation error measured no level: with the
    structure right and any white sensor noise it is ≈ 1 + Σaᵢ² (2.37 at 80 dB SNR).
    """
    e = np.atleast_2d(np.asarray(y, float) - y_sim)
    sigma = e.std(axis=0)
    signal = np.asarray(y_sim, float).std(axis=0)
    with np.errstate(divide="ignore"):
        snr = 20 * np.log10(signal / sigma)
    return {"noise_std": sigma.tolist(), "relative_noise": (sigma / signal).tolist(), "snr_db": snr.tolist()}


#: Largest order of the AR noise model tried by :func:`ar_noise_model`.
AR_MAX_ORDER = 6


def ar_noise_model(v: np.ndarray, max_order: int = AR_MAX_ORDER) -> tuple[np.ndarray, float]:
    """AR noise model D(q) v(k) = e(k), D = 1 + d₁q⁻¹ + … + d_n q⁻ⁿ, by least squares for n = 0 … max_order,
    the order chosen by BIC = N log σ̂²_e + n log N. Returns (d₁ … d_n, σ̂²_e)."""
    v = _centred(v)
    n = len(v) - max_order
    best = (np.inf, np.zeros(0), float(np.var(v)))
    for order in range(max_order + 1):
        target = v[max_order:]
        if order == 0:
            d, s2 = np.zeros(0), float(np.mean(target**2))
        else:
            lags = np.column_stack([v[max_order - i : len(v) - i] for i in range(1, order + 1)])
            coef = np.linalg.lstsq(lags, target, rcond=None)[0]
            d, s2 = -coef, float(np.mean((target - lags @ coef) ** 2))
        bic = n * np.log(s2) + order * np.log(n)
        if bic < best[0]:
            best = (bic, d, s2)
    return best[1], best[2]


def ar_spectrum(d: np.ndarray, sigma2: float, Ts: float, n_freq: int = 16) -> dict:
    """Φ_v(f) = σ²_e Ts / |D(e^{i2πfTs})|² at ``n_freq`` frequencies up to Nyquist (scipy.signal.freqz)."""
    f, h = scipy.signal.freqz([1.0], np.r_[1.0, d], worN=n_freq, fs=1.0 / Ts)
    return {"frequency_hz": f.tolist(), "psd": (sigma2 * Ts * np.abs(h) ** 2).tolist()}
