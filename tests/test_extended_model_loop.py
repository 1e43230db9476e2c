"""Extended models of closed-loop diagnoses run in the loop they were scored in: `lpvflow simulate
EXTENDED DATA --controller C` on the file `lpvflow diagnose DATA --controller C` saves reproduces the
diagnosed validation BFR for every cause such a diagnosis names on FMU records (ADIP under its LTI
controller; maglev under its gridded controller with the trim and the means removed), and the loop is
required exactly for those models."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lpvflow.errors import ModelError
from lpvflow.experiment.controller import load_controller
from lpvflow.experiment.fmu_experiment import run_fmu_experiment
from lpvflow.models import load
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.design import run_design
from lpvflow.validate.extended_model import ExtendedModel, ModelMap, controller_fingerprint
from tests.diagnosis_fmu_cases import (
    ADIP_CONTROLLER,
    ADIP_SCHEDULING,
    BUILD,
    MAGLEV_CONTROLLER,
    MAGLEV_SCHEDULING,
)

ADIP_COLUMNS = ["--u", "voltage", "--y", "arm_angle", "pendulum_angle", "--p", "sin_arm"]
MAGLEV_INPUTS = ["lower_coil_current", "upper_coil_current"]
MAGLEV_OUTPUTS = ["lower_disk_position", "upper_disk_position"]
MAGLEV_COLUMNS = ["--u", *MAGLEV_INPUTS, "--y", *MAGLEV_OUTPUTS, "--p", "y2"]
MAGLEV_START = {"x0_lower_disk_position": 0.015, "x0_upper_disk_position": 0.08}
ADIP_EXCITATION = "multisine:f_lo=0.05,f_hi=20,rms=1.5,period=10,phases=random"
MAGLEV_EXCITATION = "multisine:f_lo=0.5,f_hi=20,rms=0.02,phases=random"

#: Case → (plant, FMU effect parameters, record length [s], causes tried, cause named, kind of the saved
#: map or None). Friction is found in the closed-loop noise round (the extension refitted by closed-loop
#: IV, its map kept), so output_noise_bias is tried with it.
CASES = {
    "adip friction": ("adip", {"effect_coulomb": 0.04}, 20.0, ["friction", "output_noise_bias"], "friction",
                      "friction"),
    "adip dead zone": ("adip", {"effect_deadzone": 0.8}, 20.0, ["input_nonlinearity"], "input_nonlinearity",
                       "dead_zone"),
    "adip sensor offset": ("adip", {"effect_sensor_offset": 0.01}, 10.0, ["offset"], "offset",
                           "sensor_offset"),
    "adip dead time": ("adip", {"effect_input_delay": 0.015}, 10.0, ["input_delay"], "input_delay", None),
    "maglev dead time": ("maglev", {"effect_input_delay": 0.006}, 10.0, ["input_delay"], "input_delay", None),
    "adip model order": ("adip", {}, 10.0, ["model_order"], "model_order", None),
}
#: Orders na = nb diagnosed (2 unless stated): first order is short for the ADIP's two angles.
ORDERS = {"adip model order": "1"}
#: Experiment seeds, drawn once at random (fixed seed).
SEEDS = dict(zip(CASES, np.random.default_rng(35).integers(1, 1000, len(CASES)).tolist(), strict=True))


def record(folder: Path, plant: str, parameters: dict, duration: float, seed: int) -> Path:
    """An experiment CSV (with its sidecar): the ADIP under its stabilizing LTI controller (multisine on
    the voltage), or the maglev under its gridded controller (upper set-point a triangle, multisines on
    both coils); realistic white sensor noise."""
    csv = folder / f"{plant}.csv"
    if plant == "adip":
        run_fmu_experiment(BUILD / "adip.fmu", 0.005, duration, controller=str(ADIP_CONTROLLER), seed=seed,
                           output=csv, parameters=parameters, scheduling_columns=ADIP_SCHEDULING,
                           excitation={"voltage": ADIP_EXCITATION},
                           noise={"arm_angle": 2e-5, "pendulum_angle": 2e-5}, progress=False)
        return csv
    run_fmu_experiment(BUILD / "maglev.fmu", 0.002, duration, controller=str(MAGLEV_CONTROLLER), seed=seed,
                       output=csv, scheduling_columns=MAGLEV_SCHEDULING, progress=False,
                       parameters=MAGLEV_START | parameters,
                       excitation={name: MAGLEV_EXCITATION for name in MAGLEV_INPUTS},
                       setpoint={"upper_disk_position": f"triangle:amp=0.0075,period={duration},offset=0.08"},
                       noise={n: 2e-6 for n in MAGLEV_OUTPUTS})
    return csv


def diagnose(folder: Path, case: str) -> tuple[Path, dict, list[str], Path]:
    """`lpvflow diagnose --controller` on the case's record: (record, report, data columns, controller);
    the maglev as its example identifies it (poly:2, trim and means removed)."""
    plant, parameters, duration, causes, _, _ = CASES[case]
    csv = record(folder, plant, parameters, duration, SEEDS[case])
    columns, controller = ((ADIP_COLUMNS, ADIP_CONTROLLER) if plant == "adip"
                           else (MAGLEV_COLUMNS, MAGLEV_CONTROLLER))
    options = [] if plant == "adip" else ["--basis", "poly:2", "--remove-trim", "--remove-offsets"]
    report = folder / "diagnosis.json"
    order = ORDERS.get(case, "2")
    assert main(["diagnose", str(csv), *columns, "--na", order, "--nb", order, "--nk", "1", *options,
                 "--controller", str(controller), "--causes", *causes, "--json", str(report)]) == 0
    return csv, json.loads(report.read_text()), columns, controller


@pytest.mark.parametrize("case", sorted(CASES))
def test_simulate_in_the_loop_reproduces_the_diagnosed_bfr(tmp_path, case):
    _, _, _, _, cause, kind = CASES[case]
    csv, report, columns, controller = diagnose(tmp_path, case)
    assert report["cause"] == cause, report["summary"]
    assert np.mean(report["bfr_after"]) > np.mean(report["bfr_before"]) + 1  # the extension mattered
    extended = load(report["extended_model"])
    assert extended.simulation == "closed loop" and (extended.map.kind if extended.map else None) == kind
    assert extended.loop_scheduling == report["loop_scheduling"]
    simulated = tmp_path / "simulation.json"
    assert main(["simulate", report["extended_model"], str(csv), *columns, "--controller", str(controller),
                 "--json", str(simulated)]) == 0
    validation = json.loads(simulated.read_text())["validation"]
    assert validation["start"] == extended.validation_start
    np.testing.assert_allclose(validation["bfr"], report["bfr_after"], atol=0.1)


def test_the_loop_is_what_reproduces_it(tmp_path):
    """The same saved ADIP model simulated open loop (its record claiming so) misses the diagnosed fit:
    the ADIP is unstable, only its loop simulation follows the record."""
    csv, report, columns, _ = diagnose(tmp_path, "adip dead time")
    extended = load(report["extended_model"])
    open_loop = tmp_path / "open.json"
    replace(extended, simulation="open loop", loop_scheduling={}).save(open_loop)
    simulated = tmp_path / "simulation.json"
    assert main(["simulate", str(open_loop), str(csv), *columns, "--json", str(simulated)]) == 0
    validation = json.loads(simulated.read_text())["validation"]
    assert max(abs(np.array(validation["bfr"]) - report["bfr_after"])) > 5


def _refused(capsys, arguments: list[str], out: Path, *phrases: str) -> None:
    capsys.readouterr()
    assert main([*arguments, "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(phrase in err for phrase in phrases), err
    assert not out.exists()


def test_the_controller_is_required_exactly_for_a_closed_loop_model(tmp_path, capsys):
    csv, report, columns, controller = diagnose(tmp_path, "adip sensor offset")
    out = tmp_path / "refused.json"
    _refused(capsys, ["simulate", report["extended_model"], str(csv), *columns], out,
             "diagnosed in the loop", "--controller")
    extended = load(report["extended_model"])
    open_loop = tmp_path / "open.json"
    replace(extended, simulation="open loop", loop_scheduling={}).save(open_loop)
    _refused(capsys, ["simulate", str(open_loop), str(csv), *columns, "--controller", str(controller)], out,
             "open loop", "drop --controller")
    other = tmp_path / "other_controller.json"  # the same law but one gain 0.1 % larger
    document = json.loads(Path(controller).read_text())
    document["C"][0][0] *= 1.001
    other.write_text(json.dumps(document))
    _refused(capsys, ["simulate", report["extended_model"], str(csv), *columns, "--controller", str(other)],
             out, "diagnosed in the loop of controller", "pass the controller file diagnose took")
    same = tmp_path / "same_controller.json"  # the same law written again (indented): accepted
    same.write_text(json.dumps(json.loads(Path(controller).read_text()), indent=4))
    assert main(["simulate", report["extended_model"], str(csv), *columns, "--controller", str(same),
                 "--json", str(out)]) == 0
    out.unlink()
    model = tmp_path / "model.json"
    main(["identify", str(csv), *columns, "-o", str(model)])
    _refused(capsys, ["simulate", str(model), str(csv), *columns, "--controller", str(controller)], out,
             "identified model", "drop --controller")


def test_a_closed_loop_file_without_its_loop_is_refused(tmp_path):
    _, report, _, _ = diagnose(tmp_path, "adip dead time")
    document = json.loads(Path(report["extended_model"]).read_text())
    assert document["loop"] == {"scheduling": ADIP_SCHEDULING, "remove_trim": False,
                                "controller": controller_fingerprint(load_controller(ADIP_CONTROLLER))}
    older = tmp_path / "older.json"
    older.write_text(json.dumps(document | {"loop": None}))
    with pytest.raises(ModelError, match="does not record the loop"):
        load(older)
    assert isinstance(load(report["extended_model"]), ExtendedModel)


def test_simulate_help_names_the_controller_option(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--controller CONTROLLER.json" in text and "closed-loop diagnosis" in text


def test_the_design_stage_saves_the_file_simulate_runs_in_its_loop(tmp_path):
    """A short ADIP design with a hidden 15 ms dead time and a [diagnose] table: the stage saves the
    extended model as `lpvflow diagnose` does (diagnosis.extended.json, its loop recorded), and `lpvflow
    simulate --controller` on the design's record reproduces the stage's validation BFR."""
    seed = int(np.random.default_rng(351).integers(1, 1000))
    path = tmp_path / "design.toml"
    path.write_text(f"""
