"""The figure behind a diagnosis verdict: where the nominal simulation misses, and what fixed it."""

from __future__ import annotations

import matplotlib
import numpy as np

from lpvflow.data import Dataset
from lpvflow.validate.diagnose import Diagnosis

#: Samples of the validation time series shown (the whole record is too dense to read).
WINDOW_SAMPLES = 400


def plot_diagnosis(result: Diagnosis, data: Dataset, path: str, split: float = 0.5) -> None:
    """Four panels for the first output: validation time series (measured / nominal / extended),
    error spectrum, error RMS against every scheduling signal and input amplitude, and the ranked BFR
    gains."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, val = data.split(split)
    where = result.where["outputs"][0]
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    window = slice(0, min(val.N, WINDOW_SAMPLES))
    t = np.arange(val.N)[window] * val.Ts
    ax = axes[0, 0]
    ax.plot(t, val.y[window, 0], lw=1, label="measured")
    ax.plot(t, result.nominal_y_val[window, 0], lw=1, label=f"nominal (BFR {result.bfr_before[0]:.1f} %)")
    if result.winner is not None:
        ax.plot(t, result.winner.fit.y_val[window, 0], lw=1, ls="--",
                label=f"{result.cause} (BFR {result.bfr_after[0]:.1f} %)")
    ax.set(xlabel="time [s]", ylabel=val.y_names[0],
           title=f"validation simulation (first {len(t)} samples)")
    ax.legend(fontsize=8)
    ax = axes[0, 1]
    for row in where["rms_vs_scheduling"]:
        ax.plot(row["value"], row["rms"], "o-", label=row["channel"])
    for row in where["rms_vs_input_amplitude"]:
        ax.plot(row["value"], row["rms"], "s-", label=f"|{row['channel']}|")
    ax.set(xlabel="value", ylabel="nominal error RMS", title="where the error lives")
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    f, pxx = result.error_spectrum
    ax.semilogy(f, pxx)
    ax.set(xlabel="frequency [Hz]", ylabel="PSD", title="nominal simulation error spectrum")
    ax = axes[1, 1]
    ranking = result.ranking
    colours = ["tab:green" if r["significant"] else "tab:gray" for r in ranking]
    gains = np.array([r["bfr_gain"] for r in ranking])
    floor = -max(5.0, 0.25 * gains.max(initial=0))  # very negative gains would squash the scale
    ax.barh([r["cause"] for r in ranking], np.maximum(gains, floor), color=colours)
    for row, gain in enumerate(gains):
        if gain < floor:
            ax.annotate(f"{gain:.0f}", (floor, row), va="center", ha="left", fontsize=8, color="white")
    ax.invert_yaxis()
    ax.set(xlabel="validation BFR gain [points] (green: significant)", title=f"verdict: {result.cause}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
