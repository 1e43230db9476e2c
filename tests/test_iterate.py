"""``[experiment] iterate = N`` (issue 24, item 1): identification for control — after synth the experiment
is run again under the controller just designed, re-identified, validated against b(P, K) of that
controller and re-designed; per-round numbers and stage times in summary.json."""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np
import pytest

from lpvflow import load
from lpvflow.data import Dataset, read_columns
from lpvflow.errors import DataError
from lpvflow.identify.arx import identify_arx
from lpvflow.pipeline.config import check_table
from lpvflow.pipeline.design import run_design
from tests.design_files import adip_identification
from tests.fmu_builds import built_fmu

ROOT = Path(__file__).resolve().parents[1]
STABILIZING = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"

DESIGN = """
[design]
name = "iterated"
plant = "{plant}"
output_dir = "{out}"

[experiment]
Ts = 0.005
duration = 20.0
controller = "{controller}"
excitation = {{ voltage = "multisine:f_lo=0.05,f_hi=20,rms=0.1" }}
scheduling = {{ sin_arm = "sin(arm_angle)" }}
seed = 1
iterate = 1

""" + adip_identification(3) + """
[synth]
weights.S = [{{ bandwidth = 2.0, hf_gain = 1.0 }}, {{ num = [0.3], den = [1] }}]
weights.R = [{{ num = [1.0], den = [1] }}, {{ num = [0.01], den = [1] }}]
weights.K = {{ num = [0.05], den = [1] }}
{input_filter}
weights.integrator_shift = 1e-4
"""
#: the W_B of tests/adip_cases.py HINF_WEIGHTS: strictly proper, so the vertex controllers interpolate
INPUT_FILTER = "weights.B = { num = [0, 0.3], den = [1, -0.7] }"


@pytest.fixture(scope="module")
def adip() -> Path:
    return built_fmu("adip")


def write(tmp_path: Path, adip: Path, input_filter: str = INPUT_FILTER, **replacements: str) -> Path:
    text = DESIGN.format(plant=adip, out=tmp_path, controller=STABILIZING, input_filter=input_filter)
    for old, new in replacements.items():
        text = text.replace(old, new)
    path = tmp_path / "design.toml"
    path.write_text(text)
    return path


def test_one_round_reidentifies_under_the_designed_controller(adip, tmp_path):
    """Round 0 (iteration_0/) identifies under the LTI regulator and designs an LPV controller; the final
    round in the design folder runs the experiment under that controller file, identifies, validates with
    b(P, K) of it and designs again. A second run reuses every stage of both rounds."""
    path = write(tmp_path, adip)
    summary = run_design(path, log=lambda line: None)
    assert summary["failed"] is None, summary["failed"]
    folder = tmp_path / "iterated"
    first, last = summary["iterations"]
    assert (first["iteration"], first["folder"], first["experiment_controller"]) == (0, "iteration_0",
                                                                                     str(STABILIZING))
    designed = str(folder / "iteration_0" / "controller.json")
    assert (last["iteration"], last["folder"], last["experiment_controller"]) == (1, ".", designed)
    sidecars = [json.loads((where / "data.csv.json").read_text())
                for where in (folder / "iteration_0", folder)]
    assert sidecars[0]["controller"]["format"] == "lpvflow/lti-controller"
    assert sidecars[1]["controller"]["format"] == "lpvflow/lpv-controller"
    assert sidecars[1]["controller_file"]["path"] == designed
    # the final round's validate used the designed controller: another b(P, K), stabilizing everywhere
    assert last["min_b_P_Kid"] > 0 and last["min_b_P_Kid"] != pytest.approx(first["min_b_P_Kid"], rel=1e-3)
    assert last["gamma"] == summary["stages"]["synth"]["outputs"]["gamma"]
    for entry in (first, last):
        assert all(entry["stage_seconds"][name] > 0
                   for name in ("experiment", "identify", "validate", "synth"))
        assert entry["order"] == 4 and entry["max_nugap"] < 0.1
    assert summary["stage_seconds"]["synth"] == last["stage_seconds"]["synth"]

    lines: list[str] = []
    again = run_design(path, log=lines.append)
    ran = [line for line in lines if line.endswith("…")]
    assert not ran, ran
    assert again["iterations"][1]["gamma"] == last["gamma"]


def test_a_failing_round_ends_the_run_and_its_stages_are_the_summary(adip, tmp_path):
    """Without a strictly proper W_B round 0's synthesis fails: the run stops there, the failure names the
    round, and the summary's stages are that round's, artifacts relative to the design folder."""
    summary = run_design(write(tmp_path, adip, input_filter=""), log=lambda line: None)
    assert summary["failed"]["stage"] == "synth (iteration 0)"
    assert summary["verdict"] == {"pass": False, "reason": "stage synth (iteration 0) failed"}
    assert len(summary["iterations"]) == 1
    assert summary["stages"]["experiment"]["artifacts"] == ["iteration_0/data.csv",
                                                            "iteration_0/data.csv.json"]
    assert (tmp_path / "iterated" / "iteration_0" / "data.csv").is_file()
    assert not (tmp_path / "iterated" / "data.csv").exists()


