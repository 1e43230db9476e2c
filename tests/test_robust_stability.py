"""b(G, K) (u = K y), b_opt(G), delay and disk margins of lpvflow.validate.robust_stability, checked
against an independent frequency-grid evaluation of the four-block matrix and against each other."""

from pathlib import Path

import control as ct
import numpy as np
import pytest

from lpvflow.errors import ModelError
from lpvflow.synth.loop_shaping import central_ncf_controller
from lpvflow.validate.lti_eval import bilinear_to_continuous
from lpvflow.validate.norms import hinf_norm
from lpvflow.validate.robust_stability import (
    delay_margin_samples,
    generalized_margin,
    input_disk_margin,
    ncf_riccati,
    optimal_margin,
    robust_stability,
)
from tests.lti_helpers import random_ss
from tests.test_margins import observer_controller

SAMPLING_TIMES = (1e-3, 1e-2, 5e-2)


def four_block_peak(G, K, points=15000):
    """max σ of [I; K](I − GK)⁻¹[I G] on a dense log grid of the unit circle (no lpvflow code)."""
    Ts = G.dt
    omega = np.concatenate([[0.0], np.logspace(-7, np.log10(np.pi), points)]) / Ts
    Gf = np.moveaxis(ct.frequency_response(G, omega).complex.reshape(G.noutputs, G.ninputs, -1), -1, 0)
    Kf = np.moveaxis(ct.frequency_response(K, omega).complex.reshape(K.noutputs, K.ninputs, -1), -1, 0)
    eye_p = np.broadcast_to(np.eye(G.noutputs), (Gf.shape[0], G.noutputs, G.noutputs))
    inner = np.linalg.inv(eye_p - Gf @ Kf)
    T = np.concatenate([eye_p, Kf], axis=1) @ inner @ np.concatenate([eye_p, Gf], axis=2)
    return np.linalg.svd(T, compute_uv=False)[:, 0].max()


def random_plant(rng, p, m, Ts, unstable):
    """Zero-order-hold sample of a random continuous plant with 1–4 states (some unstable poles if asked)."""
    n = int(rng.integers(1, 5))
    Gc = random_ss(rng, n, p, m, spread=(0.05, 3.0))
    abscissa = np.max(np.linalg.eigvals(Gc.A).real)
    shift = rng.uniform(0.1, 2.0) - abscissa if unstable else 0.0
    Gc = ct.ss(Gc.A + shift * np.eye(n), Gc.B, Gc.C, 0 * Gc.D)
    return ct.sample_system(Gc, Ts)


def random_cases(seed, count):
    rng = np.random.default_rng(seed)
    for i in range(count):
        size = (1, 1) if i % 2 == 0 else (2, 2)
        yield rng, random_plant(rng, *size, SAMPLING_TIMES[i % 3], unstable=bool(i % 4 >= 2))


def test_b_matches_a_dense_frequency_grid_and_never_exceeds_b_opt():
    """Random SISO/2×2, stable/unstable plants at 1–50 ms; LQG and central controllers (u = K y)."""
    checked = 0
    for rng, G in random_cases(seed=36, count=12):
        b_opt = optimal_margin(G)
        lqg = -observer_controller(G, float(rng.uniform(0.1, 10.0)))  # that helper's K is for u = −K y
        central, _ = central_ncf_controller(G, float(rng.uniform(1.05, 3.0)))
        for K in (lqg, central):
            b = generalized_margin(G, K)
            assert b > 0.0
            b_grid = 1.0 / four_block_peak(G, K)
            assert b <= b_grid * (1 + 1e-6)
            assert b == pytest.approx(b_grid, rel=1e-2)
            assert b <= b_opt * (1 + 1e-6)
            checked += 1
    assert checked == 24


def test_central_controller_attains_b_opt():
    """The central controller at γ = 1.001 γ_opt has b within 0.1 % of b_opt = 1/γ_opt (and not above it)."""
    for _, G in random_cases(seed=7, count=12):
        K, gamma = central_ncf_controller(G, 1.001)
        b, b_opt = generalized_margin(G, K), optimal_margin(G)
        assert 1.0 / gamma <= b * (1 + 1e-6)
        assert b <= b_opt * (1 + 1e-6)
        assert b == pytest.approx(b_opt, rel=1.5e-3)


def test_b_opt_of_a_static_gain_plant():
    """G = g static: b(g, k) = |1 − gk| / √((1 + g²)(1 + k²)) is 1 at k = −g (orthogonal graphs), so
    b_opt = 1; at k = −1/g it is 2|g|/(1 + g²)."""
    for g in (0.3, 1.0, 4.0):
        G = ct.ss(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), [[g]], 0.01)
        for k, b in ((-g, 1.0), (-1.0 / g, 2 * g / (1 + g**2))):
            K = ct.ss(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), [[k]], 0.01)
            assert generalized_margin(G, K) == pytest.approx(b, rel=1e-6)
        assert optimal_margin(G) == pytest.approx(1.0, rel=1e-6)


def test_sign_convention_is_positive_feedback():
    """G = 0.5/(z − 0.5) (DC gain 1): u = +2y moves the pole to 1.5 (b = 0); u = −2y to −0.5 (b > 0)."""
    G = ct.tf([0.5], [1, -0.5], 0.01)
    assert generalized_margin(G, ct.tf([2.0], [1], 0.01)) == 0.0
    b = generalized_margin(G, ct.tf([-2.0], [1], 0.01))
    assert b == pytest.approx(1.0 / four_block_peak(ct.ss(G), ct.ss(ct.tf([-2.0], [1], 0.01))), rel=1e-3)


