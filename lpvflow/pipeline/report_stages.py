"""The design report's per-stage sections: each stage's outputs as labelled rows with units, and the
verification scenario table and the adoption table."""

from __future__ import annotations

import html
from pathlib import Path

from lpvflow.pipeline.report_card import held_step_text
from lpvflow.pipeline.report_text import (
    GATE_WORDS,
    DisplayUnit,
    breakable,
    format_value,
    is_numbers,
    number_text,
    short_reason,
    signal_range,
    signal_value,
)

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
    ("synth", "baseline_gamma"): "γ, LTI baseline",
    ("synth", "baseline_at"): "LTI baseline designed at",
    ("synth", "certificate"): "certificate",
    ("synth", "certificate_ok"): "certificate holds",
    ("synth", "solve_seconds"): "synthesis time",
    ("synth", "order"): "controller order (states)",
    ("synth", "polytope"): "scheduling polytope",
    ("synth", "box_note"): "design box against the identified scheduling range",
    ("verify", "plant"): "plant FMU",
    ("verify", "loop"): "closed loop",
    ("verify", "stable"): "every run of the LPV controller stable",
    ("verify", "passed"): "every scenario passed",
    ("verify", "largest_held_step"): "largest step the LTI baseline holds",
    ("export", "files"): "files exported",
    ("robustness", "trajectory_note"): "model in the loop against plant in the loop",
}


#: Stage outputs that are bookkeeping, not results (the file format of the verification record).
HIDDEN = {("verify", "format"), ("verify", "version")}


#: Stage outputs in seconds.
SECONDS = {("experiment", "Ts"), ("synth", "solve_seconds")}


#: Stage outputs in per cent.
PERCENT = {("identify", "one_step_bfr_validation")}


STRUCTURES = {"1dof": "1-DOF (reads r − y)", "2dof": "2-DOF (reads references and measurements apart)"}


#: Stage outputs shown as their own table, not in the stage's key/value table.
SEPARATE_TABLES = {("verify", "scenarios"), ("adoption", "rows"), ("robustness", "rows"),
                   ("robustness", "guaranteed"), ("robustness", "not_guaranteed_at"),
                   ("robustness", "trajectory")}


def stage_rows(stage: str, outputs: dict, units: dict[str, DisplayUnit],
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
        elif (stage, key) in PERCENT and is_numbers(value):
            text = "; ".join(f"{v:.1f} %" for v in value)
        elif key == "ranges" and isinstance(value, dict):
            text = "; ".join(signal_range(n, b, units) for n, b in value.items())
        elif key == "scaling" and isinstance(value, dict):
            text = "; ".join(f"{n} {signal_value(n, v, units)}" for n, v in value.items())
        elif key == "plant" and isinstance(value, str):
            text = Path(value).name
        elif key == "structure" and value in STRUCTURES:
            text = STRUCTURES[value]
        elif key == "largest_held_step" and isinstance(value, dict):
            text = held_step_text(value, units)
        elif key == "loop" and isinstance(value, dict):
            text = _loop_text(value, units)
        elif key == "gate" and isinstance(value, dict):
            text = GATE_WORDS[value.get("passed")] + f": {value.get('reason', '')}"
        elif key in ("theta", "baseline_at", "scheduling_range") and value and names:
            points = value if isinstance(value[0], list) else [value]
            if key == "scheduling_range":  # [[lo...], [hi...]]
                text = "; ".join(f"{n} {lo:.3g} … {hi:.3g}" for n, lo, hi in zip(names, *value, strict=False))
            else:
                text = "; ".join("(" + ", ".join(f"{n} {v:.3g}" for n, v in zip(names, p, strict=False)) + ")"
                                 for p in points)
        else:
            text = format_value(value)
        rows.append((label, text))
    return rows


def _loop_text(loop: dict, units: dict[str, DisplayUnit]) -> str:
    """The verification loop in words: what the controller reads and drives, its scheduling, the limits."""
    parts = [f"measures {', '.join(loop.get('measured', []))}",
             f"drives {', '.join(loop.get('actuated', []))}"]
    if loop.get("scheduling"):
        parts.append(f"scheduled on {', '.join(loop['scheduling'])}")
    limits = loop.get("actuator_limits") or {}
    if limits:
        parts.append("limits " + ", ".join(signal_range(n, b, units) for n, b in limits.items()))
    return "; ".join(parts)


def key_value_table(rows: list[tuple[str, str]]) -> str:
    body = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows)
    return f"<table>{body}</table>"


