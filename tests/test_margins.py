"""b(P, K), loop margins and Vinnicombe's robust stability theorem as a seeded property test."""

import control as ct
import numpy as np
import pytest

from lpvflow.errors import ModelError
from lpvflow.validate.margins import closed_loop, is_internally_stable, loop_margins, stability_margin
from lpvflow.validate.nugap import nugap
from tests.lti_helpers import gain, random_ss

s = ct.tf("s")




def observer_controller(P, weight):
    """Observer-based state feedback K (u = −K y) from LQR/Kalman gains: stabilizes P by design."""
    A, B, C = P.A, P.B, P.C
    if P.isdtime():
        F = ct.dlqr(A, B, np.eye(A.shape[0]), weight * np.eye(B.shape[1]))[0]
        L = ct.dlqr(A.T, C.T, np.eye(A.shape[0]), weight * np.eye(C.shape[0]))[0].T
    else:
        F = ct.lqr(A, B, np.eye(A.shape[0]), weight * np.eye(B.shape[1]))[0]
        L = ct.lqr(A.T, C.T, np.eye(A.shape[0]), weight * np.eye(C.shape[0]))[0].T
    return ct.ss(A - B @ F - L @ C + L @ P.D @ F, L, F, np.zeros((B.shape[1], C.shape[0])), P.dt)


def thesis_T_peak(P, K, omega):
    """max σ of the thesis's (6.1) T = [K; I](I + PK)^-1 [P, I] on a grid (independent of lpvflow)."""
    Gp = np.moveaxis(ct.frequency_response(P, omega).complex.reshape(P.noutputs, P.ninputs, -1), -1, 0)
    Gk = np.moveaxis(ct.frequency_response(K, omega).complex.reshape(K.noutputs, K.ninputs, -1), -1, 0)
    eye = np.broadcast_to(np.eye(P.noutputs), (len(omega), P.noutputs, P.noutputs))
    inner = np.linalg.inv(eye + Gp @ Gk)
    T = np.concatenate([Gk, eye], axis=1) @ inner @ np.concatenate([Gp, eye], axis=2)
    return np.linalg.svd(T, compute_uv=False)[:, 0].max()


def test_matlab_ncfmargin_examples():
    """MATLAB ncfmargin doc: P = 4/(s-0.001) with C = 1 gives 0.7069, with C = 10 gives 0.0995."""
    P = ct.ss(4 / (s - 0.001))
    assert stability_margin(P, gain(1.0)) == pytest.approx(0.7069, abs=5e-5)
    assert stability_margin(P, gain(10.0)) == pytest.approx(0.0995, abs=5e-5)


def test_destabilizing_controller_has_zero_margin():
    P = ct.ss(4 / (s - 0.001))
    assert not is_internally_stable(P, gain(-1.0))
    assert stability_margin(P, gain(-1.0)) == 0.0


@pytest.mark.parametrize("dt", [0, 0.1])
def test_margin_is_inverse_peak_of_thesis_closed_loop(dt):
    rng = np.random.default_rng(7)
    P = random_ss(rng, 3, 2, 2, dt)
    K = observer_controller(P, weight=float(rng.uniform(0.5, 2.0)))
    b = stability_margin(P, K)
    assert 0.0 < b <= 1.0
    top = np.pi / dt * (1 - 1e-12) if dt else 1e3
    omega = np.concatenate([[0.0], np.logspace(-3, np.log10(top), 20000)])
    assert b == pytest.approx(1.0 / thesis_T_peak(P, K, omega), rel=1e-4)
    assert b <= 1.0 / thesis_T_peak(P, K, omega) + 1e-9


def test_closed_loop_has_plant_plus_controller_states_and_right_dc_gain():
    P, K = ct.ss(2 / (s + 1)), ct.ss(3 / (s + 4))
    T = closed_loop(P, K)
    assert T.nstates == 2
    # d_u -> y at DC: P/(1 + K P) = 2 / (1 + 0.75 * 2) = 0.8
    assert ct.dcgain(T)[0, 0] == pytest.approx(0.8)


