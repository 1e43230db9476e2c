"""A 2-DOF controller reads the references and the measurements relative to the measured outputs'
operating point y_op (its port record): w = [r − y_op; y − y_op]. The Python controller
(:meth:`LPVController.input_of`), ``lpvflow verify``'s loop and the exported controller FMU apply the same
law, so a loop started at rest at a nonzero operating point stays there until the reference moves.

The plant is the maglev FMU at the thesis' operating point (lower disk 1.5 cm, upper disk 8 cm, held by
the exact equilibrium currents of fmu_plants/reference_models.py); the controller a decoupling PI law on
[r − y_op; y − y_op] whose reference gain differs from its feedback gain and varies over three breakpoints
of the upper disk position, so an operating point read as part of the reference would move the disks."""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np

from lpvflow.basis import Basis
from lpvflow.loop.fmu_controller import FmuController
from lpvflow.pipeline.export import export_fmu
from lpvflow.pipeline.ports import ControllerSignals, Port
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.pipeline.verify import simulate_loop
from lpvflow.synth.controller import LPVController
from lpvflow.synth.polytope import PiecewisePolytope
from tests.test_2dof_export import controller_and_plant_slaves

ROOT = Path(__file__).resolve().parents[1]
MAGLEV = ROOT / "fmu_plants" / "build" / "maglev.fmu"
sys.path.insert(0, str(ROOT / "fmu_plants"))
import reference_models as rm  # noqa: E402

TS = 0.002
MEASURED = ("lower_disk_position", "upper_disk_position")
ACTUATED = ("lower_coil_current", "upper_coil_current")
Y_OP = (0.015, 0.08)
BREAKPOINTS = np.array([0.075, 0.08, 0.086])
#: reference gain per breakpoint (the feedback gain is 1): 0.95 at the operating point, so an absolute
#: [r; y] would command Kp·M·(0.95 − 1)·y_op at t = 0 and integrate it
REFERENCE_GAIN = np.array([0.9, 0.95, 1.1])
STEP_AT = 0.5
SCENARIO = Scenario("upper disk 8 -> 8.2 cm", 1.5,
                    reference={"upper_disk_position": Signal(initial=Y_OP[1], steps=((STEP_AT, 0.002),))})


@functools.cache
def holding_currents() -> tuple[float, float]:
    """The currents that hold the disks at rest at Y_OP (fmu_plants/reference_models.py)."""
    currents = rm.maglev_equilibrium_currents(*Y_OP, rm.default_parameters("maglev"))
    return float(currents[0]), float(currents[1])


def loop() -> Loop:
    return Loop(MEASURED, ACTUATED, ("upper_disk_position",), u_operating_point=holding_currents(),
                y_operating_point=Y_OP,
                plant_parameters={"x0_lower_disk_position": Y_OP[0], "x0_upper_disk_position": Y_OP[1]})


def signals(y_op: tuple[float, ...], u_op: tuple[float, ...]) -> dict:
    """The port record of a controller reading the two disks at ``y_op`` and driving the coils at ``u_op``,
    scheduled on the upper disk position."""
    return ControllerSignals(
        tuple(Port(name, "m", operating_point=v) for name, v in zip(MEASURED, y_op, strict=True)),
        (Port("y2", "m", operating_point=y_op[1], expression="upper_disk_position"),),
        tuple(Port(name, "A", operating_point=v) for name, v in zip(ACTUATED, u_op, strict=True)),
    ).to_dict()


def pi_controller(y_op: tuple[float, ...] = Y_OP) -> LPVController:
    """x⁺ = x + Ts·(k_r(p) r̃ − ỹ), u = M (Ki x + Kp (k_r(p) r̃ − ỹ)) with r̃ = r − y_op, ỹ = y − y_op and
    M the inverse DC gain of the linearization at Y_OP: two decoupled PI loops (crossover ≈ Ki rad/s,
    below the plant's lightly damped modes at 17 and 43 rad/s)."""
    params = rm.default_parameters("maglev")
    x0, u0 = np.array([*Y_OP, 0.0, 0.0]), np.array(holding_currents())
    A, B = rm.jacobians(rm.maglev_derivatives, x0, u0, params)[:2]
    M = np.linalg.inv(-np.eye(2, 4) @ np.linalg.solve(A, B))
    Ki, Kp = 2.0, 0.05
    Bk = np.array([TS * np.hstack([k * np.eye(2), -np.eye(2)]) for k in REFERENCE_GAIN])
    Dk = np.array([Kp * M @ np.hstack([k * np.eye(2), -np.eye(2)]) for k in REFERENCE_GAIN])
    N = len(BREAKPOINTS)
    polytope = PiecewisePolytope(BREAKPOINTS[[0, -1]][None], np.column_stack([np.ones(N), BREAKPOINTS]),
                                 breakpoints=BREAKPOINTS)
    controller = LPVController(np.repeat(np.eye(2)[None], N, axis=0), Bk,
                               np.repeat((Ki * M)[None], N, axis=0), Dk, polytope,
                               Basis("affine", 1, p_min=(0.07,), p_max=(0.09,)), TS, structure="2dof")
    controller.info["signals"] = signals(y_op, holding_currents())
    return controller


