"""Model-in-the-loop against plant-in-the-loop (lpvflow.validate.trajectory) on first-order plant FMUs whose
closed loops are known in closed form."""

from __future__ import annotations

from pathlib import Path

import control
import numpy as np
import pytest

from lpvflow.errors import ModelError
from lpvflow.loop.model_plant import ModelPlant
from lpvflow.models import LPVSS
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.validate.trajectory import trajectory_agreement
from tests.test_verify import BASIS, TS, B, _constant, _gain

LOOP = Loop(("y",), ("u",), ("y",))


@pytest.fixture(scope="module")
def plant_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """y(k+1) = y(k) + B u(k) (an integrator) as an FMU, built as tests/test_verify.py builds its plants."""
    from lpvflow.pipeline.export import export_fmu

    folder = tmp_path_factory.mktemp("trajectory")
    names = {"measured": ["u"], "scheduling": ["q"], "actuated": ["y"]}
    return export_fmu(_constant(1.0, -B, 1.0, 0.0), folder / "integrator.fmu", names)


def first_order_model(a0: float, a1: float = 0.0, b: float = B, d: float = 0.0) -> LPVSS:
    """x(k+1) = (a0 + a1 p) x + b u, y = x + d u, affine in one scheduling signal p."""
    return LPVSS(A=[[[a0]], [[a1]]], B=[[[b]], [[0.0]]], C=[[[1.0]], [[0.0]]], D=[[[d]], [[0.0]]],
                 basis=BASIS, Ts=TS, u_names=["u"], y_names=["y"], p_names=["q"])


def closed_loop(a: float, kp: float, r: np.ndarray) -> np.ndarray:
    """y(k+1) = a y(k) + B kp (r(k) − y(k)) from y(0) = 0."""
    y = np.zeros(len(r))
    for k in range(len(r) - 1):
        y[k + 1] = a * y[k] + B * kp * (r[k] - y[k])
    return y


# the loop takes the model's scheduling (its output) past the range [-1, 1] of BASIS: no range warning
@pytest.mark.filterwarnings("error::lpvflow.basis.SchedulingRangeWarning")
def test_an_exact_model_agrees_and_a_wrong_one_differs_as_the_closed_forms_do(plant_fmu: Path) -> None:
    kp = 3.0
    step = Scenario("step", 1.0, reference={"y": Signal(steps=((0.1, 1.0),))})
    r = step.reference["y"].sample(np.arange(round(1.0 / TS)) * TS)
    differences = {}
    for a_model in (1.0, 0.8, 0.95):
        [result] = trajectory_agreement(_gain(kp), plant_fmu, lambda a=a_model: ModelPlant(
            first_order_model(a), ["y"]), [step], LOOP)
        expected = np.max(np.abs(closed_loop(1.0, kp, r) - closed_loop(a_model, kp, r)))
        assert result.largest_difference["y"] == pytest.approx(expected, abs=1e-9)
        assert result.plant_failure is None and result.model_failure is None
        differences[a_model] = result.largest_difference["y"]
    assert differences[1.0] < 1e-9 and differences[0.95] > 0.05 and differences[0.8] > differences[0.95]


def test_model_plant_schedules_on_its_own_output_and_removes_the_trim() -> None:
    """x(k+1) = (0.5 + 0.4 p) x + B (u − 0.3 y) with p = y: the quasi-LPV recursion, step by step."""
    plant = ModelPlant(first_order_model(0.5, 0.4), ["y"], trim=lambda y: 0.3 * y)
    rng = np.random.default_rng(0)
    x = 0.0
    for u in rng.uniform(-0.5, 0.5, 50):
        assert plant.outputs()[0] == pytest.approx(x, abs=1e-12)
        plant.step(np.array([u]), 0.0, TS)
        x = (0.5 + 0.4 * x) * x + B * (u - 0.3 * x)
    assert plant.input_names == ["u"] and plant.output_names == ["y"]


@pytest.mark.parametrize("seed", range(4))
def test_model_plant_at_rest_holds_its_outputs_around_the_operating_point(seed: int) -> None:
    """A random stable two-state model affine in p = y, identified around (u₀, y₀) without the trim
    u_trim(y) = 0.3 y: after rest_at(y_r) it outputs y_r, and the constant input u₀ + u_trim(y_r) + v,
    v = (y_r − y₀)/G(1) with G(1) the frozen DC gain at p = y_r (python-control), keeps it there."""
    rng = np.random.default_rng(seed)
    A0 = rng.standard_normal((2, 2))
    A0 *= 0.7 / np.max(np.abs(np.linalg.eigvals(A0)))
    A = np.array([A0, 0.05 * rng.standard_normal((2, 2))])
    model = LPVSS(A=A, B=[rng.standard_normal((2, 1)), 0.1 * rng.standard_normal((2, 1))],
                  C=[rng.standard_normal((1, 2)), np.zeros((1, 2))], D=np.zeros((2, 1, 1)), basis=BASIS,
                  Ts=TS, u_names=["u"], y_names=["y"], p_names=["q"])
    u0, y0, y_r = rng.uniform(-0.5, 0.5, 3)
    plant = ModelPlant(model, ["y"], trim=lambda y: 0.3 * y, offsets={"u": [u0], "y": [y0]})
    assert plant.outputs()[0] == pytest.approx(y0, abs=1e-12)
    plant.rest_at({"y": y_r})
    v = (y_r - y0) / float(np.real(control.dcgain(model.frozen(np.array([y_r])))))
    for _ in range(30):
        assert plant.outputs()[0] == pytest.approx(y_r, abs=1e-9)
        plant.step(np.array([u0 + 0.3 * y_r + v]), 0.0, TS)
    plant.step(np.array([u0 + 0.3 * y_r + v + 0.1]), 0.0, TS)
    assert abs(plant.outputs()[0] - y_r) > 1e-6  # another input moves it


def test_model_plant_refuses_feedthrough_and_a_wrong_number_of_expressions() -> None:
    with pytest.raises(ModelError, match="feed-through"):
        ModelPlant(first_order_model(0.5, d=1.0), ["y"])
    with pytest.raises(ModelError, match="one scheduling expression each"):
        ModelPlant(first_order_model(0.5), ["y", "y"])
