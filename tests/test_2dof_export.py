"""Exported FMUs of 2-DOF, trimmed, piecewise-scheduled controllers: the FMU computes what the Python
controller computes (λ, u_eq, the 1-DOF and 2-DOF input), and connected to the ADIP plant FMU by an
importer that knows only the port names (plain fmpy, no lpvflow code in the loop) it reproduces the
Python closed loop of ``lpvflow verify`` to 1e-9."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from lpvflow.basis import Basis
from lpvflow.loop.fmu_controller import FmuController
from lpvflow.models import load
from lpvflow.pipeline.export import export_fmu, export_json, export_mat
from lpvflow.pipeline.ports import describe_signals
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.pipeline.verify import simulate_loop
from lpvflow.synth.controller import AntiWindup, LPVController, Trim, observer_gains
from lpvflow.synth.polytope import BoxPolytope, PiecewisePolytope, PointPolytope, Polytope
from tests.adip_cases import TS
from tests.test_antiwindup import upright_controller
from tests.test_export import ADIP, _adip_model

BREAKPOINTS = np.array([-0.6, 0.0, 0.6])  # sin(arm angle) at the three vertices
#: a trim table with kinks, of the gravity trim's sign but 1/14 of its size (−4.21·sin(arm) V,
#: fmu_plants/reference_models.py adip_equilibrium): u_eq(sin(arm)) is a feedback of the arm angle, and
#: the full one destabilizes the loop of a controller designed without it (upright_controller)
TRIM = Trim([-1.0, -0.25, 0.3, 1.0], [[0.3], [0.12], [-0.08], [-0.3]])
LIMITS = (-10.0, 10.0)
LOOP = Loop(("arm_angle", "pendulum_angle"), ("voltage",), ("sin(arm_angle)",),
            actuator_limits={"voltage": LIMITS})
#: the arm to −0.35 rad, then +0.5 rad: the scheduling crosses the middle breakpoint and the trim's kinks
SCENARIO = Scenario("-20° then +29°", 3.0,
                    reference={"arm_angle": Signal(initial=0.0, steps=((0.1, -0.35), (1.2, 0.85)))},
                    plant_parameters={"x0_pendulum_angle": 0.02}, settling_band={"arm_angle": 0.02})


def _piecewise() -> Polytope:
    return PiecewisePolytope(np.array([[BREAKPOINTS[0], BREAKPOINTS[-1]]]),
                             np.column_stack([np.ones(3), BREAKPOINTS]), breakpoints=BREAKPOINTS)


@functools.cache
def _upright() -> tuple[np.ndarray, ...]:
    """(A, B, C, D) of the 1-DOF H∞ controller at the ADIP's upright point (tests/test_antiwindup.py)."""
    K = upright_controller()
    return tuple(M[0] for M in (K.Ak, K.Bk, K.Ck, K.Dk))


def adip_controller(structure: str, trim: Trim | None = TRIM) -> LPVController:
    """The upright H∞ controller (w = r − y) on a three-vertex piecewise polytope, its feedback 5 % stronger
    at −0.6 and 4 % stronger at +0.6 (not affine in sin(arm): the segments matter); as 2-DOF also a
    reference gain that differs per vertex (0.9, 1, 0.95), so the reference and measurement columns are
    not opposite."""
    A, B, C, D = _upright()
    stack = lambda M: np.repeat(M[None], 3, axis=0)  # noqa: E731
    feedback = np.array([1.05, 1.0, 1.04])[:, None, None]
    Bk, Dk = stack(B), feedback * stack(D)
    if structure == "2dof":  # [r; y]: the reference columns scaled, the measurement columns −(e columns)
        reference = np.array([0.9, 1.0, 0.95])[:, None, None]
        Bk, Dk = np.concatenate([reference * Bk, -Bk], axis=2), np.concatenate([reference * Dk, -Dk], axis=2)
    controller = LPVController(stack(A), Bk, feedback * stack(C), Dk, _piecewise(),
                               Basis("affine", 1, p_min=(-0.6,), p_max=(0.6,)), TS, structure=structure,
                               trim=trim)
    controller.info["signals"] = describe_signals(_adip_model(), {"sin_arm": "sin(arm_angle)"}, ADIP)
    return controller


