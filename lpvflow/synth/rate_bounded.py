"""Rate-bounded gain-scheduled H∞ synthesis with a parameter-dependent Lyapunov function (discrete time).

One scheduling signal p(k) in [b₀, b_M] with |p(k+1) − p(k)| ≤ ν per sample (``rate_bound``; None: any
jump inside the range). The generalized plant is given at breakpoints b₀ < … < b_M and is linear in p
between them (hat functions λ_i(p): a polytope over two breakpoints, a piecewise polytope — multi-simplex
— over more, e.g. the thesis' three vertices 0, ±φ_t, §6.3); B2, C2, D12, D21 constant and D22 = 0 as
for :mod:`lpvflow.synth.vertex_synthesis`.

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

**δ form** (what the solver sees). With a small Ts, A ≈ I and Φ carries its information in O(h)
differences of O(1) blocks (h the dimensionless step of :func:`delta_step`). The constant congruence
W = [I −cI 0 0; 0 cI 0 0; 0 0 I 0; 0 0 0 I], c = 1/√h, changes no definiteness and gives, with
Γ = [X I; S Y] (so 𝒢 + 𝒢ᵀ of the slack is Γ + Γᵀ), A' = (A − I)/h, B2' = B2/h formed once in floating
point, and the variables Q = S + h·Q_δ, F = h·F_δ (so every variable the solver sees is O(1)),

    E = (𝒜𝒢 − Γ)/h = [A'X + B2'L   A' + B2'RC2 ;  Q_δ   YA' + F_δC2],

    WᵀΦW = ⎡ P̂(p⁺)   (Γ − P̂(p⁺))/√h + √h·E    ℬ      0    ⎤
           ⎢ ⋆      (P̂(p⁺) − P̂(p))/h − E − Eᵀ  −ℬ/√h   𝒞ᵀ/√h ⎥
           ⎢ ⋆      ⋆                        γI      𝒟ᵀ   ⎥
           ⎣ ⋆      ⋆                        ⋆       γI   ⎦

(ℬ = [B1 + B2RD21; YB1 + hF_δD21], 𝒞 = [C1X + D12L  C1 + D12RC2], 𝒟 = D11 + D12RD21): the O(h)
differences 𝒜𝒢 − Γ and P̂(p⁺) − P̂(p) enter divided by h, formed from A' algebraically rather than by the
solver from O(1) numbers. The controller and the certificate are those of the shift form (Q, F above).

**One large LMI per p.** p⁺ enters WᵀΦW only through e·P̂(p⁺)·eᵀ, e = [I; −I/√h; 0; 0]. With a variable
Z_p per distinct p, the LMIs Ψ(p; Z_p) ≻ 0 — WᵀΦW with (P̂(p⁺) − P̂(p))/h replaced by Z_p, i.e.
P̂(p⁺) by P̂(p) + hZ_p — and (P̂(p⁺) − P̂(p))/h ⪰ Z_p at every p⁺ of p are equivalent to Φ(p, p⁺) ≻ 0 at
all of them: ⇐ since WᵀΦW = Ψ(p; Z_p) + e(P̂(p⁺) − P̂(p) − hZ_p)eᵀ; ⇒ since Ψ = WᵀΦ_ZW, Φ_Z the
shift form with P̂(p⁺) replaced by P̂(p) + hZ_p in its (1,1) block only, and by a Schur complement on the
last three block rows (positive definite in every Φ ≻ 0) Φ_Z ≻ 0 ⟺ P̂(p) + hZ_p ≻ N(p) and Φ ≻ 0 ⟺
P̂(p⁺) ≻ N(p), for one matrix N(p) not depending on p⁺; so hZ_p = N(p) − P̂(p) + εI serves for ε small.
The large LMIs (size 4n + n_w + n_z) are then one per distinct p instead of one per pair; the per-pair
ones are of size 2n.

**Numerics.** The LMIs are posed in the coordinates of :func:`lpvflow.synth.eliminated.preconditioned`
for the plant at the breakpoint nearest the centre (a state transform that balances the interior
Lyapunov matrices of a frozen design, and u/y scalings; the state transform commutes with the Cayley
map, so it is the discrete one too); strictness is Ψ ⪰ t·I with the margin t maximised at each γ level
in the homogenized form of :class:`_Levels`, the level search is
:func:`lpvflow.synth.levels.lowest_certified_level` bracketed by the largest
frozen estimate over the breakpoints (an estimate of the frozen optimum, not a bound: the eliminated
conditions' infimum is not attained, :mod:`lpvflow.synth.eliminated`) and the
level of the common-Lyapunov polytopic design on the same vertices (tried first; minimising γ
over these LMIs directly is ill-posed — the slack and P̂ grow without bound near the optimum, and
Clarabel stops with a numerical error on the ADIP), and a level passes only when the reconstructed
controller's Φ, rebuilt from the returned discrete numbers in shift form, is positive definite at every
(p, p⁺) with a Jacobi-scaled margin above round-off (:class:`Slack`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from itertools import pairwise

import control
import cvxpy as cp
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.synth.bilinear import Coordinates, cayley_vertex, closed_loop
from lpvflow.synth.controller import LPVController, mix, series_input_filter
from lpvflow.synth.eliminated import preconditioned
from lpvflow.synth.levels import GAMMA_MAX, lowest_certified_level
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant, check_a3, interpolate
from lpvflow.synth.polytope import hat_coordinates
from lpvflow.synth.riccati import riccati_judgement, riccati_witness
from lpvflow.synth.sdp import SolveReport, SynthesisError, solve
from lpvflow.synth.vertex_synthesis import homogenizing_scale, synthesize_vertices
from lpvflow.validate.stability import scaled_margin

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
        return hat_coordinates(self.breakpoints, p)

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
class Slack:
    """The constant slack of the module docstring in the scaled plant state x̄ (x = T x̄): X, Y, U, V with
    𝒢𝒯 = [X I; U 0] and 𝒯 = [I Yᵀ; 0 Vᵀ]; state transform T."""

    X: np.ndarray
    Y: np.ndarray
    U: np.ndarray
    V: np.ndarray
    T: np.ndarray

    @cached_property
    def T_inv(self) -> np.ndarray:
        return np.linalg.inv(self.T)

    @cached_property
    def Pi_G(self) -> np.ndarray:
        """𝒢𝒯 = [X I; U 0]."""
        n = self.X.shape[0]
        return np.block([[self.X, np.eye(n)], [self.U, np.zeros((n, n))]])

    @cached_property
    def Pi_V(self) -> np.ndarray:
        """𝒯 = [I Yᵀ; 0 Vᵀ]."""
        n = self.X.shape[0]
        return np.block([[np.eye(n), self.Y.T], [np.zeros((n, n)), self.V.T]])

    def certificate(self, plant: VertexPlant, K: tuple[np.ndarray, ...], P_hat: np.ndarray,
                    P_hat_next: np.ndarray, gamma: float) -> float:
        """Margin of Φ(p, p⁺) for the closed loop of ``plant`` (original coordinates) and ``K`` (numbers as
        returned), evaluated after the congruence diag(𝒯, 𝒯, I, I) in which 𝒫 = 𝒯⁻ᵀP̂𝒯⁻¹ becomes P̂:

            Φ̃ = [P̂(p⁺)   Π_Vᵀ𝒜Π_G   Π_Vᵀℬ   0;  ⋆   He(Π_Vᵀ Π_G) − P̂(p)   0   Π_Gᵀ𝒞ᵀ;  ⋆ ⋆ γI 𝒟ᵀ;  ⋆ ⋆ ⋆ γI],

        Π_G = 𝒢𝒯 = [X I; U 0], Π_V = 𝒯 = [I Yᵀ; 0 Vᵀ] (so Π_VᵀΠ_G = 𝒯ᵀ𝒢𝒯), and (𝒜, ℬ, 𝒞, 𝒟) the loop of
        the plant with its state scaled by T⁻¹. Positive definiteness of Φ̃ and of Φ are the same (a
        congruence); Φ̃ is where the blocks are O(1). Margin: :func:`lpvflow.validate.stability.scaled_margin`
        of Φ̃, λ_min of the Jacobi-scaled Φ̃ minus ROUNDOFF_FACTOR·m·ε·‖D⁻¹ E D⁻¹‖₂, E the same products
        formed with absolute values (the size of the terms that cancel in forming Φ̃)."""
        Ti = self.T_inv  # cached: this runs at every (p, p⁺) of the design and the fine grid
        v = VertexPlant(Ti @ plant.A @ self.T, Ti @ plant.B1, Ti @ plant.B2, plant.C1 @ self.T,
                        plant.C2 @ self.T, plant.D11, plant.D12, plant.D21, plant.D22)
        A, B, C, D = closed_loop(v, K)
        PiG, PiV = self.Pi_G, self.Pi_V
        nw, nz, m = B.shape[1], C.shape[0], 2 * self.X.shape[0]

        def assemble(A, B, C, D, PiG, PiV, Pn, P, g):
            He = PiV.T @ PiG
            return np.block([[Pn, PiV.T @ A @ PiG, PiV.T @ B, np.zeros((m, nz))],
                             [(PiV.T @ A @ PiG).T, He + He.T - P, np.zeros((m, nw)), (C @ PiG).T],
                             [(PiV.T @ B).T, np.zeros((nw, m)), g * np.eye(nw), D.T],
                             [np.zeros((nz, m)), C @ PiG, D, g * np.eye(nz)]])

        Phi = assemble(A, B, C, D, PiG, PiV, P_hat_next, P_hat, gamma)
        E = assemble(*(np.abs(M) for M in (A, B, C, D, PiG, PiV, P_hat_next)), -np.abs(P_hat), gamma)
        return scaled_margin(Phi, E)

    def lyapunov_value(self, xi: np.ndarray, P_hat: np.ndarray) -> float:
        """V = ξᵀ𝒫⁻¹ξ = (𝒯ᵀξ̄)ᵀP̂⁻¹(𝒯ᵀξ̄), ξ̄ = [T⁻¹x; x_K] (ξ = [x; x_K] in original coordinates)."""
        n = self.X.shape[0]
        xbar = np.concatenate([self.T_inv @ xi[:n], xi[n:]])
        w = self.Pi_V.T @ xbar
        return float(w @ np.linalg.solve(P_hat, w))


@dataclass
class ScheduledResult:
    """Certified rate-bounded design.

    Attributes:
        gamma: the certified level; gamma_estimate: the largest frozen estimate over the breakpoints
            (:func:`lpvflow.synth.eliminated.preconditioned`; None unless every one of those solves was
            accurate): an estimate of the frozen optimum, not a bound (:mod:`lpvflow.synth.eliminated`).
        K_vertices: discrete vertex controllers (A_K, B_K, C_K, D_K) from y to u at the breakpoints.
        schedule: breakpoints and rate bound; vertices: the generalized plant at the breakpoints.
        lyapunov: P̂ = 𝒯ᵀ𝒫𝒯 at the breakpoints (:class:`Slack`); slack: the slack and coordinates.
        margins: :meth:`Slack.certificate` at every (p, p⁺) of the design (all > 0).
    """

    gamma: float
    gamma_estimate: float | None
    K_vertices: list[tuple[np.ndarray, ...]]
    schedule: Schedule
    vertices: list[VertexPlant]
    Ts: float
    lyapunov: list[np.ndarray]
    slack: Slack
    margins: list[float] = field(default_factory=list)
    report: SolveReport = field(default_factory=lambda: SolveReport("", "", 0.0))

    def controller_at(self, p: float) -> tuple[np.ndarray, ...]:
        """(A_K, B_K, C_K, D_K) at p: Σ λ_i(p) K_i."""
        return mix(self.K_vertices, self.schedule.weights(p))

    def controller(self, p: float) -> control.StateSpace:
        """The controller frozen at p (from y to u, dt = Ts)."""
        return control.ss(*self.controller_at(p), self.Ts)

    @property
    def vertex_controllers(self) -> list[control.StateSpace]:
        return [control.ss(*K, self.Ts) for K in self.K_vertices]

    @property
    def certificate(self) -> list[float]:
        """Margins of Φ at the design's (p, p⁺) (all > 0)."""
        return self.margins

    def lyapunov_at(self, p: float) -> np.ndarray:
        """P̂(p) = Σ λ_i(p) P̂_i."""
        return sum(li * P for li, P in zip(self.schedule.weights(p), self.lyapunov, strict=True))

    def plant_at(self, p: float) -> VertexPlant:
        """The generalized plant at p: Σ λ_i(p) (vertex plant i)."""
        return interpolate(self.vertices, self.schedule.weights(p))

    def margin(self, plant: VertexPlant, p: float, q: float) -> float:
        """:meth:`Slack.certificate` of ``plant`` with the controller at p, from p to p⁺ = q."""
        return self.slack.certificate(plant, self.controller_at(p), self.lyapunov_at(p), self.lyapunov_at(q),
                                      self.gamma)


