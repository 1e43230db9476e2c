"""The design's ``[diagnose]`` stage diagnoses the identify stage's model on its validation part, through
the path of `lpvflow diagnose` (:func:`lpvflow.pipeline.model_diagnosis.diagnose_model`): open loop on
the tanks FMU, closed loop under the maglev example's gridded controller with its trim removed, and one
line for every set-up it cannot diagnose."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import lpvflow
from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset, read_columns
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.design import run_design
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.extensions import Structure
from lpvflow.validate.metrics import bfr
from tests.design_files import tanks_head

ROOT = Path(__file__).resolve().parents[1]

#: Tanks designs drawn at random (fixed seed): experiment seed, hidden pump dead time (s), [identify] split,
#: remove_offsets.
_rng = np.random.default_rng(35)
TANKS_CASES = [(int(_rng.integers(1, 1000)), float(_rng.choice([0.0, 2.0, 3.0])),
                round(float(_rng.uniform(0.5, 0.75)), 2), offsets) for offsets in (False, True, False, True)]


@pytest.fixture(scope="module")
def fmus() -> Path:
    subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py")], check=True, capture_output=True)
    return ROOT / "fmu_plants" / "build"


def tanks_design(folder: Path, fmu: Path, seed: int, dead_time: float, split: float, offsets: bool,
                 identify: str = "", diagnose: str = "") -> Path:
    """An identification-only tanks design (1500 s) with a hidden pump dead time and a [diagnose] table;
    ``identify``/``diagnose``: extra lines of those tables."""
    text = tanks_head(fmu, folder / "out", seed=seed).replace(
        f"seed = {seed}", f"seed = {seed}\nparameters = {{ effect_input_delay = {dead_time} }}")
    path = folder / "design.toml"
    path.write_text(text + f"""na = 2
nb = 2
nk = 1
basis = "poly:2"
split = {split}
remove_offsets = {str(offsets).lower()}
{identify}
[reduce]
order = 2

[validate]
grid = 2

