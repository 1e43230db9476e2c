"""``[synth] margin_goal`` of the loop-shaping design: the lead-zero family of W1 against an independent
zero-order-hold formula, the goal each breakpoint is held to, and the written controller's b(G_i, K_fb,i)
by the frequency-grid formula of tests/test_robustness.py against the goal — met wherever a lead ratio on
the ladder reaches it, lowered no further than the first such ratio, and one warning line naming every
breakpoint where none does."""

import json
import warnings

import control
import numpy as np
import pytest

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.errors import DataError, ModelError
from lpvflow.models import load
from lpvflow.pipeline.cli import main
from lpvflow.synth.loop_shaping import (
    LEAD_RATIO,
    central_ncf_controller,
    crossover_normalized,
    integrator_lead_weight,
)
from lpvflow.synth.loop_shaping_design import GAMMA_FACTOR
from lpvflow.synth.margin_goal import LADDER_STEPS, lead_weight, vertex_goals
from lpvflow.synth.polytope import PiecewisePolytope
from tests.design_files import tanks_head, tanks_synth
from tests.test_loop_shaping_method import BREAKPOINTS, CROSSOVER, DESIGN, _random_plant
from tests.test_robustness import ROOT, TANKS, grid_margin


def _zoh_response(Ts: float, crossover: float, integral_ratio: float, beta: float,
                  z: np.ndarray) -> np.ndarray:
    """The zero-order-hold sample of W1(s) = (s + ω_c/r_i)/s · (s + p/β)/(s + p) · 10ω_c/(s + 10ω_c),
    p = 2ω_c, at z: (1 − z⁻¹)·Z{W1(s)/s} from the partial fractions of W1(s)/s (a double pole at 0)."""
    p, r, a = 2.0 * crossover, 10.0 * crossover, crossover / integral_ratio

    def num(s: complex) -> complex:
        return r * (s + a) * (s + p / beta)

    # W1(s)/s = c2/s² + c1/s + d_p/(s + p) + d_r/(s + r)
    c2 = num(0.0) / (p * r)
    d_p = num(-p) / ((-p) ** 2 * (r - p))
    d_r = num(-r) / ((-r) ** 2 * (p - r))
    c1 = -(d_p + d_r)  # W1(s)/s → 0 faster than 1/s: the 1/s coefficients sum to zero
    step = (c2 * Ts * z / (z - 1) ** 2 + c1 * z / (z - 1) + d_p * z / (z - np.exp(-p * Ts))
            + d_r * z / (z - np.exp(-r * Ts)))
    return (1 - 1 / z) * step


def test_lead_weight_without_integral_factor_is_the_sampled_lead_and_rolloff():
    """integral = False (the integral action in W2, [synth] integral_outputs): random Ts, crossover, β; no
    pole at z = 1, D = 0, A and B the same for every β, and the response the exact ZOH sample of
    (s + p/β)/(s + p) · 10ω_c/(s + 10ω_c) (python-control's c2d of the continuous weight)."""
    rng = np.random.default_rng(37)
    s = control.tf("s")
    for _ in range(8):
        Ts = float(rng.choice([0.001, 0.005, 0.01, 0.05]))
        crossover = float(rng.uniform(0.02, 0.3)) * np.pi / Ts / 10
        nominal = lead_weight(Ts, crossover, 1, LEAD_RATIO, integral_ratio=10.0, integral=False)
        assert nominal.nstates == 2 and np.min(np.abs(nominal.poles() - 1.0)) > 1e-3
        z = np.exp(1j * crossover * Ts * np.logspace(-2, 1, 25))
        for beta in (LEAD_RATIO, float(rng.uniform(1.0, LEAD_RATIO)), 1.0):
            W = lead_weight(Ts, crossover, 1, beta, integral_ratio=10.0, integral=False)
            assert np.array_equal(W.A, nominal.A) and np.array_equal(W.B, nominal.B) and not W.D.any()
            p, r = 2.0 * crossover, 10.0 * crossover
            exact = control.sample_system(control.ss((s + p / beta) / (s + p) * r / (s + r)), Ts, "zoh")
            got = np.array([complex(W(zk)) for zk in z])
            want = np.array([complex(exact(zk)) for zk in z])
            assert np.max(np.abs(got - want) / np.abs(want)) < 1e-9


