"""The design report's first screen (issue 24, item 5): the summary card over a given summary dict."""

from __future__ import annotations

import copy
import html
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from lpvflow.pipeline.design import verdict_line
from lpvflow.pipeline.report import write_report
from lpvflow.pipeline.report_card import summary_card
from lpvflow.pipeline.report_text import format_value, signal_units

UNITS = {"arm_angle": "rad", "pendulum_angle": "rad", "voltage": "V"}
SPEC = {"settling_time": 1.5, "overshoot": 0.0349, "after_settling": {"pendulum_angle": 0.0175}}


def run(label: str, settling: float | None, overshoot: float, pendulum: float, failed: list[str]) -> dict:
    """One run's metrics as lpvflow.pipeline.verify writes them (the fields the card reads)."""
    return {"controller": label, "stable": True, "reason": "bounded and settled",
            "outputs": {"arm_angle": {"settling_time": settling, "settled": True, "band": 0.0175,
                                      "overshoot": overshoot, "overshoot_percent": 1.0}},
            "controls": {"voltage": {"peak_control": 4.0, "saturation_time": 0.0}}, "scheduling": None,
            "after_settling": {"pendulum_angle": pendulum}, "requirements_failed": failed}


def lost(label: str) -> dict:
    return {"controller": label, "stable": False, "outputs": {}, "controls": {}, "scheduling": None,
            "reason": "unbounded: pendulum_angle left its output_bounds at t = 1.585 s",
            "requirements_failed": ["the run failed (see reason)"]}


def scenario(name: str, lpv: dict, lti: dict, **extra: object) -> dict:
    return {"name": name, "duration": 4.0, "requirements": SPEC, "controller": lpv, "baseline": lti, **extra}


@pytest.fixture
def summary() -> dict:
    scenarios = [
        scenario("arm to +30 deg", run("lpv", 1.21, 0.0226, 0.0008, []),
                 run("baseline", 2.09, 0.0, 0.011, ["arm_angle settles in 2.09 s (limit 1.5 s)"])),
        scenario("arm to -30 deg", run("lpv", 1.33, 0.0, 0.0025, []), run("baseline", 1.35, 0.0, 0.0110, [])),
        scenario("arm to +75 deg", run("lpv", 1.48, 0.0300, 0.0150, []), lost("baseline")),
        scenario("+70 deg, heavier pendulum",
                 run("lpv", 2.31, 0.0100, 0.0300, ["arm_angle settles in 2.31 s (limit 1.5 s)",
                                                   "pendulum_angle after settling 0.03 (limit 0.0175)"]),
                 lost("baseline"), parameter_factors={"pendulum_mass": 1.1}),
    ]
    verify = {"scenarios": scenarios, "loop": {"measured": ["arm_angle", "pendulum_angle"],
                                               "actuator_limits": {"voltage": [-10.0, 10.0]}},
              "largest_held_step": {"output": "arm_angle", "criterion": "passes", "baseline": 0.6545,
                                    "resolution": math.radians(2.5)}}
    stages = {"synth": {"status": "ran", "seconds": 1.0, "artifacts": [],
                        "outputs": {"gamma": 1.4758, "baseline_gamma": 1.4336,
                                    "baseline_at": [0.0]}},
              "verify": {"status": "ran", "seconds": 1.0, "artifacts": [], "outputs": verify}}
    reason = "+70 deg, heavier pendulum: misses arm_angle settles in 2.31 s"
    return {"name": "adip", "stages": stages, "failed": None, "verdict": {"pass": False, "reason": reason}}


def rows(table: str) -> list[list[str]]:
    """Cell texts of every row with data cells."""
    found = []
    for row in re.findall(r"<tr>(.*?)</tr>", table):
        cells = [html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row)]
        if cells:
            found.append(cells)
    return found


