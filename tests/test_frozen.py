"""Frozen-point grid over the scheduling box and the frozen ν-gap / b(P, K) table."""

import control as ct
import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.validate.frozen import compare_frozen, frozen_grid, scheduling_grid
from lpvflow.validate.margins import stability_margin
from lpvflow.validate.nugap import nugap

Ts = 0.1


def lpv_model(n_p=1, shift=0.0):
    """Two-state LPV model: A(p) = A0 + Σ p_j A_j, stable over the box [-1, 1]^n_p."""
    basis = Basis(kind="affine", n_p=n_p, p_min=(-1.0,) * n_p, p_max=(1.0,) * n_p)
    A = [np.array([[0.6, 0.2], [-0.1, 0.5]])] + [np.array([[0.1 + shift, 0.0], [0.0, -0.1]])] * n_p
    B = [np.array([[1.0], [0.5]])] + [np.array([[0.2], [0.0]])] * n_p
    C = [np.array([[1.0, 0.0]])] + [np.zeros((1, 2))] * n_p
    D = [np.zeros((1, 1))] * (n_p + 1)
    return LPVSS(A=np.stack(A), B=np.stack(B), C=np.stack(C), D=np.stack(D), basis=basis, Ts=Ts)


def test_grid_tags_vertices_edges_and_interior():
    grid = scheduling_grid([[-1, 1], [0, 2]], 3)
    kinds = [kind for _, kind in grid]
    assert len(grid) == 9
    assert kinds.count("vertex") == 4 and kinds.count("edge") == 4 and kinds.count("interior") == 1
    assert {tuple(p) for p, kind in grid if kind == "vertex"} == {(-1, 0), (-1, 2), (1, 0), (1, 2)}
    one = scheduling_grid([-1, 1], 4)
    assert [kind for _, kind in one] == ["vertex", "interior", "interior", "vertex"]


def test_frozen_models_are_the_affine_combination_at_each_point():
    model = lpv_model(n_p=2)
    points = frozen_grid(model, 3)
    assert len(points) == 9
    for point in points:
        expected_A = model.A[0] + point.p[0] * model.A[1] + point.p[1] * model.A[2]
        assert np.allclose(point.system.A, expected_A)
        assert point.system.dt == Ts


def test_model_against_itself_has_zero_gap_and_passes():
    model = lpv_model()
    rows = compare_frozen(model, model, 5, controller=ct.ss([], [], [], [[0.3]], Ts))
    assert len(rows) == 5
    for row in rows:
        assert row["nugap"] < 1e-12 and row["winding_condition_held"]
        assert 0 < row["stability_margin_b"] <= 1 and row["passes"]
        assert row["margins"]["stability_margin_b"] == pytest.approx(row["stability_margin_b"])


def test_gap_table_matches_direct_nugap_and_flags_far_points():
    model, reference = lpv_model(), lpv_model(shift=0.35)  # grows apart as |p| grows
    rows = compare_frozen(model, reference, 5, controller=ct.ss([], [], [], [[0.3]], Ts))
    for row in rows:
        direct = nugap(reference.frozen(np.array(row["p"])), model.frozen(np.array(row["p"])))
        assert row["nugap"] == pytest.approx(direct.value, abs=1e-12)
    centre = next(r for r in rows if r["p"] == [0.0])
    assert centre["nugap"] < 1e-12 and centre["passes"]
    assert max(r["nugap"] for r in rows) > 0.05


def test_reference_can_be_a_callable_of_local_models():
    model = lpv_model()
    local = {-1.0: model.frozen(np.array([-1.0])), 1.0: model.frozen(np.array([1.0]))}
    rows = compare_frozen(model, lambda p: local[float(p[0])], 2)
    assert [r["nugap"] for r in rows] == [0.0, 0.0]


def test_bad_box_and_grid_size_raise_model_error():
    with pytest.raises(ModelError, match="min < max"):
        scheduling_grid([[1.0, -1.0]], 3)
    with pytest.raises(ModelError, match="at least 2 points"):
        scheduling_grid([[0.0, 1.0]], 1)
    with pytest.raises(ModelError, match="reference"):
        compare_frozen(lpv_model(), "not a model", 2)


def test_without_reference_rows_carry_margins_only():
    model = lpv_model()
    K = ct.ss([], [], [], [[0.3]], Ts)
    rows = compare_frozen(model, None, 3, controller=K)
    for row in rows:
        assert "nugap" not in row and "passes" not in row
        system = model.frozen(np.array(row["p"]))
        assert row["stability_margin_b"] == pytest.approx(stability_margin(system, K))
        assert row["margins"]["disk_margin"] > 0


def test_a_model_with_a_hidden_integrator_is_refused_naming_the_point():
    """A model whose pole at z = 1 the input cannot move (PBH) breaks the ν-gap's winding count; the
    error names the scheduling point and which system (the model, P2) it is, in one line."""
    rng = np.random.default_rng(5)
    a = rng.uniform(0.2, 0.8)
    A = np.stack([np.diag([1.0, a]), np.zeros((2, 2))])
    B = np.stack([[[0.0], [1.0]], np.zeros((2, 1))])
    C = np.stack([[[1.0, 1.0]], np.zeros((1, 2))])
    D = np.zeros((2, 1, 1))
    model = LPVSS(A, B, C, D, Basis("affine", 1, p_min=(0.0,), p_max=(1.0,)), 0.1)
    reference = ct.ss([[a]], [[1.0]], [[1.0]], [[0.0]], 0.1)
    with pytest.raises(ModelError) as err:
        compare_frozen(model, reference, 3)
    assert "scheduling point [0.0]" in str(err.value) and "P2 the model" in str(err.value)
    assert "uncontrollable or unobservable" in str(err.value) and "\n" not in str(err.value)
