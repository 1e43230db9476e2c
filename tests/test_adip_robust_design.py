"""The bundled default ADIP design end to end (what `make design` runs): the scheduled loop-shaping
controller's b(Ĝ, K_fb) against the ν-gap at the nine gate points, by a frequency-grid formula independent of
lpvflow's margin code, and the arm steps it holds on the plant FMU; the LTI baseline is the same loop-shaping
design at 0° and loses the larger ones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lpvflow.models import load
from lpvflow.pipeline.config import repository_root
from lpvflow.pipeline.scenarios import run_passed
from tests.test_robustness import assert_shipped_b_above_nugap, run_bundled_design

NAME = "adip"

pytestmark = pytest.mark.slow  # the whole design: about a minute on two cores


@pytest.fixture(scope="module")
def robust_run(tmp_path_factory):
    return run_bundled_design(NAME, tmp_path_factory.mktemp(NAME))


def test_b_of_the_shipped_feedback_exceeds_one_and_a_half_nugaps_at_every_gate_point(robust_run):
    """b(Ĝ(θ), K_fb(θ)) from the grid formula (frozen model and the 2-DOF controller's measurement
    columns, both in [validate] scaling 3 V, 0.3 rad, 0.025 rad) ≥ max(1.5·ν-gap, 0.05) at the nine
    points, equal to the stage's b within 1 %. Measured (seed 1, after the identification-for-control
    round, K∞ from hinfsyn's LMIs): b 0.080–0.128, ν-gap 0.032–0.044."""
    summary, folder = robust_run
    assert_shipped_b_above_nugap(summary, folder, np.diag([3.0]), np.diag([0.3, 0.025]), 9)
    assert summary["stages"]["synth"]["outputs"]["certificate_ok"] is True


def test_the_design_holds_its_steps_and_the_lti_baseline_loses_the_large_ones(robust_run):
    """The scheduled controller holds all eight steps; the same loop-shaping design frozen at 0° (the LTI
    baseline: same weights, reference path and tuning) loses the pendulum at ±70° and ±75°, and the
    largest step it keeps bounded lies below 70°."""
    summary, _ = robust_run
    assert summary["failed"] is None and summary["verdict"]["pass"] is True
    scenarios = summary["stages"]["verify"]["outputs"]["scenarios"]
    assert len(scenarios) == 8  # ±30°, ±60°, ±70°, ±75°
    for s in scenarios:
        assert s["controller"]["stable"] and not s["controller"].get("requirements_failed"), s["name"]
        if any(angle in s["name"] for angle in ("70", "75")):
            assert not s["baseline"]["stable"], s["name"]
    held = summary["stages"]["verify"]["outputs"]["largest_held_step"]
    assert held["lpv"] == pytest.approx(np.deg2rad(75.0), rel=1e-3) and held["baseline"] < np.deg2rad(70.0)


