"""Exactness of the observable-form realization of shifted-form (LPR) models.

Thesis (5.17)/(5.24)–(5.26)/(5.36) and Schulz et al. eq. (4); corrected Examples 5.5 and 5.7
(notes_002 §4.6–4.7).
"""

import itertools

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.identify.realize import observable_form
from lpvflow.lpvio import LPVIO

CASES = list(itertools.product([(1, 1), (2, 2)], [1, 2, 3], [1, 2], [0, 1, 2], [False, True]))


def random_lpr(rng, ny, nu, n_p, degree, nk, with_k):
    """A random shifted-form model, scaled so that it stays bounded for p in [-1, 1]."""
    basis = Basis.poly(degree, n_p)
    na, nb = 2, 2
    A = rng.normal(size=(na, basis.n_psi, ny, ny)) * 0.25 / (basis.n_psi * ny)
    B = np.zeros((nk + nb, basis.n_psi, ny, nu))
    B[nk:] = rng.normal(size=(nb, basis.n_psi, ny, nu))
    B[0, 1:] = 0.0  # the lag-0 coefficient must be constant (realization stays affine)
    C = rng.normal(size=(2, basis.n_psi, ny, ny)) * 0.2 if with_k else None
    return LPVIO(A, B, basis, 0.01, C=C)


@pytest.mark.parametrize(("dims", "n_p", "degree", "nk", "with_k"), CASES)
def test_realization_matches_io_simulation(dims, n_p, degree, nk, with_k):
    rng = np.random.default_rng(hash((dims, n_p, degree, nk, with_k)) % 2**32)
    ny, nu = dims
    io = random_lpr(rng, ny, nu, n_p, degree, nk, with_k)
    n = 400
    u = rng.normal(size=(n, nu))
    p = rng.uniform(-1, 1, size=(n, n_p))
    e = rng.normal(size=(n, ny)) if with_k else None
    y_io = io.simulate(u, p, e=e)
    ss = io.to_ss()
    y_ss = ss.simulate(u, p, e=e)
    assert np.max(np.abs(y_ss - y_io)) <= 1e-10 * np.max(np.abs(y_io))

    # Static form: C and D are parameter independent, and A_l (l >= 1) only fills the columns that
    # multiply the outputs (A(θ) = Ā_o − 𝒜_l(θ) C̄_o): the matrices hold ψ(p(k)) and nothing else.
    assert not np.any(ss.C[1:]) and not np.any(ss.D[1:])
    output_states = np.flatnonzero(ss.C[0].any(axis=0))
    other = np.setdiff1d(np.arange(ss.nx), output_states)
    assert not np.any(ss.A[1:][:, :, other])
    assert ss.nx == ny * max(2, nk + 1)  # row degree = largest lag, thesis (5.36)


def test_realization_refuses_static_dependence_form():
    io = LPVIO(np.zeros((1, 2, 1, 1)), np.ones((2, 2, 1, 1)), Basis.affine(), 1.0, form="static")
    with pytest.raises(ModelError, match="static-dependence"):
        io.to_ss()


def test_realization_refuses_scheduled_feedthrough():
    B = np.ones((2, 2, 1, 1))
    with pytest.raises(ModelError, match="lag-0 input coefficient depends on p"):
        LPVIO(np.zeros((1, 2, 1, 1)), B, Basis.affine(), 1.0).to_ss()


def lfd_simulate(row_degrees, lfd_a, lfd_b, u, theta):
    """Independent simulator of Ã(q,θ) y = B̃(q,θ) u in LPR (coefficients right of q), zero past.

    ``lfd_a[i][j]`` / ``lfd_b[i][j]`` map a power m of q to a function c(θ); the term
    q^m c(θ(k)) s(k) equals c(θ(k+m)) s(k+m) (thesis (5.7)). Row i, of degree n_i with a monic
    diagonal, written at time t = k − n_i, is solved for y_i(k); signals before time 0 vanish.
    """
    n = len(u)
    ny = len(row_degrees)
    y = np.zeros((n, ny))
    for k in range(n):
        for i, n_i in enumerate(row_degrees):
            t = k - n_i
            acc = 0.0
            for j in range(u.shape[1]):
                for m, c in lfd_b[i][j].items():
                    if t + m >= 0:
                        acc += c(theta[t + m]) * u[t + m, j]
            for j in range(ny):
                for m, c in lfd_a[i][j].items():
                    if t + m >= 0 and not (i == j and m == n_i):
                        acc -= c(theta[t + m]) * y[t + m, j]
            y[k, i] = acc
    return y


