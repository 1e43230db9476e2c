"""`lpvflow diagnose MODEL DATA`, its --help, and `identify --remove-offsets / --controller`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.models import load
from lpvflow.pipeline.cli import main
from lpvflow.validate.extensions import CAUSES, simulate_validation
from lpvflow.validate.metrics import bfr
from tests.diagnosis_cases import make_case
from tests.diagnosis_fmu_cases import ADIP_CONTROLLER, ADIP_SCHEDULING, BUILD


def _csv(path, data: Dataset, offset_u: float = 0.0, offset_y: float = 0.0) -> None:
    columns = np.column_stack([np.arange(data.N) * data.Ts, data.u[:, 0] + offset_u, data.y[:, 0] + offset_y,
                               data.p[:, 0]])
    np.savetxt(path, columns, delimiter=",", header="time,u,y,p", comments="")


def test_help_lists_every_verdict_with_its_meaning(capsys):
    with pytest.raises(SystemExit):
        main(["diagnose", "--help"])
    listed = capsys.readouterr().out.split("verdicts:")[1]
    for cause in CAUSES:
        assert f"\n  {cause} " in listed, cause


def test_diagnose_starts_from_the_users_model(tmp_path, capsys):
    """identify (lpr-arx, nk = 1) on a record whose plant has a 3-sample dead time, then
    `diagnose MODEL DATA`: the structure and columns come from the model, the reported nominal BFR is
    the user's model simulated over the record (validation part), and the cause is the dead time."""
    data, _, _ = make_case("input_delay", 1000)
    csv, model_file, report_file = tmp_path / "d.csv", tmp_path / "m.json", tmp_path / "r.json"
    _csv(csv, data)
    assert main(["identify", str(csv), "--u", "u", "--y", "y", "--p", "p", "--na", "2", "--nb", "2",
                 "--nk", "1", "-o", str(model_file)]) in (0, 1)
    assert main(["diagnose", str(model_file), str(csv), "--json", str(report_file)]) == 0
    report = json.loads(report_file.read_text())
    assert report["cause"] == "input_delay" and report["parameters"]["nk"] == 3
    user = load(model_file).io
    est, val = data.split(0.5)
    expected = bfr(val.y, simulate_validation(user, est, val))
    np.testing.assert_allclose(report["bfr_before"], expected, atol=1e-9)
    assert "cause: input_delay" in capsys.readouterr().out


def test_structure_options_with_a_model_are_refused(tmp_path, capsys):
    data, _, _ = make_case("none", 1000)
    csv, model_file = tmp_path / "d.csv", tmp_path / "m.json"
    _csv(csv, data)
    main(["identify", str(csv), "--u", "u", "--y", "y", "--p", "p", "-o", str(model_file)])
    capsys.readouterr()
    assert main(["diagnose", str(model_file), str(csv), "--na", "3", "--json", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "--na" in err and "comes from the model" in err and len(err.strip().splitlines()) == 1


def test_remove_offsets_on_identify_and_diagnose(tmp_path):
    """Inputs and outputs far from zero (u + 50, y + 300): the affine model without a constant cannot
    follow them; with --remove-offsets on both commands the diagnosis sees the deviations and finds
    the same dead time as on the centred record."""
    data, _, _ = make_case("input_delay", 1001)
    csv, model_file, report_file = tmp_path / "d.csv", tmp_path / "m.json", tmp_path / "r.json"
    _csv(csv, data, offset_u=50.0, offset_y=300.0)
    main(["identify", str(csv), "--u", "u", "--y", "y", "--p", "p", "--remove-offsets",
          "-o", str(model_file)])
    assert main(["diagnose", str(model_file), str(csv), "--remove-offsets", "--json", str(report_file)]) == 0
    report = json.loads(report_file.read_text())
    assert report["cause"] == "input_delay" and report["parameters"]["nk"] == 3


@pytest.fixture(scope="module")
def adip_csv(tmp_path_factory):
    from lpvflow.experiment.fmu_experiment import run_fmu_experiment

    csv = tmp_path_factory.mktemp("adip") / "adip.csv"
    run_fmu_experiment(BUILD / "adip.fmu", 0.005, 20.0, controller=str(ADIP_CONTROLLER), seed=1, output=csv,
                       excitation={"voltage": "multisine:f_lo=0.05,f_hi=20,rms=1.5,period=10,phases=random"},
                       scheduling_columns=ADIP_SCHEDULING, progress=False)
    return csv


def test_identify_checks_a_closed_loop_fit_in_the_loop(adip_csv, tmp_path, capsys):
    """The unstable ADIP recorded under its stabilizing controller: the open-loop simulation of the
    identified model is useless (exit 1, warning), the same model simulated in the loop with
    --controller follows the record (exit 0, BFR above 80 % on both angles)."""
    args = ["identify", str(adip_csv), "--u", "voltage", "--y", "arm_angle", "pendulum_angle",
            "--p", "sin_arm", "--na", "2", "--nb", "2", "--nk", "1"]
    assert main([*args, "-o", str(tmp_path / "open.json")]) == 1
    assert "warning" in capsys.readouterr().err
    assert main([*args, "--controller", str(ADIP_CONTROLLER), "-o", str(tmp_path / "loop.json")]) == 0
    line = capsys.readouterr().out
    bfrs = [float(part.split()[1]) for part in line.split("BFR ")[1].split(";")[0].split(", ")]
    assert len(bfrs) == 2 and min(bfrs) > 80, line


def test_readme_diagnosis_example_prints_the_dead_time(monkeypatch):
    """The README's worked example (section "Diagnosis"), run verbatim from the repository root."""
    from tests.readme_blocks import README, run_python_block

    monkeypatch.chdir(README.parent)
    lines = run_python_block("## Diagnosis").splitlines()
    assert lines[0] == "input_delay 4"
    assert lines[1] == "validation BFR 89.0 % -> 97.9 %"
