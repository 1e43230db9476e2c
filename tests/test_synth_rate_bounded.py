"""Rate-bounded gain-scheduled H∞ synthesis (lpvflow.synth.rate_bounded): γ ordered by the rate bound and
close to the frozen Riccati optimum, frozen closed loops by python-control, rate-bounded trajectories
judged by the certificate's Lyapunov function, certificates that refuse a perturbed controller, 2-DOF
against SB10DD, piecewise polytopes with scheduled weights, and the errors that name what is wrong."""

import control
import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.synth.bilinear import closed_loop
from lpvflow.synth.certify import certify_rate_bounded, rate_bounded_walk
from lpvflow.synth.hinf import hinfsyn
from lpvflow.synth.plant import VertexPlant, augment, generalized_plant, weight_systems
from lpvflow.synth.rate_bounded import Schedule, fine_check, synthesize_rate_bounded, synthesize_scheduled
from lpvflow.synth.riccati import riccati_gamma
from tests.adip_cases import TS as ADIP_TS
from tests.adip_cases import adip_vertex, bundled_weights, rm
from tests.readme_blocks import run_python_block

TS = 0.01
WEIGHTS = {"S": {"bandwidth": 1.0, "hf_gain": 2.0}, "K": {"num": [0.05], "den": [1]},
           "B": {"num": [0, 0.4], "den": [1, -0.6]}, "integrator_shift": 1e-3}
RATES = {"slow": 0.001, "fast": 0.02, "arbitrary": None}


def varying_plant() -> LPVSS:
    """x⁺ = (1 + Ts·a(p)) x + Ts·b(p) u, y = x, p ∈ [−1, 1]: the unstable pole a goes 0.5 → 3 rad/s and the
    input authority b 1 → 6 (both 6×) across the box, affinely in p."""
    t_lo, t_hi = 0.5, 3.0
    a0, a1 = (t_hi + t_lo) / 2, (t_hi - t_lo) / 2
    b0, b1 = 3.5, 2.5
    A = np.array([[[1 + TS * a0]], [[TS * a1]]])
    B = np.array([[[TS * b0]], [[TS * b1]]])
    C = np.array([[[1.0]], [[0.0]]])
    return LPVSS(A, B, C, np.zeros((2, 1, 1)), Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,)), TS)


@pytest.fixture(scope="module")
def designs():
    model = varying_plant()
    plant = generalized_plant(model, WEIGHTS)
    return model, plant, {name: synthesize_rate_bounded(plant, nu) for name, nu in RATES.items()}


def frozen_optimum(model: LPVSS, points: np.ndarray) -> float:
    W = weight_systems(WEIGHTS, 1, 1, TS)
    return max(riccati_gamma(VertexPlant.from_ss(augment(model.frozen([p]), W, TS), nw=1, nz=2), TS)
               for p in points)


def test_gamma_is_ordered_by_the_rate_bound_and_close_to_the_frozen_optimum(designs):
    model, _, results = designs
    gamma = {name: r.gamma for name, (r, _) in results.items()}
    # each certified γ is within its 1 % level search of the minimum of its own LMIs
    assert gamma["slow"] <= gamma["fast"] * 1.01 <= gamma["arbitrary"] * 1.0201
    worst = frozen_optimum(model, np.linspace(-1, 1, 11))
    # the reported estimate is the frozen optimum at the worst breakpoint (SB10DD agrees)
    assert all(r.gamma_estimate <= r.gamma for r, _ in results.values())
    assert abs(results["slow"][0].gamma_estimate / frozen_optimum(model, np.array([-1.0, 1.0])) - 1) < 1e-2
    assert gamma["slow"] <= 1.25 * worst
    assert gamma["arbitrary"] > gamma["slow"]  # the rate bound is worth something on this plant


def test_the_controller_holds_gamma_at_frozen_points_and_along_rate_bounded_trajectories(designs):
    model, plant, results = designs
    for name, (result, _) in results.items():
        certificate = certify_rate_bounded(result, model, plant.weights)
        assert certificate.ok, (name, certificate.lines())
        assert certificate.frozen_hinf_max <= result.gamma * (1 + 1e-3)
        # python-control, independently of the certificate: stable frozen loops with norm below γ
        for p in (-1.0, -0.3, 0.4, 1.0):
            P = augment(model.frozen([p]), weight_systems(WEIGHTS, 1, 1, TS), TS)
            loop = P.lft(result.controller(p), 1, 1)
            assert np.max(np.abs(loop.poles())) < 1
            assert control.norm(loop, "inf") <= result.gamma * (1 + 1e-6)


