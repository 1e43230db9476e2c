"""A synthesized LPV controller (``lpvflow/lpv-controller``) as the identification controller of a closed-loop
experiment (issue 24, item 1): wired by its ``info["signals"]``, run with the law of ``lpvflow verify``,
recorded like the other closed-loop experiments, and usable by the design pipeline's identify and
validate stages (trim removal, closed-loop fit, b(Ĝ, K_id))."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment import run_experiment, run_fmu_experiment
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.experiment.record import write_record
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.models import LPVSS
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.coordinates import controller_trim
from lpvflow.pipeline.design import run_design
from lpvflow.pipeline.model_loop import closed_loop_simulation
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.pipeline.verify import simulate_loop
from lpvflow.synth.controller import AntiWindup, LPVController, observer_gains
from tests.design_files import adip_identification
from tests.fmu_builds import built_fmu
from tests.test_2dof_export import TRIM, adip_controller

VOLTS = 3.0  # actuator range of the anti-windup in the loop test: the set-point jumps saturate it
RANGE = 10.0  # the ADIP's amplifier range
COUNT = 2 * np.pi / 4096  # one count of a 4096-counts/rev encoder [rad]
SETPOINT = "levels:lo=-0.3,hi=0.3,min_hold=1,max_hold=2"
EXCITATION = "prbs:order=6,clock=0.05,amp=0.2"


@pytest.fixture(scope="module")
def adip() -> Path:
    return built_fmu("adip")


def limited(structure: str, volts: float = VOLTS) -> LPVController:
    """The piecewise ADIP controller of tests/test_2dof_export.py (trim, sin(arm) scheduling) with
    anti-windup for ±volts."""
    K = adip_controller(structure)
    K.antiwindup = AntiWindup(observer_gains(K.Ak, K.Ck), [-volts], [volts], [0.0])
    return K


def steps_of(values: np.ndarray, Ts: float) -> Signal:
    """The piecewise-constant recorded signal as a scenario Signal (a step at every change)."""
    changes = np.flatnonzero(np.diff(values)) + 1
    return Signal(initial=float(values[0]),
                  steps=tuple((k * Ts, float(values[k] - values[k - 1])) for k in changes))


@pytest.mark.parametrize("structure", ["1dof", "2dof"])
def test_the_experiment_runs_the_verify_loop_with_setpoints_as_references(adip, structure):
    """Set-points (levels) and a PRBS excitation on the voltage, the actuator saturating: the experiment's
    record equals `lpvflow verify`'s loop run on the recorded set-point as reference and the recorded
    excitation as input disturbance (added after the actuator range), to rounding."""
    parameters = {"x0_pendulum_angle": 0.02}
    record = run_fmu_experiment(adip, None, 6.0, controller=limited(structure),
                                setpoint={"arm_angle": SETPOINT}, excitation={"voltage": EXCITATION},
                                parameters=parameters, seed=4, progress=False)
    c, Ts = record.columns, record.Ts
    assert [name for name in c if name.endswith(("_setpoint", "_excitation"))] == [
        "voltage_excitation", "arm_angle_setpoint"]
    assert record.metadata["columns"]["setpoint"] == ["arm_angle_setpoint"]
    assert record.metadata["controller"]["format"] == "lpvflow/lpv-controller"
    scenario = Scenario("experiment", 6.0, reference={"arm_angle": steps_of(c["arm_angle_setpoint"], Ts)},
                        input_disturbance={"voltage": steps_of(c["voltage_excitation"], Ts)},
                        plant_parameters=parameters, settling_band={"arm_angle": 0.1})
    loop = Loop(("arm_angle", "pendulum_angle"), ("voltage",), ("sin(arm_angle)",),
                actuator_limits={"voltage": (-VOLTS, VOLTS)})
    run = simulate_loop(limited(structure), adip, scenario, loop)
    assert run.failure is None
    np.testing.assert_allclose(run.outputs, np.column_stack([c["arm_angle"], c["pendulum_angle"]]), atol=1e-9)
    np.testing.assert_allclose(run.control[:, 0] + c["voltage_excitation"], c["voltage"], atol=1e-9)
    saturated = np.isclose(np.abs(c["voltage"] - c["voltage_excitation"]), VOLTS)
    assert saturated.any() and saturated.mean() < 0.1  # the actuator range is reached, at the jumps only
    assert np.abs(c["pendulum_angle"]).max() < 0.2 and np.ptp(c["arm_angle_setpoint"]) > 0.3


def test_an_lpv_controller_file_sweeps_the_arm_with_sensors_and_keeps_the_pendulum_up(adip, tmp_path):
    """The 2-DOF controller as a file: a ±0.5 rad triangle set-point with a multisine on the voltage and
    4096-count encoders; the arm follows (with the lag of this upright-point test controller), the pendulum
    stays within ±10°, the sidecar names the file."""
    path = tmp_path / "controller.json"
    limited("2dof", RANGE).save(path)
    record = run_fmu_experiment(adip, None, 10.0, controller=path,
                                setpoint={"arm_angle": "triangle:amp=0.5,period=10"},
                                excitation={"voltage": "multisine:f_lo=0.2,f_hi=10,rms=0.15"}, seed=2,
                                quantization={"arm_angle": COUNT, "pendulum_angle": COUNT},
                                noise={"pendulum_angle": 1e-4}, progress=False)
    c = record.columns
    assert c["arm_angle"].max() > 0.4 and c["arm_angle"].min() < -0.4
    assert np.abs(c["arm_angle"] - c["arm_angle_setpoint"]).max() < 0.45  # this test controller lags
    assert np.rad2deg(np.abs(c["pendulum_angle"]).max()) < 10.0
    counts = c["arm_angle"] / COUNT
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    assert record.metadata["controller_file"]["path"] == str(path)
    # the trim the controller applied, u_op + u_eq(sin(arm)), from the record (what remove_trim takes off)
    K = load_experiment_controller(path)
    np.testing.assert_allclose(K.trim_along(c, len(c["time"]))[:, 0],
                               np.interp(np.sin(c["arm_angle"]), TRIM.p, TRIM.u[:, 0]), atol=1e-12)


@pytest.mark.parametrize("structure", ["1dof", "2dof"])
def test_frozen_law_is_the_controller_at_fixed_scheduling_and_the_trim_adds_its_slope(structure):
    """frozen_at(p) driven by y (references at the operating point) reproduces the LPV controller at fixed
    p, less its trim; operating_laws adds ∂u_eq/∂arm = TRIM slope · cos(arm) to the arm column of D."""
    K = SynthesizedController.from_controller(adip_controller(structure))
    arm = 0.1  # sin(arm) in the trim segment [-0.25, 0.3]
    p = np.array([np.sin(arm)])
    y = np.random.default_rng(0).normal(size=(50, 2)) * 0.1
    K.reset()
    u = np.array([K.command(K.y_op, y_k, p) for y_k in y])
    frozen = K.frozen_at(p)
    np.testing.assert_allclose(frozen.response(y - K.y_op) + K.trim(p), u, atol=1e-12)
    linearized, bare = K.operating_laws({"arm_angle": arm, "pendulum_angle": 0.0})
    np.testing.assert_array_equal(bare.D, frozen.D)
    slope = (TRIM.u[2, 0] - TRIM.u[1, 0]) / (TRIM.p[2] - TRIM.p[1])
    np.testing.assert_allclose(linearized.D - bare.D, [[slope * np.cos(arm), 0.0]], rtol=1e-6)


def test_bad_lpv_controllers_give_one_line(adip, tmp_path):
    doc = adip_controller("2dof").to_dict()
    signals = doc["info"]["signals"]
    renamed = {**signals, "measured": [{**signals["measured"][0], "name": "arm"}, signals["measured"][1]]}
    unknown = {**signals, "scheduling": [{**signals["scheduling"][0], "expression": "sin(arm_speed)"}]}
    cases = {
        "unwired": ({**doc, "info": {}}, DataError, r"has no info\['signals'\] record"),
        "renamed": ({**doc, "info": {"signals": renamed}}, DataError,
                    r"reads plant output 'arm' \(its info\['signals'\]\), which FMU adip lacks"),
        "unknown": ({**doc, "info": {"signals": unknown}}, DataError,
                    r"scheduling signal 1: .*unknown name 'arm_speed'"),
        "shapes": ({**doc, "Dk": doc["Dk"][:2]}, ModelError, "inconsistent matrix sizes"),
        "format": ({**doc, "format": "lpvflow/lpv-model"}, ModelError,
                   "'lpvflow/lpv-controller' controllers"),
    }
    for name, (bad, error, message) in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(error, match=message) as caught:
            run_fmu_experiment(adip, None, 0.1, controller=path, progress=False)
        assert "\n" not in str(caught.value)
    with pytest.raises(DataError, match="set-point on diag_energy: the controller does not read it"):
        run_fmu_experiment(adip, None, 0.1, controller=adip_controller("1dof"), progress=False,
                           setpoint={"diag_energy": "const:value=0"})


class LinearAdip:
    """The ADIP's exact upright linearization, discretized at TS, as an experiment plant (the Plant protocol)
    whose input is the applied voltage less the controller's trim u_eq(sin(arm)) when ``trimmed``: the
    plant a model identified with ``remove_trim`` describes exactly."""

    def __init__(self, trimmed: bool) -> None:
        self.model_name, self.input_names = "linear_adip", ["voltage"]
        self.output_names = ["arm_angle", "pendulum_angle"]
        self.model, self.trimmed = linear_adip(), trimmed
        self.x = np.zeros(4)

    def start_value(self, name: str) -> float:
        return 0.0

    def parameter_values(self) -> dict:
        return {}

    def outputs(self) -> np.ndarray:
        return self.model.C[0] @ self.x

    def step(self, u: np.ndarray, t: float, Ts: float) -> None:
        trim = np.interp(np.sin(self.outputs()[0]), TRIM.p, TRIM.u[:, 0]) if self.trimmed else 0.0
        self.x = self.model.A[0] @ self.x + self.model.B[0] @ (u - trim)

    def close(self) -> None:
        pass


def linear_adip() -> LPVSS:
    """The upright linearization as a (constant) LPVSS in sin(arm), outputs arm and pendulum angle."""
    import control

    from tests.adip_cases import TS, rm

    a, b = rm.adip_linearization(0.0, rm.default_parameters("adip"))
    G = control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), TS, method="zoh")
    return LPVSS(*(np.array([M, 0 * M]) for M in (G.A, G.B, G.C, G.D)),
                 Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,)), TS,
                 u_names=["voltage"], y_names=["arm_angle", "pendulum_angle"], p_names=["sin_arm"])


@pytest.mark.parametrize("remove_trim", [False, True])
def test_validate_simulates_the_experiment_loop_exactly_on_an_exact_model(tmp_path, remove_trim):
    """On a linear plant the experiment runs with the saturating 2-DOF controller (set-points, excitation),
    the validate stage's closed-loop simulation of that plant's exact model under the controller file
    reproduces the record (with remove_trim the plant is driven by u − u_eq, as the model then assumes),
    and identify's trim is the one the controller applied."""
    controller = tmp_path / "K.json"
    limited("2dof").save(controller)
    plant = LinearAdip(trimmed=remove_trim)
    record = run_experiment(plant, 0.005, 4.0, controller=load_experiment_controller(controller),
                            setpoint={"arm_angle": SETPOINT}, excitation={"voltage": EXCITATION},
                            scheduling_columns={"sin_arm": "sin(arm_angle)"}, seed=4, progress=False)
    write_record(record, tmp_path / "data.csv")
    config = {"experiment": {"controller": str(controller), "scheduling": {"sin_arm": "sin(arm_angle)"}},
              "identify": {"remove_trim": remove_trim}}
    ctx = StageContext(tmp_path, config)
    data = Dataset.read(tmp_path / "data.csv", ["voltage"], ["arm_angle", "pendulum_angle"], ["sin_arm"])
    y_sim = closed_loop_simulation(linear_adip(), data, ctx)
    assert np.ptp(data.y[:, 0]) > 0.3
    np.testing.assert_allclose(y_sim, data.y, atol=1e-9)
    trim = controller_trim(ctx, data)[:, 0]
    np.testing.assert_allclose(trim, np.interp(np.sin(data.y[:, 0]), TRIM.p, TRIM.u[:, 0]), atol=1e-12)


