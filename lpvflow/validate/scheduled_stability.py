"""Stability of a gain-scheduled loop x⁺ = 𝒜(p)x under a bounded scheduling rate, certified on a grid.

One scheduling signal p(k) in [b_0, b_M] with |p(k+1) − p(k)| ≤ ν per sample (None: any jump in the
range). A storage V(k) = xᵀ𝒫(p(k))x with 𝒫 linear between breakpoints b_0 < … < b_M (hat functions λ_i,
𝒫 = Σλ_i𝒫_i) proves exponential stability along every admissible trajectory when, at every pair (p, p⁺),
𝒫(p) ≻ 0 and x⁺ᵀ𝒫(p⁺)x⁺ − xᵀ𝒫(p)x < 0 (a parameter-dependent Lyapunov function; Wu, Yang, Packard &
Becker 1996, "Induced L2-norm control for LPV systems with bounded parameter variation rates", IJRNC 6, in
discrete time; de Oliveira, Bernussou & Geromel 1999, "A new discrete-time robust stability condition",
Syst. Control Lett. 37). It is :mod:`lpvflow.synth.analysis` without input and output: in the coordinates
ζ = (x + x⁺)/√2 of the Cayley image A_c = :func:`lpvflow.synth.bilinear.cayley` (𝒜) at p, with
N = (I + A_c)/√2, the condition reads exactly

    A_cᵀ𝒫(p) + 𝒫(p)A_c + Nᵀ(𝒫(p⁺) − 𝒫(p))N ≺ 0,

affine in the 𝒫_i, and p⁺ at p ± ν (clipped) and the breakpoints between covers every admissible p⁺
(:meth:`lpvflow.synth.rate_bounded.Schedule.pairs`). The loop is not affine in p, so p is gridded
(``design_per_segment`` points per breakpoint interval and the breakpoints ± ν).

**Scaling.** 𝒫_i = S_iᵀP̃_iS_i with X_i = SᵢᵀS_i the solution of the shifted Lyapunov equation
(A_c + αI)ᵀX + X(A_c + αI) = −I of the loop's Cayley image at b_i, α half its distance to the imaginary
axis, divided by its largest eigenvalue: that storage proves the decay rate α (the unshifted one, −I on
the right, proved 10⁻⁹ on a loop whose slowest mode decays at 4·10⁻³), so P̃_i = I is a frozen
certificate with margin 2α; each pair's matrix is formed in the coordinates T = S_j⁻¹ of the breakpoint
b_j nearest p. The SDP: maximise t subject to tI ⪯ P̃_i ⪯ I (the upper bound only fixes the scale of a
homogeneous problem) and every pair's matrix ⪯ −tI, posed as one dense coefficient matrix per pair
(vec(UᵀP̃V) = (Vᵀ ⊗ Uᵀ)vec P̃). The solver is not trusted: the rate is certified when every P̃_i and every
pair's matrix, rebuilt in numpy (:func:`lpvflow.synth.analysis.dissipation_matrix`), is definite by more
than round-off (:func:`lpvflow.validate.stability.scaled_margin`) on the design points and on a grid
``per_segment`` times finer than the breakpoints.

**Block-triangular loops.** When the states split so that 𝒜(p) is block triangular at every p of that
grid (up to a permutation, the same for all p: the strongly connected components of its structural
pattern, in topological order) — e.g. a 2-DOF controller whose reference states are not driven by the
measurements — the loop is exponentially stable under the rate bound iff every diagonal block is: x_1
of [x_1; x_2]⁺ = [𝒜_11 0; 𝒜_21 𝒜_22][x_1; x_2] is autonomous, and x_2 is the exponentially stable
𝒜_22 driven by the bounded 𝒜_21x_1, an exponentially decaying input (variation of constants; the
converse holds with x_1(0) = 0). Each block is certified on its own; its storage is smaller. The first
block that fails ends the attempt at that rate (on the bundled ADIP loop a 5-state block fails in 1 s, and
the 16-state block after it took 33 s to return no point).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import cvxpy as cp
import numpy as np
import scipy.linalg
import scipy.sparse
from scipy.sparse.csgraph import connected_components

from lpvflow.errors import ModelError, SynthesisError
from lpvflow.synth.analysis import dissipation_matrix
from lpvflow.synth.bilinear import cayley
from lpvflow.synth.rate_bounded import FINE_PER_SEGMENT, Schedule, segment_grid
from lpvflow.synth.sdp import solve
from lpvflow.validate.stability import scaled_margin

#: Points per breakpoint interval at which the LMIs are imposed (besides the breakpoints ± ν).
DESIGN_PER_SEGMENT = 2


@dataclass
class BlockCertificate:
    """The storage of one diagonal block: its states, S_i and P̃_i of 𝒫_i = S_iᵀP̃_iS_i (module docstring),
    the SDP's margin t and the smallest re-checked margin with the p where it occurs."""

    states: np.ndarray
    scalings: list[np.ndarray]
    scaled: list[np.ndarray]
    t: float
    margin: float
    where: float


