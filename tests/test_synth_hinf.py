"""Output-feedback H∞ synthesis (lpvflow.synth.hinf): γ against SLICOT's Riccati optimum, closed loops by
python-control, certificates that can fail, polytopic designs against an independent formulation, errors."""

import subprocess
import sys

import control
import cvxpy as cp
import numpy as np
import pytest
import scipy.linalg

from lpvflow.errors import ModelError
from lpvflow.models import load
from lpvflow.synth.bilinear import cayley, certificate_margin, inverse_cayley
from lpvflow.synth.certify import certify, vertex_margins
from lpvflow.synth.controller import LPVController
from lpvflow.synth.hinf import hinfsyn, synthesize
from lpvflow.synth.plant import generalized_plant
from lpvflow.synth.polytope import polytope_of
from lpvflow.synth.riccati import riccati_controller, riccati_gamma
from lpvflow.synth.sdp import SynthesisError
from lpvflow.validate.norms import hinf_norm
from tests.adip_cases import TS, adip_vertex, rm
from tests.readme_blocks import run_python_block
from tests.synth_cases import two_state_plant

WEIGHTS = {"S": {"num": [0.1, 0.1], "den": [1, -1]}, "K": {"num": [0.01], "den": [1]},
           "B": {"num": [0, 0.5], "den": [1, -0.5]}}


@pytest.fixture(scope="module")
def design():
    model = two_state_plant()
    return model, synthesize(generalized_plant(model, WEIGHTS))


@pytest.fixture(scope="module")
def adip_upright():
    """The upright ADIP point, its hinfsyn result and its Riccati-optimal γ, computed once."""
    v = adip_vertex(0.0)
    return v, hinfsyn(v.ss(TS), 2, 1), riccati_gamma(v, TS)


def _closed_loop_norm(v, K, Ts):
    """‖T_zw‖∞ (python-control, its SLICOT AB13DD where ``control.norm`` says ∞ for a pole within ~1e-5 of
    the unit circle) and spectral radius of the frozen loop."""
    loop = v.ss(Ts).lft(K, v.dims[2], v.dims[4])
    return hinf_norm(loop), float(np.max(np.abs(np.linalg.eigvals(loop.A))))


@pytest.mark.parametrize("arm_degrees", [0.0, 30.0, 45.0, 60.0, 70.0, 75.5])
def test_adip_gamma_is_within_one_percent_of_the_riccati_optimum(arm_degrees):
    """Issue 22: the shift-form LMIs gave 12.62 against 2.74 at 75.5°. Reference: SB10DD bisected to 1e-4
    (riccati_gamma); the returned controller's closed loop re-checked with python-control."""
    v = adip_vertex(arm_degrees)
    res = hinfsyn(v.ss(TS), 2, 1)
    gamma_ric = riccati_gamma(v, TS)
    assert gamma_ric * (1 - 1e-3) <= res.gamma <= 1.01 * gamma_ric
    norm, radius = _closed_loop_norm(v, res.controller, TS)
    assert radius < 1 and norm <= res.gamma * (1 + 1e-6)
    assert min(res.certificate) > 0


def test_gamma_is_continuous_in_the_plant_and_reproducible():
    """0.02° apart near 75.5° the old LMIs said 12.62 and 2.78; two runs must agree to 1e-4."""
    a, b = (hinfsyn(adip_vertex(deg).ss(TS), 2, 1).gamma for deg in (75.5, 75.52))
    assert abs(a - b) <= 0.01 * a
    assert hinfsyn(adip_vertex(75.5).ss(TS), 2, 1).gamma == pytest.approx(a, rel=1e-4)


def test_certificate_refuses_a_controller_perturbed_by_one_part_in_a_million(adip_upright):
    """A certificate that round-off cannot fake: the returned controller passes; perturbing one entry of
    Ak by 1e-6 of its size in the most sensitive entry makes some vertex certificate fail."""
    v, res, _ = adip_upright
    Ak, Bk, Ck, Dk = res.K_vertices[0]
    assert certificate_margin(v, res.K_vertices[0], res.lyapunov_factor, res.gamma) > 0
    margins = []
    for i, j in np.ndindex(Ak.shape):
        for sign in (1.0, -1.0):
            bad = Ak.copy()
            bad[i, j] += sign * 1e-6 * abs(Ak[i, j])
            margins.append(certificate_margin(v, (bad, Bk, Ck, Dk), res.lyapunov_factor, res.gamma))
    assert min(margins) < 0


