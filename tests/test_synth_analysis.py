"""Rate-bounded H∞ analysis of a given gain-scheduled loop (lpvflow.synth.analysis): the LTI limit is
python-control's norm on a plant with poles at 1 − 1e-4, the bound grows with the rate and agrees with the
synthesis' own certificate, the storage dissipates along simulated rate-bounded trajectories, and
unstable loops are refused naming the point."""

import control
import numpy as np
import pytest

from lpvflow.errors import ModelError
from lpvflow.synth.analysis import dissipation_matrix, rate_bounded_gain
from lpvflow.synth.bilinear import closed_loop
from lpvflow.synth.plant import generalized_plant
from lpvflow.synth.rate_bounded import synthesize_rate_bounded
from lpvflow.synth.riccati import riccati_controller, riccati_gamma
from lpvflow.validate.stability import scaled_margin
from tests.adip_cases import TS as ADIP_TS
from tests.adip_cases import adip_vertex
from tests.readme_blocks import run_python_block
from tests.test_synth_rate_bounded import WEIGHTS, varying_plant

RATES = (0.001, 0.02, 1.0)


@pytest.fixture(scope="module")
def synthesized():
    """The 'fast' design of test_synth_rate_bounded (ν = 0.02 per sample) and its closed loop at any p."""
    result, _ = synthesize_rate_bounded(generalized_plant(varying_plant(), WEIGHTS), 0.02)

    def loop_at(p: float):
        return closed_loop(result.plant_at(p), result.controller_at(p))

    return result, loop_at


@pytest.fixture(scope="module")
def gains(synthesized):
    _, loop_at = synthesized
    b = np.linspace(-1.0, 1.0, 5)
    return {nu: rate_bounded_gain(loop_at, b, nu) for nu in RATES}


def test_an_lti_loop_gets_its_hinf_norm_despite_poles_at_one_minus_ts():
    """The exact ADIP linearization at 0° (Ts = 5 ms, a W_S pole at 1 − 1e-4) with SB10DD's controller at
    1.5× its optimum: the same loop at every p, so the bound is python-control's ‖T_zw‖∞ (in the loop's
    own coordinates, without the Riccati scaling, Clarabel stops "inaccurate" on its one frozen LMI)."""
    vertex = adip_vertex(0.0)
    K = riccati_controller(vertex, ADIP_TS, 1.5 * riccati_gamma(vertex, ADIP_TS, 1e-3))
    loop = closed_loop(vertex, K)
    norm = float(control.norm(control.ss(*loop, ADIP_TS), "inf"))
    result = rate_bounded_gain(lambda p: loop, [-1.0, 1.0], 0.5)
    assert norm <= result.gamma <= norm * 1.011  # the level search's width: 1 %
    assert result.margin > 0


def test_the_bound_grows_with_the_rate_and_covers_every_frozen_norm(synthesized, gains):
    _, loop_at = synthesized
    gamma = {nu: r.gamma for nu, r in gains.items()}
    # each certified level is within the 0.1 % bisection of its SDP's minimum
    assert gamma[0.001] <= gamma[0.02] * 1.002 <= gamma[1.0] * 1.004
    assert gamma[1.0] > 1.02 * gamma[0.001]  # the rate bound is worth something on this plant
    frozen = max(float(control.norm(control.ss(*loop_at(p), 1.0), "inf")) for p in np.linspace(-1, 1, 41))
    assert frozen <= gamma[0.001]


def test_it_certifies_the_rate_bounded_synthesis_at_its_own_level(synthesized, gains):
    """Two certificates of the same loop: the synthesis' (slack, 𝒫 affine in λ) and this analysis'
    (no slack, any 𝒫 linear between breakpoints) — the analysis may only be less conservative."""
    result, _ = synthesized
    assert gains[0.02].gamma <= result.gamma * 1.01


def test_the_storage_dissipates_along_a_rate_bounded_trajectory(synthesized, gains):
    """Time domain, independent of the LMI: V(ξ⁺, p⁺) − V(ξ, p) + ‖z‖²/γ − γ‖w‖² ≤ 0 at every step of a
    random walk |Δp| ≤ ν with random w, and the accumulated gain is below γ."""
    _, loop_at = synthesized
    bound = gains[0.02]
    rng = np.random.default_rng(5)
    xi, p, zz, ww, worst = np.zeros(bound.lyapunov[0].shape[0]), 0.0, 0.0, 0.0, -np.inf
    for _ in range(3000):
        w = rng.standard_normal(1)
        A, B, C, D = loop_at(p)
        z, xi_next = C @ xi + D @ w, A @ xi + B @ w
        p_next = float(np.clip(p + 0.02 * rng.uniform(-1, 1), -1.0, 1.0))
        supply = z @ z / bound.gamma - bound.gamma * (w @ w)
        change = xi_next @ bound.lyapunov_at(p_next) @ xi_next - xi @ bound.lyapunov_at(p) @ xi
        worst = max(worst, (change + supply) / (xi @ xi + w @ w))
        xi, p, zz, ww = xi_next, p_next, zz + z @ z, ww + w @ w
    assert worst <= 0
    assert np.sqrt(zz / ww) < bound.gamma


def test_the_certificate_refuses_a_faster_schedule_than_it_was_made_for(synthesized, gains):
    """The storage certified for ν = 0.001 fails the dissipation matrix for a jump across the range."""
    _, loop_at = synthesized
    slow = gains[0.001]
    M, E = dissipation_matrix(loop_at(-1.0), slow.lyapunov_at(-1.0), slow.lyapunov_at(1.0), slow.gamma)
    assert scaled_margin(-M, E) < 0
    M, E = dissipation_matrix(loop_at(-1.0), slow.lyapunov_at(-1.0), slow.lyapunov_at(-0.999), slow.gamma)
    assert scaled_margin(-M, E) > 0


def test_unstable_or_broken_loops_and_bad_settings_are_refused_naming_the_point(synthesized):
    _, loop_at = synthesized

    def broken(p: float):
        A, B, C, D = loop_at(p)
        return (1.01 * A if p > 0.9 else A), B, C, D

    with pytest.raises(ModelError, match=r"p = 1 is unstable"):
        rate_bounded_gain(broken, [-1.0, 1.0], 0.01)
    with pytest.raises(ModelError, match=r"p = -1 has non-finite entries"):
        rate_bounded_gain(lambda p: tuple(np.full_like(M, np.nan) for M in loop_at(p)), [-1.0, 1.0], 0.01)
    with pytest.raises(ModelError, match="suboptimality"):
        rate_bounded_gain(loop_at, [-1.0, 1.0], 0.01, suboptimality=0.0)


def test_the_readme_example_runs_as_written():
    """The README block, verbatim: the frozen norm bounds every rate's γ from below, and γ grows with
    the rate bound."""
    printed = run_python_block("### Rate-bounded gain of any scheduled loop").split()
    frozen, *gammas = (float(v) for v in printed)
    assert frozen <= gammas[0] <= gammas[1] * 1.002 <= gammas[2] * 1.004
    assert gammas[2] > gammas[0]
