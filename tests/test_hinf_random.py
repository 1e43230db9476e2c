"""hinfsyn on weighted plants it was never tuned on (tests/hinf_cases.py, fixed seeds): one outcome per call,
γ against SLICOT's Riccati optimum (SB10DD bisected, lpvflow.synth.riccati), the closed loop measured by
python-control / AB13DD (lpvflow.validate.norms), polytopic families against an independent
common-Lyapunov formulation written here, and every failure path ending in one categorised SynthesisError."""

import warnings

import control
import cvxpy as cp
import numpy as np
import pytest
import scipy.linalg

from lpvflow.errors import CentralLevelError, ModelError, SynthesisError
from lpvflow.synth import central as central_module
from lpvflow.synth.bilinear import (
    Coordinates,
    _io_scales,
    cayley_vertex,
    lqg_balancing,
)
from lpvflow.synth.hinf import central_hinfsyn, central_near_optimum, hinfsyn
from lpvflow.synth.plant import VertexPlant
from lpvflow.synth.riccati import riccati_controller, riccati_gamma
from lpvflow.synth.sdp import solve
from lpvflow.validate.norms import hinf_norm
from tests.hinf_cases import WeightedCase, polytopic_case, weighted_cases

#: Share of random plants whose certified γ is within 1 % of SB10DD: every one. Measured with the homogenized
#: level LMIs (lpvflow.synth.vertex_synthesis, step 5): 63 of 63 in each draw of seeds 2027, 2031, 2035,
#: 2039, 2043, 2047, 2053 and 2069 (worst 1.0037); 14 of 14 (seed 2026). benchmarks/README.md has the table.
WITHIN_ONE_PERCENT = 1.0


def _vertex(P: control.StateSpace, nmeas: int, ncon: int) -> VertexPlant:
    return VertexPlant.from_ss(P, P.ninputs - ncon, P.noutputs - nmeas)


def _outcomes(cases) -> list[float]:
    """γ / SB10DD optimum per case; asserts on the way that every call returned a certified controller
    whose closed loop, rebuilt by python-control, is stable with ‖T_zw‖∞ ≤ γ."""
    ratios = []
    for case in cases:
        res = hinfsyn(case.P, case.nmeas, case.ncon)
        loop = case.P.lft(res.controller, case.ncon, case.nmeas)
        assert hinf_norm(loop) <= res.gamma * (1 + 1e-6), case.label
        assert min(res.certificate) > 0, case.label
        assert {a[0] for a in res.report.attempts} == {"CLARABEL"}, case.label
        ratios.append(res.gamma / riccati_gamma(_vertex(case.P, case.nmeas, case.ncon), case.P.dt))
    return ratios


def test_random_weighted_plants_get_certified_controllers_near_the_riccati_optimum():
    """14 plants, two of each kind (stable, unstable, lightly damped, nonminimum phase, near integrator,
    2×2 coupled masses, mass chain), Ts 1–50 ms: every call answers with a certificate whose closed loop
    python-control confirms, and γ is within 1 % of SB10DD's optimum or below it on most. (Below it is
    possible: with an integral weight pole at 1 − 3e-5, SB10DD fails at levels up to 0.5973 that this
    controller reaches with a closed-loop norm of 0.5876 — seed 2026, case 11 — confirmed on a 40 000-point
    frequency grid.)"""
    ratios = np.array(_outcomes(weighted_cases(14, 2026)))
    assert np.all(ratios <= 1.01), ratios


def test_a_level_near_the_optimum_is_resolved_where_its_margin_is_tiny():
    """Seed 2027, case 22 (an unstable plant, 4 states; Ts ≈ 10 ms): solved to Clarabel's default duality
    gap 1e-8, the controller LMIs 0.26 % above the optimum returned t = −2.6e-5 (‖R‖ ≈ 2.7e3) as "optimal",
    their controller failed the certificate and the synthesis ended 1.2 % above SB10DD; with the level
    SDPs' gap at 1e-12 it must come within 0.5 %."""
    case = weighted_cases(23, 2027)[22]
    res = hinfsyn(case.P, case.nmeas, case.ncon)
    assert min(res.certificate) > 0
    assert res.gamma <= 1.005 * riccati_gamma(_vertex(case.P, case.nmeas, case.ncon), case.P.dt)


