"""Experiments on the real FMU plants (fmu_plants/build/*.fmu), through the Python API and the CLI."""

import csv
import hashlib
import json
import re
from pathlib import Path

import control
import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment import run_fmu_experiment
from lpvflow.pipeline.cli import main
from tests.fmu_builds import built_fmu

ROOT = Path(__file__).resolve().parents[1]
ADIP_CONTROLLER = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"
TANKS_INPUT = "pump_voltage=aprbs:lo=2,hi=8,min_hold=10,max_hold=60"


@pytest.fixture(scope="module")
def tanks() -> Path:
    return built_fmu("tanks")


@pytest.fixture(scope="module")
def adip() -> Path:
    return built_fmu("adip")


def _cli(capsys, *argv) -> tuple[int, str, str]:
    status = main(["experiment", *map(str, argv)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_open_loop_tanks_is_deterministic_by_seed(tanks, tmp_path, capsys):
    common = [tanks, "--Ts", 0.2, "--duration", 300, "--input", TANKS_INPUT,
              "--set", "effect_noise_std=0.002", "--set", "effect_noise_seed=9"]
    outputs = {}
    for label, seed in (("a", 1), ("b", 1), ("c", 2)):
        status, out, err = _cli(capsys, *common, "--seed", seed, "-o", tmp_path / f"{label}.csv")
        assert (status, err) == (0, ""), err
        assert f"{label}.csv" in out
        outputs[label] = (tmp_path / f"{label}.csv").read_bytes()
    assert outputs["a"] == outputs["b"]
    assert outputs["a"] != outputs["c"]
    table = np.loadtxt(tmp_path / "a.csv", delimiter=",", skiprows=1)
    assert table.shape == (1500, 4)
    assert np.ptp(table[:, 2]) > 0.01  # the level moves with the pump voltage


def test_parameters_reach_the_fmu_and_are_recorded(tanks, tmp_path):
    kw = {"Ts": 0.2, "duration": 60, "inputs": {"pump_voltage": "const:value=5"}}
    plain = run_fmu_experiment(tanks, **kw)
    shifted = run_fmu_experiment(tanks, **kw, parameters={"effect_sensor_offset": 0.01},
                                 output=tmp_path / "shifted.csv")
    np.testing.assert_allclose(shifted.columns["lower_level"] - plain.columns["lower_level"], 0.01, rtol=1e-9)
    meta = json.loads((tmp_path / "shifted.csv.json").read_text())
    assert meta["parameters_set"] == {"effect_sensor_offset": 0.01}
    assert meta["effects"]["effect_sensor_offset"] == 0.01
    assert meta["effects"]["effect_noise_std"] == 0.0 and meta["effects"]["effect_noise_seed"] == 0
    assert meta["fmu"]["sha256"] == hashlib.sha256(tanks.read_bytes()).hexdigest()
    assert meta["inputs"]["pump_voltage"]["text"] == "const:value=5"
    assert meta["mode"] == "open-loop" and meta["Ts"] == 0.2 and meta["n_samples"] == 300


def test_closed_loop_adip_stays_bounded_and_round_trips(adip, tmp_path, capsys):
    out = tmp_path / "adip.csv"
    status, _, err = _cli(capsys, adip, "--duration", 30, "--controller", ADIP_CONTROLLER,
                          "--excitation", "voltage=multisine:f_lo=0.1,f_hi=5,rms=0.5",
                          "--set", "effect_noise_std=0.0005", "--seed", 3, "-o", out)
    assert (status, err) == (0, ""), err
    with out.open(newline="") as stream:
        rows = list(csv.reader(stream))
    assert rows[0] == ["time", "voltage", "arm_angle", "pendulum_angle", "voltage_excitation", "sin_arm"]
    table = np.array(rows[1:], dtype=float)
    controller = json.loads(ADIP_CONTROLLER.read_text())
    assert table.shape == (round(30 / controller["Ts"]), 6)
    time, voltage, arm, pendulum, excitation, sin_arm = table.T
    np.testing.assert_allclose(np.diff(time), controller["Ts"], rtol=1e-9)
    assert np.sqrt(np.mean(excitation**2)) == pytest.approx(0.5, rel=1e-9)
    # bounded: the upright pendulum stays near the top and the arm within a small angle
    assert np.max(np.abs(pendulum)) < 0.2 and np.max(np.abs(arm)) < 0.5
    assert np.max(np.abs(pendulum[-1000:])) > 1e-3  # and it is excited, not at rest
    np.testing.assert_allclose(sin_arm, np.sin(arm), rtol=1e-12)
    assert np.std(voltage - excitation) > 0.01  # the controller acts on top of the excitation
    meta = json.loads((tmp_path / "adip.csv.json").read_text())
    assert meta["mode"] == "closed-loop" and meta["seed"] == 3
    assert meta["controller_file"]["sha256"] == hashlib.sha256(ADIP_CONTROLLER.read_bytes()).hexdigest()
    assert meta["controller"]["outputs"] == ["voltage"]
    assert meta["effects"]["effect_noise_std"] == 0.0005
    assert meta["scheduling"] == {"sin_arm": "sin(arm_angle)"}
    data = Dataset.read(out, u=["voltage"], y=["arm_angle", "pendulum_angle"], p=["sin_arm"])
    assert data.Ts == pytest.approx(controller["Ts"]) and data.N == len(table)


def test_arm_setpoint_levels_widen_the_adip_identification_range(adip, tmp_path, capsys):
    """The bundled identification controller with arm set-points (levels within ±0.6 rad) next to its
    excitation: the recorded arm range grows from about ±21° to beyond ±45° (60 s, seed 1, 1 V rms) with
    the pendulum up, and the CLI writes the set-point column."""
    common = {"controller": ADIP_CONTROLLER, "excitation": {"voltage": "multisine:f_lo=0.02,f_hi=20,rms=1.0"},
              "seed": 1, "progress": False}
    plain = run_fmu_experiment(adip, 0.005, 60.0, **common)
    moved = run_fmu_experiment(adip, 0.005, 60.0, **common,
                               setpoint={"arm_angle": "levels:lo=-0.6,hi=0.6,min_hold=3,max_hold=6,ramp=1"})
    reach_plain, reach_moved = (np.rad2deg(np.abs(r.columns["arm_angle"]).max()) for r in (plain, moved))
    assert reach_plain < 25 and reach_moved > 45
    assert np.rad2deg(np.abs(moved.columns["pendulum_angle"]).max()) < 25
    out = tmp_path / "moved.csv"
    status, _, err = _cli(capsys, adip, "--duration", 5, "--controller", ADIP_CONTROLLER, "--setpoint",
                          "arm_angle=levels:lo=-0.3,hi=0.3,min_hold=1,max_hold=2,ramp=0.5", "-o", out)
    assert (status, err) == (0, ""), err
    header = out.read_text().splitlines()[0].split(",")
    assert header == ["time", "voltage", "arm_angle", "pendulum_angle", "voltage_excitation",
                      "arm_angle_setpoint", "sin_arm"]


def test_diagnostics_and_fmu_scheduling_output_on_request(tanks):
    rec = run_fmu_experiment(tanks, 0.2, 20, inputs={"pump_voltage": "const:value=6"},
                             scheduling_columns={"h2": "diag_scheduling"}, record_diagnostics=True)
    assert "diag_state_upper_level" in rec.columns
    np.testing.assert_array_equal(rec.columns["h2"], rec.columns["diag_state_lower_level"])


PRBS = "prbs:order=5,clock=0.3,amp=1"  # clock not a multiple of Ts = 0.2 s
BAD_INPUT = [
    # (Python API keyword arguments, the same as CLI arguments, error type, message fragment)
    ({"fmu": "missing.fmu"}, ["missing.fmu"], DataError, "FMU file not found"),
    ({"inputs": {"throttle": "const:value=1"}}, ["--input", "throttle=const:value=1"],
     ModelError, "'throttle' not in FMU"),
    ({"Ts": 0.0}, ["--Ts", "0"], DataError, "Ts=0.0 must be a positive"),
    ({"Ts": -0.1}, ["--Ts", "-0.1"], DataError, "must be a positive"),
    ({"parameters": {"effect_noise_std": -1}}, ["--set", "effect_noise_std=-1"],
     DataError, "out of range"),
    ({"parameters": {"effect_input_delay": 100}}, ["--set", "effect_input_delay=100"],
     DataError, "out of range"),
    ({"parameters": {"effect_noise_seed": 1.5}}, ["--set", "effect_noise_seed=1.5"],
     DataError, "must be an integer"),
    ({"parameters": {"warp_factor": 9}}, ["--set", "warp_factor=9"], DataError, "unknown parameter"),
    ({"inputs": {"pump_voltage": "multisine:f_lo=1"}}, ["--input", "pump_voltage=multisine:f_lo=1"],
     DataError, "needs f_hi"),
    ({"inputs": {"pump_voltage": PRBS}}, ["--input", f"pump_voltage={PRBS}"], DataError, "multiple of Ts"),
    ({"scheduling_columns": {"p": "open('x')"}}, ["--scheduling", "p=open('x')"], DataError, "not allowed"),
    ({"Ts": None, "excitation": {"pump_voltage": "const:value=1"}},
     ["--excitation", "pump_voltage=const:value=1"], DataError, "give a controller (or use --input"),
    ({"controller": "missing.json"}, ["--controller", "missing.json"], ModelError, "does not exist"),
]


@pytest.mark.parametrize(("kwargs", "argv", "error", "message"), BAD_INPUT)
def test_bad_input_gives_one_line_via_api_and_cli(kwargs, argv, error, message, tanks, tmp_path, capsys):
    out = tmp_path / "data.csv"
    api = {"fmu": tanks, "Ts": 0.2, "duration": 10, "output": out} | kwargs
    with pytest.raises(error, match=re.escape(message)) as info:
        run_fmu_experiment(**api)
    assert "\n" not in str(info.value)
    fmu = argv[0] if argv[0].endswith(".fmu") else tanks
    options = argv[1:] if argv[0].endswith(".fmu") else argv
    if "Ts" not in kwargs:
        options = [*options, "--Ts", "0.2"]
    status, stdout, err = _cli(capsys, fmu, *options, "--duration", "10", "-o", out)
    assert status == 2 and stdout == ""
    assert err.count("\n") == 1 and message in err, err
    assert not out.exists() and not (tmp_path / "data.csv.json").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--input", "pump_voltage"], "must read NAME=VALUE"),
        (["--set", "effect_noise_std=abc"], "not a number"),
        (["--set", "effect_noise_std=nan"], "must be finite"),
        (["--input", "pump_voltage=const:value=1", "--input", "pump_voltage=const:value=2"], "given twice"),
        (["--scheduling", "sin(arm_angle)"], "NAME=EXPRESSION"),
    ],
)
def test_malformed_cli_options_give_one_line(argv, message, tanks, tmp_path, capsys):
    out = tmp_path / "d.csv"
    status, stdout, err = _cli(capsys, tanks, "--Ts", "0.2", "--duration", "10", *argv, "-o", out)
    assert status == 2 and stdout == "" and err.count("\n") == 1 and message in err, err