#: The robustness gate on, and the validate scaling weighing the arm 100× the voltage and the pendulum: the
#: final pass's controller then has b(Ĝ, K_fb) below its ν-gap, round 0's does not.
REJECTED_AT_ROBUSTNESS = {
    "weights.integrator_shift = 1e-4\n": "weights.integrator_shift = 1e-4\nrobustness_gate = true\n",
    "grid = 3\n": "grid = 3\nscaling = { voltage = 1.0, arm_angle = 0.01, pendulum_angle = 1.0 }\n"}


def test_a_final_model_the_robustness_gate_rejects_falls_back_to_the_round_before(adip, tmp_path):
    """Judged with the arm angle 100× the voltage and the pendulum, the final pass's model (from the record
    under round 0's controller) gives a controller with b(Ĝ, K_fb) below its ν-gap: that pass is rejected,
    its stage files move to iteration_1/, and the final pass runs again on round 0's experiment — the same
    record byte for byte — whose model and controller pass the gate. The report's rounds table and the
    verdict say so; a rerun reuses every stage."""
    path = write(tmp_path, adip, **REJECTED_AT_ROBUSTNESS)
    lines: list[str] = []
    summary = run_design(path, log=lines.append)
    assert summary["failed"] is None and summary["verdict"]["pass"], summary["failed"]
    assert summary["verdict"]["reason"].endswith("; iteration 1 was rejected at robustness, the design uses "
                                                 "iteration 0's record")
    folder = tmp_path / "iterated"
    designed = str(folder / "iteration_0" / "controller.json")
    first, rejected, final = summary["iterations"]
    assert (first["iteration"], first["folder"], first["experiment_controller"]) == (0, "iteration_0",
                                                                                     str(STABILIZING))
    assert (rejected["iteration"], rejected["folder"]) == (1, "iteration_1")
    assert rejected["experiment_controller"] == designed
    assert rejected["rejected"].startswith("stage robustness failed: the controller's robust stability is "
                                           "not guaranteed")
    assert (final["iteration"], final["folder"], final["experiment_controller"], final["fallback"]) == (
        0, ".", str(STABILIZING), True)
    assert any(line.startswith("iteration 1 rejected (stage robustness failed") for line in lines)
    moved = folder / "iteration_1"
    robustness = load(moved / "robustness.json")["outputs"]
    assert robustness["gate"]["passed"] is False
    # that pass's validate stage reported the model's optimal margin: no controller's b exceeds it
    optimal = load(moved / "validate.json")["outputs"]["b_opt"]
    assert all(row["b"] <= b_opt for row, b_opt in zip(robustness["rows"], optimal, strict=True))
    assert json.loads((moved / "data.csv.json").read_text())["controller_file"]["path"] == designed
    assert (folder / "data.csv").read_bytes() == (folder / "iteration_0" / "data.csv").read_bytes()
    assert summary["stages"]["robustness"]["outputs"]["gate"]["passed"] is True
    report = (folder / "report.html").read_text()
    assert '<tr class="fail"><td>1 rejected</td>' in report and "<td>0 (final, fallback)</td>" in report
    assert "Round 1 was rejected (stage robustness failed" in html.unescape(report)
    assert json.loads((moved / "rejected.json").read_text())["stage"] == "robustness"

    # a rerun judges the rejected pass where its records are and reuses every stage of both passes
    lines.clear()
    again = run_design(path, log=lines.append)
    assert not [line for line in lines if line.endswith("…")], lines
    assert any(line.startswith("iteration 1 (rejected by an earlier run): [7/7] robustness: unchanged")
               for line in lines)
    assert again["iterations"] == summary["iterations"] and again["failed"] is None


@pytest.mark.slow
def test_a_rejected_final_pass_accepted_by_a_later_run_moves_back_and_is_the_design(adip, tmp_path):
    """After the fallback above, without the robustness gate the same pass is accepted on the next run: its
    records come back from iteration_1/ (the final pass in the design folder reuses them) and it is the
    design."""
    path = write(tmp_path, adip, **REJECTED_AT_ROBUSTNESS)
    assert run_design(path, log=lambda line: None)["iterations"][1]["rejected"]
    folder, moved = tmp_path / "iterated", tmp_path / "iterated" / "iteration_1"
    designed = str(folder / "iteration_0" / "controller.json")
    path.write_text(path.read_text().replace("robustness_gate = true", "robustness_gate = false"))
    accepted = run_design(path, log=lambda line: None)
    assert accepted["failed"] is None
    assert [r["folder"] for r in accepted["iterations"]] == ["iteration_0", "."]
    assert accepted["stages"]["experiment"]["status"] == "cached"  # the record that moved back
    assert accepted["stages"]["robustness"]["outputs"]["gate"]["passed"] is None  # reported, not a gate
    assert json.loads((folder / "data.csv.json").read_text())["controller_file"]["path"] == designed
    assert not (moved / "rejected.json").exists() and not (moved / "data.csv").exists()