@pytest.fixture(scope="module")
def chain_2031_13():
    """Seed 2031, case 13 (a 10-state chain, Ts ≈ 6.4 ms): the case, its hinfsyn result, SB10DD's level."""
    case = weighted_cases(14, 2031)[13]
    reference = riccati_gamma(_vertex(case.P, case.nmeas, case.ncon), case.P.dt)
    return case, hinfsyn(case.P, case.nmeas, case.ncon), reference


def test_a_chain_whose_estimate_lies_above_the_optimum_is_certified_within_one_percent(chain_2031_13):
    """Seed 2031, case 13: the eliminated conditions' accurate minimum is 0.23 % above SB10DD's level; with
    the level LMIs as written (max t, R and S free) level 1.98808 failed (t = −7.8e-5, ‖R‖ ≈ 7.6e4) and
    the synthesis once ended at 2.00295, 1.23 % above SB10DD. γ must be within 1 %."""
    _, res, reference = chain_2031_13
    assert min(res.certificate) > 0
    assert res.gamma <= 1.01 * reference


def test_no_lower_bound_is_claimed_above_a_level_a_controller_reaches(chain_2031_13):
    """The eliminated conditions' minimum, solved with status "optimal", was reported as ``gamma_lower``
    ("no controller of this class does better") at 1.0014 times the closed-loop norm (python-control /
    AB13DD) of SB10DD's controller on this plant: no result may claim a lower bound above a norm that a
    controller reaches. The minimum is still reported, as ``gamma_estimate``."""
    case, res, reference = chain_2031_13
    vertex = _vertex(case.P, case.nmeas, case.ncon)
    K = riccati_controller(vertex, case.P.dt, reference)
    reached = hinf_norm(case.P.lft(control.ss(*K, case.P.dt), case.ncon, case.nmeas))
    claimed = getattr(res, "gamma_lower", None)
    assert claimed is None or claimed <= reached, (claimed, reached)
    assert res.gamma_estimate is not None and res.gamma_estimate > 0


def _lqg_pair(vc: VertexPlant) -> tuple[np.ndarray, np.ndarray]:
    """The unregularized LQG Riccati pair (Y, X) of a continuous generalized plant, all inputs and outputs."""
    B, C = np.hstack([vc.B1, vc.B2]), np.vstack([vc.C1, vc.C2])
    X = scipy.linalg.solve_continuous_are(vc.A, B, C.T @ C, np.eye(B.shape[1]))
    Y = scipy.linalg.solve_continuous_are(vc.A.T, C.T, B @ B.T, np.eye(C.shape[0]))
    return Y, X


