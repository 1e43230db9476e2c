"""The observer-based gain-scheduled design (lpvflow.synth.observer) on an ADIP family that is exactly affine
in its scheduling signal: the zero-order-hold discretizations of the exact linearizations at 0° and 60° with
the gravity trim's feedback closed (the plant as the bundled design's model sees it: the arm integrates),
interpolated (p = 0 … 1), with the bundled weights."""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.errors import DataError, ModelError
from lpvflow.models import LPVSS, load
from lpvflow.pipeline.cli import main
from lpvflow.pipeline.config import bundled_config, check_table
from lpvflow.synth.certify import frozen_hinf_norms
from lpvflow.synth.controller import AntiWindup, LPVController, mix
from lpvflow.synth.observer import ObserverSettings, frozen_check, observer_design
from lpvflow.synth.plant import generalized_plant, weight_systems
from lpvflow.synth.polytope import hat_coordinates
from lpvflow.synth.riccati import riccati_gamma
from tests.adip_cases import TS, bundled_weights, rm

BREAKPOINTS = [0.0, 0.5, 1.0]
TRIM_GAIN = 4.21439310  # V per unit of sin(arm angle): the bundled [synth] trim
SETTINGS = ObserverSettings(input=1.0, state=1e-6, disturbance=1.0, noise=1e-3, filter_bandwidth=2.2)


def adip_family(trim_gain: float = TRIM_GAIN) -> LPVSS:
    """A(p) = A_0 + p (A_60 − A_0), likewise B; outputs the two angles (C = [I 0], D = 0). The trim
    u = −trim_gain·sin φ1 + u_model linearizes to u = −trim_gain·cos φ1·δφ1 + u_model."""
    ends = []
    for degrees in (0.0, 60.0):
        a, b = rm.adip_linearization(np.deg2rad(degrees), rm.default_parameters("adip"))
        a = a + b @ np.array([[-trim_gain * np.cos(np.deg2rad(degrees)), 0.0, 0.0, 0.0]])
        ends.append(control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), TS, method="zoh"))
    A0, A1 = (np.asarray(G.A) for G in ends)
    B0, B1 = (np.asarray(G.B) for G in ends)
    C = np.asarray(ends[0].C)
    return LPVSS(np.array([A0, A1 - A0]), np.array([B0, B1 - B0]), np.array([C, 0 * C]),
                 np.zeros((2, 2, 1)), Basis("affine", 1, p_min=(0.0,), p_max=(1.0,)), TS)


@pytest.fixture(scope="module")
def design():
    model = adip_family()
    plant = generalized_plant(model, bundled_weights(), [[0.0, 1.0]], "2dof", BREAKPOINTS)
    return model, plant, observer_design(plant, model, SETTINGS)


def frozen_loop(model: LPVSS, K: tuple[np.ndarray, ...], p: float) -> control.StateSpace:
    """The frozen closed loop built by python-control alone: plant G(p) after W_B with a load d added to
    its input, controller K from [r; y] to u; inputs [r (2), d], outputs y (2)."""
    WB = weight_systems(bundled_weights(), 2, 1, TS)["B"]
    G = control.ss(model.frozen([p]), inputs=["up"], outputs=["y[0]", "y[1]"], name="G")
    W = control.ss(WB, inputs=["u"], outputs=["ub"], name="WB")
    load = control.summing_junction(inputs=["ub", "d"], output="up", name="load")
    C = control.ss(*K, TS, inputs=["r[0]", "r[1]", "y[0]", "y[1]"], outputs=["u"], name="K")
    return control.interconnect([G, W, load, C], inplist=["r[0]", "r[1]", "d"], outlist=["y[0]", "y[1]"],
                                dt=TS)


def test_the_state_feedback_is_the_lq_regulator_of_the_weighted_plant(design):
    """Recomputed by scipy's DARE solver (python-control's dlqr, used by the design, calls SLICOT)."""
    _, plant, result = design
    for v, K in zip(plant.vertices, result.K_vertices, strict=True):
        Q, R, N = v.C1.T @ v.C1, v.D12.T @ v.D12, v.C1.T @ v.D12
        X = scipy.linalg.solve_discrete_are(v.A, v.B2, Q, R, s=N)
        F = -np.linalg.solve(v.B2.T @ X @ v.B2 + R, v.B2.T @ X @ v.A + N.T)
        n = v.A.shape[0]
        np.testing.assert_allclose(K[2][:, :n], F, rtol=1e-6, atol=1e-9 * np.abs(F).max())


