"""``[synth] scheduling = "common"`` of the loop-shaping method: one W1 and one Lyapunov matrix over all
breakpoints. The certificate is re-checked in numpy on the loop that is shipped (the model and the
controller interpolated between breakpoints) at random points, its storage decreases along random
fast-switching schedules, b of the frozen loops is ≥ 1/γ by an independent frequency-grid formula, a
perturbed vertex controller is rejected, and the design file's key reaches the written controller."""

import functools
import json

import control
import numpy as np
import pytest

from lpvflow.models import LPVSS, load
from lpvflow.pipeline.cli import main
from lpvflow.synth.bilinear import closed_loop
from lpvflow.synth.controller import mix
from lpvflow.synth.loop_shaping import ncf_generalized_plant, output_integral_weight, shaped_plant
from lpvflow.synth.loop_shaping_common import certificate_margins, common_central_controllers, common_weight
from lpvflow.synth.margin_goal import Shaping
from lpvflow.synth.plant import VertexPlant
from lpvflow.synth.polytope import hat_coordinates
from tests.synth_cases import two_state_plant
from tests.test_loop_shaping_method import BREAKPOINTS, CROSSOVER, DESIGN, _margin_on_grid

SEEDS = [0, 1, 2]


def _random_plant(seed: int) -> LPVSS:
    """two_state_plant with its nominal A and the p-dependence of A and B drawn at random (stable on
    [−1, 1]); observable form (C constant), so B varies with p."""
    model = two_state_plant()
    rng = np.random.default_rng(seed)
    A, B = model.A.copy(), model.B.copy()
    A[0] = np.array([[rng.uniform(0.6, 0.9), rng.uniform(-0.2, 0.2)], [0.0, rng.uniform(0.5, 0.85)]])
    A[1] = np.diag(rng.uniform(-0.05, 0.05, 2))
    B[1, 1, 0] = rng.uniform(-0.4, 0.4)
    return LPVSS(A, B, model.C, model.D, model.basis, model.Ts)


@functools.cache
def _design(seed: int, output_integral: bool = False):
    """The common design of _random_plant(seed); with ``output_integral`` the integral action in W2 on the
    output (``[synth] integral_outputs``) instead of in W1."""
    model = _random_plant(seed)
    plants = [model.frozen(np.array([p])) for p in BREAKPOINTS]
    W2 = (output_integral_weight(model.Ts, CROSSOVER, [True]) if output_integral
          else control.ss([], [], [], np.eye(1), model.Ts))
    W1 = common_weight(plants, Shaping(CROSSOVER, 10.0, W2))
    common = common_central_controllers([shaped_plant(G, W1, W2) for G in plants], 1.01)
    return model, plants, W1, W2, common


def _ncf_vertex(Gs: control.StateSpace) -> VertexPlant:
    P = ncf_generalized_plant(Gs)
    return VertexPlant.from_ss(P, nw=P.ninputs - Gs.ninputs, nz=P.noutputs - Gs.noutputs)


@pytest.mark.parametrize(("seed", "output_integral"), [(s, False) for s in SEEDS] + [(0, True)])
def test_common_certificate_holds_on_the_shipped_loop_between_breakpoints(seed, output_integral):
    model, plants, W1, W2, common = _design(seed, output_integral)
    rng = np.random.default_rng(100 + seed)
    mats = [(G.A, G.B, G.C, G.D) for G in plants]
    for t in rng.uniform(BREAKPOINTS[0], BREAKPOINTS[-1], 6):
        # the model at p itself (affine in p, so the breakpoints' interpolation is exact here) shaped by W1
        G = model.frozen(np.array([t]))
        lam = hat_coordinates(BREAKPOINTS, t)
        assert np.allclose(mix(mats, lam)[1], np.asarray(G.B))
        K = mix(common.K_inf, lam)
        # the common LMI, rebuilt in numpy at this point from the certificate 𝒳 = FᵀF
        [margin] = certificate_margins([shaped_plant(G, W1, W2)], [K], common.lyapunov_factor, common.gamma)
        assert margin > 0
        # frozen: b(W2·G·W1, K∞) ≥ 1/γ by the frequency-grid formula (K = W1·K∞·W2 read by _margin_on_grid)
        assert _margin_on_grid(G, _matrices(W1 * control.ss(*K, model.Ts) * W2), W1, W2) >= 1 / common.gamma


