"""``[experiment] iterate = N`` (issue 24, item 1): identification for control — after synth the experiment
is run again under the controller just designed, re-identified, validated against b(P, K) of that
controller and re-designed; per-round numbers and stage times in summary.json."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lpvflow.errors import DataError
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
