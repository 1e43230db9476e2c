"""Polytope of an LPVSS: convex coordinates reproduce ψ(p) and the vertex systems interpolate the model."""

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.models import LPVSS
from lpvflow.synth.polytope import polytope_of, vertex_matrices
from lpvflow.synth.weights import siso_weight


def _model(basis: Basis, seed: int = 0) -> LPVSS:
    rng = np.random.default_rng(seed)
    n_psi = basis.n_psi
    return LPVSS(rng.standard_normal((n_psi, 3, 3)), rng.standard_normal((n_psi, 3, 1)),
                 rng.standard_normal((n_psi, 1, 3)), np.zeros((n_psi, 1, 1)), basis, 0.01)


def test_box_coordinates_interpolate_the_model_exactly():
    model = _model(Basis("affine", 2, p_min=(-1.0, 0.0), p_max=(2.0, 5.0)))
    poly = polytope_of(model)
    assert poly.kind == "box" and poly.n_vertices == 4
    verts = vertex_matrices(model, poly)
    for p in np.random.default_rng(1).uniform([-1, 0], [2, 5], size=(20, 2)):
        lam = poly.coordinates_of_p(model, p)
        assert lam.min() >= 0 and abs(lam.sum() - 1) < 1e-12
        A_interp = sum(w * v[0] for w, v in zip(lam, verts, strict=True))
        np.testing.assert_allclose(A_interp, model.matrices(p)[0], atol=1e-12)


def test_parabola_triangle_contains_the_curve_and_is_tighter_than_the_box():
    model = _model(Basis("poly", 1, degree=2, p_min=(-1.0,), p_max=(3.0,)))
    poly = polytope_of(model)
    assert poly.kind == "parabola-triangle" and poly.n_vertices == 3
    verts = vertex_matrices(model, poly)
    for p in np.linspace(-1, 3, 41):
        psi = model.basis.eval(np.array([[p]]))[0]
        lam = np.linalg.solve(poly.psi_vertices.T, psi)
        assert lam.min() >= -1e-12  # inside the triangle, no clipping needed
        np.testing.assert_allclose(poly.coordinates(psi) @ poly.psi_vertices, psi, atol=1e-12)
        B_interp = sum(w * v[1] for w, v in zip(poly.coordinates(psi), verts, strict=True))
        np.testing.assert_allclose(B_interp, model.matrices(p)[1], atol=1e-10)
    a, b = -1.0, 3.0
    triangle_area = 0.5 * abs((b - a) * (a * b - a * a) - ((a + b) / 2 - a) * (b * b - a * a))
    box_area = (b - a) * (max(a * a, b * b) - 0.0)
    assert triangle_area < 0.5 * box_area


def test_integrator_is_shifted_inside_the_unit_circle_by_eps():
    W = siso_weight({"num": [0.02, 0.02], "den": [1, -1]}, 0.002, "W_S", eps=1e-3)
    np.testing.assert_allclose(np.abs(W.poles()), [1 - 1e-3], atol=1e-12)
    Wb = siso_weight({"bandwidth": 10.0, "hf_gain": 0.5}, 0.01, "W_S", eps=1e-3)
    assert np.all(np.abs(Wb.poles()) <= 1 - 1e-3 + 1e-12)
    assert abs(abs(Wb(-1.0)) - 0.5) < 1e-3  # Tustin maps s = ∞ to z = −1 (shift changes it by ε/2)


def test_a_design_on_signals_tied_along_breakpoints_is_checked_along_them_not_at_box_corners():
    """x⁺ = (0.2 + 0.1s + 1.2c)x + u with (s, c) tied along the breakpoint rows (−1, 0), (0, 1), (1, 0) (sin
    and cos of an angle from −90° to 90°): unstable at the middle row, stable at the ends. The box corner
    (1, 1) is off that curve (no angle has it), and the controller scheduled there (on s = 1, the end
    vertex's) does not hold γ on the model there. The frozen check runs on the design's own plant along
    the breakpoints and passes; the same check on the box grid fails."""
    from lpvflow.synth.certify import certify
    from lpvflow.synth.design import synthesize_design
    from lpvflow.synth.hinf import synthesize
    from lpvflow.synth.plant import generalized_plant

    basis = Basis("affine", 2, p_min=(-1.0, 0.0), p_max=(1.0, 1.0))
    model = LPVSS(np.array([[[0.2]], [[0.1]], [[1.2]]]), np.array([[[1.0]], [[0.0]], [[0.0]]]),
                  np.array([[[1.0]], [[0.0]], [[0.0]]]), np.zeros((3, 1, 1)), basis, 0.01)
    weights = {"S": {"num": [0.3], "den": [1]}, "K": {"num": [0.1], "den": [1]}}
    box, rows = [[-1.0, 1.0], [0.0, 1.0]], [[-1.0, 0.0], [0.0, 1.0], [1.0, 0.0]]
    settings = {"weights": weights, "structure": "1dof", "box": box, "breakpoints": rows,
                "vertex_weights": None, "method": "common", "solver": "CLARABEL", "rate_bound": None}
    design = synthesize_design(model, settings)
    assert design.certificate.ok and design.certificate.frozen_hinf_max <= design.gamma
    result = synthesize(generalized_plant(model, weights, box, "1dof", rows))
    assert certify(result, None).frozen_hinf_max <= result.gamma
    assert certify(result, model).frozen_hinf_max > result.gamma


