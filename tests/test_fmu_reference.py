"""FMU references for frozen validation: finite-difference linearization and small-signal local ARX."""

from pathlib import Path

import control as ct
import numpy as np
import pytest

from lpvflow.errors import DataError, ModelError
from lpvflow.validate.fmu_reference import (
    FmuLinearization,
    FmuLocalModels,
    FmuOperatingPoints,
    arx_statespace,
    sample_like_fmu,
)
from lpvflow.validate.nugap import nugap
from tests.fmu_builds import built_fmu

ROOT = Path(__file__).resolve().parents[1]
Ts = 0.2
# Default tank parameters from fmu_plants/tanks/README.md
AREA, A1, A2, KP, G = 1.5518e-3, 1.7817e-5, 1.7817e-5, 3.3e-6, 9.81


@pytest.fixture(scope="module")
def tanks() -> Path:
    return built_fmu("tanks")


def analytic_tanks(h2: float) -> tuple[ct.StateSpace, float]:
    """README equations linearized at the equilibrium with lower level h2: h1 = (a2/a1)² h2,
    V = a2 √(2 g h2) / k_p, ∂(a √(2 g h))/∂h = a g / √(2 g h)."""
    h1 = (A2 / A1) ** 2 * h2
    k1, k2 = A1 * G / np.sqrt(2 * G * h1) / AREA, A2 * G / np.sqrt(2 * G * h2) / AREA
    A = np.array([[-k1, 0.0], [k1, -k2]])
    return ct.ss(A, [[KP / AREA], [0.0]], [[0.0, 1.0]], [[0.0]]), A2 * np.sqrt(2 * G * h2) / KP


def relative_error(estimate: np.ndarray, exact: np.ndarray) -> float:
    return float(np.max(np.abs(estimate - exact)) / np.max(np.abs(exact)))


def test_finite_difference_linearization_equals_analytic_one_after_zoh(tanks):
    with FmuLinearization(tanks, Ts, "diag_scheduling") as linearize:
        for level in (0.05, 0.12, 0.25):
            G = linearize(np.array([level]))
            exact, voltage = analytic_tanks(level)
            point = linearize.equilibrium(np.array([level]))
            assert point.u[0] == pytest.approx(voltage, rel=1e-9)
            assert point.x == pytest.approx([(A2 / A1) ** 2 * level, level], rel=1e-9)
            sampled = ct.sample_system(exact, Ts, "zoh")
            assert G.dt == Ts
            for M, E in ((G.A, sampled.A), (G.B, sampled.B), (G.C, sampled.C)):
                assert relative_error(M, E) < 1e-5
            assert np.all(G.D == 0)


def test_adip_equilibria_are_found_across_the_upright_point_in_grid_order():
    # Regression: θ = 0 solved from θ < 0 comes out as ~1e-22 in every entry; started from there,
    # least_squares' first trust region had that size and the θ > 0 points were refused.
    grid = np.linspace(-0.6, 0.6, 9)
    with FmuOperatingPoints(built_fmu("adip"), 0.005, ["sin(arm_angle)"]) as reference:
        points = [reference.equilibrium(np.array([theta])) for theta in grid]
    np.testing.assert_allclose([op.x[0] for op in points], np.arcsin(grid), atol=1e-9)
    # holding voltage −d1 sin φ1 / k_τ (fmu_plants/adip/README.md): odd in θ, 4.07 V at sin 75°
    holding = -4.070791 * grid / np.sin(np.radians(75))
    np.testing.assert_allclose([op.u[0] for op in points], holding, rtol=1e-6, atol=1e-9)


def test_the_fmu_input_dead_time_is_part_of_the_linearization(tanks):
    """effect_input_delay = 3 samples: the reference is the delay-free ZOH model times z⁻³ (frequency
    response at 50 points), and its step response is the delay-free one shifted by 3 samples."""
    level = np.array([0.12])
    with FmuLinearization(tanks, Ts, "diag_scheduling") as plain:
        G = plain(level)
    with FmuLinearization(tanks, Ts, "diag_scheduling", parameters={"effect_input_delay": 3 * Ts}) as delayed:
        Gd = delayed(level)
    assert Gd.nstates == G.nstates + 3
    z = np.exp(1j * np.linspace(0.01, np.pi - 0.01, 50))
    response, delayed_response = (np.array([complex(S(zk)) for zk in z]) for S in (G, Gd))
    assert relative_error(delayed_response, response * z ** -3) < 1e-9
    steps = [ct.step_response(S, T=np.arange(40) * Ts).outputs for S in (G, Gd)]
    assert np.allclose(steps[1][3:], steps[0][:-3], atol=1e-12) and np.allclose(steps[1][:3], 0)
    half_sample = {"effect_input_delay": 0.5 * Ts}
    with FmuLinearization(tanks, Ts, "diag_scheduling", parameters=half_sample) as bad:
        with pytest.raises(ModelError, match="not a whole number of samples"):
            bad(level)


def test_feedthrough_acts_one_sample_late_like_the_fmu_outputs():
    """y(k) = C x(k) + D u(k−1): impulse response 0, then C B_d + D, then C A_d B_d."""
    system = ct.ss([[-1.0]], [[2.0]], [[3.0]], [[0.5]])
    sampled = sample_like_fmu(system, 0.1)
    zoh = ct.sample_system(ct.ss([[-1.0]], [[2.0]], [[3.0]], [[0.0]]), 0.1, "zoh")
    impulse = ct.impulse_response(sampled, T=np.arange(4) * 0.1).outputs
    Ad, Bd = zoh.A[0, 0], zoh.B[0, 0]
    # python-control scales a discrete impulse by 1/dt; undo it
    assert impulse * 0.1 == pytest.approx([0.0, 3 * Bd + 0.5, 3 * Ad * Bd, 3 * Ad**2 * Bd], rel=1e-12)


