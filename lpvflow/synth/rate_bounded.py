"""Rate-bounded gain-scheduled H∞ synthesis with a parameter-dependent Lyapunov function (discrete time).

One scheduling signal p(k) in [b₀, b_M] with |p(k+1) − p(k)| ≤ ν per sample (``rate_bound``; None: any
jump inside the range). The generalized plant is given at breakpoints b₀ < … < b_M and is linear in p
between them (hat functions λ_i(p): a polytope over two breakpoints, a piecewise polytope — multi-simplex
— over more, e.g. the thesis' three vertices 0, ±φ_t, §6.3); B2, C2, D12, D21 constant and D22 = 0 as
for :mod:`lpvflow.synth.hinf`.

**Conditions** (extended bounded-real lemma with a slack, de Oliveira, Geromel & Bernussou 2002, "Extended
H2 and H∞ norm characterizations and controller parametrizations for discrete-time systems", IJC 75(9);
with a parameter-dependent Lyapunov matrix and a controller depending on p(k) only, De Caigny, Camino,
Oliveira, Peres & Swevers 2012, "Gain-scheduled dynamic output feedback control for discrete-time LPV
systems", IJRNC 22(5)). With the closed loop ξ⁺ = 𝒜(p)ξ + ℬ(p)w, z = 𝒞(p)ξ + 𝒟(p)w,

    Φ(p, p⁺) = ⎡ 𝒫(p⁺)   𝒜𝒢      ℬ     0    ⎤
               ⎢ ⋆      𝒢+𝒢ᵀ−𝒫(p)  0     𝒢ᵀ𝒞ᵀ ⎥ ≻ 0   for every admissible (p, p⁺)
               ⎢ ⋆      ⋆        γI     𝒟ᵀ   ⎥
               ⎣ ⋆      ⋆        ⋆      γI   ⎦

implies (𝒢 + 𝒢ᵀ − 𝒫 ⪯ 𝒢ᵀ𝒫⁻¹𝒢) 𝒜ᵀ𝒫(p⁺)⁻¹𝒜 − 𝒫(p)⁻¹ + … ≺ 0: V(k) = ξᵀ𝒫(p(k))⁻¹ξ certifies
‖z‖₂ < γ‖w‖₂ along every scheduling trajectory with the rate bound. The slack 𝒢 is constant; with
𝒢 = [X ⋆; U ⋆], 𝒢⁻¹ = [Yᵀ ⋆; Vᵀ ⋆], 𝒯 = [I Yᵀ; 0 Vᵀ], S = YX + VU, the congruence diag(𝒯, 𝒯, I, I)
and the variables P̂ = 𝒯ᵀ𝒫𝒯, L = D_KC2X + C_KU, R = D_K, F = YB2D_K + VB_K,
Q = YAX + YB2L + VB_KC2X + VA_KU make Φ affine:

    ⎡ P̂(p⁺)   [AX + B2L   A + B2RC2 ;  Q   YA + FC2]   [B1 + B2RD21 ; YB1 + FD21]   0                    ⎤
    ⎢ ⋆        [X + Xᵀ   I + Sᵀ ;  S + I   Y + Yᵀ] − P̂(p)   0      [C1X + D12L   C1 + D12RC2]ᵀ        ⎥ ≻ 0.
    ⎢ ⋆        ⋆                                       γI                (D11 + D12RD21)ᵀ               ⎥
    ⎣ ⋆        ⋆                                       ⋆                 γI                            ⎦

P̂, L, R, F, Q are linear in λ(p) (values at the breakpoints), X, Y, S constant. The controller
(U, V from VU = S − YX by a balanced SVD)

    D_K = R,  C_K = (L − RC2X)U⁻¹,  B_K = V⁻¹(F − YB2R),  A_K = V⁻¹(Q − YAX − YB2L − VB_KC2X)U⁻¹

is then linear in λ(p) as well — the vertex controllers at the breakpoints interpolated with the plant's
own λ(p) — and depends on p(k) only.

**Exactness of the finite set of (p, p⁺).** Φ is affine in λ(p) and in λ(p⁺) separately, so on every cell
[b_i, b_{i+1}] × [b_j, b_{j+1}] it is affine in (p, p⁺) jointly, and positivity on the polygon cell ∩
{|p⁺ − p| ≤ ν} follows from its vertices: p at every breakpoint and breakpoint ± ν, p⁺ at p ± ν (clipped
to the range) and at the breakpoints between (:meth:`Schedule.pairs`). With ν = None, p⁺ is every
breakpoint. Nothing is gridded, so nothing is missed between grid points; :func:`fine_check` re-checks
Φ on a grid ten times finer anyway, and against the true plant when it is not linear between breakpoints.

**Numerics.** The LMIs are posed in the coordinates of :func:`lpvflow.synth.hinf.balanced_coordinates`
for the plant at the breakpoint nearest the centre (a state transform that balances the interior
Lyapunov matrices of a frozen design, and u/y scalings; the state transform commutes with the Cayley
map, so it is the discrete one too); strictness is Φ ⪰ t·I with the margin t maximised at each γ level
(t ≤ 1), the level search is :func:`lpvflow.synth.hinf.lowest_certified_level` on the γ minimum of the
same LMIs, and a level passes only when the reconstructed controller's Φ, rebuilt from the returned
discrete numbers, is positive definite at every (p, p⁺) with a Jacobi-scaled margin above round-off
(:data:`lpvflow.synth.hinf.ROUNDOFF_FACTOR`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.synth.hinf import (
    ROUNDOFF_FACTOR,
    _cayley_vertex,
    _Coordinates,
    balanced_coordinates,
    closed_loop,
    lowest_certified_level,
)
from lpvflow.synth.plant import VertexPlant, check_a3
from lpvflow.synth.sdp import SolveReport, SynthesisError, solve

#: Points per breakpoint interval of :func:`fine_check` (the issue's "10× finer" than the breakpoints).
FINE_PER_SEGMENT = 10


@dataclass(frozen=True)
class Schedule:
    """Breakpoints of the scheduling signal and the rate bound ν (per sample; None: arbitrary)."""

    breakpoints: np.ndarray
    rate_bound: float | None

    def __post_init__(self) -> None:
        b = np.asarray(self.breakpoints, dtype=float).reshape(-1)
        object.__setattr__(self, "breakpoints", b)
        if len(b) < 2 or not np.all(np.diff(b) > 0):
            raise ModelError(f"breakpoints must be at least two ascending values, got {b.tolist()}")
        if self.rate_bound is not None and not self.rate_bound > 0:
            raise ModelError(f"rate_bound must be positive (per sample) or None, got {self.rate_bound!r}")

    def weights(self, p: float) -> np.ndarray:
        """λ(p): hat functions of the breakpoints (p clamped to the range); Σλ = 1, at most two nonzero."""
        b = self.breakpoints
        p = float(np.clip(p, b[0], b[-1]))
        i = min(int(np.searchsorted(b, p, side="right")) - 1, len(b) - 2)
        t = (p - b[i]) / (b[i + 1] - b[i])
        lam = np.zeros(len(b))
        lam[i], lam[i + 1] = 1.0 - t, t
        return lam

    def pairs(self, points: Sequence[float] = ()) -> list[tuple[float, list[float]]]:
        """(p, [p⁺, …]) at which Φ is imposed (module docstring), plus ``points`` as extra p."""
        b, nu = self.breakpoints, self.rate_bound
        lo, hi = b[0], b[-1]
        if nu is None:
            return [(float(p), [float(q) for q in b]) for p in np.unique(np.concatenate([b, points]))]
        ps = np.unique(np.clip(np.concatenate([b, b - nu, b + nu, np.asarray(points, float)]), lo, hi))
        out = []
        for p in ps:
            inside = b[(b > p - nu) & (b < p + nu)]
            nxt = np.unique(np.concatenate([[max(p - nu, lo), min(p + nu, hi)], inside]))
            out.append((float(p), [float(q) for q in nxt]))
        return out


@dataclass
class ScheduledResult:
    """Certified rate-bounded design.

    Attributes:
        gamma: the certified level; gamma_min: minimum of the same LMIs (no controller of this class,
            with these breakpoints and rate bound, does better).
        K_vertices: discrete vertex controllers (A_K, B_K, C_K, D_K) from y to u at the breakpoints.
        schedule: breakpoints and rate bound; vertices: the generalized plant at the breakpoints.
        lyapunov: 𝒫 at the breakpoints (inverse Lyapunov matrices, state [x̄; x_K] in ``coordinates``);
            slack: 𝒢; coordinates: the state transform 𝒯_c = blkdiag(T, I) with ξ = 𝒯_c ξ̄.
        margins: certificate margin at every (p, p⁺) of the design (all > 0).
    """

    gamma: float
    gamma_min: float
    K_vertices: list[tuple[np.ndarray, ...]]
    schedule: Schedule
    vertices: list[VertexPlant]
    Ts: float
    lyapunov: list[np.ndarray]
    slack: np.ndarray
    coordinates: np.ndarray
    margins: list[float]
    report: SolveReport = field(default_factory=lambda: SolveReport("", "", 0.0))

    def controller_at(self, p: float) -> tuple[np.ndarray, ...]:
        """(A_K, B_K, C_K, D_K) at p: Σ λ_i(p) K_i."""
        lam = self.schedule.weights(p)
        return tuple(sum(li * K[m] for li, K in zip(lam, self.K_vertices, strict=True)) for m in range(4))

    def lyapunov_at(self, p: float) -> np.ndarray:
        lam = self.schedule.weights(p)
        return sum(li * P for li, P in zip(lam, self.lyapunov, strict=True))

    def plant_at(self, p: float) -> VertexPlant:
        lam = self.schedule.weights(p)
        return VertexPlant(**{k: sum(li * getattr(v, k) for li, v in zip(lam, self.vertices, strict=True))
                              for k in VertexPlant.__dataclass_fields__})


# ---------------------------------------------------------------------------------- coordinates
def _discrete(coords: _Coordinates, v: VertexPlant) -> VertexPlant:
    """The discrete vertex in the state/u/y coordinates of ``coords`` (no frequency scaling)."""
    T, du, dy = coords.T, coords.du, coords.dy
    Ti = np.linalg.inv(T)
    return VertexPlant(Ti @ v.A @ T, Ti @ v.B1, Ti @ v.B2 * du, v.C1 @ T, (v.C2 @ T) / dy[:, None], v.D11,
                       v.D12 * du, v.D21 / dy[:, None], v.D22 * du / dy[:, None])


def _unscaled(coords: _Coordinates, K: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """The controller from y to u of one designed from ȳ to ū (same state)."""
    Ak, Bk, Ck, Dk = K
    du, dy = coords.du, coords.dy
    return Ak, Bk / dy[None, :], du[:, None] * Ck, du[:, None] * Dk / dy[None, :]


# ------------------------------------------------------------------------------------------ LMIs
class _Levels:
    """Φ of the module docstring at every pair, in scaled coordinates; γ a Parameter (margin problem) or a
    Variable (γ minimum)."""

    def __init__(self, verts: list[VertexPlant], schedule: Schedule, pairs: list) -> None:
        n, nw, nu, nz, ny = verts[0].dims
        M = len(verts)
        self.gamma, self.t = cp.Parameter(pos=True), cp.Variable()
        self.g_min = cp.Variable()
        self.X, self.Y, self.S = (cp.Variable((n, n)) for _ in range(3))
        self.P = [cp.Variable((2 * n, 2 * n), symmetric=True) for _ in range(M)]
        self.L = [cp.Variable((nu, n)) for _ in range(M)]
        self.R = [cp.Variable((nu, ny)) for _ in range(M)]
        self.F = [cp.Variable((n, ny)) for _ in range(M)]
        self.Q = [cp.Variable((n, n)) for _ in range(M)]
        self.verts, self.schedule, self.pairs = verts, schedule, pairs
        margin_rows, minimum_rows = [], []
        for p, nexts in pairs:
            for q in nexts:
                margin_rows.append(self._phi(p, q, self.gamma))
                minimum_rows.append(self._phi(p, q, self.g_min))
        self.margin_problem = cp.Problem(cp.Maximize(self.t), [Phi >> self.t * np.eye(Phi.shape[0])
                                                                for Phi in margin_rows] + [self.t <= 1])
        self.minimum_problem = cp.Problem(cp.Minimize(self.g_min), [Phi >> 0 for Phi in minimum_rows])

    def _mix(self, mats: list, lam: np.ndarray):
        return sum(float(li) * M for li, M in zip(lam, mats, strict=True) if li != 0.0)

    def _phi(self, p: float, q: float, gamma) -> cp.Expression:
        lam, lam_next = self.schedule.weights(p), self.schedule.weights(q)
        v = VertexPlant(**{k: sum(li * getattr(w, k) for li, w in zip(lam, self.verts, strict=True))
                           for k in VertexPlant.__dataclass_fields__})
        n, nw, _, nz, _ = v.dims
        X, Y, S = self.X, self.Y, self.S
        L, R, F, Q = (self._mix(m, lam) for m in (self.L, self.R, self.F, self.Q))
        I = np.eye(n)
        Acl = cp.bmat([[v.A @ X + v.B2 @ L, v.A + v.B2 @ R @ v.C2], [Q, Y @ v.A + F @ v.C2]])
        Bcl = cp.vstack([v.B1 + v.B2 @ R @ v.D21, Y @ v.B1 + F @ v.D21])
        Ccl = cp.hstack([v.C1 @ X + v.D12 @ L, v.C1 + v.D12 @ R @ v.C2])
        Dcl = v.D11 + v.D12 @ R @ v.D21
        G = cp.bmat([[X + X.T, I + S.T], [S + I, Y + Y.T]])
        Phi = cp.bmat([
            [self._mix(self.P, lam_next), Acl, Bcl, np.zeros((2 * n, nz))],
            [Acl.T, G - self._mix(self.P, lam), np.zeros((2 * n, nw)), Ccl.T],
            [Bcl.T, np.zeros((nw, 2 * n)), gamma * np.eye(nw), Dcl.T],
            [np.zeros((nz, 2 * n)), Ccl, Dcl, gamma * np.eye(nz)],
        ])
        return 0.5 * (Phi + Phi.T)


def phi_matrix(plant: VertexPlant, K: tuple[np.ndarray, ...], P: np.ndarray, P_next: np.ndarray,
               G: np.ndarray, gamma: float) -> np.ndarray:
    """Φ(p, p⁺) of the module docstring from a closed loop's numbers (state [x; x_K])."""
    A, B, C, D = closed_loop(plant, K)
    nw, nz, m = B.shape[1], C.shape[0], A.shape[0]
    return np.block([[P_next, A @ G, B, np.zeros((m, nz))],
                     [G.T @ A.T, G + G.T - P, np.zeros((m, nw)), G.T @ C.T],
                     [B.T, np.zeros((nw, m)), gamma * np.eye(nw), D.T],
                     [np.zeros((nz, m)), C @ G, D, gamma * np.eye(nz)]])


