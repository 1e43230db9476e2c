"""KCCA-LFR identification (seed 003): Stage 1 solves eq. (16), Stage 2 recovers the LFR, and the paper's
Examples 1 (rational, D11 = −0.5) and 2 (affine, D11 = 0) reach its validation BFR."""

import numpy as np
import pytest
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify import kcca_lfr
from lpvflow.identify.kcca_lfr import (
    fit_affine_lfr,
    fit_lfr_coordinate_descent,
    identify_kcca_lfr,
    kcca_states,
)
from lpvflow.lfr import LPVLFR
from lpvflow.validate.metrics import bfr

#: Paper's single-run validation BFR (seed 003 Table I).
PAPER_BFR = {"rational": 92.71, "affine": 96.05}


def seed003_system(d11: float) -> LPVLFR:
    """System (26) of seed 003 with w = p z; D11 = −0.5 (Example 1) or 0 (Example 2)."""
    return LPVLFR([[0, 1], [-0.1, 0.7]], [[0], [0.816]], [[1.073], [1.075]], [[0.524, -0.625]], [[d11]],
                  [[0.5]], [[0.443, 0.060]], [[0.5]], [[0.5]], np.array([[[0.0]], [[1.0]]]),
                  Basis.affine(1), 1.0)


def seed003_data(system: LPVLFR, n: int, rng: np.random.Generator, noise_std: float
                 ) -> tuple[Dataset, np.ndarray, np.ndarray]:
    """u ~ U(−1, 1), p(k) = 0.5 sin k + U(−0.5, 0.5), x(0) = 0; returns (data, noise-free y, states)."""
    u = rng.uniform(-1, 1, (n, 1))
    p = (0.5 * np.sin(np.arange(1, n + 1)) + rng.uniform(-0.5, 0.5, n))[:, None]
    y, x = system.simulate(u, p, return_states=True)
    return Dataset(u, y + noise_std * rng.normal(size=y.shape), p, 1.0), y, x


def example_bfr(d11: float, seed: int) -> float:
    """One run of the paper's protocol: N = 400 noisy training samples, N_val = 400 noise-free."""
    rng = np.random.default_rng(seed)
    system = seed003_system(d11)
    train, _, _ = seed003_data(system, 400, rng, 0.05)
    val, y_val, _ = seed003_data(system, 400, rng, 0.0)
    model = identify_kcca_lfr(train, 2, affine=d11 == 0)
    return float(bfr(y_val, model.simulate(val.u, val.p))[0])


def eq16_matrices(data: Dataset, d: int, gamma: float) -> tuple[np.ndarray, ...]:
    """L and R of eq. (16) built literally from the kernels (17), and K_ff, K_pp."""
    k = np.arange(d, data.N - d + 1)
    w = kcca_lfr._windows
    K_pp = kcca_lfr._kernel(np.hstack([w(data.u, k - d, d), w(data.y, k - d, d)]), w(data.p, k - d, d),
                            2.0, 10.5)
    K_ff = kcca_lfr._kernel(np.hstack([w(data.u, k, d), w(data.y, k, d)]), w(data.p, k, d), 2.0, 10.5)
    m = len(k)
    L = np.block([[np.zeros((m, m)), K_pp], [K_ff, np.zeros((m, m))]])
    R = scipy.linalg.block_diag(gamma * K_ff + np.eye(m), gamma * K_pp + np.eye(m))
    return L, R, K_ff, K_pp


def test_stage1_solves_the_generalized_eigenproblem_16():
    # (16) solved literally with a dense non-symmetric generalized eigensolver on a small record
    data, _, _ = seed003_data(seed003_system(-0.5), 60, np.random.default_rng(0), 0.05)
    states = kcca_states(data, 2, 3, 2.0, 10.5, 500.0, 500.0)
    L, R, K_ff, K_pp = eq16_matrices(data, 3, 500.0)
    m = len(K_ff)
    lam, vec = scipy.linalg.eig(L, R)
    order = np.argsort(-lam.real)[:2]
    np.testing.assert_allclose(states.eigenvalues, lam.real[order], rtol=1e-6)
    for j, col in enumerate(order):
        eta, kappa = vec[:m, col].real, vec[m:, col].real
        x_ref = (K_ff @ eta + K_pp @ kappa) / 2  # eqs. (18)-(19) averaged
        cos = abs(x_ref @ states.x[:, j]) / np.linalg.norm(x_ref) / np.linalg.norm(states.x[:, j])
        assert cos > 1 - 1e-6


def test_the_literal_eq20_svd_loses_one_of_the_two_state_estimates():
    # why Stage 1 does not use eq. (20): R⁻¹L is block anti-diagonal, so every right singular vector
    # [V1; V2] has V1 or V2 equal to zero and (18) or (19) would give a zero state (notes_003 §6.2)
    data, _, _ = seed003_data(seed003_system(-0.5), 60, np.random.default_rng(0), 0.05)
    L, R, K_ff, _ = eq16_matrices(data, 3, 500.0)
    m = len(K_ff)
    V = np.linalg.svd(np.linalg.solve(R, L))[2].T
    for j in range(4):
        blocks = sorted([np.linalg.norm(V[:m, j]), np.linalg.norm(V[m:, j])])
        assert blocks[0] < 1e-8 * blocks[1]