def test_local_arx_models_match_the_linearization_and_their_bias_shrinks_with_amplitude(tanks):
    """Tolerances. The only model error of a noise-free local ARX(2, 2, 1) is the √h nonlinearity:
    its second-order term, relative to the linear one, is of the order of the relative swing a of
    the PRBS. So we demand gain, pole sum and pole product within 0.1 a of the linearization
    (observed: ≈ 0.05 a, 0.01 a, 0.02 a), δν below 0.01 a (observed ≈ 0.002 a), and the gain bias
    to halve with a (a second-order effect is linear in a; a timing or offset error would not)."""
    with FmuLinearization(tanks, Ts, "diag_scheduling") as linearize:
        references = {level: linearize(np.array([level])) for level in (0.05, 0.25)}
    gain_errors = {}
    for amplitude in (0.01, 0.005):
        with FmuLocalModels(tanks, Ts, "diag_scheduling", amplitude=amplitude) as local:
            for level, R in references.items():
                G = local(np.array([level]))
                assert G.dt == Ts and G.nstates == 2
                gain_errors[amplitude, level] = abs(ct.dcgain(G) / ct.dcgain(R) - 1)
                assert gain_errors[amplitude, level] < 0.1 * amplitude
                poles, exact = G.poles(), R.poles()
                assert abs(np.sum(poles).real / np.sum(exact).real - 1) < 0.1 * amplitude
                assert abs(np.prod(poles).real / np.prod(exact).real - 1) < 0.1 * amplitude
                assert nugap(G, R).value < 0.01 * amplitude
    for level in references:
        assert 0.4 < gain_errors[0.005, level] / gain_errors[0.01, level] < 0.6


def test_arx_statespace_recovers_a_known_mimo_system():
    rng = np.random.default_rng(3)
    true = ct.ss([[0.5, 0.1], [0.0, 0.7]], [[1.0, 0.0], [0.2, 1.0]], np.eye(2), np.zeros((2, 2)), 1.0)
    u = rng.standard_normal((400, 2))
    y = ct.forced_response(true, U=u.T).outputs.T
    model = arx_statespace(u, y, na=2, nb=2, nk=1, Ts=1.0)
    omega = np.linspace(0.01, np.pi, 50)
    responses = [ct.frequency_response(system, omega).complex for system in (model, true)]
    assert np.allclose(*responses, atol=1e-8)


def test_bad_fmu_reference_inputs_raise_one_line(tanks, tmp_path):
    cases = [
        (lambda: FmuLinearization(tmp_path / "missing.fmu", Ts, "diag_scheduling"), DataError, "not found"),
        (lambda: FmuLinearization(tanks, Ts, "no_such_signal"), DataError, "unknown name"),
        (lambda: FmuLinearization(tanks, Ts, "diag_scheduling", start={"bogus": 1.0}), DataError, "bogus"),
        (lambda: FmuLinearization(tanks, -1.0, "diag_scheduling"), DataError, "Ts"),
        (lambda: FmuLocalModels(tanks, Ts, "diag_scheduling", amplitude=0.0), DataError, "amplitude"),
    ]
    for make, error, words in cases:
        with pytest.raises(error, match=words) as info:
            make()
        assert "\n" not in str(info.value)
    with FmuLinearization(tanks, Ts, "diag_scheduling") as linearize:
        with pytest.raises(ModelError, match="no equilibrium") as info:
            linearize(np.array([0.5]))  # above the tank height (0.3 m): levels are clipped there
        assert "\n" not in str(info.value)
        with pytest.raises(DataError, match="entries"):
            linearize(np.array([0.1, 0.2]))


def test_held_outputs_pin_an_underdetermined_equilibrium():
    """The maglev has two coil currents and one scheduling signal (the upper disk): the equilibrium at a
    scheduling value is one of a curve. ``hold`` pins the lower disk; the currents are then the unique
    holding currents of fmu_plants/reference_models.py (random points, seeded). Without it the search
    leaves the lower disk elsewhere."""
    import sys

    sys.path.insert(0, str(ROOT / "fmu_plants"))
    import reference_models as rm

    params = rm.default_parameters("maglev")
    start = {"lower_disk_position": 0.015, "upper_disk_position": 0.08, "lower_coil_current": 0.927,
             "upper_coil_current": -0.045}
    rng = np.random.default_rng(36)
    fmu = built_fmu("maglev")
    for upper, lower in zip(rng.uniform(0.074, 0.087, 3), rng.uniform(0.012, 0.018, 3), strict=True):
        with FmuOperatingPoints(fmu, 0.002, ["upper_disk_position"], start=start,
                                hold={"lower_disk_position": lower}) as held:
            point = held.equilibrium(np.array([upper]))
        np.testing.assert_allclose(point.x[:2], [lower, upper], rtol=0, atol=1e-9)
        np.testing.assert_allclose(point.u, rm.maglev_equilibrium_currents(lower, upper, params), rtol=1e-6)
    with FmuOperatingPoints(fmu, 0.002, ["upper_disk_position"], start=start) as free:
        assert abs(free.equilibrium(np.array([0.075])).x[0] - 0.015) > 0.003
    with pytest.raises(DataError, match="held outputs lower_disk_speed are not outputs"):
        FmuOperatingPoints(fmu, 0.002, ["upper_disk_position"], hold={"lower_disk_speed": 0.0})