def phi_margin(Phi: np.ndarray) -> float:
    """λ_min of the Jacobi-scaled Φ minus the round-off bound ROUNDOFF_FACTOR·m·ε·‖|Φ̃|‖₂ (> 0: holds)."""
    Phi = 0.5 * (Phi + Phi.T)
    d = np.sqrt(np.clip(np.abs(np.diag(Phi)), 1e-300, None))
    Pt = Phi / d[:, None] / d[None, :]
    roundoff = ROUNDOFF_FACTOR * len(Pt) * np.finfo(float).eps * np.linalg.norm(np.abs(Pt), 2)
    return float(np.linalg.eigvalsh(Pt)[0] - roundoff)


def _scaled_loop_plant(coords: _Coordinates, v: VertexPlant) -> VertexPlant:
    """The original discrete vertex with only its state transformed (x = T x̄): u, y unscaled, so the
    returned (unscaled) controller closes the loop on it."""
    Ti = np.linalg.inv(coords.T)
    return VertexPlant(Ti @ v.A @ coords.T, Ti @ v.B1, Ti @ v.B2, v.C1 @ coords.T, v.C2 @ coords.T, v.D11,
                       v.D12, v.D21, v.D22)


def _reconstruct(levels: _Levels, vertices: list[VertexPlant], coords: _Coordinates, schedule: Schedule,
                 gamma: float, gamma_min: float, Ts: float) -> ScheduledResult:
    """Controller of the module docstring at every breakpoint, 𝒫 and 𝒢 in the scaled state, and the
    certificate margins rebuilt from the returned discrete numbers."""
    X, Y, S = (np.asarray(V.value, dtype=float) for V in (levels.X, levels.Y, levels.S))
    n = X.shape[0]
    W, sig, Zt = np.linalg.svd(S - Y @ X)
    V, U = W * np.sqrt(sig), np.sqrt(sig)[:, None] * Zt
    K_vertices = []
    for i, v in enumerate(levels.verts):
        L, R, F, Q = (np.asarray(m[i].value, dtype=float) for m in (levels.L, levels.R, levels.F, levels.Q))
        Dk = R
        Ck = np.linalg.solve(U.T, (L - R @ v.C2 @ X).T).T
        Bk = np.linalg.solve(V, F - Y @ v.B2 @ R)
        core = Q - Y @ v.A @ X - Y @ v.B2 @ L - V @ Bk @ v.C2 @ X
        Ak = np.linalg.solve(V, np.linalg.solve(U.T, core.T).T)
        K_vertices.append(_unscaled(coords, (Ak, Bk, Ck, Dk)))
    Tcal = np.block([[np.eye(n), Y.T], [np.zeros((n, n)), V.T]])
    Tinv = np.linalg.inv(Tcal)
    G = np.block([[X, np.eye(n)], [U, np.zeros((n, n))]]) @ Tinv
    lyapunov = [Tinv.T @ (0.5 * (P.value + P.value.T)) @ Tinv for P in levels.P]
    result = ScheduledResult(gamma, gamma_min, K_vertices, schedule, vertices, Ts, lyapunov, G,
                             np.asarray(coords.T), [])
    scaled = [_scaled_loop_plant(coords, v) for v in vertices]
    plant = ScheduledResult(gamma, gamma_min, K_vertices, schedule, scaled, Ts, lyapunov, G, coords.T, [])
    result.margins = [phi_margin(phi_matrix(plant.plant_at(p), result.controller_at(p), result.lyapunov_at(p),
                                            result.lyapunov_at(q), G, gamma))
                      for p, nexts in levels.pairs for q in nexts]
    return result


