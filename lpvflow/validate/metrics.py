"""Fit metrics per output channel, exactly as thesis Sec. 3.5 (3.31)–(3.33).

    MSE = 1/(2N) Σ_k (y(k) − ŷ(k))²                       (note the factor 1/2)
    BFR = 100 % · max(1 − ‖y − ŷ‖₂ / ‖y − ȳ‖₂, 0)          (MATLAB's "fit", thesis "BFT")
    VAF = 100 % · max(1 − var(y − ŷ) / var(y), 0)

ŷ is normally the *simulated* output on validation data. :func:`frozen_response_error` compares two
models instead of a model and data.
"""

from __future__ import annotations

import numpy as np

from lpvflow.errors import DataError


def _pair(y: np.ndarray, y_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    y_hat = np.asarray(y_hat, dtype=float).reshape(len(y_hat), -1)
    if y.shape != y_hat.shape:
        raise DataError(f"measured {y.shape} and simulated {y_hat.shape} outputs differ in shape")
    return y, y_hat


def mse(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    y, y_hat = _pair(y, y_hat)
    return np.sum((y - y_hat) ** 2, axis=0) / (2 * len(y))


def bfr(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    y, y_hat = _pair(y, y_hat)
    spread = np.linalg.norm(y - y.mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = 1 - np.linalg.norm(y - y_hat, axis=0) / spread
    return 100 * np.maximum(np.where(spread > 0, fit, 0.0), 0)


def vaf(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    y, y_hat = _pair(y, y_hat)
    var_y = np.var(y, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = 1 - np.var(y - y_hat, axis=0) / var_y
    return 100 * np.maximum(np.where(var_y > 0, fit, 0.0), 0)


def fit_report(y: np.ndarray, y_hat: np.ndarray, names: list[str] | None = None) -> dict:
    """BFR, VAF and MSE per output as plain lists, keyed by metric."""
    y, y_hat = _pair(y, y_hat)
    return {
        "outputs": names or [f"y{i}" for i in range(y.shape[1])],
        "bfr": bfr(y, y_hat).tolist(),
        "vaf": vaf(y, y_hat).tolist(),
        "mse": mse(y, y_hat).tolist(),
    }


def frozen_response_error(model, reference, points=(-0.3, 0.0, 0.3), band_hz=(0.1, 5.0)) -> float:
    """Mean over frozen scheduling points p of ‖G(e^{jωTs}) − G_ref(e^{jωTs})‖_F / ‖G_ref(e^{jωTs})‖_F,
    the responses stacked over 30 log-spaced frequencies in ``band_hz``; ``model`` and ``reference``
    are realizable LPV models (anything with ``to_ss()``, e.g. :class:`lpvflow.lpvio.LPVIO`)."""
    z = np.exp(2j * np.pi * np.logspace(np.log10(band_hz[0]), np.log10(band_hz[1]), 30) * model.Ts)
    errors = []
    for p in points:
        g, g_ref = model.to_ss().frozen(np.array([p])), reference.to_ss().frozen(np.array([p]))
        resp, resp_ref = np.array([g(s) for s in z]), np.array([g_ref(s) for s in z])
        errors.append(np.linalg.norm(resp - resp_ref) / np.linalg.norm(resp_ref))
    return float(np.mean(errors))
