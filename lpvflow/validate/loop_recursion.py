"""The compiled (numba) recursion of a shifted-form LPV input-output model in the loop of a record's
controller (:mod:`lpvflow.validate.closed_loop` builds its arrays and states the loop).

Per sample k, with ψ(k) = ψ(p(k)) (:class:`~lpvflow.basis.Basis`: monomials Π_i p_i^e_i and spline
terms |p_i − η|³) and v(k) the model's input vector:

    y(k) = −Σ_{i≥1} A_i(ψ(k−i)) y(k−i) + Σ_{j≥1} B_j(ψ(k−j)) v(k−j) + B_0(ψ(k)) v(k)   (LPVIO, shifted form)

the controller (an LTI law is a one-point grid) at θ(k), its scheduling program of the outputs it reads
and their references (NaN → 0), matrices and operating points interpolated linearly on its grid and
clipped at its ends, ȳ = y_op(θ) where no reference is given:

    u_c(k) = u_op(θ) + C(θ) xc(k) + D(θ) (y(k) − ȳ(k)),    xc(k+1) = A(θ) xc(k) + B(θ) (y(k) − ȳ(k))

a model output that is an increment (``integrated``) summed into the plant's, and the plant input
u(k) = the record's inputs with u_c(k) − [u_op(θ) when the trim is removed] + r(k) on the driven ones.
A lag-0 term B_0 makes y(k) depend on u(k): y(k) is then resolved by ``passes`` fixed-point passes of
the controller's output (its state not advanced), the scheduling and v(k) recomputed from the last
resolved output (the sampling convention of :func:`lpvflow.loop.engine.close_loop`). The run stops at
the first sample whose model output reaches ``diverged`` in magnitude or whose command is not finite
(the outputs from there stay ``inf``).

Compiled as two kernels, :func:`controller_commands` and :func:`simulate_loop`, for their first-call
compile time: the helpers are inlined where they are called (``inline="always"``; a compiled callee is
optimized and emitted once alone and again inside each caller), each at one place in simulate_loop;
the controller law :func:`_law`, which both kernels call, is their one compiled callee; every function
has the same error model (numba compiles its own array and builtin implementations once per option set).
"""

from __future__ import annotations

import numba
import numpy as np

from lpvflow.experiment.expression_program import run_program
from lpvflow.validate.signal_maps import dead_zone, saturation

#: Input map codes of :func:`simulate_loop`.
NO_MAP, DEAD_ZONE, SATURATION = 0, 1, 2


@numba.njit(cache=True, error_model="numpy", inline="always")
def _weights(grid: np.ndarray, theta: float) -> tuple[int, int, float]:
    """Neighbouring grid points i, j of θ clipped to the grid and the fraction t of the way to j."""
    last = grid.shape[0] - 1
    if last == 0 or theta <= grid[0]:
        return 0, min(1, last), 0.0
    if theta >= grid[last]:
        return last - 1, last, 1.0
    i = 0
    while grid[i + 1] <= theta:  # grid[i] ≤ θ < grid[i + 1] (a controller grid has a few points)
        i += 1
    return i, i + 1, (theta - grid[i]) / (grid[i + 1] - grid[i])


