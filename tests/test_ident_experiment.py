"""Identification over the ADIP's whole arm range (issue 24, item 1): the gain-scheduled identification
controller (``lpvflow/gridded-controller``), set-point sweeps, encoder quantization and sensor noise,
and the ν-gap/b(P, K) gate of the validate stage."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from lpvflow.errors import DataError, ModelError
from lpvflow.experiment import run_fmu_experiment
from lpvflow.experiment.controller import GriddedController
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.pipeline.config import check_table
from lpvflow.pipeline.design import run_design
from lpvflow.pipeline.gate import gate_verdict
from tests.design_files import adip_identification
from tests.fmu_builds import built_fmu

ROOT = Path(__file__).resolve().parents[1]
SCHEDULED = ROOT / "fmu_plants" / "adip" / "scheduled_controller.json"
STABILIZING = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"
COUNT = 2 * np.pi / 4096  # one count of a 4096-counts/rev encoder [rad]


@pytest.fixture(scope="module")
def adip() -> Path:
    return built_fmu("adip")


@pytest.fixture(scope="module")
def sweep(adip):
    """±66° triangle sweep of the arm set-point (80 s period) with a 0.5 V multisine on the voltage,
    4096-count encoders with 1e-4 rad of noise on both angles, under the scheduled controller."""
    return run_fmu_experiment(
        adip, None, 80.0, controller=SCHEDULED, excitation={"voltage": "multisine:f_lo=0.5,f_hi=20,rms=0.5"},
        setpoint={"arm_angle": "triangle:amp=1.15,period=80"},
        scheduling_columns={"sin_arm": "sin(arm_angle)"},
        seed=1, quantization={"arm_angle": COUNT, "pendulum_angle": COUNT},
        noise={"arm_angle": 1e-4, "pendulum_angle": 1e-4}, progress=False)


def test_scheduled_controller_holds_the_pendulum_across_the_sweep(sweep):
    """The arm follows the set-point across ±66° (the excitation takes it beyond) with the pendulum
    within ±3°; the LTI stabilizing controller of the bundled design does not go there (next test)."""
    c = sweep.columns
    assert np.rad2deg(c["arm_angle"].max()) > 66 and np.rad2deg(c["arm_angle"].min()) < -66
    assert np.rad2deg(np.abs(c["pendulum_angle"]).max()) < 3.0
    assert np.rad2deg(np.abs(c["arm_angle"] - c["arm_angle_setpoint"]).max()) < 12.0
    assert np.abs(c["voltage"]).max() < 10.0  # inside the actuator range
    assert sweep.metadata["controller"]["format"] == "lpvflow/gridded-controller"
    assert sweep.metadata["sensors"]["quantization"]["arm_angle"] == COUNT


def test_the_lti_stabilizing_controller_does_not_follow_the_sweep(adip):
    """The bundled design's LTI regulator (no trim, no integrator) asked for the same ±66° sweep holds the
    arm within ±28°: gravity balances its proportional action (measured 27.2°)."""
    record = run_fmu_experiment(adip, None, 80.0, controller=STABILIZING,
                                setpoint={"arm_angle": "triangle:amp=1.15,period=80"}, progress=False)
    assert np.rad2deg(np.abs(record.columns["arm_angle"]).max()) < 28.0


def test_quantized_data_sit_on_the_encoder_grid(sweep):
    """Recorded angles (and the scheduling computed from them) are whole counts; noise below half a
    count still moves some samples to the neighbouring count (compared with a noise-free record)."""
    for name in ("arm_angle", "pendulum_angle"):
        counts = sweep.columns[name] / COUNT
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    np.testing.assert_allclose(sweep.columns["sin_arm"], np.sin(sweep.columns["arm_angle"]))
    assert len(np.unique(np.round(sweep.columns["pendulum_angle"] / COUNT))) > 10


def test_noise_alone_is_seeded_white_and_of_the_given_size(adip):
    kwargs = dict(controller=SCHEDULED, progress=False)
    clean = run_fmu_experiment(adip, None, 2.0, **kwargs)
    noisy = run_fmu_experiment(adip, None, 2.0, noise={"pendulum_angle": 1e-3}, seed=3, **kwargs)
    again = run_fmu_experiment(adip, None, 2.0, noise={"pendulum_angle": 1e-3}, seed=3, **kwargs)
    np.testing.assert_array_equal(noisy.columns["pendulum_angle"], again.columns["pendulum_angle"])
    assert np.all(clean.columns["pendulum_angle"] == 0.0)  # upright at rest: nothing moves it
    assert 0.7e-3 < np.std(noisy.columns["pendulum_angle"]) < 1.6e-3  # the noise, and what K makes of it


def test_gridded_controller_interpolates_linearly_and_round_trips(tmp_path):
    K = load_experiment_controller(SCHEDULED)
    assert isinstance(K, GriddedController) and K.scheduling == "arm_angle"
    i = len(K.grid) // 2 + 3
    np.testing.assert_array_equal(K.at(K.grid[i])[0], K.A[i])
    mid = K.at(0.5 * (K.grid[i] + K.grid[i + 1]))
    np.testing.assert_allclose(mid[0], 0.5 * (K.A[i] + K.A[i + 1]))
    np.testing.assert_allclose(mid[5], 0.5 * (K.u_op[i] + K.u_op[i + 1]))
    np.testing.assert_array_equal(K.at(10.0)[0], K.A[-1])  # clipped to the grid
    # the trim is the ADIP's gravity voltage: −4.21 sin φ1 V (README), odd in the arm angle
    np.testing.assert_allclose(K.at(np.deg2rad(60))[5], -K.at(np.deg2rad(-60))[5])
    assert K.at(np.deg2rad(60))[5][0] == pytest.approx(-4.21 * np.sin(np.deg2rad(60)), rel=0.01)
    path = tmp_path / "copy.json"
    path.write_text(json.dumps(K.to_dict()))
    again = load_experiment_controller(path)
    np.testing.assert_array_equal(again.C, K.C)
    # linearized at 60°: the trim's slope −4.21 cos 60° V/rad joins D's arm column
    lin = K.linearized(np.array([np.deg2rad(60), 0.0]))
    slope = lin.D[0, 0] - K.frozen_at(np.deg2rad(60)).D[0, 0]
    assert slope == pytest.approx(-4.21 * np.cos(np.deg2rad(60)), rel=0.02)


def test_bad_controller_files_and_sensor_settings_give_one_line(tmp_path, adip):
    doc = json.loads(SCHEDULED.read_text())
    cases = {
        "points": ({**doc, "points": doc["points"][:-1]}, "one entry per grid value"),
        "grid": ({**doc, "grid": doc["grid"][::-1]}, "increasing"),
        "scheduling": ({**doc, "scheduling": "speed"}, "unknown name 'speed'"),
        "format": ({**doc, "format": "lpvflow/lpv-model"}, "an experiment runs"),
    }
    for name, (bad, message) in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(ModelError, match=message):
            load_experiment_controller(path)
    with pytest.raises(ModelError, match="quantized output 'arm'"):
        run_fmu_experiment(adip, None, 1.0, controller=SCHEDULED, quantization={"arm": COUNT})
    with pytest.raises(DataError, match=r"quantization step of arm_angle = -0\.1 must be a positive"):
        run_fmu_experiment(adip, None, 1.0, controller=SCHEDULED, quantization={"arm_angle": -0.1})
    with pytest.raises(DataError, match=r"\[experiment\] quantization.arm_angle = 0 must be a number in \(0"):
        check_table("experiment", {"duration": 1.0, "quantization": {"arm_angle": 0}}, "design.toml")
    with pytest.raises(DataError, match=r"\[experiment\] noise.pendulum_angle = 'x' must be a number"):
        check_table("experiment", {"duration": 1.0, "noise": {"pendulum_angle": "x"}}, "design.toml")


def test_triangle_setpoint_spec():
    from lpvflow.experiment.specs import generate, parse_spec

    x = generate(parse_spec("triangle:amp=2,period=0.8"), 12, 0.1, np.random.default_rng(0))
    np.testing.assert_allclose(x[:9], [0, 1, 2, 1, 0, -1, -2, -1, 0])
    with pytest.raises(DataError, match="triangle needs period"):
        parse_spec("triangle:amp=1")


# ------------------------------------------------------------------------------------------- gate
def test_gate_verdict_names_the_worst_point():
    outputs = {"theta": [[-0.5], [0.0], [0.5]], "nugap": [0.05, 0.02, 0.2], "b_P_Kid": [0.1, 0.1, 0.08],
               "nugap_below_b_everywhere": False}
    verdict = gate_verdict(outputs, True)
    assert verdict["passed"] is False
    assert "1 of 3 frozen points (worst θ = 0.5: ν-gap 0.2 ≥ b(P, K_id) 0.08)" in verdict["reason"]
    assert "not used for synthesis" in verdict["reason"]
    lost = {"left_design_box": "left the scheduling box the controller was designed on at t = 14.07 s (…)"}
    assert verdict["reason"] + "; the experiment record " + lost["left_design_box"] == \
        gate_verdict(outputs, True, lost)["reason"]
    assert "does not stabilize" not in verdict["reason"]
    diverged = {**outputs, "b_P_Kid": [0.0, 0.1, 0.0], "nugap": [1.0, 0.02, 1.0],
                "fit_failure": "the identified model's closed loop diverges at sample 2357: …"}
    reason = gate_verdict(diverged, True)["reason"]
    assert "does not stabilize the model's frozen loop at 2 of 3 points (b = 0)" in reason
    assert reason.endswith("; validation fit: the identified model's closed loop diverges at sample 2357: …")
    outputs.update(nugap=[0.05, 0.02, 0.07], nugap_below_b_everywhere=True)
    assert gate_verdict(outputs, True)["passed"] is True
    assert gate_verdict(outputs, False)["passed"] is None
    assert gate_verdict({"theta": [], "b_P_Kid": []}, True)["passed"] is None


def test_a_failing_kid_test_judged_by_the_robustness_stage_is_reported_not_applied():
    """The final pass of an identification-for-control design with [synth] robustness_gate: the same
    failing test is reported (worst point) with passed None and says who judges, unless K_id does not
    stabilize the model somewhere or the model's b_opt is not above its ν-gap somewhere; a passing one
    still passes."""
    outputs = {"theta": [[-0.5], [0.0], [0.5]], "nugap": [0.05, 0.02, 0.2], "b_P_Kid": [0.1, 0.1, 0.08],
               "nugap_below_b_everywhere": False}
    judged = gate_verdict(outputs, True, None, judged_by_robustness=True)
    assert judged["passed"] is None
    assert "1 of 3 frozen points (worst θ = 0.5: ν-gap 0.2 ≥ b(P, K_id) 0.08)" in judged["reason"]
    assert "not applied" in judged["reason"] and "robustness_gate" in judged["reason"]
    assert "not used for synthesis" not in judged["reason"]
    # a model the experiment's own (stable) loop does not stabilize somewhere is refused in any pass
    unstable = gate_verdict({**outputs, "b_P_Kid": [0.1, 0.0, 0.08]}, True, None, judged_by_robustness=True)
    assert unstable["passed"] is False and "(b = 0)" in unstable["reason"]
    assert "not used for synthesis" in unstable["reason"] and "not applied" not in unstable["reason"]
    # where the model's optimal margin is not above the ν-gap no shipped controller can pass: refused now
    hopeless = {**outputs, "b_opt": [0.3, 0.25, 0.19], "nugap": [0.05, 0.26, 0.2]}
    refused = gate_verdict(hopeless, True, None, judged_by_robustness=True)
    assert refused["passed"] is False and "not used for synthesis" in refused["reason"]
    assert refused["reason"].endswith(
        "no controller can pass the robustness stage's test: b_opt(Ĝ) ≤ ν-gap at 2 of 3 points (worst θ = 0: "
        "b_opt 0.25 ≤ ν-gap 0.26), and b(Ĝ, K) ≤ b_opt(Ĝ) for every K")
    reachable = gate_verdict({**outputs, "b_opt": [0.3, 0.3, 0.21]}, True, None, judged_by_robustness=True)
    assert reachable == judged
    outputs.update(nugap=[0.05, 0.02, 0.07], b_P_Kid=[0.1, 0.1, 0.08], nugap_below_b_everywhere=True)
    assert gate_verdict(outputs, True, None, judged_by_robustness=True)["passed"] is True


def test_only_the_final_pass_after_rounds_with_a_robustness_gate_defers_the_kid_test():
    from lpvflow.pipeline.config import bundled_config, load_config
    from lpvflow.pipeline.design import _judged_by_robustness
    from lpvflow.pipeline.gate import JUDGED_BY_ROBUSTNESS

    config = load_config(bundled_config("adip"))
    assert config["synth"]["robustness_gate"] is True
    final = _judged_by_robustness(config)
    assert final["validate"][JUDGED_BY_ROBUSTNESS] is True
    kept = {k: v for k, v in final["validate"].items() if k != JUDGED_BY_ROBUSTNESS}
    assert kept == dict(config["validate"])
    ungated = {**config, "synth": dataclasses.replace(config["synth"], robustness_gate=False)}
    assert _judged_by_robustness(ungated) is ungated
    assert _judged_by_robustness({**config, "synth": None})["validate"] is config["validate"]


NEAR_ZERO_DESIGN = """
[design]
name = "near_zero"
plant = "{plant}"
output_dir = "{out}"

