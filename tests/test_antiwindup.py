"""Anti-windup of the synthesized controller (issue 22, item 4): the observer-form law of
lpvflow.synth.controller, in Python, in lpvflow verify and in the exported FMU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.loop.fmu_controller import FmuController
from lpvflow.models import LPVSS, load
from lpvflow.pipeline.export import export_fmu
from lpvflow.pipeline.loop_metrics import run_metrics
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.pipeline.verify import simulate_loop
from lpvflow.synth.controller import AntiWindup, LPVController, observer_gains
from lpvflow.synth.hinf import synthesize
from lpvflow.synth.plant import generalized_plant
from lpvflow.synth.polytope import BoxPolytope
from tests.adip_cases import HINF_WEIGHTS, TS, rm
from tests.test_verify import _constant
from tests.test_verify import plants as plants  # the analytic plant FMUs (a pytest fixture)

ROOT = Path(__file__).resolve().parents[1]
ADIP = ROOT / "fmu_plants" / "build" / "adip.fmu"
VOLTS = 2.0  # actuator range ±2 V: a 20° arm step saturates it for a while
LOOP = Loop(("arm_angle", "pendulum_angle"), ("voltage",), ("sin(arm_angle)",),
            actuator_limits={"voltage": (-VOLTS, VOLTS)})
STEP = Scenario("20° step", 4.0, reference={"arm_angle": Signal(steps=((0.2, np.deg2rad(20.0)),))},
                settling_band={"arm_angle": np.deg2rad(1.0)}, output_bounds={"pendulum_angle": (-0.5, 0.5)})


def upright_controller() -> LPVController:
    """The H∞ controller at the upright point of the exact ADIP linearization with the H∞ weights of
    tests/adip_cases.py (W_B in series), as an LPVController on a one-point polytope."""
    import control

    a, b = rm.adip_linearization(0.0, rm.default_parameters("adip"))
    G = control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), TS, method="zoh")
    basis = Basis("affine", 1, p_min=(-0.5,), p_max=(0.5,))
    model = LPVSS(np.array([G.A, 0 * G.A]), np.array([G.B, 0 * G.B]), np.array([G.C, 0 * G.C]),
                  np.array([G.D, 0 * G.D]), basis, TS)
    point = synthesize(generalized_plant(model, HINF_WEIGHTS, [[0.0, 0.0]])).controller
    # the same controller at both vertices of a box: exportable (the FMU knows box polytopes)
    box = BoxPolytope(np.array([[-0.5, 0.5]]), np.array([[1.0, -0.5], [1.0, 0.5]]))
    return LPVController(*(np.repeat(M, 2, axis=0) for M in (point.Ak, point.Bk, point.Ck, point.Dk)), box,
                         basis, TS)


@pytest.fixture(scope="module")
def adip_controller() -> LPVController:
    return upright_controller()


def _with_antiwindup(K: LPVController, lo: float, hi: float) -> LPVController:
    out = load_copy(K)
    out.antiwindup = AntiWindup(observer_gains(K.Ak, K.Ck), [lo], [hi], [0.0])
    return out


def load_copy(K: LPVController) -> LPVController:
    return LPVController.from_dict(K.to_dict())


def test_observer_gains_stabilise_every_vertex(adip_controller: LPVController) -> None:
    L = observer_gains(adip_controller.Ak, adip_controller.Ck)
    for A, C, Li in zip(adip_controller.Ak, adip_controller.Ck, L, strict=True):
        assert np.max(np.abs(np.linalg.eigvals(A - Li @ C))) < 1.0


def test_observer_gains_stabilise_controllers_with_an_integrator_and_an_unstable_pole() -> None:
    """Random 20-state controllers like a loop-shaping one (a pole at z = 1, one at 1.03, a lightly damped
    pair at 0.994, the rest random inside the unit circle, a large output row; seed 3): every vertex
    observer A − LC is stable."""
    rng = np.random.default_rng(3)
    Ak, Ck = [], []
    for _ in range(4):
        poles = np.concatenate([[1.0, 1.03], rng.uniform(-0.9, 0.99, 16)])
        rotation = np.array([[np.cos(0.01), -np.sin(0.01)], [np.sin(0.01), np.cos(0.01)]])
        blocks = [np.diag(poles), 0.994 * rotation]
        T = rng.standard_normal((20, 20))
        Ak.append(np.linalg.solve(T, scipy.linalg.block_diag(*blocks) @ T))
        Ck.append(100 * rng.standard_normal((1, 20)))
    L = observer_gains(np.array(Ak), np.array(Ck))
    for A, C, Li in zip(Ak, Ck, L, strict=True):
        assert np.max(np.abs(np.linalg.eigvals(A - Li @ C))) < 1.0


def test_unsaturated_the_law_is_the_plain_one_and_saturated_it_is_the_observer_form(
        adip_controller: LPVController) -> None:
    rng = np.random.default_rng(0)
    e, p = 0.01 * rng.standard_normal((200, 2)), np.zeros((200, 1))
    plain, wide = load_copy(adip_controller), _with_antiwindup(adip_controller, -1e6, 1e6)
    np.testing.assert_array_equal(plain.simulate(e, p), wide.simulate(e, p))
    K = _with_antiwindup(adip_controller, -0.01, 0.01)
    K.reset(rng.standard_normal(K.order))
    x0, ek = K.x.copy(), np.array([0.3, -0.1])
    A, B, _, _ = K.matrices(np.zeros(1))
    u = K.step(ek, np.zeros(1))
    assert abs(u[0]) > 0.01  # saturated
    L = K.antiwindup.L[0]
    expected = A @ x0 + B @ ek + L @ (np.clip(u, -0.01, 0.01) - u)
    np.testing.assert_allclose(K.x, expected, rtol=1e-12, atol=1e-12)


def _pi(kp: float, ki: float) -> LPVController:
    """u = kp e + ki x, x⁺ = x + e: a PI law (integrator state) at both vertices of a box."""
    return _constant(1.0, 1.0, ki, kp)


def test_a_saturating_step_overshoots_less_with_antiwindup(plants: dict) -> None:
    """Classic windup on the analytic plant y⁺ = 0.8y + 0.5u with |u| ≤ 0.5 and a PI law: without
    anti-windup the integrator keeps growing while u is clipped and the step overshoots; with it the
    state follows the applied u. (The ADIP version is the next test: there saturation can only be
    short, or the pendulum is lost with or without anti-windup.)"""
    loop = Loop(("y",), ("u",), ("y",), actuator_limits={"u": (-0.5, 0.5)})
    scenario = Scenario("step", 3.0, reference={"y": Signal(steps=((0.1, 1.0),))})
    K = _pi(0.8, 0.3)
    with_aw = LPVController.from_dict(K.to_dict())
    with_aw.antiwindup = AntiWindup(observer_gains(K.Ak, K.Ck), [-0.5], [0.5], [0.0])
    metrics = {label: run_metrics(simulate_loop(law, plants[0.8], scenario, loop, label), scenario, loop)
               for label, law in (("plain", K), ("antiwindup", with_aw))}
    assert metrics["plain"]["controls"]["u"]["saturation_time"] > 0.1
    plain, aw = (metrics[k]["outputs"]["y"] for k in ("plain", "antiwindup"))
    assert plain["overshoot"] > aw["overshoot"] + 0.05, (plain, aw)


def test_on_the_adip_a_saturating_step_settles_sooner_and_swings_the_pendulum_less_with_antiwindup(
        adip_controller: LPVController) -> None:
    """A 20° arm step on the ADIP FMU with the voltage limited to ±1.5 V. Unsaturated, the step peaks at
    3.3 V in its first (non-minimum-phase) kick; at ±1.5 V the plain law is clipped for 0.13 s and its
    state integrates the unapplied voltage, with anti-windup the state follows the applied voltage and
    the command is back inside the limits after 0.015 s. Both keep the pendulum up (below about ±1.4 V
    both lose it: with 10–30° steps, every limit between 0.4 and 0.45 of the unsaturated peak and below
    saturated for 0.5–1.2 s and lost the pendulum). Measured: arm settling to ±1° 1.795 s plain, 1.68 s
    with anti-windup; pendulum peak 0.058 rad against 0.052 rad; the arm does not overshoot in either. (How
    much less the pendulum swings depends on the near-optimal controller the LMI solve returns: 0.066
    against 0.043 rad with the level SDPs solved to a duality gap of 1e-8 instead of 1e-12.)"""
    volts = 1.5
    loop = Loop(LOOP.measured, LOOP.actuated, LOOP.scheduling, actuator_limits={"voltage": (-volts, volts)})
    runs = {label: simulate_loop(law, ADIP, STEP, loop, label)
            for label, law in (("plain", load_copy(adip_controller)),
                               ("antiwindup", _with_antiwindup(adip_controller, -volts, volts)))}
    metrics = {label: run_metrics(run, STEP, loop) for label, run in runs.items()}
    assert all(m["stable"] for m in metrics.values()), {k: m["reason"] for k, m in metrics.items()}
    plain, aw = (metrics[k]["controls"]["voltage"]["saturation_time"] for k in ("plain", "antiwindup"))
    assert plain >= 0.1 and aw < plain / 2
    plain, aw = (metrics[k]["outputs"]["arm_angle"]["settling_time"] for k in ("plain", "antiwindup"))
    assert aw < plain - 0.08, (plain, aw)
    plain, aw = (np.max(np.abs(runs[k].outputs[:, 1])) for k in ("plain", "antiwindup"))
    assert aw < plain, (plain, aw)


def test_exported_fmu_applies_the_same_antiwindup_law(adip_controller: LPVController, tmp_path: Path) -> None:
    K = _with_antiwindup(adip_controller, -VOLTS, VOLTS)
    K.save(tmp_path / "k.json")
    assert load(tmp_path / "k.json").antiwindup is not None
    path = export_fmu(K, tmp_path / "k.fmu")
    python = simulate_loop(K, ADIP, STEP, LOOP)
    fmu = FmuController(path)
    try:
        exported = simulate_loop(fmu, ADIP, STEP, LOOP)
    finally:
        fmu.close()
    assert np.any(python.commanded != python.control)  # the run saturates
    np.testing.assert_allclose(exported.control, python.control, rtol=0, atol=1e-9)
    np.testing.assert_allclose(exported.outputs, python.outputs, rtol=0, atol=1e-9)
