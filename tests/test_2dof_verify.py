"""2-DOF controllers, trim feed-forward and piecewise scheduling in the Python controller and in
``lpvflow verify``, against analytic closed loops.

The plant is the integrator FMU of tests/test_verify.py, y(k+1) = y(k) + b u(k) with b = 0.5. With the
static 2-DOF law u = k_r r − k_y y the loop is y⁺ = (1 − b k_y) y + b k_r r: after a unit step
y = (k_r/k_y)(1 − c^j), c = 1 − b k_y, j samples after the step. With the 1-DOF law u = u_eq(y) + k (r − y)
and the trim u_eq(p) = α p (scheduled on p = y) the loop is y⁺ = (1 + b(α − k)) y + b k r, whose step
response tends to k/(k − α) instead of 1.
"""

from __future__ import annotations

import json
from pathlib import Path

import control
import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import load
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal
from lpvflow.pipeline.verify import run_verification, simulate_loop
from lpvflow.synth.controller import AntiWindup, LPVController, Trim
from lpvflow.synth.polytope import PiecewisePolytope, PointPolytope, Polytope
from tests.test_verify import BASIS, POLY, TS
from tests.test_verify import B as GAIN
from tests.test_verify import plants as plants  # the analytic plant FMUs (a pytest fixture)

LOOP = Loop(("y",), ("u",), ("y",))
STEP = Scenario("step", 1.0, reference={"y": Signal(steps=((0.1, 1.0),))})
POINT = PointPolytope(np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]]))


def _static(D: list[float], structure: str, poly: Polytope = POLY, trim: Trim | None = None) -> LPVController:
    """u = D w (a one-state controller whose state stays zero), the same at every vertex."""
    N, nw = poly.n_vertices, len(D)
    return LPVController(np.zeros((N, 1, 1)), np.zeros((N, 1, nw)), np.zeros((N, 1, 1)),
                         np.tile(np.array(D, dtype=float), (N, 1, 1)), poly, BASIS, TS, structure=structure,
                         trim=trim)


def _step_response(k_ratio: float, c: float, n: int = 100, at: int = 10) -> np.ndarray:
    j = np.arange(n) - at
    return np.where(j > 0, k_ratio * (1.0 - c ** np.clip(j, 0, None)), 0.0)


def test_verify_feeds_a_2dof_controller_references_then_measurements(plants: dict) -> None:
    k_r, k_y = 0.2, 0.4  # y → k_r/k_y = 0.5 with c = 1 − b k_y = 0.8
    lpv = _static([k_r, -k_y], "2dof")
    baseline = _static([k_r, -k_y], "2dof", poly=POINT)  # an LTI baseline of the same structure
    verification = run_verification(lpv, plants[1.0], [STEP], LOOP, baseline)
    for run in verification.results[0].runs:
        assert run.failure is None
        np.testing.assert_allclose(run.outputs[:, 0], _step_response(k_r / k_y, 1 - GAIN * k_y), atol=1e-12)
    # [y; r] instead of [r; y] would be u = k_r y − k_y r: a different (unstable, c = 1.1) loop
    swapped = simulate_loop(_static([-k_y, k_r], "2dof"), plants[1.0], STEP, LOOP)
    assert np.max(np.abs(swapped.outputs[:, 0] - verification.results[0].runs[0].outputs[:, 0])) > 0.4


def test_a_2dof_law_with_equal_gains_is_the_1dof_law(plants: dict) -> None:
    one = simulate_loop(_static([0.3], "1dof"), plants[1.0], STEP, LOOP)
    two = simulate_loop(_static([0.3, -0.3], "2dof"), plants[1.0], STEP, LOOP)
    # D·[r; y] with D = [k, −k] is k·(r − y) up to the rounding of the product's order (numpy's matmul
    # may fuse or reorder it), so equal to a few ulps, not bit for bit
    np.testing.assert_allclose(one.outputs, two.outputs, rtol=0, atol=1e-14)
    np.testing.assert_allclose(one.outputs[:, 0], _step_response(1.0, 1 - GAIN * 0.3), atol=1e-12)


def test_verify_applies_the_trim_feedforward(plants: dict) -> None:
    k, alpha = 0.4, 0.1  # u = α y + k (r − y): y → k/(k − α) = 4/3, c = 1 + b(α − k) = 0.85
    trim = Trim([-5.0, 5.0], [[-5.0 * alpha], [5.0 * alpha]])  # u_eq(p) = α p on [−5, 5]
    run = simulate_loop(_static([k], "1dof", trim=trim), plants[1.0], STEP, LOOP)
    np.testing.assert_allclose(run.outputs[:, 0], _step_response(k / (k - alpha), 1 + GAIN * (alpha - k)),
                               atol=1e-12)
    # the command logged is the trim plus the feedback
    np.testing.assert_allclose(run.commanded[:, 0], alpha * run.outputs[:, 0]
                               + k * (run.reference[:, 0] - run.outputs[:, 0]), atol=1e-12)