def test_thesis_example_5_5_corrected():
    """Kailath example: Ã = [[q³+q²4θ+q5θ+2θ, q+2θ],[0, q²+q4θ+4θ]], B̃ = [[0, −q²],[−q, −q]].

    The printed Ã_o has −2θ at (3,3) and a garbled B̃_o; the corrected values (notes_002 §4.6)
    are −4θ and B̃_oᵀ = [[0,0,0,0,−1],[0,0,−1,0,−1]].
    """
    basis = Basis.affine()
    # 𝒜_l rows: (row 1: q⁰, q¹, q²), (row 2: q⁰, q¹); columns y1, y2; ψ = [1, θ].
    al_const = np.array([[0, 0], [0, 1], [0, 0], [0, 0], [0, 0]], float)
    al_theta = np.array([[2, 2], [5, 0], [4, 0], [0, 4], [0, 4]], float)
    bl = np.array([[0, 0], [0, 0], [0, -1], [0, 0], [-1, -1]], float)
    ss = observable_form([3, 2], np.stack([al_const, al_theta]), np.stack([bl, 0 * bl]),
                         np.zeros((2, 2)), basis, 1.0)
    th = 0.37
    A, B, C, _ = ss.matrices([th])
    A_expected = np.array([
        [0, 0, -2 * th, 0, -2 * th],
        [1, 0, -5 * th, 0, -1],
        [0, 1, -4 * th, 0, 0],
        [0, 0, 0, 0, -4 * th],
        [0, 0, 0, 1, -4 * th],
    ])
    np.testing.assert_allclose(A, A_expected, atol=1e-15)
    np.testing.assert_allclose(B, [[0, 0], [0, 0], [0, -1], [0, 0], [-1, -1]], atol=1e-15)
    np.testing.assert_allclose(C, [[0, 0, 1, 0, 0], [0, 0, 0, 0, 1]], atol=1e-15)

    lfd_a = [
        [{3: lambda t: 1.0, 2: lambda t: 4 * t, 1: lambda t: 5 * t, 0: lambda t: 2 * t},
         {1: lambda t: 1.0, 0: lambda t: 2 * t}],
        [{}, {2: lambda t: 1.0, 1: lambda t: 4 * t, 0: lambda t: 4 * t}],
    ]
    lfd_b = [[{}, {2: lambda t: -1.0}], [{1: lambda t: -1.0}, {1: lambda t: -1.0}]]
    rng = np.random.default_rng(5)
    n = 60
    u = rng.normal(size=(n, 2))
    theta = rng.uniform(-0.2, 0.2, size=n)
    y_ref = lfd_simulate([3, 2], lfd_a, lfd_b, u, theta)
    y_ss = ss.simulate(u, theta[:, None])
    np.testing.assert_allclose(y_ss, y_ref, atol=1e-12 * np.max(np.abs(y_ref)))


def test_thesis_example_5_7_corrected():
    """y1 = q⁻¹ã111 y1 + q⁻²ã112 y1 + q⁻¹ã121 y2 + q⁻²ã122 y2 + q⁻¹b̃11 u1 + q⁻²b̃12 u2,
    y2 = q⁻¹ã211 y1 + q⁻¹ã221 y2 + q⁻¹b̃21 u1 (note the + signs; notes_002 §4.7 correction):
    Ã_o = [[0, ã112, ã122], [1, ã111, ã121], [0, ã211, ã221]], B̃_o = [[0, b̃12], [b̃11, 0], [b̃21, 0]].
    """
    rng = np.random.default_rng(7)
    basis = Basis.affine()
    coef = {k: rng.normal(size=2) * 0.3 for k in ("a111", "a112", "a121", "a122", "a211", "a221")}
    coef |= {k: rng.normal(size=2) for k in ("b11", "b12", "b21")}
    A = np.zeros((2, 2, 2, 2))  # (lag, psi, row, col); the model's y-coefficients are −ã
    A[0, :, 0, 0], A[1, :, 0, 0] = -coef["a111"], -coef["a112"]
    A[0, :, 0, 1], A[1, :, 0, 1] = -coef["a121"], -coef["a122"]
    A[0, :, 1, 0], A[0, :, 1, 1] = -coef["a211"], -coef["a221"]
    B = np.zeros((3, 2, 2, 2))
    B[1, :, 0, 0], B[2, :, 0, 1], B[1, :, 1, 0] = coef["b11"], coef["b12"], coef["b21"]
    io = LPVIO(A, B, basis, 1.0, na=np.array([[2, 2], [1, 1]]))
    ss = io.to_ss()
    th = -0.6
    ev = {k: v[0] + v[1] * th for k, v in coef.items()}
    Ao, Bo, Co, _ = ss.matrices([th])
    np.testing.assert_allclose(Ao, [[0, ev["a112"], ev["a122"]], [1, ev["a111"], ev["a121"]],
                                    [0, ev["a211"], ev["a221"]]], atol=1e-14)
    np.testing.assert_allclose(Bo, [[0, ev["b12"]], [ev["b11"], 0], [ev["b21"], 0]], atol=1e-14)
    np.testing.assert_allclose(Co, [[0, 1, 0], [0, 0, 1]], atol=1e-14)
    u = rng.normal(size=(200, 2))
    p = rng.uniform(-1, 1, size=(200, 1))
    y_io = io.simulate(u, p)
    np.testing.assert_allclose(ss.simulate(u, p), y_io, atol=1e-10 * np.max(np.abs(y_io)))