def test_the_card_compares_both_controllers_per_scenario_in_order_with_units(summary):
    card = summary_card(summary, UNITS).replace("<wbr>", "")  # line-break opportunities after "_"
    nominal, perturbed = card.split("Robustness: perturbed plants")
    heads = re.findall(r"<th[^>]*>(.*?)</th>", nominal)
    assert heads[:3] == ["scenario", "LPV controller", "LTI baseline"]
    assert heads[3:7] == ["arm_angle settling [s]", "arm_angle overshoot [°]",
                          "pendulum_angle after settling [°]", "result"]
    # settling in s, overshoot and pendulum in degrees (rad × 180/π), LPV then LTI, scenarios in order
    assert rows(nominal) == [
        ["arm to +30 deg", "1.21", "1.29", "0.0458", "pass", "2.09", "0", "0.63", "fail"],
        ["arm to -30 deg", "1.33", "0", "0.143", "pass", "1.35", "0", "0.63", "pass"],
        ["arm to +75 deg", "1.48", "1.72", "0.859", "pass", "–", "–", "–",
         "fail: pendulum_angle out of bounds at 1.58 s"],
    ]
    assert rows(perturbed) == [["+70 deg, heavier pendulum", "pendulum_mass × 1.1", "2.31", "0.573", "1.72",
                                "fail", "–", "–", "–", "fail: pendulum_angle out of bounds at 1.58 s"]]
    # the cells that miss the specification are the marked ones: the baseline's 2.09 s, the perturbed
    # run's 2.31 s and its pendulum 1.72° > 1°
    marked = re.findall(r'<td class="fail">([\d.]+)</td>', card)
    assert marked == ["2.09", "2.31", "1.72"]


def test_the_card_states_spec_gammas_verdict_and_the_largest_held_step(summary):
    text = html.unescape(re.sub(r"<[^>]+>", " ", summary_card(summary, UNITS)))
    assert ("arm to +30 deg, arm to -30 deg, arm to +75 deg, +70 deg, heavier pendulum : arm_angle into ±1° "
            "within 1.5 s, overshoot ≤ 2°; pendulum_angle within ±1° after settling") in text
    assert "Verdict: did not pass — LPV controller passes 3 of 4 scenarios, LTI baseline 1 of 4" in text
    assert "LPV controller 1.476; LTI baseline 1.434 (designed at θ = 0)" in text
    assert "lower bound" not in text
    assert ("Largest arm_angle step the LTI baseline holds: 37.5°; held means the run meets its scenario's "
            "specification; found by bisection to within 2.5°.") in text


@pytest.mark.parametrize("scheduling", ["frozen", "common"])
def test_the_card_says_what_a_loop_shaping_level_certifies(summary, scheduling):
    """Frozen loop shaping: per-breakpoint levels; one Lyapunov matrix: certified for any rate."""
    summary["stages"]["synth"]["outputs"].update(method="loop-shaping", scheduling=scheduling)
    text = html.unescape(re.sub(r"<[^>]+>", " ", summary_card(summary, UNITS)))
    assert ("largest level γ_i = 1.476 of the shaped plants" in text) == (scheduling == "frozen")
    assert ("level γ = 1.476, certified for every value and every rate of change of the scheduling signal"
            in text) == (scheduling == "common")


def test_the_card_states_b_against_the_nugap_from_the_robustness_stage(summary):
    """The card's robust-stability line: ranges of b and ν-gap, how many points have b > ν-gap, the
    smallest delay and disk margins — counted from the stage's rows, and marked failed when one point
    misses."""
    rows_ = [{"theta": [0.1 * i], "b": 0.08 + 0.01 * i, "nugap": 0.05 - 0.01 * i, "b_above_nugap": True,
              "delay_margin_samples": 3 + i, "input_disk_margin": 0.4 + 0.05 * i} for i in range(3)]
    rows_[1]["nugap"], rows_[1]["b_above_nugap"] = 0.2, False
    summary["stages"]["robustness"] = {"status": "ran", "seconds": 0.1, "artifacts": [],
                                       "outputs": {"rows": rows_, "guaranteed": False}}
    card = summary_card(summary, UNITS)
    text = html.unescape(re.sub(r"<[^>]+>", " ", card))
    assert ("Robust stability (Vinnicombe, b(Ĝ, K) > ν-gap): b 0.08–0.1 against ν-gap 0.03–0.2; b > ν-gap "
            "at 2 of 3 validate points; delay margin ≥ 3 samples; input disk margin ≥ 0.40") in text
    assert '<p class="fail">Robust stability' in card


def test_without_units_the_card_says_output_units_and_shows_the_numbers_as_they_are(summary):
    card = summary_card(summary, {}).replace("<wbr>", "")
    assert "arm_angle overshoot (output units)" in card
    assert rows(card.split("Robustness")[0])[0][:3] == ["arm to +30 deg", "1.21", "0.0226"]


def test_a_card_without_a_step_sweep_or_scenarios_says_so(summary):
    del summary["stages"]["verify"]["outputs"]["largest_held_step"]
    assert "Largest step the LTI baseline holds: not measured in this run." in summary_card(summary, UNITS)
    del summary["stages"]["verify"]
    card = summary_card(summary, UNITS)
    assert "<table" not in card and "LPV controller 1.476" in card