@numba.njit(cache=True, error_model="numpy", no_cpython_wrapper=True)
def _law(controller, x: np.ndarray, y_read: np.ndarray, r: np.ndarray, stack: np.ndarray, u: np.ndarray,
         trim: np.ndarray, dy: np.ndarray) -> tuple[int, int, float]:
    """The command u_c into ``u`` and u_op(θ) into ``trim`` of the controller at its state ``x`` for the
    outputs read and references r, y − ȳ into ``dy``; returns the grid points and fraction (i, j, t) of θ
    for :func:`_advance`. A θ that is NaN gives a NaN command (i = −1)."""
    grid, _, _, KC, KD, y_op, u_op, codes, arguments = controller
    n_read, n_x, n_u = y_read.shape[0], KC.shape[2], KC.shape[1]
    sample = np.empty(2 * n_read)
    for c in range(n_read):
        sample[c] = y_read[c]
        sample[n_read + c] = 0.0 if np.isnan(r[c]) else r[c]
    theta = run_program(codes, arguments, sample, stack)
    if np.isnan(theta):
        for a in range(n_u):
            u[a] = np.nan
            trim[a] = np.nan
        return -1, -1, 0.0
    i, j, t = _weights(grid, theta)
    s = 1.0 - t
    for c in range(n_read):
        dy[c] = y_read[c] - (s * y_op[i, c] + t * y_op[j, c] if np.isnan(r[c]) else r[c])
    for a in range(n_u):
        trim[a] = s * u_op[i, a] + t * u_op[j, a]
        acc = 0.0
        for b in range(n_x):
            acc += (s * KC[i, a, b] + t * KC[j, a, b]) * x[b]
        feed = 0.0
        for c in range(n_read):
            feed += (s * KD[i, a, c] + t * KD[j, a, c]) * dy[c]
        u[a] = trim[a] + acc + feed
    return i, j, t


@numba.njit(cache=True, error_model="numpy", inline="always")
def _advance(controller, x: np.ndarray, i: int, j: int, t: float, dy: np.ndarray) -> None:
    """xc(k+1) = A(θ) xc(k) + B(θ)(y(k) − ȳ(k)) in place, at the (i, j, t) and ``dy`` of :func:`_law`."""
    KA, KB = controller[1], controller[2]
    n_x, n_read = KA.shape[1], dy.shape[0]
    s = 1.0 - t
    nxt = np.empty(n_x)
    for a in range(n_x):
        acc = 0.0
        for b in range(n_x):
            acc += (s * KA[i, a, b] + t * KA[j, a, b]) * x[b]
        for c in range(n_read):
            acc += (s * KB[i, a, c] + t * KB[j, a, c]) * dy[c]
        nxt[a] = acc
    for a in range(n_x):
        x[a] = nxt[a]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _finite(values: np.ndarray) -> bool:
    for value in values:
        if not np.isfinite(value):
            return False
    return True


@numba.njit(cache=True, error_model="numpy")
def controller_commands(controller, y_read: np.ndarray, references: np.ndarray,
                        trim_removed: bool) -> np.ndarray:
    """(n, nu) commands of the controller run from rest on the outputs it reads ``y_read`` (n, n_read),
    less its trim when ``trim_removed``; NaN after the first non-finite command (which is kept)."""
    n, n_u = y_read.shape[0], controller[6].shape[1]
    commands = np.empty((n, n_u))
    commands[:] = np.nan
    x = np.zeros(controller[1].shape[1])
    stack = np.empty(controller[7].shape[0] + 1)
    u_c, trim, dy = np.empty(n_u), np.empty(n_u), np.empty(y_read.shape[1])
    for k in range(n):
        i, j, t = _law(controller, x, y_read[k], references[k], stack, u_c, trim, dy)
        for a in range(n_u):
            commands[k, a] = u_c[a] - trim[a] if trim_removed else u_c[a]
        if not _finite(u_c):
            break
        _advance(controller, x, i, j, t, dy)
    return commands


@numba.njit(cache=True, error_model="numpy", inline="always")
def _basis(p: np.ndarray, exponents: np.ndarray, signal: np.ndarray, knot: np.ndarray,
           psi: np.ndarray) -> None:
    """ψ(p) into ``psi``: Π_i p_i^exponents[l, i] where signal[l] < 0, else |p_signal − knot|³."""
    for term in range(psi.shape[0]):
        if signal[term] < 0:
            value = 1.0
            for i in range(p.shape[0]):
                if exponents[term, i] > 0:
                    value *= p[i] ** exponents[term, i]
            psi[term] = value
        else:
            psi[term] = abs(p[signal[term]] - knot[term]) ** 3


