"""H∞ loop shaping by LMIs (lpvflow.synth.loop_shaping): the four-block plant, and the LMI γ against the
Riccati optimum 1/b_opt of the shaped plant and against SLICOT SB10DD at frozen points."""

import control as ct
import numpy as np
import pytest
import slycot
from scipy.linalg import block_diag

from lpvflow.errors import ModelError
from lpvflow.synth.loop_shaping import (
    crossover_normalized,
    in_plant_coordinates,
    integrator_lead_weight,
    loop_shaping,
    ncf_generalized_plant,
    output_integral_weight,
    output_washout_weight,
    shaped_plant,
)
from lpvflow.validate.norms import hinf_norm
from lpvflow.validate.robust_stability import generalized_margin, optimal_margin
from tests.lti_helpers import random_ss

SAMPLING_TIMES = (1e-3, 1e-2, 5e-2)


def pi_rolloff_weight(m, Ts, integral_corner, rolloff, gain=1.0):
    """Strictly proper W1 = gain (z − a)/((z − 1)(z − c)) in every input channel,
    a = e^{−ω_i Ts}, c = e^{−ω_r Ts}."""
    a, c = np.exp(-integral_corner * Ts), np.exp(-rolloff * Ts)
    channel = ct.ss(ct.tf([gain * (1 - c), -gain * (1 - c) * a], [1, -(1 + c), c], Ts))
    return ct.append(*[channel] * m)


def identity(p, Ts):
    return ct.ss([], [], [], np.eye(p), Ts)


def random_plants(seed, count):
    """ZOH samples of random plants, D = 0 (SISO and 2×2; n ≥ outputs, so the DC gain has full rank)."""
    rng = np.random.default_rng(seed)
    for i in range(count):
        p = 1 + i % 2
        Gc = random_ss(rng, int(rng.integers(p, p + 3)), p, p, spread=(0.05, 3.0))
        if i % 4 >= 2:  # some unstable plants
            shift = rng.uniform(0.1, 1.0) - np.max(np.linalg.eigvals(Gc.A).real)
            Gc = ct.ss(Gc.A + shift * np.eye(Gc.nstates), Gc.B, Gc.C, Gc.D)
        Ts = SAMPLING_TIMES[i % 3]
        yield rng, ct.sample_system(ct.ss(Gc.A, Gc.B, Gc.C, 0 * Gc.D), Ts)


def response(system, omega):
    return np.moveaxis(ct.frequency_response(system, omega).complex.reshape(
        system.noutputs, system.ninputs, -1), -1, 0)


def test_shaped_plant_is_the_series_product():
    for rng, G in random_plants(seed=1, count=6):
        p, Ts = G.noutputs, G.dt
        W1 = pi_rolloff_weight(p, Ts, rng.uniform(0.1, 2.0), rng.uniform(20, 200), rng.uniform(0.5, 5))
        W2 = ct.ss([], [], [], np.diag(rng.uniform(0.5, 2.0, p)), Ts)
        omega = np.logspace(-2, np.log10(np.pi / Ts) - 1e-6, 200)
        np.testing.assert_allclose(response(shaped_plant(G, W1, W2), omega), response(W2 * G * W1, omega),
                                   rtol=1e-8, atol=1e-10)


def test_four_block_plant_closes_to_the_ncf_transfer_matrix():
    """The LFT P11 + P12 K (I − P22 K)⁻¹ P21 of the generalized plant equals [I; K](I − GsK)⁻¹[I Gs]."""
    for rng, G in random_plants(seed=2, count=4):
        p, Ts = G.noutputs, G.dt
        P = ncf_generalized_plant(G)
        K = ct.ss(random_ss(rng, 2, p, p, dt=Ts).A, rng.standard_normal((2, p)), rng.standard_normal((p, 2)),
                  rng.standard_normal((p, p)), Ts)
        omega = np.logspace(-2, np.log10(np.pi / Ts) - 1e-6, 50)
        Pf, Kf, Gf = response(P, omega), response(K, omega), response(G, omega)
        z, w = slice(0, 2 * p), slice(2 * p, None)
        P11, P12, P21, P22 = Pf[:, z, z], Pf[:, z, w], Pf[:, w, z], Pf[:, w, w]
        eye = np.broadcast_to(np.eye(p), Kf.shape)
        lft = P11 + P12 @ Kf @ np.linalg.inv(eye - P22 @ Kf) @ P21
        inner = np.linalg.inv(eye - Gf @ Kf)
        four_block = np.concatenate([eye, Kf], axis=1) @ inner @ np.concatenate([eye, Gf], axis=2)
        np.testing.assert_allclose(lft, four_block, rtol=1e-9, atol=1e-9)


