"""IV-ARX, IV-OE and refined IV: consistency where least squares is biased (thesis Ch. 4)."""

from functools import partial

import numpy as np
import pytest
import scipy.signal

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify import montecarlo as mc
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.iv import identify_iv_arx, identify_iv_oe, identify_riv, parameter_vector
from lpvflow.lpvio import LPVIO


def mimo_model(form: str) -> LPVIO:
    """Two outputs, two inputs, affine in one scheduling signal, stable for p in [0, 1]."""
    A = np.zeros((1, 2, 2, 2))
    A[0, 0] = [[-0.5, 0.1], [0.05, -0.3]]
    A[0, 1] = [[0.2, 0.0], [-0.1, 0.1]]
    B = np.zeros((2, 2, 2, 2))
    B[1, 0] = [[1.0, 0.3], [0.2, 0.8]]
    B[1, 1] = [[0.4, -0.2], [0.1, 0.3]]
    one = np.ones((2, 2), dtype=int)
    return LPVIO(A, B, Basis.affine(), 1.0, form=form, na=one, nb=one, nk=one)


def mimo_data(form: str, noise: float, seed: int = 0, n: int = 4000) -> Dataset:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, (n, 2))
    p = (0.5 + 0.5 * np.sin(0.07 * np.arange(n)))[:, None]
    x = mimo_model(form).simulate(u, p)
    return Dataset(u, x + noise * rng.standard_normal((n, 2)), p, 1.0)


def test_iv_oe_bias_at_15db_is_ten_times_below_least_squares_on_the_same_runs():
    trial = partial(mc.ch4_trial, snr_db=15, noise="white", methods=("LS", "IV-OE"))
    est = mc.run_monte_carlo(trial, runs=8, seed=3, workers=1, progress=False)
    ls = mc.summarize(est["LS"], mc.CH4_P0)["bias"]
    ivoe = mc.summarize(est["IV-OE"], mc.CH4_P0)["bias"]
    assert ls > 1.0  # the benchmark's LS bias (thesis Table 4.1: 1.2212)
    assert ivoe * 10 < ls


@pytest.mark.parametrize("form", ["shifted", "static"])
@pytest.mark.parametrize("method", [identify_iv_arx, identify_iv_oe,
                                    partial(identify_iv_oe, auxiliary="batch")])
def test_mimo_iv_recovers_noise_free_model_exactly(form, method):
    data = mimo_data(form, noise=0.0)
    io = method(data, 1, 1, 1, "affine", form=form)
    np.testing.assert_allclose(parameter_vector(io), parameter_vector(mimo_model(form)), atol=1e-9)


@pytest.mark.parametrize("form", ["shifted", "static"])
def test_mimo_iv_oe_removes_the_output_noise_bias_of_least_squares(form):
    data = mimo_data(form, noise=0.5, seed=1, n=20000)
    true = parameter_vector(mimo_model(form))
    ls_err = np.linalg.norm(parameter_vector(identify_arx(data, 1, 1, 1, "affine", form=form)) - true)
    iv_err = np.linalg.norm(parameter_vector(identify_iv_oe(data, 1, 1, 1, "affine", form=form)) - true)
    assert iv_err < ls_err / 3


def test_shifted_iv_oe_model_is_realizable_with_the_same_input_output_behaviour():
    data = mimo_data("shifted", noise=0.1, seed=2)
    io = identify_iv_oe(data, 1, 1, 1, "affine", form="shifted")
    np.testing.assert_allclose(io.to_ss().simulate(data.u, data.p), io.simulate(data.u, data.p), atol=1e-9)


def coloured_siso(form: str, seed: int, n: int = 5000) -> tuple[Dataset, np.ndarray]:
    rng = np.random.default_rng(seed)
    true = mc.ch4_model(form=form)
    u = rng.uniform(-1, 1, n)
    p = 0.5 + 0.5 * np.sin(0.35 * np.pi * np.arange(n))
    x = true.simulate(u[:, None], p[:, None])[:, 0]
    v = scipy.signal.lfilter([1.0], mc.CH4_NOISE_DEN, rng.standard_normal(n))
    v *= np.sqrt(np.mean(x**2) / np.mean(v**2) / 10 ** 1.5)
    return Dataset(u[:, None], (x + v)[:, None], p[:, None], 1.0), parameter_vector(true)


