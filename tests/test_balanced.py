"""Generalized-Gramian balanced truncation (lpvflow.identify.balanced): the a-priori ℓ2 bound holds
under arbitrary scheduling in the box; unstable or unbounded-region models are refused."""

import itertools

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.identify.balanced import balanced_truncation, scheduling_vertices
from lpvflow.identify.reduce import reduce
from lpvflow.models import LPVSS

BOX = 1.0


def stable_model(rng: np.random.Generator, nx: int, n_p: int, contraction: float = 0.9,
                 unreachable: int = 0) -> LPVSS:
    """Random affine LPVSS, 2 inputs/outputs, ψ-dependent A, B, C, D; every vertex of A has norm
    ≤ ``contraction`` in the coordinates of a random similarity (so it is quadratically stable but not
    contractive in its own coordinates). The last ``unreachable`` states get neither B nor coupling."""
    n_psi = n_p + 1
    A = rng.standard_normal((n_psi, nx, nx))
    A[1:] *= 0.3
    B = rng.standard_normal((n_psi, nx, 2))
    if unreachable:
        A[:, nx - unreachable :, : nx - unreachable] = 0.0
        B[:, nx - unreachable :] = 0.0
    corners = Basis.affine(n_p).eval(np.array(list(itertools.product([-BOX, BOX], repeat=n_p))))
    A *= contraction / max(np.linalg.norm(np.tensordot(c, A, axes=1), 2) for c in corners)
    S = rng.standard_normal((nx, nx)) + 2 * np.eye(nx)
    Si = np.linalg.inv(S)
    basis = Basis.affine(n_p).with_range(np.array([[-BOX] * n_p, [BOX] * n_p]))
    return LPVSS(S @ A @ Si, S @ B, rng.standard_normal((n_psi, 2, nx)) @ Si,
                 rng.standard_normal((n_psi, 2, 2)), basis, 0.05)


def worst_gain(ss: LPVSS, red: LPVSS, rng: np.random.Generator, trials: int = 12, N: int = 400) -> float:
    """max over random inputs and scheduling (uniform, bang-bang corners, slow) of ‖y − ŷ‖ / ‖u‖."""
    n_p = ss.basis.n_p
    worst = 0.0
    for t in range(trials):
        u = rng.standard_normal((N, ss.nu))
        if t % 3 == 1:
            u = np.cumsum(u, axis=0) / np.sqrt(np.arange(1, N + 1))[:, None]  # low-frequency content
        kind = t % 3
        if kind == 0:
            p = rng.uniform(-BOX, BOX, (N, n_p))
        elif kind == 1:
            p = rng.choice([-BOX, BOX], size=(N, n_p))
        else:
            p = BOX * np.sin(np.linspace(0, rng.uniform(1, 20), N))[:, None] * np.ones(n_p)
        err = ss.simulate(u, p) - red.simulate(u, p)
        worst = max(worst, np.linalg.norm(err) / np.linalg.norm(u))
    return worst


@pytest.mark.parametrize(("seed", "nx", "n_p", "order"),
                         [(1, 5, 1, 3), (2, 5, 2, 2), (3, 6, 2, 4), (4, 4, 1, 1)])
def test_simulated_error_respects_the_a_priori_bound(seed, nx, n_p, order):
    rng = np.random.default_rng(seed)
    ss = stable_model(rng, nx, n_p)
    red = balanced_truncation(ss, order=order)
    rec = red.reduction
    sigma = np.array(rec["singular_values"])
    assert red.nx == order and rec["method"] == "balanced"
    assert np.all(np.diff(sigma) <= 0) and sigma[-1] > 0
    assert rec["error_bound"] == pytest.approx(2 * sigma[order:].sum())
    gain = worst_gain(ss, red, rng)
    assert 0 < gain <= rec["error_bound"]


def test_full_order_balancing_is_exact_and_bound_zero():
    rng = np.random.default_rng(5)
    ss = stable_model(rng, 4, 2)
    full = balanced_truncation(ss, order=4)
    assert full.reduction["error_bound"] == 0.0
    assert worst_gain(ss, full, rng, trials=3) < 1e-10


def test_unreachable_states_get_negligible_sigma_and_are_dropped_automatically():
    rng = np.random.default_rng(6)
    ss = stable_model(rng, 6, 1, unreachable=2)
    red = balanced_truncation(ss)
    rec = red.reduction
    assert red.nx == 4
    assert rec["error_bound"] < 1e-3 * rec["singular_values"][0]
    assert worst_gain(ss, red, rng, trials=3) <= rec["error_bound"]


def test_unstable_model_is_refused():
    rng = np.random.default_rng(7)
    ss = stable_model(rng, 4, 1)
    radius = max(max(abs(np.linalg.eigvals(f.A))) for _, f in ss.vertices())
    ss.A *= 1.1 / radius  # one vertex now has an eigenvalue of modulus 1.1
    with pytest.raises(ModelError, match="not quadratically stable") as info:
        balanced_truncation(ss, order=2)
    assert "\n" not in str(info.value)


def test_frozen_stable_but_not_quadratically_stable_polytope_is_refused():
    """Vertices A_+ = [[0, 2], [0, 0.5]] and A_- = [[0.5, 0], [2, 0]] are each Schur stable, but no
    common Lyapunov matrix exists: A_+A_- has spectral radius 4 (alternating between them diverges)."""
    A_plus = np.array([[0.0, 2.0], [0.0, 0.5]])
    A_minus = np.array([[0.5, 0.0], [2.0, 0.0]])
    assert max(abs(np.linalg.eigvals(A_plus))) < 1 and max(abs(np.linalg.eigvals(A_minus))) < 1
    assert max(abs(np.linalg.eigvals(A_plus @ A_minus))) > 1
    A = np.array([(A_plus + A_minus) / 2, (A_plus - A_minus) / 2])
    basis = Basis.affine(1).with_range(np.array([[-1.0], [1.0]]))
    ss = LPVSS(A, np.ones((2, 2, 1)), np.ones((2, 1, 2)), np.zeros((2, 1, 1)), basis, 1.0)
    with pytest.raises(ModelError, match="not quadratically stable"):
        balanced_truncation(ss, order=1)


def test_region_checks_and_dispatch_from_reduce():
    rng = np.random.default_rng(8)
    ss = stable_model(rng, 4, 1)
    red = reduce(ss, order=2, method="balanced")
    assert red.reduction["method"] == "balanced" and red.nx == 2
    with pytest.raises(ModelError, match="depth applies"):
        reduce(ss, order=2, method="balanced", depth=(2, 2))
    ss.basis = Basis.affine(1)  # no recorded range
    with pytest.raises(ModelError, match="pass box"):
        balanced_truncation(ss, order=2)
    assert len(scheduling_vertices(ss, box=[[-1.0, 1.0]])) == 2
    poly = LPVSS(np.concatenate([ss.A, 0 * ss.A[:1]]), np.concatenate([ss.B, 0 * ss.B[:1]]),
                 np.concatenate([ss.C, 0 * ss.C[:1]]), np.concatenate([ss.D, 0 * ss.D[:1]]),
                 Basis.poly(2, 1), ss.Ts)
    with pytest.raises(ModelError, match="psi_box"):
        balanced_truncation(poly, order=2)
    psi_red = balanced_truncation(poly, order=2, psi_box=[[-1.0, 1.0], [0.0, 1.0]])
    assert psi_red.nx == 2 and psi_red.reduction["n_vertices"] == 4