def sb10dd_controller(P, p, gamma):
    """SLICOT SB10DD's discrete H∞ controller at level γ, or None when it declares γ too small."""
    A, B, C, D = (np.asarray(M, dtype=float) for M in (P.A, P.B, P.C, P.D))
    try:
        out = slycot.sb10dd(A.shape[0], B.shape[1], C.shape[0], p, p, gamma, A, B, C, D)
    except (ValueError, ArithmeticError):
        return None
    return ct.ss(*out[1:5], P.dt)


def test_lmi_gamma_equals_the_riccati_optimum_of_the_shaped_plant():
    """LTI witness: LMI γ = 1/b_opt(Gs) within 1 %, b(Gs, K∞) = 1/γ within 1 %; SB10DD (independent) finds a
    controller with b ≥ 1/(1.01 γ_opt) and none that stabilizes with b ≥ 1/(0.99 γ_opt)."""
    for rng, G in random_plants(seed=36, count=6):
        p, Ts = G.noutputs, G.dt
        W1 = pi_rolloff_weight(p, Ts, rng.uniform(0.1, 2.0), rng.uniform(20, 200), rng.uniform(0.5, 5))
        W2 = identity(p, Ts)
        design = loop_shaping([G], [W1], W2)
        Gs = design.shaped[0]
        gamma_opt = 1.0 / optimal_margin(Gs)
        assert design.gamma == pytest.approx(gamma_opt, rel=1e-2)
        assert design.gamma >= gamma_opt * (1 - 1e-6)
        b = generalized_margin(Gs, design.K_inf[0])
        assert b == pytest.approx(1.0 / design.gamma, rel=1e-2)
        assert b >= (1.0 / design.gamma) * (1 - 1e-6)
        # K = W1·K∞·W2 on the plant: the same loop, so b(G, K) > 0 (b itself is not invariant under weights)
        assert generalized_margin(G, design.feedback[0]) > 0.0
        P = ncf_generalized_plant(Gs)
        above, below = sb10dd_controller(P, p, 1.01 * gamma_opt), sb10dd_controller(P, p, 0.99 * gamma_opt)
        assert above is not None and generalized_margin(Gs, above) >= (1 - 1e-6) / (1.01 * gamma_opt)
        assert below is None or generalized_margin(Gs, below) < 1.0 / (0.99 * gamma_opt)


@pytest.mark.parametrize("breakpoints, options", [
    ([-1.0, 0.0, 1.0], {}),  # one common Lyapunov matrix over the three vertex plants
    ([-1.0, 1.0], {"breakpoints": [-1.0, 1.0], "rate_bound": 0.05}),  # hinfsyn's rate-bounded design
])
def test_scheduled_design_meets_its_gamma_between_breakpoints(breakpoints, options):
    """Plants with the same C on p ∈ [−1, 1] (A and B vary), W1 scheduled in its gain (its C): γ ≥ the
    largest frozen γ_opt, and at frozen points between breakpoints (shaped plant and K∞ interpolated linearly
    in p, the polytopic model the certificate covers) b(Gs(p), K∞(p)) ≥ 1/γ."""
    rng = np.random.default_rng(5)
    Ts = 0.01
    base = random_ss(rng, 2, 1, 1, spread=(0.5, 2.0))
    A1 = 0.3 * rng.standard_normal((2, 2))

    def plant(q):
        return ct.sample_system(ct.ss(base.A + q * A1, base.B * (1 + 0.3 * q), base.C, 0 * base.D), Ts)

    design = loop_shaping([plant(q) for q in breakpoints],
                          [pi_rolloff_weight(1, Ts, 0.5, 100.0, gain=2.0 + q) for q in breakpoints],
                          identity(1, Ts), **options)
    assert design.gamma >= max(1.0 / optimal_margin(Gs) for Gs in design.shaped) * (1 - 1e-6)
    for q in np.linspace(-1.0, 1.0, 9):
        lam = [np.interp(q, breakpoints, np.eye(len(breakpoints))[i]) for i in range(len(breakpoints))]
        Gs, K = ([sum(w * np.asarray(M, dtype=float) for w, M in zip(lam, Ms, strict=True))
                  for Ms in zip(*[(S.A, S.B, S.C, S.D) for S in systems], strict=True)]
                 for systems in (design.shaped, design.K_inf))
        assert generalized_margin(ct.ss(*Gs, Ts), ct.ss(*K, Ts)) >= (1.0 / design.gamma) * (1 - 1e-6)


def test_feedthrough_in_the_shaped_plant_is_refused():
    Ts = 0.01
    G = ct.ss([[0.9]], [[1.0]], [[1.0]], [[0.5]], Ts)  # plant feed-through
    proper = ct.ss([[1.0]], [[Ts]], [[1.0]], [[1.0]], Ts)  # PI: D ≠ 0
    with pytest.raises(ModelError, match="strictly proper"):
        loop_shaping([G], [proper], identity(1, Ts))
    with pytest.raises(ModelError, match="one W1 per plant"):
        loop_shaping([G, G], [proper], identity(1, Ts))