def test_trim_is_np_interp_of_the_first_scheduling_signal_clamped_at_the_ends() -> None:
    trim = Trim([-1.0, 0.2, 1.0], [[2.0, 0.0], [0.5, 1.0], [-3.0, 1.0]])
    for p1 in (-2.0, -1.0, -0.4, 0.2, 0.7, 1.0, 3.0):
        expected = [np.interp(p1, [-1.0, 0.2, 1.0], column) for column in ([2.0, 0.5, -3.0], [0.0, 1.0, 1.0])]
        np.testing.assert_array_equal(trim.value(np.array([p1, 99.0])), expected)  # p[1] is not used
    np.testing.assert_array_equal(trim.value(np.array([-0.4])), [2.0 - 1.5 * 0.5, 0.5])  # by hand


def test_the_controller_output_includes_the_trim_and_the_antiwindup_sees_it() -> None:
    trim = Trim([0.0, 1.0], [[0.0], [8.0]])  # u_eq = 8 p
    K = LPVController(np.full((2, 1, 1), 0.5), np.ones((2, 1, 1)), np.ones((2, 1, 1)),
                      np.full((2, 1, 1), 2.0), POLY, BASIS, TS, trim=trim)
    plain = LPVController.from_dict(K.to_dict())
    plain.trim = None
    p, w = np.array([0.5]), np.array([0.25])
    assert K.output(w, p)[0] == pytest.approx(4.0 + plain.output(w, p)[0])
    # actuator range [−5, 5] around u_op = 0: the trim alone (4) plus 2·0.25 fits, with x = 1 it does not
    K.antiwindup = AntiWindup(np.full((2, 1, 1), 0.3), [-5.0], [5.0], [0.0])
    K.reset(np.ones(1))
    u = K.step(w, p)
    assert u[0] == pytest.approx(4.0 + 1.0 + 0.5)
    assert K.x[0] == pytest.approx(0.5 * 1.0 + 0.25 + 0.3 * (5.0 - u[0]))  # L (u_a − u), u_a = 5


def _piecewise(b: list[float]) -> Polytope:
    b = np.asarray(b, dtype=float)
    return PiecewisePolytope(np.array([[b[0], b[-1]]]), np.column_stack([np.ones(len(b)), b]), breakpoints=b)


def test_piecewise_coordinates_are_hat_functions_of_the_first_signal() -> None:
    poly = _piecewise([-1.0, 0.0, 0.5])
    lam = lambda p: poly.coordinates_at(BASIS, np.array([p]))  # noqa: E731
    for i, b in enumerate(poly.breakpoints):
        np.testing.assert_array_equal(lam(b), np.eye(3)[i])  # a vertex at each breakpoint
    np.testing.assert_allclose(lam(-0.25), [0.25, 0.75, 0.0], atol=1e-15)
    np.testing.assert_allclose(lam(0.1), [0.0, 0.8, 0.2], atol=1e-15)
    np.testing.assert_array_equal(lam(-7.0), [1.0, 0.0, 0.0])  # clamped at the ends
    np.testing.assert_array_equal(lam(2.0), [0.0, 0.0, 1.0])
    for p in np.linspace(-1.2, 0.7, 41):
        weights = lam(p)
        assert weights.sum() == pytest.approx(1.0) and np.all(weights >= 0) and np.count_nonzero(weights) <= 2
        # linear in between: the λ-weighted breakpoints give p back (clamped)
        assert weights @ poly.breakpoints == pytest.approx(np.clip(p, -1.0, 0.5), abs=1e-14)


def test_a_piecewise_controller_interpolates_its_vertex_matrices_per_segment() -> None:
    poly = _piecewise([-1.0, 0.0, 0.5])
    K = LPVController(np.zeros((3, 1, 1)), np.zeros((3, 1, 1)), np.zeros((3, 1, 1)),
                      np.array([[[1.0]], [[3.0]], [[-1.0]]]), poly, BASIS, TS)
    assert K.matrices(np.array([-0.5]))[3][0, 0] == pytest.approx(2.0)
    assert K.matrices(np.array([0.25]))[3][0, 0] == pytest.approx(1.0)
    with pytest.raises(ModelError, match="one strictly ascending breakpoint per vertex"):
        PiecewisePolytope(poly.box, poly.psi_vertices, breakpoints=np.array([0.0, -1.0, 0.5]))
    record = K.to_dict()  # a controller file: the same line, and an unknown kind is named
    record["polytope"]["breakpoints"] = [0.0, -1.0, 0.5]
    with pytest.raises(ModelError, match="one strictly ascending breakpoint per vertex"):
        LPVController.from_dict(record)
    record["polytope"]["kind"] = "simplex"
    with pytest.raises(ModelError, match="unknown polytope kind 'simplex'"):
        LPVController.from_dict(record)