def test_cayley_map_preserves_the_norm_and_the_lyapunov_inequality():
    """The exactness the synthesis relies on: ‖·‖∞ kept, inverse_cayley undoes cayley, and AᵀXA − X ≺ 0
    holds iff A_cᵀX + XA_c ≺ 0 for the same X (discrete and continuous Lyapunov inequalities)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        A = rng.standard_normal((4, 4))
        A *= rng.uniform(0.5, 1.2) / np.max(np.abs(np.linalg.eigvals(A)))
        B, C, D = rng.standard_normal((4, 2)), rng.standard_normal((3, 4)), rng.standard_normal((3, 2))
        Ac, Bc, Cc, Dc = cayley(A, B, C, D)
        for M, Mc in zip((A, B, C, D), inverse_cayley(Ac, Bc, Cc, Dc), strict=True):
            np.testing.assert_allclose(Mc, M, atol=1e-10)
        L = rng.standard_normal((4, 4))
        X = L @ L.T + 0.1 * np.eye(4)
        discrete = np.linalg.eigvalsh(A.T @ X @ A - X)[-1] < 0
        continuous = np.linalg.eigvalsh(Ac.T @ X + X @ Ac)[-1] < 0
        assert discrete == continuous
        if np.max(np.abs(np.linalg.eigvals(A))) < 1:
            nd = control.norm(control.ss(A, B, C, D, 1.0), "inf")
            assert control.norm(control.ss(Ac, Bc, Cc, Dc), "inf") == pytest.approx(nd, rel=1e-6)


def _discrete_eliminated_optimum(vertices) -> float:
    """Independent reference: the common-Lyapunov optimum of the *discrete* eliminated conditions of
    Gahinet & Apkarian (1994, Thm. 5.3; polytopic: Apkarian, Gahinet & Becker 1995), per vertex

        [N_Xᵀ diag(X, γI) N_X   N_Xᵀ[A_iX  B1_i; C1_iX  D11_i]; ⋆   diag(X, γI)] ⪰ 0,
        [Y   [YA_i  YB1_i]N_Y   0; ⋆   N_Yᵀdiag(Y, γI)N_Y   N_Yᵀ[C1_iᵀ; D11_iᵀ]; ⋆  ⋆  γI] ⪰ 0,
        [X I; I Y] ⪰ 0,

    in the shift form on coordinates balanced by scipy's matrix_balance (no bilinear map)."""
    n, nw, _, nz, _ = vertices[0].dims
    _, (s, _) = scipy.linalg.matrix_balance(np.mean([np.abs(v.A) for v in vertices], axis=0), permute=False,
                                            separate=True)
    X, Y, g = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True), cp.Variable()
    cons = [cp.bmat([[X, np.eye(n)], [np.eye(n), Y]]) >> 0]
    for v in vertices:
        A, B1, B2 = v.A * s[None, :] / s[:, None], v.B1 / s[:, None], v.B2 / s[:, None]
        C1, C2 = v.C1 * s[None, :], v.C2 * s[None, :]
        NX = scipy.linalg.null_space(np.hstack([B2.T, v.D12.T]))
        NY = scipy.linalg.null_space(np.hstack([C2, v.D21]))
        dX = cp.bmat([[X, np.zeros((n, nz))], [np.zeros((nz, n)), g * np.eye(nz)]])
        dXw = cp.bmat([[X, np.zeros((n, nw))], [np.zeros((nw, n)), g * np.eye(nw)]])
        out = NX.T @ cp.bmat([[A @ X, B1], [C1 @ X, v.D11]])
        M1 = cp.bmat([[NX.T @ dX @ NX, out], [out.T, dXw]])
        inp = cp.hstack([Y @ A, Y @ B1]) @ NY
        right = NY.T @ np.vstack([C1.T, v.D11.T])
        dY = cp.bmat([[Y, np.zeros((n, nw))], [np.zeros((nw, n)), g * np.eye(nw)]])
        M2 = cp.bmat([[Y, inp, np.zeros((n, nz))], [inp.T, NY.T @ dY @ NY, right],
                      [np.zeros((nz, n)), right.T, g * np.eye(nz)]])
        cons += [0.5 * (M1 + M1.T) >> 0, 0.5 * (M2 + M2.T) >> 0]
    cp.Problem(cp.Minimize(g), cons).solve(solver="CLARABEL")
    return float(g.value)