@numba.njit(cache=True, error_model="numpy")
def simulate_loop(A, B, basis, p, computed, programs, u, extra, offset, sensor, input_map, sign_of,
                  controller, y_index, u_index, references, excitation, trim_removed, passes, diverged,
                  integrated):
    """Outputs (n, ny) of the model in the loop (module docstring), ``inf`` from a stop on.

    A (n_a, n_ψ, ny, ny), B (n_b, n_ψ, ny, nv): the model's coefficients; ``basis`` (exponents, signal,
    knot) of :func:`_basis`; p (n, n_p) the scheduling (overwritten in the columns ``computed`` by the
    programs (codes, arguments, starts) of the plant outputs, the model's plus ``offset``; in the output
    columns ``integrated`` (int64) the model's output is the increment y(k) − y(k−1) of the plant's, summed
    from rest, and the returned outputs are the plant's); ``sensor``
    (ny,) the sensor offsets o the controller reads on top of the plant outputs (it reads y + o, the
    dynamics and the scheduling act on y); u (n, nu) the record's inputs; extra (n, ·) exogenous model
    inputs; input_map (code, input, level) on u;
    sign_of the output whose velocity sign ends v (−1: none); controller (grid, A, B, C, D, y_op, u_op,
    codes, arguments) reading the plant outputs ``y_index`` and driving the inputs ``u_index``."""
    n, ny = p.shape[0], offset.shape[0]
    n_a, n_b, nv = A.shape[0], B.shape[0], B.shape[3]
    nu, n_extra = u.shape[1], extra.shape[1]
    exponents, signal, knot = basis
    codes, arguments, starts = programs
    map_kind, map_input, level = input_map
    y = np.empty((n, ny))
    y[:] = np.inf
    y_model = np.zeros((n, ny))
    a_at = np.zeros((n, n_a, ny, ny))
    b_at = np.zeros((n, n_b, ny, nv))
    v = np.zeros((n, nv))
    psi = np.empty(A.shape[1])
    stack = np.empty(max(codes.shape[0], controller[7].shape[0]) + 1)
    x = np.zeros(controller[1].shape[1])
    n_u = controller[6].shape[1]
    u_c, trim = np.empty(n_u), np.empty(n_u)
    dy, y_read = np.empty(y_index.shape[0]), np.empty(y_index.shape[0])
    past = np.zeros(ny)
    last = np.zeros(ny)
    out = np.zeros(ny)
    shift = offset.copy()  # offset plus, in the integrated columns, the plant output of the sample before
    for k in range(n):
        for r in range(ny):
            last[r] = past[r]
            out[r] = last[r] + shift[r]
        stop = False
        for q in range(passes + 1):  # the fixed-point passes, then the sample's step (q = passes)
            step = q == passes
            if step and not _within(out, offset, diverged):
                stop = True
                break
            _read(out, sensor, y_index, y_read)
            i, j, t = _law(controller, x, y_read, references[k], stack, u_c, trim, dy)
            if step:
                if not _finite(u_c):
                    stop = True
                    break
                _advance(controller, x, i, j, t, dy)
            u_k = _actuate(u[k], u_c, trim, u_index, excitation[k], trim_removed)
            if step:
                for r in range(ny):
                    y[k, r] = out[r] - offset[r]
                if passes > 0:  # sample k's scheduling and coefficients are those of the last pass
                    break
            direct = _present(k, u_k, last, A, B, exponents, signal, knot, p, computed, codes, arguments,
                              starts, shift, extra, map_kind, map_input, level, sign_of, y_model, a_at, b_at,
                              v, psi, stack, nu, n_extra)
            if not step:
                for r in range(ny):
                    last[r] = past[r] + direct[r]
                    out[r] = last[r] + shift[r]
        if stop:
            break
        for r in range(ny):
            y_model[k, r] = last[r]
        for c in integrated:
            shift[c] += last[c]
        past = _from_past(k + 1, a_at, b_at, y_model, v)
    return y