def test_a_loop_that_loses_the_pendulum_is_named_as_diverged_not_written(adip, tmp_path, capsys):
    # 2.5 V rms on top of the regulator throws the pendulum over (1.5 V rms keeps it up); the arm then
    # spins up without bound. The line names the state and the likely cause, not the solver first.
    out = tmp_path / "lost.csv"
    status, _, err = _cli(capsys, adip, "--duration", 10, "--controller", ADIP_CONTROLLER, "--excitation",
                          "voltage=multisine:f_lo=0.02,f_hi=20,rms=2.5", "--seed", 1, "-o", out)
    assert status == 2 and not out.exists()
    assert len(err.strip().splitlines()) == 1
    assert re.search(r"diag_state_\w+ became non-finite: the simulated plant diverged \(an unstable", err)


def test_output_never_overwrites_the_fmu_or_controller(adip, tmp_path, capsys):
    fmu_copy = tmp_path / "adip.fmu"
    fmu_copy.write_bytes(adip.read_bytes())
    controller_copy = tmp_path / "k.json"
    controller_copy.write_text(ADIP_CONTROLLER.read_text())
    before = (fmu_copy.read_bytes(), controller_copy.read_bytes())
    for target in (fmu_copy, controller_copy, tmp_path / "k"):  # k -> sidecar k.json is the controller
        argv = [fmu_copy, "--duration", "1", "--controller", controller_copy, "-o", target]
        status, _, err = _cli(capsys, *argv)
        assert status == 2 and "would overwrite the input" in err
    assert (fmu_copy.read_bytes(), controller_copy.read_bytes()) == before


