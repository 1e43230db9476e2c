"""LPVLFR: closed-loop matrices (seed 003 eq. (3)), simulation, frozen models, well-posedness, files."""

import control
import numpy as np
import pytest

import lpvflow
from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.lfr import LPVLFR, require_affine
from lpvflow.models import LPVSS


def example_lfr(d11: float = -0.5) -> LPVLFR:
    """Seed 003 system (26) with Δ(p) = p on p ∈ [−1, 1]."""
    basis = Basis.affine(1).with_range(np.array([[-1.0], [1.0]]))
    return LPVLFR([[0, 1], [-0.1, 0.7]], [[0], [0.816]], [[1.073], [1.075]], [[0.524, -0.625]], [[d11]],
                  [[0.5]], [[0.443, 0.060]], [[0.5]], [[0.5]], np.array([[[0.0]], [[1.0]]]), basis, 0.1)


def test_closed_loop_matrices_match_the_explicit_rational_form():
    # notes_003 §4.2: with g(p) = p / (1 + 0.5 p) the closed loop is written out by hand
    model = example_lfr()
    for p in (-1.0, -0.3, 0.0, 0.7, 1.0):
        g = p / (1 + 0.5 * p)
        A, B, C, D = model.matrices([p])
        np.testing.assert_allclose(A, [[0, 1], [-0.1 + 0.427584 * g, 0.7 - 0.51 * g]], atol=1e-12)
        np.testing.assert_allclose(B, [[1.073], [1.075 + 0.408 * g]], atol=1e-12)
        np.testing.assert_allclose(C, [[0.443 + 0.262 * g, 0.060 - 0.3125 * g]], atol=1e-12)
        np.testing.assert_allclose(D, [[0.5 + 0.25 * g]], atol=1e-12)


def test_simulation_solves_the_feedback_loop_at_every_sample():
    model = example_lfr()
    rng = np.random.default_rng(1)
    u, p = rng.uniform(-1, 1, (50, 1)), rng.uniform(-1, 1, (50, 1))
    y, x = model.simulate(u, p, return_states=True)
    xk = np.zeros(2)
    for k in range(50):  # solve the LTI block equations with w = p z for (z, w) directly
        z = np.linalg.solve(np.eye(1) - model.D11 * p[k, 0], model.C1 @ xk + model.D12 @ u[k])
        w = p[k, 0] * z
        np.testing.assert_allclose(y[k], model.C2 @ xk + model.D21 @ w + model.D22 @ u[k], atol=1e-12)
        xk = model.A @ xk + model.B1 @ w + model.B2 @ u[k]
        np.testing.assert_allclose(x[k + 1], xk, atol=1e-12)


def test_frozen_model_is_a_discrete_statespace_with_the_loop_closed():
    model = example_lfr()
    sys = model.frozen([0.4])
    assert isinstance(sys, control.StateSpace) and sys.dt == model.Ts
    for frozen_matrix, direct in zip((sys.A, sys.B, sys.C, sys.D), model.matrices([0.4]), strict=True):
        np.testing.assert_allclose(frozen_matrix, direct)
    # the frozen model's DC gain equals the steady state of the closed LFR at constant p
    y = model.simulate(np.ones((400, 1)), np.full((400, 1), 0.4))
    np.testing.assert_allclose(y[-1, 0], control.dcgain(sys), rtol=1e-6)


def test_affine_lfr_converts_exactly_and_rational_one_is_refused():
    affine = example_lfr(0.0)
    ss = affine.to_lpvss()
    rng = np.random.default_rng(2)
    u, p = rng.uniform(-1, 1, (80, 1)), rng.uniform(-1, 1, (80, 1))
    np.testing.assert_allclose(ss.simulate(u, p), affine.simulate(u, p), atol=1e-12)
    with pytest.raises(ModelError, match="rational dependence"):
        example_lfr(-0.5).to_lpvss()


def test_require_affine_refuses_a_rational_lfr_with_one_clear_line():
    with pytest.raises(ModelError) as err:
        require_affine(example_lfr(-0.5))
    message = str(err.value)
    assert message.startswith("polytopic synthesis needs affine dependence; this is an LFR with rational "
                              "dependence") and "\n" not in message
    assert isinstance(require_affine(example_lfr(0.0)), LPVSS)
    ss = example_lfr(0.0).to_lpvss()
    assert require_affine(ss) is ss


def test_well_posedness_failure_names_the_point_inside_the_box():
    model = example_lfr(-0.9)  # 1 + 0.9 p = 0 at p = −1.111…
    model.check_well_posed(box=[[-1.0, 1.0]])  # fine on the recorded box
    with pytest.raises(ModelError, match=r"not well posed in the scheduling box near p = \[-1\.1"):
        model.check_well_posed(box=[[-1.2, 1.2]])  # the grid steps over the singular point
    exact = example_lfr(-1.0)  # singular exactly at the grid point p = −1
    with pytest.raises(ModelError, match=r"at p = \[-1\.0\]"):
        exact.check_well_posed()
    with pytest.raises(ModelError, match="not well posed at sample 3"):
        exact.simulate(np.zeros((5, 1)), np.array([[0.0], [0.5], [0.2], [-1.0], [0.0]]))


def test_save_and_load_round_trip(tmp_path):
    model = example_lfr()
    path = tmp_path / "lfr.json"
    model.save(path)
    loaded = lpvflow.load(path)
    assert isinstance(loaded, LPVLFR)
    rng = np.random.default_rng(3)
    u, p = rng.uniform(-1, 1, (30, 1)), rng.uniform(-1, 1, (30, 1))
    np.testing.assert_array_equal(loaded.simulate(u, p), model.simulate(u, p))
    d = model.to_dict() | {"version": 99}
    with pytest.raises(ModelError, match="version 99 is not supported"):
        LPVLFR.from_dict(d)


def test_bad_shapes_are_refused():
    with pytest.raises(ModelError, match=r"LPVLFR B1 has shape \(2, 1\); expected \(2, 2\)"):
        LPVLFR(np.eye(2), np.zeros((2, 1)), np.zeros((2, 1)), np.zeros((1, 2)), np.zeros((2, 2)),
               np.zeros((1, 1)), np.zeros((1, 2)), np.zeros((1, 1)), np.zeros((1, 1)),
               np.zeros((2, 1, 1)), Basis.affine(1), 1.0)


def test_frozen_lfr_models_go_through_the_nu_gap_validation():
    from lpvflow.validate.nugap import nugap

    rational, affine = example_lfr(-0.5), example_lfr(0.0)
    assert nugap(rational.frozen([0.5]), rational.frozen([0.5])).value < 1e-6
    # at p = 0 the loop is open (Δ = 0) and D11 does not matter; elsewhere it does
    assert nugap(rational.frozen([0.0]), affine.frozen([0.0])).value < 1e-6
    assert nugap(rational.frozen([0.9]), affine.frozen([0.9])).value > 0.01