@numba.njit(cache=True, error_model="numpy", inline="always")
def _read(out, sensor, y_index, y_read):
    """The outputs the controller reads: plant output plus sensor offset at ``y_index``, into ``y_read``."""
    for c in range(y_index.shape[0]):
        y_read[c] = out[y_index[c]] + sensor[y_index[c]]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _within(out, offset, bound):
    """|out − offset| < bound on every output (False at a NaN)."""
    for r in range(out.shape[0]):
        if not abs(out[r] - offset[r]) < bound:
            return False
    return True


@numba.njit(cache=True, error_model="numpy", inline="always")
def _actuate(recorded, u_c, trim, u_index, excitation, trim_removed):
    """The plant input: the recorded one with the command (less the trim) plus r on the driven inputs."""
    u_k = recorded.copy()
    for a in range(u_index.shape[0]):
        u_k[u_index[a]] = (u_c[a] - trim[a] if trim_removed else u_c[a]) + excitation[a]
    return u_k


@numba.njit(cache=True, error_model="numpy", inline="always")
def _present(k, u_k, y_k, A, B, exponents, signal, knot, p, computed, codes, arguments, starts, offset, extra,
             map_kind, map_input, level, sign_of, y_model, a_at, b_at, v, psi, stack, nu, n_extra):
    """Scheduling, coefficients and model input of sample k for the plant input u_k and the output
    y_k last given; returns B_0(ψ(k)) v(k)."""
    ny = y_k.shape[0]
    plant = np.empty(ny)
    for r in range(ny):
        plant[r] = y_k[r] + offset[r]
    for c in range(computed.shape[0]):
        p[k, computed[c]] = run_program(codes[starts[c]:starts[c + 1]], arguments[starts[c]:starts[c + 1]],
                                        plant, stack)
    _basis(p[k], exponents, signal, knot, psi)
    for lag in range(A.shape[0]):
        for r in range(ny):
            for c in range(ny):
                acc = 0.0
                for term in range(psi.shape[0]):
                    acc += psi[term] * A[lag, term, r, c]
                a_at[k, lag, r, c] = acc
    for lag in range(B.shape[0]):
        for r in range(ny):
            for c in range(B.shape[3]):
                acc = 0.0
                for term in range(psi.shape[0]):
                    acc += psi[term] * B[lag, term, r, c]
                b_at[k, lag, r, c] = acc
    for a in range(nu):
        value = u_k[a]
        if a == map_input and map_kind == DEAD_ZONE:
            value = dead_zone(value, level)
        elif a == map_input and map_kind == SATURATION:
            value = saturation(value, level)
        v[k, a] = value
    for e in range(n_extra):
        v[k, nu + e] = extra[k, e]
    if sign_of >= 0:  # velocity_sign of the simulated output; none before the first sample
        now = y_k[sign_of]
        if k == 0:
            v[k, nu + n_extra] = 0.0
        else:
            earlier = y_model[k - 2, sign_of] if k >= 2 else y_model[0, sign_of]
            v[k, nu + n_extra] = np.sign(2 * now - 3 * y_model[k - 1, sign_of] + earlier)
    direct = np.zeros(ny)
    for r in range(ny):
        acc = 0.0
        for c in range(v.shape[1]):
            acc += b_at[k, 0, r, c] * v[k, c]
        direct[r] = acc
    return direct


@numba.njit(cache=True, error_model="numpy", inline="always")
def _from_past(k, a_at, b_at, y_model, v):
    """−Σ_i A_i(ψ(k−i)) y(k−i) + Σ_{j≥1} B_j(ψ(k−j)) v(k−j)."""
    ny = y_model.shape[1]
    past = np.zeros(ny)
    for i in range(1, min(a_at.shape[1], k) + 1):
        for r in range(ny):
            acc = 0.0
            for c in range(ny):
                acc += a_at[k - i, i - 1, r, c] * y_model[k - i, c]
            past[r] -= acc
    for j in range(1, min(b_at.shape[1] - 1, k) + 1):
        for r in range(ny):
            acc = 0.0
            for c in range(v.shape[1]):
                acc += b_at[k - j, j, r, c] * v[k - j, c]
            past[r] += acc
    return past