DESIGN = """
[design]
name = "lpv_identification"
plant = "{plant}"
output_dir = "{out}"

[experiment]
duration = 30.0
controller = "{controller}"
setpoint = {{ arm_angle = "triangle:amp=0.5,period=15" }}
excitation = {{ voltage = "multisine:f_lo=0.1,f_hi=20,rms=0.15" }}
scheduling = {{ sin_arm = "sin(arm_angle)" }}
seed = 1

""" + adip_identification(3, remove_trim=True) + """{extra}
"""


def test_the_design_pipeline_identifies_under_an_lpv_controller_file(adip, tmp_path):
    """`[experiment] controller` names an lpvflow/lpv-controller: the experiment records set-point and
    excitation, identify removes the controller's trim, validate simulates the model under it (a fit)
    and computes b(Ĝ(θ), K_id) with it at every frozen point; [diagnose] refuses it in one line."""
    controller = tmp_path / "K.json"
    limited("2dof", RANGE).save(controller)
    text = DESIGN.format(plant=adip, out=tmp_path, controller=controller, extra="")
    (tmp_path / "design.toml").write_text(text)
    summary = run_design(tmp_path / "design.toml", log=lambda line: None)
    assert summary["failed"] is None, summary["failed"]
    ranges = summary["stages"]["experiment"]["outputs"]["ranges"]
    assert {"arm_angle_setpoint", "voltage_excitation"} <= set(ranges)
    assert "minus the trim" in summary["stages"]["identify"]["outputs"]["input"]
    validate = summary["stages"]["validate"]["outputs"]
    assert validate["fit"]["bfr"][0] > 50.0 and "fit_failure" not in validate  # the arm; the pendulum
    # moves too little under this weak test controller for a 30 s record to identify it
    assert len(validate["b_P_Kid"]) == len(validate["nugap"]) == 3
    assert 0.0 < validate["b_P_Kid"][1] < 1.0  # K_id stabilizes the model at the centre of the range

    (tmp_path / "design.toml").write_text(DESIGN.format(
        plant=adip, out=tmp_path, controller=controller,
        extra='[diagnose]\ncandidates = ["sin_arm"]\n'))
    summary = run_design(tmp_path / "design.toml", log=lambda line: None)
    assert summary["failed"]["stage"] == "diagnose"
    error = summary["failed"]["error"]
    assert "is an lpvflow/lpv-controller file; [diagnose], which simulates the [experiment] controller's " \
           "loop, runs 'lpvflow/lti-controller' or 'lpvflow/gridded-controller' controllers" in error
    assert "\n" not in error


