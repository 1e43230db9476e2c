"""Closed-loop verification: metrics against analytic answers, baselines, verdicts, scenario files, CLI.

The analytic plant is a first-order discrete system y(k+1) = a y(k) + b u(k), built as an FMU through
the export path; with a static controller u = kp e the loop is y(k+1) = c y(k) + b kp r, c = a − b kp,
so after a unit step at t_s (a = 1): y = 1 − c^j, j samples after the step.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import control
import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import DataError
from lpvflow.experiment.controller import LtiController
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.config import load_scenarios
from lpvflow.pipeline.export import export_fmu
from lpvflow.pipeline.loop_metrics import ClosedLoopRun, after_settling_peaks, requirement_failures
from lpvflow.pipeline.scenarios import Loop, Requirements, Scenario, Signal
from lpvflow.pipeline.verify import coverage_note, plot_runs, run_verification, verify
from lpvflow.synth.controller import LPVController
from lpvflow.synth.polytope import BoxPolytope
from tests.test_export import _adip_lpv_controller

ROOT = Path(__file__).resolve().parents[1]
ADIP = ROOT / "fmu_plants" / "build" / "adip.fmu"
TS, B = 0.01, 0.5
POLY = BoxPolytope(np.array([[-1.0, 1.0]]), np.array([[1.0, -1.0], [1.0, 1.0]]))
BASIS = Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,))
LOOP = Loop(("y",), ("u",), ("y",))


def _constant(A: float | list, B_: float | list, C: float | list, D: float | list) -> LPVController:
    """An LPVController with the same matrices at both vertices (LTI in LPV form)."""
    mats = [np.atleast_2d(np.asarray(M, dtype=float)) for M in (A, B_, C, D)]
    return LPVController(*(np.array([M, M]) for M in mats), POLY, BASIS, TS)


def _gain(kp: float) -> LPVController:
    """Static law u = kp e, as a one-state controller whose state stays zero."""
    return _constant(0.0, 0.0, 0.0, kp)


@pytest.fixture(scope="module")
def plants(tmp_path_factory: pytest.TempPathFactory) -> dict[float, Path]:
    """First-order plant FMUs y(k+1) = a y + B u for a = 1 (integrator) and a = 0.8."""
    folder = tmp_path_factory.mktemp("plants")
    # the FMU forms e = u_ref − u with u_ref held at 0 by the loop (an exogenous input): e = −u, so −B
    names = {"measured": ["u"], "scheduling": ["q"], "actuated": ["y"]}
    return {
        a: export_fmu(_constant(a, -B, 1.0, 0.0), folder / f"plant_{int(10 * a)}.fmu", names)
        for a in (1.0, 0.8)
    }


def _step(duration: float = 1.0, at: float = 0.1, **kwargs: object) -> Scenario:
    return Scenario("step", duration, reference={"y": Signal(steps=((at, 1.0),))}, **kwargs)


@pytest.mark.parametrize(("c", "settle_samples", "overshoot"), [(0.9, 38, 0.0), (-0.5, 6, 0.5)])
def test_settling_time_and_overshoot_match_the_analytic_loop(
    plants: dict, c: float, settle_samples: int, overshoot: float
) -> None:
    kp = (1.0 - c) / B
    # |y − 1| = |c|^j ≤ 0.02 from j = ceil(ln 0.02 / ln |c|) on: 38 for c = 0.9, 6 for c = −0.5
    assert settle_samples == math.ceil(math.log(0.02) / math.log(abs(c)))
    result = verify(_gain(kp), plants[1.0], [_step()], LOOP)["scenarios"][0]["controller"]
    metrics = result["outputs"]["y"]
    assert result["stable"] and metrics["settled"]
    assert metrics["settling_time"] == pytest.approx(settle_samples * TS, abs=1e-12)
    assert metrics["overshoot"] == pytest.approx(overshoot, abs=1e-12)
    assert metrics["overshoot_percent"] == pytest.approx(100 * overshoot, abs=1e-9)
    assert metrics["band"] == pytest.approx(0.02) and metrics["change_time"] == pytest.approx(0.1)
    j = np.arange(90, 100) - 10  # final window: the last 10 of 100 samples, j samples after the step
    assert metrics["steady_state_error"] == pytest.approx(abs(np.mean(c**j)), rel=1e-6, abs=1e-15)
    j = np.arange(90)  # |r − y| = |c|^j from the step on
    assert metrics["iae"] == pytest.approx(TS * np.sum(np.abs(c) ** j), rel=1e-9)
    assert metrics["ise"] == pytest.approx(TS * np.sum(c ** (2 * j)), rel=1e-9)
    assert result["controls"]["u"]["peak_control"] == pytest.approx(kp)  # kp·e at the step
    assert result["controls"]["u"]["saturation_time"] == 0.0


def test_scheduling_outside_the_design_box_is_measured_and_named(plants: dict) -> None:
    # c = 0.9, scheduled on y itself: y = 1 − 0.9^j after the step at k = 10 leaves the box [−0.5, 0.5]
    # when 0.9^j < 0.5, i.e. from j = 7 (k = 17) to the end of the 100-sample run: 83 samples outside
    kp = 0.1 / B
    narrow = BoxPolytope(np.array([[-0.5, 0.5]]), np.array([[1.0, -0.5], [1.0, 0.5]]))
    basis = Basis("affine", 1, p_min=(-0.5,), p_max=(0.5,))
    zero = np.zeros((2, 1, 1))
    controller = LPVController(zero, zero, zero, np.full((2, 1, 1), kp), narrow, basis, TS)  # u = kp e
    verification = run_verification(controller, plants[1.0], [_step()], LOOP,
                                    baseline=control.ss([], [], [], [[kp]], TS))
    lpv, base = (verification.to_dict()["scenarios"][0][key] for key in ("controller", "baseline"))
    coverage = lpv["scheduling"]
    assert coverage["box"] == [[-0.5, 0.5]]
    assert coverage["first_outside_box"] == pytest.approx(0.17, abs=1e-12)
    assert coverage["time_outside_box"] == pytest.approx(83 * TS, abs=1e-12)
    assert coverage["range"] == [[0.0, pytest.approx(1 - 0.9**89, abs=1e-12)]]
    assert coverage_note(lpv) == ("scheduling left the design box [-0.5, 0.5] at t = 0.17 s and spanned "
                                  f"[0, {1 - 0.9**89:.3g}] (0.83 s outside)")
    # the same loop inside its box, and an LTI baseline (no box): the range only, no note
    assert base["scheduling"] == {"range": coverage["range"], "box": None, "time_outside_box": None,
                                  "first_outside_box": None} and coverage_note(base) == ""
    inside = verify(_gain(kp), plants[1.0], [_step()], LOOP)["scenarios"][0]["controller"]["scheduling"]
    assert inside["box"] == [[-1.0, 1.0]] and inside["time_outside_box"] == 0.0
    assert inside["first_outside_box"] is None


def test_steady_state_error_of_a_proportional_loop(plants: dict) -> None:
    kp = 0.4  # a = 0.8: y_ss = B kp / (1 − a + B kp) = 0.5, error 0.5
    metrics = verify(_gain(kp), plants[0.8], [_step(duration=2.0)], LOOP)["scenarios"][0]["controller"]
    y_ss = B * kp / (1 - 0.8 + B * kp)
    assert metrics["outputs"]["y"]["steady_state_error"] == pytest.approx(1 - y_ss, abs=1e-9)
    assert not metrics["stable"] and metrics["reason"] == "not settled: y"


def test_saturation_time_counts_the_clipped_samples(plants: dict) -> None:
    # kp = 1, |u| ≤ 0.25: y grows by B·0.25 = 0.125 per sample while kp (1 − y) > 0.25, i.e. for 6 samples
    loop = Loop(("y",), ("u",), ("y",), actuator_limits={"u": (-0.25, 0.25)})
    result = verify(_gain(1.0), plants[1.0], [_step()], loop)["scenarios"][0]["controller"]
    assert result["controls"]["u"]["saturation_time"] == pytest.approx(6 * TS)
    assert result["controls"]["u"]["peak_control"] == pytest.approx(0.25)
    assert result["stable"]


def test_unstable_loop_fails_its_verdict(plants: dict) -> None:
    kp = 2.5 / B  # c = −1.5
    bounded = _step(output_bounds={"y": (-100.0, 100.0)})
    result = verify(_gain(kp), plants[1.0], [_step(), bounded], LOOP)
    free, stopped = (s["controller"] for s in result["scenarios"])
    assert not result["stable"] and not free["stable"] and free["reason"] == "not settled: y"
    assert not stopped["stable"] and stopped["reason"].startswith("unbounded: y left its output_bounds")


def test_lti_baselines_run_with_the_same_loop_convention(plants: dict) -> None:
    kp = 0.2 / B
    verification = run_verification(
        _gain(kp), plants[1.0], [_step()], LOOP, baseline=control.ss([], [], [], [[kp]], TS)
    )
    lpv, base = verification.results[0].runs
    np.testing.assert_allclose(base.outputs, lpv.outputs, atol=1e-12)
    # an lpvflow/lti-controller file reads y − r: D = −kp is the same law; its u_op offsets u
    lti = LtiController(
        np.zeros((0, 0)),
        np.zeros((0, 1)),
        np.zeros((1, 0)),
        np.array([[-kp]]),
        TS,
        ("y",),
        ("u",),
        np.zeros(1),
        np.zeros(1),
    )
    verification = run_verification(_gain(kp), plants[1.0], [_step()], LOOP, baseline=lti)
    np.testing.assert_allclose(verification.results[0].runs[1].control, lpv.control, atol=1e-12)
    assert verification.to_dict()["scenarios"][0]["baseline"]["stable"]


def test_disturbances_act_where_the_scenario_says(plants: dict) -> None:
    # integrator plant with an integral-free P loop: an input step d is cancelled only with error
    # e_ss = −d/kp (u = kp e + d = 0); an output step is rejected completely (integrator plant)
    kp = 0.5 / B
    scenario = Scenario(
        "dist", 2.0, input_disturbance={"u": Signal(steps=((0.5, 0.05),))}, settling_band={"y": 1e-3}
    )
    metrics = verify(_gain(kp), plants[1.0], [scenario], LOOP)["scenarios"][0]["controller"]["outputs"]["y"]
    assert metrics["steady_state_error"] == pytest.approx(0.05 / kp, rel=1e-6)
    scenario = Scenario(
        "dist", 2.0, output_disturbance={"y": Signal(steps=((0.5, 0.3),))}, settling_band={"y": 1e-3}
    )
    metrics = verify(_gain(kp), plants[1.0], [scenario], LOOP)["scenarios"][0]["controller"]["outputs"]["y"]
    assert metrics["steady_state_error"] < 1e-9 and metrics["peak_deviation"] == pytest.approx(0.3)


def test_exogenous_inputs_follow_their_signal_and_can_schedule(plants: dict) -> None:
    # the plant FMU's input q is not driven by the controller: it is exogenous, and p = 2 q here
    loop = Loop(("y",), ("u",), ("2 * q",))
    ramp = Signal(initial=-0.5, ramps=((0.2, 0.6, 1.0),))
    scenario = _step(exogenous={"q": ramp})
    run = run_verification(_gain(1.0), plants[1.0], [scenario], loop).results[0].runs[0]
    np.testing.assert_allclose(run.scheduling[:, 0], 2 * ramp.sample(run.time), atol=1e-12)


@pytest.mark.parametrize(
    ("c", "requirements", "missed"),
    [
        (0.9, Requirements(settling_time=0.3), ["y settles in 0.38 s (limit 0.3 s)"]),  # 38 samples
        (-0.5, Requirements(settling_time=0.3, overshoot=0.1), ["y overshoot 0.5 (limit 0.1)"]),
        (-0.5, Requirements(settling_time=0.07, overshoot=0.6), []),
    ],
)
def test_requirements_are_checked_on_the_analytic_loop(
    plants: dict, c: float, requirements: Requirements, missed: list[str]
) -> None:
    result = run_verification(_gain((1.0 - c) / B), plants[1.0], [_step(requirements=requirements)], LOOP)
    metrics = result.to_dict()["scenarios"][0]["controller"]
    assert metrics["stable"] and metrics["requirements_failed"] == missed
    assert result.passed == (not missed) and result.to_dict()["passed"] == (not missed)
    assert metrics["after_settling"] == {}  # the only output is tracked


def test_after_settling_is_the_untracked_output_peak_once_the_tracked_ones_settled() -> None:
    time = np.arange(100) * TS
    pendulum = np.where(time < 0.5, 0.3 * np.sin(20 * time), 0.05 * np.cos(7 * time))
    none = np.zeros((100, 1))
    run = ClosedLoopRun("lpv", time, np.zeros((100, 2)), np.column_stack([time, pendulum]), none, none, none,
                        ("arm", "pendulum"), ("u",))
    loop = Loop(("arm", "pendulum"), ("u",), ("arm",))
    scenario = Scenario("s", 1.0)
    arm = {"change_time": 0.1, "settling_time": 0.4}  # settled at t = 0.5
    peaks = after_settling_peaks(run, scenario, loop, {"arm": arm})
    assert peaks == {"pendulum": pytest.approx(np.max(np.abs(0.05 * np.cos(7 * time[50:]))))}
    spec = Requirements(after_settling={"pendulum": 0.04})
    assert requirement_failures(spec, {"arm": arm | {"overshoot": 0.0}}, peaks) == [
        f"pendulum after settling {peaks['pendulum']:.3g} (limit 0.04)"]
    never = after_settling_peaks(run, scenario, loop, {"arm": arm | {"settling_time": None}})
    assert never == {"pendulum": None}
    assert requirement_failures(spec, {"arm": arm | {"settling_time": None, "overshoot": 0.0}}, never) == [
        "pendulum after settling: not measured, the tracked outputs do not settle"]


def test_requirements_on_an_unknown_output_give_one_line(plants: dict) -> None:
    scenario = _step(requirements=Requirements(after_settling={"z": 0.1}))
    with pytest.raises(DataError, match=r"unknown requirements\.after_settling output 'z'; known: y") as info:
        verify(_gain(1.0), plants[1.0], [scenario], LOOP)
    assert "\n" not in str(info.value)


def test_an_after_settling_bound_on_a_tracked_output_gives_one_line(plants: dict) -> None:
    scenario = _step(requirements=Requirements(after_settling={"y": 0.1}))
    with pytest.raises(DataError, match="names the tracked output 'y'") as info:
        verify(_gain(1.0), plants[1.0], [scenario], LOOP)
    assert "\n" not in str(info.value)


def test_a_failed_run_misses_its_requirements(plants: dict) -> None:
    bounded = _step(output_bounds={"y": (-100.0, 100.0)}, requirements=Requirements(settling_time=1.0))
    metrics = verify(_gain(2.5 / B), plants[1.0], [bounded], LOOP)["scenarios"][0]["controller"]
    assert metrics["requirements_failed"] == ["the run failed (see reason)"]
    assert metrics["reason"].startswith("unbounded: y left its output_bounds")


def test_adip_lpv_loop_with_noise_is_stable_and_plotted(tmp_path: Path) -> None:
    loop = Loop(
        ("arm_angle", "pendulum_angle"),
        ("voltage",),
        ("sin(arm_angle)",),
        actuator_limits={"voltage": (-10.0, 10.0)},
        plant_parameters={"effect_noise_std": 1e-4, "effect_noise_seed": 3},
    )
    scenario = Scenario(
        "pendulum offset",
        2.5,
        plant_parameters={"x0_pendulum_angle": 0.03},
        settling_band={"pendulum_angle": 0.005, "arm_angle": 0.01},
    )
    verification = run_verification(_adip_lpv_controller(), ADIP, [scenario], loop)
    assert verification.stable
    run = verification.results[0].runs[0]
    assert np.std(np.diff(run.outputs[-50:, 1])) > 1e-5  # the FMU's measurement noise is on
    png = plot_runs(verification.results[0].runs, tmp_path / "adip.png", "ADIP")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


SCENARIO_TOML = """
[verify.loop]
measured = ["y"]
actuated = ["u"]
scheduling = ["y"]
actuator_limits = { u = [-5.0, 5.0] }