def test_the_model_in_the_loop_is_reported_per_scenario_and_matches_a_numpy_loop(robust_run):
    """The robustness stage's model-in-the-loop against plant-in-the-loop rows: one per scenario, every run
    to the end, within 1° of pendulum on every one (arm: the next test; the model identified from the sweep
    alone missed the arm by up to 10.4°). For the −75° step the stage's largest differences equal those of the
    identified model in the loop written out here (p = (sin φ1, 1/(1 − κ cos² φ1), cos φ1/(1 − κ cos² φ1))
    of the model's arm, κ = 0.3785; model input = the clipped command minus the final experiment
    controller's trim −4.21439310 sin φ1 V ([synth] trim: the first round's controller ran the final
    experiment) at the model's arm; the 2-DOF controller reading [r; y]) against the verify stage's
    co-simulation, to 1e-9 rad. Measured (seed 1, K∞ from hinfsyn's LMIs): arm 0.51° (+30°) to 2.02° (−75°),
    pendulum 0.04–0.16°."""
    from lpvflow.pipeline.config import load_config
    from lpvflow.pipeline.verify import simulate_loop

    summary, folder = robust_run
    rows = summary["stages"]["robustness"]["outputs"]["trajectory"]
    scenarios = summary["stages"]["verify"]["outputs"]["scenarios"]
    assert [row["scenario"] for row in rows] == [s["name"] for s in scenarios]
    assert all(row["plant_failure"] is None and row["model_failure"] is None for row in rows)
    assert all(row["largest_difference"]["pendulum_angle"] < np.deg2rad(1.0) for row in rows)
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(repository_root())
        config = load_config(folder.parent / "design.toml")
    loop = config["verify"]["loop"]
    [scenario] = [s for s in config["verify"]["scenario"] if s.name == "arm to -75 deg"]
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    on_plant = simulate_loop(controller, config["design"]["plant"], scenario, loop)
    assert np.max(np.abs(model.C[1:]), initial=0.0) == 0.0 and np.max(np.abs(model.D)) == 0.0
    x, y_model = np.zeros(model.nx), np.zeros_like(on_plant.outputs)
    controller.reset()
    for k, r in enumerate(on_plant.reference):
        y_model[k] = model.C[0] @ x  # C does not depend on p (observable form)
        arm = y_model[k, 0]
        det = 1.0 / (1.0 - 0.3785 * np.cos(arm) ** 2)
        p = np.array([np.sin(arm), det, np.cos(arm) * det])
        u = np.clip(controller.step(np.concatenate([r, y_model[k]]), p), -10.0, 10.0)
        A, B, _, _ = model.matrices(p)
        x = A @ x + B @ (u + 4.21439310 * np.sin(arm))
    difference = np.max(np.abs(on_plant.outputs - y_model), axis=0)
    [row] = [row for row in rows if row["scenario"] == scenario.name]
    assert [row["largest_difference"][name] for name in loop.measured] == pytest.approx(difference, abs=1e-9)


def test_the_loop_survives_two_samples_of_input_delay_and_a_10_ms_delay_on_the_fmu(robust_run):
    """Delay margin ≥ 2 samples at the plant input at every gate point, checked by poles, not by lpvflow's
    margin code: the frozen model with d = 0, 1, 2 samples of delay in front of it, closed by the shipped
    feedback part (u = K_fb y, python-control's positive feedback) has every pole inside the unit circle,
    and the stage's delay margin is ≥ 2 there; the loop closed with a sign error is unstable. On the
    plant FMU with ``effect_input_delay = 0.01`` (one sample at 10 ms) the eight steps still pass
    (measured: 5.8–6.6 s settling, benchmarks/bench_adip_robust.py)."""
    import control

    from lpvflow.pipeline.config import load_config
    from lpvflow.pipeline.robustness import measurement_feedback
    from lpvflow.pipeline.verify import verify

    summary, folder = robust_run
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    rows = summary["stages"]["robustness"]["outputs"]["rows"]
    for row in rows:
        theta = np.array(row["theta"])
        G, K_fb = model.frozen(theta), measurement_feedback(controller, theta)
        assert row["delay_margin_samples"] >= 2, row
        for d in range(3):
            delay = control.ss(np.eye(d, k=-1), np.eye(d, 1), np.eye(1, d, d - 1), 0.0, G.dt) if d \
                else control.ss([], [], [], 1.0, G.dt)
            loop = control.feedback(G * delay, K_fb, sign=1)
            assert np.max(np.abs(loop.poles())) < 1.0, (theta, d)
        assert np.max(np.abs(control.feedback(G, K_fb, sign=-1).poles())) > 1.0
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(repository_root())
        config = load_config(folder.parent / "design.toml")
        delayed = [dataclasses.replace(s, plant_parameters={**s.plant_parameters, "effect_input_delay": 0.01})
                   for s in config["verify"]["scenario"]]
        result = verify(controller, config["design"]["plant"], delayed, config["verify"]["loop"])
    assert len(result["scenarios"]) == 8
    for s in result["scenarios"]:
        assert run_passed(s["controller"]), (s["name"], s["controller"]["reason"],
                                             s["controller"].get("requirements_failed"))


