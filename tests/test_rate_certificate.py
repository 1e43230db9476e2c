"""The robustness stage's moving-parameter line (lpvflow.pipeline.rate_certificate, report_robustness)."""

import math
from types import SimpleNamespace

import control
import numpy as np
import pytest

from lpvflow.pipeline.rate_certificate import rate_certificate, scheduling_signal
from lpvflow.pipeline.report_robustness import rate_statement
from lpvflow.pipeline.report_text import DisplayUnit
from lpvflow.pipeline.scheduling_values import SignalImages, SignalValues
from lpvflow.synth.polytope import BoxPolytope, PiecewisePolytope

ADIP = ["sin(arm_angle)", "1/(1 - 0.3785*cos(arm_angle)**2)", "cos(arm_angle)/(1 - 0.3785*cos(arm_angle)**2)"]


def test_the_scheduling_signal_is_the_one_output_every_expression_reads():
    assert scheduling_signal(ADIP, ["arm_angle", "pendulum_angle"]) == "arm_angle"
    assert scheduling_signal(["lower_level"], ["lower_level"]) == "lower_level"  # the output itself
    assert scheduling_signal([*ADIP, "pendulum_angle**2"], ["arm_angle", "pendulum_angle"]) is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_rate_line_converts_per_sample_to_display_units_per_second(seed):
    rng = np.random.default_rng(seed)
    Ts, peak = float(rng.choice([0.002, 0.005, 0.01])), float(rng.uniform(1e-3, 5e-3))
    rates = [peak / 16, peak / 4, peak, None]
    cert = {"signal": "arm_angle", "peak_per_sample": peak, "peak_scenario": "arm to -70 deg", "Ts": Ts,
            "rates": rates, "reason": "not certified at ν = … per sample: block of 16 states"}
    units = {"arm_angle": DisplayUnit.of("rad")}

    def speed(per_sample: float) -> str:
        return f"{math.degrees(per_sample) / Ts:.3g} °/s"

    tail = f"the fastest verify scenario (arm to -70 deg) peaks at {speed(peak)}"
    certified = {"largest": rates[1], "certified": [True, True, False]}
    line = rate_statement({"rate_certificate": cert | certified}, units)
    assert line == f"stability certified for arm_angle rates up to {speed(rates[1])}; {tail}"
    line = rate_statement({"rate_certificate": cert | {"largest": 0.0, "certified": [False]}}, units)
    assert line.startswith(f"stability not certified for arm_angle changing even at {speed(rates[0])} ")
    assert "block of 16 states" in line and line.endswith(tail)
    line = rate_statement({"rate_certificate": cert | {"largest": None, "certified": [True] * 4}}, units)
    assert line == f"stability certified for arm_angle changing at any rate; {tail}"
    assert rate_statement({"rate_certificate_note": "not assessed: why"}, units) == \
        "moving scheduling: not assessed: why"
    assert rate_statement({}, units) == ""


def scalar_design(gain: float, given=None, polytope=None, inserted=(), recorded=True):
    """A one-state plant x⁺ = a(y)x + u, y = x, scheduled by sin(y) on breakpoints, under u = −gain·y;
    ``[synth] breakpoints`` given as values of y (the design file's ``{ signal = "y", values = … }``)
    unless ``given``, the controller on their piecewise polytope unless ``polytope``; ``inserted``: values
    the synth stage inserted (its ``inserted_breakpoints``, unless not ``recorded``), which the controller's
    polytope then has too."""
    given_values = np.array([-1.2, -0.5, 0.0, 0.5, 1.2])
    source = SignalValues("y", tuple(given_values))
    images = SignalImages([[float(np.sin(b))] for b in given_values], source) if given is None else given
    ctx = SimpleNamespace(config={"experiment": {"scheduling": {"sin_y": "sin(y)"}},
                                  "synth": {"breakpoints": images}},
                          outputs={"synth": {"inserted_breakpoints": list(inserted) if recorded else []}})
    model = SimpleNamespace(p_names=["sin_y"], y_names=["y"], Ts=0.01,
                            frozen=lambda p: control.ss([[0.9 + 0.3 * p[0]]], [[1.0]], [[1.0]], [[0.0]],
                                                        0.01))
    breakpoints = np.sort(np.concatenate([given_values, inserted]))
    vertices = np.array([[1.0, np.sin(b)] for b in breakpoints])
    piecewise = PiecewisePolytope(np.array([[np.sin(-1.2), np.sin(1.2)]]), vertices,
                                  breakpoints=np.sin(breakpoints))
    controller = SimpleNamespace(polytope=piecewise if polytope is None else polytope)
    rows = [{"scenario": "a move", "largest_step": {"y": 0.02}}, {"scenario": "a faster move",
                                                                  "largest_step": {"y": 0.05}}]
    static = control.ss(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[-gain]], 0.01)
    out = rate_certificate(ctx, model, controller, rows, lambda p: static)
    return out, breakpoints