def test_the_card_lists_identification_for_control_rounds_and_marks_a_refused_model(summary):
    first = {"iteration": 0, "folder": "iteration_0",
             "experiment_controller": "/x/adip/scheduled_controller.json", "order": 5,
             "fit_bfr": [98.43, 91.17], "max_nugap": 0.0662, "min_b_P_Kid": 0.1033,
             "gate": {"passed": True}, "gamma": 2.7707, "baseline_gamma": 1.5567}
    second = {"iteration": 1, "folder": ".", "experiment_controller": "/x/iteration_0/controller.json",
              "order": 5, "fit_bfr": [99.09, 59.92], "max_nugap": 0.2772, "min_b_P_Kid": 0.0,
              "gate": {"passed": False}, "gamma": None, "baseline_gamma": None}
    # the final pass judged by the robustness stage: its K_id test "not applied", not a failed model
    third = {**second, "iteration": 2, "gate": {"passed": None}}
    summary["iterations"] = [first, second, third]
    table = summary_card(summary, UNITS).split("Identification for control")[1]
    found = [[html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row)]
             for row in re.findall(r"<tr[^>]*>(.*?)</tr>", table)]
    assert [cells for cells in found if cells] == [
        ["0", "adip/scheduled_controller.json", "5", "98.4, 91.2", "0.0662", "0.103", "passed",
         "2.771 / 1.557"],
        ["1", "iteration_0/controller.json", "5", "99.1, 59.9", "0.277", "0", "failed", "– / –"],
        ["2", "iteration_0/controller.json", "5", "99.1, 59.9", "0.277", "0", "not applied", "– / –"]]
    assert table.count('<tr class="fail">') == 1


def test_the_report_opens_with_the_card_and_has_no_json_cells(tmp_path, summary):
    summary["stages"]["experiment"] = {"status": "ran", "seconds": 0.1, "artifacts": [], "outputs": {
        "ranges": {"voltage": [-4.855, 4.407]}, "offsets": {}, "nested": {"a": {"b": [1.0, 2.0]}}}}
    page = write_report(tmp_path, summary, UNITS).read_text()
    body = page.split("</style>", 1)[1]
    assert body.index("Results at a glance") < body.index("<h2>Stages</h2>") < body.index("<h2>verify</h2>")
    assert "{" not in body and "}" not in body and '"' not in re.sub(r"<[^>]+>", "", body)
    assert "voltage -4.86 V … 4.41 V" in body and "a: b: [1, 2]" in body


@pytest.mark.parametrize(("value", "text"), [
    ({"measured": ["arm_angle", "pendulum_angle"], "u_operating_point": None,
      "actuator_limits": {"voltage": [-10.0, 10.0]}},
     "measured: arm_angle; pendulum_angle; u_operating_point: –; actuator_limits: voltage: [-10, 10]"),
    ([{"name": "a", "ok": True}, {"name": "b", "ok": False}], "name: a; ok: yes | name: b; ok: no"),
    ([[-0.556], [0.606]], "-0.556; 0.606"),
    ({}, "–"),
])
def test_stage_outputs_read_as_text_not_json(value, text):
    assert format_value(value) == text


def test_units_come_from_the_controllers_port_record(tmp_path):
    ports = {"measured": [{"name": "arm_angle", "unit": "rad"}],
             "actuated": [{"name": "voltage", "unit": "V"}], "scheduling": [{"name": "sin_arm", "unit": ""}]}
    (tmp_path / "controller.json").write_text(json.dumps({"info": {"signals": ports}}))
    assert signal_units(tmp_path) == {"arm_angle": "rad", "voltage": "V"}
    assert signal_units(tmp_path / "missing") == {}


def test_the_verdict_line_counts_scenarios_and_gives_the_reason(summary):
    assert verdict_line(summary) == ("design did not pass: LPV controller passes 3 of 4 scenarios, LTI "
                                     "baseline 1 of 4; +70 deg, heavier pendulum: misses arm_angle settles "
                                     "in 2.31 s")
    passed = copy.deepcopy(summary)
    passed["verdict"] = {"pass": True, "reason": "every configured stage ran and every scenario passed"}
    assert verdict_line(passed).startswith("design passed: LPV controller passes 3 of 4")
    stopped = {"stages": {}, "verdict": {"pass": False, "reason": "stage synth failed"}}
    assert verdict_line(stopped) == "design did not pass: stage synth failed"


