"""Rate-bounded H∞ analysis of a given gain-scheduled closed loop, posed so that small Ts does not break it.

Any gain-scheduled loop — a frozen plant with an interpolated controller, however both were made —
ξ⁺ = 𝒜(p)ξ + ℬ(p)w, z = 𝒞(p)ξ + 𝒟(p)w, one scheduling signal with |p(k+1) − p(k)| ≤ ν per sample. A
storage V(k) = ξᵀ𝒫(p(k))ξ with 𝒫 linear between breakpoints b_0 < … < b_M (hat functions λ_i, 𝒫 = Σλ_i𝒫_i)
proves ‖z‖₂ < γ‖w‖₂ along every admissible scheduling trajectory when, at every pair (p, p⁺),

    ξ⁺ᵀ𝒫(p⁺)ξ⁺ − ξᵀ𝒫(p)ξ + zᵀz/γ − γwᵀw < 0   for all (ξ, w) ≠ 0

(the dissipation inequality with a parameter-dependent storage; Wu, Yang, Packard & Becker 1996, "Induced
L2-norm control for LPV systems with bounded parameter variation rates", IJRNC 6, in discrete time).

**The bilinear image.** With A ≈ I (Ts = 2–5 ms) the shift form carries its information in O(Ts)
differences of O(‖𝒫‖) blocks. In the coordinates ζ = (ξ + ξ⁺)/√2 of the loop's Cayley image at p,
(A_c, B_c, C_c, D_c) = :func:`lpvflow.synth.bilinear.cayley` (𝒜, ℬ, 𝒞, 𝒟), the same inequality reads exactly

    ξ = ((I − A_c)ζ − B_cw)/√2,   ξ⁺ = ((I + A_c)ζ + B_cw)/√2,   z = C_cζ + D_cw,
    ξ⁺ᵀ𝒫ξ⁺ − ξᵀ𝒫ξ = 2(A_cζ + B_cw)ᵀ𝒫ζ        (𝒫 = 𝒫(p)),

so, with N = [I + A_c, B_c]/√2 and a Schur complement on zᵀz/γ,

    ⎡ A_cᵀ𝒫(p) + 𝒫(p)A_c    𝒫(p)B_c    C_cᵀ ⎤     ⎡ Nᵀ(𝒫(p⁺) − 𝒫(p))N   0 ⎤
    ⎢ ⋆                    −γI         D_cᵀ ⎥  +  ⎣ 0                    0 ⎦  ≺ 0,
    ⎣ ⋆                    ⋆           −γI  ⎦

affine in (𝒫_i, γ), with no difference of large blocks left: the frozen part is the continuous bounded-real
matrix of the Cayley image (which preserves ‖·‖∞), the rate enters through 𝒫(p⁺) − 𝒫(p) only.

**Scaling.** The storage of one frozen loop is ill-conditioned in the loop's own coordinates (on the
ADIP: eigenvalues 5·10⁻⁸…8·10³, and Clarabel stops "inaccurate" on that single frozen LMI). So every
breakpoint's variable is 𝒫_i = S_iᵀ P̃_i S_i with X_i = S_iᵀS_i the stabilizing solution of the frozen
bounded-real Riccati equation of the Cayley image at b_i (level 1.2·‖T_zw(b_i)‖∞, scipy's
``solve_continuous_are`` with the indefinite weight −(γ²I − D_cᵀD_c)), divided by that level: there
P̃_i ≈ I solves the frozen problem; each pair's matrix is taken through the congruence diag(S_j⁻¹, I, I)
of the breakpoint b_j nearest p. (Congruences do not change definiteness.)

**Where it is imposed.** For a fixed p the matrix is affine in λ(p⁺), so p⁺ at p ± ν (clipped) and the
breakpoints between covers every admissible p⁺ (:meth:`lpvflow.synth.rate_bounded.Schedule.pairs`). The loop
is not affine in p between breakpoints (plant and controller both vary), so p is gridded:
``design_per_segment`` points per breakpoint interval, the breakpoints ± ν, and ``points``.

**The level search and the certificate.** At a level γ, the storage with the largest margin t (every
matrix ⪯ −t·I, P̃_i ⪰ t·I, t ≤ 1, in the scaled coordinates). (Minimising γ directly is not used: on the
ADIP its minimiser came back "inaccurate" 1 % below a level at which the margin SDP found t < 0.) The
solver is not trusted: a level is certified when every pair's matrix, rebuilt in numpy from the returned
P̃_i and ``loop_at`` (:meth:`RateBoundedGain.margin_at`), is negative definite with a Jacobi-scaled margin
above round-off (:func:`lpvflow.validate.stability.scaled_margin`), every P̃_i is positive definite the same
way, and all of this holds on a grid ``per_segment`` times finer than the breakpoints. The levels are those
of :func:`lpvflow.synth.levels.lowest_certified_level` from the largest frozen ‖T_zw(b_i)‖∞ (python-control;
no storage does better): γ_low·(1 + δ·2^k) until one passes, then bisection to a relative width δ
(``suboptimality``). When none passes, the point where the highest level failed joins the LMI grid and the
search is repeated (at most ``refinements`` times); then the point is named.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import control
import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError
from lpvflow.synth.bilinear import cayley
from lpvflow.synth.levels import lowest_certified_level
from lpvflow.synth.rate_bounded import FINE_PER_SEGMENT, Schedule, segment_grid
from lpvflow.synth.sdp import SolveReport, SynthesisError, solve
from lpvflow.validate.stability import scaled_margin

Loop = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: Points per breakpoint interval at which the LMIs are imposed (besides breakpoints ± ν): the loop is not
#: affine in p between breakpoints, so p is gridded (p⁺ is not: the matrix is affine in 𝒫(p⁺)).
DESIGN_PER_SEGMENT = 4
#: Level, relative to the frozen ‖T_zw‖∞, of the Riccati storage that scales each breakpoint's variable.
SCALING_LEVEL = 1.2


@dataclass
class RateBoundedGain:
    """A certified bound on the closed loop's gain under rate-bounded scheduling.

    Attributes:
        gamma: the certified level (‖z‖₂ < γ‖w‖₂ for every trajectory with |Δp| ≤ ν per sample).
        gamma_lower: the largest frozen ‖T_zw‖∞ at the breakpoints: no storage certifies less.
        schedule: breakpoints and rate bound; lyapunov: 𝒫_i at the breakpoints (loop coordinates);
            scalings, scaled: S_i and P̃_i of 𝒫_i = S_iᵀP̃_iS_i (module docstring, Scaling).
        margin, where: the smallest certificate margin at γ and the p where it occurs (design pairs and
            the fine grid).
        frozen_norms: ‖T_zw(b_i)‖∞ at the breakpoints (python-control), a lower bound on any γ.
    """

    gamma: float
    gamma_lower: float
    schedule: Schedule
    margin: float
    where: float
    frozen_norms: list[float]
    scalings: list[np.ndarray]
    scaled: list[np.ndarray]
    report: SolveReport = field(default_factory=lambda: SolveReport("", "", 0.0))

    @property
    def lyapunov(self) -> list[np.ndarray]:
        """𝒫_i = S_iᵀP̃_iS_i at the breakpoints, in the loop's coordinates."""
        return [S.T @ P @ S for S, P in zip(self.scalings, self.scaled, strict=True)]

    def lyapunov_at(self, p: float) -> np.ndarray:
        """𝒫(p) = Σ λ_i(p) 𝒫_i."""
        return sum(li * P for li, P in zip(self.schedule.weights(p), self.lyapunov, strict=True))

    @cached_property
    def inverse_scalings(self) -> list[np.ndarray]:
        """S_i⁻¹: the congruence of every pair whose p is nearest b_i."""
        return [np.linalg.inv(S) for S in self.scalings]

    def margin_at(self, image: Loop, p: float, q: float, gamma: float) -> float:
        """:func:`lpvflow.validate.stability.scaled_margin` of minus the dissipation matrix from p to p⁺ = q
        at level γ, ``image`` the Cayley image (:func:`lpvflow.synth.bilinear.cayley`) of the closed loop at
        p, formed in the coordinates of the breakpoint nearest p (T = S_j⁻¹): > 0 certifies the pair."""
        T = self.inverse_scalings[int(np.argmin(np.abs(self.schedule.breakpoints - p)))]
        M, E = _dissipation(image, self._storage(p, T), self._storage(q, T), gamma, T)
        return scaled_margin(-M, E)

    def _storage(self, p: float, T: np.ndarray) -> np.ndarray:
        """Tᵀ𝒫(p)T = Σ λ_i(p) (S_iT)ᵀP̃_i(S_iT)."""
        lam = self.schedule.weights(p)
        terms = zip(lam, self.scalings, self.scaled, strict=True)
        return sum(li * ((S @ T).T @ P @ (S @ T)) for li, S, P in terms if li)


