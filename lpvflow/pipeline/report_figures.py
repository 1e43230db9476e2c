"""The design report's figures: drawn from the stored artifacts (the recorded data, the ν-gap and
margins over a physical scheduling axis) and embedded in the page with their captions."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from lpvflow.pipeline.report_text import DisplayUnit, controller_ports, unit_of

FIGURE_CAPTIONS = {
    "data.png": "Identification experiment: inputs, outputs and scheduling.",
    "fit.png": "Validation: measured outputs and the model simulated in the identification loop.",
    "singular_values.png": "Singular values of the LPV Ho-Kalman reduction (order chosen: marked).",
    "margins.png": "Generalized stability margin b(P(θ), K_id) of frozen models over the scheduling range.",
    "nugap.png": "ν-gap of the frozen model to the plant FMU at the same scheduling value, and the "
                 "stability margin b(Ĝ(θ), K_id) of the identification loop: δν < b is the thesis' test.",
    "nugap_physical.png": "ν-gap of the frozen model to the plant FMU at the same scheduling value, and "
                          "the stability margin b(Ĝ(θ), K_id) of the identification loop, over the plant "
                          "signal the scheduling is computed from: δν < b is the thesis' test.",
    "robustness_physical.png": "Robust stability of the shipped controller: b(Ĝ(θ), K_fb(θ)) of the "
                               "frozen model under the controller's feedback part, and the ν-gap of the "
                               "model to the plant FMU there (Vinnicombe: b > δν guarantees stability).",
    "bode.png": "Frozen Bode magnitude: identified model (solid) and plant FMU linearization (dashed).",
    "residuals.png": "One-step prediction residuals on the validation part: time series and autocorrelation "
                     "with the 99 % whiteness band.",
    "diagnosis.png": "Diagnosis: where the nominal simulation misses, and the validation gain of each "
                     "extension (green: significant).",
}


def embed_figure(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    caption = FIGURE_CAPTIONS.get(path.name, path.stem.replace("_", " "))
    if path.name.startswith("adoption_"):
        caption = ("Closed loop on the plant FMU: the LPV controller designed on the identified model "
                   "(before adoption) and on the adopted extension (after).")
    elif path.name.startswith("verify_"):
        caption = ("Closed loop on the plant FMU: the LPV controller and the LTI baseline on this scenario "
                   "(reference dashed; the scenario's name above the plot).")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(path.name)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def draw_figures(folder: Path, units: dict[str, DisplayUnit]) -> list[str]:
    """Data and margin figures from the stored artifacts (matplotlib, Agg), signals in their display
    units (angles in degrees); the names written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lpvflow.data import read_columns

    written = []
    data_csv = folder / "data.csv"
    if data_csv.exists():
        table = read_columns(data_csv)
        names = [n for n in table if n != "time" and not n.startswith("diag_")]
        fig, axes = plt.subplots(len(names), 1, figsize=(10, 1.6 * len(names)), sharex=True, squeeze=False)
        for ax, name in zip(axes[:, 0], names, strict=True):
            unit = unit_of(name, units)
            ax.plot(table["time"], table[name] * unit.factor, lw=0.6)
            ax.set_ylabel(f"{name} [{unit.label}]" if unit.label else f"{name} [–]", fontsize=8)
        axes[-1, 0].set_xlabel("time [s]")
        fig.tight_layout()
        fig.savefig(folder / "data.png", dpi=90)
        plt.close(fig)
        written.append("data.png")
    validate = folder / "validate.json"
    if validate.exists():
        out = json.loads(validate.read_text())["outputs"]
        axis = physical_axis(folder, out.get("theta") or [], units)
        if out.get("nugap") and out.get("b_P_Kid") and axis is not None:
            from lpvflow.validate.plots import gap_margin_plot

            rows = [{"p": p, "nugap": g, "stability_margin_b": b}
                    for p, g, b in zip(out["theta"], out["nugap"], out["b_P_Kid"], strict=True)]
            gap_margin_plot(folder / GAP_FIGURE, rows, axis)
            written.append(GAP_FIGURE)
        if out.get("b_P_Kid") and "nugap" not in out and len(out["theta"][0]) == 1:
            fig, ax = plt.subplots(figsize=(6, 3))
            ax.plot([p[0] for p in out["theta"]], out["b_P_Kid"], "o-")
            ax.set(xlabel="scheduling θ [–]", ylabel="b(P(θ), K_id) [–]", ylim=(0, None))
            ax.grid(alpha=0.3)
            fig.tight_layout()
            fig.savefig(folder / "margins.png", dpi=90)
            plt.close(fig)
            written.append("margins.png")
    robustness = folder / "robustness.json"
    rows = json.loads(robustness.read_text())["outputs"].get("rows") if robustness.exists() else None
    if rows and "nugap" in rows[0]:
        from lpvflow.validate.plots import gap_margin_plot

        gap_rows = [{"p": row["theta"], "nugap": row["nugap"], "stability_margin_b": row["b"]}
                    for row in rows]
        top = min(1.02, 1.25 * max(max(row["b"], row["nugap"]) for row in rows))
        gap_margin_plot(folder / ROBUSTNESS_FIGURE, gap_rows,
                        physical_axis(folder, [row["theta"] for row in rows], units), top=top)
        written.append(ROBUSTNESS_FIGURE)
    return written