@pytest.mark.parametrize("dt", [0, 0.05])
def test_vinnicombe_theorem_holds_on_random_loops(dt, record_property):
    """If b(P, K) > δν(P, P2) then (P2, K) is internally stable (Vinnicombe 2001, Thm 3.8)."""
    rng = np.random.default_rng(11)
    premise, crossed_stability, destabilized_without_premise = 0, 0, 0
    for _ in range(110):
        p, m = [(1, 1), (2, 2), (1, 2)][rng.integers(3)]
        P = random_ss(rng, int(rng.integers(2, 4)), p, m, dt, spread=(0.6, 1.2) if dt else (-0.4, 0.6))
        K = observer_controller(P, weight=float(rng.choice([0.1, 1.0, 10.0])))
        b = stability_margin(P, K)
        scale = float(rng.choice([0.01, 0.05, 0.3]))
        P2 = ct.ss(P.A + scale * rng.standard_normal(P.A.shape), P.B + scale * rng.standard_normal(P.B.shape),
                   P.C + scale * rng.standard_normal(P.C.shape), P.D, dt)
        distance = nugap(P, P2).value
        stable = is_internally_stable(P2, K)
        if b > distance:
            premise += 1
            assert stable, f"Vinnicombe's theorem violated: b = {b:.4f} > δν = {distance:.4f}"
            unstable = [np.sum(np.abs(X.poles()) > 1 if dt else X.poles().real > 0) for X in (P, P2)]
            crossed_stability += int(unstable[0] != unstable[1])
        elif not stable:
            destabilized_without_premise += 1
    record_property("premise_cases", premise)
    print(f"dt={dt}: premise held in {premise} cases ({crossed_stability} with a changed count of unstable "
          f"poles); {destabilized_without_premise} other perturbations destabilized the loop")
    assert premise >= 50
    assert destabilized_without_premise > 0  # the perturbations are large enough to matter


def test_loop_margins_match_closed_form_for_second_order_loop():
    P, K = ct.ss(5 / ((s + 1) * (s + 2))), gain(1.0)
    margins = loop_margins(P, K)
    w_gain = np.sqrt((-5 + np.sqrt(25 + 84)) / 2)  # |L(jω)| = 1
    assert margins["gain_crossover_rad_s"] == pytest.approx(w_gain, rel=1e-6)
    expected_pm = 180 - np.degrees(np.arctan(w_gain) + np.arctan(w_gain / 2))
    assert margins["phase_margin_deg"] == pytest.approx(expected_pm, rel=1e-6)
    assert margins["gain_margin"] == np.inf
    omega = np.logspace(-4, 4, 200001)
    L = 5 / ((1j * omega + 1) * (1j * omega + 2))
    assert margins["disk_margin"] == pytest.approx(np.min(2 * np.abs(1 + L) / np.abs(1 - L)), rel=1e-4)
    assert margins["stability_margin_b"] == pytest.approx(stability_margin(P, K))


def test_loop_margins_discrete_gain_margin():
    z = ct.tf([1, 0], [1], 0.1)
    P = ct.ss(0.5 / (z * (z - 0.5)))
    margins = loop_margins(P, gain(1.0, 0.1))
    L_at_phase_crossover = complex(P(np.exp(1j * margins["phase_crossover_rad_s"] * 0.1)))
    assert abs(abs(np.angle(L_at_phase_crossover, deg=True)) - 180) < 1e-3
    assert margins["gain_margin"] == pytest.approx(1 / abs(L_at_phase_crossover), rel=1e-6)
    assert margins["gain_margin"] > 1  # the loop is stable at k = 1


