"""The design report: one self-contained HTML page (figures embedded) over ``summary.json``."""

from __future__ import annotations

import base64
import html
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

from lpvflow.models import atomic_write_text
from lpvflow.pipeline.scenarios import run_passed

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
#: Stage outputs shown as their own table, not in the stage's key/value table.
SEPARATE_TABLES = {("verify", "scenarios"), ("adoption", "rows"), ("robustness", "rows"),
                   ("robustness", "guaranteed"), ("robustness", "not_guaranteed_at")}


def _embed(path: Path) -> str:
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


def _table(rows: list[tuple[str, str]]) -> str:
    body = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows)
    return f"<table>{body}</table>"


def _fmt(value: object) -> str:
    """A stage output as text for one table cell: numbers with 4 significant digits, lists joined, tables
    as ``key: value`` phrases (never JSON); nothing (None, an empty list or table) is "–"."""
    if value is None or (isinstance(value, dict | list) and not value):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, dict) and {"outputs", "bfr", "vaf"} <= set(value):  # a fit report
        return "; ".join(f"{n}: BFR {b:.1f} %, VAF {v:.1f} %"
                         for n, b, v in zip(value["outputs"], value["bfr"], value["vaf"], strict=True))
    if isinstance(value, dict):
        if all(_is_numbers(v) for v in value.values()):  # e.g. signal ranges: "voltage: [-4.86, 4.41]"
            return "; ".join(f"{k}: [{_fmt(v)}]" for k, v in value.items())
        return "; ".join(f"{k}: {_fmt(v)}" for k, v in value.items())
    if isinstance(value, list):
        if all(isinstance(v, str) for v in value):
            return "; ".join(value)  # e.g. the certificate's lines
        if all(_is_numbers(v) for v in value):  # rows of numbers, e.g. a grid of scheduling points
            return "; ".join(_fmt(v) for v in value)
        separator = " | " if any(isinstance(v, dict) for v in value) else ", "
        return separator.join(_fmt(v) for v in value)
    return str(value)


def _is_numbers(value: object) -> bool:
    """A non-empty list of numbers (not booleans)."""
    return (isinstance(value, list) and bool(value)
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value))


def _figures(folder: Path, units: dict[str, _Unit]) -> list[str]:
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
            unit = _unit_of(name, units)
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
        axis = _physical_axis(folder, out.get("theta") or [], units)
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
                        _physical_axis(folder, [row["theta"] for row in rows], units), top=top)
        written.append(ROBUSTNESS_FIGURE)
    return written


#: The ν-gap figure over a physical scheduling axis (drawn by the report; the validate stage's
#: ``nugap.png``, over the scheduling coordinates, is shown when no such axis is found).
GAP_FIGURE = "nugap_physical.png"
#: b(Ĝ, K_fb) and the ν-gap of the robustness stage over the physical scheduling axis (drawn by the report).
ROBUSTNESS_FIGURE = "robustness_physical.png"


def _physical_axis(folder: Path, thetas: list[list[float]], units: dict[str, _Unit]
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
    ports = _ports(folder).get("scheduling", [])
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
        unit = units.get(name, _Unit(""))
        return (np.asarray(best) * unit.factor).tolist(), f"{name} [{unit.label or '–'}]"
    return None


def _number(value: object, unit: str = "", digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}g}{unit}"


def _scheduling_cell(coverage: dict | None, names: list[str]) -> str:
    """Visited range of each scheduling signal (by name); for an LPV controller, the time outside its
    design box."""
    if not coverage:
        return "–"
    ranges = coverage["range"]
    labels = names if len(names) == len(ranges) else [f"θ{i + 1}" for i in range(len(ranges))]
    cell = "; ".join(f"{n} {lo:.3g} … {hi:.3g}" for n, (lo, hi) in zip(labels, ranges, strict=True))
    if coverage["box"] is not None:
        cell += f"; {_number(coverage['time_outside_box'])} s outside the design box"
    return cell


#: How the verification record names the controllers, and how the report does.
CONTROLLERS = {"lpv": "LPV controller", "baseline": "LTI baseline"}