def test_structure_trim_and_breakpoints_survive_the_controller_file(tmp_path: Path) -> None:
    K = _static([0.2, -0.4], "2dof", poly=_piecewise([-1.0, 0.0, 0.5]), trim=Trim([0.0, 1.0], [[1.0], [2.0]]))
    K.save(tmp_path / "K.json")
    loaded = load(tmp_path / "K.json")
    assert loaded.structure == "2dof" and loaded.n_measured == 1
    np.testing.assert_array_equal(loaded.polytope.breakpoints, [-1.0, 0.0, 0.5])
    np.testing.assert_array_equal(loaded.trim.p, [0.0, 1.0])
    np.testing.assert_array_equal(loaded.trim.u, [[1.0], [2.0]])
    # a file written before the fields existed is a 1-DOF controller without trim
    old = _static([0.3], "1dof").to_dict()
    del old["structure"], old["polytope"]["breakpoints"]
    assert "trim" not in old
    (tmp_path / "old.json").write_text(json.dumps(old))
    legacy = load(tmp_path / "old.json")
    assert legacy.structure == "1dof" and legacy.trim is None and legacy.polytope.breakpoints is None


@pytest.mark.parametrize(("change", "message"), [
    ({"structure": "3dof"}, "controller structure '3dof' is unknown"),
    ({"structure": "2dof", "D": [0.1, 0.2, 0.3]}, "a 2dof controller reads [r; y], an even number"),
    ({"trim": Trim([0.0], [[1.0, 2.0]])}, "trim table has 2 column(s) for the controller's 1 output(s)"),
])
def test_bad_structure_or_trim_is_one_line(change: dict, message: str) -> None:
    D = change.pop("D", [0.1, 0.2])
    with pytest.raises(ModelError) as info:
        LPVController(np.zeros((2, 1, 1)), np.zeros((2, 1, len(D))), np.zeros((2, 1, 1)),
                      np.tile(np.array(D), (2, 1, 1)), POLY, BASIS, TS, **change)
    assert message in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(("p", "u", "message"), [
    ([0.0, 0.0], [[1.0], [2.0]], "strictly ascending"),
    ([0.0, 1.0], [[1.0]], "one finite row per breakpoint"),
])
def test_bad_trim_table_is_one_line(p: list, u: list, message: str) -> None:
    with pytest.raises(ModelError, match=message):
        Trim(p, u)


def test_a_loop_with_the_wrong_number_of_2dof_inputs_is_refused(plants: dict) -> None:
    with pytest.raises(ModelError, match=r"2dof\) has 2 input\(s\).*\(4 2dof controller inputs\)"):
        simulate_loop(_static([0.2, -0.4], "2dof"), plants[1.0], STEP, Loop(("y", "x"), ("u",), ("y",)))


def test_input_of_orders_references_before_measurements() -> None:
    basis = Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,))
    K = LPVController(np.zeros((2, 1, 1)), np.zeros((2, 1, 4)), np.zeros((2, 1, 1)), np.zeros((2, 1, 4)),
                      POLY, basis, TS, structure="2dof")
    np.testing.assert_array_equal(K.input_of([1.0, 2.0], [3.0, 5.0]), [1.0, 2.0, 3.0, 5.0])
    one = LPVController(np.zeros((2, 1, 1)), np.zeros((2, 1, 2)), np.zeros((2, 1, 1)), np.zeros((2, 1, 2)),
                        POLY, basis, TS)
    np.testing.assert_array_equal(one.input_of([1.0, 2.0], [3.0, 5.0]), [-2.0, -3.0])


def test_a_2dof_controller_and_a_1dof_lti_baseline_run_side_by_side(plants: dict) -> None:
    """A 1-DOF StateSpace baseline (u = k e) next to a 2-DOF LPV controller: each gets its own input."""
    k = 0.3
    verification = run_verification(_static([0.2, -0.4], "2dof"), plants[1.0], [STEP], LOOP,
                                     baseline=control.ss([], [], [], [[k]], TS))
    lpv, baseline = verification.results[0].runs
    np.testing.assert_allclose(lpv.outputs[:, 0], _step_response(0.5, 1 - GAIN * 0.4), atol=1e-12)
    np.testing.assert_allclose(baseline.outputs[:, 0], _step_response(1.0, 1 - GAIN * k), atol=1e-12)
