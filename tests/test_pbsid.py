"""LPV PBSIDopt (seed 004): primal = kernel, exactness on noise-free data, row selection on periodic
scheduling, closed-loop consistency, bilinear systems, GCV, and the error paths.

The reference systems are seed 004's benchmarks as coded in the PBSID toolbox (notes_004 §6).
"""

from __future__ import annotations

import itertools
import warnings

import control
import numpy as np
import pytest
import scipy.signal

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.identify.pbsid import bilinear_data, identify_pbsid, regression_rows, state_matrix
from lpvflow.identify.pbsid_examples import verdult_benchmark, verdult_experiment, verdult_signals
from lpvflow.identify.pbsid_kernel import gcv_curve, kernel_row_sums, primal_blocks
from lpvflow.models import LPVSS
from lpvflow.validate.metrics import vaf

pytestmark = pytest.mark.filterwarnings("ignore::lpvflow.basis.SchedulingRangeWarning")


def sub_markov(A: np.ndarray, B: np.ndarray, C: np.ndarray, depth: int = 2) -> np.ndarray:
    """C A_{l1} ⋯ A_{ls} B_j for every word of length s ≤ depth: invariant under a state transform."""
    blocks = []
    for s in range(depth + 1):
        for word in itertools.product(range(A.shape[0]), repeat=s):
            left = C
            for letter in word:
                left = left @ A[letter]
            blocks += [(left @ Bj).ravel() for Bj in B]
    return np.concatenate(blocks)


@pytest.fixture(scope="module")
def benchmark_validation():
    u, p = verdult_signals(1000, np.random.default_rng(99))
    return u, p, verdult_benchmark().simulate(u, p)


# ------------------------------------------------------------------------- data matrices / kernel
def test_kernel_blocks_equal_explicit_products_of_primal_blocks():
    """Theorem 10 / Lemma 8: S_i = Σ_j (Z^{i,j})ᵀ Z^{1,j} with Z^{i,j} the leading rows of Z^{1,j−i+1}."""
    rng = np.random.default_rng(0)
    n, past, m, dz = 40, 3, 3, 2
    z = rng.normal(size=(n, dz))
    mu = np.column_stack([np.ones(n), rng.normal(size=(n, m - 1))])
    blocks = primal_blocks(z, mu, past)
    assert [b.shape[0] for b in blocks] == [dz * m ** (past - j + 1) for j in range(1, past + 1)]
    for c in (0, 7):  # one column written out: μ_{c+2} ⊗ μ_{c+1} ⊗ μ_c ⊗ z_c
        expected = np.kron(mu[c + 2], np.kron(mu[c + 1], np.kron(mu[c], z[c])))
        np.testing.assert_allclose(blocks[0][:, c], expected)
    sums = kernel_row_sums(z, mu, past, past)
    for i in range(1, past + 1):
        explicit = sum(blocks[j - i][: blocks[j - 1].shape[0]].T @ blocks[j - 1] for j in range(i, past + 1))
        np.testing.assert_allclose(sums[i - 1], explicit, rtol=1e-12, atol=1e-10)


def test_gcv_curve_matches_its_definition():
    rng = np.random.default_rng(1)
    W = rng.normal(size=(6, 15))
    Y = rng.normal(size=(2, 15))
    G = W.T @ W
    eigenvalues, Q = np.linalg.eigh(G)
    lambdas = np.array([1e-3, 0.1, 10.0])
    curve = gcv_curve(eigenvalues, Y @ Q, 0.0, 15, lambdas)
    for lam, value in zip(lambdas, curve, strict=True):
        I_minus_H = np.eye(15) - G @ np.linalg.inv(G + lam * np.eye(15))
        direct = 15 * np.linalg.norm(Y @ I_minus_H) ** 2 / np.trace(I_minus_H) ** 2
        assert value == pytest.approx(direct, rel=1e-9)


def test_regression_rows_reproduce_table_1_of_the_paper():
    """Seed 004 Table 1 (m = 4, r = ℓ) counts the Z rows, i.e. ours minus the r rows of U."""
    for p, ell, rows in [(2, 1, 40), (3, 3, 504), (5, 5, 13640), (4, 2, 1360)]:
        assert regression_rows(ell, ell, 4, p) - ell == rows


# ------------------------------------------------------------------------ noise-free benchmark
@pytest.mark.parametrize("form", ["primal", "kernel"])
def test_noise_free_benchmark_identified_to_vaf_999(form, benchmark_validation):
    data, _ = verdult_experiment(1000, np.random.default_rng(5))
    u, p, y = benchmark_validation
    model = identify_pbsid(data, order=4, past=3, form=form)
    assert vaf(y, model.simulate(u, p)).min() >= 99.9
    assert model.reduction["order"] == 4


