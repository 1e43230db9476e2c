"""The compiled closed-loop simulation (lpvflow.validate.loop_recursion through simulate_in_loop) against
independent formulas: python-control's response of the frozen LTI loop for an LTI model and controller,
a plain per-sample reference of the loop equations for a scheduled case (gridded controller scheduled on
an output and its set-point, a scheduling column computed from the outputs, a lag-0 term, an input map,
the velocity sign, exogenous inputs, removed trim and output offsets), and the scheduling expressions'
programs against their numpy evaluation."""

from __future__ import annotations

import control
import numpy as np
import pytest

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.expression_program import CALLS, expression_program, run_program
from lpvflow.experiment.scheduling import CONSTANTS, FUNCTIONS, compile_expression
from lpvflow.lpvio import LPVIO
from lpvflow.validate.closed_loop import InputMap, Loop, loop_signals, simulate_in_loop
from lpvflow.validate.signal_maps import saturation

BASES = ("affine", "poly:2", "spline:-0.5,0.5")


def stable(rng: np.random.Generator, n: int, radius: float) -> np.ndarray:
    A = rng.standard_normal((n, n))
    return A * radius / max(1.0, np.max(np.abs(np.linalg.eigvals(A)), initial=0.0))


def random_model(rng: np.random.Generator, ny: int, nv: int, n_a: int, n_b: int, basis: Basis,
                 lag0: bool = False, scale: float = 0.3) -> LPVIO:
    """Coefficients small enough that the loop below stays bounded; B_0 = 0 unless ``lag0``."""
    A = scale / n_a * rng.standard_normal((n_a, basis.n_psi, ny, ny))
    B = scale * rng.standard_normal((n_b + 1, basis.n_psi, ny, nv))
    B[0] *= 0.05 if lag0 else 0.0
    return LPVIO(A=A, B=B, basis=basis, Ts=0.01)


def random_controller(rng: np.random.Generator, nx: int, ny: int, nu: int) -> LtiController:
    return LtiController(A=stable(rng, nx, 0.7), B=0.3 * rng.standard_normal((nx, ny)),
                         C=0.3 * rng.standard_normal((nu, nx)), D=0.1 * rng.standard_normal((nu, ny)),
                         Ts=0.01, inputs=tuple(f"y{i}" for i in range(ny)),
                         outputs=tuple(f"u{i}" for i in range(nu)), y_op=rng.standard_normal(ny),
                         u_op=rng.standard_normal(nu))


def arx_state_space(A: np.ndarray, B: np.ndarray, Ts: float) -> control.StateSpace:
    """y(k) = −Σ_i A_i y(k−i) + Σ_{j≥1} B_j u(k−j) with the state [y(k−1) … y(k−na), u(k−1) … u(k−nb)]."""
    n_a, ny = A.shape[0], A.shape[1]
    n_b, nu = B.shape[0] - 1, B.shape[2]
    n = n_a * ny + n_b * nu
    C = np.hstack([-A[i] for i in range(n_a)] + [B[j] for j in range(1, n_b + 1)])
    F = np.zeros((n, n))
    G = np.zeros((n, nu))
    F[:ny] = C  # y(k) enters the first block of the next state
    F[ny:n_a * ny, : (n_a - 1) * ny] = np.eye((n_a - 1) * ny)
    G[n_a * ny: n_a * ny + nu] = np.eye(nu)  # u(k) enters the first input block
    F[n_a * ny + nu:, n_a * ny: n - nu] = np.eye((n_b - 1) * nu)
    return control.ss(F, G, C, np.zeros((ny, nu)), Ts)