def test_polytopic_gamma_matches_an_independent_common_lyapunov_optimum():
    """The two-vertex test plant: γ within 5 % of the discrete-form common-Lyapunov optimum, certified
    (vertex margins, frozen norms by python-control, switching simulation)."""
    model, weights = two_state_plant(), WEIGHTS
    gp = generalized_plant(model, weights)
    res = synthesize(gp)
    reference = _discrete_eliminated_optimum(gp.vertices)
    assert abs(res.gamma_estimate - reference) <= 0.05 * reference
    assert reference * (1 - 0.05) <= res.gamma <= 1.05 * reference
    cert = certify(res, model, per_axis=11)
    assert cert.ok and cert.frozen_hinf_max <= res.gamma * (1 + 1e-3)


def test_polytopic_gamma_is_not_below_any_frozen_optimum(design):
    model, res = design
    for v in res.vertices:
        assert res.gamma >= riccati_gamma(v, model.Ts) * (1 - 1e-3)
    assert min(vertex_margins(res)) > 0


def test_every_controller_passes_the_independent_recheck(design):
    model, res = design
    cert = certify(res, model, per_axis=15)
    assert cert.ok and cert.margin > 0 and cert.quadratically_stable
    assert cert.frozen_hinf_max <= cert.gamma * (1 + 1e-3)
    assert cert.switching_growth <= 1.0 and cert.switching_final < 1.0


def test_recheck_catches_a_tampered_controller(design):
    _, res = design
    Ak, Bk, Ck, Dk = res.K_vertices[0]
    assert certificate_margin(res.vertices[0], (Ak, Bk, 1.5 * Ck, Dk), res.lyapunov_factor, res.gamma) < 0


def test_riccati_gamma_finds_optima_below_one():
    """The old bracket started at 1 and returned 1.0045 for an optimum of 0.837."""
    model = two_state_plant()
    v = generalized_plant(model, WEIGHTS, [[0.0, 0.0]]).vertices[0]
    optimum = riccati_gamma(v, model.Ts)
    assert riccati_controller(v, model.Ts, optimum) is not None
    assert riccati_controller(v, model.Ts, optimum * (1 - 1e-3)) is None
    res = hinfsyn(v.ss(model.Ts), 1, 1)
    assert optimum * (1 - 1e-3) <= res.gamma <= 1.01 * optimum


def test_degenerate_box_is_the_lti_design_at_that_point(design):
    model, res = design
    gp = generalized_plant(model, WEIGHTS, [[0.5, 0.5]])
    assert gp.polytope.kind == "point" and gp.polytope.n_vertices == 1
    lti = synthesize(gp)
    assert certify(lti, model, per_axis=3).ok
    assert lti.gamma <= res.gamma * (1 + 1e-2)


def test_hinfsyn_vertex_controllers_interpolate_like_the_plant(design):
    """hinfsyn on the vertex StateSpaces gives vertex controllers whose λ-interpolation keeps every
    frozen closed loop within γ (python-control norms at interior points)."""
    model, _ = design
    gp = generalized_plant(model, WEIGHTS)
    res = hinfsyn([v.ss(model.Ts) for v in gp.vertices], 1, 1)
    assert len(res.vertex_controllers) == 2 and all(K.dt == model.Ts for K in res.vertex_controllers)
    for lam in (0.0, 0.3, 0.7, 1.0):
        v = gp.at(np.array([1 - lam, lam]))
        norm, radius = _closed_loop_norm(v, res.controller([1 - lam, lam]), model.Ts)
        assert radius < 1 and norm <= res.gamma * (1 + 1e-6)


def test_hinfsyn_refuses_bad_plants_with_one_line():
    G = control.ss(np.eye(2) * 0.5, np.ones((2, 3)), np.ones((3, 2)), np.zeros((3, 3)), 0.01)
    with pytest.raises(ModelError, match="discrete-time"):
        hinfsyn(control.ss(-np.eye(2), np.ones((2, 3)), np.ones((3, 2)), np.zeros((3, 3))), 1, 1)
    with pytest.raises(ModelError, match="nmeas = 3"):
        hinfsyn(G, 3, 1)
    with pytest.raises(ModelError, match="differ"):
        hinfsyn([G, control.ss(G.A, G.B, G.C, G.D, 0.02)], 1, 1)