def _matrices(M: control.StateSpace) -> tuple[np.ndarray, ...]:
    return tuple(np.asarray(X, dtype=float) for X in (M.A, M.B, M.C, M.D))


@pytest.mark.parametrize("seed", SEEDS)
def test_common_storage_decreases_when_the_scheduling_signal_jumps_every_sample(seed):
    """Any rate: with p(k) drawn anew every sample, V = ξᵀ𝒳ξ of the autonomous closed loop decreases at
    every step (𝒜(p)ᵀ𝒳𝒜(p) ≺ 𝒳 follows from the bounded-real inequality at every p)."""
    model, _, W1, W2, common = _design(seed)
    X = common.lyapunov_factor.T @ common.lyapunov_factor
    rng = np.random.default_rng(200 + seed)
    xi = rng.standard_normal(X.shape[0])
    for t in rng.uniform(BREAKPOINTS[0], BREAKPOINTS[-1], 60):
        A = closed_loop(_ncf_vertex(shaped_plant(model.frozen(np.array([t])), W1, W2)),
                        mix(common.K_inf, hat_coordinates(BREAKPOINTS, t)))[0]
        nxt = A @ xi
        assert nxt @ X @ nxt < xi @ X @ xi
        xi = nxt / np.sqrt(nxt @ X @ nxt)


@pytest.mark.parametrize("seed", SEEDS[:2])
def test_perturbed_vertex_controller_fails_the_common_certificate(seed):
    _, plants, W1, W2, common = _design(seed)
    shaped = [shaped_plant(G, W1, W2) for G in plants]
    assert min(certificate_margins(shaped, common.K_inf, common.lyapunov_factor, common.gamma)) > 0
    A, B, C, D = common.K_inf[1]
    perturbed = [common.K_inf[0], (A, B, 1.5 * C, D), common.K_inf[2]]
    margins = certificate_margins(shaped, perturbed, common.lyapunov_factor, common.gamma)
    assert margins[1] <= 0 < min(margins[0], margins[2])


def test_design_file_common_scheduling_writes_one_level_and_refuses_margin_goal(tmp_path, capsys):
    model = _random_plant(0)
    model.save(tmp_path / "model.json")
    (tmp_path / "design.toml").write_text(DESIGN + 'scheduling = "common"\n')
    out = tmp_path / "K.json"
    assert main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"),
                 "-o", str(out)]) == 0
    info = json.loads(out.read_text())["info"]
    assert info["scheduling"] == "common" and len(set(info["vertex_gammas"])) == 1
    assert info["certificate"]["ok"] and min(info["certificate"]["certificate"]) > 0
    # the written controller (u = −K e) is the common design's W1·K∞ at every breakpoint
    _, _, W1, _, common = _design(0)
    controller = load(out)
    for i in range(len(BREAKPOINTS)):
        written = control.ss(controller.Ak[i], -controller.Bk[i], controller.Ck[i], -controller.Dk[i],
                             model.Ts)
        expected = W1 * control.ss(*common.K_inf[i], model.Ts)
        z = np.exp(1j * np.array([0.01, 0.3, 3.0]))
        assert np.allclose(written(z, squeeze=False), expected(z, squeeze=False), rtol=1e-4, atol=1e-8)
    capsys.readouterr()
    (tmp_path / "goal.toml").write_text(DESIGN + 'scheduling = "common"\nmargin_goal = { at_least = 0.1 }\n')
    assert main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "goal.toml"),
                 "-o", str(tmp_path / "K2.json")]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "margin_goal" in error[0] and not (tmp_path / "K2.json").exists()


def test_common_scheduling_with_another_method_is_one_error_line(tmp_path, capsys):
    _random_plant(1).save(tmp_path / "model.json")
    design = DESIGN.replace('method = "loop-shaping"', 'method = "common"') + 'scheduling = "common"\n'
    (tmp_path / "design.toml").write_text(design)
    out = tmp_path / "K.json"
    assert main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"),
                 "-o", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "scheduling" in error[0] and not out.exists()
