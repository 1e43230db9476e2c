"""Polytopic state-feedback H∞ synthesis: LTI optimum, frozen-point bound, dilated ≤ quadratic, disk, errors.

The LTI reference is independent of every SDP: the discrete-time H∞ state-feedback game Riccati
equation (Başar & Bernhard, "H∞-optimal control and related minimax design problems", 2nd ed. 1995,
Thm. 3.7, closed-loop perfect state information; the minimiser u = Kx moves before w): a gain with
‖T_zw‖∞ < γ exists iff the DARE

    X = AᵀXA + C1ᵀC1 − (AᵀXB + C1ᵀD)(BᵀXB + R)⁻¹(BᵀXA + DᵀC1),  B = [B1 B2], D = [D11 D12],
    R = DᵀD − diag(γ²I, 0),

has a stabilizing solution X ⪰ 0 with γ²I − B1ᵀXB1 − D11ᵀD11 ≻ 0 (w-concavity; with D12 of full
column rank the u-block condition follows). γ_ric is found by bisection on this test (scipy's
``solve_discrete_are``), and the saddle-point gain at γ_ric(1 + 1e-3) is checked with python-control's
``norm``: the reference is an attained upper bound as well as the theory's lower bound.
"""

import dataclasses
import re
import textwrap
from pathlib import Path

import control
import numpy as np
import pytest
import scipy.linalg

import lpvflow.synth.lmi_statefeedback as sfmod
import lpvflow.synth.statefeedback_certificate as certificate_module
from lpvflow.synth.examples import maglev_like, random_lpv
from lpvflow.synth.lmi_statefeedback import (
    as_vertices,
    synthesize_state_feedback,
    vertex_lmi_max_eig,
)
from lpvflow.synth.plant import augment, generalized_plant, weight_systems
from lpvflow.synth.sdp import SynthesisError
from lpvflow.synth.statefeedback_certificate import certify_state_feedback
from tests.readme_blocks import run_python_block
from tests.synth_cases import two_state_plant

WEIGHTS = {"S": {"num": [0.1, 0.1], "den": [1, -1]}, "K": {"num": [0.01], "den": [1]},
           "B": {"num": [0, 0.5], "den": [1, -0.5]}}
DISK = (0.5, 0.45)




def _riccati(v, gamma):
    """(feasible, saddle-point gain K) of the game DARE in the module docstring at γ."""
    nw, nu = v.B1.shape[1], v.B2.shape[1]
    B, D = np.hstack([v.B1, v.B2]), np.hstack([v.D11, v.D12])
    R = D.T @ D - np.diag(np.r_[np.full(nw, gamma**2), np.zeros(nu)])
    try:
        X = scipy.linalg.solve_discrete_are(v.A, B, v.C1.T @ v.C1, R, s=v.C1.T @ D)
    except (np.linalg.LinAlgError, ValueError):
        return False, None
    X = 0.5 * (X + X.T)
    H, L = B.T @ X @ B + R, B.T @ X @ v.A + D.T @ v.C1
    Hww, Hwu, Huu = H[:nw, :nw], H[:nw, nw:], H[nw:, nw:]
    if np.linalg.eigvalsh(X)[0] < -1e-9 * max(1.0, np.abs(X).max()) or np.linalg.eigvalsh(Hww)[-1] >= 0:
        return False, None
    S = Huu - Hwu.T @ np.linalg.solve(Hww, Hwu)
    return True, -np.linalg.solve(S, L[nw:] - Hwu.T @ np.linalg.solve(Hww, L[:nw]))


def _riccati_gamma(v, rel=1e-5):
    lo, hi = 0.0, 1.0
    while not _riccati(v, hi)[0]:
        lo, hi = hi, 2.0 * hi
    while hi - lo > rel * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if _riccati(v, mid)[0] else (mid, hi)
    return hi


def _norm(v, K, Ts=1.0):
    A, B, C, D = v.closed_loop(K)
    return float(control.norm(control.ss(A, B, C, D, Ts), "inf"))


def _tuple(v):
    return (v.A, v.B1, v.B2, v.C1, v.D11, v.D12)


@pytest.fixture(scope="module")
def toy():
    model = two_state_plant()
    gp = generalized_plant(model, WEIGHTS)
    designs = {(m, d): synthesize_state_feedback(gp, m, disk=d)
               for m in ("quadratic", "dilated") for d in (None, DISK)}
    return model, gp, designs