@pytest.mark.parametrize("form", ["shifted", "static"])
def test_refined_iv_is_consistent_under_coloured_noise(form):
    errs = {"ls": [], "riv": [], "sriv": []}
    for seed in range(3):
        data, true = coloured_siso(form, seed)
        b = Basis.poly(2)
        errs["ls"].append(parameter_vector(identify_arx(data, 2, 2, 1, b, form=form)) - true)
        errs["riv"].append(parameter_vector(identify_riv(data, 2, 2, 1, b, form=form)) - true)
        sriv = identify_riv(data, 2, 2, 1, b, form=form, simplified=True)
        errs["sriv"].append(parameter_vector(sriv) - true)
    bias = {k: np.linalg.norm(np.mean(v, axis=0)) for k, v in errs.items()}
    assert bias["riv"] < bias["ls"] / 10
    assert bias["sriv"] < bias["ls"] / 5


def test_bad_requests_raise_one_line_errors():
    data = mimo_data("shifted", noise=0.0, n=500)
    with pytest.raises(DataError, match="auxiliary"):
        identify_iv_oe(data, 1, 1, 1, "affine", auxiliary="kalman")
    with pytest.raises(DataError, match="one output"):
        identify_riv(data, 1, 1, 1, "affine")
    with pytest.raises(DataError, match="form"):
        identify_iv_arx(data, 1, 1, 1, "affine", form="dynamic")


def test_instrumental_solve_accepts_good_instruments_of_an_ill_conditioned_regressor():
    """The test is on the canonical correlations of instruments and regressors, not on the
    condition of ζᵀφ, which squares the regressor's collinearity (a monomial basis in a signal far
    from zero, slow outputs): instruments spanning the regressors' space, ζ = φG, give the IV
    estimate, though the normal matrix looks singular to a condition test."""
    from lpvflow.identify.iv import IV_RCOND, solve_instrumental

    rng = np.random.default_rng(11)
    n, m = 3000, 12
    for _ in range(5):
        u = np.linalg.qr(rng.normal(size=(n, m)))[0]
        v = np.linalg.qr(rng.normal(size=(m, m)))[0]
        phi = (u * np.geomspace(1.0, 3e-7, m)) @ v.T  # cond(φ) ≈ 3·10⁶
        zeta = phi @ (np.eye(m) + 0.3 * rng.normal(size=(m, m)) / np.sqrt(m))
        theta = rng.normal(size=m)
        scaled_z, scaled_p = zeta / np.linalg.norm(zeta, axis=0), phi / np.linalg.norm(phi, axis=0)
        s = np.linalg.svd(scaled_z.T @ scaled_p, compute_uv=False)
        assert s[-1] / s[0] <= IV_RCOND  # the case: the normal matrix's condition test refuses it
        np.testing.assert_allclose(solve_instrumental(zeta, phi, phi @ theta), theta, rtol=1e-6)


def test_instrumental_solve_refuses_instruments_that_miss_a_regressor_direction():
    from lpvflow.identify.iv import solve_instrumental

    rng = np.random.default_rng(12)
    phi = rng.normal(size=(2000, 6))
    zeta = phi.copy()
    zeta[:, -1] = rng.normal(size=2000)
    q, _ = np.linalg.qr(phi)
    zeta[:, -1] -= q @ (q.T @ zeta[:, -1])  # orthogonal to every regressor: ζᵀφ is singular
    zeta[:, -1] /= np.linalg.norm(zeta[:, -1])
    zeta[:, :-1] = phi[:, :-1]
    with pytest.raises(DataError, match="instrument matrix is singular"):
        solve_instrumental(zeta, phi, phi @ np.ones(6))
    zeta[:, 0] = 0.0  # an instrument without excitation
    with pytest.raises(DataError, match="instrument matrix is singular"):
        solve_instrumental(phi[:, :3] * 0 + zeta[:, :3], phi[:, :3], phi[:, 0])