@pytest.mark.parametrize("seed", range(6))
def test_an_lti_model_in_an_lti_loop_is_the_frozen_loops_response(seed):
    """LTI model (an LPV model at constant scheduling p0: its coefficients Σ_l ψ_l(p0) A_l) and LTI
    controller, u = u_op + K(y − y_op) + r (or without u_op when the trim is removed): the outputs are
    python-control's forced response of feedback(P, K, +1) to r + u_op − K(y_op)."""
    rng = np.random.default_rng(seed)
    n, t, stable_loop = 400, np.arange(400) * 0.01, False
    while not stable_loop:  # a random loop; redrawn until the frozen closed loop is stable
        ny, nu = int(rng.integers(1, 3)), int(rng.integers(1, 3))
        basis = Basis.from_spec(BASES[seed % 3], 1)
        model = random_model(rng, ny, nu, int(rng.integers(1, 4)), int(rng.integers(1, 4)), basis)
        K = random_controller(rng, int(rng.integers(0, 4)), ny, nu)
        p0 = rng.uniform(-1, 1)
        psi = basis.eval(np.array([[p0]]))[0]
        P = arx_state_space(np.einsum("l,ilrc->irc", psi, model.A), np.einsum("l,jlrc->jrc", psi, model.B),
                            0.01)
        Kss = control.ss(K.A, K.B, K.C, K.D, 0.01)
        loop_ss = control.feedback(P, Kss, sign=1)
        stable_loop = bool(np.all(np.abs(control.poles(loop_ss)) < 0.99))
    trim_removed = bool(seed % 2)
    data = Dataset(rng.standard_normal((n, nu)), rng.standard_normal((n, ny)), np.full((n, 1), p0), 0.01,
                   list(K.outputs), list(K.inputs), ["p"])
    r = rng.standard_normal((n, nu))
    y = simulate_in_loop(model, data, Loop(K, r, {}, trim_removed=trim_removed))

    offset = control.forced_response(Kss, t, np.tile(K.y_op[:, None], n)).outputs.reshape(nu, n)
    v = r.T - offset + (0 if trim_removed else K.u_op[:, None])
    expected = control.forced_response(loop_ss, t, v).outputs.reshape(ny, n).T
    assert np.all(np.isfinite(y))
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-9 * max(1.0, np.max(np.abs(expected))))


def reference_loop(model: LPVIO, data: Dataset, K: GriddedController, r: np.ndarray, s: np.ndarray,
                   offset: np.ndarray, trim_removed: bool, input_map: InputMap, sign_of: int,
                   extra: np.ndarray, passes: int, sensor: np.ndarray | None = None) -> np.ndarray:
    """The loop's equations sample by sample in plain numpy: p(k) = sin(y0 + offset0) + 0.5 (y1 + offset1)
    of the output last given; θ = y1 + 0.3·s; ȳ = y_op(θ) or s where given; u_c from (A, B, C, D, y_op,
    u_op) interpolated at θ (K.at); u = u_c − trim + r; v = [input_map(u), extra, velocity sign], the
    sign of 2 y(k) − 3 y(k−1) + y(k−2) (missing past samples: the first one; 0 at k = 0). A sensor
    offset o (``sensor``): the controller reads y + offset + o (also in θ), the scheduling y + offset,
    and y + o is returned."""
    sensor = np.zeros(data.y.shape[1]) if sensor is None else sensor
    n, ny = data.N, data.y.shape[1]
    y_model, v_hist, psi_hist = np.zeros((n, ny)), [], []
    out = np.full((n, ny), np.inf)
    x = np.zeros(K.order)

    def theta(y_plant, k):
        return y_plant[1] + 0.3 * (0.0 if np.isnan(s[k, 1]) else s[k, 1])

    def command(y_plant, k, advance):
        A, B, C, D, y_op, u_op = K.at(theta(y_plant, k))
        dy = y_plant - np.where(np.isnan(s[k]), y_op, s[k])
        u_c = u_op + C @ x + D @ dy
        return u_c - (u_op if trim_removed else 0) + r[k], A @ x + B @ dy

    def model_input(k, u, y_last):
        p = np.sin(y_last[0] + offset[0]) + 0.5 * (y_last[1] + offset[1])
        vel = 0.0 if k == 0 else np.sign(2 * y_last[sign_of] - 3 * y_model[k - 1, sign_of]
                                         + y_model[max(k - 2, 0), sign_of])
        return basis_at(model, p), np.concatenate([input_map(u), extra[k], [vel]])

    for k in range(n):
        past = np.zeros(ny)
        for i in range(1, min(model.A.shape[0], k) + 1):
            past -= np.einsum("l,lrc->rc", psi_hist[k - i], model.A[i - 1]) @ y_model[k - i]
        for j in range(1, min(model.B.shape[0] - 1, k) + 1):
            past += np.einsum("l,lrc->rc", psi_hist[k - j], model.B[j]) @ v_hist[k - j]
        last = past
        for _ in range(passes):
            u, _ = command(last + offset + sensor, k, False)
            psi, v = model_input(k, u, last)
            last = past + np.einsum("l,lrc->rc", psi, model.B[0]) @ v
        u, x_next = command(last + offset + sensor, k, True)
        if passes == 0:
            psi, v = model_input(k, u, last)
        x = x_next
        psi_hist.append(psi)
        v_hist.append(v)
        y_model[k] = last
        out[k] = last + sensor
    return out