def _scenario_table(scenarios: list[dict], units: dict[str, _Unit], scheduling: list[str]) -> str:
    """One row per scenario and controller: verdict, and per tracked output and actuated input the
    settling time, overshoot, steady-state error, IAE and peak control, the untracked outputs' largest
    deviation after settling, the requirements missed, and the scheduling range visited with the time spent
    outside the controller's design box (:mod:`lpvflow.pipeline.verify`); values in display units (angles
    in degrees)."""
    head = ["scenario", "controller", "stable", "output", "settling [s]", "overshoot", "steady-state error",
            "IAE", "peak control", "saturated [s]", "after settling", "requirements",
            "scheduling visited", "reason"]
    body = []
    for scenario in scenarios:
        for key in ("controller", "baseline"):
            run = scenario.get(key)
            if not run:
                continue
            inputs = run.get("controls", {})
            controls = "; ".join(f"{u} {_signal_value(u, c['peak_control'], units)}"
                                 for u, c in inputs.items())
            saturated = "; ".join(_number(c["saturation_time"]) for c in inputs.values())
            after = "; ".join(f"{y} {_signal_value(y, peak, units)}"
                              for y, peak in run.get("after_settling", {}).items())
            missed = run.get("requirements_failed")
            requirements = "–" if missed is None else "; ".join(missed) or "met"
            tracked = run.get("outputs", {}) or {"–": {}}
            for output, m in tracked.items():
                value = lambda v, name=output: "–" if v is None else _signal_value(name, v, units)  # noqa: E731
                overshoot = (f"{value(m['overshoot'])} ({_number(m.get('overshoot_percent'), ' %', 2)})"
                             if m.get("overshoot") is not None else "–")
                unit = units.get(output, _Unit(""))
                iae = ("–" if m.get("iae") is None
                       else f"{m['iae'] * unit.factor:.4g} {unit.label or '(no unit)'}·s")
                cells = [scenario["name"], CONTROLLERS.get(run["controller"], run["controller"]),
                         "yes" if run["stable"] else "no", output, _number(m.get("settling_time")), overshoot,
                         value(m.get("steady_state_error")), iae, controls, saturated, after or "–",
                         requirements, _scheduling_cell(run.get("scheduling"), scheduling),
                         _short_reason(run.get("reason", ""))]
                css = "" if run["stable"] and not missed else ' class="fail"'
                body.append(f"<tr{css}>" + "".join(f"<td>{_breakable(str(c))}</td>" for c in cells)
                            + "</tr>")
    return ('<div class="wide"><table class="scenarios"><tr>' + "".join(f"<th>{h}</th>" for h in head)
            + "</tr>" + "".join(body) + "</table></div>")


# ------------------------------------------------------------------------------------- summary card
@dataclass(frozen=True)
class _Unit:
    """How a signal's values are shown: ``label`` in the column head, values multiplied by ``factor``."""

    label: str
    factor: float = 1.0

    @classmethod
    def of(cls, unit: str) -> _Unit:
        """Angles in rad are shown in degrees; other units as they are ("" when the FMU gives none)."""
        return cls("°", 180.0 / math.pi) if unit == "rad" else cls(unit)

    def head(self, text: str) -> str:
        return f"{text} [{self.label}]" if self.label else f"{text} (output units)"

    def value(self, value: float | None) -> str:
        return _number(None if value is None else value * self.factor)


def _ports(folder: Path) -> dict:
    """The synthesized controller's port record (``controller.json`` ``info["signals"]``,
    :func:`lpvflow.pipeline.export.describe_signals`); empty without one."""
    path = folder / "controller.json"
    if not path.exists():
        return {}
    try:
        return json.loads(path.read_text()).get("info", {}).get("signals", {}) or {}
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        return {}


def signal_units(folder: Path) -> dict[str, str]:
    """Unit of every measured and actuated signal, from the synthesized controller's port record
    (:func:`_ports`); empty without one."""
    signals = _ports(folder)
    return {port["name"]: port.get("unit", "") for kind in ("measured", "actuated")
            for port in signals.get(kind, [])}


def _ordered(names: list[str]) -> list[str]:
    return list(dict.fromkeys(names))


def _requirement_text(requirements: dict | None, bands: dict[str, float], units: dict[str, _Unit]) -> str:
    """One scenario's specification as a phrase, e.g. "arm_angle into ±1° within 1.5 s, overshoot ≤ 2°;
    pendulum_angle within ±1° after settling"."""
    if not requirements:
        return "stable (settles, stays within its output bounds); no requirements"
    parts = []
    for name, band in bands.items():
        unit = units.get(name, _Unit(""))
        phrase = f"{name} into ±{unit.value(band)}{unit.label}"
        if requirements.get("settling_time") is not None:
            phrase += f" within {requirements['settling_time']:g} s"
        if requirements.get("overshoot") is not None:
            phrase += f", overshoot ≤ {unit.value(requirements['overshoot'])}{unit.label}"
        parts.append(phrase)
    if not bands:  # no run got far enough to name its tracked outputs and their bands
        limits = [f"within {requirements['settling_time']:g} s" if requirements.get("settling_time") else "",
                  f"overshoot ≤ {requirements['overshoot']:g} (output units)" if requirements.get("overshoot")
                  else ""]
        parts.append("tracked outputs settle " + ", ".join(p for p in limits if p))
    for name, bound in requirements.get("after_settling", {}).items():
        unit = units.get(name, _Unit(""))
        parts.append(f"{name} within ±{unit.value(bound)}{unit.label} after settling")
    return "; ".join(p for p in parts if p)