@dataclass
class ScheduledStability:
    """Outcome of :func:`scheduled_stability`: ``certified`` iff every block's re-checked margin is > 0;
    ``blocks`` the certificate of each diagonal block tried, in the triangular order, up to the first that
    fails (None for a block whose SDP returned no point), ``reason`` why not, ``seconds`` the wall time."""

    schedule: Schedule
    certified: bool
    blocks: list[BlockCertificate | None]
    reason: str
    seconds: float

    def margin(self, loop_at: Callable[[float], np.ndarray], per_segment: int = FINE_PER_SEGMENT
               ) -> tuple[float, float]:
        """(smallest margin, p) of this certificate for the loop ``loop_at`` (e.g. a perturbed one) on a grid
        ``per_segment`` times finer than the breakpoints, block by block: > 0 certifies it too when it is
        block triangular in the same blocks (only the diagonal blocks are checked)."""
        points = segment_grid(self.schedule.breakpoints, per_segment)
        worst = (np.inf, float(points[0]))
        for block in self.blocks:
            if block is None:
                return -np.inf, float(points[0])
            worst = min(worst, _recheck(self.schedule, block.scalings, block.scaled,
                                        partial(_block_at, loop_at, block.states), points))
        return worst


@dataclass
class RateLadder:
    """Outcome of :func:`largest_certified_rate`: every rate tried (None: any jump) and its result."""

    rates: list[float | None]
    results: list[ScheduledStability] = field(default_factory=list)

    @property
    def largest(self) -> float | None:
        """The largest certified rate (None: any jump; 0.0: none of the rates tried)."""
        certified = [r for r, res in zip(self.rates, self.results, strict=False) if res.certified]
        return certified[-1] if certified else 0.0

    @property
    def seconds(self) -> float:
        return float(sum(res.seconds for res in self.results))


def triangular_blocks(matrices: Sequence[np.ndarray]) -> list[np.ndarray]:
    """State index sets of the diagonal blocks of the finest block-triangular form shared by ``matrices``
    (strongly connected components of the union of their nonzero patterns, in topological order: no
    block is driven by a later one)."""
    pattern = np.zeros_like(np.asarray(matrices[0]), dtype=bool)
    for M in matrices:
        pattern |= np.asarray(M) != 0
    count, label = connected_components(scipy.sparse.csr_matrix(pattern), directed=True, connection="strong")
    # block u drives block v when some state of v reads a state of u (pattern[row in v, column in u])
    rows, cols = np.nonzero(pattern)
    drives = {(int(label[c]), int(label[r])) for r, c in zip(rows, cols, strict=True) if label[r] != label[c]}
    order: list[int] = []
    remaining = set(range(count))
    while remaining:
        ready = sorted(b for b in remaining if not any(u in remaining for u, v in drives if v == b))
        order += ready
        remaining -= set(ready)
    return [np.flatnonzero(label == b) for b in order]