def test_integrator_lead_weight_is_the_sampled_continuous_weight():
    """D = 0, one pole at z = 1, |W1| within 2 % of the continuous W1(jω) up to the crossover (ZOH), the
    lead's phase at ω_c within 3° of arcsin((α − 1)/(α + 1)) + the integrator/roll-off phases."""
    Ts, wc = 0.005, 15.0
    W1 = integrator_lead_weight(Ts, wc)
    assert np.max(np.abs(W1.D)) == 0.0
    assert np.min(np.abs(W1.poles() - 1.0)) < 1e-12
    s = ct.tf("s")
    Wc = (s + wc / 10) / s * (s + wc / 2) / (s + 2 * wc) * 10 * wc / (s + 10 * wc)
    for w in np.logspace(-1, np.log10(wc), 20):
        discrete, continuous = W1(np.exp(1j * w * Ts)), Wc(1j * w)
        assert abs(discrete) == pytest.approx(abs(continuous), rel=2e-2)
    lead, integrator = np.arcsin(3 / 5), np.arctan(10) - np.pi / 2
    rolloff, hold = -np.arctan(0.1), -wc * Ts / 2
    expected = np.degrees(lead + integrator + rolloff + hold)
    assert np.degrees(np.angle(W1(np.exp(1j * wc * Ts)))) == pytest.approx(expected, abs=3.0)
    with pytest.raises(ModelError, match="Nyquist"):
        integrator_lead_weight(Ts, 100.0)


def _integrator(z, corner, Ts):
    return 1 + corner * Ts / (z - 1)


def _washout(z, corner, Ts):
    return (z - 1) / (z - np.exp(-corner * Ts))


@pytest.mark.parametrize(("weight", "ratio_key", "channel", "dc", "seed"),
                         [(output_integral_weight, "integral_ratio", _integrator, None, 11),
                          (output_washout_weight, "washout_ratio", _washout, 0.0, 12)])
def test_an_output_weight_acts_only_on_the_marked_outputs(weight, ratio_key, channel, dc, seed):
    """W2 = diag(w_j), the ZOH sample of the channel on the marked outputs, 1 on the others, nothing off the
    diagonal, one state per marked output: (s + ω_c/r_i)/s → 1 + (ω_c/r_i)·Ts/(z − 1) (integral);
    s/(s + ω_c/r_w) → (z − 1)/(z − e^{−ω_c Ts/r_w}) (washout, zero at DC). No output marked is refused."""
    rng = np.random.default_rng(seed)
    for _ in range(6):
        Ts, wc = float(rng.choice([0.002, 0.01])), float(rng.uniform(1.0, 20.0))
        ratio = float(rng.uniform(3, 30))
        marked = [bool(m) for m in rng.integers(0, 2, 3)]
        marked[int(rng.integers(0, 3))] = True
        W2 = weight(Ts, wc, marked, **{ratio_key: ratio})
        for w in rng.uniform(0.01, 0.9, 4) * np.pi / Ts:
            z = np.exp(1j * w * Ts)
            expected = np.diag([channel(z, wc / ratio, Ts) if m else 1.0 for m in marked])
            np.testing.assert_allclose(W2(z, squeeze=False), expected, rtol=1e-12, atol=1e-12)
        if dc is not None:
            np.testing.assert_allclose(W2(1.0, squeeze=False), np.diag([dc if m else 1.0 for m in marked]),
                                       atol=1e-12)
        assert W2.nstates == sum(marked)
    with pytest.raises(ModelError, match="at least one"):
        weight(0.01, 1.0, [False, False])


def test_crossover_normalized_with_an_output_weight_crosses_one_at_the_crossover():
    for rng, G in random_plants(seed=10, count=6):
        wc = float(rng.uniform(0.5, 5.0))
        W1 = integrator_lead_weight(G.dt, wc, inputs=G.ninputs, integral=False)
        W2 = output_integral_weight(G.dt, wc, [True] + [False] * (G.noutputs - 1))
        W1n = crossover_normalized(G, W1, wc, W2)
        z = np.exp(1j * wc * G.dt)
        loop = W2(z, squeeze=False) @ G(z, squeeze=False) @ W1n(z, squeeze=False)
        assert np.linalg.norm(loop, 2) == pytest.approx(1.0, rel=1e-9)


def test_crossover_normalized_weight_crosses_one_at_the_crossover():
    for rng, G in random_plants(seed=9, count=6):
        wc = float(rng.uniform(0.5, 5.0))
        W1 = integrator_lead_weight(G.dt, wc, inputs=G.ninputs)
        W1n = crossover_normalized(G, W1, wc)
        z = np.exp(1j * wc * G.dt)
        assert np.linalg.norm(G(z, squeeze=False) @ W1n(z, squeeze=False), 2) == pytest.approx(1.0, rel=1e-9)
        np.testing.assert_array_equal(W1n.A, W1.A)
        np.testing.assert_array_equal(W1n.B, W1.B)