def synthesize_scheduled(vertices: list[VertexPlant], breakpoints: Sequence[float], Ts: float, *,
                         rate_bound: float | None, suboptimality: float = 1e-2, solver: str = "CLARABEL",
                         points: Sequence[float] = ()) -> ScheduledResult:
    """Rate-bounded parameter-dependent-Lyapunov H∞ design (module docstring) on vertex plants at the
    breakpoints; ``points`` adds scheduling values at which Φ is also imposed.

    Raises:
        ModelError: breakpoints that do not match the vertices, or B2, C2, D12, D21 not constant.
        SynthesisError: infeasible LMIs, or no level whose controller passes the certificate.
    """
    schedule = Schedule(np.asarray(breakpoints, dtype=float), rate_bound)
    if len(vertices) != len(schedule.breakpoints):
        raise ModelError(f"{len(vertices)} vertex plants for {len(schedule.breakpoints)} breakpoints")
    check_a3(vertices)
    start = time.perf_counter()
    centre = int(np.argmin(np.abs(schedule.breakpoints - schedule.breakpoints.mean())))
    coords, _, _, attempts = balanced_coordinates([_cayley_vertex(vertices[centre])], None, solver)
    verts = [_discrete(coords, v) for v in vertices]
    levels = _Levels(verts, schedule, schedule.pairs(points))
    what = (f"the rate-bounded H∞ LMIs ({len(verts)} breakpoints, "
            f"ν = {'any' if rate_bound is None else f'{rate_bound:g}'} per sample)")
    report = solve(levels.minimum_problem, solver, what)
    attempts += report.attempts
    gamma_min = float(levels.g_min.value)

    def certified(gamma: float) -> ScheduledResult | None:
        levels.gamma.value = gamma
        try:
            level_report = solve(levels.margin_problem, solver, f"{what} at γ = {gamma:.6g}")
        except SynthesisError:
            return None
        attempts.extend(level_report.attempts)
        try:
            result = _reconstruct(levels, vertices, coords, schedule, gamma, gamma_min, Ts)
        except np.linalg.LinAlgError:
            return None
        return result if min(result.margins) > 0 else None

    best = lowest_certified_level(certified, gamma_min, suboptimality, None)
    if best is None:
        raise SynthesisError(f"{what}: γ minimum {gamma_min:.4g}, but no level up to "
                             f"{gamma_min * (1 + suboptimality * 2 ** 8):.4g} gave a controller that passes the "
                             "certificate; loosen the weights or the rate bound")
    best.report = SolveReport(solver, "optimal", time.perf_counter() - start, attempts)
    return best