def fmu_open_loop(path: Path, w, p) -> np.ndarray:
    """The exported controller FMU's outputs for inputs w(k) at scheduling p(k), from reset."""
    fmu = FmuController(path)
    try:
        fmu.reset()
        return np.array([fmu.step(np.asarray(wk, dtype=float), np.atleast_1d(pk))
                         for wk, pk in zip(w, p, strict=True)])
    finally:
        fmu.close()


def controller_and_plant_slaves(controller_fmu: Path, plant_fmu: Path, plant_parameters: dict, tmp: Path
                                ) -> tuple[tuple[FMU2Slave, FMU2Slave], dict[str, dict[str, int]]]:
    """The controller FMU ("K") and the plant FMU ("G", ``plant_parameters`` set in initialisation) as
    initialised fmpy slaves, and each one's value references by variable name."""
    slaves, refs = [], {}
    for key, path in (("K", controller_fmu), ("G", plant_fmu)):
        description = read_model_description(str(path))
        refs[key] = {v.name: v.valueReference for v in description.modelVariables}
        slave = FMU2Slave(guid=description.guid, unzipDirectory=extract(str(path), str(tmp / key)),
                          modelIdentifier=description.coSimulation.modelIdentifier, instanceName=key)
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        if key == "G":
            for name, value in plant_parameters.items():
                slave.setReal([refs["G"][name]], [value])
        slave.exitInitializationMode()
        slaves.append(slave)
    return (slaves[0], slaves[1]), refs