def _random_certificate(rng, n, m, p):
    """A random controller (order n, p inputs, m outputs) and a random positive definite 𝒳 (2n × 2n)."""
    K = (rng.standard_normal((n, n)), rng.standard_normal((n, p)), rng.standard_normal((m, n)),
         rng.standard_normal((m, p)))
    F = rng.standard_normal((2 * n, 2 * n)) + 2 * n * np.eye(2 * n)
    return K, F.T @ F


def _transformed(K, X, T):
    """K in the basis x_K = T x̃_K and 𝒳 written for [x; x̃_K]."""
    n = T.shape[0]
    Ti = np.linalg.inv(T)
    E = block_diag(np.eye(X.shape[0] - n), T)
    return (Ti @ K[0] @ T, Ti @ K[1], K[2] @ T, K[3]), E.T @ X @ E


@pytest.mark.parametrize("seed", range(4))
def test_plant_coordinates_do_not_depend_on_the_basis_the_solver_returned(seed):
    """in_plant_coordinates of (K, 𝒳) and of the same controller and certificate in any other controller
    basis are the same matrices; after a plant state change x = Q x̂ (𝒳 written for [x̂; x_K]) the result
    changes by the same Q; and 𝒳 in the result's basis is [S −P; −P P], P = S − R⁻¹."""
    rng = np.random.default_rng(seed)
    n, m, p = int(rng.integers(2, 5)), int(rng.integers(1, 3)), int(rng.integers(1, 3))
    K, X = _random_certificate(rng, n, m, p)
    base = in_plant_coordinates(K, X)
    V = rng.standard_normal((n, n)) + 3 * np.eye(n)
    for a, b in zip(in_plant_coordinates(*_transformed(K, X, V)), base, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-10)
    Q = rng.standard_normal((n, n)) + 3 * np.eye(n)
    E = block_diag(Q, np.eye(n))
    moved = in_plant_coordinates(K, E.T @ X @ E)
    for a, b in zip(moved, _transformed(base, X, Q)[0], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-10)
    # the basis change x_K = T x̃_K from K to the result, from the controllability matrices of both
    ctrb = [np.hstack([np.linalg.matrix_power(k[0], j) @ k[1] for j in range(n)]) for k in (K, base)]
    T = ctrb[0] @ np.linalg.pinv(ctrb[1])  # x_K = T x̃_K
    S, R = X[:n, :n], np.linalg.inv(X)[:n, :n]
    P = S - np.linalg.inv(R)
    np.testing.assert_allclose(_transformed(K, X, T)[1], np.block([[S, -P], [-P, P]]), rtol=1e-7,
                               atol=1e-9 * np.abs(X).max())


def test_lmi_controllers_meet_their_level_by_python_control():
    """The LMI controller K∞ in the shaped plant's coordinates: ‖T_zw‖∞ of the four-block loop ≤ γ by
    python-control (lpvflow.validate.norms.hinf_norm) and b(Gs, K∞) ≥ 1/γ, for random plants."""
    for rng, G in random_plants(seed=7, count=6):
        p, Ts = G.noutputs, G.dt
        W1 = pi_rolloff_weight(p, Ts, rng.uniform(0.1, 2.0), rng.uniform(20, 200), rng.uniform(0.5, 5))
        design = loop_shaping([G], [W1], identity(p, Ts))
        Gs, K = design.shaped[0], design.K_inf[0]
        P = ncf_generalized_plant(Gs)
        A, B, C, D = (np.asarray(M) for M in (P.A, P.B, P.C, P.D))
        # exogenous [w1; w2] and performance [z1; z2] first, then u (columns) and y (rows); D22 = 0
        e, c = slice(0, P.ninputs - Gs.ninputs), slice(P.ninputs - Gs.ninputs, None)
        f, y = slice(0, P.noutputs - p), slice(P.noutputs - p, None)
        Ak, Bk, Ck, Dk = (np.asarray(M) for M in (K.A, K.B, K.C, K.D))
        loop = ct.ss(np.block([[A + B[:, c] @ Dk @ C[y], B[:, c] @ Ck], [Bk @ C[y], Ak]]),
                     np.vstack([B[:, e] + B[:, c] @ Dk @ D[y, e], Bk @ D[y, e]]),
                     np.hstack([C[f] + D[f, c] @ Dk @ C[y], D[f, c] @ Ck]),
                     D[f, e] + D[f, c] @ Dk @ D[y, e], Ts)
        assert hinf_norm(loop) <= design.gamma * (1 + 1e-6)
        assert generalized_margin(Gs, K) >= (1.0 / design.gamma) * (1 - 1e-6)