def test_every_polytope_kind_is_a_class_and_survives_a_controller_file():
    """polytope_of picks the kind's class (box, parabola-triangle, term-box, point; piecewise from
    breakpoints); its λ(p) is a convex combination reproducing ψ(p) inside the box (the hat functions p₁
    for piecewise), and a controller file gives back the same class with the same λ."""
    from lpvflow.synth.controller import LPVController
    from lpvflow.synth.polytope import (
        BoxPolytope,
        ParabolaTriangle,
        PiecewisePolytope,
        PointPolytope,
        TermBoxPolytope,
        piecewise_polytope,
    )

    rng = np.random.default_rng(34)
    cases = [(Basis("affine", 2, p_min=(-1.0, 0.0), p_max=(2.0, 5.0)), None, BoxPolytope),
             (Basis("poly", 1, degree=2, p_min=(-1.0,), p_max=(3.0,)), None, ParabolaTriangle),
             (Basis("poly", 1, degree=3, p_min=(-1.0,), p_max=(1.0,)), None, TermBoxPolytope),
             (Basis("affine", 1, p_min=(0.5,), p_max=(0.5,)), None, PointPolytope),
             (Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,)), np.sort(rng.uniform(-0.9, 0.9, 3)),
              PiecewisePolytope)]
    for basis, inner, cls in cases:
        model = _model(basis)
        if inner is None:
            poly = polytope_of(model)
        else:
            poly = piecewise_polytope(model, None, np.concatenate([[-1.0], inner, [1.0]]))
        assert type(poly) is cls and poly.n_vertices == poly.expected_vertices
        N = poly.n_vertices
        K = LPVController(*(rng.standard_normal((N, *shape)) for shape in ((2, 2), (2, 1), (1, 2), (1, 1))),
                          poly, basis, 0.01)
        loaded = LPVController.from_dict(K.to_dict()).polytope
        assert type(loaded) is cls and loaded.kind == poly.kind
        for p in rng.uniform(basis.p_min, basis.p_max, size=(10, basis.n_p)):
            lam = poly.coordinates_at(basis, p)
            assert lam.min() >= 0 and abs(lam.sum() - 1) < 1e-12
            np.testing.assert_array_equal(loaded.coordinates_at(basis, p), lam)
            if cls is PiecewisePolytope:
                assert lam @ poly.breakpoints == pytest.approx(p[0], abs=1e-12)
            else:
                psi = basis.eval(p.reshape(1, -1))[0]
                np.testing.assert_allclose(lam @ poly.psi_vertices, psi, atol=1e-12)


def test_a_2dof_plant_without_a_reference_weight_measures_r_itself():
    """[synth] structure = "2dof" with no weights.R: the reference the controller measures is r itself
    (W_R = I), the same generalized plant as with an explicit unit W_R (it raised python-control's
    "could not find signal r" before)."""
    from lpvflow.synth.plant import generalized_plant
    from tests.synth_cases import two_state_plant

    weights = {"S": {"num": [0.1, 0.1], "den": [1, -1]}, "K": {"num": [0.01], "den": [1]},
               "B": {"num": [0, 0.5], "den": [1, -0.5]}}
    model = two_state_plant()
    bare = generalized_plant(model, weights, structure="2dof")
    unit = generalized_plant(model, weights | {"R": {"num": [1], "den": [1]}}, structure="2dof")
    for a, b in zip(bare.vertices, unit.vertices, strict=True):
        for name in ("A", "B1", "B2", "C1", "C2", "D11", "D12", "D21", "D22"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert bare.vertices[0].dims[1] == 2 and bare.vertices[0].dims[4] == 2  # w = [r; n], y = [r; y_m]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_each_polytope_kind_gives_its_own_design_grid_and_hat_breakpoints(seed):
    """The behaviour the certificate and the rate-bounded design ask of a polytope (no test of its kind's
    name): a piecewise polytope's design grid holds every breakpoint, where λ is that vertex's unit
    vector, and its λ is the hat functions of its breakpoints; a box over one signal is the segment of its
    two ends (λ the hats of [lo, hi]); a box over two signals has no breakpoints and grids the box."""
    from lpvflow.synth.polytope import hat_coordinates, piecewise_polytope

    rng = np.random.default_rng(seed)
    lo, hi = np.sort(rng.uniform(-3.0, 3.0, 2)) + np.array([0.0, 0.5])
    model = _model(Basis("affine", 1, p_min=(lo,), p_max=(hi,)), seed)
    inner = np.sort(rng.uniform(lo, hi, 3))
    piecewise = piecewise_polytope(model, None, np.concatenate([[lo], inner, [hi]]))
    points = piecewise.design_points(7)[:, 0]
    for i, b in enumerate(piecewise.vertex_breakpoints):
        assert np.min(np.abs(points - b)) < 1e-12
        np.testing.assert_allclose(piecewise.coordinates_of_p(model, [b]), np.eye(5)[i], atol=1e-12)
    segment = polytope_of(model)
    np.testing.assert_array_equal(segment.vertex_breakpoints, [lo, hi])
    for p in rng.uniform(lo, hi, 10):
        np.testing.assert_allclose(segment.coordinates_of_p(model, [p]),
                                   hat_coordinates(segment.vertex_breakpoints, p), atol=1e-12)
        np.testing.assert_allclose(piecewise.coordinates_of_p(model, [p]),
                                   hat_coordinates(piecewise.vertex_breakpoints, p), atol=1e-12)
    box = polytope_of(_model(Basis("affine", 2, p_min=(lo, -1.0), p_max=(hi, 1.0)), seed))
    assert box.vertex_breakpoints is None
    assert box.design_points(4).shape == (16, 2)