def basis_at(model: LPVIO, p: float) -> np.ndarray:
    return model.basis.eval(np.array([[p]]), check_range=False)[0]


def scheduled_case(rng: np.random.Generator, seed: int) -> tuple[LPVIO, Dataset, Loop, dict, tuple]:
    """A random scheduled loop (:func:`test_a_scheduled_loop_follows_its_equations_sample_by_sample`):
    (model, data, loop, the drive of simulate_in_loop, the arguments of :func:`reference_loop`)."""
    n, ny, nu, nx, G = 60, 2, 2, int(rng.integers(1, 4)), int(rng.integers(1, 5))
    grid = np.sort(rng.uniform(-0.5, 0.5, G)) + np.arange(G) * 1e-3
    K = GriddedController(grid=grid, A=np.stack([stable(rng, nx, 0.6) for _ in range(G)]),
                          B=0.3 * rng.standard_normal((G, nx, ny)), C=0.3 * rng.standard_normal((G, nu, nx)),
                          D=0.1 * rng.standard_normal((G, nu, ny)), y_op=0.1 * rng.standard_normal((G, ny)),
                          u_op=rng.standard_normal((G, nu)), Ts=0.01, inputs=("y0", "y1"),
                          outputs=("u0", "u1"), scheduling="y1 + 0.3 * y1_setpoint")
    basis = Basis.from_spec(BASES[seed % 3], 1)
    lag0, sign_of, trim_removed = bool(seed % 2), int(rng.integers(0, 2)), bool(seed < 3)
    model = random_model(rng, ny, nu + 2, 2, 2, basis, lag0=lag0, scale=0.1)
    data = Dataset(rng.standard_normal((n, nu)), rng.standard_normal((n, ny)), rng.standard_normal((n, 1)),
                   0.01, ["u0", "u1"], ["y0", "y1"], ["p"])
    offset = 0.2 * rng.standard_normal(ny)
    s = np.where(rng.uniform(size=(n, ny)) < 0.4, np.nan, 0.1 * rng.standard_normal((n, ny)))
    r, extra = rng.standard_normal((n, nu)), rng.standard_normal((n, 1))
    input_map = InputMap(("dead_zone", "saturation")[seed // 2 % 2], int(rng.integers(0, nu)), 0.3)
    loop = Loop(K, r, {"p": "sin(y0) + 0.5 * y1"}, s, trim_removed, offset)
    drive = {"input_map": input_map, "exogenous": extra, "sign_of": sign_of}
    return model, data, loop, drive, (K, r, s, offset, trim_removed, input_map, sign_of, extra, 3 * lag0)


@pytest.mark.parametrize("seed", range(8))
def test_a_scheduled_loop_follows_its_equations_sample_by_sample(seed):
    """A gridded controller scheduled on an output and its set-point (NaN set-points in part), a
    scheduling column computed from the outputs, removed output offsets and trim, a dead zone or a
    saturation on an input, an exogenous input and the velocity sign of an output, with or without a
    lag-0 term: the compiled loop equals :func:`reference_loop` over 60 samples."""
    model, data, loop, drive, arguments = scheduled_case(np.random.default_rng(1000 + seed), seed)
    y = simulate_in_loop(model, data, loop, **drive)
    expected = reference_loop(model, data, *arguments)
    assert np.all(np.isfinite(expected))
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(expected))))


@pytest.mark.parametrize("seed", range(6))
def test_a_sensor_offset_is_read_by_the_controller_not_by_the_dynamics(seed):
    """The scheduled loop with a sensor offset o on the outputs (y_meas = y + o): the compiled loop equals
    :func:`reference_loop` with the controller (and its scheduling θ) reading y + o, the model's
    scheduling column computed from y, and y + o returned — not the loop without o shifted by o."""
    rng = np.random.default_rng(3000 + seed)
    model, data, loop, drive, arguments = scheduled_case(rng, seed)
    sensor = 0.2 * rng.standard_normal(data.y.shape[1])
    y = simulate_in_loop(model, data, loop, **drive, sensor_offset=sensor)
    expected = reference_loop(model, data, *arguments, sensor=sensor)
    assert np.all(np.isfinite(expected))
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(expected))))
    assert np.max(np.abs(y - sensor - simulate_in_loop(model, data, loop, **drive))) > 1e-3