def test_report_figures_are_optional(tmp_path: Path, summary):
    assert write_report(tmp_path, summary).name == "report.html"  # no controller.json: no units, no figures


def test_stage_tables_use_words_units_and_file_names(tmp_path, summary):
    """No raw output key, no bookkeeping row, no folder of the plant; angles in degrees like the card."""
    verify = summary["stages"]["verify"]["outputs"]
    verify |= {"format": "lpvflow/verification", "version": 1, "plant": "/home/someone/plants/adip.fmu",
               "loop": {"measured": ["arm_angle"], "actuated": ["voltage"], "scheduling": ["sin(arm_angle)"],
                        "actuator_limits": {"voltage": [-10.0, 10.0]}}}
    summary["stages"]["validate"] = {"status": "ran", "seconds": 1.0, "artifacts": [], "outputs": {
        "b_P_Kid": [0.11, 0.19], "nugap_below_b_everywhere": True, "scaling": {"arm_angle": 0.3}}}
    body = write_report(tmp_path, summary, UNITS).read_text().split("</style>", 1)[1]
    cells = re.findall(r"<th>([^<]*)</th>", body)
    for key in ("b_P_Kid", "nugap_below_b_everywhere", "largest_held_step", "format", "version"):
        assert key not in cells
    assert "/home/someone" not in body and "<td>adip.fmu</td>" in body
    assert "arm_angle 17.2°" in body  # 0.3 rad
    assert "limits voltage -10 V … 10 V" in body
    held = verify["largest_held_step"]
    assert f"{math.degrees(held['baseline']):.3g}°" in body.split("<h2>verify</h2>", 1)[1]


def test_the_nugap_figure_is_drawn_over_the_plant_signal_the_scheduling_comes_from(tmp_path):
    """Frozen points of (sin φ, 1/(1 − κ cos² φ)) map back to the arm angle φ, in degrees."""
    import numpy as np

    from lpvflow.pipeline.report_figures import GAP_FIGURE, draw_figures, physical_axis
    from lpvflow.pipeline.report_text import DisplayUnit

    rng = np.random.default_rng(4)
    angles = np.sort(rng.uniform(-1.3, 1.3, 7))
    expressions = {"sin_arm": "sin(arm_angle)", "inv_det": "1/(1 - 0.3785*cos(arm_angle)**2)"}
    (tmp_path / "controller.json").write_text(json.dumps({"info": {"signals": {"scheduling": [
        {"name": n, "expression": e} for n, e in expressions.items()]}}}))
    (tmp_path / "experiment.json").write_text(json.dumps({"outputs": {"ranges": {
        "voltage": [-6.0, 6.0], "arm_angle": [-1.33, 1.37]}}}))
    thetas = [[np.sin(a), 1 / (1 - 0.3785 * np.cos(a) ** 2)] for a in angles]
    units = {"arm_angle": DisplayUnit.of("rad"), "voltage": DisplayUnit.of("V")}
    values, label = physical_axis(tmp_path, thetas, units)
    assert label == "arm_angle [°]"
    np.testing.assert_allclose(values, np.degrees(angles), atol=0.05)  # the 4001-point search grid
    assert physical_axis(tmp_path, [[0.5, 9.0]], units) is None  # off the curve
    (tmp_path / "validate.json").write_text(json.dumps({"outputs": {
        "theta": thetas, "nugap": [0.05] * 7, "b_P_Kid": [0.2] * 7}}))
    assert GAP_FIGURE in draw_figures(tmp_path, units)


def test_the_scenario_table_shows_each_outputs_peak_deviation_as_the_cross_coupling_peak(tmp_path, summary):
    """Per run and output, the verify record's peak |y − r| lands in its own column in display units: for
    the output whose reference does not change, the cross-coupling peak (thesis §6.2's comparison)."""
    rng = np.random.default_rng(5)
    scenarios = summary["stages"]["verify"]["outputs"]["scenarios"]
    expected = {}
    for scenario_record in scenarios:
        for key in ("controller", "baseline"):
            outputs = scenario_record[key]["outputs"]
            if not outputs:
                continue
            outputs["pendulum_angle"] = {"settling_time": None, "settled": True, "band": 0.0175,
                                         "overshoot": None}
            for name in outputs:
                outputs[name]["peak_deviation"] = float(rng.uniform(0.001, 0.5))
                expected[(scenario_record["name"], key, name)] = math.degrees(outputs[name]["peak_deviation"])
    body = write_report(tmp_path, summary, UNITS).read_text().split("<h2>verify</h2>", 1)[1]
    table = body.split('<table class="scenarios">', 1)[1].split("</table>", 1)[0]
    head = [html.unescape(h) for h in re.findall(r"<th>([^<]*)</th>", table)]
    column = head.index("peak |y − r|")
    shown = {}
    for row in re.findall(r"<tr[^>]*>(.*?)</tr>", table):
        cells = [html.unescape(re.sub(r"<[^>]+>", "", c)) for c in re.findall(r"<td[^>]*>(.*?)</td>", row)]
        if len(cells) == len(head):
            key = "controller" if cells[1] == "LPV controller" else "baseline"
            shown[(cells[0], key, cells[3])] = cells[column]
    assert expected and set(expected) <= set(shown)
    for key, text in shown.items():  # a lost run has no metrics: "–"
        assert text == (f"{expected[key]:.3g}°" if key in expected else "–")