def test_iterate_needs_synth_and_an_excitation(adip, tmp_path):
    no_synth = write(tmp_path, adip)
    no_synth.write_text(no_synth.read_text().split("[synth]")[0])
    with pytest.raises(DataError, match=r"iterate = 1 needs a \[synth\] table"):
        run_design(no_synth)
    open_loop = write(tmp_path, adip, **{'controller = "': 'inputs = { voltage = "const:value=0" }\n# "'})
    with pytest.raises(DataError, match="the designed controller drives voltage; give its signal as"):
        run_design(open_loop)
    assert not (tmp_path / "iterated").exists()
    with pytest.raises(DataError, match=r"\[experiment\] iterate"):
        check_table("experiment", {"duration": 1.0, "iterate": -1}, "design.toml")


def test_all_rounds_estimate_from_every_record_and_later_rounds_take_their_own_signals(adip, tmp_path):
    """``[identify] rounds = "all"`` with ``iterate_excitation``: the final round records under the designed
    controller with its own excitation (half the rms of round 0's), and its model is the least-squares
    LPV-ARX of the estimation parts of both records as one problem (rebuilt here from the two data.csv)."""
    path = write(tmp_path, adip, **{"iterate = 1\n": 'iterate = 1\niterate_excitation = { voltage = '
                                    '"multisine:f_lo=0.05,f_hi=20,rms=0.05" }\n',
                                    'p = ["sin_arm"]\n': 'p = ["sin_arm"]\nrounds = "all"\n'})
    summary = run_design(path, log=lambda line: None)
    assert summary["failed"] is None, summary["failed"]
    folder = tmp_path / "iterated"
    records = [read_columns(where / "data.csv") for where in (folder / "iteration_0", folder)]
    rms = [float(np.sqrt(np.mean(r["voltage_excitation"] ** 2))) for r in records]
    assert rms == [pytest.approx(0.1, rel=1e-3), pytest.approx(0.05, rel=1e-3)]
    parts = [Dataset.from_columns(r, "data.csv", ["voltage"], ["arm_angle", "pendulum_angle"], ["sin_arm"],
                                  time="auto").split(0.7)[0] for r in records]
    assert summary["stages"]["identify"]["outputs"]["estimation_records"] == [part.N for part in parts]
    expected = identify_arx(parts, 2, 2, 1, "affine").to_ss()
    model = load(folder / "model_full.json")
    for p in np.random.default_rng(18).uniform(model.basis.p_min, model.basis.p_max, size=(4, 1)):
        for got, want in zip(model.matrices(p), expected.matrices(p), strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_keys_of_the_rounds_need_iterate_and_an_estimator_for_several_records(adip, tmp_path):
    once = {"iterate = 1\n": "iterate = 0\n"}
    for extra, what in (('iterate_setpoint = { arm_angle = "const:value=0.1" }\n', "iterate_setpoint"),
                        ('iterate_excitation = { voltage = "const:value=0.1" }\n', "iterate_excitation")):
        with pytest.raises(DataError, match=rf"\[experiment\] {what} applies to the rounds"):
            run_design(write(tmp_path, adip, **{"iterate = 1\n": "iterate = 0\n" + extra}))
    all_rounds = {'p = ["sin_arm"]\n': 'p = ["sin_arm"]\nrounds = "all"\n'}
    with pytest.raises(DataError, match=r'\[identify\] rounds = "all" applies to the rounds'):
        run_design(write(tmp_path, adip, **once, **all_rounds))
    with pytest.raises(DataError, match="which method 'oe' does not; use \"lpr-arx\""):
        run_design(write(tmp_path, adip, **all_rounds,
                         **{'rounds = "all"\n': 'rounds = "all"\nmethod = "oe"\n'}))
    with pytest.raises(DataError, match="with remove_offsets"):
        run_design(write(tmp_path, adip, **all_rounds,
                         **{'rounds = "all"\n': 'rounds = "all"\nremove_offsets = true\n'}))
    with pytest.raises(DataError, match="is not an input of the plant FMU"):
        run_design(write(tmp_path, adip, **{"iterate = 1\n": 'iterate = 1\niterate_excitation = '
                                            '{ torque = "const:value=0.1" }\n'}))
    assert not (tmp_path / "iterated").exists()