@pytest.mark.parametrize("seed", range(3))
def test_a_read_only_sensor_offset_gives_the_same_loop_without_a_second_compile(seed):
    """A read-only sensor offset (another numba type than a writable array) is copied: the loop's outputs
    equal those of the writable offset and the compiled loop keeps one signature per argument types."""
    from lpvflow.validate.loop_recursion import simulate_loop

    rng = np.random.default_rng(4000 + seed)
    model, data, loop, drive, _ = scheduled_case(rng, seed)
    sensor = 0.2 * rng.standard_normal(data.y.shape[1])
    y = simulate_in_loop(model, data, loop, **drive, sensor_offset=sensor)
    compiled = len(simulate_loop.signatures)
    sensor.setflags(write=False)
    np.testing.assert_array_equal(simulate_in_loop(model, data, loop, **drive, sensor_offset=sensor), y)
    assert len(simulate_loop.signatures) == compiled


def test_the_loop_kernels_helpers_are_compiled_inside_the_kernel_not_on_their_own():
    """A fresh compile of the loop kernel (no cache) compiles none of its helpers as a function of its own
    (each would be optimized and emitted once alone and again inside its caller): they are inlined where
    they are called; the controller law, shared with controller_commands, is the one compiled
    callee. The fresh kernel gives the cached one's outputs."""
    import numba

    from lpvflow.validate import loop_recursion as lr
    from lpvflow.validate.closed_loop import InLoopModel

    rng = np.random.default_rng(4100)
    model, data, loop, drive, _ = scheduled_case(rng, 0)
    arguments = InLoopModel(model, data, loop, law=loop.controller.loop_law(), **drive)
    helpers = (lr._weights, lr._advance, lr._finite, lr._basis, lr._read, lr._within, lr._actuate,
               lr._present, lr._from_past)
    before = [len(h.signatures) for h in helpers]
    fresh = numba.njit(error_model="numpy")(lr.simulate_loop.py_func)
    y = fresh(*arguments._arguments, np.int64(arguments.passes), 1e12, arguments.integrated)
    assert [len(h.signatures) for h in helpers] == before == [0] * len(helpers)
    np.testing.assert_array_equal(y, arguments.simulate())


@pytest.mark.parametrize("seed", range(3))
def test_the_gridded_loops_signals_rebuild_a_records_driven_inputs(seed):
    """Loop.from_record recovers r = u − K(y) under a gridded controller with set-points and removed
    trim; loop_signals of the record's own outputs give back its driven inputs."""
    rng = np.random.default_rng(2000 + seed)
    n, G, nx = 300, 4, 2
    K = GriddedController(grid=np.linspace(-1, 1, G), A=np.stack([stable(rng, nx, 0.6) for _ in range(G)]),
                          B=rng.standard_normal((G, nx, 2)), C=rng.standard_normal((G, 2, nx)),
                          D=rng.standard_normal((G, 2, 2)), y_op=rng.standard_normal((G, 2)),
                          u_op=rng.standard_normal((G, 2)), Ts=0.01, inputs=("y0", "y1"),
                          outputs=("u0", "u1"), scheduling="y0 - y1_setpoint")
    data = Dataset(rng.standard_normal((n, 2)), rng.uniform(-1.5, 1.5, (n, 2)), rng.standard_normal((n, 1)),
                   0.01, ["u0", "u1"], ["y0", "y1"], ["p"])
    setpoints = np.where(rng.uniform(size=(n, 2)) < 0.5, np.nan, rng.standard_normal((n, 2)))
    loop = Loop.from_record(data, K, {}, setpoints, trim_removed=True)
    u, _ = loop_signals(data.y, data, loop)
    np.testing.assert_allclose(u, data.u, rtol=0, atol=1e-12 * np.max(np.abs(data.u)))


