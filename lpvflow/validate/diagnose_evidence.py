"""Evidence of a diagnosis: where the nominal validation simulation error lives (spectrum, drift,
RMS against scheduling and input amplitude) and the residual tests on the nominal model's one-step
residuals, with 99 % bands (Ljung, System Identification, 2nd ed., §16.6)."""

from __future__ import annotations

import numpy as np

from lpvflow.data import Dataset
from lpvflow.validate import residuals


def where(val: Dataset, error: np.ndarray) -> dict:
    """Where the nominal validation simulation error lives, per output: spectrum, drift, and RMS
    against every scheduling signal and every input's amplitude."""
    out = []
    for i in range(error.shape[1]):
        e = error[:, i]
        f, pxx = residuals.error_spectrum(e, val.Ts)
        cum = np.cumsum(pxx) / np.sum(pxx)
        slope, p_drift = residuals.drift(e)
        out.append({
            "output": val.y_names[i],
            "spectrum_peak_hz": float(f[np.argmax(pxx)]),
            "spectrum_half_power_below_hz": float(f[np.searchsorted(cum, 0.5)]),
            "rms_vs_scheduling": [_binned(name, e, val.p[:, m]) for m, name in enumerate(val.p_names)],
            "rms_vs_input_amplitude": [_binned(name, e, np.abs(val.u[:, j]))
                                       for j, name in enumerate(val.u_names)],
            "drift_slope": slope,
            "drift_p_value": p_drift,
        })
    return {"outputs": out}


def _binned(channel: str, e: np.ndarray, x: np.ndarray) -> dict:
    centres, rms = residuals.binned_rms(e, x)
    return {"channel": channel, "value": centres.tolist(), "rms": rms.tolist()}


def evidence(est: Dataset, nominal_residuals: np.ndarray, channels: dict) -> list[dict]:
    """Residual tests on the nominal model's one-step residuals (estimation data), 99 % bands: for
    every output, whiteness, cross-correlation with every input, and correlation with every input's
    amplitude, the sign of its motion and of itself, a trend, every scheduling signal squared times
    its last value, and every candidate channel."""
    items = []
    n = len(nominal_residuals)
    band = residuals.band99(n)
    start = est.N - n
    for i, name in enumerate(est.y_names):
        e = nominal_residuals[:, i]
        q, p_lb = residuals.ljung_box(e)
        items.append({"test": "ljung_box", "output": name, "Q": q, "p_value": p_lb,
                      "text": f"{name}: one-step residuals {'are not' if p_lb < 0.01 else 'look'} white "
                              f"(Ljung–Box Q={q:.1f}, p={p_lb:.2g})"})
        for j, u_name in enumerate(est.u_names):
            lags = range(-5, 31)
            r = residuals.cross_correlation(e, est.u[start:, j], lags)
            k = int(np.argmax(np.abs(r)))
            items.append({"test": "cross_correlation", "output": name, "input": u_name,
                          "peak_lag": lags[k], "peak": float(r[k]), "band99": band,
                          "lags_outside_band": [lags[m] for m in np.flatnonzero(np.abs(r) > band)],
                          "text": f"{name} residual vs {u_name}: peak correlation {r[k]:.3f} at lag "
                                  f"{lags[k]} (99 % band ±{band:.3f})"})
        features = {f"|{u_name}| (input amplitude)": np.abs(est.u[start:, j])
                    for j, u_name in enumerate(est.u_names)}
        features |= {f"sign of d{name}/dt": np.sign(np.diff(est.y[:, i]))[start - 1 :],
                     f"sign of {name}(k-1)": np.sign(est.y[start - 1 : -1, i]),
                     "trend": np.linspace(0, 1, n)}
        features |= {f"{p_name}^2 * {name}(k-1)": est.p[start - 1 : -1, m] ** 2 * est.y[start - 1 : -1, i]
                     for m, p_name in enumerate(est.p_names)}
        features |= {f"channel {c}": values[0][start:] for c, values in channels.items()}
        for label, x in features.items():
            if np.std(x) == 0:
                continue
            r = float(np.corrcoef(e, x)[0, 1])
            items.append({"test": "feature_correlation", "output": name, "feature": label, "r": r,
                          "band99": band, "text": f"{name} residual vs {label}: r = {r:.3f}"})
    return items