def test_affine_stage2_recovers_the_system_from_true_states():
    system = seed003_system(0.0)
    data, _, x = seed003_data(system, 200, np.random.default_rng(1), 0.0)
    th = fit_affine_lfr(x, data.u, data.y, data.p)
    fitted = LPVLFR(th.A, th.B1, th.B2, th.C1, th.D11, th.D12, th.C2, th.D21, th.D22, system.delta,
                    system.basis, 1.0)
    for p in (-1.0, 0.0, 0.6):
        for got, want in zip(fitted.matrices([p]), system.matrices([p]), strict=True):
            np.testing.assert_allclose(got, want, atol=1e-9)


def test_coordinate_descent_recovers_the_rational_lfr_and_keeps_the_latent_scale():
    system = seed003_system(-0.5)
    data, _, x = seed003_data(system, 300, np.random.default_rng(2), 0.0)
    z0 = np.random.default_rng(3).uniform(-1, 1, (data.N, 1))
    th, sweeps = fit_lfr_coordinate_descent(x, data.u, data.y, data.p, z0, iterations=2000, tol=1e-12)
    assert th.D11[0, 0] == pytest.approx(-0.5, abs=1e-3)  # D11 is identifiable for scalar Δ
    z = (x[:-1] @ th.C1.T + data.u @ th.D12.T) / (1 - th.D11[0, 0] * data.p)
    assert np.sqrt(np.mean(z**2)) == pytest.approx(1.0, rel=1e-3)  # normalised, not collapsing to 0
    fitted = LPVLFR(th.A, th.B1, th.B2, th.C1, th.D11, th.D12, th.C2, th.D21, th.D22, system.delta,
                    system.basis, 1.0)
    u_val = np.random.default_rng(4).uniform(-1, 1, (200, 1))
    p_val = np.random.default_rng(5).uniform(-1, 1, (200, 1))
    assert bfr(system.simulate(u_val, p_val), fitted.simulate(u_val, p_val))[0] > 99.5
    assert sweeps < 2000


# A single seed varies: over 10 seeds the validation BFR ranged over [95.3, 97.8] % (affine) and
# [91.0, 95.8] % (rational) (benchmarks/results/cva_kcca.json); the fast check of one seed therefore
# asks for the 10-seed minimum less one point, the paper's figure is for the 10-seed mean (slow test).
@pytest.mark.parametrize(("d11", "floor"), [(0.0, 94.3), (-0.5, 90.0)])
def test_one_seed_of_the_paper_examples(d11, floor):
    assert example_bfr(d11, seed=0) >= floor


@pytest.mark.slow
@pytest.mark.parametrize(("d11", "kind"), [(0.0, "affine"), (-0.5, "rational")])
def test_ten_seed_mean_reaches_the_paper(d11, kind):
    scores = [example_bfr(d11, seed) for seed in range(10)]
    assert np.mean(scores) >= PAPER_BFR[kind]


def test_bad_settings_raise_one_line_errors():
    data, _, _ = seed003_data(seed003_system(0.0), 60, np.random.default_rng(6), 0.05)
    with pytest.raises(DataError, match="init must be"):
        identify_kcca_lfr(data, 2, init="zeros")
    with pytest.raises(DataError, match="must be > 0"):
        kcca_states(data, 2, sigma=0.0)
    with pytest.raises(DataError, match="too few"):
        kcca_states(data.select(slice(0, 8)), 2)
    long = Dataset(np.zeros((9000, 1)), np.zeros((9000, 1)), np.zeros((9000, 1)), 1.0)
    with pytest.raises(DataError, match="use at most 8005 samples"):
        kcca_states(long, 2)


def test_mimo_lfr_with_two_scheduling_signals():
    # 3 states, Δ(p) = diag(p1, p2), 2 inputs, 2 outputs: both Stage-2 variants run and the
    # coordinate descent (true D11 = diag(−0.3, 0.2)) fits better than the affine restriction
    rng = np.random.default_rng(0)
    delta = np.zeros((3, 2, 2))
    delta[1, 0, 0] = delta[2, 1, 1] = 1.0
    system = LPVLFR(np.diag([0.5, 0.3, -0.4]), 0.3 * rng.normal(size=(3, 2)), rng.normal(size=(3, 2)),
                    0.5 * rng.normal(size=(2, 3)), np.diag([-0.3, 0.2]), 0.3 * rng.normal(size=(2, 2)),
                    rng.normal(size=(2, 3)), 0.3 * rng.normal(size=(2, 2)), np.zeros((2, 2)), delta,
                    Basis.affine(2), 1.0)

    def record(n: int, noise: float) -> tuple[Dataset, np.ndarray]:
        u, p = rng.uniform(-1, 1, (n, 2)), rng.uniform(-1, 1, (n, 2))
        y = system.simulate(u, p)
        return Dataset(u, y + noise * rng.normal(size=y.shape), p, 1.0), y

    train, _ = record(600, 0.01)
    val, y_val = record(400, 0.0)
    fits = {aff: bfr(y_val, identify_kcca_lfr(train, 3, affine=aff, horizon=4).simulate(val.u, val.p))
            for aff in (True, False)}
    assert np.all(fits[False] > 98) and np.all(fits[True] > 95)
    assert np.mean(fits[False]) > np.mean(fits[True])
