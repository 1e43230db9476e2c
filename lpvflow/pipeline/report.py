"""The design report: one self-contained HTML page (figures embedded) over ``summary.json``: the
summary card, a table per stage and every figure."""

from __future__ import annotations

import html
from pathlib import Path

from lpvflow.models import atomic_write_text
from lpvflow.pipeline.report_card import summary_card
from lpvflow.pipeline.report_figures import GAP_FIGURE, ROBUSTNESS_FIGURE, draw_figures, embed_figure
from lpvflow.pipeline.report_robustness import robustness_section, trajectory_table
from lpvflow.pipeline.report_stages import adoption_table, key_value_table, scenario_table, stage_rows
from lpvflow.pipeline.report_text import DisplayUnit, controller_ports, signal_units


def write_report(folder: Path, summary: dict, units: dict[str, str] | None = None) -> Path:
    """``report.html`` in ``folder``: the summary card (:func:`summary_card`), then a table per stage and
    every figure, embedded. ``units`` (signal name → unit) default to :func:`signal_units` of ``folder``."""
    units = signal_units(folder) if units is None else units
    shown = {name: DisplayUnit.of(unit) for name, unit in units.items()}
    scheduling = [port["name"] for port in controller_ports(folder).get("scheduling", [])]
    drawn = draw_figures(folder, shown)
    sections = [f"<h1>lpvflow design: {html.escape(summary['name'])}</h1>", summary_card(summary, units)]
    times = [(n, f"{s.get('seconds', float('nan')):.1f} s ({s['status']})" if "seconds" in s else s["status"])
             for n, s in summary["stages"].items()]
    sections.append("<h2>Stages</h2>" + key_value_table(times))
    for name, stage in summary["stages"].items():
        if stage["status"] == "not configured":
            continue
        outputs = stage.get("outputs", {})
        rows = stage_rows(name, outputs, shown, scheduling)
        sections.append(f"<h2>{html.escape(name)}</h2>" + (key_value_table(rows) if rows else ""))
        if name == "verify" and outputs.get("scenarios"):
            sections.append(scenario_table(outputs["scenarios"], shown, scheduling))
        if name == "adoption" and outputs.get("rows"):
            sections.append(adoption_table(outputs["rows"]))
        if name == "robustness" and outputs.get("rows"):
            sections.append(robustness_section(folder, outputs, shown, scheduling))
            if ROBUSTNESS_FIGURE in drawn:
                sections.append(embed_figure(folder / ROBUSTNESS_FIGURE))
        if name == "robustness" and outputs.get("trajectory"):
            sections.append(trajectory_table(outputs["trajectory"], shown))
        for artifact in stage.get("artifacts", []):
            if artifact == "nugap.png" and GAP_FIGURE in drawn:
                sections.append(embed_figure(folder / GAP_FIGURE))
            elif artifact.endswith(".png"):
                sections.append(embed_figure(folder / artifact))
        # drawn from the folder's data.csv / validate.json, which a failed stage leaves as the previous run's
        extra = {"experiment": ["data.png"], "validate": ["margins.png"]}.get(name, [])
        if stage["status"] != "failed":
            sections += [embed_figure(folder / f) for f in extra if f in drawn]
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