def test_unstable_loops_have_zero_margin():
    unstable = [G for _, G in random_cases(seed=11, count=8) if np.max(np.abs(G.poles())) > 1.0]
    assert len(unstable) == 4
    for G in unstable:
        zero = ct.ss([], [], [], np.zeros((G.ninputs, G.noutputs)), G.dt)
        assert generalized_margin(G, zero) == 0.0
        assert delay_margin_samples(G, zero) == -1
        assert input_disk_margin(G, zero) == (0.0, 0.0, 0.0)


def test_norm_of_a_stable_system_with_a_pole_next_to_the_unit_circle():
    """‖Ts/(z − (1 − ε))‖∞ = Ts/ε at z = 1; control.norm answers inf for ε = 1e-7, the fallback does not."""
    Ts, eps = 1e-3, 1e-7
    system = ct.ss([[1 - eps]], [[Ts]], [[1.0]], [[0.0]], Ts)
    assert ct.norm(system, "inf", print_warning=False) == np.inf
    assert hinf_norm(system) == pytest.approx(Ts / eps, rel=1e-6)


def test_delay_margin_is_the_first_destabilizing_delay_minus_one():
    """Integrator plant Ts/(z − 1) with u = −k y: with d extra samples the loop z^{d}(z − 1) + kTs is stable
    iff every root is inside the unit circle; compare with direct polynomial roots."""
    Ts = 0.01
    G = ct.tf([Ts], [1, -1], Ts)
    for k in (5.0, 20.0, 60.0):
        K = ct.tf([-k], [1], Ts)
        expected = -1
        for d in range(0, 60):
            poly = np.zeros(d + 2)
            poly[0], poly[1] = 1.0, -1.0
            poly[-1] += k * Ts
            if np.max(np.abs(np.roots(poly))) >= 1.0:
                break
            expected = d
        assert delay_margin_samples(G, K, max_samples=60) == expected
        assert expected >= 0


def test_siso_input_disk_margin_from_the_balanced_sensitivity():
    """α = 1/max|(S − T)/2| with L = −KG (negative-feedback form of u = K y), on the same grid."""
    rng = np.random.default_rng(3)
    G = random_plant(rng, 1, 1, 0.01, unstable=False)
    K = -observer_controller(G, 1.0)
    omega = np.logspace(-3, np.log10(np.pi / 0.01) - 1e-9, 3000)
    L = (ct.frequency_response(-K * G, omega).complex).ravel()
    alpha = 1.0 / np.max(np.abs((1 - L) / (2 * (1 + L))))
    assert input_disk_margin(G, K, omega)[0] == pytest.approx(alpha, rel=1e-6)
    report = robust_stability(G, K)
    assert report.b <= report.b_opt and report.delay_margin_samples >= 0


def test_a_hidden_mode_on_the_unit_circle_is_refused():
    """A rank-1 2×2 plant behind an integrator in each input: one integrator is unobservable (no controller
    stabilizes it), which a Riccati solution that is not stabilizing would hide behind a huge 1/b_opt."""
    Ts = 0.01
    G = ct.ss([[0.9]], [[1.0, 0.5]], [[1.0], [2.0]], np.zeros((2, 2)), Ts)
    integrator = ct.ss([[1.0]], [[Ts]], [[1.0]], [[0.0]], Ts)
    with pytest.raises(ModelError, match="no stabilizing solution"):
        optimal_margin(G * ct.append(integrator, integrator))
    assert optimal_margin(G[0, 0] * integrator) > 0.1  # the same plant, SISO: minimal, b_opt exists


def test_continuous_plant_is_refused():
    with pytest.raises(ModelError, match="discrete"):
        optimal_margin(ct.tf([1], [1, 1]))


def test_ncf_riccati_solves_a_shaped_plant_with_a_double_pole_at_one():
    """A shaped ADIP plant of a held-out design (tests/shaped_adip_double_integrator.npz: the arm's
    integrator and W1's, a double pole at z = 1, Ts = 5 ms; ‖B‖ ≈ 0.009 in the bilinear image), on which
    scipy's ordered QZ gave up unscaled ("Reordering of (A, B) failed") and the design stopped with "pass a
    stabilizable and detectable plant". Solved on the frequency-scaled image: γ_opt equals SLICOT SG02AD's
    (python-control ``care`` on the unscaled image, written here) and the central controller at 1.01·γ_opt
    reaches b ≥ 1/γ by the frequency-grid four-block peak."""
    data = np.load(Path(__file__).with_name("shaped_adip_double_integrator.npz"))
    G = ct.ss(data["A"], data["B"], data["C"], data["D"], float(data["Ts"]))
    A, B, C, D = (np.real(M) for M in bilinear_to_continuous(G.A, G.B, G.C, G.D))
    X, _, _ = ct.care(A, B, C.T @ C, np.eye(B.shape[1]) + D.T @ D, C.T @ D)
    Z, _, _ = ct.care(A.T, C.T, B @ B.T, np.eye(C.shape[0]) + D @ D.T, B @ D.T)
    gamma_slicot = np.sqrt(1.0 + np.max(np.linalg.eigvals(X @ Z).real))
    assert ncf_riccati(G).gamma_opt == pytest.approx(gamma_slicot, rel=1e-6)
    K, gamma = central_ncf_controller(G, 1.01)
    assert 1.0 / four_block_peak(G, K) >= (1.0 - 1e-6) / gamma