@pytest.mark.parametrize("vertex", [0, 1])
def test_one_vertex_gamma_equals_the_riccati_optimum(toy, vertex):
    _, gp, _ = toy
    v = as_vertices(gp)[vertex]
    gamma_ric = _riccati_gamma(v)
    ok, K_ric = _riccati(v, gamma_ric * (1 + 1e-3))
    assert ok and _norm(v, K_ric) <= gamma_ric * (1 + 1e-3)  # the reference is attained
    res = synthesize_state_feedback([_tuple(v)], "quadratic")
    print(f"vertex {vertex}: γ_LMI = {res.gamma_opt:.6f}, γ_Riccati = {gamma_ric:.6f}")
    assert gamma_ric * (1 - 1e-3) <= res.gamma_opt <= gamma_ric * (1 + 1e-2)
    assert gamma_ric * (1 - 1e-3) <= _norm(v, res.K_vertices[0]) <= res.gamma


def test_ill_conditioned_vertex_reaches_the_riccati_optimum():  # 3-5 s: maglev, poles at 0.999, tiny D12
    """Needs the re-centring passes: the first pass alone stops at γ = 1.525 (Riccati: 1.332)."""
    model, weights = maglev_like()
    v = as_vertices(generalized_plant(model, weights))[0]
    gamma_ric = _riccati_gamma(v)
    res = synthesize_state_feedback([_tuple(v)], "quadratic")
    print(f"maglev vertex 0: γ_LMI = {res.gamma_opt:.6f}, γ_Riccati = {gamma_ric:.6f}; {res.report.status}")
    assert gamma_ric * (1 - 1e-3) <= res.gamma_opt <= gamma_ric * (1 + 1e-2)


def test_polytopic_gamma_is_not_below_the_frozen_optima(toy):
    model, _, designs = toy
    W = weight_systems(WEIGHTS, 1, 1, model.Ts)
    frozen = []
    for p in np.linspace(-1, 1, 21):
        P = augment(model.frozen([p]), W, model.Ts)
        A, B, C, D = (np.asarray(M) for M in (P.A, P.B, P.C, P.D))
        v = sfmod.SFVertex(A, B[:, :1], B[:, 1:], C[:2], D[:2, :1], D[:2, 1:])
        frozen.append(_riccati_gamma(v))
    for method in ("quadratic", "dilated"):
        print(f"{method}: γ_opt = {designs[method, None].gamma_opt:.6f}, worst frozen {max(frozen):.6f}")
        assert designs[method, None].gamma_opt >= max(frozen) * (1 - 1e-3)


def _dilated_ratio(gp, seed_quadratic):
    q = synthesize_state_feedback(gp, "quadratic")
    d = synthesize_state_feedback(gp, "dilated", seed_quadratic=seed_quadratic)
    print(f"γ_quadratic = {q.gamma_opt:.6f}, γ_dilated = {d.gamma_opt:.6f}, "
          f"ratio {d.gamma_opt / q.gamma_opt:.6f}")
    return q, d


def test_dilated_is_not_worse_than_quadratic(toy):
    """Default "dilated" starts from the quadratic point, so ≤ holds by construction here; the random
    polytopes below compare two independent solves. With the disk, the vertex-dependent Q_i pay off."""
    _, _, designs = toy
    for disk in (None, DISK):
        q, d = designs["quadratic", disk], designs["dilated", disk]
        print(f"disk {disk}: γ_quadratic = {q.gamma_opt:.6f}, γ_dilated = {d.gamma_opt:.6f}")
        assert d.gamma_opt <= q.gamma_opt * (1 + 1e-6)
    assert designs["dilated", DISK].gamma_opt < 0.9 * designs["quadratic", DISK].gamma_opt


@pytest.mark.parametrize("seed", [2, 3, 5])
def test_dilated_not_worse_on_random_polytopes(seed):
    gp = generalized_plant(random_lpv(seed, nx=2), WEIGHTS)
    q, d = _dilated_ratio(gp, seed_quadratic=False)  # two independent solves
    assert d.gamma_opt <= q.gamma_opt * (1 + 1e-6)