def test_cli_experiment_takes_an_lpv_controller(adip, tmp_path, capsys):
    from lpvflow.pipeline.cli import main

    controller = tmp_path / "K.json"
    adip_controller("1dof").save(controller)
    out = tmp_path / "run.csv"
    assert main(["experiment", str(adip), "--duration", "1", "--controller", str(controller),
                 "--setpoint", "arm_angle=const:value=0.2", "-o", str(out)]) == 0
    assert "arm_angle_setpoint" in capsys.readouterr().out
    assert json.loads((tmp_path / "run.csv.json").read_text())["controller"]["structure"] == "1dof"


def test_a_record_leaving_the_controllers_design_box_is_named(adip, tmp_path):
    """An LPV controller outside the box it was designed on extrapolates: ``design_box_exit`` names the
    first sample where the record's scheduling leaves the box, on a record made up here, and the design's
    experiment stage reports it (``left_design_box``) on an FMU run holding the arm at 0.8 rad (sin 0.72 >
    the box's 0.6), while a run inside the box reports nothing."""
    from lpvflow.pipeline.stages import experiment

    K = SynthesizedController.from_controller(limited("2dof"))
    time = np.arange(200) * 0.005
    arm = np.where(time < 0.5, 0.3, 0.7)  # sin 0.30 inside [-0.6, 0.6], sin 0.64 outside from t = 0.5 s
    assert K.design_box_exit(time, {"arm_angle": 0.3 + 0 * time, "pendulum_angle": 0 * time}) is None
    note = K.design_box_exit(time, {"arm_angle": arm, "pendulum_angle": 0 * time})
    assert "at t = 0.5 s" in note and "sin(arm_angle) = 0.6442 in [-0.6, 0.6]" in note
    assert "100 of 200 samples" in note
    path = tmp_path / "K.json"
    path.write_text(json.dumps(limited("2dof").to_dict()))
    notes = []
    for value in (0.3, 0.8):
        cfg = {"Ts": None, "duration": 3.0, "inputs": {}, "controller": str(path), "excitation": {},
               "parameters": {}, "scheduling": {}, "seed": 1, "quantization": {}, "noise": {},
               "output_bounds": {}, "setpoint": {"arm_angle": f"const:value={value}"}}
        folder = tmp_path / str(value)
        folder.mkdir()
        outputs, _ = experiment(StageContext(folder, {"experiment": cfg, "design": {"plant": str(adip)}}))
        notes.append(outputs.get("left_design_box"))
    assert notes[0] is None
    assert notes[1].startswith("left the scheduling box the controller was designed on at t = ")