def fine_check(result: ScheduledResult, plant_at: Callable[[float], VertexPlant] | None = None,
               per_segment: int = FINE_PER_SEGMENT) -> tuple[float, float]:
    """(smallest margin, where) of Φ on a grid ``per_segment`` times finer than the breakpoints, with
    p⁺ = p ± ν (clipped) and the breakpoints between: the design's own piecewise-linear plant, or
    ``plant_at(p)`` (the true plant, e.g. exact linearizations) with the interpolated controller."""
    b = result.schedule.breakpoints
    fine = np.unique(np.concatenate([np.linspace(b[i], b[i + 1], per_segment + 1) for i in range(len(b) - 1)]))
    Tc = np.linalg.inv(result.coordinates)
    worst = (np.inf, float(fine[0]))
    for p, nexts in result.schedule.pairs(fine):
        v = result.plant_at(p) if plant_at is None else plant_at(p)
        v = VertexPlant(Tc @ v.A @ result.coordinates, Tc @ v.B1, Tc @ v.B2, v.C1 @ result.coordinates,
                        v.C2 @ result.coordinates, v.D11, v.D12, v.D21, v.D22)
        K = result.controller_at(p)
        for q in nexts:
            m = phi_margin(phi_matrix(v, K, result.lyapunov_at(p), result.lyapunov_at(q), result.slack,
                                      result.gamma))
            worst = min(worst, (m, p))
    return worst