[experiment]
Ts = 0.005
duration = 30.0
controller = "{controller}"
excitation = {{ voltage = "multisine:f_lo=0.02,f_hi=20,rms=1.5" }}
scheduling = {{ sin_arm = "sin(arm_angle)" }}
seed = 1

""" + adip_identification(5, "{gate}") + """[synth]
weights.S = {{ bandwidth = 2.0 }}
weights.K = {{ num = [0.05], den = [1] }}
"""


@pytest.mark.parametrize("gate", [True, False])
def test_gate_refuses_the_model_identified_near_zero(tmp_path, adip, gate):
    """The old bundled experiment (LTI regulator, arm near 0°, here 30 s) gives a model whose ν-gap to the
    FMU exceeds b(P, K_id): with the gate the design stops after validate with that reason and no synth
    is run; with gate = false it goes on to synthesis."""
    text = NEAR_ZERO_DESIGN.format(plant=adip, out=tmp_path, controller=STABILIZING,
                                   gate="" if gate else "gate = false\n")
    (tmp_path / "design.toml").write_text(text)
    lines: list[str] = []
    summary = run_design(tmp_path / "design.toml", log=lines.append)
    validate = summary["stages"]["validate"]["outputs"]
    assert validate["nugap_below_b_everywhere"] is False
    assert any(g >= b for g, b in zip(validate["nugap"], validate["b_P_Kid"], strict=True))
    if gate:
        assert validate["gate"]["passed"] is False
        assert summary["failed"] == {"stage": "validate", "error": validate["gate"]["reason"]}
        assert "synth" not in summary["stages"] or summary["stages"]["synth"].get("status") is None
        assert any("not used for synthesis" in line for line in lines)
        assert "not used for synthesis" in (tmp_path / "near_zero" / "report.html").read_text()
    else:
        assert validate["gate"]["passed"] is None
        assert summary["stages"]["synth"]["status"] in ("ran", "failed")


def test_cli_runs_the_scheduled_controller_with_sensors(adip, tmp_path, capsys):
    from lpvflow.pipeline.cli import main

    out = tmp_path / "sweep.csv"
    status = main(["experiment", str(adip), "--duration", "4", "--controller", str(SCHEDULED),
                   "--setpoint", "arm_angle=triangle:amp=0.5,period=4",
                   "--quantization", f"arm_angle={COUNT!r}", "--noise", "pendulum_angle=1e-4",
                   "-o", str(out)])
    assert status == 0 and "arm_angle_setpoint" in capsys.readouterr().out
    meta = json.loads((tmp_path / "sweep.csv.json").read_text())
    assert meta["sensors"] == {"quantization": {"arm_angle": COUNT}, "noise": {"pendulum_angle": 1e-4}}
    assert main(["experiment", str(adip), "--duration", "1", "--controller", str(SCHEDULED),
                 "--noise", "pendulum_angle=lots", "-o", str(out)]) == 2
    assert "--noise pendulum_angle='lots': the value is not a number" in capsys.readouterr().err