def test_order_from_singular_value_gap_is_the_true_order():
    data, _ = verdult_experiment(500, np.random.default_rng(6))
    model = identify_pbsid(data, past=3, form="kernel")
    s = np.asarray(model.reduction["singular_values"])
    assert model.nx == 4 and model.reduction["order_rule"].startswith("largest gap")
    assert s[4] < 1e-2 * s[3]


@pytest.mark.parametrize(("past", "regularization"), [(3, None), (5, None), (3, "gcv")])
def test_primal_and_kernel_forms_agree(past, regularization):
    """Both forms compute the same Γ^pK^pZ (noise-free, to 1e-8 relative), hence the same model."""
    data, _ = verdult_experiment(500, np.random.default_rng(7))
    mu = Basis.affine(3).eval(data.p)
    primal, info_p = state_matrix(data, mu, past, past, "primal", regularization)
    kernel, info_k = state_matrix(data, mu, past, past, "kernel", regularization)
    assert np.abs(primal - kernel).max() <= 1e-8 * np.abs(primal).max()
    assert info_p["lambda"] == pytest.approx(info_k["lambda"], rel=1e-6)


def test_primal_and_kernel_models_simulate_alike_on_noisy_data(benchmark_validation):
    data, _ = verdult_experiment(500, np.random.default_rng(8), snr_db=40)
    u, p, _ = benchmark_validation
    outputs = [identify_pbsid(data, 4, 3, form=f).simulate(u, p) for f in ("primal", "kernel")]
    assert np.abs(outputs[0] - outputs[1]).max() <= 1e-8 * np.abs(outputs[0]).max()


def test_gcv_regularization_beats_minimum_norm_when_parameters_outnumber_samples(benchmark_validation):
    """p = 5: q̃ = 6820 rows against N̄ = 495 columns; seed 004 Table 2 shows regularization helps."""
    u, p, y = benchmark_validation
    gains = []
    for seed in (10, 11):
        data, _ = verdult_experiment(500, np.random.default_rng(seed), snr_db=20)
        plain = vaf(y, identify_pbsid(data, 4, 5, form="kernel").simulate(u, p)).mean()
        model = identify_pbsid(data, 4, 5, form="kernel", regularization="gcv")
        assert model.reduction["lambda"] > 0
        gains.append(vaf(y, model.simulate(u, p)).mean() - plain)
    assert np.mean(gains) > 0


# ----------------------------------------------------------------------- periodic row selection
def flap_model() -> LPVSS:
    """Toolbox ex19 flapping dynamics with C = I and K^(1) = 0.3 I (notes_004 §6.2 [CHK] setting)."""
    A = np.array([[[0, 0.0734], [-6.5229, -0.4997]], [[-0.0021, 0], [-0.0138, 0.5196]]])
    B = np.array([[[-0.7221], [-9.6277]], [[0.0], [0.0]]])
    C = np.zeros((2, 2, 2))
    C[0] = np.eye(2)
    K = np.zeros((2, 2, 2))
    K[0] = 0.3 * np.eye(2)
    return LPVSS(A, B, C, np.zeros((2, 2, 1)), Basis.affine(1), 1.0, K=K)


def test_periodic_row_selection_reproduces_the_full_kernel_solution():
    n, past, period = 1000, 4, 10
    rng = np.random.default_rng(3)
    p = (np.cos(2 * np.pi * np.arange(n) / period) + 0.2)[:, None]
    u = rng.normal(size=(n, 1))
    data = Dataset(u, flap_model().simulate(u, p, e=0.1 * rng.normal(size=(n, 2))), p, 1.0)
    mu = Basis.affine(1).eval(p)
    full, info_full = state_matrix(data, mu, past, past, "kernel")
    chosen, info = state_matrix(data, mu, past, past, "kernel", periodic_rows=True)
    bound = period * 3 * past + 1  # P (r+ℓ) p rows, + r for D (notes_004 §3.3)
    assert info["rows"] <= bound < info_full["rows"] / 5
    assert np.abs(full - chosen).max() <= 1e-8 * np.abs(full).max()
    first, _ = state_matrix(data, mu, past, past, "kernel", periodic_rows=bound)
    assert np.abs(full - first).max() <= 1e-4 * np.abs(full).max()
    a = identify_pbsid(data, 2, past, form="kernel")
    b = identify_pbsid(data, 2, past, form="kernel", periodic_rows=True)
    np.testing.assert_allclose(sub_markov(b.A, b.B, b.C[0]), sub_markov(a.A, a.B, a.C[0]),
                               rtol=1e-6, atol=1e-8)