def scheduled_stability(loop_at: Callable[[float], np.ndarray], breakpoints: Sequence[float],
                        rate_bound: float | None, *, design_per_segment: int = DESIGN_PER_SEGMENT,
                        per_segment: int = FINE_PER_SEGMENT, solver: str = "CLARABEL") -> ScheduledStability:
    """Certify x⁺ = 𝒜(p)x, 𝒜 = ``loop_at(p)``, for |p(k+1) − p(k)| ≤ ``rate_bound`` in [b_0, b_M] (module
    docstring; None: any jump), block by block (:func:`triangular_blocks` on the fine grid), up to the first
    block that fails.

    Raises:
        ModelError: bad breakpoints or rate bound; a frozen loop on the fine grid that has non-finite
            entries or is unstable (no rate is certified then; the message names the point).
    """
    start = time.perf_counter()
    schedule = Schedule(np.asarray(breakpoints, dtype=float), rate_bound)
    b = schedule.breakpoints
    design = segment_grid(b, design_per_segment)
    fine = np.union1d(segment_grid(b, per_segment), [p for p, _ in schedule.pairs(design)])
    loops = {float(p): np.asarray(loop_at(float(p)), dtype=float) for p in fine}
    for p, A in loops.items():
        if not np.all(np.isfinite(A)):
            raise ModelError(f"the loop at p = {p:.4g} has non-finite entries: check loop_at")
        radius = float(np.max(np.abs(np.linalg.eigvals(A))))
        if radius >= 1.0:
            raise ModelError(f"the frozen loop at p = {p:.4g} is unstable (spectral radius {radius:.6g}): "
                             "no rate is certified; fix the controller there first")
    blocks, reason = [], ""
    split = triangular_blocks(list(loops.values()))
    for states in split:
        block = _certify_block(schedule, states, {p: _block(A, states) for p, A in loops.items()}, design,
                               solver)
        blocks.append(block)
        if block is None or block.margin <= 0:  # not certified: no later block can change that
            where = ("the SDP solver returned no point" if block is None
                     else f"margin {block.margin:.3g} at p = {block.where:.4g}")
            later = len(split) - len(blocks)
            nu = "any" if rate_bound is None else f"{rate_bound:g}"
            reason = (f"not certified at ν = {nu} per sample: block of {len(states)} states ({where})"
                      + (f"; {later} later block(s) not tried" if later else ""))
            break
    return ScheduledStability(schedule, not reason, blocks, reason, time.perf_counter() - start)


def largest_certified_rate(loop_at: Callable[[float], np.ndarray], breakpoints: Sequence[float],
                           rates: Sequence[float | None], **options) -> RateLadder:
    """:func:`scheduled_stability` at each rate of the ascending ladder ``rates`` (None, last: any jump),
    stopping at the first that is not certified; ``options`` are passed on.

    Raises:
        ModelError: an empty or non-ascending ladder, or what :func:`scheduled_stability` raises.
    """
    finite = [r for r in rates if r is not None]
    if not rates or None in rates[:-1] or np.any(np.diff(finite) <= 0):
        raise ModelError(f"rates must be an ascending list of rates per sample, optionally ending with None "
                         f"(any jump), got {list(rates)!r}")
    ladder = RateLadder(list(rates))
    for rate in rates:
        result = scheduled_stability(loop_at, breakpoints, rate, **options)
        ladder.results.append(result)
        if not result.certified:
            break
    return ladder


def _block(A: np.ndarray, states: np.ndarray) -> np.ndarray:
    return A[np.ix_(states, states)]


def _block_at(loop_at: Callable[[float], np.ndarray], states: np.ndarray, p: float) -> np.ndarray:
    return _block(np.asarray(loop_at(p), dtype=float), states)


def _image(A: np.ndarray) -> np.ndarray:
    """A_c of the discrete A (:func:`lpvflow.synth.bilinear.cayley` without inputs and outputs)."""
    m = A.shape[0]
    return cayley(A, np.zeros((m, 0)), np.zeros((0, m)), np.zeros((0, 0)))[0]


def _scaling(Ac: np.ndarray) -> np.ndarray:
    """S with SᵀS the shifted Lyapunov storage of A_c divided by its largest eigenvalue (module docstring)."""
    m = Ac.shape[0]
    alpha = -0.5 * float(np.max(np.linalg.eigvals(Ac).real))
    X = scipy.linalg.solve_continuous_lyapunov((Ac + alpha * np.eye(m)).T, -np.eye(m))
    w, U = np.linalg.eigh(0.5 * (X + X.T))
    w = np.clip(w / w[-1], 1e-12, None)
    return (U * np.sqrt(w)[None, :]).T