def scenario_table(scenarios: list[dict], units: dict[str, DisplayUnit], scheduling: list[str]) -> str:
    """One row per scenario and controller: verdict, and per tracked output and actuated input the
    settling time, overshoot, steady-state error, IAE, the peak |y − r| after the reference change (for an
    output whose reference does not change: its cross-coupling peak) and peak control, the untracked
    outputs' largest deviation after settling, the requirements missed, and the scheduling range visited
    with the time spent outside the controller's design box (:mod:`lpvflow.pipeline.verify`); values in
    display units (angles in degrees)."""
    head = ["scenario", "controller", "stable", "output", "settling [s]", "overshoot", "steady-state error",
            "IAE", "peak |y − r|", "peak control", "saturated [s]", "after settling", "requirements",
            "scheduling visited", "reason"]
    body = []
    for scenario in scenarios:
        for key in ("controller", "baseline"):
            run = scenario.get(key)
            if not run:
                continue
            inputs = run.get("controls", {})
            controls = "; ".join(f"{u} {signal_value(u, c['peak_control'], units)}"
                                 for u, c in inputs.items())
            saturated = "; ".join(number_text(c["saturation_time"]) for c in inputs.values())
            after = "; ".join(f"{y} {signal_value(y, peak, units)}"
                              for y, peak in run.get("after_settling", {}).items())
            missed = run.get("requirements_failed")
            requirements = "–" if missed is None else "; ".join(missed) or "met"
            tracked = run.get("outputs", {}) or {"–": {}}
            for output, m in tracked.items():
                value = lambda v, name=output: "–" if v is None else signal_value(name, v, units)  # noqa: E731
                overshoot = (f"{value(m['overshoot'])} ({number_text(m.get('overshoot_percent'), ' %', 2)})"
                             if m.get("overshoot") is not None else "–")
                unit = units.get(output, DisplayUnit(""))
                iae = ("–" if m.get("iae") is None
                       else f"{m['iae'] * unit.factor:.4g} {unit.label or '(no unit)'}·s")
                cells = [scenario["name"], CONTROLLERS.get(run["controller"], run["controller"]),
                         "yes" if run["stable"] else "no", output, number_text(m.get("settling_time")),
                         overshoot,
                         value(m.get("steady_state_error")), iae, value(m.get("peak_deviation")), controls,
                         saturated, after or "–",
                         requirements, _scheduling_cell(run.get("scheduling"), scheduling),
                         short_reason(run.get("reason", ""))]
                css = "" if run["stable"] and not missed else ' class="fail"'
                body.append(f"<tr{css}>" + "".join(f"<td>{breakable(str(c))}</td>" for c in cells)
                            + "</tr>")
    return ('<div class="wide"><table class="scenarios"><tr>' + "".join(f"<th>{h}</th>" for h in head)
            + "</tr>" + "".join(body) + "</table></div>")


def _scheduling_cell(coverage: dict | None, names: list[str]) -> str:
    """Visited range of each scheduling signal (by name); for an LPV controller, the time outside its
    design box."""
    if not coverage:
        return "–"
    ranges = coverage["range"]
    labels = names if len(names) == len(ranges) else [f"θ{i + 1}" for i in range(len(ranges))]
    cell = "; ".join(f"{n} {lo:.3g} … {hi:.3g}" for n, (lo, hi) in zip(labels, ranges, strict=True))
    if coverage["box"] is not None:
        cell += f"; {number_text(coverage['time_outside_box'])} s outside the design box"
    return cell


#: How the verification record names the controllers, and how the report does.
CONTROLLERS = {"lpv": "LPV controller", "baseline": "LTI baseline"}


def adoption_table(rows: list[dict]) -> str:
    """Before/after adoption of the diagnosed extension: one row per scenario and tracked output, the
    LPV controller designed on the identified model (before) and on the extended one (after)."""
    head = ["scenario", "output", "controller", "stable", "settling [s]", "overshoot", "IAE", "ISE",
            "steady-state error"]
    body = []
    for row in rows:
        for key in ("before", "after"):
            m = row[key]
            cells = [row["scenario"], row["output"], f"{key} adoption", "yes" if m["stable"] else "no",
                     number_text(m["settling_time"]), number_text(m["overshoot_percent"], " %", 2),
                     number_text(m["iae"], "", 4), number_text(m["ise"], "", 4),
                     number_text(m["steady_state_error"])]
            css = "" if m["stable"] else ' class="fail"'
            body.append(f"<tr{css}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
    return ("<h3>Before/after adoption</h3><table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"
            + "".join(body) + "</table>")