def test_infeasible_spec_names_the_reason():
    gp = generalized_plant(two_state_plant(), WEIGHTS)
    with pytest.raises(SynthesisError, match=r"γ = 0.01.*no strict solution.*vertex poles") as info:
        synthesize(gp, gamma_max=0.01)
    assert info.value.category == "infeasible"


def test_a_box_no_common_controller_covers_is_refused_with_the_reason():
    """The exact ADIP linearizations at 0°, 60° and 75.5°: no common Lyapunov matrix (known since the
    ±75° design issue); the refusal names the method and what to change."""
    verts = [adip_vertex(deg) for deg in (0.0, 60.0, 75.5)]
    with pytest.raises(SynthesisError, match=r"common Lyapunov matrix.*shrink the scheduling box"):
        hinfsyn([v.ss(TS) for v in verts], 2, 1)


def test_parameter_dependent_input_matrix_without_filter_is_refused():
    weights = {k: v for k, v in WEIGHTS.items() if k != "B"}
    with pytest.raises(Exception, match="B2 of the generalized plant depends"):
        generalized_plant(two_state_plant(), weights)


def test_static_controller_survives_json(tmp_path):
    model = two_state_plant()
    poly = polytope_of(model)
    K = LPVController(np.zeros((2, 0, 0)), np.zeros((2, 0, 1)), np.zeros((2, 1, 0)),
                      np.array([[[0.5]], [[0.7]]]), poly, model.basis, model.Ts)
    K.save(tmp_path / "k.json")
    K2 = load(tmp_path / "k.json")
    assert K2.order == 0 and K2.Dk.shape == (2, 1, 1)
    np.testing.assert_allclose(K2.step(np.array([2.0]), np.array([1.0])), [1.4])


def test_riccati_controller_meets_its_level_and_none_below_the_optimum(adip_upright):
    """SB10DD's controller at 1.05 γ_opt: stable closed loop with ‖T_zw‖∞ ≤ γ by an independent lft;
    at 0.9 γ_opt (below the optimum) no controller is returned."""
    vertex, _, gamma_opt = adip_upright
    K = riccati_controller(vertex, TS, 1.05 * gamma_opt)
    loop = vertex.ss(TS).lft(control.ss(*K, TS), 1, 2)
    assert np.max(np.abs(np.linalg.eigvals(loop.A))) < 1
    assert control.norm(loop, "inf") <= 1.05 * gamma_opt * (1 + 1e-3)
    assert riccati_controller(vertex, TS, 0.9 * gamma_opt) is None


def test_controller_round_trip_and_online_step(design, tmp_path):
    _, res = design
    K = res.controller
    path = tmp_path / "k.json"
    K.save(path)
    K2 = load(path)
    assert isinstance(K2, LPVController)
    rng = np.random.default_rng(0)
    e, p = rng.standard_normal((50, 1)), rng.uniform(-1, 1, (50, 1))
    np.testing.assert_allclose(K.simulate(e, p), K2.simulate(e, p), atol=1e-12)
    K.reset()
    pc = np.full((50, 1), 0.3)
    _, y_frozen = control.forced_response(K.frozen([0.3]), U=e[:, 0])
    np.testing.assert_allclose(K.simulate(e, pc)[:, 0], y_frozen, atol=1e-9)