def test_the_robustness_section_tables_the_model_in_the_loop_difference_in_degrees(summary):
    """The robustness stage's ``trajectory`` rows (radians) as the report's table, one row per scenario in
    degrees with how each run ended, and the card's robustness line naming each output's largest value
    and its scenario; random values, a model run that was lost."""
    from lpvflow.pipeline.report_robustness import trajectory_table
    from lpvflow.pipeline.report_text import DisplayUnit

    rng = np.random.default_rng(7)
    names = [s["name"] for s in summary["stages"]["verify"]["outputs"]["scenarios"]]
    rows_ = [{"scenario": name, "largest_difference": {"arm_angle": float(rng.uniform(0.0, 0.2)),
                                                       "pendulum_angle": float(rng.uniform(0.0, 0.02))},
              "plant_failure": None, "model_failure": None} for name in names]
    rows_[2]["model_failure"] = "unbounded: pendulum_angle left its output_bounds at t = 1.25 s"
    table = trajectory_table(rows_, {name: DisplayUnit.of(unit) for name, unit in UNITS.items()})
    assert "largest arm_angle difference [°]" in table and "largest pendulum_angle difference [°]" in table
    assert rows(table) == [
        [r["scenario"], f"{math.degrees(r['largest_difference']['arm_angle']):.3g}",
         f"{math.degrees(r['largest_difference']['pendulum_angle']):.3g}", "ran to the end",
         "pendulum_angle out of bounds at 1.25 s" if r["model_failure"] else "ran to the end"] for r in rows_]
    summary["stages"]["robustness"] = {"status": "ran", "seconds": 0.1, "artifacts": [],
                                       "outputs": {"rows": [], "guaranteed": None, "trajectory": rows_}}
    text = html.unescape(re.sub(r"<[^>]+>", " ", summary_card(summary, UNITS)))
    arm = max(rows_, key=lambda r: r["largest_difference"]["arm_angle"])
    pendulum = max(rows_, key=lambda r: r["largest_difference"]["pendulum_angle"])
    worst_arm = math.degrees(arm["largest_difference"]["arm_angle"])
    worst_pendulum = math.degrees(pendulum["largest_difference"]["pendulum_angle"])
    assert (f"Model vs plant in the loop, largest difference: arm_angle {worst_arm:.3g}° "
            f"({arm['scenario']}), pendulum_angle {worst_pendulum:.3g}° ({pendulum['scenario']}).") in text


def test_a_failed_experiment_shows_no_figure_of_the_record_a_previous_run_left(tmp_path, summary):
    """A failed experiment writes nothing, so the folder's data.csv is the previous run's: the report draws
    the record only for an experiment that ran (here the same file either way)."""
    t = np.arange(0.0, 1.0, 0.01)
    (tmp_path / "data.csv").write_text("time,voltage,arm_angle\n" + "".join(
        f"{a},{np.sin(a)},{np.cos(a)}\n" for a in t))
    caption = "Identification experiment: inputs, outputs and scheduling."
    summary["stages"]["experiment"] = {"status": "ran", "seconds": 0.1, "artifacts": [], "outputs": {}}
    assert caption in write_report(tmp_path, summary, UNITS).read_text()
    error = "plant output pendulum_angle = 0.51 left its bounds [-0.5, 0.5] at t=12.8 s"
    summary["stages"]["experiment"] = {"status": "failed", "error": error}
    summary["failed"] = {"stage": "experiment", "error": error}
    page = write_report(tmp_path, summary, UNITS).read_text()
    assert caption not in page
    assert "left its bounds" in page