def test_lead_weight_moves_only_the_lead_zero_of_the_design_weight():
    """Random Ts, crossover, integral ratio, β: A and B are integrator_lead_weight's, β = α is that weight
    to the bit, and the frequency response is the ZOH of the continuous weight with its zero at p/β."""
    rng = np.random.default_rng(36)
    for _ in range(12):
        Ts = float(rng.choice([0.001, 0.005, 0.01, 0.05]))
        crossover = float(rng.uniform(0.02, 0.3)) * np.pi / Ts / 10
        ratio = float(rng.uniform(1.0, 20.0))
        nominal = integrator_lead_weight(Ts, crossover, 1, integral_ratio=ratio)
        assert np.array_equal(lead_weight(Ts, crossover, 1, LEAD_RATIO, integral_ratio=ratio).C, nominal.C)
        z = np.exp(1j * crossover * Ts * np.logspace(-2, 1, 25))
        for beta in (LEAD_RATIO, float(rng.uniform(1.0, LEAD_RATIO)), 1.0):
            W = lead_weight(Ts, crossover, 1, beta, integral_ratio=ratio)
            assert np.array_equal(W.A, nominal.A) and np.array_equal(W.B, nominal.B) and not W.D.any()
            got = np.array([complex(W(zk)) for zk in z])
            want = _zoh_response(Ts, crossover, ratio, beta, z)
            assert np.max(np.abs(got - want) / np.abs(want)) < 1e-7
    two = lead_weight(0.01, 4.0, 2, 2.0, integral_ratio=10.0)
    assert two.ninputs == two.noutputs == 2 and two.nstates == 6
    with pytest.raises(ModelError, match="lead_used"):
        lead_weight(0.01, 4.0, 1, 0.5, integral_ratio=10.0)


def test_each_breakpoint_is_held_to_the_largest_goal_of_the_points_it_takes_part_in():
    """Random validate points and ν-gaps on random breakpoints: vertex i gets max(1.5·ν, 0.05) over the
    points strictly inside its two intervals or on it, and 0.05 when there is none (counted here from the
    breakpoints directly, not from the polytope's coordinates)."""
    rng = np.random.default_rng(7)
    basis = Basis("affine", 1)
    goal = {"nugap_factor": 1.5, "at_least": 0.05}
    for _ in range(20):
        b = np.sort(rng.choice(np.linspace(-1, 1, 41), size=rng.integers(3, 7), replace=False))
        polytope = PiecewisePolytope(np.array([[b[0], b[-1]]]), np.column_stack([np.ones(len(b)), b]),
                                     breakpoints=b)
        points = list(rng.uniform(b[0], b[-1], size=rng.integers(1, 5)))
        points += list(rng.choice(b, size=1))  # a point on a breakpoint touches that breakpoint only
        nugap = rng.uniform(0.0, 0.1, size=len(points))
        goals = vertex_goals(goal, [[p] for p in points], nugap, polytope, basis)
        for i, bi in enumerate(b):
            lo, hi = b[max(i - 1, 0)], b[min(i + 1, len(b) - 1)]
            near = [max(1.5 * g, 0.05) for p, g in zip(points, nugap, strict=True)
                    if p == bi or lo < p < hi]
            assert goals[i] == pytest.approx(max(near, default=0.05))
    with pytest.raises(DataError, match="nugap_factor needs the validate stage's ν-gap"):
        vertex_goals(goal, None, None, polytope, basis)
    only_floor = vertex_goals({"at_least": 0.2}, None, None, polytope, basis)
    assert np.all(only_floor == 0.2)


def _ladder_margins(G) -> list[float]:
    """b(G, W1_β·K∞_β) by the grid formula for every β of the ladder (W1 normalized at the crossover, K∞
    the Riccati central controller at 1.01·γ_opt — an independent stand-in for the design's central LMI
    controller at 1.01·γ_LMI, whose b it matches within 1 %), from β = α down to 1."""
    bs = []
    for k in range(LADDER_STEPS + 1):
        beta = LEAD_RATIO ** (1.0 - k / LADDER_STEPS)
        W1 = crossover_normalized(G, lead_weight(G.dt, CROSSOVER, 1, beta, integral_ratio=10.0), CROSSOVER)
        K, _ = central_ncf_controller(G * W1, GAMMA_FACTOR)
        feedback = W1 * K
        bs.append(grid_margin(tuple(np.asarray(M) for M in (G.A, G.B, G.C, G.D)),
                              tuple(np.asarray(M) for M in (feedback.A, feedback.B, feedback.C, feedback.D))))
    return bs


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow),  # 2: 21 s, 5: 19 s
                                  pytest.param(5, marks=pytest.mark.slow)])