def test_a_stable_mode_no_input_drives_still_gets_lqg_balanced_coordinates():
    """Seed 2047, case 20 (a 5-mass chain, Ts 36 ms, with a weight on T whose state is driven through the
    chain's relative degree of 10: |w·[B1 B2]| ≈ 1e-21), and 8 random weighted plants (seed 11) each with
    a stable state appended that no input drives: the LQG pair of such a plant is singular (Y had an
    eigenvalue −1e-19 on case 20, so no balancing was used and hinfsyn ended 5.49× SB10DD); the balancing
    must still exist and be finite. On the plants as drawn whose own pair is well determined (each of
    Y, X of condition ≤ 1e8), it must balance that pair as solved to 1e-6 (raising the Riccati weights
    CᵀC, BBᵀ by 1e-10 of their norm instead leaves 1e-4)."""
    rng = np.random.default_rng(11)
    plants = [weighted_cases(21, 2047)[20]]
    for c in weighted_cases(8, 11):  # append x⁺ = a·x (|a| < 0.9), no input, seen by the z outputs
        P = c.P
        A = scipy.linalg.block_diag(P.A, [[rng.uniform(-0.9, 0.9)]])
        B = np.vstack([P.B, np.zeros((1, P.ninputs))])
        C = np.hstack([P.C, np.r_[rng.uniform(0.1, 1.0, P.noutputs - c.nmeas), np.zeros(c.nmeas)][:, None]])
        plants.append(WeightedCase(control.ss(A, B, C, P.D, P.dt), c.nmeas, c.ncon, c.label))
    for c in plants:
        vc = cayley_vertex(_vertex(c.P, c.nmeas, c.ncon))
        scaled = Coordinates(np.eye(c.P.nstates), 1.0, *_io_scales(vc, np.eye(c.P.nstates), 1.0)).apply(vc)
        T = lqg_balancing(scaled)
        assert T is not None and np.all(np.isfinite(T)), c.label
    balanced = 0
    for c in weighted_cases(8, 11):
        vc = cayley_vertex(_vertex(c.P, c.nmeas, c.ncon))
        scaled = Coordinates(np.eye(c.P.nstates), 1.0, *_io_scales(vc, np.eye(c.P.nstates), 1.0)).apply(vc)
        Y, X = _lqg_pair(scaled)
        if min(np.linalg.eigvalsh(M)[0] / np.linalg.eigvalsh(M)[-1] for M in (Y, X)) < 1e-8:
            continue  # not well determined in double precision
        balanced += 1
        T = lqg_balancing(scaled)
        Ti = np.linalg.inv(T)
        left, right = Ti @ Y @ Ti.T, T.T @ X @ T
        sigma = np.sqrt(np.abs(np.diag(left) * np.diag(right)))
        for M in (left, right):
            assert np.allclose(M / np.sqrt(np.outer(sigma, sigma)), np.eye(len(M)), atol=1e-6), c.label
    assert balanced >= 5


def test_a_chain_whose_weight_state_no_input_drives_is_solved_near_the_riccati_optimum():
    """Seed 2047, case 20 (the chain above, 13 states): in the unbalanced coordinates the level SDPs failed
    up to 6.4e4× SB10DD and the synthesis ended at 5.49×; it must be within 1 % (measured 1.0031×)."""
    ratios = _outcomes([weighted_cases(21, 2047)[20]])
    assert ratios[0] <= 1.01, ratios


def test_coupled_masses_whose_level_kkt_solves_need_refinement_are_solved_near_the_riccati_optimum():
    """Seed 2047, case 26 (2×2 coupled masses, Ts 22 ms): with Clarabel 0.11.1's default refinement of its
    KKT solves every level SDP within 1.6× SB10DD ended NumericalError and the synthesis at 2.56×; with the
    level SDPs' KKT solves refined to 1e-16 (lpvflow.synth.sdp._REFINED) it must be within 1 % (measured
    0.9997×), its closed loop confirmed by python-control in _outcomes."""
    ratios = _outcomes([weighted_cases(27, 2047)[26]])
    assert ratios[0] <= 1.01, ratios


def test_levels_whose_lmi_optimum_lies_at_infinity_are_certified_near_the_riccati_optimum():
    """Seed 2035 case 55 (a 12-state mass chain, Ts 4.1 ms) and seed 2047 case 9 (lightly damped, Ts
    14.5 ms): maximising the margin t of the level LMIs as written, its supremum near the optimum is
    approached only as R, S grow without bound (‖R‖ ≈ 1e5, cond(I − RS) up to 1e11); Clarabel stalled at
    t < 0 and the syntheses ended at 1.0162× and 1.0131× SB10DD. Homogenized (R, S ⪯ I, the constant terms
    times a variable τ), the level SDPs converge: both must be within 1 % (measured 1.0037× and 1.0032×)."""
    ratios = _outcomes([weighted_cases(56, 2035)[55], weighted_cases(10, 2047)[9]])
    assert max(ratios) <= 1.01, ratios


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2027, 2035, 2047])
def test_sixty_three_random_weighted_plants(seed):
    ratios = np.array(_outcomes(weighted_cases(63, seed)))
    assert np.mean(ratios <= 1.01) >= WITHIN_ONE_PERCENT, ratios