[[verify.scenario]]
name = "step"
duration = 1.0
reference = { y = { steps = [[0.1, 1.0]] } }

[[verify.scenario]]
name = "ramp"
duration = 1.5
reference = { y = { initial = 0.5, ramps = [[0.1, 0.3, 1.0]] } }
"""


def test_signal_samples_steps_and_ramps() -> None:
    signal = Signal(initial=0.5, ramps=((0.1, 0.3, 1.0),), steps=((1.0, -0.2),))
    np.testing.assert_allclose(signal.sample(np.array([0.0, 0.2, 0.5, 1.0])), [0.5, 1.0, 1.5, 1.3])


def test_scenario_file_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO_TOML)
    parsed = load_scenarios(path)
    assert parsed.loop.measured == ("y",) and parsed.loop.actuator_limits == {"u": (-5.0, 5.0)}
    assert [s.name for s in parsed.scenarios] == ["step", "ramp"]
    assert parsed.scenarios[1].reference["y"] == Signal(0.5, (), ((0.1, 0.3, 1.0),))


LOOP_TOML = "[verify.loop]\nmeasured = ['y']\nactuated = ['u']\nscheduling = ['y']\n"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[[verify.scenario]\n", "not valid TOML"),
        (LOOP_TOML + "[[verify.scenario]]\nname = 'a'\n", "lacks duration"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 1.0\ncolour = 2\n", "unknown key 'colour'"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 1.0\n"
         "reference = { y = { ramps = [[0.5, 0.2, 1.0]] } }\n", "t_stop"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 'long'\n", "must be a finite number"),
        ("[verify.loop]\nmeasured = ['y']\n[[verify.scenario]]\nduration = 1.0\n", "[loop] lacks 'actuated'"),
        ("x = 1\n", "unknown table(s) ['x']"),
        ("[loop]\nmeasured = ['y']\n[[scenario]]\nduration = 1.0\n", "now use [verify.loop]"),
        (LOOP_TOML, "[verify] lacks ['scenario']"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 1.0\nrequirements = { settling_time = -1.5 }\n",
         "= -1.5 must be > 0"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 1.0\nrequirements = { rise_time = 1 }\n",
         "unknown key 'rise_time'"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 1.0\nrequirements = 2\n",
         "requirements must be a table"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 1.0\nparameter_factors = { pendulum_mass = -1.1 }\n",
         "parameter_factors.pendulum_mass = -1.1 must be a factor > 0"),
        (LOOP_TOML + "[[verify.scenario]]\nduration = 1.0\nparameter_factors = { pendulum_mass = 'x' }\n",
         "parameter_factors.pendulum_mass must be a finite number"),
    ],
)
def test_bad_scenario_files_give_one_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(DataError) as info:
        load_scenarios(path)
    assert message in str(info.value) and "\n" not in str(info.value)


def _cli(capsys: pytest.CaptureFixture, argv: list[str]) -> tuple[int, str]:
    status = main(argv)
    err = capsys.readouterr().err
    return status, err


def test_verify_cli_exit_codes_and_one_line_errors(
    plants: dict, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    stable, unstable = tmp_path / "K.json", tmp_path / "K_bad.json"
    _gain(0.2 / B).save(stable)
    _gain(2.5 / B).save(unstable)
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO_TOML)
    plant, out = str(plants[1.0]), tmp_path / "out.json"
    base = ["verify", "--plant", plant, "--scenario", str(scenario), "--json", str(out)]
    status = main([*base, str(stable), "--baseline", str(stable), "--figures", str(tmp_path / "fig")])
    printed = capsys.readouterr().out
    report = json.loads(out.read_text())
    assert status == 0 and report["stable"] and len(report["scenarios"]) == 2
    # the ramp to 1.5 leaves the controllers' box [−1, 1] (both runs); the step to 1 stays inside it
    assert printed.count("scheduling left the design box [-1, 1] at t = ") == 2
    assert all("ramp [" in line for line in printed.splitlines() if "design box" in line)
    assert report["scenarios"][1]["controller"]["outputs"]["y"]["change_time"] == pytest.approx(0.1)
    assert (tmp_path / "fig" / "scenario_2.png").exists()
    assert _cli(capsys, [*base, str(unstable)])[0] == 1
    demanding = tmp_path / "demanding.toml"  # the stable loop settles in 0.06 s; 10 ms is not enough
    demanding.write_text(SCENARIO_TOML.replace('"ramp"', '"ramp"\nrequirements = { settling_time = 0.01 }'))
    argv = ["verify", "--plant", plant, "--scenario", str(demanding), "--json", str(tmp_path / "d.json")]
    argv.append(str(stable))
    assert _cli(capsys, argv)[0] == 1
    report = json.loads((tmp_path / "d.json").read_text())
    assert report["stable"] and not report["passed"]

    def one_line(argv: list[str], fragment: str) -> None:
        status, err = _cli(capsys, argv)
        assert status == 2 and err.count("\n") == 1 and fragment in err, err

    one_line(
        [
            "verify",
            str(stable),
            "--plant",
            str(tmp_path / "none.fmu"),
            "--scenario",
            str(scenario),
            "--json",
            str(out),
        ],
        "not found",
    )
    one_line([*base[:-2], "--json", str(scenario), str(stable)], "would overwrite the input")
    renamed = tmp_path / "renamed.toml"
    renamed.write_text(SCENARIO_TOML.replace('measured = ["y"]', 'measured = ["z"]'))
    one_line(
        ["verify", str(stable), "--plant", plant, "--scenario", str(renamed), "--json", str(out)],
        "unknown measured plant output 'z'",
    )
    renamed.write_text(SCENARIO_TOML.replace('scheduling = ["y"]', 'scheduling = ["speed"]'))
    one_line(
        ["verify", str(stable), "--plant", plant, "--scenario", str(renamed), "--json", str(out)],
        "unknown name 'speed'",
    )
    two_inputs = tmp_path / "K2.json"
    LPVController(
        np.zeros((2, 1, 1)), np.zeros((2, 1, 2)), np.zeros((2, 1, 1)), np.ones((2, 1, 2)), POLY, BASIS, TS
    ).save(two_inputs)
    one_line([*base, str(two_inputs)], "2 input(s)")
    perturbed = 'name = "step"\nparameter_factors = { mass = 1.1 }'
    renamed.write_text(SCENARIO_TOML.replace('name = "step"', perturbed))
    one_line(
        ["verify", str(stable), "--plant", plant, "--scenario", str(renamed), "--json", str(out)],
        "scenario 'step': parameter_factors names 'mass', not a Real parameter of plant_10.fmu; its "
        "parameters: none",
    )
    renamed.write_text("[[scenario]\n")
    one_line(
        ["verify", str(stable), "--plant", plant, "--scenario", str(renamed), "--json", str(out)],
        "not valid TOML",
    )


# ------------------------------------------------------------------------- perturbed plants (robustness)
ADIP_LOOP = Loop(("arm_angle", "pendulum_angle"), ("voltage",), ("sin(arm_angle)",),
                 actuator_limits={"voltage": (-10.0, 10.0)},
                 plant_parameters={"arm_damping": 0.02})  # other than the FMU's start value 0.015


def _hold(**kwargs: object) -> Scenario:
    """Hold the arm at 0 and take a 0.5 V step load disturbance on the voltage at 0.5 s."""
    return Scenario("hold", 2.0, input_disturbance={"voltage": Signal(steps=((0.5, 0.5),))},
                    settling_band={"arm_angle": 0.05}, **kwargs)


def test_parameter_factors_perturb_the_plant_and_leave_the_nominal_run_alone() -> None:
    from fmpy import read_model_description

    from lpvflow.experiment.plant import open_plant
    from lpvflow.pipeline.verify import plant_parameters, simulate_loop

    start = {v.name: float(v.start) for v in read_model_description(str(ADIP)).modelVariables
             if v.causality == "parameter" and v.type == "Real"}
    heavy = _hold(parameter_factors={"pendulum_mass": 1.1, "arm_damping": 2.0})
    values = plant_parameters(ADIP, ADIP_LOOP, heavy)
    # a factor multiplies the FMU's start value, or the value plant_parameters gives
    assert values == {"pendulum_mass": pytest.approx(1.1 * start["pendulum_mass"]), "arm_damping": 0.04}
    plant = open_plant(ADIP, values)
    try:
        assert plant.parameter_values()["pendulum_mass"] == pytest.approx(1.1 * start["pendulum_mass"])
    finally:
        plant.close()
    K = _adip_lpv_controller()
    nominal, unit, perturbed = (simulate_loop(K, ADIP, scenario, ADIP_LOOP).outputs for scenario in (
        _hold(), _hold(parameter_factors={"pendulum_mass": 1.0}), heavy))
    np.testing.assert_array_equal(unit, nominal)  # a factor of 1 is the nominal plant
    assert np.max(np.abs(nominal[:, 0])) > 1e-3  # the load disturbance moves the held arm
    assert np.max(np.abs(perturbed - nominal)) > 1e-3  # and the perturbed plant answers differently
    record = run_verification(K, ADIP, [heavy], ADIP_LOOP).to_dict()["scenarios"][0]
    assert record["parameter_factors"] == {"pendulum_mass": 1.1, "arm_damping": 2.0}


@pytest.mark.parametrize(("factors", "message"), [
    ({"pendulum_weight": 1.1}, "scenario 'hold': parameter_factors names 'pendulum_weight', not a Real "
                               "parameter of adip.fmu; its parameters: x0_arm_angle, "),
    ({"x0_arm_angle": 2.0}, "parameter_factors: x0_arm_angle is 0, a factor cannot change it"),
])
def test_a_bad_parameter_factor_is_one_line(factors: dict, message: str) -> None:
    with pytest.raises(DataError) as info:
        run_verification(_adip_lpv_controller(), ADIP, [_hold(parameter_factors=factors)], ADIP_LOOP)
    assert message in str(info.value) and "\n" not in str(info.value)
    assert "pendulum_mass" in str(info.value) or "x0_arm_angle is 0" in str(info.value)
