"""Properties of the ν-gap (Vinnicombe 1993) checked against independent dense-grid evaluations."""

import warnings

import control as ct
import numpy as np
import pytest
from scipy.linalg import sqrtm

from lpvflow.errors import ModelError
from lpvflow.validate.nugap import nugap
from tests.lti_helpers import gain as static
from tests.lti_helpers import random_ss

s = ct.tf("s")




def random_pair(rng, n, p, m, dt, scale=0.05):
    """A random stable system and a perturbation of it (same size, may change stability)."""
    P = random_ss(rng, n, p, m, dt)
    Q = ct.ss(P.A + scale * rng.standard_normal(P.A.shape), P.B + scale * rng.standard_normal(P.B.shape),
              P.C, P.D + scale * rng.standard_normal(P.D.shape), dt)
    return P, Q


def dense_response(P, omega):
    """Frequency response (N, p, m) by a linear solve per point (written apart from lpvflow's)."""
    points = np.exp(1j * omega * P.dt) if P.isdtime() else 1j * omega
    resolvent_B = np.linalg.solve(points[:, None, None] * np.eye(P.nstates) - P.A, np.broadcast_to(
        P.B.astype(complex), (len(points), *P.B.shape)))
    return P.C @ resolvent_B + P.D


def dense_chordal_svd(P1, P2, omega):
    """κ(ω) = σmax((I+G2G2*)^-1/2 (G1-G2) (I+G1*G1)^-1/2), one frequency at a time with sqrtm."""
    G1, G2 = dense_response(P1, omega), dense_response(P2, omega)
    out = np.empty(len(omega))
    for i, (g1, g2) in enumerate(zip(G1, G2, strict=True)):
        left = np.linalg.inv(sqrtm(np.eye(g2.shape[0]) + g2 @ g2.conj().T))
        right = np.linalg.inv(sqrtm(np.eye(g1.shape[1]) + g1.conj().T @ g1))
        out[i] = np.linalg.svd(left @ (g1 - g2) @ right, compute_uv=False)[0]
    return out


def winding_condition_by_phase(P1, P2, n_points=20_001):
    """wno det(I + P2~P1) + η(P1) − η̃(P2) = 0, with wno from the unwrapped phase along the boundary.

    wno counts zeros minus poles in the unstable region: minus the counterclockwise winding of
    det(I + P2*P1) as the frequency runs up the imaginary axis / around the unit circle. For real
    systems the negative frequencies mirror the positive ones, doubling the half-range winding.
    """
    if P1.isdtime():
        omega = np.linspace(0.0, np.pi / P1.dt, n_points)
        unstable = [np.sum(np.abs(np.linalg.eigvals(P.A)) > 1 + 1e-9) for P in (P1, P2)]
    else:
        omega = 10 * np.tan(np.linspace(0.0, np.pi / 2 - 1e-9, n_points))
        unstable = [np.sum(np.linalg.eigvals(P.A).real > 1e-9) for P in (P1, P2)]
    G1, G2 = dense_response(P1, omega), dense_response(P2, omega)
    det = np.linalg.det(np.eye(P1.ninputs) + np.conj(np.swapaxes(G2, 1, 2)) @ G1)
    steps = np.angle(det[1:] / det[:-1])
    assert np.max(np.abs(steps)) < 0.5, "grid too coarse for an unambiguous phase count"
    wno = -round(2 * np.sum(steps) / (2 * np.pi))
    return wno + unstable[0] - unstable[1] == 0


# --- basic properties -------------------------------------------------------------------------------


@pytest.mark.parametrize("dt", [0, 0.05])
def test_distance_to_itself_is_zero(dt):
    rng = np.random.default_rng(1)
    for P in (random_pair(rng, 4, 1, 1, dt)[0], random_pair(rng, 5, 2, 2, dt)[0]):
        result = nugap(P, P)
        assert result.value < 1e-12
        assert result.winding_condition_held


