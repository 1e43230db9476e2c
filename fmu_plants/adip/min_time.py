"""Minimum-time transfer between two equilibria of a plant whose input is bounded and zero-order held.

Problem solved (direct multiple shooting, Bock & Plitt 1984), for ẋ = f(x, u, p), x ∈ Rⁿ, u ∈ Rᵐ:

    minimise    T
    over        T,  u_0 … u_{N−1},  x_1 … x_{N−1}   (and x_N when a terminal band is given)
    subject to  x_{k+1} = Φ(x_k, u_k, T/N)   for k = 0 … N−1,   x_0 = x0,
                x_N = xf                      (exact rest; or |x_N − xf| ≤ band, elementwise),
                |u_k| ≤ vmax                  (elementwise),
                lo_k ≤ x_k ≤ hi_k, k = 1 … N−1  (optional path bounds, at the nodes only),

with u(t) = u_k on [k h, (k+1) h), h = T/N (N equal intervals, zero-order hold), and Φ(x, u, h) =
s classical RK4 steps of length h/s, s chosen so that h/s ≤ max_substep. The plant rests at the
equilibrium (x0, u_eq0) before t = 0 and is held at (xf, u_eq_f) after T, so |u_eq_f| ≤ vmax is
necessary; otherwise `minimum_time_transfer` raises ValueError. With `duration` given, T is fixed
and the objective becomes the input energy h Σ|u_k|² (a feasibility problem with a regulariser).

The interval length h is free, so T is not quantised by the grid; N is made round(T/interval) by
solving again on that many intervals, warm-started from the previous solution, until it holds (at
most `max_regrids` times; not with node-by-node path bounds), so h stays within ±4 % of `interval`
for N ≥ 12 and results from different starts are comparable. The defects' Jacobians are exact to
rounding: complex step (Im Φ(z + iε e_j)/ε, ε = 1e-30) through the RK4 map, every interval and
direction in one batched evaluation, so `f` must accept x of shape (n, K), u of shape (m, K),
complex values, and return (n, K). The NLP is solved by scipy's SLSQP (ftol 1e-12) in the scaled
variables u/vmax and x/state_scale; a solution is accepted when SLSQP reports success, the largest
defect is below 1e-8 and |u| ≤ vmax. SLSQP finds a local minimum: start it from several guesses.

For the ADIP (fmu_plants/adip/README.md, "Equations"): x = (φ1, φ2, ω1, ω2), u = (V,),
f = `reference_models.adip_derivatives` (it takes columns of points), x0 = 0, xf = (φt, 0, 0, 0),
u_eq = V_eq(φ) = −d1 sin φ / k_τ, and `ADIP_STATE_SCALE` (rates ~10× the angles) halves SLSQP's iterations.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import Bounds, minimize

BatchModel = Callable[[np.ndarray, np.ndarray, dict], np.ndarray]
STEP = 1e-30  # complex step
DEFECT_TOLERANCE = 1e-8
ADIP_STATE_SCALE = np.array([1.0, 1.0, 10.0, 10.0])  # rad, rad, rad/s, rad/s


@dataclass(frozen=True)
class Transfer:
    """A solution of the module docstring's problem: u_k held on [grid[k], grid[k+1])."""

    T: float
    grid: np.ndarray  # (N + 1,) node times, grid[0] = 0, grid[N] = T
    voltage: np.ndarray  # (N, m) input of every interval
    states: np.ndarray  # (N + 1, n) states at the nodes
    substeps: int  # RK4 steps per interval
    success: bool  # SLSQP success, max_defect < DEFECT_TOLERANCE and |u| ≤ vmax
    status: str
    max_defect: float  # largest |x_{k+1} − Φ(x_k, u_k, h)| (x_N = xf for an exact target)
    iterations: int  # SLSQP iterations, summed over the re-gridding rounds

    @property
    def interval(self) -> float:
        return float(self.grid[1] - self.grid[0])