def test_at_every_breakpoint_the_arm_tracks_without_offset_and_a_load_leaves_none(design):
    """DC gains of the frozen loop (python-control interconnect and dcgain): arm reference → arm 1,
    → pendulum 0; a constant load at the plant input → both angles 0 (feed-forward, disturbance observer
    and integral action on the measured error); every loop stable."""
    model, _, result = design
    for p, K in zip(BREAKPOINTS, result.K_vertices, strict=True):
        loop = frozen_loop(model, K, p)
        assert np.abs(loop.poles()).max() < 1.0
        dc = np.asarray(loop.dcgain())
        np.testing.assert_allclose(dc[:, 0], [1.0, 0.0], atol=1e-6)
        np.testing.assert_allclose(dc[:, 2], [0.0, 0.0], atol=1e-6)


def test_its_gamma_is_python_controls_frozen_norm_and_no_better_than_the_riccati_optimum():
    """On the family without the trim (the exact linearizations; with the trim the arm integrates exactly, a
    mode no exogenous input reaches, and SB10DD's filter Riccati has no solution): the reported γ equals
    the largest ‖T_zw‖∞ of the frozen loops rebuilt from model.frozen(p) on the 21-point grid
    (``certify.frozen_hinf_norms``: control.interconnect, lft, norm), and at every breakpoint that norm is
    at least SLICOT SB10DD's optimum for the frozen plant (no controller does better). Measured: γ 4.59
    against optima 1.55–1.57 — the LQG design is 2.9× the frozen H∞ optimum of its own weights."""
    model = adip_family(trim_gain=0.0)
    plant = generalized_plant(model, bundled_weights(), [[0.0, 1.0]], "2dof", BREAKPOINTS)
    result = observer_design(plant, model, SETTINGS)
    grid = np.linspace(0.0, 1.0, 21).reshape(-1, 1)
    norms = frozen_hinf_norms(lambda p: mix(result.K_vertices, hat_coordinates(BREAKPOINTS, p[0])), model,
                              plant.weights, grid, "2dof")
    assert result.check.hinf_max == pytest.approx(norms.max(), rel=1e-6)
    for v, norm in zip(plant.vertices, norms[::10], strict=True):
        optimum = riccati_gamma(v, TS)
        assert optimum * (1 - 1e-3) <= norm <= 3.5 * optimum


def test_the_frozen_check_holds_and_refuses_a_controller_with_a_flipped_output(design):
    _, plant, result = design
    assert result.check.ok and result.check.spectral_radius < 1.0
    assert result.check.points == 2 * 10 + 1
    bad = list(result.K_vertices)
    Ak, Bk, Ck, Dk = bad[1]
    bad[1] = (Ak, Bk, -Ck, -Dk)  # the middle controller pushes the wrong way
    assert not frozen_check(plant, bad).ok


def test_with_anti_windup_the_estimate_stays_exact_through_saturation(design):
    """A 20° arm step through ±0.15 V at p = 0: with the design's anti-windup gains the model estimate x̂_G
    is driven by the applied voltage and equals the plant state at every sample (no noise, same start);
    without them it leaves it while the actuator saturates."""
    model, _, result = design
    A, B, C, _ = (np.asarray(M) for M in (lambda G: (G.A, G.B, G.C, G.D))(model.frozen([0.0])))
    errors = {}
    for name, aw in (("plain", None), ("antiwindup", AntiWindup(result.antiwindup_gains, [-0.15], [0.15],
                                                                  [0.0]))):
        K = LPVController.from_dict(result.controller.to_dict())
        K.antiwindup = aw
        x, worst, saturated = np.zeros(4), 0.0, 0
        for _ in range(600):
            u = K.step(K.input_of([np.deg2rad(20.0), 0.0], C @ x), np.zeros(1))
            u_a = np.clip(u, -0.15, 0.15)
            saturated += int(abs(u[0]) > 0.15)
            x = A @ x + B @ u_a
            worst = max(worst, np.abs(K.x[:4] - x).max())
        errors[name] = worst
        assert saturated > 20
    assert errors["antiwindup"] < 1e-6 * np.deg2rad(20.0)  # round-off over 600 samples
    assert errors["plain"] > 1e-3