#: The ν-gap figure over a physical scheduling axis (drawn by the report; the validate stage's
#: ``nugap.png``, over the scheduling coordinates, is shown when no such axis is found).
GAP_FIGURE = "nugap_physical.png"


#: b(Ĝ, K_fb) and the ν-gap of the robustness stage over the physical scheduling axis (drawn by the report).
ROBUSTNESS_FIGURE = "robustness_physical.png"


def physical_axis(folder: Path, thetas: list[list[float]], units: dict[str, DisplayUnit]
                   ) -> tuple[list[float], str] | None:
    """The frozen points as values of the one recorded plant signal every scheduling expression is a
    function of (e.g. the arm angle for sin(arm_angle), 1/(1 − κ cos²(arm_angle)), …), in its display
    unit, with the axis label; None when there is no such signal or a point is off the curve. The signal
    is searched over its recorded range (``experiment.json``) on 4001 values; a point maps to the
    nearest, refined on 201 values between its neighbours, and is off the curve when its scheduling
    values miss by more than 1 % of their span."""
    from lpvflow.errors import DataError
    from lpvflow.experiment.scheduling import evaluate

    experiment = folder / "experiment.json"
    ports = controller_ports(folder).get("scheduling", [])
    if not thetas or not ports or not experiment.exists():
        return None
    import numpy as np

    ranges = json.loads(experiment.read_text()).get("outputs", {}).get("ranges", {})
    points = np.asarray(thetas, dtype=float)
    if points.ndim != 2 or points.shape[1] != len(ports):
        return None
    for name, (lo, hi) in ranges.items():
        grid = np.linspace(lo, hi, 4001)

        def curve(values: np.ndarray, name: str = name) -> np.ndarray:
            return np.column_stack([evaluate(port["expression"] or port["name"], {name: values})
                                    for port in ports])

        try:
            span = np.ptp(curve(grid), axis=0) + 1e-12
        except DataError:
            continue

        def misses(values: np.ndarray, span: np.ndarray = span) -> np.ndarray:
            return np.abs((curve(values)[None, :, :] - points[:, None, :]) / span).max(axis=2)

        miss = misses(grid)
        nearest = miss.argmin(axis=1)
        if miss[np.arange(len(points)), nearest].max() > 0.01:
            continue
        step = grid[1] - grid[0]  # refined between the grid values either side of the nearest
        fine = grid[nearest][:, None] + np.linspace(-step, step, 201)[None, :]
        best = [row[misses(row)[i].argmin()] for i, row in enumerate(fine)]
        unit = units.get(name, DisplayUnit(""))
        return (np.asarray(best) * unit.factor).tolist(), f"{name} [{unit.label or '–'}]"
    return None
