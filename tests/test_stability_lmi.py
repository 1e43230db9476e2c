"""Quadratic and rate-bounded Lyapunov certificates: certify, refuse with the reason, re-check."""

from fractions import Fraction

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.validate.stability import (
    check_common_lyapunov,
    check_quadratic_certificate,
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
    assert certificate.check.passed and certificate.check.worst_margin > 0
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


# ------------------------------------------------------------ acceptance relative to block scale (issue 22)
def _decrease_is_exactly_positive_definite(A_vertices: list[np.ndarray], P: np.ndarray) -> bool:
    """P ≻ 0 and P − AᵢᵀPAᵢ ≻ 0 for the stored floating-point numbers, in exact rational arithmetic
    (Sylvester's criterion: every leading principal minor > 0); independent of any rounding."""
    def exact(M: np.ndarray) -> list[list[Fraction]]:
        return [[Fraction(float(v)) for v in row] for row in M]

    def product(X: list, Y: list) -> list:
        return [[sum(X[i][k] * Y[k][j] for k in range(len(Y))) for j in range(len(Y[0]))]
                for i in range(len(X))]

    def determinant(M: list) -> Fraction:
        if len(M) == 1:
            return M[0][0]
        return sum((-1) ** j * M[0][j] * determinant([row[:j] + row[j + 1:] for row in M[1:]])
                   for j in range(len(M)))

    def positive_definite(M: list) -> bool:
        return all(determinant([row[:k] for row in M[:k]]) > 0 for k in range(1, len(M) + 1))

    Pe = exact(0.5 * (P + P.T))
    blocks = [Pe]
    for A in A_vertices:
        Ae = exact(A)
        AtPA = product(product([list(col) for col in zip(*Ae, strict=True)], Pe), Ae)
        blocks.append([[Pe[i][j] - AtPA[i][j] for j in range(len(Pe))] for i in range(len(Pe))])
    return all(positive_definite(M) for M in blocks)


def _slow_mode_fed_by_fast_ones(slow: float) -> list[np.ndarray]:
    """Two vertices with a mode at z = 1 − slow that the fast states drive (block upper triangular)."""
    return [np.array([[1 - slow, 0.3, 0.0], [0.0, 0.5, 0.2], [0.0, 0.0, -0.3]]),
            np.array([[1 - slow, 0.0, 0.1], [0.0, 0.4, 0.0], [0.0, 0.2, 0.2]])]


def test_a_slow_mode_beside_fast_ones_is_certified_where_the_absolute_margin_refused_it():
    """Quadratically stable: P = diag(1, 1e8, 1e8) proves it, exactly. The absolute rule (P ⪰ I and
    AᵢᵀPAᵢ − P ⪯ −1e-4·I, re-checked against −½·1e-4·σ_min(T⁻¹)²) needs entries of P ~ 1e10 here;
    Clarabel called that LMI infeasible and quadratic_stability refused with "no common Lyapunov
    matrix". In difference form with margins relative to each block's scale it is certified, and the P
    returned is exact."""
    vertices = _slow_mode_fed_by_fast_ones(1e-8)
    assert _decrease_is_exactly_positive_definite(vertices, np.diag([1.0, 1e8, 1e8]))
    certificate = quadratic_stability(vertices)
    assert certificate.certified, certificate.reason
    assert certificate.check.worst_margin > 0.1  # Jacobi-scaled: far from round-off
    assert _decrease_is_exactly_positive_definite(vertices, certificate.P)


def test_fast_sampling_does_not_hide_the_decrease():
    """Vertices exp(A_c·Ts) with A_c + A_cᵀ ≺ 0 at Ts = 1e-12 s: every pole within 1e-11 of z = 1, P = I
    decreases along both (‖A_i‖₂ < 1). Certified with a Jacobi-scaled margin of order one."""
    from scipy.linalg import expm

    continuous = [np.array([[-1.0, 5.0], [-5.0, -0.5]]), np.array([[-0.3, -2.0], [2.0, -2.0]])]
    vertices = [expm(Ac * 1e-12) for Ac in continuous]
    assert all(np.linalg.norm(A, 2) < 1 for A in vertices)
    certificate = quadratic_stability(vertices)
    assert certificate.certified, certificate.reason
    assert certificate.check.worst_margin > 0.1


@pytest.mark.parametrize(("gap", "accepted"), [(1e-9, True), (1e-13, False)])
def test_a_decrease_at_round_off_level_is_refused(gap, accepted):
    """A = ρ·R(0.5) with ρ² = 1 − gap and P = I: P − AᵀPA = gap·I, formed from terms of size one. At
    gap = 1e-9 the decrease stands well above round-off and is accepted; at 1e-13 it is within a
    thousand times the round-off of forming it, and the certificate (given or solved for) is refused,
    though every eigenvalue of the computed block is positive."""
    c, s = np.cos(0.5), np.sin(0.5)
    A = np.sqrt(1.0 - gap) * np.array([[c, -s], [s, c]])
    block = np.eye(2) - A.T @ A
    assert np.linalg.eigvalsh(block)[0] > 0
    check = check_quadratic_certificate([A], np.eye(2))
    assert check.passed is accepted
    assert (check.worst_margin > 0.5) is accepted
    assert quadratic_stability([A]).certified is accepted
    if not accepted:
        assert "vertex 0 has Jacobi-scaled margin" in check.reason


def test_the_acceptance_rule_does_not_depend_on_the_units_of_the_states():
    """A diagonal change of state units (here 1e-6 … 1e6) leaves every Jacobi-scaled margin unchanged."""
    vertices = _slow_mode_fed_by_fast_ones(1e-6)
    P = quadratic_stability(vertices).P
    S = np.diag([1e-6, 1.0, 1e6])
    Si = np.linalg.inv(S)
    original = check_quadratic_certificate(vertices, P)
    scaled = check_quadratic_certificate([S @ A @ Si for A in vertices], Si.T @ P @ Si)
    assert original.passed and scaled.passed
    np.testing.assert_allclose(scaled.margins, original.margins, rtol=1e-9)
