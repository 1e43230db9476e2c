"""The identify stage's residual check: one-step-ahead residuals of an IO model on validation data, their
BFR, whiteness (Ljung–Box) and figure (time series and autocorrelation with the 99 % band)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lpvflow.data import Dataset
from lpvflow.identify.arx import prediction_residuals
from lpvflow.lpvio import LPVIO


def plot_residuals(
    path: Path, residuals: np.ndarray, Ts: float, names: list[str], units: dict[str, str] | None = None,
    lags: int = 50,
) -> list[float]:
    """Residual time series and autocorrelation r̂_ee(τ), τ ≤ ``lags``, with the 99 % band ±2.58/√N of a
    white sequence, one row per output (PNG); returns the Ljung–Box p-value (20 lags) per output."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lpvflow.validate.residuals import autocorrelation, band99, ljung_box

    t = np.arange(len(residuals)) * Ts
    fig, axes = plt.subplots(len(names), 2, figsize=(10, 2.4 * len(names)), squeeze=False)
    p_values = []
    for (ax_t, ax_r), name, e in zip(axes, names, residuals.T, strict=True):
        p_values.append(ljung_box(e)[1])
        ax_t.plot(t, e, lw=0.5)
        unit = (units or {}).get(name)
        ax_t.set(xlabel="time [s]", ylabel=f"ε {name} [{unit}]" if unit else f"ε {name}")
        band = band99(len(e))
        r = autocorrelation(e, lags)  # fewer than lags + 1 values for a residual shorter than lags
        ax_r.stem(np.arange(len(r)), r, basefmt=" ")
        ax_r.axhspan(-band, band, color="tab:green", alpha=0.2)
        ax_r.set(xlabel="lag", ylabel="r̂_εε", title=f"Ljung–Box p = {p_values[-1]:.2g}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return p_values


def one_step_residuals(io: LPVIO, val: Dataset, figure: Path, units: dict[str, str] | None = None
                       ) -> dict[str, list[float]]:
    """The one-step-ahead equation-error residuals ε(k) of ``io`` on ``val``: per output the BFR
    100 (1 − ‖ε‖/‖y − ȳ‖) and the Ljung–Box p-value, with their figure written to ``figure``
    (:func:`plot_residuals`)."""
    residuals = prediction_residuals(io, val)
    y = val.y[io.max_lag:]
    one_step = 100 * (1 - np.linalg.norm(residuals, axis=0) / np.linalg.norm(y - y.mean(axis=0), axis=0))
    return {"one_step_bfr_validation": one_step.tolist(),
            "ljung_box_p_value": plot_residuals(figure, residuals, val.Ts, val.y_names, units)}
