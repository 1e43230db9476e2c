"""The signals a model is identified in (issue 24): inputs without the experiment controller's trim
(``[identify] remove_trim``), outputs through their increments (``[identify] increments``) integrated back
into the model, and the ν-gap gate taken with the trim's feedback moved from K_id to the plant."""

from __future__ import annotations

import json
from types import SimpleNamespace

import control
import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.identify.realize import integrate_outputs
from lpvflow.models import LPVSS
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.coordinates import model_coordinates
from lpvflow.pipeline.frozen_references import frozen_experiment_controller, trim_closed

NAMES = {"u_names": ["voltage"], "y_names": ["arm_angle", "pendulum_angle"], "p_names": ["p"]}


def _increments_model() -> LPVSS:
    """A random stable 3-state LPVSS, affine in one p, whose outputs are (arm increment, pendulum)."""
    rng = np.random.default_rng(3)
    A = 0.3 * rng.normal(size=(2, 3, 3))
    return LPVSS(A, rng.normal(size=(2, 3, 1)), rng.normal(size=(2, 2, 3)), rng.normal(size=(2, 2, 1)),
                 Basis.affine(1), 0.01, **NAMES)


def test_integrated_model_outputs_the_running_sum_of_the_increments():
    """y_arm(k) = Σ_{i ≤ k} w_arm(i) on a simulation with varying p; the pendulum row is unchanged; the
    frozen arm row is the increments' transfer function times 1/(1 − z⁻¹)."""
    w_model = _increments_model()
    model = integrate_outputs(w_model, ["arm_angle"])
    assert model.nx == 4 and model.y_names == ["arm_angle", "pendulum_angle"]
    rng = np.random.default_rng(4)
    u, p = rng.normal(size=(300, 1)), np.sin(np.arange(300) / 20)[:, None]
    w, y = w_model.simulate(u, p), model.simulate(u, p)
    np.testing.assert_allclose(y[:, 0], np.cumsum(w[:, 0]), atol=1e-10)
    np.testing.assert_allclose(y[:, 1], w[:, 1], atol=1e-12)
    z = np.exp(0.7j)
    G, W = model.frozen([0.4])(z), w_model.frozen([0.4])(z)
    np.testing.assert_allclose(G[0, 0], W[0, 0] / (1 - 1 / z), rtol=1e-10)
    with pytest.raises(ModelError, match=r"cannot integrate \['speed'\]"):
        integrate_outputs(w_model, ["speed"])


def _gridded_controller(path, scheduling: str) -> str:
    """A 1-state gridded controller reading (arm, pendulum), driving voltage, with the trim u_op(θ) = −2θ
    on the grid θ = −2, 0, 2 (held outside it) and gains that change with θ."""
    points = [{"A": [[0.5]], "B": [[1.0, 0.2 * g]], "C": [[0.3]], "D": [[-1.0 - 0.1 * g, 4.0]],
               "u_operating_point": [-2.0 * g]} for g in (-2.0, 0.0, 2.0)]
    doc = {"format": "lpvflow/gridded-controller", "version": 1, "Ts": 0.01,
           "inputs": ["arm_angle", "pendulum_angle"], "outputs": ["voltage"], "scheduling": scheduling,
           "grid": [-2.0, 0.0, 2.0], "points": points}
    path.write_text(json.dumps(doc))
    return str(path)


def _context(tmp_path, remove_trim: bool, increments: list[str], scheduling: str) -> StageContext:
    controller = _gridded_controller(tmp_path / "controller.json", scheduling)
    config = {"identify": {"remove_trim": remove_trim, "increments": increments},
              "experiment": {"controller": controller}}
    return StageContext(tmp_path, config)


def test_model_coordinates_remove_the_controllers_trim_and_take_increments(tmp_path):
    """θ = (arm + set-point)/2 from the recorded columns, clipped to the grid: the model input is
    voltage + 2·clip(θ, −2, 2); the arm becomes its increments (0 first), the pendulum stays."""
    arm = np.array([0.0, 0.5, 1.5, 3.0, 4.0, -5.0])
    setpoint = np.array([0.0, 0.5, 0.5, 3.0, 4.0, -1.0])
    voltage = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    pendulum = np.array([0.1, -0.1, 0.2, 0.0, 0.3, -0.2])
    columns = {"time": np.arange(6) * 0.01, "voltage": voltage, "arm_angle": arm, "pendulum_angle": pendulum,
               "arm_angle_setpoint": setpoint}
    np.savetxt(tmp_path / "data.csv", np.column_stack(list(columns.values())), delimiter=",",
               header=",".join(columns), comments="")
    data = Dataset(u=voltage[:, None], y=np.column_stack([arm, pendulum]), p=arm[:, None], Ts=0.01, **NAMES)
    ctx = _context(tmp_path, True, ["arm_angle"], "0.5*arm_angle + 0.5*arm_angle_setpoint")
    out = model_coordinates(ctx, data)
    theta = np.clip(0.5 * (arm + setpoint), -2, 2)
    np.testing.assert_allclose(out.u[:, 0], voltage + 2 * theta, atol=1e-12)
    np.testing.assert_allclose(out.y[:, 0], [0.0, 0.5, 1.0, 1.5, 1.0, -9.0], atol=1e-12)
    np.testing.assert_array_equal(out.y[:, 1], pendulum)
    np.testing.assert_array_equal(out.p, data.p)
    unchanged = model_coordinates(_context(tmp_path, False, [], "arm_angle"), data)
    np.testing.assert_array_equal(unchanged.u, data.u)
    np.testing.assert_array_equal(unchanged.y, data.y)
    with pytest.raises(DataError, match=r"increments \['speed'\] are not model outputs"):
        model_coordinates(_context(tmp_path, False, ["speed"], "arm_angle"), data)


def test_gate_moves_the_trims_feedback_from_the_controller_to_the_plant(tmp_path):
    """With remove_trim, K_id is the controller without its trim's feedback and the reference gets it:
    the loop (G closed by T, K_id bare) has the closed-loop poles of (G, K_id linearized with its trim),
    which the gate uses without remove_trim; T is the trim's slope, +2 V/rad on the arm (u = −T y)."""
    rng = np.random.default_rng(7)
    G = control.ss(np.diag([1.02, 0.9, 0.5]) + 0.05 * rng.normal(size=(3, 3)), rng.normal(size=(3, 1)),
                   rng.normal(size=(2, 3)), np.zeros((2, 1)), 0.01)
    model = SimpleNamespace(**NAMES)
    operating = SimpleNamespace(plant=SimpleNamespace(output_names=["pendulum_angle", "arm_angle"]),
                                equilibrium=lambda p: SimpleNamespace(y=np.array([0.0, p[0]])))
    reference = SimpleNamespace(reference=operating)

    def poles(plant, K):
        return np.sort_complex(np.linalg.eigvals(control.feedback(plant, K, sign=-1).A))

    K_trim, _, none = frozen_experiment_controller(_context(tmp_path, False, [], "arm_angle"), model,
                                                    reference)
    assert none is None
    K_bare, _, T = frozen_experiment_controller(_context(tmp_path, True, [], "arm_angle"), model, reference)
    for p in (np.array([-0.7]), np.array([1.3])):
        np.testing.assert_allclose(T(p), [[2.0, 0.0]], atol=1e-8)
        np.testing.assert_allclose(poles(trim_closed(lambda _: G, T)(p), K_bare(p)), poles(G, K_trim(p)),
                                   atol=1e-9)
        assert not np.allclose(K_bare(p).D, K_trim(p).D)