def _specification(scenarios: list[dict], units: dict[str, _Unit]) -> str:
    """The specification, one line per distinct requirement text with the scenarios it applies to."""
    def bands_of(scenario: dict) -> dict[str, float]:
        runs = [r for r in (scenario["controller"], scenario.get("baseline")) if r]
        return {name: m["band"] for r in runs for name, m in r.get("outputs", {}).items()}

    known: dict[str, set[float]] = {}
    for scenario in scenarios:
        for name, band in bands_of(scenario).items():
            known.setdefault(name, set()).add(band)
    # a scenario whose runs failed before settling has no metrics: it shares the one band every
    # other scenario uses for an output, if they agree
    shared = {name: next(iter(bands)) for name, bands in known.items() if len(bands) == 1}
    texts: dict[str, list[str]] = {}
    for scenario in scenarios:
        bands = bands_of(scenario) or shared
        texts.setdefault(_requirement_text(scenario.get("requirements"), bands, units), []).append(
            scenario["name"])
    items = "".join(f"<li><b>{html.escape(', '.join(names))}</b>: {html.escape(text)}</li>"
                    for text, names in texts.items())
    return f"<h3>Specification</h3><ul>{items}</ul>"


def _comparison_table(scenarios: list[dict], units: dict[str, _Unit], perturbed: bool) -> str:
    """LPV controller against the LTI baseline, one row per scenario: per tracked output the settling
    time and overshoot, per untracked output its peak |y − r| after settling, and pass/fail; cells that
    miss a requirement are marked. ``perturbed`` adds the plant parameters the scenario changes."""
    tracked = _ordered([n for s in scenarios for r in (s["controller"], s.get("baseline")) if r
                        for n in r.get("outputs", {})])
    after = _ordered([n for s in scenarios for n in (s.get("requirements") or {}).get("after_settling", {})]
                     + [n for s in scenarios for r in (s["controller"], s.get("baseline")) if r
                        for n in r.get("after_settling", {})])
    heads = []
    for name in tracked:
        unit = units.get(name, _Unit(""))
        heads += [f"{name} settling [s]", unit.head(f"{name} overshoot")]
    heads += [units.get(name, _Unit("")).head(f"{name} after settling") for name in after]
    heads.append("result")
    controllers = [("controller", "LPV controller")]
    if any(s.get("baseline") for s in scenarios):
        controllers.append(("baseline", "LTI baseline"))
    first = ["scenario"] + (["parameter factors"] if perturbed else [])
    head = ("<tr>" + "".join(f'<th rowspan="2">{h}</th>' for h in first)
            + "".join(f'<th colspan="{len(heads)}">{label}</th>' for _, label in controllers) + "</tr><tr>"
            + "".join(f"<th>{_breakable(h)}</th>" for _ in controllers for h in heads) + "</tr>")
    body = []
    for scenario in scenarios:
        requirements = scenario.get("requirements") or {}
        cells = [html.escape(scenario["name"])]
        if perturbed:
            changed = scenario["parameter_factors"].items()
            cells.append(html.escape(", ".join(f"{k} × {v:g}" for k, v in changed)))
        for key, _ in controllers:
            run = scenario.get(key)
            if not run:
                cells += ["–"] * len(heads)
                continue
            cells += _run_cells(run, tracked, after, requirements, units)
        body.append("<tr>" + "".join(c if c.startswith("<td") else f"<td>{c}</td>" for c in cells) + "</tr>")
    return f'<table class="card">{head}{"".join(body)}</table>'