def test_a_loop_stable_at_every_frozen_point_of_a_scalar_plant_is_certified_at_any_rate():
    # 𝒜(y) = 0.9 + 0.3 sin(y) − 0.5 ∈ [0.15, 0.65]: V = x² decreases whatever y does
    out, breakpoints = scalar_design(0.5)
    cert = out["rate_certificate"]
    assert cert["signal"] == "y" and cert["peak_scenario"] == "a faster move"
    assert cert["peak_per_sample"] == 0.05
    assert cert["breakpoints"] == breakpoints.tolist()  # the design file's, not searched for
    assert cert["rates"][:3] == pytest.approx([0.05 / 16, 0.05 / 4, 0.05]) and cert["rates"][3] is None
    assert cert["certified"] == [True] * 4 and cert["largest"] is None


def test_an_unstable_frozen_loop_is_a_note_not_a_crash():
    # 0.9 + 0.3 sin(y) − 0.1 > 1 for y > 0.73
    out, _ = scalar_design(0.1)
    assert list(out) == ["rate_certificate_note"] and "is unstable" in out["rate_certificate_note"]


def test_breakpoints_the_synth_stage_inserted_are_the_storages_too():
    """A controller on the design file's breakpoints plus two the synth stage inserted
    (:mod:`lpvflow.pipeline.breakpoint_refinement`): the storage's breakpoints are all seven, in y; without
    the stage's record the controller's are not the file's, and the line is that note."""
    out, breakpoints = scalar_design(0.5, inserted=(-0.85, 0.25))
    assert breakpoints.tolist() == [-1.2, -0.85, -0.5, 0.0, 0.25, 0.5, 1.2]
    assert out["rate_certificate"]["breakpoints"] == breakpoints.tolist()
    assert out["rate_certificate"]["largest"] is None  # certified at any rate, as on the file's five
    out, _ = scalar_design(0.5, inserted=(-0.85, 0.25), recorded=False)
    assert "not those of [synth] breakpoints" in out["rate_certificate_note"]


def test_the_breakpoints_come_from_the_design_file_or_the_note_says_how_to_give_them():
    """The storage's breakpoints are [synth] breakpoints in the measured signal: given as scheduling rows
    (their y values unknown), as values of another signal, or not the controller's (random moves of
    one row), the line is a note naming what to give; a box over the one signal (no breakpoints, the
    tanks designs) is not assessed, as before."""
    rows = [[float(np.sin(b))] for b in (-1.2, -0.5, 0.0, 0.5, 1.2)]
    out, _ = scalar_design(0.5, given=rows)
    assert list(out) == ["rate_certificate_note"]
    assert 'give [synth] breakpoints as values of y ({ signal = "y", values = [...] })' in \
        out["rate_certificate_note"]
    out, _ = scalar_design(0.5, given=SignalImages(rows, SignalValues("z", (0.0,) * 5)))
    assert "as values of y" in out["rate_certificate_note"]
    rng = np.random.default_rng(3)
    for _ in range(3):
        moved = [row[:] for row in rows]
        moved[int(rng.integers(5))][0] += float(rng.uniform(1e-6, 1e-2))
        out, _ = scalar_design(0.5, given=SignalImages(moved, SignalValues("y", (-1.2, -0.5, 0.0, 0.5, 1.2))))
        assert "not those of [synth] breakpoints" in out["rate_certificate_note"]
    box = BoxPolytope(np.array([[-0.9, 0.9]]), np.array([[1.0, -0.9], [1.0, 0.9]]))
    assert box.vertex_breakpoints is not None  # hat-form λ, yet not assessed: the design gives no breakpoints
    out, _ = scalar_design(0.5, polytope=box)
    assert "needs a controller on breakpoints" in out["rate_certificate_note"]