def test_a_rate_bounded_trajectory_gains_less_than_gamma(designs):
    """Time domain: w a random signal, p a random walk with |Δp| ≤ ν, ‖z‖₂ / ‖w‖₂ < γ."""
    _, _, results = designs
    result = results["fast"][0]
    rng = np.random.default_rng(3)
    n = result.vertices[0].dims[0] + result.K_vertices[0][0].shape[0]
    x, p, zz, ww = np.zeros(n), 0.0, 0.0, 0.0
    for _ in range(3000):
        w = rng.standard_normal(1)
        A, B, C, D = closed_loop(result.plant_at(p), result.controller_at(p))
        z = C @ x + D @ w
        x = A @ x + B @ w
        zz, ww = zz + z @ z, ww + w @ w
        p = float(np.clip(p + 0.02 * rng.uniform(-1, 1), -1, 1))
    assert np.sqrt(zz / ww) < result.gamma
    assert rate_bounded_walk(result)[2] <= 1.0


def test_the_certificate_refuses_a_perturbed_controller(designs):
    _, _, results = designs
    result = results["slow"][0]
    assert min(result.margins) > 0 and fine_check(result)[0] > 0
    Ak, Bk, Ck, Dk = result.K_vertices[0]
    bad = Ak.copy()
    bad[0, 0] *= 1 + 1e-2
    result.K_vertices[0] = (bad, Bk, Ck, Dk)
    try:
        assert fine_check(result)[0] < 0
    finally:
        result.K_vertices[0] = (Ak, Bk, Ck, Dk)


def test_the_implementable_controller_interpolates_the_breakpoint_controllers(designs):
    _, plant, results = designs
    result, controller = results["fast"]
    assert controller.structure == "1dof" and controller.info["method"] == "rate-bounded"
    assert controller.polytope.n_vertices == 2
    # W_B in series: the LPVController's frozen response is W_B·K at every p
    WB = plant.input_filter
    for p in (-1.0, 0.25, 1.0):
        expected = WB * result.controller(p)
        got = controller.frozen(np.array([p]))
        w = np.exp(1j * np.linspace(0.01, 3.0, 7))
        assert np.allclose(got(w), expected(w), rtol=1e-8, atol=1e-10)


def test_a_two_dof_design_reaches_the_riccati_optimum():
    W = weight_systems(bundled_weights(), 2, 1, ADIP_TS)
    a, b = rm.adip_linearization(0.0, rm.default_parameters("adip"))
    G = control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), ADIP_TS, method="zoh")
    P = augment(G, W, ADIP_TS, "2dof")
    assert P.ninputs == 2 + 2 + 1 and P.noutputs == 3 + 4  # inputs [w, n, u], outputs [z, r, y_m]
    result = hinfsyn(P, 4, 1)
    reference = riccati_gamma(VertexPlant.from_ss(P, nw=4, nz=3), ADIP_TS)
    assert reference <= result.gamma <= 1.01 * reference
    loop = P.lft(result.controller, 1, 4)
    assert control.norm(loop, "inf") <= result.gamma * (1 + 1e-6)


def test_on_the_upright_adip_the_rate_bounded_gamma_is_near_the_riccati_optimum():
    """A hard plant for the rate-bounded path: the exact ADIP linearizations at ±20° (unstable pendulum,
    bundled weights, 1-DOF), breakpoints at sin(±20°), |Δ sin φ1| ≤ 0.002 per sample. The frozen estimate
    equals SLICOT SB10DD's optimum at the breakpoints to 1 %, the certified γ is within 5 % of it, and the
    python-control norm of the design's plant with the returned controller, frozen between the
    breakpoints, is below γ."""
    degrees = (-20.0, 20.0)
    vertices = [adip_vertex(d) for d in degrees]
    result = synthesize_scheduled(vertices, np.sin(np.deg2rad(degrees)), ADIP_TS, rate_bound=0.002)
    optimum = max(riccati_gamma(v, ADIP_TS) for v in vertices)
    assert abs(result.gamma_estimate / optimum - 1) < 0.01
    assert optimum <= result.gamma <= 1.05 * optimum
    assert min(result.margins) > 0
    for p in np.sin(np.deg2rad([-10.0, 0.0, 10.0])):
        v = result.plant_at(p)
        loop = v.ss(ADIP_TS).lft(result.controller(p), v.dims[2], v.dims[4])
        assert np.max(np.abs(np.linalg.eigvals(loop.A))) < 1
        assert control.norm(loop, "inf") <= result.gamma * (1 + 1e-6)


