"""``[synth] method = "loop-shaping"`` through ``lpvflow synth --config``: the vertex levels against the
Riccati optimum of the shaped plant, the margin of the written controller by an independent frequency-grid
formula, and the frozen check refusing a destabilized controller."""

import itertools
import json

import control
import numpy as np
import pytest

from lpvflow.models import LPVSS, load
from lpvflow.pipeline.cli import main
from lpvflow.synth.controller import mix
from lpvflow.synth.loop_shaping import crossover_normalized, integrator_lead_weight, loop_shaping
from lpvflow.synth.loop_shaping_design import FROZEN_PER_SEGMENT, frozen_margin_check, modal_form
from lpvflow.synth.polytope import hat_coordinates
from lpvflow.validate.robust_stability import optimal_margin
from tests.synth_cases import two_state_plant

BREAKPOINTS = [-1.0, 0.0, 1.0]
CROSSOVER = 4.0
DESIGN = f"""[synth]
method = "loop-shaping"
crossover = {CROSSOVER}
box = [[-1.0, 1.0]]
breakpoints = {BREAKPOINTS}
weights.S = {{ num = [0.5], den = [1] }}
weights.K = {{ num = [0.1], den = [1] }}
weights.B = {{ num = [0, 0.5], den = [1, -0.5] }}
"""


def _random_plant(seed: int) -> LPVSS:
    """two_state_plant with its nominal A and its B dependence drawn at random (stable on [−1, 1])."""
    model = two_state_plant()
    rng = np.random.default_rng(seed)
    A, B = model.A.copy(), model.B.copy()
    A[0] = np.array([[rng.uniform(0.6, 0.9), rng.uniform(-0.2, 0.2)], [0.0, rng.uniform(0.5, 0.85)]])
    B[1, 1, 0] = rng.uniform(-0.4, 0.4)
    return LPVSS(A, B, model.C, model.D, model.basis, model.Ts)


def _margin_on_grid(G: control.StateSpace, K: tuple[np.ndarray, ...], W1: control.StateSpace) -> float:
    """b(G·W1, K∞) with K∞ = W1⁻¹K (u = K y) from the frequency responses on a grid, 0 if the loop
    G, K is unstable: b = 1/max_ω σ̄([I; K∞](I − Gs K∞)⁻¹[I  Gs])."""
    Ak, Bk, Ck, Dk = K
    A, B, C = (np.asarray(M) for M in (G.A, G.B, G.C))
    loop = np.block([[A + B @ Dk @ C, B @ Ck], [Bk @ C, Ak]])
    if np.abs(np.linalg.eigvals(loop)).max() >= 1.0:
        return 0.0
    Ts = float(G.dt)
    worst = 0.0
    for w in np.logspace(-3, np.log10(np.pi / Ts) - 1e-6, 3000):
        z = np.exp(1j * w * Ts)
        g, w1 = G(z, squeeze=False), W1(z, squeeze=False)
        k = Ck @ np.linalg.solve(z * np.eye(Ak.shape[0]) - Ak, Bk) + Dk
        gs, k_inf = g @ w1, np.linalg.solve(w1, k)
        p = gs.shape[0]
        inner = np.linalg.inv(np.eye(p) - gs @ k_inf)
        T = np.vstack([np.eye(p), k_inf]) @ inner @ np.hstack([np.eye(p), gs])
        worst = max(worst, np.linalg.norm(T, 2))
    return 1.0 / worst