def test_every_experiment_controller_kind_answers_through_the_protocol():
    """``run_fmu_experiment`` branches on no controller class: each object gives the controller an
    experiment runs (``experiment_controller()``): the experiment kinds themselves, an LPVController
    wired by its port record (the same wiring as its file), and one DataError line without that record.
    The LTI and gridded kinds have no design box, so no record leaves one: on random records far
    outside any range ``design_box_exit`` is None (the protocol's answer), where the LPV controller's
    names the first sample outside its box."""
    import dataclasses

    import control

    from lpvflow.experiment.controller import GriddedController, LtiController
    from lpvflow.loop.protocol import ExperimentController

    rng = np.random.default_rng(7)
    lti = LtiController.from_statespace(control.ss([[0.5]], [[0.2]], [[1.0]], [[0.1]], 0.005),
                                        inputs=["arm_angle"], outputs=["voltage"])
    grid = np.array([-1.0, 0.0, 1.0])
    gridded = GriddedController(grid, np.full((3, 1, 1), 0.5), np.full((3, 1, 1), 0.2), np.ones((3, 1, 1)),
                                np.full((3, 1, 1), 0.1), np.zeros((3, 1)), np.zeros((3, 1)), 0.005,
                                ("arm_angle",), ("voltage",), "sin(arm_angle)")
    law = limited("2dof")
    wired = law.experiment_controller()
    expected = SynthesizedController.from_controller(law)
    assert wired.law is law and (wired.inputs, wired.outputs, wired.scheduling) == (
        expected.inputs, expected.outputs, expected.scheduling)
    np.testing.assert_array_equal(wired.u_op, expected.u_op)
    for K in (lti, gridded, wired):
        assert ExperimentController in type(K).__mro__ and K.experiment_controller() is K
    time = np.arange(300) * 0.005
    for _ in range(5):
        columns = {"arm_angle": rng.uniform(-50, 50, time.size), "pendulum_angle": rng.normal(size=time.size)}
        assert lti.design_box_exit(time, columns) is None and gridded.design_box_exit(time, columns) is None
        first = int(np.argmax(np.abs(np.sin(columns["arm_angle"])) > 0.6))
        assert f"at t = {time[first]:.4g} s" in wired.design_box_exit(time, columns)
    bare = dataclasses.replace(law, info={})
    with pytest.raises(DataError, match=r"has no info\['signals'\] record"):
        bare.experiment_controller()
