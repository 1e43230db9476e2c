"""Spline knots by separable least squares (thesis Ch. 3 §3.2–3.3, notes_002 §2.1–2.3, §5.1)."""

from pathlib import Path

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.spline_sls import SeparableProblem, fit_spline_knots, identify_spline_sls
from lpvflow.lpvio import LPVIO
from lpvflow.validate.metrics import bfr

pytestmark = pytest.mark.filterwarnings("ignore::lpvflow.basis.SchedulingRangeWarning")
TANKS_FMU = Path(__file__).resolve().parents[1] / "fmu_plants" / "build" / "tanks.fmu"
TRUE_KNOTS = [-0.4, 0.3]


def spline_system(form: str = "shifted") -> LPVIO:
    """SISO LPV-ARX whose coefficients are cubic splines with knots TRUE_KNOTS, p in [-1, 1]."""
    A = np.zeros((2, 4, 1, 1))
    A[0, :, 0, 0] = [-1.0, 0.1, 0.15, -0.2]
    A[1, :, 0, 0] = [0.4, -0.05, -0.05, 0.1]
    B = np.zeros((3, 4, 1, 1))
    B[1, :, 0, 0] = [1.0, 0.2, 0.5, -0.6]
    B[2, :, 0, 0] = [0.3, 0.0, -0.2, 0.2]
    return LPVIO(A, B, Basis.spline(TRUE_KNOTS), 1.0, form=form)


def simulated(io: LPVIO, n: int, seed: int) -> Dataset:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, io.nu))
    p = rng.uniform(-1, 1, size=(n, io.basis.n_p))
    return Dataset(u, io.simulate(u, p), p, io.Ts)


def test_batch_sls_recovers_true_knots_and_coefficients_noise_free():
    true = spline_system()
    est = identify_spline_sls(simulated(true, 2000, 0), 2, 2, 1, n_knots=2)
    knots = np.array(est.basis.knots[0])
    assert np.all(np.abs(knots - TRUE_KNOTS) < 0.01 * 2.0)  # 1 % of the scheduling range [-1, 1]
    np.testing.assert_allclose(est.A, true.A, atol=1e-6)
    np.testing.assert_allclose(est.B, true.B, atol=1e-6)


def test_static_form_mimo_knots_recovered():
    """Two outputs sharing the knots, static (Bamieh–Giarré) form."""
    basis = Basis.spline(TRUE_KNOTS)
    A = np.zeros((1, 4, 2, 2))
    A[0, :, 0, 0] = [-0.6, 0.05, 0.1, -0.1]
    A[0, :, 1, 1] = [-0.5, -0.05, -0.08, 0.12]
    A[0, :, 1, 0] = [0.1, 0.0, 0.05, 0.05]
    B = np.zeros((2, 4, 2, 1))
    B[1, :, 0, 0] = [1.0, 0.3, -0.4, 0.5]
    B[1, :, 1, 0] = [0.5, -0.2, 0.3, 0.4]
    true = LPVIO(A, B, basis, 1.0, form="static")
    fit = fit_spline_knots(simulated(true, 1500, 1), 1, 1, 1, 2, form="static", starts=3)
    assert np.all(np.abs(np.array(fit.knots[0]) - TRUE_KNOTS) < 0.02)
    assert fit.cost < 1e-20


def test_recursive_variant_converges_to_the_true_knots():
    data = simulated(spline_system(), 1000, 2)
    fit = fit_spline_knots(data, 2, 2, 1, 2, starts=1, recursive=True, forgetting=0.999, passes=4)
    assert np.all(np.abs(np.array(fit.knots[0]) - TRUE_KNOTS) < 0.02)


