"""The diagnosis' closed loop (compiled, lpvflow.validate.loop_recursion): a model with a lag-0 input
term (direct feedthrough) against the closed-form solution of its algebraic loop, the controller's command
evaluated without advancing its state, and the loop's signals rebuilt from a record's own outputs."""

from __future__ import annotations

import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.experiment.controller import LtiController
from lpvflow.loop.protocol import LtiLaw
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import Loop, loop_signals, simulate_in_loop


def random_controller(rng: np.random.Generator, nx: int, ny: int = 1, nu: int = 1) -> LtiController:
    A = rng.standard_normal((nx, nx))
    A *= 0.8 / max(1.0, np.max(np.abs(np.linalg.eigvals(A)), initial=0.0))  # a stable controller
    return LtiController(A=A, B=rng.standard_normal((nx, ny)), C=rng.standard_normal((nu, nx)),
                         D=rng.standard_normal((nu, ny)), Ts=0.01, inputs=tuple(f"y{i}" for i in range(ny)),
                         outputs=tuple(f"u{i}" for i in range(nu)), y_op=rng.standard_normal(ny),
                         u_op=rng.standard_normal(nu))


@pytest.mark.parametrize("seed", range(5))
def test_a_lag0_input_term_is_resolved_in_the_loop(seed):
    """y(k) + a y(k−1) = b0 u(k) + b1 u(k−1) under u(k) = u_op + d (y(k) − y_op) + r(k): the loop is
    algebraic; its solution is y(k) = (−a y(k−1) + b1 u(k−1) + b0 (u_op − d y_op + r(k))) / (1 − b0 d).
    With b0 d = 1e-3 the engine's three fixed-point passes leave ~(b0 d)³ of the first guess' error
    (two passes would leave 1e-6 of it)."""
    rng = np.random.default_rng(seed)
    a, b0, b1 = rng.uniform(-0.8, 0.8), 0.5, rng.uniform(-1.0, 1.0)
    d = 1e-3 / b0
    controller = LtiController(A=np.zeros((0, 0)), B=np.zeros((0, 1)), C=np.zeros((1, 0)), D=np.array([[d]]),
                               Ts=0.01, inputs=("y0",), outputs=("u0",), y_op=rng.standard_normal(1),
                               u_op=rng.standard_normal(1))
    model = LPVIO(A=np.array([[[[a]], [[0.0]]]]), B=np.array([[[[b0]], [[0.0]]], [[[b1]], [[0.0]]]]),
                  basis=Basis.affine(1), Ts=0.01)
    n = 300
    data = Dataset(rng.standard_normal((n, 1)), rng.standard_normal((n, 1)), rng.uniform(-1, 1, (n, 1)), 0.01)
    r = rng.standard_normal((n, 1))
    y = simulate_in_loop(model, data, Loop(controller, r, {}))

    expected, y_prev, u_prev = np.zeros(n), 0.0, 0.0
    (u_op,), (y_op,) = controller.u_op, controller.y_op
    for k in range(n):
        expected[k] = (-a * y_prev + b1 * u_prev + b0 * (u_op - d * y_op + r[k, 0])) / (1 - b0 * d)
        y_prev, u_prev = expected[k], u_op + d * (expected[k] - y_op) + r[k, 0]
    np.testing.assert_allclose(y[:, 0], expected, rtol=0, atol=1e-8 * np.max(np.abs(expected)))


@pytest.mark.parametrize("seed", range(5))
def test_the_lti_command_is_evaluated_without_advancing_the_state(seed):
    """LtiLaw.output(r, y, p) is what step(r, y, p) returns, and leaves the state where it was."""
    rng = np.random.default_rng(100 + seed)
    law = LtiLaw(random_controller(rng, nx=3, ny=2, nu=2))
    for _ in range(20):
        r = np.where(rng.uniform(size=2) < 0.3, np.nan, rng.standard_normal(2))
        y = rng.standard_normal(2)
        first, again = law.output(r, y, np.zeros(0)), law.output(r, y, np.zeros(0))
        np.testing.assert_array_equal(first, again)
        np.testing.assert_allclose(law.step(r, y, np.zeros(0)), first, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("seed", range(5))
def test_the_loop_signals_of_a_records_own_outputs_are_the_record(seed):
    """The excitation is recovered as r = u − K(y); the loop's signals rebuilt from the record's outputs
    give back its driven input, and a scheduling column with an expression is recomputed from y."""
    rng = np.random.default_rng(200 + seed)
    n = 200
    y = rng.standard_normal((n, 2))
    data = Dataset(rng.standard_normal((n, 2)), y, np.sin(y[:, :1]), 0.01, ["u0", "u1"], ["y0", "y1"], ["s"])
    controller = random_controller(rng, nx=int(rng.integers(0, 4)))
    loop = Loop.from_record(data, controller, {"s": "sin(y0)"})
    u, p = loop_signals(data.y, data, loop)
    np.testing.assert_allclose(u, data.u, rtol=0, atol=1e-12)
    np.testing.assert_allclose(p, data.p, rtol=0, atol=1e-15)