[diagnose]
{diagnose}
""")
    return path


@pytest.fixture(scope="module")
def tanks_runs(tmp_path_factory, fmus) -> list[tuple[tuple, Path, dict]]:
    """Each case of :data:`TANKS_CASES` run once: (case, design folder, diagnose stage outputs)."""
    runs = []
    for case in TANKS_CASES:
        folder = tmp_path_factory.mktemp("tanks")
        summary = run_design(tanks_design(folder, fmus / "tanks.fmu", *case), log=lambda _: None)
        assert summary["failed"] is None, summary["failed"]
        runs.append((case, folder / "out" / "tanks", summary["stages"]["diagnose"]["outputs"]))
    return runs


def test_the_stage_reports_the_identified_models_validation_fit(tanks_runs):
    """The nominal BFR of the stage is the identify stage's model (model_full.json) simulated over the
    record from a zero past, scored on the identify split's validation part, in the signals identify
    used (the estimation part's means removed with remove_offsets): the user's model, not a refit."""
    for (_, _, split, offsets), folder, outputs in tanks_runs:
        io = lpvflow.load(folder / "model_full.json").io
        data = Dataset.read(folder / "data.csv", ["pump_voltage"], ["lower_level"], ["level"])
        est, val = data.split(split)
        u0, y0 = (est.u.mean(axis=0), est.y.mean(axis=0)) if offsets else (0.0, 0.0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            expected = bfr(val.y - y0, io.simulate(data.u - u0, data.p)[est.N:])
        np.testing.assert_allclose(outputs["bfr_before"], expected, rtol=1e-9)
        assert outputs["model"] == "model_full.json"


def test_the_stage_and_the_cli_give_the_same_diagnosis(tanks_runs, tmp_path):
    """`lpvflow diagnose model_full.json data.csv --split S` on the design's own files: the same verdict,
    parameters, nominal and extended fits and ranking as the stage — with remove_offsets too, since the
    model records the estimation part's means it was identified about (``operating_point``)."""
    compared = 0
    for (_, dead_time, split, offsets), folder, outputs in tanks_runs:
        io = lpvflow.load(folder / "model_full.json").io
        if offsets:
            data = Dataset.read(folder / "data.csv", ["pump_voltage"], ["lower_level"], ["level"])
            est = data.split(split)[0]
            np.testing.assert_allclose(io.operating_point["y"], est.y.mean(axis=0), rtol=1e-12)
        else:
            assert io.operating_point == {}
        report = tmp_path / f"r{compared}.json"
        assert main(["diagnose", str(folder / "model_full.json"), str(folder / "data.csv"), "--split",
                     str(split), "--json", str(report)]) == 0
        _assert_same(json.loads(report.read_text()), outputs)
        if dead_time >= 2.0 and not offsets:
            assert outputs["cause"] == "input_delay" and outputs["parameters"]["nk"] == 1 + int(dead_time)
        compared += 1
    assert compared == 4


def _assert_same(cli: dict, stage: dict) -> None:
    assert cli["cause"] == stage["cause"] and cli["parameters"] == stage["parameters"]
    for key in ("bfr_before", "bfr_after"):
        np.testing.assert_allclose(cli[key], stage[key], rtol=1e-9)
    assert [r["cause"] for r in cli["ranking"]] == [r["cause"] for r in stage["ranking"]]
    np.testing.assert_allclose([r["bfr_gain"] for r in cli["ranking"]],
                               [r["bfr_gain"] for r in stage["ranking"]], rtol=1e-9, atol=1e-9)


# ------------------------------------------------------------------------------- closed loop (maglev)
def maglev_design(folder: Path, duration: float = 4.0) -> Path:
    """The maglev example's identification (gridded controller with its trim u*(y2), remove_trim,
    remove_offsets, poly:2, split 0.7) over ``duration`` seconds (one set-point sweep), a [diagnose]
    table with the excitation of the lower coil as a candidate."""
    text = (ROOT / "lpvflow" / "pipeline" / "examples" / "maglev.toml").read_text()
    head = text[: text.index("[reduce]")].replace("duration = 80.0", f"duration = {duration}")
    head = head.replace("period=40", f"period={duration}").replace('"fmu_plants/', f'"{ROOT}/fmu_plants/')
    head = head.replace('name = "maglev"', f'name = "maglev"\noutput_dir = "{folder / "out"}"')
    assert "remove_trim = true" in head and "gridded" in (ROOT / "fmu_plants" / "maglev" /
                                                          "scheduled_controller.json").read_text()
    path = folder / "design.toml"
    path.write_text(head + '[reduce]\n\n[validate]\ngrid = 2\n\n[diagnose]\n'
                           'candidates = ["lower_coil_current_excitation"]\n')
    return path


MAGLEV_U = ["lower_coil_current", "upper_coil_current"]
MAGLEV_Y = ["lower_disk_position", "upper_disk_position"]


def test_the_stage_diagnoses_in_a_gridded_loop_with_the_trim_and_offsets_removed(tmp_path, fmus):
    """The maglev example's set-up (gridded controller, remove_trim, remove_offsets): the stage runs and
    its nominal fit is the identified model's in the loop, scored as diagnose() scores it on the record
    made by hand in identify's signals (currents minus the trim u*(y2(k)), less the estimation part's
    means)."""
    summary = run_design(maglev_design(tmp_path), log=lambda _: None)
    assert summary["failed"] is None, summary["failed"]
    outputs = summary["stages"]["diagnose"]["outputs"]
    assert min(outputs["bfr_before"]) > 80.0
    folder = tmp_path / "out" / "maglev"
    c = read_columns(folder / "data.csv")
    K = load_experiment_controller(ROOT / "fmu_plants" / "maglev" / "scheduled_controller.json")
    n = len(c["time"])
    data = Dataset(np.column_stack([c[name] for name in MAGLEV_U]) - K.trim_along(c, n),
                   np.column_stack([c[name] for name in MAGLEV_Y]), c["y2"], 0.002, MAGLEV_U, MAGLEV_Y,
                   ["y2"])
    est = data.split(0.7)[0]
    u0, y0 = est.u.mean(axis=0), est.y.mean(axis=0)
    data = replace(data, u=data.u - u0, y=data.y - y0, offsets={"u": u0.tolist(), "y": y0.tolist()})
    io = lpvflow.load(folder / "model_full.json").io
    setpoints = np.column_stack([np.full(n, np.nan), c["upper_disk_position_setpoint"]])
    direct = diagnose(data, Structure.of_model(io), split=0.7, causes=["offset"], controller=K,
                      scheduling={"y2": "upper_disk_position"}, model=io, setpoints=setpoints,
                      remove_trim=True)
    np.testing.assert_allclose(outputs["bfr_before"], direct.bfr_before, rtol=1e-9)


def test_the_stage_and_the_cli_agree_in_an_lti_loop(tmp_path, fmus):
    """Closed loop without trim or offsets (the ADIP under its LTI stabilizing controller, 10 s of
    multisine excitation, the arm angle's sine as scheduling): `lpvflow diagnose --controller` on the
    design's files (scheduling from the experiment's sidecar) gives the stage's diagnosis."""
    controller = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"
    path = tmp_path / "design.toml"
    path.write_text(f"""
[design]
name = "adip"
plant = "{fmus / 'adip.fmu'}"
output_dir = "{tmp_path / 'out'}"

[experiment]
Ts = 0.005
duration = 10.0
controller = "{controller}"
excitation = {{ voltage = "multisine:f_lo=0.1,f_hi=5,rms=0.5" }}
scheduling = {{ sin_arm = "sin(arm_angle)" }}
noise = {{ arm_angle = 2e-5, pendulum_angle = 2e-5 }}
seed = 1
""" + """
[identify]
u = ["voltage"]
y = ["arm_angle", "pendulum_angle"]
p = ["sin_arm"]
split = 0.7

[reduce]

[validate]
grid = 2

[diagnose]
candidates = ["voltage_excitation"]
""")
    summary = run_design(path, log=lambda _: None)
    assert summary["failed"] is None, summary["failed"]
    folder = tmp_path / "out" / "adip"
    report = tmp_path / "r.json"
    assert main(["diagnose", str(folder / "model_full.json"), str(folder / "data.csv"), "--split", "0.7",
                 "--controller", str(controller), "--candidates", "voltage_excitation",
                 "--json", str(report)]) == 0
    _assert_same(json.loads(report.read_text()), summary["stages"]["diagnose"]["outputs"])


# ------------------------------------------------------------------------------------------ refusals
@pytest.mark.parametrize("identify, message", [
    ('increments = ["lower_level"]', "[diagnose] cannot diagnose a model identified through [identify] "
                                     "increments"),
    ('method = "pbsid"\norder = 2', "[diagnose] needs an input-output model; [identify] method = 'pbsid'"),
])
def test_what_the_stage_cannot_diagnose_is_one_line_naming_the_key(tmp_path, fmus, identify, message):
    summary = run_design(tanks_design(tmp_path, fmus / "tanks.fmu", 3, 0.0, 0.6, False, identify),
                         log=lambda _: None)
    assert summary["failed"]["stage"] == "diagnose"
    error = summary["failed"]["error"]
    assert message in error and "\n" not in error


def test_a_record_too_short_to_validate_on_is_refused(tmp_path, fmus):
    """600 s at split 0.7 leave 180 validation samples, fewer than a diagnosis needs."""
    path = tanks_design(tmp_path, fmus / "tanks.fmu", 3, 0.0, 0.7, False)
    path.write_text(path.read_text().replace("duration = 1500.0", "duration = 600.0"))
    summary = run_design(path, log=lambda _: None)
    assert summary["failed"]["stage"] == "diagnose"
    assert "fewer than 200 for validation at split 0.7" in summary["failed"]["error"]


def test_the_diagnose_split_key_is_gone(tmp_path, fmus, capsys):
    """The diagnosis validates on the identified model's own split: [diagnose] split is an unknown key."""
    path = tanks_design(tmp_path, fmus / "tanks.fmu", 3, 0.0, 0.6, False, diagnose="split = 0.5")
    assert main(["design", str(path)]) == 2
    err = capsys.readouterr().err
    assert "[diagnose] has unknown key(s) ['split']" in err and err.count("\n") == 1


def test_cli_remove_trim_without_a_controller_is_one_line(tmp_path, fmus, capsys):
    summary = run_design(tanks_design(tmp_path, fmus / "tanks.fmu", 3, 0.0, 0.6, False), log=lambda _: None)
    assert summary["failed"] is None
    folder = tmp_path / "out" / "tanks"
    report = tmp_path / "r.json"
    assert main(["diagnose", str(folder / "model_full.json"), str(folder / "data.csv"), "--remove-trim",
                 "--json", str(report)]) == 2
    err = capsys.readouterr().err
    assert "remove_trim" in err and "--controller" in err and err.count("\n") == 1
    assert not report.exists()