def test_distance_to_itself_is_zero_for_unstable_and_integrating_plants():
    for P in (ct.ss(1 / (s - 2)), ct.ss(1 / s), ct.ss((s + 1) / (s**2 + 1e-3 * s + 4)), ct.ss(1 / s**2)):
        assert nugap(P, P).value < 1e-12
    z = ct.tf([1, 0], [1], 0.1)
    for P in (ct.ss(1 / (z - 1)), ct.ss(0.5 / (z - 1.5)), ct.ss(1 / (z**2 - 1.9 * z + 1))):
        assert nugap(P, P).value < 1e-12


@pytest.mark.parametrize("dt", [0, 0.1])
def test_symmetric_and_between_zero_and_one(dt):
    rng = np.random.default_rng(2)
    for scale in (0.02, 0.3, 1.0):
        P1, P2 = random_pair(rng, 4, 2, 2, dt, scale)
        forward, backward = nugap(P1, P2), nugap(P2, P1)
        assert 0.0 <= forward.value <= 1.0
        assert forward.value == pytest.approx(backward.value, abs=1e-7)
        assert forward.winding_condition_held == backward.winding_condition_held


@pytest.mark.parametrize("dt", [0, 0.2])
@pytest.mark.parametrize(("k1", "k2"), [(2.0, -0.3), (0.0, 5.0), (-1.0, -3.0), (10.0, 10.5)])
def test_static_gains_match_closed_form(k1, k2, dt):
    expected = abs(k1 - k2) / np.sqrt((1 + k1**2) * (1 + k2**2))
    assert nugap(static(k1, dt), static(k2, dt)).value == pytest.approx(expected, abs=1e-12)


def test_opposite_static_gains_at_distance_one():
    result = nugap(static(1.0), static(-1.0))
    assert result.value == 1.0
    assert not result.winding_condition_held


def test_matlab_gapmetric_example():
    """MATLAB documents nugap = 0.0020 for 1/(s-0.001) vs 1/(s+0.001); exactly 2ε/(1+ε²) at ω = 0."""
    result = nugap(ct.ss(1 / (s - 0.001)), ct.ss(1 / (s + 0.001)))
    assert result.winding_condition_held
    assert result.value == pytest.approx(0.002 / (1 + 1e-6), rel=1e-6)


# --- winding-number condition ------------------------------------------------------------------------


def test_small_stable_and_unstable_gains_violate_winding_condition():
    """0.1/(s+1) and 0.1/(s-1) are pointwise close (κ < 0.2) but one unstable pole apart: δν = 1."""
    result = nugap(ct.ss(0.1 / (s + 1)), ct.ss(0.1 / (s - 1)))
    assert result.chordal_max < 0.2
    assert not result.winding_condition_held
    assert result.value == 1.0
    assert "winding" in result.reason


def test_discrete_small_gains_across_unit_circle_violate_winding_condition():
    z = ct.tf([1, 0], [1], 0.1)
    result = nugap(ct.ss(0.1 / (z - 1.2)), ct.ss(0.1 / (z - 0.8)))
    assert result.chordal_max < 0.81
    assert result.value == 1.0


def test_pole_crossing_boundary_with_large_gain_keeps_winding_condition():
    """A pole moving from s = -ε to s = +ε is a small ν-gap change (the metric's raison d'être)."""
    assert nugap(ct.ss(1 / (s + 0.01)), ct.ss(1 / (s - 0.01))).value < 0.021
    z = ct.tf([1, 0], [1], 0.1)
    assert nugap(ct.ss(1 / (z - 0.999)), ct.ss(1 / (z - 1.001))).value < 0.003


@pytest.mark.parametrize("dt", [0, 0.1])
def test_winding_condition_agrees_with_phase_unwrapping(dt):
    """The eigenvalue count agrees with an independent argument-principle count on random pairs."""
    rng = np.random.default_rng(3)
    outcomes = []
    for _ in range(12):
        P1, P2 = random_pair(rng, 3, 1, 2, dt, scale=rng.choice([0.1, 0.5, 1.5]))
        result = nugap(P1, P2)
        if result.chordal_max > 0.999:  # det ≈ 0 on the boundary: the phase count is ill-posed
            continue
        held = winding_condition_by_phase(P1, P2, n_points=20_001)
        assert result.winding_condition_held == held
        outcomes.append(held)
    assert True in outcomes and False in outcomes