[design]
name = "adip"
plant = "{BUILD / 'adip.fmu'}"
output_dir = "{tmp_path / 'out'}"

[experiment]
Ts = 0.005
duration = 10.0
controller = "{ADIP_CONTROLLER}"
excitation = {{ voltage = "{ADIP_EXCITATION}" }}
scheduling = {{ sin_arm = "sin(arm_angle)" }}
noise = {{ arm_angle = 2e-5, pendulum_angle = 2e-5 }}
parameters = {{ effect_input_delay = 0.015 }}
seed = {seed}
""" + """
[identify]
u = ["voltage"]
y = ["arm_angle", "pendulum_angle"]
p = ["sin_arm"]
split = 0.5

[reduce]

[validate]
grid = 2

[diagnose]
""")
    summary = run_design(path, log=lambda _: None)
    assert summary["failed"] is None, summary["failed"]
    outputs = summary["stages"]["diagnose"]["outputs"]
    assert outputs["cause"] == "input_delay", outputs["summary"]
    folder = tmp_path / "out" / "adip"
    extended = load(folder / outputs["extended_model"])
    assert extended.loop_scheduling == ADIP_SCHEDULING and not extended.remove_trim
    simulated = tmp_path / "simulation.json"
    assert main(["simulate", str(folder / outputs["extended_model"]), str(folder / "data.csv"), *ADIP_COLUMNS,
                 "--controller", str(ADIP_CONTROLLER), "--json", str(simulated)]) == 0
    np.testing.assert_allclose(json.loads(simulated.read_text())["validation"]["bfr"], outputs["bfr_after"],
                               atol=0.1)


@pytest.mark.parametrize("model_map", [ModelMap("backlash", "u", {"level": 0.2}),
                                       ModelMap("sensor_offset", "y", {"offset": 0.1}),
                                       ModelMap("sensor_clip", "y", {"lower": None, "upper": 1.0}),
                                       ModelMap("friction", "y", {"motion": "velocity"})])
def test_a_map_the_loop_does_not_apply_is_one_line(model_map):
    with pytest.raises(ModelError, match=f"the {model_map.kind} map is not simulated in the identification"):
        model_map.loop_drive(np.zeros((10, 1)), ["u"], ["y"])
