"""The closed-loop output-error refinement (:mod:`lpvflow.identify.closed_loop_oe`) on random LPV-ARX plants
(fixed seeds) in a closed loop with an LTI controller: with output noise (the controller reads the noisy
output, so the least-squares estimate is biased) the refinement lowers the criterion and the in-loop
simulation error below the least-squares start, and its equation-error term stays below the whole
criterion at the start (the bound the descent itself gives); on noise-free data from a model in the class
(the least-squares estimate is the truth) it stays at the truth."""

from __future__ import annotations

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.controller import LtiController
from lpvflow.identify.arx import identify_arx, prediction_residuals
from lpvflow.identify.closed_loop_oe import LoopRecord, refine_closed_loop_oe
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import Loop

N = 1500
TS = 0.01


def random_plant(rng: np.random.Generator) -> LPVIO:
    """y(k) = −a1(p) y(k−1) − a2(p) y(k−2) + b1(p) u(k−1) + b2(p) u(k−2), affine in one p ∈ [−1, 1], every
    frozen model stable (poles of radius ≤ 0.85)."""
    radius, angle = rng.uniform(0.5, 0.7), rng.uniform(0.2, 1.0)
    A = np.zeros((2, 2, 1, 1))
    A[0, 0], A[1, 0] = -2 * radius * np.cos(angle), radius ** 2
    A[0, 1], A[1, 1] = rng.uniform(-0.1, 0.1), rng.uniform(-0.05, 0.05)
    B = np.zeros((3, 2, 1, 1))
    B[1:, 0, 0, 0] = rng.uniform(0.2, 0.5, 2)
    B[1:, 1, 0, 0] = rng.uniform(-0.1, 0.1, 2)
    return LPVIO(A, B, Basis("affine", 1), TS, na=np.array([[2]]), nb=np.array([[2]]), nk=np.array([[1]]),
                 u_names=["u"], y_names=["y"], p_names=["p"])


def controller() -> LtiController:
    """A lag controller on y − 0 (integrator-like state, small gain)."""
    return LtiController(A=np.array([[0.95]]), B=np.array([[-0.05]]), C=np.array([[1.0]]),
                         D=np.array([[-0.3]]), Ts=TS, inputs=("y",), outputs=("u",), y_op=np.zeros(1),
                         u_op=np.zeros(1))


