"""PNG figures of the frozen validation: Bode magnitude overlays and δν, b(P, K) over the grid.

`bode_overlay`: |G(e^{jωTs})| in dB of the model (solid) and the reference (dashed) at several
frozen scheduling values θ, one panel per input/output channel, colour per θ.
`gap_margin_plot`: δν(G_ref(θ), Ĝ(θ)) and, with a controller, b(Ĝ(θ), K(θ)) at every grid point,
the region below b (where δν < b passes Vinnicombe's test) shaded, failing points marked. With one
scheduling signal the abscissa is θ; with several it is the grid-point index.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import control
import numpy as np

#: Magnitude range shown below the largest value in each Bode panel.
DB_RANGE = 80.0


def _pyplot() -> object:
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _magnitude_db(system: control.StateSpace, omega: np.ndarray) -> np.ndarray:
    """(ny, nu, len(omega)) magnitudes in dB."""
    response = control.frequency_response(system, omega).complex
    response = response.reshape(system.noutputs, system.ninputs, len(omega))
    return 20 * np.log10(np.maximum(np.abs(response), 1e-300))


def bode_overlay(
    path: str | Path,
    model_at: Callable[[np.ndarray], control.StateSpace],
    reference_at: Callable[[np.ndarray], control.StateSpace] | None,
    points: Sequence[np.ndarray],
    omega: np.ndarray | None = None,
) -> None:
    """Write the frozen Bode magnitude overlay of model (and reference) at `points` to `path`."""
    plt = _pyplot()
    first = model_at(points[0])
    if omega is None:
        omega = np.logspace(-3, np.log10(np.pi) - 1e-9, 400) / first.dt  # up to the Nyquist frequency
    ny, nu = first.noutputs, first.ninputs
    fig, axes = plt.subplots(ny, nu, figsize=(4.8 * nu + 1.5, 3.2 * ny), squeeze=False)
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(points)))
    for p, colour in zip(points, colours, strict=True):
        label = "θ = " + ", ".join(f"{v:.3g}" for v in np.atleast_1d(p))
        model_db = _magnitude_db(model_at(p), omega)
        reference_db = None if reference_at is None else _magnitude_db(reference_at(p), omega)
        for i in range(ny):
            for j in range(nu):
                ax = axes[i, j]
                ax.semilogx(omega, model_db[i, j], color=colour, lw=1.2, label=f"model, {label}")
                if reference_db is not None:
                    ax.semilogx(omega, reference_db[i, j], color=colour, lw=1.2, ls="--",
                                label=f"reference, {label}")
    for ax in axes.flat:  # a zero near the Nyquist frequency would squash everything else
        top = max(line.get_ydata().max() for line in ax.get_lines())
        ax.set_ylim(bottom=max(ax.get_ylim()[0], top - DB_RANGE))
    for i in range(ny):
        for j in range(nu):
            axes[i, j].set_title(f"{first.input_labels[j]} → {first.output_labels[i]}", fontsize=9)
            axes[i, j].set_ylabel("magnitude [dB]")
            axes[i, j].set_xlabel("ω [rad/s]")
            axes[i, j].grid(True, which="both", alpha=0.3)
    axes[0, -1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.suptitle("Frozen Bode magnitude: model (solid) vs reference (dashed)" if reference_at is not None
                 else "Frozen Bode magnitude of the model")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def gap_margin_plot(path: str | Path, rows: Sequence[dict],
                    axis: tuple[np.ndarray, str] | None = None, top: float = 1.02) -> None:
    """Write δν (and b with the δν < b pass region) over the frozen grid rows of `compare_frozen`, against
    ``axis`` (one value per row and its label, e.g. the arm angle in degrees) when given, else against
    the scheduling value (one signal) or the row number; the vertical axis runs from 0 to ``top``."""
    plt = _pyplot()
    p = np.array([row["p"] for row in rows], dtype=float)
    if axis is not None:
        x = np.asarray(axis[0], dtype=float)
    else:
        x = p[:, 0] if p.shape[1] == 1 else np.arange(len(rows))
    order = np.argsort(x)
    x = x[order]
    gap = np.array([rows[k]["nugap"] for k in order])
    fig, ax = plt.subplots(figsize=(7.5, 4.0))
    if "stability_margin_b" in rows[0]:
        b = np.array([rows[k]["stability_margin_b"] for k in order])
        ax.fill_between(x, 0, b, color="tab:green", alpha=0.15, step=None, label="δν < b: passes")
        ax.plot(x, b, color="tab:green", lw=1.5, marker="s", ms=4, label="b(Ĝ(θ), K(θ))")
        failing = gap >= b
        if np.any(failing):
            ax.plot(x[failing], gap[failing], "x", color="tab:red", ms=9, mew=2, label="fails")
    ax.plot(x, gap, color="tab:blue", lw=1.5, marker="o", ms=4, label="δν(G_ref(θ), Ĝ(θ))")
    ax.set_ylim(0, top)
    ax.set_xlabel(axis[1] if axis is not None else "θ" if p.shape[1] == 1 else "grid point")
    ax.set_ylabel("ν-gap / stability margin [–]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
