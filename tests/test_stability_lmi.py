"""Quadratic and rate-bounded Lyapunov certificates: certify, refuse with the reason, re-check."""

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.validate.stability import (
    check_common_lyapunov,
    quadratic_stability,
    rate_bounded_stability,
    rate_bounded_vertices,
)

A0 = np.array([[0.5, 0.2], [0.0, 0.6]])
A1 = np.array([[0.0, 0.3], [-0.3, 0.0]])
Ts = 0.05


def spring(theta, damping=1.0):
    """Euler-discretized x'' + c x' + k x = 0 with stiffness k = θ (affine in θ)."""
    return np.eye(2) + Ts * np.array([[0.0, 1.0], [-theta[0], -damping]])


def test_quadratically_stable_polytope_is_certified_and_holds_inside():
    certificate = quadratic_stability([A0 - A1, A0 + A1])
    assert certificate.certified, certificate.reason
    assert certificate.check.passed and certificate.check.worst_eigenvalue <= -certificate.check.eps
    P = certificate.P
    assert np.linalg.eigvalsh(P)[0] > 0
    rng = np.random.default_rng(0)
    for w in rng.uniform(0, 1, 50):  # the certificate covers the whole polytope, not only vertices
        A = w * (A0 - A1) + (1 - w) * (A0 + A1)
        assert np.linalg.eigvalsh(A.T @ P @ A - P)[-1] < 0


def test_unstable_vertex_is_refused_with_its_spectral_radius():
    certificate = quadratic_stability([A0, np.diag([1.07, 0.2])])
    assert not certificate.certified
    assert certificate.reason == "vertex 1 is unstable: spectral radius 1.07"
    assert certificate.P is None


def test_stable_vertices_without_common_lyapunov_matrix_are_refused():
    B1 = 0.9 * np.array([[0.0, 2.0], [-0.1, 0.9]])
    B2 = 0.9 * np.array([[0.9, -0.1], [2.0, 0.0]])
    assert max(abs(np.linalg.eigvals(B1))) < 1 and max(abs(np.linalg.eigvals(B2))) < 1
    certificate = quadratic_stability([B1, B2])
    assert not certificate.certified
    assert "no common Lyapunov matrix" in certificate.reason
    # consistent: alternating the two vertices diverges, so no common quadratic function exists
    assert max(abs(np.linalg.eigvals(B1 @ B2))) > 1


def test_recheck_rejects_a_wrong_lyapunov_matrix():
    A = np.array([[0.9, 0.5], [0.0, 0.9]])  # stable, but P = I does not decrease along it
    check = check_common_lyapunov([A], np.eye(2), eps=1e-6)
    assert not check.passed
    assert "vertex 0" in check.reason


def test_rate_bounded_certificate_covers_slow_but_not_fast_scheduling():
    box = [[1.0, 5.0]]
    assert not quadratic_stability([spring([1.0]), spring([5.0])]).certified
    slow = rate_bounded_stability(spring, box, [0.005])
    assert slow.certified, slow.reason
    assert slow.kind == "rate-bounded" and slow.check.passed
    # independent of the slack matrix G: P(θ) − A(θ)ᵀ P(θ⁺) A(θ) ≻ 0 at random admissible pairs
    rng = np.random.default_rng(1)
    P0, P1 = slow.P
    for _ in range(200):
        theta = rng.uniform(1.0, 5.0)
        theta_next = np.clip(theta + rng.uniform(-0.005, 0.005), 1.0, 5.0)
        A = spring([theta])
        decrease = (P0 + theta * P1) - A.T @ (P0 + theta_next * P1) @ A
        assert np.linalg.eigvalsh(decrease)[0] > 0
    fast = rate_bounded_stability(spring, box, [0.5])
    assert not fast.certified
    assert "rates [0.5]" in fast.reason


def test_rate_bounded_vertices_form_hexagon_per_signal():
    pairs = rate_bounded_vertices(np.array([[0.0, 1.0]]), np.array([0.25]))
    points = {(float(a[0]), float(b[0])) for a, b in pairs}
    assert points == {(0.0, 0.0), (0.0, 0.25), (0.75, 1.0), (1.0, 1.0), (1.0, 0.75), (0.25, 0.0)}
    assert len(rate_bounded_vertices(np.array([[0.0, 1.0], [0.0, 1.0]]), np.array([2.0, 0.1]))) == 4 * 6


def test_lpvss_model_is_accepted_by_both_certificates():
    basis = Basis(kind="affine", n_p=1, p_min=(1.0,), p_max=(5.0,))
    A = np.stack([np.eye(2) + Ts * np.array([[0.0, 1.0], [0.0, -1.0]]), Ts * np.array([[0, 0], [-1.0, 0]])])
    zeros = {"B": np.zeros((2, 2, 1)), "C": np.zeros((2, 1, 2)), "D": np.zeros((2, 1, 1))}
    model = LPVSS(A=A, basis=basis, Ts=Ts, **zeros)
    assert not quadratic_stability(model).certified
    assert rate_bounded_stability(model, None, [0.005]).certified


def test_bad_inputs_raise_one_line_model_error():
    with pytest.raises(ModelError, match="square and of one size"):
        quadratic_stability([np.eye(2), np.eye(3)])
    with pytest.raises(ModelError, match="not affine"):
        rate_bounded_stability(lambda th: np.eye(2) * 0.5 * np.cos(th[0]), [[0.0, 2.0]], [0.1])
    with pytest.raises(ModelError, match="non-negative") as info:
        rate_bounded_stability(spring, [[1.0, 5.0]], [-1.0])
    assert "\n" not in str(info.value)