@pytest.mark.slow
def test_maglev_like_dilated_not_worse_than_quadratic():  # 40-80 s: 12 states, 9 dilated LMIs of size 30
    model, weights = maglev_like()
    # started from the quadratic point: without it Clarabel stops at 1.47308 > 1.47213 (quadratic)
    plant = generalized_plant(model, weights)
    q, d = _dilated_ratio(plant, seed_quadratic=True)
    assert d.gamma_opt <= q.gamma_opt * (1 + 1e-6)
    assert certify_state_feedback(d, model, plant.weights, per_axis=11).ok


@pytest.mark.parametrize("disk", [None, DISK])
def test_every_quadratic_point_is_a_dilated_point(toy, disk):
    _, _, designs = toy
    q = designs["quadratic", disk]
    X = q.G
    as_dilated = dataclasses.replace(q, method="dilated", P=[X] * len(q.P),
                                     Q=None if disk is None else [X] * len(q.P))
    assert vertex_lmi_max_eig(as_dilated) < 0  # every (i, j) pair, G = P_i = Q_i = X
    tampered = dataclasses.replace(as_dilated, K_vertices=[1.5 * K for K in q.K_vertices])
    assert vertex_lmi_max_eig(tampered) > 0


def _max_disk_distance(result, model):
    """max over a θ grid of max |eig(A + B2 K(θ)) − q| / r for DISK, from model.frozen(p) and the weights."""
    W = weight_systems(WEIGHTS, 1, 1, model.Ts)
    worst = 0.0
    for p in np.linspace(-1, 1, 21):
        P = augment(model.frozen([p]), W, model.Ts)
        A_cl = np.asarray(P.A) + np.asarray(P.B)[:, 1:] @ result.gain_at([p])
        worst = max(worst, np.max(np.abs(np.linalg.eigvals(A_cl) - DISK[0])) / DISK[1])
    return worst


@pytest.mark.parametrize("method", ["quadratic", "dilated"])
def test_disk_moves_every_frozen_pole_into_the_disk_and_is_active(toy, method):
    model, gp, designs = toy
    free, placed = designs[method, None], designs[method, DISK]
    outside, inside = _max_disk_distance(free, model), _max_disk_distance(placed, model)
    cert = certify_state_feedback(placed, model, gp.weights, per_axis=21)
    print(f"{method}: max |z − q|/r without the disk {outside:.3f}, with it {inside:.3f}; "
          f"γ {free.gamma:.4f} → {placed.gamma:.4f}")
    assert outside > 1.0 and inside < 1.0 and cert.pole_max < 1.0 and cert.ok


@pytest.mark.parametrize("method", ["quadratic", "dilated"])
def test_every_controller_passes_the_independent_recheck(toy, method):
    model, gp, designs = toy
    for disk in (None, DISK):
        cert = certify_state_feedback(designs[method, disk], model, gp.weights)
        print(method, disk, *cert.lines(), sep="\n  ")
        assert cert.ok and cert.frozen_hinf_max <= cert.gamma * (1 + 1e-3) and cert.switching_final < 1e-6
        if method == "quadratic":
            assert cert.quadratically_stable


def test_recheck_catches_a_tampered_design(toy):
    model, gp, designs = toy
    good = designs["quadratic", None]
    bad = dataclasses.replace(good, K_vertices=[2.0 * K for K in good.K_vertices])
    cert = certify_state_feedback(bad, model, gp.weights, per_axis=11)
    assert cert.lmi_max_eig > 0 and not cert.ok
    low = dataclasses.replace(good, gamma=0.8 * good.gamma)
    cert = certify_state_feedback(low, model, gp.weights, per_axis=11)
    assert cert.frozen_hinf_max > low.gamma and not cert.ok


def test_a_point_failing_the_recheck_is_an_error_not_a_controller(monkeypatch):
    monkeypatch.setattr(sfmod, "vertex_lmi_max_eig", lambda result: 1e-3)
    gp = generalized_plant(two_state_plant(), WEIGHTS)
    with pytest.raises(SynthesisError, match="passes the independent vertex-LMI re-check"):
        synthesize_state_feedback(gp, "quadratic")


def _scalar_vertex(a, b2):
    return (np.array([[a]]), np.array([[1.0]]), np.array([[b2]]), np.array([[1.0], [0.0]]),
            np.zeros((2, 1)), np.array([[0.0], [0.1]]))