def test_kaufman_gradient_equals_the_finite_difference_gradient_of_the_reduced_cost():
    """J_Sᵀ E / n is the exact gradient of V(η) (variable projection), here checked at off-optimum knots
    with noisy data: a wrong sign or factor in ∂|p−η|³/∂η would fail this."""
    data = simulated(spline_system(), 600, 3)
    noisy = Dataset(data.u, data.y + 0.05 * np.random.default_rng(4).normal(size=data.y.shape), data.p, 1.0)
    problem = SeparableProblem(noisy, 2, 2, 1, 2, "shifted")
    z = problem.unit([[-0.2, 0.5]])
    E, J = problem.residuals(z)
    grad = J.T @ E / problem.n_eff
    h = 1e-6
    fd = [(problem.cost(z + h * e) - problem.cost(z - h * e)) / (2 * h) for e in np.eye(len(z))]
    np.testing.assert_allclose(grad, fd, rtol=1e-5)


def test_knots_stay_inside_the_data_range_and_ordered_with_two_scheduling_signals():
    rng = np.random.default_rng(5)
    n = 800
    u, p = rng.normal(size=(n, 1)), np.column_stack([rng.uniform(0, 2, n), rng.uniform(-3, -1, n)])
    y = np.convolve(u[:, 0] * (1 + np.abs(p[:, 0] - 1.2) ** 3), [0, 1, 0.5])[:n, None]
    y += 0.2 * rng.normal(size=(n, 1))
    fit = fit_spline_knots(Dataset(u, y, p, 1.0), 1, 2, 1, 2, starts=4, seed=1)
    for i, knots in enumerate(fit.knots):
        assert list(knots) == sorted(knots) and knots[0] < knots[1]
        assert p[:, i].min() <= knots[0] and knots[1] <= p[:, i].max()
    assert abs(fit.knots[0][0] - 1.2) < 0.05 or abs(fit.knots[0][1] - 1.2) < 0.05


@pytest.mark.parametrize(
    "kwargs, message",
    [({"n_knots": 0}, "n_knots"), ({"n_knots": 1, "starts": 0}, "starts"),
     ({"n_knots": 1, "forgetting": 1.5}, "forgetting")],
)
def test_bad_arguments_raise_data_error(kwargs, message):
    with pytest.raises(DataError, match=message):
        fit_spline_knots(simulated(spline_system(), 200, 6), 2, 2, 1, **kwargs)


def test_constant_scheduling_is_refused():
    data = simulated(spline_system(), 200, 7)
    with pytest.raises(DataError, match="constant"):
        identify_spline_sls(Dataset(data.u, data.y, np.ones((200, 1)), 1.0), 2, 2, 1, 1)


def tanks_data(seed: int, duration: float, lo: float, hi: float) -> Dataset:
    from lpvflow.experiment import run_fmu_experiment

    rec = run_fmu_experiment(TANKS_FMU, 0.2, duration,
                             inputs={"pump_voltage": f"aprbs:lo={lo},hi={hi},min_hold=4,max_hold=40"},
                             parameters={"effect_noise_std": 0.0002}, seed=seed, progress=False)
    c = rec.columns
    return Dataset(c["pump_voltage"], c["lower_level"], c["level"], 0.2, ["V"], ["h2"], ["level"])


@pytest.mark.skipif(not TANKS_FMU.exists(), reason="tanks FMU not built (make fmus)")
def test_tanks_spline_beats_polynomial_with_the_same_number_of_coefficients():
    """Thesis §5.1 (Table 3.1) on our tanks FMU: scheduling on the measured lower level, na = nb = 3,
    nk = 2; K knots (K + 2 basis functions) against a polynomial of degree K + 1 (same count)."""
    est, val = tanks_data(1, 1200.0, 1.0, 13.0), tanks_data(2, 600.0, 2.0, 11.0)

    def validation_bfr(model: LPVIO) -> float:
        return float(bfr(val.y, model.simulate(val.u, val.p))[0])

    for k in (1, 2):
        spline = validation_bfr(identify_spline_sls(est, 3, 3, 2, n_knots=k))
        poly = validation_bfr(identify_arx(est, 3, 3, 2, f"poly:{k + 1}"))
        assert spline > poly, (k, spline, poly)