def test_the_state_basis_the_plant_is_given_in_does_not_change_gamma():
    """The README plant and 6 random weighted plants (one per kind but the chain, seed 7), each also given
    in three other state bases — a permutation, a permutation with a diagonal scaling of condition up to
    100 (other units), and a random rotation with that scaling: every γ within 0.5 % of the plant's own,
    and within 1 % of SB10DD. (Before the LQG-balanced starting coordinates, the scaled README plant came
    out 79 % above SB10DD and a scaled 9-state chain failed.)"""
    G = control.c2d(control.tf([4.0], [1.0, 0.4, 4.0]), 0.01)
    readme = control.ss(control.augw(G, control.c2d(control.tf([0.5, 1.0], [1.0, 0.01]), 0.01),
                                      control.tf(0.1, 1, 0.01)))
    plants = [(readme, 1, 1)] + [(c.P, c.nmeas, c.ncon) for c in weighted_cases(6, 7)]
    rng = np.random.default_rng(7)
    for P, nmeas, ncon in plants:
        n = P.nstates
        reference = riccati_gamma(_vertex(P, nmeas, ncon), P.dt)
        own = hinfsyn(P, nmeas, ncon).gamma
        assert own <= 1.01 * reference
        scaling = np.diag(10 ** rng.uniform(-1, 1, n))
        rotation = np.linalg.qr(rng.standard_normal((n, n)))[0]
        for T in (np.eye(n)[rng.permutation(n)], np.eye(n)[rng.permutation(n)] @ scaling, rotation @ scaling):
            Ti = np.linalg.inv(T)
            other = control.ss(Ti @ P.A @ T, Ti @ P.B, P.C @ T, P.D, P.dt)
            assert abs(hinfsyn(other, nmeas, ncon).gamma / own - 1) <= 5e-3


def _common_lyapunov_optimum(vertices: list[VertexPlant]) -> float:
    """Independent reference: the eliminated conditions of Gahinet & Apkarian (1994, Thm. 4.3) with one
    R, S for every vertex, on the bilinear images scaled only in frequency (s = ω₀s', ω₀ = max ‖A_c‖₂:
    A_c/ω₀, B_c/√ω₀, C_c/√ω₀ leave the conditions' optimum unchanged), minimised by Clarabel.
    Its optimum lies where R, S grow without bound (the infimum of the eliminated conditions is not
    attained, lpvflow.synth.eliminated), so Clarabel may stop short of its full accuracy
    (``optimal_inaccurate``; with Clarabel 0.11.1 on 4 of these 20 families, each within 0.4 % of
    hinfsyn's γ): such a value is kept as the reference, a failed solve is not."""
    images = [cayley_vertex(v) for v in vertices]
    w0 = max(float(np.linalg.norm(v.A, 2)) for v in images)
    r = np.sqrt(w0)
    images = [VertexPlant(v.A / w0, v.B1 / r, v.B2 / r, v.C1 / r, v.C2 / r, v.D11, v.D12, v.D21, v.D22)
              for v in images]
    n = images[0].dims[0]
    R, S, g = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True), cp.Variable()
    constraints = [cp.bmat([[R, np.eye(n)], [np.eye(n), S]]) >> 0]
    for v in images:
        nw, nz = v.dims[1], v.dims[3]
        NR = scipy.linalg.block_diag(scipy.linalg.null_space(np.hstack([v.B2.T, v.D12.T])), np.eye(nw))
        NS = scipy.linalg.block_diag(scipy.linalg.null_space(np.hstack([v.C2, v.D21])), np.eye(nz))
        MR = cp.bmat([[v.A @ R + R @ v.A.T, R @ v.C1.T, v.B1], [v.C1 @ R, -g * np.eye(nz), v.D11],
                      [v.B1.T, v.D11.T, -g * np.eye(nw)]])
        MS = cp.bmat([[v.A.T @ S + S @ v.A, S @ v.B1, v.C1.T], [v.B1.T @ S, -g * np.eye(nw), v.D11.T],
                      [v.C1, v.D11, -g * np.eye(nz)]])
        for M in (NR.T @ MR @ NR, NS.T @ MS @ NS):
            constraints.append(0.5 * (M + M.T) << 0)
    problem = cp.Problem(cp.Minimize(g), constraints)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Solution may be inaccurate")
            problem.solve(solver="CLARABEL")
    except cp.error.SolverError:
        return np.nan
    return float(g.value) if problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) else np.nan