# --- accuracy against dense grids --------------------------------------------------------------------


@pytest.mark.parametrize("dt", [0, 0.05])
def test_small_perturbation_matches_dense_grid(dt):
    rng = np.random.default_rng(4)
    P1, P2 = random_pair(rng, 4, 1, 1, dt, scale=0.01)
    result = nugap(P1, P2)
    assert result.winding_condition_held
    omega = np.logspace(-4, np.log10(np.pi / dt) - 1e-12, 100_000) if dt else np.logspace(-4, 4, 100_000)
    G1, G2 = dense_response(P1, omega)[:, 0, 0], dense_response(P2, omega)[:, 0, 0]
    dense = np.max(np.abs(G1 - G2) / np.sqrt((1 + np.abs(G1) ** 2) * (1 + np.abs(G2) ** 2)))
    assert 0 < result.value < 0.2
    assert result.value == pytest.approx(dense, abs=1e-4)
    assert result.value >= dense - 1e-12


def test_added_sample_delays_keep_the_nugap_finite_and_match_the_dense_grid():
    """Pure delays put zeros of det(I + P2~P1) at z = ∞ (w = 1 after the bilinear map): no warning, and
    the value is the dense-grid maximum of the chordal distance."""
    P = ct.ss(ct.tf([0.2], [1, -0.8], 0.5))
    delayed = ct.ss(ct.tf([0.2], [1, -0.8, 0, 0], 0.5))  # two more samples of dead time
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        value = nugap(P, delayed).value
    omega = np.linspace(1e-4, np.pi / 0.5, 20001)
    g1, g2 = (dense_response(S, omega)[:, 0, 0] for S in (P, delayed))
    chordal = np.abs(g1 - g2) / np.sqrt((1 + np.abs(g1) ** 2) * (1 + np.abs(g2) ** 2))
    assert value == pytest.approx(chordal.max(), rel=1e-3)
    assert value > 0.1


@pytest.mark.parametrize("dt", [0, 0.1])
def test_mimo_matches_svd_formula_on_dense_grid(dt):
    rng = np.random.default_rng(5)
    P1, P2 = random_pair(rng, 4, 2, 2, dt, scale=0.05)
    result = nugap(P1, P2, return_grid=True)
    assert result.winding_condition_held
    omega = np.logspace(-3, np.log10(np.pi / dt) - 1e-12, 4000) if dt else np.logspace(-3, 3, 4000)
    dense = dense_chordal_svd(P1, P2, omega)
    assert result.value == pytest.approx(dense.max(), abs=1e-4)
    assert result.value >= dense.max() - 1e-9
    on_grid = dense_chordal_svd(P1, P2, result.grid[np.isfinite(result.grid)][:50])
    assert np.allclose(on_grid, result.chordal[np.isfinite(result.grid)][:50], atol=1e-10)


# --- bad calls ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("P1", "P2", "words"),
    [
        (ct.ss(-np.eye(2), np.ones((2, 1)), np.eye(2), 0), ct.ss([[-1]], [[1]], [[1]], 0), "2x1"),
        (ct.ss([[0.2]], [[1]], [[1]], 0, 0.1), ct.ss([[0.5]], [[1]], [[1]], 0, 0.2), "Ts"),
        (ct.ss([[-1]], [[1]], [[1]], 0), ct.ss([[0.5]], [[1]], [[1]], 0, 0.1), "continuous-time"),
        (np.eye(2), ct.ss(-np.eye(2), np.eye(2), np.eye(2), 0), "not an LTI system"),
    ],
)
def test_bad_calls_raise_one_line_model_error(P1, P2, words):
    with pytest.raises(ModelError, match=words) as info:
        nugap(P1, P2)
    assert "\n" not in str(info.value)
