"""The design report's first screen: verdict, specification, the LPV controller against the LTI
baseline per scenario, γ, the largest step the baseline holds and the identification-for-control
rounds."""

from __future__ import annotations

import html
from pathlib import Path

from lpvflow.pipeline.report_text import (
    GATE_WORDS,
    DisplayUnit,
    breakable,
    number_text,
    short_reason,
    signal_value,
)
from lpvflow.pipeline.scenarios import run_passed


def summary_card(summary: dict, units: dict[str, str]) -> str:
    """The report's first screen: the verdict (and, for a run that stopped early, where and why), the
    specification, the LPV controller against the LTI baseline per scenario (nominal, then on perturbed
    plants: scenarios with ``parameter_factors``), γ of both and the largest step the baseline holds.
    ``units``: signal name → unit (angles in rad are shown in degrees)."""
    shown = {name: DisplayUnit.of(unit) for name, unit in units.items()}
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
    parts.append(_robustness_line(stages.get("robustness", {}).get("outputs", {}), shown))
    if scenarios:
        parts.append(_held_step_line(verify, shown))
    if summary.get("iterations"):
        parts.append(_iterations_table(summary["iterations"]))
    return f'<section class="summary"><h2>Results at a glance</h2>{"".join(parts)}</section>'


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


def _specification(scenarios: list[dict], units: dict[str, DisplayUnit]) -> str:
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


def _requirement_text(requirements: dict | None, bands: dict[str, float],
                      units: dict[str, DisplayUnit]) -> str:
    """One scenario's specification as a phrase, e.g. "arm_angle into ±1° within 1.5 s, overshoot ≤ 2°;
    pendulum_angle within ±1° after settling"."""
    if not requirements:
        return "stable (settles, stays within its output bounds); no requirements"
    parts = []
    for name, band in bands.items():
        unit = units.get(name, DisplayUnit(""))
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
        unit = units.get(name, DisplayUnit(""))
        parts.append(f"{name} within ±{unit.value(bound)}{unit.label} after settling")
    return "; ".join(p for p in parts if p)


def _ordered(names: list[str]) -> list[str]:
    return list(dict.fromkeys(names))


def _comparison_table(scenarios: list[dict], units: dict[str, DisplayUnit], perturbed: bool) -> str:
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
        unit = units.get(name, DisplayUnit(""))
        heads += [f"{name} settling [s]", unit.head(f"{name} overshoot")]
    heads += [units.get(name, DisplayUnit("")).head(f"{name} after settling") for name in after]
    heads.append("result")
    controllers = [("controller", "LPV controller")]
    if any(s.get("baseline") for s in scenarios):
        controllers.append(("baseline", "LTI baseline"))
    first = ["scenario"] + (["parameter factors"] if perturbed else [])
    head = ("<tr>" + "".join(f'<th rowspan="2">{h}</th>' for h in first)
            + "".join(f'<th colspan="{len(heads)}">{label}</th>' for _, label in controllers) + "</tr><tr>"
            + "".join(f"<th>{breakable(h)}</th>" for _ in controllers for h in heads) + "</tr>")
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
               units: dict[str, DisplayUnit]) -> list[str]:
    """The comparison cells of one run (:func:`_comparison_table`), escaped; a missed bound is red."""
    def cell(text: str, missed: bool) -> str:
        return f'<td class="fail">{breakable(text)}</td>' if missed else breakable(text)

    cells = []
    for name in tracked:
        m = run.get("outputs", {}).get(name, {})
        unit = units.get(name, DisplayUnit(""))
        settling, limit = m.get("settling_time"), requirements.get("settling_time")
        late = bool(m) and limit is not None and (settling is None or settling > limit)
        cells.append(cell("not settled" if m and settling is None else number_text(settling), late))
        overshoot, limit = m.get("overshoot"), requirements.get("overshoot")
        cells.append(cell(unit.value(overshoot), overshoot is not None and limit is not None
                          and overshoot > limit))
    bounds = requirements.get("after_settling", {})
    for name in after:
        peak = run.get("after_settling", {}).get(name)
        cells.append(cell(units.get(name, DisplayUnit("")).value(peak),
                          peak is not None and name in bounds and peak > bounds[name]))
    if run_passed(run):
        cells.append('<td class="pass">pass</td>' if "requirements_failed" in run else
                     '<td class="pass">stable</td>')
    else:
        why = "" if run["stable"] else f": {short_reason(run['reason'])}"
        cells.append(f'<td class="fail">fail{breakable(why)}</td>')
    return cells


def _gamma_line(synth: dict) -> str:
    """γ of the LPV controller and of the LTI baseline (and where the baseline was designed)."""
    if "gamma" not in synth:
        return ""
    text = f"H∞ γ: LPV controller {synth['gamma']:.4g}"
    if synth.get("method") == "loop-shaping":
        text = (f"H∞ loop shaping: largest level γ_i = {synth['gamma']:.4g} of the shaped plants "
                "(b(Gs_i, K∞_i) ≥ 1/γ_i; not comparable with a mixed-sensitivity γ)")
        if synth.get("scheduling") == "common":
            text = (f"H∞ loop shaping with one Lyapunov matrix over all breakpoints: level γ = "
                    f"{synth['gamma']:.4g}, certified for every value and every rate of change of the "
                    "scheduling signal (not comparable with a mixed-sensitivity γ)")
    elif synth.get("method") == "observer":
        text += " (largest frozen closed-loop ‖T_zw‖∞ of the observer design; no LMI bound)"
    if synth.get("baseline_gamma") is not None:
        at = ", ".join(f"{v:.3g}" for v in synth.get("baseline_at") or [])
        kind = " (the same loop shaping at one point)" if synth.get("method") == "loop-shaping" else ""
        text += (f"; LTI baseline{kind} {synth['baseline_gamma']:.4g}"
                 + (f" (designed at θ = {at})" if at else ""))
    return f"<p>{html.escape(text)}</p>"