@pytest.mark.parametrize("seed", [11, pytest.param(3001, marks=pytest.mark.slow)])
def test_random_polytopic_families_match_an_independent_common_lyapunov_optimum(seed):
    """20 families of 2–4 vertices; every vertex loop certified and γ within 2 % of the reference wherever
    the reference is valid: its solve returned a point (it must on most) not below the largest vertex's own
    SB10DD optimum (no common-Lyapunov design can beat that). Seed 3001
    (drawn after the method was fixed) family 17 — two vertices ±4 %, a near integrator under a DC weight of
    930 at Ts = 11.7 ms — has a reference of 0.934 under vertex optima 1.150 and
    1.122: invalid, so not compared (hinfsyn's 1.197 is 1.041× the bound)."""
    rng = np.random.default_rng(seed)
    compared = 0
    for _ in range(20):
        plants, nmeas, ncon, label = polytopic_case(rng)
        res = hinfsyn(plants, nmeas, ncon)
        for P, K in zip(plants, res.vertex_controllers, strict=True):
            assert hinf_norm(P.lft(K, ncon, nmeas)) <= res.gamma * (1 + 1e-6), label
        vertices = [_vertex(P, nmeas, ncon) for P in plants]
        floor = max(riccati_gamma(v, P.dt, rel=1e-3) for v, P in zip(vertices, plants, strict=True))
        reference = _common_lyapunov_optimum(vertices)
        if np.isfinite(reference) and reference >= floor * (1 - 1e-3):
            compared += 1
            assert abs(res.gamma / reference - 1) <= 0.02, label
    assert compared >= 15


def test_an_unstabilizable_weight_is_an_assumption_error_naming_the_mode():
    """A weight pole at z = 1.2 that neither u nor y touches: no controller exists."""
    case = weighted_cases(1, 3)[0]
    P = case.P
    n = P.nstates
    A = scipy.linalg.block_diag(P.A, [[1.2]])
    B = np.vstack([P.B, np.zeros((1, P.ninputs))])
    B[-1, 0] = 1.0  # driven by w only
    C = np.hstack([P.C, np.zeros((P.noutputs, 1))])
    C[0, n] = 1.0  # seen in z only
    bad = control.ss(A, B, C, P.D, P.dt)
    with pytest.raises(SynthesisError, match=r"mode at z = 1\.2.*not stabilizable") as info:
        hinfsyn(bad, case.nmeas, case.ncon)
    assert info.value.category == "assumption"
    assert "\n" not in str(info.value)


def test_a_level_below_the_optimum_is_infeasible_and_sb10dd_agrees():
    case = weighted_cases(2, 4)[1]
    optimum = riccati_gamma(_vertex(case.P, case.nmeas, case.ncon), case.P.dt)
    with pytest.raises(SynthesisError) as info:
        hinfsyn(case.P, case.nmeas, case.ncon, gamma_max=0.5 * optimum)
    message = str(info.value)
    assert info.value.category == "infeasible"
    assert "SB10DD finds no controller" in message and "scheduling box" not in message