def test_synth_meets_the_goal_where_a_lead_reaches_it_and_names_the_breakpoints_where_none_does(
        tmp_path, capsys, seed):
    """Random plant families (tests/test_loop_shaping_method.py), goal = at_least chosen between the
    nominal design's b and the best lead's at the breakpoint with most room (so the nominal design misses
    it): at every breakpoint the written 1-DOF controller's b(G_i, K_fb,i) (grid formula) is ≥ the goal
    where some β on the ladder reaches it — with the first such β, the nominal W1 where it already does —
    and the one warning line names exactly the breakpoints where no β does."""
    model = _random_plant(seed)
    model.save(tmp_path / "model.json")
    plants = [model.frozen(np.array([p])) for p in BREAKPOINTS]
    ladders = [_ladder_margins(G) for G in plants]
    room = [max(bs) - bs[0] for bs in ladders]
    widest = ladders[int(np.argmax(room))]
    goal = 0.5 * (widest[0] + max(widest))
    (tmp_path / "design.toml").write_text(DESIGN + f"margin_goal = {{ at_least = {goal} }}\n")
    out = tmp_path / "K.json"
    main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"), "-o", str(out)])
    captured = capsys.readouterr()
    controller = load(out)
    assert widest[0] < goal  # the design without the goal misses it
    unattainable = []
    for i, (G, bs) in enumerate(zip(plants, ladders, strict=True)):
        K_fb = (controller.Ak[i], -controller.Bk[i], controller.Ck[i], -controller.Dk[i])  # reads r − y
        b = grid_margin(tuple(np.asarray(M) for M in (G.A, G.B, G.C, G.D)), K_fb)
        reaching = [k for k, bk in enumerate(bs) if bk >= goal]
        if reaching:
            assert b >= goal * (1 - 1e-3)
            assert b == pytest.approx(bs[reaching[0]], rel=1e-2)  # lowered no further than needed
        else:
            assert b == pytest.approx(max(bs), rel=1e-2)
            unattainable.append(f"p_1 = {BREAKPOINTS[i]:.4g}: b ")
    lines = [line for line in captured.err.splitlines() if "margin_goal" in line]
    if unattainable:
        assert len(lines) == 1
        assert lines[0].startswith("lpvflow synth: warning: [synth] margin_goal is not met")
        assert all(name in lines[0] for name in unattainable)
        assert lines[0].count(": b ") == len(unattainable)
    else:
        assert not lines
    info = controller.info["certificate"]["margin_goal"]
    assert info["goals"] == pytest.approx([goal] * len(BREAKPOINTS))


def test_nugap_factor_without_a_validate_stage_is_one_line_exit_2(tmp_path, capsys):
    """``lpvflow synth`` has no ν-gap: a goal with nugap_factor is refused in one line, nothing written; so
    are a goal on another method and malformed goals."""
    _random_plant(1).save(tmp_path / "model.json")
    (tmp_path / "design.toml").write_text(DESIGN + "margin_goal = { nugap_factor = 1.5, at_least = 0.05 }\n")
    out = tmp_path / "K.json"
    status = main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"),
                   "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and not out.exists() and len(err) == 1
    assert "margin_goal.nugap_factor needs the validate stage's ν-gap" in err[0]
    (tmp_path / "design.toml").write_text(DESIGN.replace('"loop-shaping"', '"common"')
                                          + "margin_goal = { at_least = 0.05 }\n")
    status = main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"),
                   "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and not out.exists() and len(err) == 1
    assert "margin_goal shapes the loop-shaping design only" in err[0]
    for bad in ("{ nugap = 1.5 }", "{ at_least = 1.5 }", "{ nugap_factor = -1 }", "{ }"):
        (tmp_path / "design.toml").write_text(DESIGN + f"margin_goal = {bad}\n")
        status = main(["synth", str(tmp_path / "model.json"), "--config", str(tmp_path / "design.toml"),
                       "-o", str(out)])
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 2 and len(err) == 1 and "margin_goal" in err[0] and not out.exists()