def dissipation_matrix(loop: Loop, P: np.ndarray, P_next: np.ndarray, gamma: float,
                       T: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """(M, E): the module docstring's matrix of the discrete ``loop`` at p with 𝒫(p) = ``P`` and
    𝒫(p⁺) = ``P_next`` (negative definite iff the dissipation inequality holds), and the sum of the absolute
    values of its terms (for the round-off bound of :func:`lpvflow.validate.stability.scaled_margin`).
    With a state transform ``T`` (ζ = Tζ̄), ``P`` and ``P_next`` are Tᵀ𝒫T and M is
    diag(T, I, I)ᵀ(…)diag(T, I, I)."""
    return _dissipation(cayley(*loop), P, P_next, gamma, T)


def _dissipation(image: Loop, P: np.ndarray, P_next: np.ndarray, gamma: float, T: np.ndarray | None
                 ) -> tuple[np.ndarray, ...]:
    """:func:`dissipation_matrix` from the loop's Cayley image (formed once per p by the caller)."""
    Ac, Bc, Cc, Dc = image
    if T is not None:
        Ac, Bc, Cc = np.linalg.solve(T, Ac @ T), np.linalg.solve(T, Bc), Cc @ T
    m, nw, nz = Ac.shape[0], Bc.shape[1], Cc.shape[0]
    N = np.hstack([np.eye(m) + Ac, Bc]) / np.sqrt(2.0)

    def assemble(Ac, Bc, Cc, Dc, N, P, dP, g):
        F = np.block([[Ac.T @ P + P @ Ac, P @ Bc], [Bc.T @ P, -g * np.eye(nw)]]) + N.T @ dP @ N
        return np.block([[F, np.vstack([Cc.T, Dc.T])], [np.hstack([Cc, Dc]), -g * np.eye(nz)]])

    M = assemble(Ac, Bc, Cc, Dc, N, P, P_next - P, gamma)
    E = assemble(*(np.abs(X) for X in (Ac, Bc, Cc, Dc, N, P)), np.abs(P_next) + np.abs(P), gamma)
    return 0.5 * (M + M.T), E


def _riccati_scaling(loop: Loop, p: float) -> tuple[np.ndarray, float]:
    """(S, ‖T_zw‖∞) of the frozen loop at breakpoint p: X = SᵀS the bounded-real Riccati storage of the
    loop's Cayley image at level SCALING_LEVEL·‖T_zw‖∞, divided by that level (module docstring, Scaling).

    Raises:
        ModelError: the loop has non-finite entries or is unstable, or the Riccati equation has no
            stabilizing solution."""
    A, B, C, D = loop
    if not all(np.all(np.isfinite(M)) for M in loop):
        raise ModelError(f"the closed loop at p = {p:.4g} has non-finite entries: check loop_at")
    radius = float(np.max(np.abs(np.linalg.eigvals(A))))
    if radius >= 1.0:
        raise ModelError(f"the frozen closed loop at p = {p:.4g} is unstable (spectral radius {radius:.6g}): "
                         "no rate-bounded gain exists; fix the controller there first")
    norm = float(control.norm(control.ss(A, B, C, D, 1.0), "inf"))
    level = SCALING_LEVEL * norm
    Ac, Bc, Cc, Dc = cayley(A, B, C, D)
    try:
        X = scipy.linalg.solve_continuous_are(Ac, Bc, Cc.T @ Cc, Dc.T @ Dc - level**2 * np.eye(Bc.shape[1]),
                                              s=Cc.T @ Dc) / level
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ModelError(f"the frozen bounded-real Riccati equation at p = {p:.4g} has no stabilizing "
                         f"solution ({exc}): the closed loop there is too close to instability") from None
    w, U = np.linalg.eigh(0.5 * (X + X.T))
    w = np.clip(w, 1e-12 * w[-1], None)
    return (U * np.sqrt(w)[None, :]).T, norm


def rate_bounded_gain(loop_at: Callable[[float], Loop | control.StateSpace], breakpoints: Sequence[float],
                      rate_bound: float | None, *, points: Sequence[float] = (),
                      design_per_segment: int = DESIGN_PER_SEGMENT, per_segment: int = FINE_PER_SEGMENT,
                      refinements: int = 3, suboptimality: float = 1e-2, solver: str = "CLARABEL",
                      gamma_max: float | None = None) -> RateBoundedGain:
    """Certified gain of the discrete closed loop ``loop_at(p)`` — (𝒜, ℬ, 𝒞, 𝒟) or a ``control.StateSpace``,
    e.g. ``plant(p).lft(controller(p))`` — for scheduling signals with |p(k+1) − p(k)| ≤ ``rate_bound`` in
    [b_0, b_M] (module docstring; ``None``: any jump).

    The LMIs are imposed at p on ``design_per_segment`` points per breakpoint interval, the breakpoints ± ν
    and ``points``; the certificate is re-checked on ``per_segment`` points per interval. When no level
    passes, the point where the highest level tried failed joins the LMI grid and the search is repeated,
    at most ``refinements`` times. Levels are tried up to ``gamma_max`` (default: 100 × the largest frozen
    norm, above which a certificate says little about the loop).

    Raises:
        ModelError: bad breakpoints, rate bound or suboptimality; a frozen loop at a breakpoint that is
            unstable or has non-finite entries.
        SynthesisError: no level up to the search's top passes after the refinements (naming the point).
    """
    user_loop = loop_at

    def loop_at(p: float) -> Loop:
        loop = user_loop(p)
        return (loop.A, loop.B, loop.C, loop.D) if isinstance(loop, control.StateSpace) else tuple(loop)

    schedule = Schedule(np.asarray(breakpoints, dtype=float), rate_bound)
    if not suboptimality > 0:
        raise ModelError(f"suboptimality must be positive, got {suboptimality!r}")
    start = time.perf_counter()
    b = schedule.breakpoints
    scalings, norms = (list(x) for x in zip(*(_riccati_scaling(loop_at(float(bi)), float(bi)) for bi in b),
                                            strict=True))
    what = (f"the rate-bounded dissipation LMIs ({len(b)} breakpoints, "
            f"ν = {'any' if rate_bound is None else f'{rate_bound:g}'} per sample)")
    fine = segment_grid(b, per_segment)
    design = np.concatenate([segment_grid(b, design_per_segment), np.asarray(points, dtype=float)])
    top_level = 100.0 * max(norms) if gamma_max is None else gamma_max
    images: dict[float, Loop] = {}  # the Cayley image of the loop at every p of the LMIs and the check
    attempts: list = []
    for _ in range(refinements + 1):
        pairs = schedule.pairs(design)
        checked = schedule.pairs(np.concatenate([fine, design]))  # the design's own pairs and the fine grid
        images.update({p: cayley(*loop_at(p)) for p, _ in checked if p not in images})
        levels = _MarginProblem(images, pairs, schedule, scalings)
        failed: list[tuple[float, float]] = []

        def certified(gamma: float, levels: _MarginProblem = levels, failed: list = failed,
                      checked: list = checked) -> RateBoundedGain | None:
            try:
                report = levels.solve(gamma, solver, f"{what} at γ = {gamma:.6g}")
            except SynthesisError:
                return None
            attempts.extend(report.attempts)
            result = RateBoundedGain(gamma, max(norms), schedule, -np.inf, float(b[0]), norms, scalings,
                                     levels.scaled(), report)
            result.margin, result.where = _worst(result, checked, images, gamma)
            failed.append((gamma, result.where))
            return result if result.margin > 0 else None

        best = lowest_certified_level(certified, max(norms), suboptimality, top_level, lower=max(norms))
        if best is not None:
            best.report = SolveReport(best.report.solver, best.report.status, time.perf_counter() - start,
                                      attempts)
            return best
        if not failed:
            raise SynthesisError(f"{what}: the SDP solver returned no point at any level from the largest "
                                 f"frozen norm {max(norms):.4g} up: lower the rate bound or check the loop",
                                 category="accuracy")
        top, where = max(failed)
        if np.any(design == where):  # the LMIs are imposed there already: refining cannot help
            break
        design = np.append(design, where)
    raise SynthesisError(f"{what}: no level up to γ = {top:.4g} (the largest frozen norm is "
                         f"{max(norms):.4g}) passes the certificate with the LMIs at "
                         f"{len(np.unique(design))} points, refined where it failed; it fails at "
                         f"p = {where:.4g}: lower the rate bound or add breakpoints near that point",
                         category="accuracy")


def _worst(result: RateBoundedGain, pairs: list, images: dict[float, Loop], gamma: float
           ) -> tuple[float, float]:
    """(smallest margin, p) of the certificate at γ: every P̃_i ≻ 0 and every pair's dissipation matrix."""
    b = result.schedule.breakpoints
    out = min((scaled_margin(P, np.abs(P)), float(bi)) for P, bi in zip(result.scaled, b, strict=True))
    for p, nexts in pairs:
        out = min(out, *((result.margin_at(images[p], p, q, gamma), p) for q in nexts))
    return out


class _MarginProblem:
    """The margin SDP of the module docstring at ``pairs``, compiled once with γ a Parameter: maximise t
    subject to every pair's matrix ⪯ −t·I and P̃_i ⪰ t·I (scaled coordinates), t ≤ 1."""

    def __init__(self, images: dict[float, Loop], pairs: list, schedule: Schedule, scalings: list[np.ndarray]
                 ) -> None:
        b = schedule.breakpoints
        m = scalings[0].shape[0]
        self.P_tilde = [cp.Variable((m, m), symmetric=True) for _ in b]
        self.gamma, t = cp.Parameter(pos=True), cp.Variable()
        gamma, P_tilde = self.gamma, self.P_tilde

        def storage(lam: np.ndarray, T: np.ndarray) -> cp.Expression:
            """Tᵀ𝒫(λ)T = Σ λ_i (S_iT)ᵀ P̃_i (S_iT)."""
            return sum(float(li) * ((scalings[i] @ T).T @ P_tilde[i] @ (scalings[i] @ T))
                       for i, li in enumerate(lam) if li != 0.0)

        constraints = [t <= 1] + [P >> t * np.eye(m) for P in P_tilde]
        inverses = [np.linalg.inv(S) for S in scalings]
        for p, nexts in pairs:
            T = inverses[int(np.argmin(np.abs(b - p)))]
            Ac, Bc, Cc, Dc = images[p]
            nw, nz = Bc.shape[1], Cc.shape[0]
            a, bc, cc = np.linalg.solve(T, Ac @ T), np.linalg.solve(T, Bc), Cc @ T
            N = np.hstack([(np.eye(m) + Ac) @ T, Bc]) / np.sqrt(2.0)  # [ζ̄; w] ↦ ξ⁺
            lam = schedule.weights(p)
            P = storage(lam, T)
            for q in nexts:
                F = cp.bmat([[a.T @ P + P @ a, P @ bc], [bc.T @ P, -gamma * np.eye(nw)]])
                dlam = schedule.weights(q) - lam
                if np.any(dlam != 0.0):
                    F = F + sum(float(d) * ((scalings[i] @ N).T @ P_tilde[i] @ (scalings[i] @ N))
                                for i, d in enumerate(dlam) if d != 0.0)
                M = cp.bmat([[F, np.vstack([cc.T, Dc.T])], [np.hstack([cc, Dc]), -gamma * np.eye(nz)]])
                constraints.append(0.5 * (M + M.T) << -t * np.eye(M.shape[0]))
        self.problem = cp.Problem(cp.Maximize(t), constraints)

    def solve(self, gamma: float, solver: str, what: str) -> SolveReport:
        self.gamma.value = gamma
        return solve(self.problem, solver, what)

    def scaled(self) -> list[np.ndarray]:
        """The P̃_i of the last solve."""
        return [0.5 * (P.value + P.value.T) for P in self.P_tilde]