def _run_cells(run: dict, tracked: list[str], after: list[str], requirements: dict,
               units: dict[str, _Unit]) -> list[str]:
    """The comparison cells of one run (:func:`_comparison_table`), escaped; a missed bound is red."""
    def cell(text: str, missed: bool) -> str:
        return f'<td class="fail">{_breakable(text)}</td>' if missed else _breakable(text)

    cells = []
    for name in tracked:
        m = run.get("outputs", {}).get(name, {})
        unit = units.get(name, _Unit(""))
        settling, limit = m.get("settling_time"), requirements.get("settling_time")
        late = bool(m) and limit is not None and (settling is None or settling > limit)
        cells.append(cell("not settled" if m and settling is None else _number(settling), late))
        overshoot, limit = m.get("overshoot"), requirements.get("overshoot")
        cells.append(cell(unit.value(overshoot), overshoot is not None and limit is not None
                          and overshoot > limit))
    bounds = requirements.get("after_settling", {})
    for name in after:
        peak = run.get("after_settling", {}).get(name)
        cells.append(cell(units.get(name, _Unit("")).value(peak),
                          peak is not None and name in bounds and peak > bounds[name]))
    if run_passed(run):
        cells.append('<td class="pass">pass</td>' if "requirements_failed" in run else
                     '<td class="pass">stable</td>')
    else:
        why = "" if run["stable"] else f": {_short_reason(run['reason'])}"
        cells.append(f'<td class="fail">fail{_breakable(why)}</td>')
    return cells


def _breakable(text: str) -> str:
    """``text`` escaped for HTML, with line-break opportunities after underscores (signal names such as
    upper_disk_position wrap there in a narrow column)."""
    return html.escape(text).replace("_", "_<wbr>")


def _short_reason(reason: str) -> str:
    """A failed run's reason for a table cell: "unbounded: y left its output_bounds at t = 1.585 s" reads
    "y out of bounds at 1.59 s"; other reasons as they are."""
    lost = re.fullmatch(r"unbounded: (.+) left its output_bounds at t = (\S+) s", reason)
    return f"{lost[1]} out of bounds at {float(lost[2]):.3g} s" if lost else reason


def _gamma_line(synth: dict) -> str:
    """γ of the LPV controller and of the LTI baseline (and where the baseline was designed)."""
    if "gamma" not in synth:
        return ""
    text = f"H∞ γ: LPV controller {synth['gamma']:.4g}"
    if synth.get("method") == "observer":
        text += " (largest frozen closed-loop ‖T_zw‖∞ of the observer design; no LMI bound)"
    elif synth.get("gamma_lower") is not None:
        text += f" (LMI lower bound {synth['gamma_lower']:.4g})"
    if synth.get("baseline_gamma") is not None:
        at = ", ".join(f"{v:.3g}" for v in synth.get("baseline_at") or [])
        text += f"; LTI baseline {synth['baseline_gamma']:.4g}" + (f" (designed at θ = {at})" if at else "")
    return f"<p>{html.escape(text)}</p>"


def _held_step_line(verify: dict, units: dict[str, _Unit]) -> str:
    """The largest step the LTI baseline (and the LPV controller) holds: the verify stage's output
    ``largest_held_step`` = {"output": name, "criterion": "passes" | "bounded", "baseline": amplitude,
    "lpv": amplitude (optional), "resolution": of the bisection (optional)}, amplitudes in the output's
    units, as :func:`lpvflow.pipeline.step_sweep.largest_held_step` returns them."""
    record = verify.get("largest_held_step")
    if not record:
        return "<p>Largest step the LTI baseline holds: not measured in this run.</p>"
    return f"<p>{html.escape(_held_step_text(record, units))}.</p>"


def _held_step_text(record: dict, units: dict[str, _Unit]) -> str:
    """:func:`_held_step_line`'s sentence (also the verify table's cell), amplitudes in display units."""
    unit = units.get(record["output"], _Unit(""))
    criterion = {"passes": "meets its scenario's specification",
                 "bounded": "keeps the constrained outputs within their bounds"}[record["criterion"]]
    text = (f"Largest {record['output']} step the LTI baseline holds: {unit.value(record['baseline'])}"
            f"{unit.label}")
    if record.get("lpv") is not None:
        text += f" (LPV controller: {unit.value(record['lpv'])}{unit.label})"
    text += f"; held means the run {criterion}; found by bisection"
    if record.get("resolution"):
        text += f" to within {unit.value(record['resolution'])}{unit.label}"
    return text


def scenario_tally(summary: dict) -> str:
    """How many verification scenarios each controller passes, e.g. "LPV controller passes 2 of 4
    scenarios, LTI baseline 4 of 4"; "" when nothing was verified."""
    scenarios = summary["stages"].get("verify", {}).get("outputs", {}).get("scenarios", [])
    if not scenarios:
        return ""
    text = (f"LPV controller passes {sum(run_passed(s['controller']) for s in scenarios)} of "
            f"{len(scenarios)} scenarios")
    baselines = [s["baseline"] for s in scenarios if s.get("baseline")]
    if baselines:
        text += f", LTI baseline {sum(run_passed(b) for b in baselines)} of {len(baselines)}"
    return text