def closed_loop_record(plant: LPVIO, rng: np.random.Generator, noise: float,
                       increments: bool = False) -> Dataset:
    """The plant under :func:`controller` reading y + e (e white, ``noise`` std), r a random multistep on the
    controller output, p a slow random signal; the record holds the measured y + e. With ``increments``
    the LPV-ARX gives the increments of the output, the plant's output is their sum."""
    K = controller()
    p = np.clip(np.cumsum(rng.normal(0, 0.05, N)), -1, 1)[:, None]
    r = np.repeat(rng.normal(0, 1.0, N // 20), 20)
    psi = plant.basis.eval(p, check_range=False)
    y, u, measured, plant_y = np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N)
    x = np.zeros(1)
    for k in range(N):
        acc = 0.0
        for i in (1, 2):
            if k >= i:
                acc -= psi[k - i] @ plant.A[i - 1, :, 0, 0] * y[k - i]
                acc += psi[k - i] @ plant.B[i, :, 0, 0] * u[k - i]
        y[k] = acc
        plant_y[k] = (plant_y[k - 1] if k else 0.0) + acc if increments else acc
        measured[k] = plant_y[k] + noise * rng.standard_normal()
        u[k] = (K.C @ x + K.D @ measured[k:k + 1])[0] + r[k]
        x = K.A @ x + K.B @ measured[k:k + 1]
    return Dataset(u[:, None], measured[:, None], p, TS, ["u"], ["y"], ["p"])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_refinement_lowers_the_criterion_and_the_loop_error(seed: int) -> None:
    rng = np.random.default_rng(3600 + seed)
    data = closed_loop_record(random_plant(rng), rng, noise=0.05)
    ls = identify_arx(data, 2, 2, 1, "affine")
    loop = Loop.from_record(data, controller())
    result = refine_closed_loop_oe(ls, [data], [LoopRecord(data, loop)], np.array([0.05]), iterations=5)
    assert result.cost_end < result.cost_start
    assert np.all(result.simulation_rms_end < result.simulation_rms_start)
    sigma = result.equation_rms_start
    e_end = prediction_residuals(result.model, data)
    assert np.sum((e_end / sigma) ** 2) <= result.cost_start  # each term ≤ the criterion at the start
    assert np.allclose(result.equation_rms_end, np.sqrt(np.mean(e_end ** 2, axis=0)))


@pytest.mark.parametrize("seed", [4, 5])
def test_refinement_of_noise_free_data_stays_at_the_truth(seed: int) -> None:
    rng = np.random.default_rng(3600 + seed)
    plant = random_plant(rng)
    data = closed_loop_record(plant, rng, noise=0.0)
    ls = identify_arx(data, 2, 2, 1, "affine")
    np.testing.assert_allclose(ls.A, plant.A, atol=1e-8)
    result = refine_closed_loop_oe(ls, [data], [LoopRecord(data, Loop.from_record(data, controller()))],
                                   np.array([0.05]), iterations=3)
    scale = max(np.abs(plant.A).max(), np.abs(plant.B).max())
    np.testing.assert_allclose(result.model.A, plant.A, atol=1e-6 * scale)
    np.testing.assert_allclose(result.model.B, plant.B, atol=1e-6 * scale)
    assert np.all(result.simulation_rms_end < 1e-6 * np.std(data.y))


def test_an_increments_model_runs_summed_in_the_loop() -> None:
    """A model of the output's increments (``[identify] increments``), identified exactly from noise-free
    increments, simulated with ``integrated`` reproduces the plant's output in the loop, and the refinement
    keeps it."""
    rng = np.random.default_rng(3606)
    plant = random_plant(rng)
    data = closed_loop_record(plant, rng, noise=0.0, increments=True)
    steps = Dataset(data.u, np.diff(data.y, axis=0, prepend=0.0), data.p, TS, ["u"], ["y"], ["p"])
    ls = identify_arx(steps, 2, 2, 1, "affine")
    np.testing.assert_allclose(ls.A, plant.A, atol=1e-8)
    result = refine_closed_loop_oe(ls, [steps], [LoopRecord(data, Loop.from_record(data, controller()))],
                                   np.array([0.05]), iterations=2, integrated=("y",))
    assert np.all(result.simulation_rms_start < 1e-8 * np.std(data.y))
    np.testing.assert_allclose(result.model.B, plant.B, atol=1e-6 * np.abs(plant.B).max())


def test_bad_scales_are_one_error() -> None:
    rng = np.random.default_rng(3607)
    data = closed_loop_record(random_plant(rng), rng, noise=0.05)
    ls = identify_arx(data, 2, 2, 1, "affine")
    with pytest.raises(DataError, match="one positive scale per output"):
        refine_closed_loop_oe(ls, [data], [LoopRecord(data, Loop.from_record(data, controller()))],
                              np.array([0.05, 1.0]), iterations=5)


@pytest.mark.parametrize(("change", "message"), [
    ({"identify": {"method": "pbsid"}}, 'use method = "lpr-arx"'),
    ({"experiment": {"controller": None}}, "no \\[experiment\\] controller"),
    ({"identify": {"refine_scales": {"arm": 0.03}}}, "refine_scales lacks \\['tip'\\]"),
    ({"identify": {"remove_offsets": True}}, "remove_offsets"),
])
def test_a_refine_key_without_what_it_needs_is_one_error(change: dict, message: str) -> None:
    from lpvflow.pipeline.refine import check_refine

    config = {"identify": {"refine": "closed-loop-oe", "method": "lpr-arx", "y": ["arm", "tip"],
                           "refine_scales": {"arm": 0.03, "tip": 0.02}, "remove_offsets": False},
              "experiment": {"controller": "K.json"}}
    check_refine(config)
    for table, keys in change.items():
        config[table] = {**config[table], **keys}
    with pytest.raises(DataError, match=message):
        check_refine(config)
