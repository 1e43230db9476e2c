"""The figure behind a diagnosis verdict: where the nominal simulation misses, and the evidence."""

from __future__ import annotations

import matplotlib
import numpy as np

from lpvflow.data import Dataset
from lpvflow.validate import residuals
from lpvflow.validate.diagnose import Diagnosis

#: Samples of the validation time series shown (the whole record is too dense to read).
WINDOW_SAMPLES = 400


def plot_diagnosis(result: Diagnosis, data: Dataset, path: str, split: float = 0.5) -> None:
    """One row per output — validation time series (measured / nominal / extended), nominal error
    RMS against every scheduling signal, against every input's amplitude (separate axes: their units
    differ), and the error spectrum — then the evidence of the verdict: the ranking it was decided on
    (the noise round's when it ran; the named cause in red, significant gains green) and, per output,
    the adequacy tests' input-explained gains (nominal or consistent refit, and the extended model)."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, val = data.split(split)
    ny = val.y.shape[1]
    fig, axes = plt.subplots(ny + 1, 4, figsize=(16, 3.2 * (ny + 1)), squeeze=False)
    window = slice(0, min(val.N, WINDOW_SAMPLES))
    t = np.arange(val.N)[window] * val.Ts
    for i, where in enumerate(result.where["outputs"]):
        ax = axes[i, 0]
        ax.plot(t, val.y[window, i], lw=1, label="measured")
        ax.plot(t, result.nominal_y_val[window, i], lw=1, label=f"nominal ({result.bfr_before[i]:.1f} %)")
        if result.winner is not None:
            ax.plot(t, result.winner.fit.y_val[window, i], lw=1, ls="--",
                    label=f"{result.cause} ({result.bfr_after[i]:.1f} %)")
        ax.set(xlabel="time [s]", ylabel=val.y_names[i], title=f"validation simulation, {len(t)} samples")
        ax.legend(fontsize=7)
        for ax, key, title in ((axes[i, 1], "rms_vs_scheduling", "error RMS vs scheduling"),
                               (axes[i, 2], "rms_vs_input_amplitude", "error RMS vs |input|")):
            for row in where[key]:
                ax.plot(row["value"], row["rms"], "o-", label=row["channel"])
            ax.set(xlabel="value", ylabel=f"{val.y_names[i]} error RMS", title=title)
            ax.legend(fontsize=7)
        f, pxx = residuals.error_spectrum(val.y[:, i] - result.nominal_y_val[:, i], val.Ts)
        axes[i, 3].semilogy(f, pxx)
        axes[i, 3].set(xlabel="frequency [Hz]", ylabel="PSD", title=f"{val.y_names[i]} error spectrum")
    _ranking(axes[ny, 0], result)
    _adequacy(axes[ny, 1], result, val.y_names)
    for ax in axes[ny, 2:]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _ranking(ax, result: Diagnosis) -> None:
    ranking = result.refit_ranking if result.noise_round else result.ranking
    colours = ["tab:red" if r["cause"] == result.cause else "tab:green" if r["significant"] else "tab:gray"
               for r in ranking]
    gains = np.array([r["bfr_gain"] for r in ranking])
    floor = -max(5.0, 0.25 * gains.max(initial=0))  # very negative gains would squash the scale
    ax.barh([r["cause"] for r in ranking], np.maximum(gains, floor), color=colours)
    ax.invert_yaxis()
    which = "noise round (consistent refits)" if result.noise_round else "least-squares fits"
    ax.set(xlabel=f"validation BFR gain [points], {which}", title=f"verdict: {result.cause}")


def _adequacy(ax, result: Diagnosis, names: list[str]) -> None:
    adequacy = result.adequacy
    if not adequacy:
        ax.text(0.5, 0.5, "closed loop: judged by the loop simulations", ha="center", va="center")
        ax.axis("off")
        return
    gains = [row["bfr_gain"] for row in adequacy["per_output"]]
    labels = [f"{name}: nominal" for name in names]
    if "extended_model" in adequacy:
        gains.append(adequacy["extended_model"]["bfr_gain"])
        labels.append(f"{result.cause} model")
    ax.barh(labels, gains, color=["tab:red" if adequacy["significant"] else "tab:gray"] * len(names)
            + ["tab:blue"] * (len(gains) - len(names)))
    ax.invert_yaxis()
    ax.set(xlabel="BFR gain of a correction from the input history [points]",
           title=f"adequacy (lags {adequacy['lags'][0]}–{adequacy['lags'][1]})")