def summary_card(summary: dict, units: dict[str, str]) -> str:
    """The report's first screen: the verdict (and, for a run that stopped early, where and why), the
    specification, the LPV controller against the LTI baseline per scenario (nominal, then on perturbed
    plants: scenarios with ``parameter_factors``), γ of both and the largest step the baseline holds.
    ``units``: signal name → unit (angles in rad are shown in degrees)."""
    shown = {name: _Unit.of(unit) for name, unit in units.items()}
    verdict = summary.get("verdict") or {"pass": False, "reason": "no verdict recorded"}
    stages = summary["stages"]
    verify = stages.get("verify", {}).get("outputs", {})
    scenarios = verify.get("scenarios", [])
    css = "pass" if verdict["pass"] else "fail"
    tally = scenario_tally(summary)
    line = f"Verdict: {'pass' if verdict['pass'] else 'did not pass'}" + (f" — {tally}" if tally else "")
    parts = [f'<p class="verdict {css}"><b>{html.escape(line)}</b></p>',
             f'<p class="why">{html.escape(verdict["reason"])}</p>']
    if summary.get("failed"):
        f = summary["failed"]
        parts.append(f'<p class="fail">Stopped at stage <b>{html.escape(f["stage"])}</b>: '
                     f"{html.escape(f['error'])}</p>")
    if scenarios:
        nominal = [s for s in scenarios if not s.get("parameter_factors")]
        perturbed = [s for s in scenarios if s.get("parameter_factors")]
        parts.append(_specification(scenarios, shown))
        if nominal:
            parts.append("<h3>LPV controller and LTI baseline, nominal plant</h3>"
                         + _comparison_table(nominal, shown, perturbed=False))
        if perturbed:
            parts.append("<h3>Robustness: perturbed plants</h3>"
                         + _comparison_table(perturbed, shown, perturbed=True))
    parts.append(_gamma_line(stages.get("synth", {}).get("outputs", {})))
    if scenarios:
        parts.append(_held_step_line(verify, shown))
    if summary.get("iterations"):
        parts.append(_iterations_table(summary["iterations"]))
    return f'<section class="summary"><h2>Results at a glance</h2>{"".join(parts)}</section>'