# ----------------------------------------------------------------------------------- closed loop
CL_PREDICTOR = np.array([[[0.3, 0.2], [0.0, 0.2]], [[0.1, 0.0], [0.05, 0.1]]])
CL_K = np.array([[[1.0], [0.4]], [[0.1], [0.0]]])
CL_C = np.array([[1.0, 0.0]])
CL_A = CL_PREDICTOR + CL_K @ CL_C  # A^(1) has an eigenvalue 1.368: open-loop unstable
CL_B = np.array([[[1.0], [0.5]], [[0.2], [0.0]]])


def closed_loop_data(n: int, rng: np.random.Generator) -> Dataset:
    """The unstable plant under a strictly causal observer-based LQ controller, reference excited."""
    gain, _, _ = control.dlqr(CL_A[0], CL_B[0], np.eye(2), 1.0)
    p = rng.uniform(-1, 1, n)
    r, e = rng.normal(size=n), 0.3 * rng.normal(size=n)
    x, xi = np.zeros(2), np.zeros(2)
    u, y = np.zeros(n), np.zeros(n)
    for k in range(n):
        u[k] = r[k] - gain[0] @ xi
        y[k] = CL_C[0] @ x + e[k]
        x = (CL_A[0] + p[k] * CL_A[1]) @ x + (CL_B[0] + p[k] * CL_B[1])[:, 0] * u[k] \
            + (CL_K[0] + p[k] * CL_K[1])[:, 0] * e[k]
        xi = CL_A[0] @ xi + CL_B[0][:, 0] * u[k] + CL_K[0][:, 0] * (y[k] - CL_C[0] @ xi)
    return Dataset(u[:, None], y[:, None], p[:, None], 1.0)


def test_closed_loop_unstable_plant_identified_consistently():
    assert max(abs(np.linalg.eigvals(CL_A[0]))) > 1.3
    truth = sub_markov(CL_A, CL_B, CL_C)
    errors = {}
    for n in (1000, 8000):
        runs = []
        for seed in range(4):
            model = identify_pbsid(closed_loop_data(n, np.random.default_rng(seed)), order=2, past=6)
            estimate = sub_markov(model.A, model.B, model.C[0])
            runs.append(np.linalg.norm(estimate - truth) / np.linalg.norm(truth))
        errors[n] = np.mean(runs)
    assert errors[8000] < 0.6 * errors[1000]
    assert errors[8000] < 0.03


# -------------------------------------------------------------------------------------- bilinear
def test_bilinear_system_through_input_scheduling():
    """Seed 004 Sec. 7.3: x⁺ = (A1 + u A2) x + B u, y = [1 1] x, identified with μ = [1, u]."""
    A = np.array([[[0.5, 0.5], [-0.5, 0.5]], [[0.2, 0.2], [-0.2, 0.2]]])
    B = np.array([[[1.0], [0.0]], [[0.0], [0.0]]])
    C = np.zeros((2, 1, 2))
    C[0] = [1.0, 1.0]
    system = LPVSS(A, B, C, np.zeros((2, 1, 1)), Basis.affine(1), 1.0)
    rng = np.random.default_rng(4)
    b, a = scipy.signal.butter(4, 0.8)
    u = 0.5 * scipy.signal.lfilter(b, a, rng.normal(size=(700, 1)), axis=0)
    y = system.simulate(u[:500], u[:500])
    data = bilinear_data(Dataset(u[:500], y, np.zeros((500, 1)), 1.0))
    assert np.array_equal(data.p, data.u)
    model = identify_pbsid(data, order=2, past=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        fresh = system.simulate(u[500:], u[500:])
        assert vaf(fresh, model.simulate(u[500:], u[500:])).min() >= 99.9


# ---------------------------------------------------------------------------------- error paths
@pytest.mark.parametrize(("kwargs", "error", "words"), [
    ({"form": "dual"}, ModelError, "form must be"),
    ({"order": 20, "past": 3}, ModelError, "order 20"),
    ({"past": 3, "future": 4}, ModelError, "future window"),
    ({"regularization": "lcurve"}, ModelError, "regularization"),
    ({"periodic_rows": True}, ModelError, "form='kernel'"),
    ({"form": "kernel", "periodic_rows": True, "regularization": "gcv"}, ModelError, "only one"),
    ({"basis": Basis.affine(2)}, DataError, "scheduling signal"),
])
def test_bad_arguments_raise_one_line_errors(kwargs, error, words):
    data, _ = verdult_experiment(300, np.random.default_rng(0))
    with pytest.raises(error, match=words) as info:
        identify_pbsid(data, **{"order": 4, "past": 3, **kwargs})
    assert "\n" not in str(info.value)


def test_too_short_data_is_refused():
    data, _ = verdult_experiment(40, np.random.default_rng(0))
    with pytest.raises(DataError, match="too few"):
        identify_pbsid(data, order=4, past=3)
