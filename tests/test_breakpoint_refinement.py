"""Breakpoints inserted where a loop-shaping design's frozen check fails between two
(lpvflow.pipeline.breakpoint_refinement): on a random two-state family designed on its box's ends only,
the check fails, the value halfway between the failing segment's breakpoints is inserted, and the design
that passes is the one given those breakpoints directly; a design that passes inserts nothing; the
number inserted is bounded."""

import tomllib

import numpy as np
import pytest

from lpvflow.models import LPVSS
from lpvflow.pipeline.breakpoint_refinement import (
    MAX_INSERTED,
    design_breakpoints,
    failing_segment,
    inserted_lines,
    refined_design,
)
from lpvflow.pipeline.config import check_table
from lpvflow.pipeline.scheduling_values import SignalImages, SignalValues, signal_values
from lpvflow.synth.design import synthesize_design
from tests.synth_cases import two_state_plant

SYNTH = tomllib.loads("""
method = "loop-shaping"
crossover = 4.0
box = [[-1.0, 1.0]]
breakpoints = [-1.0, 1.0]
weights.S = { num = [0.5], den = [1] }
weights.K = { num = [0.1], den = [1] }
weights.B = { num = [0, 0.5], den = [1, -0.5] }
""")


def _family(seed: int) -> LPVSS:
    """two_state_plant with A(p) = A0 + p·A1 and B's dependence drawn at random."""
    model = two_state_plant()
    rng = np.random.default_rng(seed)
    A, B = model.A.copy(), model.B.copy()
    A[0] = np.array([[rng.uniform(0.6, 0.95), rng.uniform(-0.2, 0.2)], [0.0, rng.uniform(0.5, 0.9)]])
    A[1] = np.array([[rng.uniform(-0.1, 0.1), rng.uniform(-0.3, 0.3)],
                     [rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.1)]])
    B[1, 1, 0] = rng.uniform(-0.9, 0.9)
    return LPVSS(A, B, model.C, model.D, model.basis, model.Ts)


def _settings(values: tuple[float, ...]) -> dict:
    """The [synth] table with breakpoints given as values of the scheduling column p0 itself."""
    settings = dict(check_table("synth", SYNTH, "test"))
    settings["breakpoints"] = SignalImages([[v] for v in values], SignalValues("p0", values))
    return settings


def test_the_midpoint_of_the_failing_segment_is_inserted_and_the_design_is_the_one_given_it():
    model = _family(1)
    coarse = synthesize_design(model, _settings((-1.0, 1.0)))
    assert coarse.certificate.worst_ratio < 1 and failing_segment(coarse) == (0, 1)
    design, inserted = refined_design(lambda table: synthesize_design(model, table), _settings((-1.0, 1.0)),
                                      list(model.p_names), {})
    assert inserted == [0.0] and design.certificate.ok
    direct = synthesize_design(model, _settings((-1.0, 0.0, 1.0)))
    assert design.plant.polytope.breakpoints.tolist() == [-1.0, 0.0, 1.0]
    for got, want in zip((design.controller.Ak, design.controller.Ck), (direct.controller.Ak,
                                                                      direct.controller.Ck), strict=True):
        np.testing.assert_array_equal(got, want)
    again, none = refined_design(lambda table: synthesize_design(model, table), _settings((-1.0, 0.0, 1.0)),
                                 list(model.p_names), {})
    assert none == [] and again.certificate.ok


@pytest.mark.parametrize("seed", [7])
def test_a_design_that_keeps_failing_stops_after_the_bounded_number_of_insertions(seed):
    """Each inserted value halves a segment of the breakpoints before it; never more than MAX_INSERTED."""
    model = _family(seed)
    design, inserted = refined_design(lambda table: synthesize_design(model, table), _settings((-1.0, 1.0)),
                                      list(model.p_names), {})
    assert len(inserted) == MAX_INSERTED and not design.certificate.ok
    values = [-1.0, 1.0]
    for v in inserted:
        assert any(v == 0.5 * (a + b) for a, b in zip(sorted(values), sorted(values)[1:], strict=False))
        values.append(v)
    assert design.plant.polytope.breakpoints.tolist() == sorted(values)


def test_the_breakpoints_used_follow_the_polytope_order_even_when_the_map_decreases():
    """p₁ = −y: breakpoints given in y as 1, 0, −1 (ascending p₁), 0.5 inserted → 1, 0.5, 0, −1."""
    given = SignalImages([[-1.0], [0.0], [1.0]], SignalValues("y", (1.0, 0.0, -1.0)))
    used = design_breakpoints(given, [0.5], ["m"], {"m": "-y"})
    assert used.source.values == (1.0, 0.5, 0.0, -1.0)
    assert used == [[-1.0], [-0.5], [0.0], [1.0]]
    assert design_breakpoints(given, [], ["m"], {"m": "-y"}) is given


def test_the_certificate_line_names_inserted_values_in_the_unit_the_design_file_gave():
    """Breakpoints given in degrees keep their unit through an insertion: the line reads −67.5°, not the
    radians the design works in; given in the signal's own units, the number as it is."""
    given = signal_values({"signal": "arm_angle", "values": [-75, -60, 0], "unit": "deg"},
                          "[synth] breakpoints")
    rows = SignalImages([[np.sin(v)] for v in given.values], given)
    used = design_breakpoints(rows, [np.radians(-67.5)], ["s"], {"s": "sin(arm_angle)"})
    assert used.source.unit == "deg" and used.source.values[1] == np.radians(-67.5)
    info = {"inserted_breakpoints": [np.radians(-67.5)]}
    assert "arm_angle = -67.5° (in that order" in inserted_lines(info, used)[0]
    plain = SignalImages([[-1.0], [1.0]], SignalValues("y", (-1.0, 1.0)))
    assert "y = 0.25 (in that order" in inserted_lines({"inserted_breakpoints": [0.25]}, plain)[0]