def test_a_piecewise_polytope_with_vertex_weights_is_certified_across_its_segment_boundary():
    """The thesis' structure (§6.3): vertices at the ends and the middle of the range, the tracking
    weight relaxed at the ends (W_S1 ≠ W_S2 ≠ W_S3), one controller interpolated per segment."""
    model = varying_plant()
    relaxed = {"S": {"bandwidth": 0.5, "hf_gain": 2.0}}
    plant = generalized_plant(model, WEIGHTS, breakpoints=[-1.0, 0.0, 1.0],
                              vertex_weights=[relaxed, {}, relaxed])
    assert plant.polytope.kind == "piecewise" and plant.polytope.n_vertices == 3
    assert not np.allclose(plant.vertices[0].C1, plant.vertices[1].C1)  # the weights really differ
    result, controller = synthesize_rate_bounded(plant, 0.02)
    assert controller.polytope.kind == "piecewise"
    margin, _ = fine_check(result)
    assert margin > 0
    # pairs that straddle the boundary p = 0 are part of the design and of the fine check
    assert any(p < 0 <= q or q < 0 <= p for p, nexts in result.schedule.pairs() for q in nexts)
    assert rate_bounded_walk(result, seed=1)[2] <= 1.0
    lam = controller.coordinates(np.array([0.5]))
    assert np.allclose(lam, [0.0, 0.5, 0.5])


def test_a_scheduled_control_weight_is_refused_naming_D12():
    with pytest.raises(ModelError, match=r"D12 .*W_K"):
        generalized_plant(varying_plant(), WEIGHTS, breakpoints=[-1.0, 0.0, 1.0],
                          vertex_weights=[{"K": {"num": [0.1], "den": [1]}}, {}, {}])


def test_vertex_weights_must_match_the_vertices():
    with pytest.raises(ModelError, match="2 weight tables for a polytope with 3 vertices"):
        generalized_plant(varying_plant(), WEIGHTS, breakpoints=[-1.0, 0.0, 1.0], vertex_weights=[{}, {}])


def test_the_pairs_contain_every_vertex_of_the_rate_band_in_each_cell():
    """Φ is affine on each cell [b_i, b_i+1] × [b_j, b_j+1]; the pairs must include every vertex of the
    cell ∩ {|p⁺ − p| ≤ ν}, so a brute-force check of the polygon vertices finds none missing."""
    schedule = Schedule(np.array([-1.0, -0.2, 0.5, 1.0]), 0.3)
    pairs = {(round(p, 12), round(q, 12)) for p, nexts in schedule.pairs() for q in nexts}
    b, nu = schedule.breakpoints, 0.3
    for i in range(3):
        for j in range(3):
            lines = [b[i], b[i + 1]]
            cols = [b[j], b[j + 1]]
            candidates = [(p, q) for p in lines for q in cols]
            candidates += [(p, p + s * nu) for p in lines for s in (-1, 1)]
            candidates += [(q - s * nu, q) for q in cols for s in (-1, 1)]
            for p, q in candidates:
                inside = (lines[0] <= p <= lines[1] and cols[0] <= q <= cols[1] and abs(q - p) <= nu + 1e-12
                          and -1 <= p <= 1 and -1 <= q <= 1)
                if inside:
                    assert (round(p, 12), round(q, 12)) in pairs, (p, q)


def test_bad_schedules_are_refused():
    with pytest.raises(ModelError, match="ascending"):
        Schedule(np.array([0.0, -1.0]), 0.1)
    with pytest.raises(ModelError, match="rate_bound must be positive"):
        Schedule(np.array([0.0, 1.0]), 0.0)
    with pytest.raises(ModelError, match="rate_bound needs breakpoints"):
        hinfsyn(adip_vertex(0.0).ss(ADIP_TS), 2, 1, rate_bound=0.01)


def test_the_readme_example_runs_as_written():
    """The README's rate-bounded block, executed verbatim: the frozen loop's norm stays below γ."""
    gamma, norm = (float(v) for v in run_python_block("### Gain scheduling with a rate bound").split())
    assert 0 < norm <= gamma


def test_refinement_against_a_true_plant_that_is_not_linear_between_breakpoints():
    """synthesize_gridded: the true plant a(p + 0.15(p³ − p)) bends away from the segments between the
    breakpoints −1, 0, 1;
    the fine check against it decides the certified γ' (at most 10 % above the designed level, else it
    refines), and python-control's frozen norms of the true plant stay below γ'."""
    from lpvflow.synth.rate_bounded import synthesize_gridded

    model = varying_plant()
    W = weight_systems(WEIGHTS, 1, 1, TS)

    def plant_at(p: float) -> VertexPlant:
        return VertexPlant.from_ss(augment(model.frozen([p + 0.15 * (p ** 3 - p)]), W, TS), nw=1, nz=2)

    result = synthesize_gridded(plant_at, [-1.0, 0.0, 1.0], TS, rate_bound=0.02)
    margin, _ = fine_check(result, plant_at)
    assert margin > 0
    # the certificate is about the true plant: the design's own two-vertex interpolation is not it
    b = result.schedule.breakpoints
    assert b[0] == -1.0 and b[-1] == 1.0 and len(b) > 3  # the three given ones were not enough
    for p in np.linspace(-1, 1, 9):
        loop = plant_at(p).ss(TS).lft(result.controller(p), 1, 1)
        assert control.norm(loop, "inf") <= result.gamma * (1 + 1e-6)