def test_a_level_sb10dd_reaches_is_never_called_infeasible(monkeypatch):
    """Held-out draw seed 3001 case 20 (a mass chain at Ts = 1.37 ms): the eliminated conditions' minimum,
    solved "optimal", is 2.216 where SB10DD reaches 2.165 and hinfsyn certifies 2.170, and that estimate
    once refused every level below it as "infeasible" — for hinfsyn with gamma_max 0.3 % and 1 % above
    SB10DD and for the central controller at 1.01 × hinfsyn's γ. At each such level a call now returns a
    certified controller within it (closed loop checked by python-control / AB13DD) or an ``"accuracy"``
    error naming SB10DD's level, never ``"infeasible"`` — also when the solver calls a negative margin
    accurate: the central step's widest point at 1.01 × γ solved at Clarabel's default tolerances (not the
    fine ones lpvflow uses there) ends "optimal" with margin −0.004."""
    case = weighted_cases(21, 3001)[20]
    optimum = riccati_gamma(_vertex(case.P, case.nmeas, case.ncon), case.P.dt)

    def answered(call, level):
        try:
            res = call(level)
        except SynthesisError as exc:
            assert exc.category == "accuracy", str(exc)
            return str(exc)
        assert res.gamma <= level * (1 + 1e-9) and min(res.certificate) > 0
        assert hinf_norm(case.P.lft(res.controller, case.ncon, case.nmeas)) <= res.gamma * (1 + 1e-6)
        return None

    for factor in (1.003, 1.01):
        message = answered(lambda g: hinfsyn(case.P, case.nmeas, case.ncon, gamma_max=g), factor * optimum)
        assert message is None or "SB10DD reaches γ = 2.16" in message
    gamma = hinfsyn(case.P, case.nmeas, case.ncon).gamma
    assert gamma <= 1.01 * optimum
    answered(lambda g: central_hinfsyn(case.P, case.nmeas, case.ncon, g), 1.01 * gamma)
    def coarse(problem, solver, what, fine=False, refined=False):
        return solve(problem, solver, what, refined=True)

    with monkeypatch.context() as patched:
        patched.setattr(central_module, "solve", coarse)
        message = answered(lambda g: central_hinfsyn(case.P, case.nmeas, case.ncon, g), 1.01 * gamma)
    assert message is not None and "SB10DD reaches γ = 2.16" in message
    try:  # the same central step after hinfsyn's own optimum: certified, or an error naming step and factor
        central, _ = central_near_optimum(case.P, case.nmeas, case.ncon, 1.01)
    except CentralLevelError as exc:
        assert exc.category == "accuracy" and exc.factor == 1.01
    else:
        assert min(central.certificate) > 0


def test_an_integrating_weight_on_the_unit_circle_is_an_assumption_error():
    """W1 with its pole at z = 1 exactly on e = w − y: the weight's state is seen in z only, so (C2, A)
    is not detectable at z = 1 (this plant once ended in a NaN ValueError)."""
    G = control.ss([[0.9]], [[1.0]], [[1.0]], [[0.0]], 0.01)
    for d in (0.0, 1.0):
        P = control.augw(G, control.ss([[1.0]], [[0.01]], [[1.0]], [[d]], 0.01),
                         control.ss([], [], [], [[0.1]], 0.01))
        with pytest.raises(SynthesisError, match="not detectable") as info:
            hinfsyn(P, 1, 1)
        assert info.value.category == "assumption"


def test_a_pole_at_minus_one_is_an_assumption_error():
    G = control.ss([[-1.0]], [[1.0]], [[1.0]], [[0.0]], 0.01)
    P = control.augw(G, control.ss([], [], [], [[1.0]], 0.01), control.ss([], [], [], [[0.1]], 0.01))
    with pytest.raises(SynthesisError, match="z = −1") as info:
        hinfsyn(P, 1, 1)
    assert info.value.category == "assumption"


def test_non_finite_plants_are_refused_in_one_line():
    case = weighted_cases(1, 5)[0]
    A = np.array(case.P.A, dtype=float)
    A[0, 0] = np.nan
    with pytest.raises(ModelError, match="NaN"):
        hinfsyn(control.ss(A, case.P.B, case.P.C, case.P.D, case.P.dt), case.nmeas, case.ncon)


def test_the_solver_asked_for_is_the_one_every_sdp_used():
    """No silent fallback: with SCS every SDP of the run is SCS's, and the outcome is either a certified
    controller or one SynthesisError (never a numpy error)."""
    for case in weighted_cases(1, 6):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                res = hinfsyn(case.P, case.nmeas, case.ncon, solver="SCS")
            except SynthesisError as exc:
                assert exc.category in SynthesisError.CATEGORIES
                continue
        assert {a[0] for a in res.report.attempts} == {"SCS"}
        assert res.report.solver == "SCS"
        assert hinf_norm(case.P.lft(res.controller, case.ncon, case.nmeas)) <= res.gamma * (1 + 1e-6)