def _robustness_line(robustness: dict, units: dict[str, DisplayUnit]) -> str:
    """The robustness stage in one line: b(Ĝ, K_fb) against the ν-gap over the validate points (the range
    of each, how many points have b > ν-gap), the smallest delay margin and input disk margin, and the
    largest difference between the model-in-the-loop and the plant-in-the-loop runs of each measured
    output over the verify scenarios (:func:`worst_trajectory_text`, reported, not judged)."""
    rows = [r for r in robustness.get("rows", []) if r.get("nugap") is not None]
    trajectory = worst_trajectory_text(robustness.get("trajectory") or [], units)
    if not rows:
        return f"<p>{html.escape(trajectory[:1].upper() + trajectory[1:])}.</p>" if trajectory else ""
    held = sum(bool(r["b_above_nugap"]) for r in rows)
    b = [r["b"] for r in rows]
    nu = [r["nugap"] for r in rows]
    text = (f"Robust stability (Vinnicombe, b(Ĝ, K) > ν-gap): b {min(b):.3g}–{max(b):.3g} against ν-gap "
            f"{min(nu):.3g}–{max(nu):.3g}; b > ν-gap at {held} of {len(rows)} validate points")
    delays = [r["delay_margin_samples"] for r in rows if r.get("delay_margin_samples") is not None]
    disks = [r["input_disk_margin"] for r in rows if r.get("input_disk_margin") is not None]
    if delays:
        text += f"; delay margin ≥ {min(delays)} samples"
    if disks:
        text += f"; input disk margin ≥ {min(disks):.2f}"
    if trajectory:
        text += f"; {trajectory}"
    css = "pass" if held == len(rows) else "fail"
    return f'<p class="{css}">{html.escape(text)}</p>'


def worst_trajectory_text(rows: list[dict], units: dict[str, DisplayUnit]) -> str:
    """The largest model-in-the-loop against plant-in-the-loop difference of each measured output over the
    scenarios of the robustness stage's ``trajectory`` rows and where, in display units, e.g. "model vs
    plant in the loop, largest difference: arm_angle 10.4° (arm to -75 deg), pendulum_angle 0.286° (arm
    to -75 deg)"; "" without rows."""
    if not rows:
        return ""
    worst = []
    for name in rows[0]["largest_difference"]:
        row = max(rows, key=lambda r, name=name: r["largest_difference"][name])
        worst.append(f"{name} {signal_value(name, row['largest_difference'][name], units)} "
                     f"({row['scenario']})")
    return f"model vs plant in the loop, largest difference: {', '.join(worst)}"


def _held_step_line(verify: dict, units: dict[str, DisplayUnit]) -> str:
    """The largest step the LTI baseline (and the LPV controller) holds: the verify stage's output
    ``largest_held_step`` = {"output": name, "criterion": "passes" | "bounded", "baseline": amplitude,
    "lpv": amplitude (optional), "resolution": of the bisection (optional)}, amplitudes in the output's
    units, as :func:`lpvflow.pipeline.step_sweep.largest_held_step` returns them."""
    record = verify.get("largest_held_step")
    if not record:
        return "<p>Largest step the LTI baseline holds: not measured in this run.</p>"
    return f"<p>{html.escape(held_step_text(record, units))}.</p>"


def held_step_text(record: dict, units: dict[str, DisplayUnit]) -> str:
    """:func:`_held_step_line`'s sentence (also the verify table's cell), amplitudes in display units."""
    unit = units.get(record["output"], DisplayUnit(""))
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


def _iterations_table(rounds: list[dict]) -> str:
    """The identification-for-control rounds (``[experiment] iterate``, ``summary["iterations"]``): per
    round its experiment controller, model order, fit, largest ν-gap against smallest b(P, K_id), the
    gate, and the γ of its design; a final pass that was rejected and the one that fell back to the round
    before (:func:`lpvflow.pipeline.design._run_final_pass`) are labelled, the rejection stated below."""
    head = ["round", "experiment controller", "order", "fit BFR [%]", "largest ν-gap", "smallest b(P, K_id)",
            "gate", "γ (LPV / LTI baseline)"]
    body, notes = [], []
    for r in rounds:
        gate = r.get("gate") or {}
        used = Path(r["experiment_controller"]) if r.get("experiment_controller") else None
        label = f"{r['iteration']} (final, fallback)" if r.get("fallback") else str(r["iteration"])
        cells = [label + (" rejected" if r.get("rejected") else ""),
                 "open loop" if used is None else f"{used.parent.name}/{used.name}",
                 number_text(r.get("order")),
                 ", ".join(number_text(b, "", 3) for b in r.get("fit_bfr") or []) or "–",
                 number_text(r.get("max_nugap")), number_text(r.get("min_b_P_Kid")),
                 "–" if not gate else GATE_WORDS[gate.get("passed")],
                 f"{number_text(r.get('gamma'), '', 4)} / {number_text(r.get('baseline_gamma'), '', 4)}"]
        css = ' class="fail"' if r.get("rejected") or gate.get("passed") is False else ""
        body.append(f"<tr{css}>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
        if r.get("rejected"):
            where = f"its files are in {r['folder']}/; " if r.get("folder") else ""
            notes.append(f"Round {r['iteration']} was rejected ({r['rejected']}); {where}the final design "
                         f"uses the record of round {r['iteration'] - 1}'s experiment.")
    return ("<h3>Identification for control ([experiment] iterate)</h3><table><tr>"
            + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" + "".join(body) + "</table>"
            + "".join(f"<p>{html.escape(n)}</p>" for n in notes))
