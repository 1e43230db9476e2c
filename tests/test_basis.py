"""Scheduling bases ψ(p): term sets, values, range recording, serialisation, spec parsing."""

import warnings

import numpy as np
import pytest

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.errors import ModelError


def test_polynomial_terms_with_and_without_cross_terms():
    full = Basis.poly(2, 2)
    assert full.term_names == ["1", "p0", "p1", "p0^2", "p0*p1", "p1^2"]
    plain = Basis.poly(2, 2, cross=False)
    assert plain.term_names == ["1", "p0", "p1", "p0^2", "p1^2"]
    p = np.array([[2.0, 3.0]])
    values = dict(zip(full.term_names, full.eval(p)[0], strict=True))
    assert values == {"1": 1, "p1": 3, "p0": 2, "p1^2": 9, "p0*p1": 6, "p0^2": 4}
    assert Basis.poly(3, 3).n_psi == 20  # C(3+3, 3)


def test_affine_basis_is_one_and_the_signals():
    b = Basis.affine(2)
    np.testing.assert_array_equal(b.eval(np.array([[0.5, -2.0]])), [[1, 0.5, -2.0]])
    assert b.is_affine and Basis.poly(1, 2).is_affine and not Basis.poly(2).is_affine


def test_spline_basis_is_the_truncated_power_form():
    b = Basis.spline([-1.0, 0.5])
    theta = np.array([[0.0], [2.0]])
    expected = [[1, 0, 1, 0.125], [1, 2, 27, 3.375]]  # [1, θ, |θ+1|³, |θ−0.5|³]
    np.testing.assert_allclose(b.eval(theta), expected)
    with pytest.raises(ModelError, match="strictly increasing"):
        Basis.spline([0.5, -1.0])


def test_range_is_recorded_and_extrapolation_warns():
    b = Basis.poly(2).with_range(np.array([[-1.0], [0.5], [2.0]]))
    assert (b.p_min, b.p_max) == ((-1.0,), (2.0,))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        b.eval(np.array([[0.0], [2.0]]))  # inside: silent
    with pytest.warns(SchedulingRangeWarning, match="outside the identified range"):
        b.eval(np.array([[2.5]]))


@pytest.mark.parametrize("basis", [Basis.affine(2), Basis.poly(3, 2, cross=False),
                                   Basis.spline([[0.1, 0.4], [0.2]]).with_range(np.zeros((1, 2)))])
def test_serialisation_roundtrip(basis):
    again = Basis.from_dict(basis.to_dict())
    assert again == basis
    p = np.random.default_rng(0).uniform(-1, 1, size=(5, basis.n_p))
    np.testing.assert_array_equal(again.eval(p, check_range=False), basis.eval(p, check_range=False))


def test_spec_parsing():
    assert Basis.from_spec("poly:3", 1) == Basis.poly(3)
    assert Basis.from_spec("poly:2:nocross", 2) == Basis.poly(2, 2, cross=False)
    assert Basis.from_spec("spline:0.2,0.5", 1).knots == ((0.2, 0.5),)
    assert Basis.from_spec("spline:0.2;0.1,0.3", 2).knots == ((0.2,), (0.1, 0.3))
    for bad in ("poly", "poly:x", "quad:2", "affine:1", "poly:2:foo"):
        with pytest.raises(ModelError, match="bad basis spec"):
            Basis.from_spec(bad, 1)
    with pytest.raises(ModelError, match="strictly increasing"):  # the specific reason survives
        Basis.from_spec("spline:0.5,0.2", 1)
    with pytest.raises(ModelError, match="expects 2 scheduling"):
        Basis.affine(2).eval(np.zeros((3, 3)))