def fmpy_closed_loop(controller_fmu: Path, plant_fmu: Path, scenario: Scenario, Ts: float, tmp: Path,
                     scheduling: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """An importer's loop with fmpy alone, wired by port names: per sample the plant's arm_angle and
    pendulum_angle go to the controller ports of the same names, the references to ``<output>_ref``,
    ``scheduling[name](arm_angle)`` to each scheduling port (default: sin(arm_angle) to ``sin_arm``); the
    controller's ``voltage``, clipped to ±10 V, drives the plant for one step. Returns the measured
    outputs (n, 2) and the applied voltage (n,)."""
    scheduling = {"sin_arm": np.sin} if scheduling is None else scheduling
    (K, G), refs = controller_and_plant_slaves(controller_fmu, plant_fmu, scenario.plant_parameters, tmp)
    n = round(scenario.duration / Ts)
    r = scenario.reference["arm_angle"].sample(np.arange(n) * Ts)
    outputs, applied = np.zeros((n, 2)), np.zeros(n)
    names = ("arm_angle", "pendulum_angle")
    t = 0.0
    for k in range(n):
        arm, pendulum = G.getReal([refs["G"][name] for name in names])
        outputs[k] = arm, pendulum
        K.setReal([refs["K"][name] for name in ("arm_angle_ref", "pendulum_angle_ref", *names, *scheduling)],
                  [r[k], 0.0, arm, pendulum, *(f(arm) for f in scheduling.values())])
        applied[k] = np.clip(K.getReal([refs["K"]["voltage"]])[0], *LIMITS)
        G.setReal([refs["G"]["voltage"]], [applied[k]])
        G.doStep(t, Ts)
        K.doStep(t, Ts)
        t += Ts
    for slave in (K, G):
        slave.terminate()
        slave.freeInstance()
    return outputs, applied


@pytest.mark.parametrize("structure", ["2dof", "1dof"])
def test_exported_fmu_with_the_plant_fmu_reproduces_the_python_closed_loop(structure: str, tmp_path: Path
                                                                           ) -> None:
    controller = adip_controller(structure)
    path = export_fmu(controller, tmp_path / f"K_{structure}.fmu")
    python = simulate_loop(controller, ADIP, SCENARIO, LOOP)
    assert python.failure is None
    p = python.scheduling[:, 0]
    assert p.min() < -0.2 and p.max() > 0.3  # λ moves across the middle breakpoint
    trim = np.array([controller.feedforward(pk)[0] for pk in python.scheduling])
    assert np.ptp(trim) > 0.25  # u_eq really varies along the run
    outputs, applied = fmpy_closed_loop(path, ADIP, SCENARIO, controller.Ts, tmp_path)
    difference = max(np.max(np.abs(outputs - python.outputs)), np.max(np.abs(applied - python.control[:, 0])))
    assert difference <= 1e-9, difference
    # verify's own FMU runner agrees as well
    fmu = FmuController(path)
    try:
        exported = simulate_loop(fmu, ADIP, SCENARIO, LOOP)
    finally:
        fmu.close()
    np.testing.assert_allclose(exported.outputs, python.outputs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(exported.control, python.control, rtol=0, atol=1e-9)


def test_the_2dof_and_trim_change_the_closed_loop() -> None:
    """The quantities compared above matter: without the trim, or as a 1-DOF law, the run differs."""
    runs = {key: simulate_loop(controller, ADIP, SCENARIO, LOOP).outputs
            for key, controller in (("2dof", adip_controller("2dof")), ("1dof", adip_controller("1dof")),
                                    ("no trim", adip_controller("2dof", trim=None)))}
    assert np.max(np.abs(runs["2dof"] - runs["1dof"])) > 1e-2
    assert np.max(np.abs(runs["2dof"] - runs["no trim"])) > 1e-2


def test_fmu_coordinates_are_the_python_hat_functions(tmp_path: Path) -> None:
    """A controller whose output i is λ_i(p)·w (no states; D_i = the i-th unit column) shows the FMU's λ."""
    N = 3
    controller = LPVController(np.zeros((N, 1, 1)), np.zeros((N, 1, 1)), np.zeros((N, N, 1)),
                               np.eye(N)[:, :, None], _piecewise(), Basis("affine", 1), 0.01)
    path = export_fmu(controller, tmp_path / "lam.fmu")
    p = np.concatenate([BREAKPOINTS, np.linspace(-1.0, 1.0, 57), [-0.3, 0.3]])
    lam_fmu = fmu_open_loop(path, [[1.0, 0.0]] * len(p), p)  # w = r − y = 1
    lam_python = np.array([controller.coordinates(np.array([pk])) for pk in p])
    np.testing.assert_allclose(lam_fmu, lam_python, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(lam_python[:3], np.eye(3))  # a vertex at each breakpoint
    assert np.all(np.count_nonzero(lam_python, axis=1) <= 2)


def test_fmu_trim_is_np_interp_in_and_outside_the_table(tmp_path: Path) -> None:
    trim = Trim([-0.5, 0.1, 0.4], [[1.0, -2.0], [3.0, 0.5], [-1.0, 0.0]])
    controller = LPVController(np.zeros((2, 1, 1)), np.zeros((2, 1, 1)), np.zeros((2, 2, 1)),
                               np.zeros((2, 2, 1)), BoxPolytope(np.array([[-1.0, 1.0]]),
                                                       np.array([[1.0, -1.0], [1.0, 1.0]])),
                               Basis("affine", 1), 0.01, trim=trim)
    path = export_fmu(controller, tmp_path / "trim.fmu")
    p = np.concatenate([trim.p, np.linspace(-1.0, 1.0, 41)])
    u_fmu = fmu_open_loop(path, np.zeros((len(p), 2)), p)
    expected = np.array([[np.interp(pk, trim.p, column) for column in trim.u.T] for pk in p])
    np.testing.assert_allclose(u_fmu, expected, rtol=0, atol=1e-15)


def test_2dof_fmu_ports_are_references_measurements_and_scheduling_with_units(tmp_path: Path) -> None:
    path = export_fmu(adip_controller("2dof"), tmp_path / "K.fmu")
    description = read_model_description(str(path))
    inputs = [(v.name, v.unit) for v in description.modelVariables if v.causality == "input"]
    assert inputs == [("arm_angle_ref", "rad"), ("pendulum_angle_ref", "rad"), ("arm_angle", "rad"),
                      ("pendulum_angle", "rad"), ("sin_arm", None)]
    outputs = [(v.name, v.unit) for v in description.modelVariables if v.causality == "output"]
    assert outputs == [("voltage", "V")]
    assert "2-DOF, controller input w = [y_ref − y_op; y − y_op]" in description.description
    assert "piecewise over sin_arm with breakpoints b = [-0.6, 0, 0.6]" in description.description
    assert "u_eq(sin_arm)" in description.description


def test_mat_and_json_carry_structure_trim_and_breakpoints(tmp_path: Path) -> None:
    controller = adip_controller("2dof")
    mat = scipy.io.loadmat(export_mat(controller, tmp_path / "K.mat"))
    assert str(mat["structure"][0]) == "2dof" and str(mat["polytope_kind"][0]) == "piecewise"
    np.testing.assert_array_equal(mat["trim_p"][0], TRIM.p)
    np.testing.assert_array_equal(mat["trim_u"], TRIM.u)
    np.testing.assert_array_equal(mat["breakpoints"][0], BREAKPOINTS)
    assert mat["Bk"].shape == (controller.order, 4, 3)  # n × 2·ny × N: [r; y]
    loaded = load(export_json(controller, tmp_path / "K.json"))
    assert loaded.structure == "2dof"
    np.testing.assert_array_equal(loaded.trim.u, TRIM.u)
    np.testing.assert_array_equal(loaded.polytope.breakpoints, BREAKPOINTS)
    p = np.array([0.37])
    np.testing.assert_array_equal(loaded.coordinates(p), controller.coordinates(p))


def test_fmu_antiwindup_sees_the_command_with_the_trim(tmp_path: Path) -> None:
    """2-DOF, piecewise, trim and anti-windup together, open loop: the state correction L(u_a − u) uses
    u = u_eq(p) + C x + D w in the FMU as in Python (the trim alone saturates the actuator at the ends)."""
    rng = np.random.default_rng(3)
    n, N = 3, 3
    trim = Trim([-0.6, 0.6], [[1.5, -0.4], [-1.5, 0.4]])
    A = 0.5 * rng.standard_normal((N, n, n)) / np.sqrt(n)
    controller = LPVController(A, rng.standard_normal((N, n, 4)), rng.standard_normal((N, 2, n)),
                               rng.standard_normal((N, 2, 4)), _piecewise(), Basis("affine", 1), 0.01,
                               structure="2dof", trim=trim)
    controller.antiwindup = AntiWindup(observer_gains(controller.Ak, controller.Ck), [-1.0, -1.0], [1.0, 1.0],
                                       [0.0, 0.0])
    path = export_fmu(controller, tmp_path / "aw.fmu")
    w, p = 0.3 * rng.standard_normal((300, 4)), rng.uniform(-0.9, 0.9, (300, 1))
    u_python = controller.simulate(w, p)
    u_fmu = fmu_open_loop(path, w, p)
    assert np.mean(np.abs(u_python) > 1.0) > 0.2  # the actuator saturates often
    np.testing.assert_allclose(u_fmu, u_python, rtol=0, atol=1e-9 * np.max(np.abs(u_python)))


def test_an_lti_baseline_on_a_point_polytope_exports_and_steps_like_python(tmp_path: Path) -> None:
    """The pipeline's LTI baseline (a "point" polytope), 2-DOF with a trim: the FMU is the Python law."""
    rng = np.random.default_rng(5)
    point = PointPolytope(np.array([[0.1, 0.1]]), np.array([[1.0, 0.1]]))
    controller = LPVController(0.3 * rng.standard_normal((1, 2, 2)), rng.standard_normal((1, 2, 2)),
                               rng.standard_normal((1, 1, 2)), rng.standard_normal((1, 1, 2)), point,
                               Basis("affine", 1), 0.01, structure="2dof",
                               trim=Trim([0.0, 1.0], [[0.0], [2.0]]))
    path = export_fmu(controller, tmp_path / "baseline.fmu")
    assert "LTI controller designed at p1 = 0.1" in read_model_description(str(path)).description
    w, p = rng.standard_normal((100, 2)), rng.uniform(-0.5, 1.5, (100, 1))
    u_python = controller.simulate(w, p)
    u_fmu = fmu_open_loop(path, w, p)
    np.testing.assert_allclose(u_fmu, u_python, rtol=0, atol=1e-12 * np.max(np.abs(u_python)))