def test_cli_synth_writes_controller_and_keeps_model(tmp_path):
    model = two_state_plant()
    mpath, cpath, kpath = tmp_path / "m.json", tmp_path / "d.toml", tmp_path / "k.json"
    model.save(mpath)
    before = mpath.read_bytes()
    cpath.write_text('[synth]\nweights.S = {num = [0.1, 0.1], den = [1, -1]}\n'
                     'weights.K = {num = [0.01], den = [1]}\nweights.B = {num = [0, 0.5], den = [1, -0.5]}\n'
                     'trim = { p = [-1.0, 1.0], u = [[0.5], [-0.5]] }\n')
    run = subprocess.run([sys.executable, "-m", "lpvflow.pipeline.cli", "synth", str(mpath), "--config",
                          str(cpath), "-o", str(kpath)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "gamma =" in run.stdout and "smallest margin" in run.stdout
    K = load(kpath)
    assert isinstance(K, LPVController) and mpath.read_bytes() == before
    # the table's trim is part of the controller, as in the design's synth stage
    np.testing.assert_array_equal(K.trim.u, [[0.5], [-0.5]])
    cpath.write_text("[synth]\nweights.S = {num = [0.1], den = [1]}\n")
    run = subprocess.run([sys.executable, "-m", "lpvflow.pipeline.cli", "synth", str(mpath), "--config",
                          str(cpath), "-o", str(kpath)], capture_output=True, text=True)
    assert run.returncode == 2 and "W_K" in run.stderr and len(run.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("example", ["maglev", "airpath"])
def test_fmu_operating_point_gamma_is_within_one_percent_of_the_riccati_optimum(example):
    """The bundled maglev and airpath designs' LTI problem at their baseline point, on the plant FMU's own
    linearization (finite differences at the equilibrium, ZOH at the design's Ts) with the design's
    weights: the certified γ within 1 % of SB10DD, the closed loop re-checked by python-control."""
    import tomllib
    from pathlib import Path

    from lpvflow.pipeline.config import bundled_config
    from lpvflow.synth.plant import augment, weight_systems
    from lpvflow.validate.fmu_reference import FmuLinearization, SelectedChannels

    config = tomllib.loads(bundled_config(example).read_text())
    experiment, identify, synth = config["experiment"], config["identify"], config["synth"]
    fmu = Path(__file__).resolve().parents[1] / config["design"]["plant"]
    if not fmu.exists():
        pytest.skip(f"{fmu} not built (make fmus)")
    Ts = float(experiment["Ts"])
    expressions = [experiment.get("scheduling", {}).get(name, name) for name in identify["p"]]
    start = {}
    if example == "maglev":  # the FMU's default start is 7 cm: begin the search at the design point
        currents = rm.maglev_equilibrium_currents(0.015, 0.08, rm.default_parameters("maglev"))
        start = {"lower_disk_position": 0.015, "upper_disk_position": 0.08,
                 "lower_coil_current": currents[0], "upper_coil_current": currents[1]}
    with FmuLinearization(fmu, Ts, expressions, start=start) as reference:
        G = SelectedChannels(reference, identify["u"], identify["y"])(np.asarray(synth["baseline_at"]))
    ny, nu = len(identify["y"]), len(identify["u"])
    W = weight_systems(synth["weights"], ny, nu, Ts)
    P = augment(control.ss(G.A, G.B, G.C, G.D, Ts), W, Ts)
    res = hinfsyn(P, ny, nu)
    v = res.vertices[0]
    gamma_ric = riccati_gamma(v, Ts)
    assert gamma_ric * (1 - 1e-3) <= res.gamma <= 1.01 * gamma_ric
    norm, radius = _closed_loop_norm(v, res.controller, Ts)
    assert radius < 1 and norm <= res.gamma * (1 + 1e-6)


def test_augw_generalized_plant_like_control_hinfsyn():
    """The README's example: a lightly damped plant with control.augw weights (a W1 pole at z = 0.9999):
    the certified γ within 1 % of SB10DD (measured 0.24 %; the previous core answered 2.9 % above, and
    4.8 % or 17.7 % above depending on the installed Clarabel and SCS) and the python-control closed-loop
    norm below it."""
    G = control.c2d(control.tf([4.0], [1.0, 0.4, 4.0]), 0.01)
    W1 = control.c2d(control.tf([0.5, 1.0], [1.0, 0.01]), 0.01)
    P = control.augw(G, W1, control.tf(0.1, 1, 0.01))
    res = hinfsyn(P, 1, 1)
    gamma_ric = riccati_gamma(res.vertices[0], 0.01)
    assert gamma_ric * (1 - 1e-3) <= res.gamma <= 1.01 * gamma_ric
    norm, radius = _closed_loop_norm(res.vertices[0], res.controller, 0.01)
    assert radius < 1 and norm <= res.gamma * (1 + 1e-6)


def test_the_readme_example_runs_as_written():
    """The README's hinfsyn block, executed verbatim: the certified γ bounds the python-control norm."""
    gamma, norm = (float(v) for v in run_python_block("## H∞ synthesis in python-control's idiom").split())
    assert 0 < norm <= gamma