@pytest.mark.parametrize(
    ("P", "K", "words"),
    [
        (ct.ss(-np.eye(2), np.ones((2, 1)), np.eye(2), 0), gain([[1.0, 1.0], [1.0, 1.0]]), "must be 1x2"),
        (ct.ss([[-1]], [[1]], [[1]], 0), gain(1.0, 0.1), "continuous-time"),
        (ct.ss([[0.5]], [[1]], [[1]], 0, 0.1), gain(1.0, 0.2), "Ts"),
        (gain(1.0), gain(-1.0), "ill-posed"),
    ],
)
def test_bad_loops_raise_one_line_model_error(P, K, words):
    with pytest.raises(ModelError, match=words) as info:
        stability_margin(P, K)
    assert "\n" not in str(info.value)


def _mu_two_scalar_blocks(M):
    """μ of a 2×2 matrix for two complex scalar blocks: exactly inf_d σ̄(diag(d, 1) M diag(1/d, 1))
    (the D-scaled bound is exact for up to three complex blocks; Packard & Doyle 1993)."""
    from scipy.optimize import minimize_scalar

    def scaled(log_d):
        d = np.exp(log_d)
        return np.linalg.svd(np.diag([d, 1.0]) @ M @ np.diag([1 / d, 1.0]), compute_uv=False)[0]

    return minimize_scalar(scaled, bounds=(-12, 12), method="bounded", options={"xatol": 1e-10}).fun


def test_mimo_disk_margins_equal_independent_mu_of_balanced_sensitivity():
    """Multiloop disk margin α = 1/max_ω μ(S − I/2) at plant input (L = KP) and output (L = PK)."""
    P = ct.c2d(ct.ss(np.array([[-1.0, 0.4], [0.0, -2.0]]), np.array([[1.0, 0.3], [0.2, 1.0]]),
                     np.array([[1.0, 0.5], [-0.3, 1.0]]), np.zeros((2, 2))), 0.1)
    K = ct.ss([], [], [], np.array([[2.0, 0.5], [-0.4, 1.5]]), 0.1)
    omega = np.logspace(-3, np.log10(np.pi / 0.1) - 1e-9, 300)
    margins = loop_margins(P, K, omega)
    for prefix, L in (("input_", K * P), ("output_", P * K)):
        G = np.moveaxis(ct.frequency_response(L, omega).complex, -1, 0)
        S = np.linalg.inv(np.eye(2) + G)
        alpha = 1 / max(_mu_two_scalar_blocks(Sk - 0.5 * np.eye(2)) for Sk in S)
        assert margins[prefix + "disk_margin"] == pytest.approx(alpha, rel=1e-3)
        # balanced disk: gain margin (2 + α)/(2 − α), phase margin 2 arctan(α/2)
        gain_db = 20 * np.log10((2 + alpha) / (2 - alpha))
        phase_deg = np.degrees(2 * np.arctan(alpha / 2))
        assert margins[prefix + "disk_gain_margin_db"] == pytest.approx(gain_db, rel=2e-3)
        assert margins[prefix + "disk_phase_margin_deg"] == pytest.approx(phase_deg, rel=2e-3)
    assert "phase_margin_deg" not in margins
    assert margins["stability_margin_b"] == pytest.approx(stability_margin(P, K))


def test_decoupled_mimo_disk_margin_is_the_worst_siso_one():
    P1, P2 = ct.ss(5 / ((s + 1) * (s + 2))), ct.ss(3 / (s + 0.5))
    P = ct.append(P1, P2)
    mimo = loop_margins(P, gain(np.eye(2)))
    siso = [loop_margins(Pi, gain(1.0))["disk_margin"] for Pi in (P1, P2)]
    assert mimo["input_disk_margin"] == pytest.approx(min(siso), rel=1e-4)
    assert mimo["output_disk_margin"] == pytest.approx(min(siso), rel=1e-4)


def test_unstable_loop_has_zero_disk_margins():
    P = ct.ss(4 / (s - 0.001))
    margins = loop_margins(P, gain(-1.0))
    assert margins["disk_margin"] == 0.0 and margins["stability_margin_b"] == 0.0