#: The tanks design of tests/test_robustness.py shaped by loop shaping on three breakpoints.
TANKS_SHAPED = ('method = "loop-shaping"', "breakpoints = [0.05, 0.115, 0.18]", "crossover = 0.05",
                "scaling = { pump_voltage = 2.0, lower_level = 0.05 }")
GOAL = "margin_goal = { nugap_factor = 5.5, at_least = 0.05 }"


def _state_space(system) -> tuple:
    return system.A, system.B, system.C, system.D


def test_design_holds_each_breakpoint_to_the_validated_nugap_of_its_points(tmp_path, capsys):
    """``lpvflow design`` on the tanks with margin_goal = { nugap_factor = 5.5, at_least = 0.05 } against the
    validate stage's ν-gap (0.59 at the empty-tank point, which no controller can beat 5.5-fold; 0.04 and 0.12
    at the others): at each validate point whose breakpoints meet their goal, b(Ĝ, K_fb) by the grid formula
    is ≥ max(5.5·ν-gap, 0.05) — at the full-tank point the design without the goal is below it — and one
    warning line names the breakpoint of the empty-tank point."""
    u_scale, y_scale = 2.0, 0.05
    head = tanks_head(ROOT / "fmu_plants" / "build" / "tanks.fmu", tmp_path / "out") + TANKS.format(
        u_scale=u_scale, y_scale=y_scale)
    margins = {}
    for name, keys in (("plain", TANKS_SHAPED), ("goal", (*TANKS_SHAPED, GOAL))):
        path = tmp_path / f"{name}.toml"
        path.write_text(head.replace('name = "tanks"', f'name = "{name}"') + tanks_synth(*keys))
        assert main(["design", str(path)]) == 0
        err = capsys.readouterr().err
        folder = tmp_path / "out" / name
        summary = json.loads((folder / "summary.json").read_text())
        validate = summary["stages"]["validate"]["outputs"]
        model, controller = load(folder / "model.json"), load(folder / "controller.json")
        margins[name] = []
        for theta in validate["theta"]:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SchedulingRangeWarning)
                AG, BG, CG, DG = (np.asarray(M) for M in _state_space(model.frozen(np.array(theta))))
            AK, BK, CK, DK = (np.asarray(M) for M in _state_space(controller.frozen(np.array(theta))))
            G = (AG, BG * u_scale, CG / y_scale, DG * u_scale / y_scale)
            margins[name].append(grid_margin(G, (AK, -BK * y_scale, CK / u_scale, -DK * y_scale / u_scale)))
    goals = [max(5.5 * gap, 0.05) for gap in validate["nugap"]]
    levels = [theta[0] for theta in validate["theta"]]
    assert levels[0] < 0.05 and goals[0] > 1.0 and 0.05 < levels[1] < 0.115 < levels[2] < 0.18
    assert margins["plain"][2] < goals[2] <= margins["goal"][2]  # the goal lowered the lead
    assert margins["goal"][1] >= goals[1]
    lines = [line for line in err.splitlines() if "margin_goal" in line]
    assert len(lines) == 1 and "p_1 = 0.05: b " in lines[0] and "p_1 = 0.115" not in lines[0]
    assert "p_1 = 0.18" not in lines[0]


def test_identification_rounds_design_without_the_goal_and_the_final_pass_with_it(tmp_path):
    """``[experiment] iterate``: a round's controller only runs the next experiment, so its synth table has
    no margin_goal; every other key, and the final pass's table, is the file's."""
    from lpvflow.pipeline.config import load_config
    from lpvflow.pipeline.design import _without_margin_goal

    path = tmp_path / "design.toml"
    path.write_text(tanks_head(ROOT / "fmu_plants" / "build" / "tanks.fmu", tmp_path / "out")
                    + TANKS.format(u_scale=2.0, y_scale=0.05) + tanks_synth(*TANKS_SHAPED, GOAL))
    config = load_config(path)
    round_config = _without_margin_goal(config)
    assert config["synth"]["margin_goal"] == {"nugap_factor": 5.5, "at_least": 0.05}
    assert round_config["synth"]["margin_goal"] is None
    assert {k: v for k, v in round_config["synth"].items() if k != "margin_goal"} == {
        k: v for k, v in config["synth"].items() if k != "margin_goal"}
    assert all(round_config[t] is config[t] for t in config if t != "synth")