# ------------------------------------------------------------------------------------------ LMIs
def delta_step(verts: list[VertexPlant], centre: int) -> float:
    """h of the δ form (module docstring): ‖A − I‖₂ of the centre vertex in the LMIs' coordinates, the
    dimensionless step by which the plant moves per sample (floored at machine precision)."""
    A = verts[centre].A
    return max(float(np.linalg.norm(A - np.eye(len(A)), 2)), float(np.finfo(float).eps))


class _Levels:
    """Φ_δ of the module docstring at every pair, in scaled coordinates, at the level γ (a Parameter), solved
    **homogenized** (as :mod:`lpvflow.synth.vertex_synthesis` step 5): every term of Ψ_δ that multiplies no
    variable (the identities of Γ, A' in E, B1, C1, D11 and the γI blocks) is multiplied by a variable
    τ ≥ 0, so Ψ_δ^τ(v, τ) = τ·Ψ_δ(v/τ) for the variables v; maximise t subject to Ψ_δ^τ(p) ⪰ t·I at every
    distinct p, (P̂(p⁺) − P̂(p))/h ⪰ Z_p at its p⁺, and Σ_i tr P̂_i = 2n·M (M breakpoints: the mean
    eigenvalue of P̂ is 1). A point with t > 0 has τ > 0 (at τ = 0 the γI blocks vanish) and v/τ satisfies
    the LMIs as written with margin t/τ; conversely any solution of those (P̂ ≻ 0), scaled to the trace,
    is a point here. So the level is feasible exactly when t > 0, and t ≤ λ_min(P̂(p⁺)) ≤ 1 stays bounded;
    the LMIs as written, at a fixed τ = 1, reach their supremum near the optimal level only as the slack
    and P̂ grow (on this stack: seed 3 of tests/test_synth_rate_bounded_random.py at 1 ms certified 1.037×
    the common-Lyapunov level, 1.0009× homogenized). The normalization is an affine slice (not P̂_i ⪯ I) so
    that it excludes the origin: with P̂_i ⪯ I, every infeasible level had its optimum t = 0 at v = 0,
    τ = 0, a degenerate point Clarabel reported ``optimal_inaccurate`` (4 of the 5 random cases tried).
    Variables X, Y, S, per breakpoint P̂, L, R, F_δ, Q_δ (F = h·F_δ, Q = S + h·Q_δ), per p the bound Z_p;
    :meth:`controller_variables`, :meth:`slack` and :meth:`lyapunov` return them divided by τ."""

    def __init__(self, verts: list[VertexPlant], schedule: Schedule, pairs: list, h: float) -> None:
        n, _nw, nu, _nz, ny = verts[0].dims
        M = len(verts)
        self.h = h
        self.gamma, self.t, self.tau = cp.Parameter(pos=True), cp.Variable(), cp.Variable(nonneg=True)
        self.X, self.Y, self.S = (cp.Variable((n, n)) for _ in range(3))
        self.P = [cp.Variable((2 * n, 2 * n), symmetric=True) for _ in range(M)]
        self.L = [cp.Variable((nu, n)) for _ in range(M)]
        self.R = [cp.Variable((nu, ny)) for _ in range(M)]
        self.Fd = [cp.Variable((n, ny)) for _ in range(M)]
        self.Qd = [cp.Variable((n, n)) for _ in range(M)]
        # A' = (A − I)/h and B2' = B2/h at every breakpoint, formed once in floating point
        self.Ad = [(v.A - np.eye(n)) / h for v in verts]
        self.B2d = verts[0].B2 / h
        self.verts, self.schedule, self.pairs = verts, schedule, pairs
        constraints = [sum(cp.trace(P) for P in self.P) == 2 * n * M]
        for p, nexts in pairs:
            Z = cp.Variable((2 * n, 2 * n), symmetric=True)
            Psi = self._psi(p, Z, self.gamma)
            constraints.append(Psi >> self.t * np.eye(Psi.shape[0]))
            P = self._mix(self.P, schedule.weights(p))
            constraints += [(self._mix(self.P, schedule.weights(q)) - P) / h - Z >> 0 for q in nexts]
        self.margin_problem = cp.Problem(cp.Maximize(self.t), constraints)

    def _value(self, var: cp.Variable) -> np.ndarray:
        """A variable of the LMIs as written: the homogenized solution divided by τ (LinAlgError when τ is
        not positive, i.e. the solve found no point of the level's LMIs)."""
        return np.asarray(var.value, dtype=float) / homogenizing_scale(self.tau)

    def slack(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, S) of the LMIs as written."""
        return self._value(self.X), self._value(self.Y), self._value(self.S)

    def lyapunov(self) -> list[np.ndarray]:
        """P̂ at the breakpoints (symmetrized) of the LMIs as written."""
        return [0.5 * (P + P.T) for P in map(self._value, self.P)]

    def _mix(self, mats: list, lam: np.ndarray):
        return sum(float(li) * M for li, M in zip(lam, mats, strict=True) if li != 0.0)

    def controller_variables(self, i: int) -> tuple[np.ndarray, ...]:
        """(L, R, F, Q) at breakpoint i of the LMIs as written: F = h·F_δ, Q = S + h·Q_δ."""
        L, R, Fd, Qd, S = map(self._value, (self.L[i], self.R[i], self.Fd[i], self.Qd[i], self.S))
        return L, R, self.h * Fd, S + self.h * Qd

    def _psi(self, p: float, Z: cp.Variable, gamma) -> cp.Expression:
        """Ψ_δ^τ(p; Z): Φ_δ(p, p⁺) with (P̂(p⁺) − P̂(p))/h replaced by Z, homogenized (class docstring)."""
        lam = self.schedule.weights(p)
        v = interpolate(self.verts, lam)
        n, nw, _, nz, _ = v.dims
        h, c = self.h, 1.0 / np.sqrt(self.h)
        X, Y, S, tau = self.X, self.Y, self.S, self.tau
        L, R, Fd, Qd = (self._mix(m, lam) for m in (self.L, self.R, self.Fd, self.Qd))
        Ad, B2d = self._mix(self.Ad, lam), self.B2d
        E = cp.bmat([[Ad @ X + B2d @ L, tau * Ad + B2d @ R @ v.C2], [Qd, Y @ Ad + Fd @ v.C2]])
        Gamma = cp.bmat([[X, tau * np.eye(n)], [S, Y]])
        P = self._mix(self.P, lam)
        Bcl = cp.vstack([tau * v.B1 + v.B2 @ R @ v.D21, Y @ v.B1 + h * Fd @ v.D21])
        Ccl = cp.hstack([v.C1 @ X + v.D12 @ L, tau * v.C1 + v.D12 @ R @ v.C2])
        Dcl = tau * v.D11 + v.D12 @ R @ v.D21
        off = c * (Gamma - P) - Z / c + E / c
        Phi = cp.bmat([
            [P + h * Z, off, Bcl, np.zeros((2 * n, nz))],
            [off.T, Z - E - E.T, -c * Bcl, c * Ccl.T],
            [Bcl.T, -c * Bcl.T, gamma * tau * np.eye(nw), Dcl.T],
            [np.zeros((nz, 2 * n)), c * Ccl, Dcl, gamma * tau * np.eye(nz)],
        ])
        return 0.5 * (Phi + Phi.T)


def _reconstruct(levels: _Levels, vertices: list[VertexPlant], coords: Coordinates, schedule: Schedule,
                 gamma: float, gamma_estimate: float | None, Ts: float) -> ScheduledResult:
    """Controller of the module docstring at every breakpoint, 𝒫 and 𝒢 in the scaled state, and the
    certificate margins rebuilt from the returned discrete numbers."""
    X, Y, S = levels.slack()
    W, sig, Zt = np.linalg.svd(S - Y @ X)
    V, U = W * np.sqrt(sig), np.sqrt(sig)[:, None] * Zt
    K_vertices = []
    for i, v in enumerate(levels.verts):
        L, R, F, Q = levels.controller_variables(i)
        Dk = R
        Ck = np.linalg.solve(U.T, (L - R @ v.C2 @ X).T).T
        Bk = np.linalg.solve(V, F - Y @ v.B2 @ R)
        core = Q - Y @ v.A @ X - Y @ v.B2 @ L - V @ Bk @ v.C2 @ X
        Ak = np.linalg.solve(V, np.linalg.solve(U.T, core.T).T)
        K_vertices.append(coords.controller((Ak, Bk, Ck, Dk)))
    result = ScheduledResult(gamma, gamma_estimate, K_vertices, schedule, vertices, Ts, levels.lyapunov(),
                             Slack(X, Y, U, V, np.asarray(coords.T)))
    result.margins = [result.margin(result.plant_at(p), p, q) for p, nexts in levels.pairs for q in nexts]
    return result


def _common_lyapunov_level(vertices: list[VertexPlant], Ts: float, suboptimality: float, gamma_max: float,
                           solver: str, attempts: list) -> float | None:
    """γ of the polytopic design with one common Lyapunov matrix on the same vertices
    (:func:`lpvflow.synth.vertex_synthesis.synthesize_vertices`; its SDPs are appended to ``attempts``), or
    None when it has no certified result. A constant P̂ is one choice of these LMIs, so the rate-bounded
    optimum is expected at or below it; it is the first level tried (the level search goes on upwards if
    it fails)."""

    try:
        result = synthesize_vertices(vertices, Ts, suboptimality, gamma_max, solver)
    except SynthesisError as exc:
        attempts.append((solver.upper(), exc.category, 0.0))
        return None
    attempts.extend(result.report.attempts)
    return float(result.gamma)


def _refuse_below_frozen_optimum(vertices: list[VertexPlant], breakpoints: np.ndarray, Ts: float,
                                 gamma_max: float, what: str) -> None:
    """Raise ``"infeasible"`` when SLICOT SB10DD (bisected, :func:`lpvflow.synth.riccati.riccati_witness`)
    reaches no γ ≤ ``gamma_max`` for the plant frozen at some breakpoint: p constant there is an admissible
    trajectory at any rate bound, on which every scheduled controller is an LTI controller of that plant,
    so none reaches ``gamma_max``. Otherwise return (the failure is the solver's, not the problem's)."""
    for p, vertex in zip(breakpoints, vertices, strict=True):
        judgement, category = riccati_judgement(riccati_witness(vertex, Ts), gamma_max)
        if category == "infeasible":
            raise SynthesisError(f"{what}: no level up to γ = {gamma_max:.4g} passed; for the plant "
                                 f"frozen at the breakpoint {p:.4g}, {judgement}, so no scheduled controller "
                                 "reaches it there: raise gamma_max or loosen the weights", category=category)


def synthesize_scheduled(vertices: list[VertexPlant], breakpoints: Sequence[float], Ts: float, *,
                         rate_bound: float | None, suboptimality: float = 1e-2, solver: str = "CLARABEL",
                         points: Sequence[float] = (), gamma_max: float = GAMMA_MAX) -> ScheduledResult:
    """Rate-bounded parameter-dependent-Lyapunov H∞ design (module docstring) on vertex plants at the
    breakpoints; ``points`` adds scheduling values at which Φ is also imposed.

    Raises:
        ModelError: breakpoints that do not match the vertices, or B2, C2, D12, D21 not constant.
        SynthesisError: no level up to ``gamma_max`` whose controller passes the certificate —
            ``"infeasible"`` where SB10DD finds no controller within ``gamma_max`` for the plant frozen at a
            breakpoint (named), else ``"accuracy"``; ``"infeasible"`` also when the solver proves the frozen
            eliminated LMIs infeasible at every γ.
    """
    if not suboptimality > 0:
        raise ModelError(f"suboptimality must be positive, got {suboptimality!r}")
    schedule = Schedule(np.asarray(breakpoints, dtype=float), rate_bound)
    if len(vertices) != len(schedule.breakpoints):
        raise ModelError(f"{len(vertices)} vertex plants for {len(schedule.breakpoints)} breakpoints")
    check_a3(vertices)
    start = time.perf_counter()
    # per breakpoint: the frozen estimate (the search starts at the largest) and the balanced coordinates;
    # the LMIs are posed in those of the breakpoint nearest the centre
    frozen = [preconditioned([cayley_vertex(v)], gamma_max, solver) for v in vertices]
    centre = int(np.argmin(np.abs(schedule.breakpoints - schedule.breakpoints.mean())))
    coords = frozen[centre].coordinates.discrete()
    accurate = [f.estimate.gamma for f in frozen if f.estimate.accurate]
    gamma_estimate = max(accurate) if len(accurate) == len(frozen) else None
    estimate = max(f.estimate.gamma for f in frozen)
    attempts = [a for f in frozen for a in f.attempts]
    common = _common_lyapunov_level(vertices, Ts, suboptimality, gamma_max, solver, attempts)
    first = estimate if common is None else max(estimate, common / (1 + suboptimality))
    verts = [coords.apply(v) for v in vertices]
    levels = _Levels(verts, schedule, schedule.pairs(points), delta_step(verts, centre))
    what = (f"the rate-bounded H∞ LMIs ({len(verts)} breakpoints, "
            f"ν = {'any' if rate_bound is None else f'{rate_bound:g}'} per sample)")

    def certified(gamma: float) -> ScheduledResult | None:
        levels.gamma.value = gamma
        try:
            level_report = solve(levels.margin_problem, solver, f"{what} at γ = {gamma:.6g}")
        except SynthesisError as exc:
            attempts.append((solver.upper(), exc.category, 0.0))
            return None
        attempts.extend(level_report.attempts)
        try:
            result = _reconstruct(levels, vertices, coords, schedule, gamma, gamma_estimate, Ts)
        except np.linalg.LinAlgError:
            return None
        result.report = level_report
        return result if min(result.margins) > 0 else None

    best = lowest_certified_level(certified, first, suboptimality, gamma_max, gamma_estimate)
    if best is None:
        _refuse_below_frozen_optimum(vertices, schedule.breakpoints, Ts, gamma_max, what)
        polytopic = "none" if common is None else f"{common:.4g}"
        lowest = min(first * (1 + suboptimality), gamma_max)
        raise SynthesisError(f"{what}: no level from {lowest:.4g} (frozen estimate "
                             f"{estimate:.4g}, common-Lyapunov level {polytopic}) up to "
                             f"{gamma_max:.4g} gave a controller that passes the certificate: lower the rate "
                             "bound, shrink the range, add breakpoints or loosen the weights",
                             category="accuracy")
    best.report = SolveReport(best.report.solver, best.report.status, time.perf_counter() - start, attempts)
    return best


def segment_grid(breakpoints: np.ndarray, per_segment: int) -> np.ndarray:
    """``per_segment`` equal intervals in every breakpoint interval (the breakpoints included)."""
    return np.unique(np.concatenate([np.linspace(lo, hi, per_segment + 1)
                                     for lo, hi in pairwise(breakpoints)]))


def fine_check(result: ScheduledResult, plant_at: Callable[[float], VertexPlant] | None = None,
               per_segment: int = FINE_PER_SEGMENT) -> tuple[float, float]:
    """(smallest margin, where) of Φ on a grid ``per_segment`` times finer than the breakpoints, with
    p⁺ = p ± ν (clipped) and the breakpoints between: the design's own piecewise-linear plant, or
    ``plant_at(p)`` (the true plant, e.g. exact linearizations) with the interpolated controller."""
    b = result.schedule.breakpoints
    fine = segment_grid(b, per_segment)
    worst = (np.inf, float(fine[0]))
    for p, nexts in result.schedule.pairs(fine):
        v = result.plant_at(p) if plant_at is None else plant_at(p)
        worst = min(worst, *((result.margin(v, p, q), p) for q in nexts))
    return worst


def synthesize_gridded(plant_at: Callable[[float], VertexPlant], breakpoints: Sequence[float], Ts: float, *,
                       rate_bound: float | None, refinements: int = 3, gamma_slack: float = 0.1,
                       suboptimality: float = 1e-2, solver: str = "CLARABEL") -> ScheduledResult:
    """:func:`synthesize_scheduled` on the plants ``plant_at(b)`` at the breakpoints, re-checked by
    :func:`fine_check` against ``plant_at`` itself (the true plant between breakpoints, not their
    interpolation). Φ only gains from a larger γ (its γI blocks), so the certified level for the true plant
    is the smallest γ' in [γ, (1 + ``gamma_slack``)·γ] at which the fine check holds (bisection to 0.1 %; no
    SDP); the result carries γ'. When even (1 + gamma_slack)·γ fails, the worst point becomes a breakpoint
    and the design is repeated, at most ``refinements`` times.

    Raises:
        SynthesisError: the certificate still fails after the refinements (naming the point).
    """
    points = sorted(float(b) for b in breakpoints)
    for _ in range(refinements + 1):
        result = synthesize_scheduled([plant_at(b) for b in points], points, Ts, rate_bound=rate_bound,
                                      suboptimality=suboptimality, solver=solver)
        designed = result.gamma
        result.gamma = designed * (1 + gamma_slack)
        margin, where = fine_check(result, plant_at)
        if margin > 0:
            lo, hi = designed, result.gamma
            while hi / lo > 1 + 1e-3:
                result.gamma = 0.5 * (lo + hi)
                lo, hi = (lo, result.gamma) if fine_check(result, plant_at)[0] > 0 else (result.gamma, hi)
            result.gamma = hi  # result.margins are those at the designed γ: larger at γ' ≥ γ
            return result
        points = sorted({*points, where})
    raise SynthesisError(f"after {refinements} refinements (breakpoints {np.round(points, 4).tolist()}) the "
                         f"certificate still fails against the true plant at p = {where:.4g} (margin "
                         f"{margin:.3g} at {1 + gamma_slack:g}× the designed γ): add breakpoints near it or "
                         "lower the rate bound", category="accuracy")


def synthesize_rate_bounded(plant: GeneralizedPlant, rate_bound: float | None, solver: str = "CLARABEL",
                            suboptimality: float = 1e-2) -> tuple[ScheduledResult, LPVController]:
    """:func:`synthesize_scheduled` on a mixed-sensitivity design of one scheduling signal whose polytope
    is a segment (``"box"``) or piecewise (``"piecewise"``), and the implementable :class:`LPVController`
    (vertex controllers at the breakpoints, W_B in series, the plant's λ(p) and structure)."""
    poly = plant.polytope
    breakpoints = poly.vertex_breakpoints
    if breakpoints is None:
        raise ModelError(f"the rate-bounded design needs one scheduling signal and an affine basis or "
                         f"breakpoints; this design's polytope is {poly.kind!r} over {len(poly.box)} signals")
    result = synthesize_scheduled(plant.vertices, breakpoints, plant.Ts, rate_bound=rate_bound,
                                  suboptimality=suboptimality, solver=solver)
    K = result.K_vertices
    if plant.input_filter is not None:
        K = [series_input_filter(k, plant.input_filter) for k in K]
    info = {"method": "rate-bounded", "rate_bound": rate_bound, "gamma": result.gamma,
            "gamma_estimate": result.gamma_estimate, "solver": solver, "solve_seconds": result.report.seconds,
            "polytope": poly.kind, "breakpoints": [float(b) for b in breakpoints]}
    stacks = [np.array([k[m] for k in K]) for m in range(4)]
    return result, LPVController(*stacks, poly, plant.basis, plant.Ts, info=info, structure=plant.structure)
