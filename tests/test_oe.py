"""LPV-OE by prediction error: analytic sensitivities and convergence to the true parameters."""

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.identify import montecarlo as mc
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.iv import Structure, parameter_vector, simulate_psi
from lpvflow.identify.oe import identify_oe, sensitivities
from lpvflow.lpvio import LPVIO
from tests.test_iv import mimo_model


def siso_data(form: str, noise: float = 0.0, seed: int = 0, n: int = 3000) -> Dataset:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, (n, 1))
    p = (0.5 + 0.5 * np.sin(0.35 * np.pi * np.arange(n)))[:, None]
    y = mc.ch4_model(form=form).simulate(u, p)
    return Dataset(u, y + noise * rng.standard_normal(y.shape), p, 1.0)


def perturbed(io: LPVIO, struct: Structure, scale: float, seed: int) -> LPVIO:
    """``io`` with every free parameter moved by scale·N(0, 1)."""
    rng = np.random.default_rng(seed)
    return struct.model([t + scale * rng.standard_normal(t.shape) for t in struct.thetas(io)])


@pytest.mark.parametrize("form", ["shifted", "static"])
def test_oe_converges_to_the_true_parameters_noise_free(form):
    data = siso_data(form)
    true = mc.ch4_model(form=form)
    init = perturbed(true, Structure.from_data(data, 2, 2, 1, "poly:2", form), 0.05, seed=1)
    assert np.linalg.norm(parameter_vector(init) - mc.CH4_P0) > 0.1
    io = identify_oe(data, 2, 2, 1, "poly:2", form=form, init=init)
    np.testing.assert_allclose(parameter_vector(io), mc.CH4_P0, atol=1e-7)


@pytest.mark.parametrize("form", ["shifted", "static"])
def test_sensitivities_match_finite_differences(form):
    data = siso_data(form, n=400)
    struct = Structure.from_data(data, 2, 2, 1, "poly:2", form)
    psi = struct.basis.eval(data.p)
    io = perturbed(mc.ch4_model(form=form), struct, 0.02, seed=2)
    theta = struct.thetas(io)[0]
    y0 = simulate_psi(io, data.u, psi)
    S = sensitivities(struct, io, y0, data.u, psi)[:, 0, :]
    h = 1e-6
    for m in range(len(theta)):
        step = theta.copy()
        step[m] += h
        fd = (simulate_psi(struct.model([step]), data.u, psi) - y0)[:, 0] / h
        np.testing.assert_allclose(S[:, m], fd, atol=1e-4 * (1 + np.abs(fd).max()))


def test_mimo_oe_converges_noise_free():
    rng = np.random.default_rng(5)
    n = 2000
    u = rng.uniform(-1, 1, (n, 2))
    p = (0.5 + 0.5 * np.sin(0.07 * np.arange(n)))[:, None]
    true = mimo_model("shifted")
    data = Dataset(u, true.simulate(u, p), p, 1.0)
    struct = Structure.from_data(data, 1, 1, 1, "affine", "shifted")
    io = identify_oe(data, 1, 1, 1, "affine", form="shifted", init=perturbed(true, struct, 0.03, seed=3))
    np.testing.assert_allclose(parameter_vector(io), parameter_vector(true), atol=1e-7)


def test_oe_is_consistent_under_white_output_noise():
    data = siso_data("static", noise=0.1, seed=4, n=5000)
    io = identify_oe(data, 2, 2, 1, "poly:2", form="static")
    ls = identify_arx(data, 2, 2, 1, "poly:2", form="static")
    oe_err = np.linalg.norm(parameter_vector(io) - mc.CH4_P0)
    assert oe_err < np.linalg.norm(parameter_vector(ls) - mc.CH4_P0) / 3
    assert io.noise_cov[0, 0] == pytest.approx(0.01, rel=0.1)  # simulation error = the output noise