def test_varying_input_matrix_gives_one_constant_gain():
    verts = [_scalar_vertex(1.2, 1.0), _scalar_vertex(1.1, 0.6)]
    res = synthesize_state_feedback(verts, "quadratic")
    assert not res.scheduled
    np.testing.assert_array_equal(res.K_vertices[0], res.K_vertices[1])
    cert = certify_state_feedback(res, per_axis=21)
    assert cert.ok, cert.lines()


def test_uncontrollable_unstable_mode_is_refused_with_the_reason():
    A = np.diag([1.2, 0.5])
    vert = (A, np.ones((2, 1)), np.array([[0.0], [1.0]]), np.eye(2), np.zeros((2, 1)), np.zeros((2, 1)))
    with pytest.raises(SynthesisError, match=r"uncontrollable unstable mode at z = 1\.2"):
        synthesize_state_feedback([vert], "quadratic")


def test_disk_that_excludes_an_uncontrollable_mode_is_refused_with_the_reason():
    A = np.diag([0.9, 1.5])
    vert = (A, np.ones((2, 1)), np.array([[0.0], [1.0]]), np.eye(2), np.zeros((2, 1)), np.zeros((2, 1)))
    synthesize_state_feedback([vert], "quadratic")  # feasible without the disk
    with pytest.raises(SynthesisError, match=r"uncontrollable mode at z = 0\.9, outside the disk"):
        synthesize_state_feedback([vert], "quadratic", disk=(0.0, 0.5))


def test_no_constant_gain_for_opposite_input_signs_is_refused_with_the_reason():
    verts = [_scalar_vertex(1.5, 1.0), _scalar_vertex(1.5, -1.0)]  # |1.5 + k| < 1 and |1.5 − k| < 1: none
    with pytest.raises(SynthesisError, match="one constant gain must serve all vertices"):
        synthesize_state_feedback(verts, "dilated")


def test_gamma_spec_below_the_optimum_is_refused_with_the_reason(toy):
    _, gp, designs = toy
    with pytest.raises(SynthesisError, match=r"no state feedback reaches γ ≤ 0\.4"):
        synthesize_state_feedback(gp, "quadratic", gamma_max=0.4)
    assert designs["quadratic", None].gamma_opt > 0.4


def test_quadratic_stability_falls_back_to_the_designs_own_lyapunov_matrix(toy, monkeypatch):
    model, gp, designs = toy
    failed = certificate_module.quadratic_stability([np.array([[2.0]])])  # a real refusal (unstable vertex)
    monkeypatch.setattr(certificate_module, "quadratic_stability", lambda A: failed)
    good = designs["quadratic", None]
    cert = certify_state_feedback(good, model, gp.weights, per_axis=5)
    assert cert.quadratically_stable and "the design's P" in cert.stability_note and cert.ok
    bad = dataclasses.replace(good, K_vertices=[3.0 * K for K in good.K_vertices])
    assert not certify_state_feedback(bad, model, gp.weights, per_axis=5).quadratically_stable


def test_the_module_docstring_example_runs():
    """The library-API example at the top of lpvflow.synth.lmi_statefeedback designs and certifies."""
    doc = sfmod.__doc__
    block = doc[doc.index("::\n") + 3:doc.index("\n\n", doc.index("::\n") + 4)]
    exec(textwrap.dedent(block), {})


def test_the_docs_example_runs_and_both_designs_are_certified():
    """The example of docs/synthesis_methods.md runs as printed there: both designs pass the independent
    re-check, dilated γ ≤ quadratic γ, and the γ values the page shows are the ones it prints."""
    page = Path(__file__).resolve().parents[1] / "docs" / "synthesis_methods.md"
    heading = "## A library API beside the methods: polytopic state feedback"
    line = re.compile(r"^(quadratic|dilated): gamma = ([0-9.]+), K is 1x4, certified: (True|False)$", re.M)
    printed = {m[1]: (float(m[2]), m[3]) for m in line.finditer(run_python_block(heading, page))}
    assert set(printed) == {"quadratic", "dilated"}
    assert all(certified == "True" for _, certified in printed.values())
    assert printed["dilated"][0] <= printed["quadratic"][0]
    section = page.read_text().split(heading, 1)[1].split("\n## ", 1)[0]
    shown = {m[1]: float(m[2]) for m in line.finditer(section)}  # the output the page shows
    assert shown.keys() == printed.keys()
    for method, gamma in shown.items():
        assert printed[method][0] == pytest.approx(gamma, rel=2e-3), method