@dataclass(frozen=True)
class _Problem:
    """One NLP; decision vector [T?, u_0..u_{N−1} / vmax, (x_1..x_{N−1}, x_N?) / scale]."""

    f: BatchModel
    p: dict
    x0: np.ndarray
    xf: np.ndarray
    vmax: np.ndarray
    intervals: int
    substeps: int
    duration: float | None  # fixed T, or None when T is a decision variable
    band: np.ndarray | None  # terminal half-widths, or None for x_N = xf
    path: tuple[np.ndarray, np.ndarray]  # (lo, hi) of x_1 … x_{N−1}: shape (n,) for all, or (N − 1, n)
    scale: np.ndarray

    @property
    def n(self) -> int:
        return len(self.x0)

    @property
    def m(self) -> int:
        return len(self.vmax)

    @property
    def offset(self) -> int:
        """Index of u_0 in the decision vector."""
        return 0 if self.duration is not None else 1

    @property
    def free_states(self) -> int:
        return self.intervals - (0 if self.band is not None else 1)

    def unpack(self, z: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """(T, u (m, N), x (n, N + 1)) from the decision vector."""
        N, n, m = self.intervals, self.n, self.m
        T = self.duration if self.duration is not None else float(z[0])
        u = z[self.offset : self.offset + N * m].reshape(N, m).T * self.vmax[:, None]
        inner = z[self.offset + N * m :].reshape(self.free_states, n).T * self.scale[:, None]
        last = [] if self.band is not None else [self.xf[:, None]]
        return T, u, np.hstack([self.x0[:, None], inner, *last])

    def pack(self, T: float, u: np.ndarray, x: np.ndarray) -> np.ndarray:
        head = [] if self.duration is not None else [[T]]
        states = x[:, 1 : 1 + self.free_states] / self.scale[:, None]
        return np.concatenate([*head, (u / self.vmax[:, None]).T.ravel(), states.T.ravel()])

    def bounds(self, interval: float, max_substep: float) -> Bounds:
        """T ∈ [N interval/4, N s max_substep] (sub-steps ≤ max_substep), |u| ≤ vmax, path, band."""
        N = self.intervals
        lower, upper = [np.full(N * self.m, -1.0)], [np.full(N * self.m, 1.0)]
        if self.duration is None:
            lower.insert(0, [N * interval / 4])
            upper.insert(0, [N * self.substeps * max_substep])
        for side, bound in zip((lower, upper), self.path, strict=True):
            side.append((np.broadcast_to(bound, (N - 1, self.n)) / self.scale).ravel())
        if self.band is not None:
            lower.append((self.xf - self.band) / self.scale)
            upper.append((self.xf + self.band) / self.scale)
        return Bounds(np.concatenate(lower), np.concatenate(upper))


def rk4(
    f: BatchModel, x: np.ndarray, u: np.ndarray, dt: np.ndarray | float, substeps: int, p: dict
) -> np.ndarray:
    """`substeps` RK4 steps of length dt (one per column, or a scalar) with u held; x (n, K), u (m, K)."""
    for _ in range(substeps):
        k1 = f(x, u, p)
        k2 = f(x + dt / 2 * k1, u, p)
        k3 = f(x + dt / 2 * k2, u, p)
        k4 = f(x + dt * k3, u, p)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def simulate(
    f: BatchModel, x0: np.ndarray, voltage: np.ndarray, interval: float, substeps: int, p: dict
) -> tuple[np.ndarray, np.ndarray]:
    """Times and states (N·substeps + 1, n) of the zero-order-held input (N, m), at every RK4 sub-step."""
    dt = interval / substeps
    x = np.asarray(x0, dtype=float)[:, None]
    states = [x[:, 0]]
    for u in np.asarray(voltage, dtype=float):
        for _ in range(substeps):
            x = rk4(f, x, u[:, None], dt, 1, p)
            states.append(x[:, 0])
    return dt * np.arange(len(states)), np.array(states)


def _shoot(problem: _Problem, z: np.ndarray) -> tuple[np.ndarray, ...]:
    """Φ(x_k, u_k, h) (n, N) and its derivatives by x (n, N, n), u (n, N, m) and T (n, N), complex step."""
    T, u, x = problem.unpack(z)
    n, m, N, s = problem.n, problem.m, problem.intervals, problem.substeps
    directions = n + m + 1
    xc = np.repeat(x[:, :N, None], directions, axis=2).astype(complex)
    uc = np.repeat(u[:, :, None], directions, axis=2).astype(complex)
    dt = np.full((N, directions), T / (N * s), dtype=complex)
    xc[:, :, :n] += 1j * STEP * np.eye(n)[:, None, :]
    uc[:, :, n : n + m] += 1j * STEP * np.eye(m)[:, None, :]
    dt[:, -1] += 1j * STEP / (N * s)
    end = rk4(problem.f, xc.reshape(n, -1), uc.reshape(m, -1), dt.ravel(), s, problem.p).reshape(n, N, -1)
    sensitivity = end.imag / STEP
    return end[:, :, 0].real, sensitivity[:, :, :n], sensitivity[:, :, n : n + m], sensitivity[:, :, -1]


class _Defects:
    """x_{k+1} − Φ(x_k, u_k, h) stacked by interval, and its Jacobian, both from one cached `_shoot`."""

    def __init__(self, problem: _Problem) -> None:
        self.problem = problem
        self._z: np.ndarray | None = None

    def _evaluate(self, z: np.ndarray) -> None:
        if self._z is not None and np.array_equal(z, self._z):
            return
        self._z = z.copy()
        pb = self.problem
        n, m, N = pb.n, pb.m, pb.intervals
        end, d_x, d_u, d_T = _shoot(pb, z)
        self.value = (pb.unpack(z)[2][:, 1:] - end).T.ravel()
        jac = np.zeros((N, n, len(z)))
        k = np.arange(N)
        u_columns = pb.offset + k[:, None] * m + np.arange(m)  # (N, m)
        jac[k[:, None, None], np.arange(n)[None, :, None], u_columns[:, None, :]] = (
            -np.moveaxis(d_u, 1, 0) * pb.vmax
        )
        if pb.duration is None:
            jac[:, :, 0] = -d_T.T
        first_state = pb.offset + N * m
        x_columns = first_state + (k[:, None] - 1) * n + np.arange(n)  # columns of x_k, k ≥ 1
        inner = k[1:]
        jac[inner[:, None, None], np.arange(n)[None, :, None], x_columns[inner][:, None, :]] = (
            -np.moveaxis(d_x[:, inner, :], 1, 0) * pb.scale
        )
        free = np.arange(pb.free_states)  # intervals whose end x_{k+1} is a decision variable
        jac[free[:, None], np.arange(n), first_state + free[:, None] * n + np.arange(n)] = pb.scale
        self.jacobian = jac.reshape(N * n, len(z))

    def __call__(self, z: np.ndarray) -> np.ndarray:
        self._evaluate(z)
        return self.value

    def jac(self, z: np.ndarray) -> np.ndarray:
        self._evaluate(z)
        return self.jacobian


def _objective(problem: _Problem) -> tuple[Callable, Callable]:
    """T (free time) or h Σ|u_k|² (fixed time), and its gradient, in the decision vector."""
    if problem.duration is None:
        return (lambda z: float(z[0])), (lambda z: np.eye(1, len(z))[0])
    weight = problem.duration / problem.intervals * np.tile(problem.vmax**2, problem.intervals)
    inputs = slice(0, problem.intervals * problem.m)

    def gradient(z: np.ndarray) -> np.ndarray:
        g = np.zeros_like(z)
        g[inputs] = 2 * weight * z[inputs]
        return g

    return (lambda z: float(weight @ z[inputs] ** 2)), gradient


def smoothstep_guess(
    x0: np.ndarray, xf: np.ndarray, u0: np.ndarray, uf: np.ndarray, N: int
) -> tuple[np.ndarray, np.ndarray]:
    """Input (m, N) and node states (n, N + 1) moving from (x0, u0) to (xf, uf) along 3s² − 2s³."""

    def ramp(s: np.ndarray) -> np.ndarray:
        return s * s * (3 - 2 * s)

    nodes = ramp(np.linspace(0.0, 1.0, N + 1))
    middles = ramp((np.arange(N) + 0.5) / N)
    return np.outer(u0, 1 - middles) + np.outer(uf, middles), np.outer(x0, 1 - nodes) + np.outer(xf, nodes)


def _regrid(transfer: Transfer, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Input (m, N) and node states (n, N + 1) of `transfer` resampled on N equal intervals."""
    nodes = np.linspace(0.0, transfer.T, N + 1)
    middles = (nodes[:-1] + nodes[1:]) / 2
    index = np.minimum(np.searchsorted(transfer.grid, middles, side="right") - 1, len(transfer.voltage) - 1)
    states = np.array([np.interp(nodes, transfer.grid, column) for column in transfer.states.T])
    return transfer.voltage[index].T, states


def _solve(
    problem: _Problem,
    T: float,
    u: np.ndarray,
    x: np.ndarray,
    interval: float,
    max_substep: float,
    max_iterations: int,
) -> Transfer:
    defects = _Defects(problem)
    objective, gradient = _objective(problem)
    bounds = problem.bounds(interval, max_substep)
    z0 = np.clip(problem.pack(T, u, x), bounds.lb, bounds.ub)
    out = minimize(
        objective,
        z0,
        jac=gradient,
        method="SLSQP",
        bounds=bounds,
        constraints=[{"type": "eq", "fun": defects, "jac": defects.jac}],
        options={"ftol": 1e-12, "maxiter": max_iterations},
    )
    T, u, x = problem.unpack(out.x)
    max_defect = float(np.max(np.abs(defects(out.x))))
    within = bool(np.all(np.abs(u) <= problem.vmax[:, None] * (1 + 1e-12)))
    return Transfer(
        T=T,
        grid=np.linspace(0.0, T, problem.intervals + 1),
        voltage=u.T.copy(),
        states=x.T.copy(),
        substeps=problem.substeps,
        success=bool(out.success) and max_defect < DEFECT_TOLERANCE and within,
        status=f"SLSQP: {out.message} (max defect {max_defect:.1e})",
        max_defect=max_defect,
        iterations=int(out.nit),
    )


def _numbers(values: np.ndarray) -> str:
    return ", ".join(f"{v:.4g}" for v in values)


def minimum_time_transfer(
    f: BatchModel,
    x0: np.ndarray,
    xf: np.ndarray,
    u_eq0: np.ndarray,
    u_eq_f: np.ndarray,
    vmax: float | np.ndarray,
    p: dict,
    *,
    interval: float = 0.02,
    max_substep: float = 1e-3,
    T_guess: float = 1.5,
    guess: tuple[np.ndarray, np.ndarray] | None = None,
    band: np.ndarray | None = None,
    path: tuple[np.ndarray, np.ndarray] | None = None,
    duration: float | None = None,
    state_scale: np.ndarray | None = None,
    max_iterations: int = 1000,
    max_regrids: int = 3,
) -> Transfer:
    """Solve the module docstring's problem from rest at (x0, u_eq0) to rest at (xf, u_eq_f).

    `guess` = (input (m, N), node states (n, N + 1)) on N equal intervals spanning T_guess; default
    `smoothstep_guess` on N = round(T_guess/interval). `band`: terminal half-widths instead of
    x_N = xf. `path`: (lo, hi) bounds of the nodes x_1 … x_{N−1} (±inf where free), each of shape
    (n,), or (N − 1, n) node by node (then N stays that of `guess`: no re-gridding). `duration`: fixed
    T (no re-gridding). `state_scale`: typical magnitude of each state (default 1).
    Raises ValueError when |u_eq0| or |u_eq_f| exceeds vmax: the plant cannot be held there.
    """
    x0, xf = np.asarray(x0, dtype=float), np.asarray(xf, dtype=float)
    u_eq0, u_eq_f = (
        np.atleast_1d(np.asarray(u_eq0, dtype=float)),
        np.atleast_1d(np.asarray(u_eq_f, dtype=float)),
    )
    vmax = np.broadcast_to(np.asarray(vmax, dtype=float), u_eq_f.shape).copy()
    for name, u_eq in (("target", u_eq_f), ("start", u_eq0)):
        if np.any(np.abs(u_eq) > vmax):
            raise ValueError(
                f"vmax = {_numbers(vmax)} is below the holding voltage |u_eq| = "
                f"{_numbers(np.abs(u_eq))} of the {name} equilibrium: the plant cannot rest there"
            )
    n = len(x0)
    path = path if path is not None else (np.full(n, -np.inf), np.full(n, np.inf))
    scale = np.ones(n) if state_scale is None else np.asarray(state_scale, dtype=float)
    band = None if band is None else np.asarray(band, dtype=float)
    T = duration if duration is not None else T_guess
    u, x = (
        guess if guess is not None else smoothstep_guess(x0, xf, u_eq0, u_eq_f, max(2, round(T / interval)))
    )
    iterations = 0
    for _ in range(max_regrids + 1):
        N = u.shape[1]
        h_max = T / N if duration is not None else 1.25 * interval
        problem = _Problem(
            f, p, x0, xf, vmax, N, math.ceil(h_max / max_substep - 1e-9), duration, band, path, scale
        )
        transfer = _solve(problem, T, u, x, interval, max_substep, max_iterations)
        iterations += transfer.iterations
        N_new = max(2, round(transfer.T / interval))
        if duration is not None or N_new == N or np.ndim(path[0]) == 2:
            break
        T = transfer.T
        u, x = _regrid(transfer, N_new)
    return replace(transfer, iterations=iterations)