def test_the_model_in_the_loop_is_within_two_degrees_of_arm_on_every_step(robust_run):
    """The trajectory goal: the model in the loop of the shipped controller follows the plant within 2° of
    arm on every step: 1.84° at −75° (numpy 2.4.6, scipy 1.17.1, cvxpy 1.9.3, Clarabel 0.11.1; 2.02° on the
    stack of 2026-11-27), a thin margin; ``[identify] refine = "closed-loop-oe"`` (off in the bundled
    design, benchmarks/README.md) gave 1.35°."""
    rows = robust_run[0]["stages"]["robustness"]["outputs"]["trajectory"]
    assert all(row["largest_difference"]["arm_angle"] < np.deg2rad(2.0) for row in rows)


class _EquationPlant:
    """The ADIP of fmu_plants/reference_models.py (README "Equations") with the voltage held over each
    sample, RK4 in 1 ms steps (the FMU's solver_max_step); ``centrifugal`` = False drops the term
    c sin(φ1 − φ2) ω1² from the pendulum's equation."""

    model_name = "adip equations"
    input_names, output_names = ["voltage"], ["arm_angle", "pendulum_angle"]

    def __init__(self, centrifugal: bool) -> None:
        from tests.adip_cases import rm

        self.rm, self.p, self.x = rm, dict(rm.default_parameters("adip")), np.zeros(4)
        self.centrifugal = centrifugal

    def start_value(self, name):
        return 0.0

    def parameter_values(self):
        return {}

    def outputs(self):
        return self.x[:2].copy()

    def derivatives(self, x, u):
        dx = self.rm.adip_derivatives(x, u, self.p)
        if not self.centrifugal:  # r2 loses c sinΔ ω1²: ω̇ = M⁻¹ r changes by M⁻¹ (0, −c sinΔ ω1²)
            a, b, c, _, _ = self.rm.adip_coefficients(self.p)
            delta = x[0] - x[1]
            m12, r2 = c * np.cos(delta), c * np.sin(delta) * x[2] ** 2
            det = a * b - m12**2
            dx = dx - np.array([0.0, 0.0, -m12 * r2 / det, a * r2 / det])
        return dx

    def step(self, u, t, Ts):
        h, u = Ts / 5, np.asarray(u, dtype=float)
        for _ in range(5):
            k1 = self.derivatives(self.x, u)
            k2 = self.derivatives(self.x + h / 2 * k1, u)
            k3 = self.derivatives(self.x + h / 2 * k2, u)
            k4 = self.derivatives(self.x + h * k3, u)
            self.x = self.x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def close(self):
        pass


def test_what_the_sweep_misses_is_the_centrifugal_term_of_the_moving_arm(robust_run):
    """Why the model needs the round of arm steps: in the loop of the shipped controller the plant's
    equations reproduce the FMU's ±75° steps to 1e-6 rad, but without the centrifugal torque
    c sin(φ1 − φ2) φ̇1² on the pendulum — a term of the moving arm that no frozen linearization, and so no
    model fitted to slow sweeps, contains — the held arm lags the FMU's by more than 2° (measured 5.2°)."""
    from lpvflow.pipeline.config import load_config
    from lpvflow.pipeline.verify import simulate_loop, simulate_loop_on

    _, folder = robust_run
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(repository_root())
        config = load_config(folder.parent / "design.toml")
    loop, controller = config["verify"]["loop"], load(folder / "controller.json")
    for scenario in (s for s in config["verify"]["scenario"] if "75" in s.name):
        fmu = simulate_loop(controller, config["design"]["plant"], scenario, loop).outputs
        exact, without = (simulate_loop_on(controller, _EquationPlant(term), scenario, loop).outputs
                          for term in (True, False))
        assert np.max(np.abs(fmu - exact)) < 1e-6, scenario.name
        assert np.max(np.abs(fmu - without)[:, 0]) > np.deg2rad(2.0), scenario.name
