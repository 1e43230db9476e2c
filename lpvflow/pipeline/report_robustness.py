"""The design report's robustness section: Vinnicombe's robust stability test b > δν and the margins of
the shipped controller at each frozen point, and the model-in-the-loop against the plant-in-the-loop
under that controller on each verify scenario."""

from __future__ import annotations

import html
import math
from pathlib import Path

from lpvflow.pipeline.report_figures import physical_axis
from lpvflow.pipeline.report_text import DisplayUnit, number_text, short_reason


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


def robustness_section(folder: Path, outputs: dict, units: dict[str, DisplayUnit],
                       scheduling: list[str]) -> str:
    """The robustness stage: :func:`robustness_statement` and one row per frozen point: the point (the
    plant signal the scheduling is computed from, in its display unit, when there is one:
    :func:`physical_axis`), b(Ĝ, K_fb), δν, b > δν, the input delay margin and the input disk margin."""
    rows = outputs["rows"]
    thetas = [row["theta"] for row in rows]
    axis = physical_axis(folder, thetas, units)
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
    cells = [[text, number_text(row["b"]), number_text(row.get("nugap")),
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
    rate = rate_statement(outputs, units)
    return (f'<p class="{css}">{html.escape(statement)}</p><table><tr>'
            + "".join(f"<th>{html.escape(h)}</th>" for h in shown) + f"</tr>{body}</table>"
            + (f"<p>{html.escape(rate)}</p>" if rate else ""))


def rate_statement(outputs: dict, units: dict[str, DisplayUnit]) -> str:
    """The stage's ``rate_certificate`` as one line — "stability certified for arm_angle rates up to X °/s;
    the fastest verify scenario (…) peaks at Y °/s", or "not certified even at X °/s (the smallest rate
    tried)" — or its ``rate_certificate_note``; "" when neither was asked for."""
    if "rate_certificate_note" in outputs:
        return f"moving scheduling: {outputs['rate_certificate_note']}"
    if "rate_certificate" not in outputs:
        return ""
    cert = outputs["rate_certificate"]
    name = cert["signal"]
    unit = units.get(name, DisplayUnit(""))

    def speed(per_sample: float) -> str:
        return number_text(per_sample * unit.factor / cert["Ts"], f" {unit.label}/s" if unit.label else "/s")

    peak = f"the fastest verify scenario ({cert['peak_scenario']}) peaks at {speed(cert['peak_per_sample'])}"
    if cert["largest"] is None:
        return f"stability certified for {name} changing at any rate; {peak}"
    if cert["largest"] == 0.0:
        return (f"stability not certified for {name} changing even at {speed(cert['rates'][0])} (the "
                f"smallest rate tried; {cert['reason']}); {peak}")
    return f"stability certified for {name} rates up to {speed(cert['largest'])}; {peak}"


def trajectory_table(rows: list[dict], units: dict[str, DisplayUnit]) -> str:
    """The robustness stage's ``trajectory`` rows: per verify scenario the largest difference of each
    measured output between the identified model in the loop of the shipped controller and the plant FMU
    in the same loop, in its display unit, and how each run ended (:mod:`lpvflow.validate.trajectory`)."""
    names = list(rows[0]["largest_difference"])
    shown = [units.get(name, DisplayUnit("")) for name in names]
    head = ["scenario", *(unit.head(f"largest {name} difference") for name, unit in zip(names, shown,
                                                                                          strict=True)),
            "plant in the loop", "model in the loop"]
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(cell)}</td>" for cell in [
            row["scenario"], *(unit.value(row["largest_difference"][name])
                               for name, unit in zip(names, shown, strict=True)),
            *(short_reason(row[key]) if row[key] else "ran to the end"
              for key in ("plant_failure", "model_failure"))]) + "</tr>"
        for row in rows)
    return ("<h3>Model in the loop against plant in the loop</h3><p>The shipped controller in the loop "
            "with the identified model (scheduled from the model's outputs) and with the plant FMU, on "
            "each verify scenario: the largest difference of each measured output over the samples both "
            "runs completed. Frozen points (above) say nothing about the moves between them; this is "
            "reported, not part of the verdict.</p><table><tr>"
            + "".join(f"<th>{html.escape(h)}</th>" for h in head) + f"</tr>{body}</table>")
