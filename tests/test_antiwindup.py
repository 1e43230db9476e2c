"""Anti-windup of the synthesized controller (issue 22, item 4): the observer-form law of
lpvflow.synth.controller, in Python, in lpvflow verify and in the exported FMU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.models import LPVSS, load
from lpvflow.pipeline.export import export_fmu
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.pipeline.verify import FmuController, run_metrics, simulate_loop
from lpvflow.synth.controller import AntiWindup, LPVController, observer_gains
from lpvflow.synth.hinf import synthesize
from lpvflow.synth.plant import generalized_plant
from lpvflow.synth.polytope import Polytope
from tests.adip_cases import TS, bundled_weights, rm
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
    """The H∞ controller at the upright point of the exact ADIP linearization with the bundled weights
    (W_B in series), as an LPVController on a one-point polytope."""
    import control

    a, b = rm.adip_linearization(0.0, rm.default_parameters("adip"))
    G = control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), TS, method="zoh")
    basis = Basis("affine", 1, p_min=(-0.5,), p_max=(0.5,))
    model = LPVSS(np.array([G.A, 0 * G.A]), np.array([G.B, 0 * G.B]), np.array([G.C, 0 * G.C]),
                  np.array([G.D, 0 * G.D]), basis, TS)
    point = synthesize(generalized_plant(model, bundled_weights(), [[0.0, 0.0]])).controller
    # the same controller at both vertices of a box: exportable (the FMU knows box polytopes)
    box = Polytope("box", np.array([[-0.5, 0.5]]), np.array([[1.0, -0.5], [1.0, 0.5]]))
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
    state follows the applied u. (On the ADIP FMU every scenario tried where the voltage saturates for
    more than ~0.1 s loses the pendulum with or without anti-windup: ±1–5 V limits with 20–60° steps,
    3–8 V input disturbances; anti-windup delayed the loss by 0.1–0.5 s, which shows the law acts, not
    that it rescues an unstable plant with too little actuator authority.)"""
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