def _iterations_table(rounds: list[dict]) -> str:
    """The identification-for-control rounds (``[experiment] iterate``, ``summary["iterations"]``): per
    round its experiment controller, model order, fit, largest ν-gap against smallest b(P, K_id), the
    gate, and the γ of its design."""
    head = ["round", "experiment controller", "order", "fit BFR [%]", "largest ν-gap", "smallest b(P, K_id)",
            "gate", "γ (LPV / LTI baseline)"]
    body = []
    for r in rounds:
        gate = r.get("gate") or {}
        used = Path(r["experiment_controller"]) if r.get("experiment_controller") else None
        cells = [str(r["iteration"]), "open loop" if used is None else f"{used.parent.name}/{used.name}",
                 _number(r.get("order")), ", ".join(_number(b, "", 3) for b in r.get("fit_bfr") or []) or "–",
                 _number(r.get("max_nugap")), _number(r.get("min_b_P_Kid")),
                 "–" if not gate else ("passed" if gate.get("passed") else "failed"),
                 f"{_number(r.get('gamma'), '', 4)} / {_number(r.get('baseline_gamma'), '', 4)}"]
        css = ' class="fail"' if gate and not gate.get("passed") else ""
        body.append(f"<tr{css}>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    return ("<h3>Identification for control ([experiment] iterate)</h3><table><tr>"
            + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" + "".join(body) + "</table>")


def _adoption_table(rows: list[dict]) -> str:
    """Before/after adoption of the diagnosed extension: one row per scenario and tracked output, the
    LPV controller designed on the identified model (before) and on the extended one (after)."""
    head = ["scenario", "output", "controller", "stable", "settling [s]", "overshoot", "IAE", "ISE",
            "steady-state error"]
    body = []
    for row in rows:
        for key in ("before", "after"):
            m = row[key]
            cells = [row["scenario"], row["output"], f"{key} adoption", "yes" if m["stable"] else "no",
                     _number(m["settling_time"]), _number(m["overshoot_percent"], " %", 2),
                     _number(m["iae"], "", 4), _number(m["ise"], "", 4), _number(m["steady_state_error"])]
            css = "" if m["stable"] else ' class="fail"'
            body.append(f"<tr{css}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
    return ("<h3>Before/after adoption</h3><table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"
            + "".join(body) + "</table>")


def robustness_statement(outputs: dict, points: list[str]) -> str:
    """The robustness stage's one line: "robust stability (Vinnicombe): guaranteed at every point" or
    "… not guaranteed at N of M points (…)" naming them (``points``: every row's point as text), or that
    no ν-gap was computed to compare b with."""
    if outputs.get("guaranteed") is None:
        return "robust stability (Vinnicombe): not assessed (the validate stage computed no ν-gap)"
    if outputs["guaranteed"]:
        return "robust stability (Vinnicombe): guaranteed at every point"
    failing = [text for text, row in zip(points, outputs["rows"], strict=True) if not row["b_above_nugap"]]
    return (f"robust stability (Vinnicombe): not guaranteed at {len(failing)} of {len(points)} points "
            f"({'; '.join(failing)})")


def robustness_section(folder: Path, outputs: dict, units: dict[str, _Unit], scheduling: list[str]) -> str:
    """The robustness stage: :func:`robustness_statement` and one row per frozen point: the point (the
    plant signal the scheduling is computed from, in its display unit, when there is one:
    :func:`_physical_axis`), b(Ĝ, K_fb), δν, b > δν, the input delay margin and the input disk margin."""
    rows = outputs["rows"]
    thetas = [row["theta"] for row in rows]
    axis = _physical_axis(folder, thetas, units)
    if axis is not None:  # label "name [unit]"
        name, unit = axis[1][:-1].rsplit(" [", 1)
        unit = {"–": "", "°": "°"}.get(unit, f" {unit}")
        span = max(axis[0]) - min(axis[0])  # three digits of the span: 0.1° on ±75°; + 0.0: no "-0"
        digits = max(0, 3 - math.floor(math.log10(span))) if span > 0 else 3
        values = [f"{round(v, digits) + 0.0:g}" for v in axis[0]]
        points = [f"{name} {v}{unit}" for v in values]
    else:
        values = points = ["(" + ", ".join(f"{n} {v:.3g}" for n, v in zip(scheduling, p, strict=False))
                           + ")" for p in thetas]
    cells = [[text, _number(row["b"]), _number(row.get("nugap")),
              "–" if "b_above_nugap" not in row else "yes" if row["b_above_nugap"] else "no",
              str(row["delay_margin_samples"]) if row["delay_margin_samples"] >= 0 else "unstable",
              f"{row['input_disk_margin']:.3g} (±{row['input_disk_gain_margin_db']:.3g} dB, "
              f"±{row['input_disk_phase_margin_deg']:.3g}°)"]
             for text, row in zip(values, rows, strict=True)]
    shown = [axis[1] if axis is not None else "scheduling point", "b(Ĝ, K_fb)", "ν-gap δν", "b > δν",
             "delay margin [samples]", "input disk margin α (gain, phase)"]
    body = "".join("<tr" + ("" if c[3] != "no" else ' class="fail"') + ">"
                   + "".join(f"<td>{html.escape(v)}</td>" for v in c) + "</tr>" for c in cells)
    statement = robustness_statement(outputs, points)
    css = "pass" if outputs.get("guaranteed") else "fail"
    return (f'<p class="{css}">{html.escape(statement)}</p><table><tr>'
            + "".join(f"<th>{html.escape(h)}</th>" for h in shown) + f"</tr>{body}</table>")


# ---------------------------------------------------------------------------------------- stage tables
#: (stage, output key) → the row's label in the report; keys not listed are shown by their words.
LABELS = {
    ("experiment", "samples"): "samples recorded",
    ("experiment", "Ts"): "sampling time",
    ("experiment", "ranges"): "range of each recorded signal",
    ("identify", "method"): "identification method",
    ("identify", "one_step_bfr_validation"): "one-step prediction fit on the validation part (BFR)",
    ("identify", "ljung_box_p_value"): "Ljung–Box p-value of the residuals (small: not white)",
    ("identify", "input"): "model input",
    ("identify", "nx"): "model order (states)",
    ("identify", "offsets"): "offsets removed",
    ("identify", "scheduling_range"): "scheduling range of the data",
    ("reduce", "order"): "order after reduction (states)",
    ("reduce", "full_order"): "order before reduction (states)",
    ("reduce", "order_rule"): "order chosen by",
    ("reduce", "max_frozen_radius"): "largest frozen spectral radius, reduced model",
    ("reduce", "full_max_frozen_radius"): "largest frozen spectral radius, full model",
    ("reduce", "singular_values"): "Hankel singular values",
    ("validate", "fit"): "simulation fit on the validation part",
    ("validate", "scaling"): "signal scales of the ν-gap (typical amplitudes)",
    ("validate", "theta"): "frozen scheduling points",
    ("validate", "b_P_Kid"): "stability margin b(P, K_id) of the identification loop",
    ("validate", "reference"): "ν-gap reference (plant FMU)",
    ("validate", "nugap"): "ν-gap δν between plant FMU and model",
    ("validate", "gate_margin"): "margin b(P, K_id) − δν",
    ("validate", "nugap_below_b_everywhere"): "δν < b(P, K_id) at every frozen point",
    ("validate", "gate"): "model gate",
    ("synth", "method"): "synthesis method",
    ("synth", "structure"): "controller structure",
    ("synth", "gamma"): "γ, LPV controller",
    ("synth", "gamma_lower"): "γ lower bound (LMI)",
    ("synth", "baseline_gamma"): "γ, LTI baseline",
    ("synth", "baseline_at"): "LTI baseline designed at",
    ("synth", "certificate"): "certificate",
    ("synth", "certificate_ok"): "certificate holds",
    ("synth", "solve_seconds"): "synthesis time",
    ("synth", "order"): "controller order (states)",
    ("synth", "polytope"): "scheduling polytope",
    ("verify", "plant"): "plant FMU",
    ("verify", "loop"): "closed loop",
    ("verify", "stable"): "every run of the LPV controller stable",
    ("verify", "passed"): "every scenario passed",
    ("verify", "largest_held_step"): "largest step the LTI baseline holds",
    ("export", "files"): "files exported",
}
#: Stage outputs that are bookkeeping, not results (the file format of the verification record).
HIDDEN = {("verify", "format"), ("verify", "version")}
#: Stage outputs in seconds.
SECONDS = {("experiment", "Ts"), ("synth", "solve_seconds")}
#: Stage outputs in per cent.
PERCENT = {("identify", "one_step_bfr_validation")}
STRUCTURES = {"1dof": "1-DOF (reads r − y)", "2dof": "2-DOF (reads references and measurements apart)"}


def _unit_of(name: str, units: dict[str, _Unit]) -> _Unit:
    """The display unit of a recorded signal: its own, or for an experiment's ``<signal>_excitation`` and
    ``<signal>_setpoint`` columns that of the signal; none for a scheduling signal."""
    for suffix in ("", "_excitation", "_setpoint"):
        if name.endswith(suffix) and name.removesuffix(suffix) in units:
            return units[name.removesuffix(suffix)] if suffix else units[name]
    return _Unit("")


def _signal_value(name: str, value: float, units: dict[str, _Unit]) -> str:
    """One value of a named signal in its display unit, e.g. "70.2°", "6.02 V" (a plain number without
    one)."""
    unit = _unit_of(name, units)
    return unit.value(value) + ("" if unit.label in ("°", "") else " ") + unit.label


def _signal_range(name: str, bounds: list[float], units: dict[str, _Unit]) -> str:
    lo, hi = (_signal_value(name, v, units) for v in bounds)
    return f"{name} {lo} … {hi}"


def stage_rows(stage: str, outputs: dict, units: dict[str, _Unit],
               scheduling: list[str] | None = None) -> list[tuple[str, str]]:
    """A stage's outputs as (label, value) rows a reader understands: :data:`LABELS`, values with their
    units (angles in degrees, times in s), file names without folders, no bookkeeping (:data:`HIDDEN`)
    and no list longer than 12 values (those are drawn)."""
    names = scheduling or []
    rows = []
    for key, value in outputs.items():
        if (stage, key) in HIDDEN | SEPARATE_TABLES or (isinstance(value, list) and len(value) > 12):
            continue
        label = LABELS.get((stage, key), key.replace("_", " "))
        if (stage, key) in SECONDS and isinstance(value, int | float):
            text = f"{value:.4g} s"
        elif (stage, key) in PERCENT and _is_numbers(value):
            text = "; ".join(f"{v:.1f} %" for v in value)
        elif key == "ranges" and isinstance(value, dict):
            text = "; ".join(_signal_range(n, b, units) for n, b in value.items())
        elif key == "scaling" and isinstance(value, dict):
            text = "; ".join(f"{n} {_signal_value(n, v, units)}" for n, v in value.items())
        elif key == "plant" and isinstance(value, str):
            text = Path(value).name
        elif key == "structure" and value in STRUCTURES:
            text = STRUCTURES[value]
        elif key == "largest_held_step" and isinstance(value, dict):
            text = _held_step_text(value, units)
        elif key == "loop" and isinstance(value, dict):
            text = _loop_text(value, units)
        elif key == "gate" and isinstance(value, dict):
            text = ("passed" if value.get("passed") else "failed") + f": {value.get('reason', '')}"
        elif key in ("theta", "baseline_at", "scheduling_range") and value and names:
            points = value if isinstance(value[0], list) else [value]
            if key == "scheduling_range":  # [[lo...], [hi...]]
                text = "; ".join(f"{n} {lo:.3g} … {hi:.3g}" for n, lo, hi in zip(names, *value, strict=False))
            else:
                text = "; ".join("(" + ", ".join(f"{n} {v:.3g}" for n, v in zip(names, p, strict=False)) + ")"
                                 for p in points)
        else:
            text = _fmt(value)
        rows.append((label, text))
    return rows


def _loop_text(loop: dict, units: dict[str, _Unit]) -> str:
    """The verification loop in words: what the controller reads and drives, its scheduling, the limits."""
    parts = [f"measures {', '.join(loop.get('measured', []))}",
             f"drives {', '.join(loop.get('actuated', []))}"]
    if loop.get("scheduling"):
        parts.append(f"scheduled on {', '.join(loop['scheduling'])}")
    limits = loop.get("actuator_limits") or {}
    if limits:
        parts.append("limits " + ", ".join(_signal_range(n, b, units) for n, b in limits.items()))
    return "; ".join(parts)


def write_report(folder: Path, summary: dict, units: dict[str, str] | None = None) -> Path:
    """``report.html`` in ``folder``: the summary card (:func:`summary_card`), then a table per stage and
    every figure, embedded. ``units`` (signal name → unit) default to :func:`signal_units` of ``folder``."""
    units = signal_units(folder) if units is None else units
    shown = {name: _Unit.of(unit) for name, unit in units.items()}
    scheduling = [port["name"] for port in _ports(folder).get("scheduling", [])]
    drawn = _figures(folder, shown)
    sections = [f"<h1>lpvflow design: {html.escape(summary['name'])}</h1>", summary_card(summary, units)]
    times = [(n, f"{s.get('seconds', float('nan')):.1f} s ({s['status']})" if "seconds" in s else s["status"])
             for n, s in summary["stages"].items()]
    sections.append("<h2>Stages</h2>" + _table(times))
    for name, stage in summary["stages"].items():
        if stage["status"] == "not configured":
            continue
        outputs = stage.get("outputs", {})
        rows = stage_rows(name, outputs, shown, scheduling)
        sections.append(f"<h2>{html.escape(name)}</h2>" + (_table(rows) if rows else ""))
        if name == "verify" and outputs.get("scenarios"):
            sections.append(_scenario_table(outputs["scenarios"], shown, scheduling))
        if name == "adoption" and outputs.get("rows"):
            sections.append(_adoption_table(outputs["rows"]))
        if name == "robustness" and outputs.get("rows"):
            sections.append(robustness_section(folder, outputs, shown, scheduling))
            if ROBUSTNESS_FIGURE in drawn:
                sections.append(_embed(folder / ROBUSTNESS_FIGURE))
        for artifact in stage.get("artifacts", []):
            if artifact == "nugap.png" and GAP_FIGURE in drawn:
                sections.append(_embed(folder / GAP_FIGURE))
            elif artifact.endswith(".png"):
                sections.append(_embed(folder / artifact))
        extra = {"experiment": ["data.png"], "validate": ["margins.png"]}.get(name, [])
        sections += [_embed(folder / f) for f in extra if f in drawn]
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;margin:0.5em 0;max-width:100%}"
             ".wide{overflow-x:auto;max-width:100%}th,td{border:1px solid #ccc;padding:3px 8px;"
             "text-align:left;font-size:13px;vertical-align:top}th{background:#f4f4f4}"
             "img{max-width:100%}figcaption{font-size:12px;color:#555}.fail{color:#b00}.pass{color:#070}"
             ".summary{border:1px solid #bbb;border-radius:6px;padding:0.5em 1.2em;background:#fcfcfc;"
             "overflow-x:auto}"
             ".summary h2{margin-top:0.4em}.verdict{font-size:17px}.why{font-size:12px;color:#555}"
             "table.card td{text-align:right}table.card td:first-child{text-align:left}"
             "table.card th{font-size:12px}table.scenarios td{font-size:12px}"
             "table.card,table.scenarios{width:100%;table-layout:fixed}"
             "table.scenarios th:nth-child(13){width:14%}"
             "table.card th,table.card td,table.scenarios td{overflow-wrap:break-word}")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>lpvflow design {summary['name']}"
            f"</title><style>{style}</style></head><body>{''.join(sections)}</body></html>")
    path = folder / "report.html"
    atomic_write_text(path, page)
    return path