def test_a_saturation_map_and_a_diverging_loop():
    """A saturation in the loop acts as np.clip on its input, and a loop that diverges gives inf from
    the first sample whose output reaches 1e12 on (the outputs before it finite)."""
    u = np.array([-2.0, -0.5, 0.0, 0.7, 3.0])
    mapped = [InputMap("saturation", 0, 1.0)(np.array([v, v]))[0] for v in u]
    assert np.array_equal(mapped, saturation(u, 1.0))
    n = 400
    model = LPVIO(A=np.array([[[[-1.5]], [[0.0]]]]), B=np.array([[[[0.0]], [[0.0]]], [[[1.0]], [[0.0]]]]),
                  basis=Basis.affine(1), Ts=0.01)
    K = LtiController(A=np.zeros((0, 0)), B=np.zeros((0, 1)), C=np.zeros((1, 0)), D=np.array([[0.0]]),
                      Ts=0.01, inputs=("y0",), outputs=("u0",), y_op=np.zeros(1), u_op=np.zeros(1))
    data = Dataset(np.zeros((n, 1)), np.zeros((n, 1)), np.zeros((n, 1)), 0.01)
    y = simulate_in_loop(model, data, Loop(K, np.ones((n, 1)), {}))
    expected = np.zeros(n)  # y(k) = 1.5 y(k−1) + 1 from y(0) = 0
    for k in range(1, n):
        expected[k] = 1.5 * expected[k - 1] + 1.0
    stop = int(np.argmax(np.abs(expected) >= 1e12))
    np.testing.assert_allclose(y[:stop, 0], expected[:stop], rtol=1e-12)
    assert np.all(np.isinf(y[stop:]))


EXPRESSIONS = ("sin(a) + 0.5 * b", "-a ** 2 / (1 + b * b)", "arctan2(a, b) - pi",
               "minimum(a, b) * maximum(a, 2)",
               "sqrt(abs(a)) + exp(-b) + log(1 + a * a) + tanh(b) + cos(a) + tan(0.2 * b)", "+a - -b")


def random_expression(rng: np.random.Generator, depth: int) -> str:
    if depth == 0 or rng.uniform() < 0.25:
        return str(rng.choice(["a", "b", "c", "pi", f"{rng.uniform(0.1, 2):.3f}"]))
    kind = rng.integers(0, 3)
    if kind == 0:
        return f"({random_expression(rng, depth - 1)} {rng.choice(['+', '-', '*', '/'])} " \
               f"{random_expression(rng, depth - 1)})"
    if kind == 1:
        return f"-{random_expression(rng, depth - 1)}"
    name = str(rng.choice(sorted(CALLS)))
    args = ", ".join(random_expression(rng, depth - 1) for _ in range(CALLS[name][1]))
    return f"{name}({args})"


def test_every_scheduling_function_has_a_program_code():
    assert set(CALLS) == set(FUNCTIONS)


@pytest.mark.parametrize("expression", EXPRESSIONS + tuple(random_expression(np.random.default_rng(s), 4)
                                                         for s in range(40)))
def test_an_expressions_program_computes_its_numpy_value(expression):
    """The program's value on random samples is the expression's numpy value (non-finite ones alike); an
    expression the per-sample evaluation refuses (it is checked at zero signals) is refused alike."""
    try:
        compile_expression(expression, ["a", "b", "c"])
    except DataError:
        with pytest.raises(DataError):
            expression_program(expression, ["a", "b", "c"])
        return
    rng = np.random.default_rng(7)
    samples = rng.uniform(0.2, 1.5, (50, 3))
    expected = _numpy_value(expression, samples)
    codes, arguments = expression_program(expression, ["a", "b", "c"])
    stack = np.empty(len(codes) + 1)
    got = np.array([run_program(codes, arguments, row, stack) for row in samples])
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-300, equal_nan=True)


def _numpy_value(expression: str, samples: np.ndarray) -> np.ndarray:
    """The expression evaluated by numpy on the columns a, b, c (what evaluate() computes, without its
    check that every value is finite)."""
    with np.errstate(all="ignore"):
        value = eval(expression, {"__builtins__": {}, **FUNCTIONS, **CONSTANTS},
                     {"a": samples[:, 0], "b": samples[:, 1], "c": samples[:, 2]})
    return np.broadcast_to(value, (len(samples),))