def fmpy_closed_loop(controller_fmu: Path, tmp: Path) -> tuple[np.ndarray, np.ndarray]:
    """An importer's loop with fmpy alone, wired by port names: the disk positions go to the controller's
    ports of the same names (absolute, in m), the references to ``<output>_ref``, the upper disk position
    to the scheduling port ``y2``; the controller's coil currents drive the plant for one step. Returns
    the measured positions (n, 2) and the currents (n, 2)."""
    (K, G), refs = controller_and_plant_slaves(controller_fmu, MAGLEV, loop().plant_parameters, tmp)
    n = round(SCENARIO.duration / TS)
    t_k = np.arange(n) * TS
    r = np.column_stack([np.full(n, Y_OP[0]), SCENARIO.reference["upper_disk_position"].sample(t_k)])
    outputs, currents = np.zeros((n, 2)), np.zeros((n, 2))
    t = 0.0
    for k in range(n):
        outputs[k] = G.getReal([refs["G"][name] for name in MEASURED])
        K.setReal([refs["K"][name] for name in (*(f"{m}_ref" for m in MEASURED), *MEASURED, "y2")],
                  [*r[k], *outputs[k], outputs[k, 1]])
        currents[k] = K.getReal([refs["K"][name] for name in ACTUATED])
        G.setReal([refs["G"][name] for name in ACTUATED], list(currents[k]))
        G.doStep(t, TS)
        K.doStep(t, TS)
        t += TS
    for slave in (K, G):
        slave.terminate()
        slave.freeInstance()
    return outputs, currents


def test_2dof_loop_at_a_nonzero_operating_point_starts_at_rest_and_the_fmu_agrees(tmp_path: Path) -> None:
    controller = pi_controller()
    python = simulate_loop(controller, MAGLEV, SCENARIO, loop())
    assert python.failure is None
    before = python.time < STEP_AT
    # at rest at the operating point until the reference moves: no transient at t = 0
    assert np.max(np.abs(python.outputs[before] - Y_OP)) < 1e-9
    assert np.max(np.abs(python.control[before] - holding_currents())) < 1e-9
    # the controller acts on the step: the upper disk moves most of the 2 mm by the end
    assert python.outputs[-1, 1] - Y_OP[1] > 0.0015
    path = export_fmu(controller, tmp_path / "K.fmu")
    outputs, currents = fmpy_closed_loop(path, tmp_path)
    difference = max(np.max(np.abs(outputs - python.outputs)), np.max(np.abs(currents - python.control)))
    assert difference <= 1e-9, difference
    fmu = FmuController(path)  # verify's own runner of the exported FMU
    try:
        exported = simulate_loop(fmu, MAGLEV, SCENARIO, loop())
    finally:
        fmu.close()
    np.testing.assert_allclose(exported.outputs, python.outputs, rtol=0, atol=1e-9)


def test_the_operating_point_matters_in_this_loop() -> None:
    """The same controller recorded at y_op = 0 (it then reads the absolute positions) leaves the rest
    state at t = 0: the check above can fail."""
    python = simulate_loop(pi_controller(y_op=(0.0, 0.0)), MAGLEV, SCENARIO, loop())
    before = python.time < STEP_AT
    assert np.max(np.abs(python.control[before] - holding_currents())) > 1e-3


def test_input_of_and_the_fmu_take_the_operating_point_off_random_2dof_controllers(tmp_path: Path) -> None:
    """Random 2-DOF controllers and operating points (seeded): w = [r − y_op; y − y_op]; the exported FMU,
    handed absolute r and y, returns what the Python controller does; a 1-DOF input is r − y whatever
    y_op."""
    rng = np.random.default_rng(36)
    for case in range(2):
        n, N = 3, len(BREAKPOINTS)
        y_op = tuple(rng.uniform(-1.0, 1.0, 2))
        u_op = tuple(rng.uniform(-1.0, 1.0, 2))
        polytope = PiecewisePolytope(BREAKPOINTS[[0, -1]][None], np.column_stack([np.ones(N), BREAKPOINTS]),
                                     breakpoints=BREAKPOINTS)
        controller = LPVController(0.5 * rng.standard_normal((N, n, n)) / np.sqrt(n),
                                   rng.standard_normal((N, n, 4)), rng.standard_normal((N, 2, n)),
                                   rng.standard_normal((N, 2, 4)), polytope, Basis("affine", 1), TS,
                                   structure="2dof")
        controller.info["signals"] = signals(y_op, u_op)
        r, y = rng.standard_normal((40, 2)), rng.standard_normal((40, 2))
        p = rng.uniform(0.07, 0.09, (40, 1))
        np.testing.assert_array_equal(controller.input_of(r[0], y[0]),
                                      np.concatenate([r[0], y[0]]) - np.tile(y_op, 2))
        expected = np.array([controller.step(controller.input_of(rk, yk), pk)
                             for rk, yk, pk in zip(r, y, p, strict=True)])
        fmu = FmuController(export_fmu(controller, tmp_path / f"K{case}.fmu"))
        try:
            fmu.reset()
            u_fmu = np.array([fmu.step(fmu.input_of(rk, yk), pk) for rk, yk, pk in zip(r, y, p, strict=True)])
        finally:
            fmu.close()
        np.testing.assert_allclose(u_fmu, expected + u_op, rtol=0, atol=1e-12)
        one = LPVController(controller.Ak, controller.Bk[:, :, :2], controller.Ck, controller.Dk[:, :, :2],
                            polytope, Basis("affine", 1), TS, info={"signals": signals(y_op, u_op)})
        np.testing.assert_array_equal(one.input_of(r[0], y[0]), r[0] - y[0])