def test_airpath_with_exogenous_speed_trajectory(tmp_path):
    rec = run_fmu_experiment(
        built_fmu("airpath"), 0.01, 20,
        inputs={"engine_speed": "levels:lo=1000,hi=5000,min_hold=1,max_hold=3,ramp=0.5",
                "throttle_position": "multisine:f_lo=0.1,f_hi=10,rms=3"},
        seed=2, output=tmp_path / "air.csv")
    speed = rec.columns["engine_speed"]
    assert speed.min() >= 1000 and speed.max() <= 5000
    assert np.max(np.abs(np.diff(speed))) <= 4000 / 50 + 1e-9  # ramp of 0.5 s = 50 samples
    np.testing.assert_array_equal(rec.columns["speed"], speed)  # the default scheduling column
    np.testing.assert_array_equal(rec.columns["valve_lift"], 80.0)  # undriven input at its start value
    assert abs(np.mean(rec.columns["throttle_position"]) - 20.0) < 0.5  # multisine around the start value
    assert np.all(np.isfinite(rec.columns["air_mass_flow"])) and np.ptp(rec.columns["manifold_pressure"]) > 0
    header = (tmp_path / "air.csv").read_text().splitlines()[0].split(",")
    assert header == ["time", "throttle_position", "valve_lift", "engine_speed", "air_mass_flow",
                      "manifold_pressure", "speed"]


