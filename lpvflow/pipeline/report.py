"""The design report: one self-contained HTML page (figures embedded) over ``summary.json``."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

FIGURE_CAPTIONS = {
    "data.png": "Identification experiment: inputs, outputs and scheduling.",
    "fit.png": "Validation: measured outputs and the model simulated in the identification loop.",
    "singular_values.png": "Singular values of the LPV Ho-Kalman reduction (order chosen: marked).",
    "margins.png": "Generalized stability margin b(P(θ), K_id) of frozen models over the scheduling range.",
    "nugap.png": "ν-gap of the frozen model to the plant FMU at the same scheduling value, and the "
                 "stability margin b(Ĝ(θ), K_id) of the identification loop: δν < b is the thesis' test.",
    "bode.png": "Frozen Bode magnitude: identified model (solid) and plant FMU linearization (dashed).",
    "residuals.png": "One-step prediction residuals on the validation part: time series and autocorrelation "
                     "with the 99 % whiteness band.",
    "diagnosis.png": "Diagnosis: where the nominal simulation misses, and the validation gain of each "
                     "extension (green: significant).",
}
#: Stage outputs shown as their own table, not in the stage's key/value table.
SEPARATE_TABLES = {("verify", "scenarios"), ("adoption", "rows")}


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


def _fmt(value) -> str:
    if isinstance(value, dict) and {"outputs", "bfr", "vaf"} <= set(value):  # a fit report
        return "; ".join(f"{n}: BFR {b:.1f} %, VAF {v:.1f} %"
                         for n, b, v in zip(value["outputs"], value["bfr"], value["vaf"], strict=True))
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list) and value and all(isinstance(v, float) for v in value):
        return ", ".join(f"{v:.4g}" for v in value)
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        return "; ".join(value)  # e.g. the certificate's lines
    if isinstance(value, dict) and value and all(isinstance(v, list) and v and all(
            isinstance(x, float) for x in v) for v in value.values()):
        return "; ".join(f"{k}: [{_fmt(v)}]" for k, v in value.items())  # e.g. signal ranges
    return json.dumps(value, ensure_ascii=False) if isinstance(value, dict | list) else str(value)


def _figures(folder: Path) -> list[str]:
    """Data and margin figures from the stored artifacts (matplotlib, Agg); the names written."""
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
            ax.plot(table["time"], table[name], lw=0.6)
            ax.set_ylabel(name, fontsize=8)
        axes[-1, 0].set_xlabel("time [s]")
        fig.tight_layout()
        fig.savefig(folder / "data.png", dpi=90)
        plt.close(fig)
        written.append("data.png")
    validate = folder / "validate.json"
    if validate.exists():
        out = json.loads(validate.read_text())["outputs"]
        if out.get("b_P_Kid") and "nugap" not in out and len(out["theta"][0]) == 1:
            fig, ax = plt.subplots(figsize=(6, 3))
            ax.plot([p[0] for p in out["theta"]], out["b_P_Kid"], "o-")
            ax.set(xlabel="θ", ylabel="b(P(θ), K_id)", ylim=(0, None))
            ax.grid(alpha=0.3)
            fig.tight_layout()
            fig.savefig(folder / "margins.png", dpi=90)
            plt.close(fig)
            written.append("margins.png")
    return written


def _number(value: object, unit: str = "", digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}g}{unit}"


def _scheduling_cell(coverage: dict | None) -> str:
    """Visited range per scheduling signal; for an LPV controller, its design box and the time outside it."""
    from lpvflow.pipeline.verify import box_text

    if not coverage:
        return "–"
    cell = box_text(coverage["range"])
    if coverage["box"] is not None:
        cell += f" (box {box_text(coverage['box'])}: {_number(coverage['time_outside_box'])} s outside)"
    return cell


def _scenario_table(scenarios: list[dict]) -> str:
    """One row per scenario and controller: verdict, and per tracked output and actuated input the
    settling time, overshoot, steady-state error, IAE and peak control, the untracked outputs' largest
    deviation after settling, the requirements missed, and the scheduling range visited with the time spent
    outside the controller's design box (:mod:`lpvflow.pipeline.verify`)."""
    head = ["scenario", "controller", "stable", "output", "settling [s]", "overshoot", "steady-state error",
            "IAE", "peak control", "saturated [s]", "after settling", "requirements", "scheduling", "reason"]
    body = []
    for scenario in scenarios:
        for key in ("controller", "baseline"):
            run = scenario.get(key)
            if not run:
                continue
            inputs = run.get("controls", {})
            controls = "; ".join(f"{u} {_number(c['peak_control'])}" for u, c in inputs.items())
            saturated = "; ".join(_number(c["saturation_time"]) for c in inputs.values())
            after = "; ".join(f"{y} {_number(peak)}" for y, peak in run.get("after_settling", {}).items())
            missed = run.get("requirements_failed")
            requirements = "–" if missed is None else "; ".join(missed) or "met"
            tracked = run.get("outputs", {}) or {"–": {}}
            for output, m in tracked.items():
                overshoot = (f"{_number(m['overshoot'])} ({_number(m['overshoot_percent'], ' %', 2)})"
                             if "overshoot" in m else "–")
                cells = [scenario["name"], run["controller"], "yes" if run["stable"] else "no", output,
                         _number(m.get("settling_time")), overshoot, _number(m.get("steady_state_error")),
                         _number(m.get("iae"), "", 4), controls, saturated, after or "–", requirements,
                         _scheduling_cell(run.get("scheduling")), run.get("reason", "")]
                css = "" if run["stable"] and not missed else ' class="fail"'
                body.append(f"<tr{css}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells)
                            + "</tr>")
    return ("<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(body) + "</table>")


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


def write_report(folder: Path, summary: dict) -> Path:
    """``report.html`` in ``folder``: summary tables per stage and every figure, embedded."""
    drawn = _figures(folder)
    sections = [f"<h1>lpvflow design: {html.escape(summary['name'])}</h1>"]
    verdict = summary.get("verdict")
    if verdict:
        css = "pass" if verdict["pass"] else "fail"
        sections.append(f'<p class="{css}"><b>Verdict: {"pass" if verdict["pass"] else "did not pass"}</b> — '
                        f"{html.escape(verdict['reason'])}</p>")
    if summary.get("failed"):
        f = summary["failed"]
        sections.append(f'<p class="fail">Stopped at stage <b>{html.escape(f["stage"])}</b>: '
                        f"{html.escape(f['error'])}</p>")
    times = [(n, f"{s.get('seconds', float('nan')):.1f} s ({s['status']})" if "seconds" in s else s["status"])
             for n, s in summary["stages"].items()]
    sections.append("<h2>Stages</h2>" + _table(times))
    for name, stage in summary["stages"].items():
        if stage["status"] == "not configured":
            continue
        outputs = stage.get("outputs", {})
        rows = [(k, _fmt(v)) for k, v in outputs.items()
                if (not isinstance(v, list) or len(v) <= 12) and (name, k) not in SEPARATE_TABLES]
        sections.append(f"<h2>{html.escape(name)}</h2>" + (_table(rows) if rows else ""))
        if name == "verify" and outputs.get("scenarios"):
            sections.append(_scenario_table(outputs["scenarios"]))
        if name == "adoption" and outputs.get("rows"):
            sections.append(_adoption_table(outputs["rows"]))
        for artifact in stage.get("artifacts", []):
            if artifact.endswith(".png"):
                sections.append(_embed(folder / artifact))
        extra = {"experiment": ["data.png"], "validate": ["margins.png"]}.get(name, [])
        sections += [_embed(folder / f) for f in extra if f in drawn]
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;margin:0.5em 0}th,td{border:1px solid #ccc;padding:3px 8px;"
             "text-align:left;font-size:13px;vertical-align:top}th{background:#f4f4f4}"
             "img{max-width:100%}figcaption{font-size:12px;color:#555}.fail{color:#b00}.pass{color:#070}")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>lpvflow design {summary['name']}"
            f"</title><style>{style}</style></head><body>{''.join(sections)}</body></html>")
    path = folder / "report.html"
    path.write_text(page)
    return path

