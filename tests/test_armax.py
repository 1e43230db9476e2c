"""LPV-ARMAX by pseudo-linear regression: recovers C, hence the innovation gain K of to_ss()."""

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.armax import identify_armax
from lpvflow.lpvio import LPVIO


def innovation_model(form: str) -> LPVIO:
    A = np.zeros((2, 2, 1, 1))
    A[0, :, 0, 0] = [-0.6, 0.3]
    A[1, :, 0, 0] = [0.2, -0.1]
    B = np.zeros((2, 2, 1, 1))
    B[1, :, 0, 0] = [1.0, 0.5]
    C = np.zeros((1, 2, 1, 1))
    C[0, :, 0, 0] = [0.5, -0.3]
    one = np.ones((1, 1), dtype=int)
    return LPVIO(A, B, Basis.affine(), 1.0, C=C, form=form, na=2 * one, nb=one, nk=one)


def armax_data(form: str, n: int = 20000, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    p = (0.5 + 0.5 * np.sin(0.05 * np.arange(n)))[:, None]
    u = rng.standard_normal((n, 1))
    e = 0.3 * rng.standard_normal((n, 1))
    return Dataset(u, innovation_model(form).simulate(u, p, e=e), p, 1.0)


@pytest.mark.parametrize("form", ["shifted", "static"])
def test_armax_recovers_the_noise_polynomial(form):
    io = identify_armax(armax_data(form), 2, 1, 1, nc=1, basis="affine", form=form)
    true = innovation_model(form)
    np.testing.assert_allclose(io.C, true.C, atol=0.04)
    np.testing.assert_allclose(io.A, true.A, atol=0.04)
    assert io.noise_cov[0, 0] == pytest.approx(0.09, rel=0.05)


def test_armax_gives_the_innovation_gain_of_the_known_model():
    data = armax_data("shifted")
    io = identify_armax(data, 2, 1, 1, nc=1, basis="affine", form="shifted")
    ss, true_ss = io.to_ss(), innovation_model("shifted").to_ss()
    np.testing.assert_allclose(ss.K, true_ss.K, atol=0.05)
    # the realized K reproduces the ARMAX noise path exactly
    e = np.random.default_rng(9).standard_normal((500, 1))
    np.testing.assert_allclose(ss.simulate(data.u[:500], data.p[:500], e=e),
                               io.simulate(data.u[:500], data.p[:500], e=e), atol=1e-9)


def test_armax_beats_arx_one_step_prediction_on_coloured_equation_error():
    from lpvflow.identify.arx import identify_arx, prediction_residuals

    data = armax_data("shifted", n=8000, seed=1)
    arx = identify_arx(data, 2, 1, 1, "affine")
    armax = identify_armax(data, 2, 1, 1, nc=1, basis="affine")
    assert armax.noise_cov[0, 0] < np.mean(prediction_residuals(arx, data) ** 2)


def test_nc_zero_is_refused():
    with pytest.raises(DataError, match="nc"):
        identify_armax(armax_data("shifted", n=300), 2, 1, 1, nc=0, basis="affine")