def test_settings_and_config_errors_name_the_key():
    model = adip_family()
    with pytest.raises(ModelError, match='structure = "2dof"'):
        plant = generalized_plant(model, bundled_weights(), [[0.0, 1.0]], "1dof", BREAKPOINTS)
        observer_design(plant, model, SETTINGS)
    with pytest.raises(ModelError, match="breakpoints"):
        plant = generalized_plant(model, bundled_weights(), [[0.0, 1.0]], "2dof")
        observer_design(plant, model, SETTINGS)
    with pytest.raises(ModelError, match=r"observer.noise must be positive"):
        ObserverSettings(noise=0.0)
    with pytest.raises(ModelError, match=r"reference_filter.bandwidth must be positive"):
        ObserverSettings(filter_bandwidth=-1.0)
    with pytest.raises(DataError, match=r"\[synth\] observer .*some of the keys input, state"):
        check_table("synth", {"weights": bundled_weights(), "observer": {"gain": 1.0}}, "design.toml")
    with pytest.raises(DataError, match=r"\[synth\] reference_filter .*bandwidth = 2.2"):
        check_table("synth", {"weights": bundled_weights(), "reference_filter": {"damping": 1.0}},
                    "design.toml")


def test_lpvflow_synth_designs_it_from_a_design_file(tmp_path, capsys):
    """`lpvflow synth --config` with method = "observer": names the method, reports the frozen check, and
    writes the controller of observer_design with W_B in series (same numbers as the library call)."""
    model = adip_family()
    model.save(tmp_path / "model.json")
    text = bundled_config("adip").read_text()
    weights = [line for line in text.splitlines() if line.startswith("weights.")]
    (tmp_path / "synth.toml").write_text("\n".join([
        "[synth]", 'method = "observer"', 'structure = "2dof"', "box = [[0.0, 1.0]]",
        "breakpoints = [0.0, 0.5, 1.0]", "reference_filter = { bandwidth = 2.2 }", *weights]) + "\n")
    status = main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "synth.toml"),
                   "-o", str(tmp_path / "K.json")])
    out, err = capsys.readouterr()
    assert status == 0 and "inaccurate" not in err  # the observer design solves no SDP
    assert out.startswith("observer-based: frozen LQG designs at the breakpoints, interpolated, polytope "
                          "piecewise with 3 vertices, 2dof")
    assert "largest frozen closed-loop norm" in out and "largest spectral radius" in out
    K = load(tmp_path / "K.json")
    expected = observer_design(generalized_plant(model, bundled_weights(), [[0.0, 1.0]], "2dof", BREAKPOINTS),
                               model, SETTINGS).controller
    np.testing.assert_allclose(K.Ck, expected.Ck, rtol=1e-9, atol=1e-12)
    assert K.info["method"] == "observer" and K.info["certificate"]["ok"] is True


def test_lpvflow_synth_says_when_the_controller_rests_on_an_inaccurate_solve(tmp_path, capsys, monkeypatch):
    """The line comes from the status the design records, once, only when that status is inaccurate."""
    from lpvflow.pipeline import controller_design

    model = adip_family()
    model.save(tmp_path / "model.json")
    text = bundled_config("adip").read_text()
    weights = [line for line in text.splitlines() if line.startswith("weights.")]
    (tmp_path / "synth.toml").write_text("\n".join([
        "[synth]", 'method = "observer"', 'structure = "2dof"', "box = [[0.0, 1.0]]",
        "breakpoints = [0.0, 0.5, 1.0]", *weights]) + "\n")
    real = controller_design.synthesize_design

    def inaccurate(*args, **kwargs):
        result = real(*args, **kwargs)
        result.controller.info["status"] = "optimal_inaccurate"
        return result

    monkeypatch.setattr(controller_design, "synthesize_design", inaccurate)
    assert main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "synth.toml"),
                 "-o", str(tmp_path / "K.json")]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("lpvflow synth: warning: the SDP solver returned")