def test_python_control_controller_gives_the_same_run_as_its_file(adip):
    doc = json.loads(ADIP_CONTROLLER.read_text())
    assert not any(doc["y_operating_point"]) and not any(doc["u_operating_point"])  # zero, as from_statespace
    sys_k = control.ss(doc["A"], doc["B"], doc["C"], doc["D"], doc["Ts"], inputs=doc["inputs"],
                       outputs=doc["outputs"])
    excitation = {"voltage": "prbs:order=7,clock=0.02,amp=0.3"}
    from_file = run_fmu_experiment(adip, None, 2.0, controller=ADIP_CONTROLLER, excitation=excitation)
    from_object = run_fmu_experiment(adip, None, 2.0, controller=sys_k, excitation=excitation)
    for name, values in from_file.columns.items():
        np.testing.assert_array_equal(from_object.columns[name], values)
    assert "controller_file" not in from_object.metadata and from_object.metadata["mode"] == "closed-loop"


def test_design_experiment_stage_takes_a_setpoint_table(adip, tmp_path):
    """A design's `[experiment] setpoint = { arm_angle = "..." }` reaches the experiment (data.csv)."""
    from lpvflow.pipeline.config import bundled_config, load_config
    from lpvflow.pipeline.context import StageContext
    from lpvflow.pipeline.stages import experiment

    text = bundled_config("adip").read_text().replace("duration = 240.0", "duration = 4.0")
    text = re.sub(r"^setpoint = .*$", 'setpoint = { arm_angle = "levels:lo=-0.2,hi=0.2,min_hold=1,'
                  'max_hold=2,ramp=0.5" }', text, flags=re.M)
    (tmp_path / "design.toml").write_text(text)
    config = load_config(tmp_path / "design.toml")
    outputs, artifacts = experiment(StageContext(tmp_path, config))
    assert artifacts == ["data.csv", "data.csv.json"] and "arm_angle_setpoint" in outputs["ranges"]
    assert max(map(abs, outputs["ranges"]["arm_angle_setpoint"])) <= 0.2