@pytest.mark.parametrize("seed", [None, 3])
def test_loop_shaping_controller_reaches_the_optimal_shaped_margin(tmp_path, seed):
    model = two_state_plant() if seed is None else _random_plant(seed)
    model.save(tmp_path / "model.json")
    (tmp_path / "design.toml").write_text(DESIGN)
    out = tmp_path / "K.json"
    # exit 1 only when the frozen check between breakpoints fails; the controller is written either way
    rc = main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"),
               "-o", str(out)])
    controller = load(out)
    gammas = json.loads(out.read_text())["info"]["vertex_gammas"]
    assert controller.info["method"] == "loop-shaping" and controller.info["crossover"] == CROSSOVER
    W1 = integrator_lead_weight(model.Ts, CROSSOVER)
    for i, p in enumerate(BREAKPOINTS):
        G = model.frozen(np.array([p]))
        W1_i = crossover_normalized(G, W1, CROSSOVER)
        assert gammas[i] == pytest.approx(1.0 / optimal_margin(G * W1_i), rel=1e-2)
        # the written controller reads e = r − y: u = −K e is u = K y with B and D negated back
        K = (controller.Ak[i], -controller.Bk[i], controller.Ck[i], -controller.Dk[i])
        assert _margin_on_grid(G, K, W1_i) >= 1.0 / (1.01 * gammas[i])
    # between the breakpoints: the interpolated controller on the interpolated model, W1(λ) = Σλ_iW1_i
    plants = [model.frozen(np.array([p])) for p in BREAKPOINTS]
    weights = [crossover_normalized(G, W1, CROSSOVER) for G in plants]
    ratios = []
    for t in np.linspace(BREAKPOINTS[0], BREAKPOINTS[-1], 2 * FROZEN_PER_SEGMENT - 1):
        lam = hat_coordinates(BREAKPOINTS, t)
        G, W1_l = (control.ss(*mix([(M.A, M.B, M.C, M.D) for M in Ms], lam), model.Ts)
                   for Ms in (plants, weights))
        Ak, Bk, Ck, Dk = mix([(controller.Ak[i], controller.Bk[i], controller.Ck[i], controller.Dk[i])
                              for i in range(len(BREAKPOINTS))], lam)
        ratios.append(_margin_on_grid(G, (Ak, -Bk, Ck, -Dk), W1_l) * 1.1 * gammas[int(np.argmax(lam))])
    certificate = controller.info["certificate"]
    assert min(ratios) == pytest.approx(certificate["worst_ratio"], rel=1e-2)
    assert (rc == 0) == certificate["ok"] == (certificate["worst_ratio"] >= 1.0)


def test_frozen_check_refuses_a_destabilized_controller():
    model = two_state_plant()
    W1 = integrator_lead_weight(model.Ts, CROSSOVER)
    W2 = control.ss([], [], [], np.eye(1), model.Ts)
    vertices, weights, K_inf, gammas = [], [], [], []
    for p in BREAKPOINTS:
        G = model.frozen(np.array([p]))
        W1_i = crossover_normalized(G, W1, CROSSOVER)
        design = loop_shaping([G], [W1_i], W2)
        vertices.append(tuple(np.asarray(M) for M in (G.A, G.B, G.C, G.D)))
        weights.append(tuple(np.asarray(M) for M in (W1_i.A, W1_i.B, W1_i.C, W1_i.D)))
        K_inf.append(modal_form(tuple(np.asarray(M) for M in (design.K_inf[0].A, design.K_inf[0].B,
                                                             design.K_inf[0].C, design.K_inf[0].D))))
        gammas.append(design.gamma)
    t = np.unique(np.concatenate([np.linspace(lo, hi, FROZEN_PER_SEGMENT)
                                  for lo, hi in itertools.pairwise(BREAKPOINTS)]))
    lams = [hat_coordinates(BREAKPOINTS, ti) for ti in t]
    assert frozen_margin_check(vertices, weights, K_inf, gammas, lams, model.Ts).b_min > 0  # all stable
    Ak, Bk, Ck, Dk = K_inf[1]
    broken = (Ak, Bk, Ck, Dk - 50.0)  # a large positive-feedback gain at the middle breakpoint
    G, W1_1 = control.ss(*vertices[1], model.Ts), control.ss(*weights[1], model.Ts)
    loop = (G * W1_1).feedback(control.ss(*broken, model.Ts), sign=1)
    assert np.abs(loop.poles()).max() > 1.0  # independently: the frozen loop there is unstable
    check = frozen_margin_check(vertices, weights, [K_inf[0], broken, K_inf[2]], gammas, lams, model.Ts)
    assert not check.ok and check.worst_ratio == 0.0


def test_crossover_above_the_weight_band_is_one_error_line(tmp_path, capsys):
    two_state_plant().save(tmp_path / "model.json")
    (tmp_path / "design.toml").write_text(DESIGN.replace(f"crossover = {CROSSOVER}", "crossover = 1000.0"))
    out = tmp_path / "K.json"
    assert main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"),
                 "-o", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "crossover 1000" in error[0] and not out.exists()