def _certify_block(schedule: Schedule, states: np.ndarray, loops: dict[float, np.ndarray],
                   design: np.ndarray, solver: str) -> BlockCertificate | None:
    """The margin SDP of the module docstring for one block and its numpy re-check on every p of
    ``loops`` (the block's 𝒜 on the design pairs and the fine grid); None when the solver returned no
    point."""
    b = schedule.breakpoints
    images = {p: _image(A) for p, A in loops.items()}
    m = len(states)
    scalings = [_scaling(images[float(bi)]) for bi in b]
    inverses = [np.linalg.inv(S) for S in scalings]
    P_tilde = [cp.Variable((m, m), symmetric=True) for _ in b]
    vecs = [cp.vec(P, order="F") for P in P_tilde]
    t = cp.Variable()
    constraints = [c for P in P_tilde for c in (P << np.eye(m), P >> t * np.eye(m))]
    for p, nexts in schedule.pairs(design):
        T = inverses[int(np.argmin(np.abs(b - p)))]
        a = np.linalg.solve(T, images[p] @ T)
        N = (np.eye(m) + images[p]) @ T / np.sqrt(2.0)
        lam = schedule.weights(p)
        frozen = {}
        for i, li in enumerate(lam):  # λ_i (aᵀWᵀP̃W + WᵀP̃Wa), W = S_iT
            if li:
                W = scalings[i] @ T
                frozen[i] = li * (np.kron(W.T, (W @ a).T) + np.kron((W @ a).T, W.T))
        for q in nexts:
            coefficients = dict(frozen)
            for i, d in enumerate(schedule.weights(q) - lam):  # (λ_i(p⁺) − λ_i(p)) (S_iN)ᵀP̃(S_iN)
                if d:
                    SN = scalings[i] @ N
                    coefficients[i] = coefficients.get(i, 0.0) + d * np.kron(SN.T, SN.T)
            M = cp.reshape(sum(C @ vecs[i] for i, C in coefficients.items()), (m, m), order="F")
            constraints.append(0.5 * (M + M.T) << -t * np.eye(m))
    what = (f"the rate-bounded stability LMIs ({m} states, ν = "
            f"{'any' if schedule.rate_bound is None else f'{schedule.rate_bound:g}'} per sample)")
    try:
        solve(cp.Problem(cp.Maximize(t), constraints), solver, what)
    except SynthesisError:
        return None
    scaled = [0.5 * (P.value + P.value.T) for P in P_tilde]
    margin, where = _recheck(schedule, scalings, scaled, loops.__getitem__, np.asarray(list(loops)))
    return BlockCertificate(states, scalings, scaled, float(t.value), margin, where)


def _recheck(schedule: Schedule, scalings: list[np.ndarray], scaled: list[np.ndarray],
             loop_at: Callable[[float], np.ndarray], points: np.ndarray) -> tuple[float, float]:
    """(smallest margin, p): every P̃_i and every pair's matrix at ``points`` and the breakpoints ± ν
    (p⁺ from :meth:`Schedule.pairs`), rebuilt in numpy from ``loop_at(p)`` and judged by
    :func:`scaled_margin`."""
    b = schedule.breakpoints
    worst = min((scaled_margin(P, np.abs(P)), float(bi)) for P, bi in zip(scaled, b, strict=True))
    inverses = [np.linalg.inv(S) for S in scalings]

    def storage(p: float, T: np.ndarray) -> np.ndarray:
        """Tᵀ𝒫(p)T = Σ λ_i(p)(S_iT)ᵀP̃_i(S_iT)."""
        return sum(li * ((S @ T).T @ P @ (S @ T))
                   for li, S, P in zip(schedule.weights(p), scalings, scaled, strict=True) if li)

    m = scaled[0].shape[0]
    empty = (np.zeros((m, 0)), np.zeros((0, m)), np.zeros((0, 0)))
    for p, nexts in schedule.pairs(points):
        T = inverses[int(np.argmin(np.abs(b - p)))]
        loop = (loop_at(p), *empty)
        P_now = storage(p, T)
        for q in nexts:
            M, E = dissipation_matrix(loop, P_now, storage(q, T), 0.0, T)
            worst = min(worst, (scaled_margin(-M, E), p))
    return worst
