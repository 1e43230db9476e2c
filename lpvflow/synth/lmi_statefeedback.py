"""Polytopic state-feedback H∞ synthesis with an optional disk pole region, discrete time.

A library API (no ``[synth] method`` uses it: the design's plants measure outputs, not states), for a
generalized plant whose states are all measured, e.g. a model in state coordinates with its weights::

    from lpvflow.synth.examples import random_lpv
    from lpvflow.synth.lmi_statefeedback import synthesize_state_feedback
    from lpvflow.synth.plant import generalized_plant
    from lpvflow.synth.statefeedback_certificate import certify_state_feedback

    model = random_lpv(seed=2, nx=2)
    weights = {"S": {"num": [0.1, 0.1], "den": [1, -1]}, "K": {"num": [0.01], "den": [1]},
               "B": {"num": [0, 0.5], "den": [1, -0.5]}}
    plant = generalized_plant(model, weights)
    result = synthesize_state_feedback(plant, "dilated", disk=(0.5, 0.45))
    K = result.gain_at(model.basis.p_min)          # the gain u = K x at one scheduling value
    assert certify_state_feedback(result, model, plant.weights).ok

Plant at vertex i (the generalized plant of :mod:`lpvflow.synth.plant`, state x = [x_plant; x_weights],
every state measured; or plain vertex tuples):

    x⁺ = A_i x + B1_i w + B2_i u,   z = C1_i x + D11_i w + D12_i u,   u = K(θ) x,

closed loop 𝒜_i = A_i + B2_iK_i, 𝒞_i = C1_i + D12_iK_i, ℬ_i = B1_i, 𝒟_i = D11_i. With
K(θ) = Σ λ_i(θ) K_i (λ the convex coordinates of the design polytope) the closed loop is affine in λ
only when B2 and D12 are the same at every vertex. When either varies, one constant gain K is
designed instead (one common W, resp. Z, below); :attr:`StateFeedbackResult.scheduled` says which.

**Bounded-real lemma** (dual form, de Oliveira, Geromel & Bernussou 2002, with γ in both identity
blocks so that γ itself is the linear SDP objective): ‖T_zw‖∞ < γ if there are P ≻ 0 and G with

    ⎡ P     𝒜G          ℬ     0    ⎤
    ⎢ ⋆     G + Gᵀ − P   0     Gᵀ𝒞ᵀ ⎥ ≻ 0                                             (H)
    ⎢ ⋆     ⋆            γI    𝒟ᵀ   ⎥
    ⎣ ⋆     ⋆            ⋆     γI   ⎦

(de Oliveira, Geromel & Bernussou 2002, IJC 75(9), Thm. 3: G + Gᵀ − P ⪯ GᵀP⁻¹G, a congruence with
diag(I, G⁻¹, I, I) then gives the dual bounded-real LMI in P; the congruence
diag(√γ I, √γ I, I/√γ, √γ I) turns γI, γI into I, γ²I and multiplies P, G by γ.) With Z = KG,
𝒜G = A G + B2 Z and 𝒞G = C1 G + D12 Z are linear in (G, Z).

* Method ``"quadratic"`` (common Lyapunov function, arbitrarily fast θ; Boyd et al. 1994 ch. 7, in the
  dual form of Gahinet & Apkarian 1994): G = P = X ≻ 0 common, W_i = K_i X, the LMI (H_i) at every
  vertex i with (2,2) block X; K_i = W_i X⁻¹. Since X is common, Σ λ_i W_i = K(θ)X, and (H) is affine
  in λ, so the vertex LMIs hold over the polytope and for every trajectory θ(k) (V = xᵀX⁻¹x).
* Method ``"dilated"`` (de Oliveira, Bernussou & Geromel 1999, Syst. Control Lett. 37, "A new
  discrete-time robust stability condition"; de Oliveira, Geromel & Bernussou 2002): vertex Lyapunov
  matrices P_i, one slack G, Z_i = K_iG, so K_i = Z_iG⁻¹. For time-varying θ(k) the (1,1) block holds
  P at the next sample and the (2,2) block at the current one:

      (H_ij):  P → P_j in (1,1),  P → P_i in (2,2),  (A, B1, B2, C1, D11, D12, Z) → vertex i,

  imposed at every pair (i, j); affine in λ(k) and λ(k+1) separately, so it holds for every trajectory
  (arbitrary rate of variation; poly-quadratic V = xᵀP(θ)⁻¹x, Daafouz & Bernussou 2001).
  G = P_i = X, Z_i = W_i turns (H_ij) into (H_i) of ``"quadratic"``: every quadratic point is dilated
  feasible, so γ_dilated ≤ γ_quadratic.

**Disk pole region** D(q, r) = {z : |z − q| < r} (Chilali & Gahinet 1996, IEEE TAC 41(3), LMI region
with L = [−r −q; −q −r], M = [0 1; 0 0]; discrete-time regions in Chilali, Gahinet & Apkarian 1999,
IEEE TAC 44(12)): eig(𝒜) ⊂ D(q, r) ⇔ Â = (𝒜 − qI)/r is Schur ⇔ ∃ X ≻ 0 with ÂXÂᵀ − X ≺ 0, i.e. by a
Schur complement (times r)

    ⎡ −rX          𝒜X − qX ⎤
    ⎣ (𝒜X − qX)ᵀ   −rX     ⎦ ≺ 0,        𝒜X = A_iX + B2W_i                             (D_i)

with the X of (H_i) for ``"quadratic"`` (affine in λ, so every frozen closed loop of the polytope has
its eigenvalues in the disk). For ``"dilated"``, the dilated Schur test of de Oliveira et al. (1999)
for Â with the same G and its own vertex matrices Q_i, multiplied by r:

    ⎡ rQ_i   A_iG + B2_iZ_i − qG ⎤
    ⎣ ⋆      r(G + Gᵀ − Q_i)      ⎦ ≻ 0                                               (D̃_i)

(affine in λ for a frozen θ; G = Q_i = X recovers (D_i)). Only frozen eigenvalues are constrained.

Numerics (see :func:`synthesize_state_feedback`): γ is the SDP objective (step 1),
then the LMIs are solved at γ = (1 + suboptimality)·γ_opt for a centred, strictly feasible point
(step 2); every LMI ⪰ margin·I; every Lyapunov matrix and sym G ⪯ β·I (β = 1e6) in scaled
coordinates, which are re-centred on the previous point over a few passes; bisection on step 2 when
step 1 fails numerically. The returned numbers are re-evaluated in numpy in the original coordinates
(:func:`vertex_lmi_max_eig`) and the result is refused unless every LMI holds strictly, whatever the
solver status (``optimal_inaccurate`` is accepted only that way).
:func:`lpvflow.synth.statefeedback_certificate.certify_state_feedback` adds the independent closed-loop
checks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import cvxpy as cp
import numpy as np
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.synth.plant import GeneralizedPlant
from lpvflow.synth.polytope import Polytope
from lpvflow.synth.sdp import SolveReport, SynthesisError, psd, solve

METHODS = ("quadratic", "dilated")
_BOUND = 1e6  # Lyapunov matrices and sym G ⪯ β·I in the scaled coordinates
_CONST_TOL = 1e-10


@dataclass(frozen=True)
class SFVertex:
    """State-feedback plant at one vertex: x⁺ = Ax + B1w + B2u, z = C1x + D11w + D12u."""

    A: np.ndarray
    B1: np.ndarray
    B2: np.ndarray
    C1: np.ndarray
    D11: np.ndarray
    D12: np.ndarray

    @property
    def dims(self) -> tuple[int, int, int, int]:
        """(n, nw, nu, nz)."""
        return self.A.shape[0], self.B1.shape[1], self.B2.shape[1], self.C1.shape[0]

    def closed_loop(self, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A + B2K, B1, C1 + D12K, D11)."""
        return self.A + self.B2 @ K, self.B1, self.C1 + self.D12 @ K, self.D11


def as_vertices(plant: GeneralizedPlant | Sequence) -> list[SFVertex]:
    """State-feedback vertices of a GeneralizedPlant (its C2, D21, D22 are not used: the state is measured)
    or of a sequence of (A, B1, B2, C1, D11, D12) tuples (or SFVertex)."""
    if isinstance(plant, GeneralizedPlant):
        return [SFVertex(v.A, v.B1, v.B2, v.C1, v.D11, v.D12) for v in plant.vertices]
    verts = []
    for k, mats in enumerate(plant):
        if isinstance(mats, SFVertex):
            verts.append(mats)
            continue
        if len(mats) != 6:
            raise ModelError(f"vertex {k}: need (A, B1, B2, C1, D11, D12), got {len(mats)} matrices")
        A, B1, B2, C1, D11, D12 = (np.atleast_2d(np.asarray(M, dtype=float)) for M in mats)
        n, nw, nu, nz = A.shape[0], B1.shape[1], B2.shape[1], C1.shape[0]
        expected = {"A": (n, n), "B1": (n, nw), "B2": (n, nu), "C1": (nz, n), "D11": (nz, nw),
                    "D12": (nz, nu)}
        for name, M in zip(expected, (A, B1, B2, C1, D11, D12), strict=True):
            if M.shape != expected[name]:
                raise ModelError(f"vertex {k}: {name} has shape {M.shape}; expected {expected[name]}")
        verts.append(SFVertex(A, B1, B2, C1, D11, D12))
    if not verts:
        raise ModelError("state-feedback synthesis needs at least one vertex")
    if len({v.dims for v in verts}) != 1:
        raise ModelError(f"vertices differ in size: {sorted({v.dims for v in verts})}")
    return verts


def _constant(verts: list[SFVertex], name: str) -> bool:
    ref = getattr(verts[0], name)
    scale = max(1.0, np.max(np.abs(ref), initial=0.0))
    return all(np.max(np.abs(getattr(v, name) - ref), initial=0.0) <= _CONST_TOL * scale for v in verts)


@dataclass
class StateFeedbackResult:
    """Vertex gains K_i (u = K(θ)x, K(θ) = Σ λ_i K_i) with the γ they are certified for.

    For a GeneralizedPlant, x = [x_plant; x_weights] and u is its control input, i.e. the input of the
    filter W_B when the design has one (W_B's state is part of x).

    Attributes:
        gamma: the γ of the returned certificate; gamma_opt: the smallest γ of the γ minimisation (with
            bisection: the largest γ at which no re-checked point was found).
        report: solver, passes and statuses, total solve time.
        scheduled: False when B2 or D12 varies over the vertices: then every K_i is the same gain.
        P, G: Lyapunov matrices and slack of (H) in the original coordinates (P_i = G = X for
            ``"quadratic"``); Q: those of the disk LMI (None without a disk; Q_i = X for ``"quadratic"``).
        polytope, basis: how θ maps to λ (None for plain vertex lists: use :meth:`gain` with λ).
        lmi_max_eig: :func:`vertex_lmi_max_eig` of the returned numbers (< 0: certified).
    """

    method: str
    gamma: float
    gamma_opt: float
    K_vertices: list[np.ndarray]
    scheduled: bool
    P: list[np.ndarray]
    G: np.ndarray
    Q: list[np.ndarray] | None
    disk: tuple[float, float] | None
    vertices: list[SFVertex]
    report: SolveReport
    Ts: float = 1.0
    polytope: Polytope | None = None
    basis: Basis | None = None
    lmi_max_eig: float = float("nan")

    def gain(self, lam: np.ndarray) -> np.ndarray:
        """K = Σ λ_i K_i at convex coordinates λ."""
        lam = np.asarray(lam, dtype=float).reshape(-1)
        if lam.size != len(self.K_vertices):
            raise ModelError(f"λ has {lam.size} entries; the design has {len(self.K_vertices)} vertices")
        return np.tensordot(lam, np.array(self.K_vertices), axes=1)

    def coordinates(self, p: np.ndarray) -> np.ndarray:
        """λ(p) of the design polytope for one scheduling point p (n_p,)."""
        if self.polytope is None or self.basis is None:
            raise ModelError("this design was made from plain vertex lists: give λ to gain(), not p")
        psi = self.basis.eval(np.atleast_1d(np.asarray(p, dtype=float)).reshape(1, -1), check_range=False)
        return self.polytope.coordinates(psi[0])

    def gain_at(self, p: np.ndarray) -> np.ndarray:
        """K(θ(p)) = Σ λ_i(p) K_i."""
        return self.gain(self.coordinates(p))


def _scalings(verts: list[SFVertex]) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal state and control scalings (s, d_u).

    s balances the mean |A_i| (Parlett–Reinsch), clipped to [1e-6, 1e6]; d_u makes every column of
    [S⁻¹B2_i; D12_i] have unit largest entry over all vertices (B2 may vary here). w and z are not
    scaled: that would change ‖T_zw‖∞.
    """
    mean_abs = np.mean([np.abs(v.A) for v in verts], axis=0)
    _, (s, _) = scipy.linalg.matrix_balance(mean_abs, permute=False, separate=True)
    s = np.clip(s, 1e-6, 1e6)
    cols = np.max([np.max(np.abs(np.vstack([v.B2 / s[:, None], v.D12])), axis=0) for v in verts], axis=0)
    return s, 1.0 / np.maximum(cols, 1e-12)


def _transformed(v: SFVertex, T: np.ndarray, du: np.ndarray) -> SFVertex:
    """The vertex in x̃ = T⁻¹x, ũ = D_u⁻¹u."""
    Ti = np.linalg.inv(T)
    return SFVertex(Ti @ v.A @ T, Ti @ v.B1, Ti @ v.B2 * du[None, :], v.C1 @ T, v.D11, v.D12 * du[None, :])


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    """L with L Lᵀ = M for a symmetric M ≻ 0 (eigenvalues clipped at 1e-12·max: the solver's round-off)."""
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    return V * np.sqrt(np.clip(w, 1e-12 * w[-1], None))[None, :]


def hinf_block(Pnext, AG, B1, Pcur, CG, D11, w_scale, z_scale):
    """The matrix of (H) (module docstring) with w_scale·I, z_scale·I in the (3,3), (4,4) blocks (γ, γ in
    the synthesis, 1, γ² in the re-check), for numbers or cvxpy expressions; Pcur is the (2,2) block."""
    n, nw, nz = AG.shape[0], B1.shape[1], CG.shape[0]
    rows = [
        [Pnext, AG, B1, np.zeros((n, nz))],
        [AG.T, Pcur, np.zeros((n, nw)), CG.T],
        [B1.T, np.zeros((nw, n)), w_scale * np.eye(nw), D11.T],
        [np.zeros((nz, n)), CG, D11, z_scale * np.eye(nz)],
    ]
    return np.block(rows) if isinstance(Pnext, np.ndarray) else cp.bmat(rows)


def disk_block(Qi, AG, G, Gsym_minus_Q, q: float, r: float):
    """The matrix of (D̃_i) (module docstring): [[r Q_i, AG − qG], [⋆, r(G + Gᵀ − Q_i)]]."""
    off = AG - q * G
    rows = [[r * Qi, off], [off.T, r * Gsym_minus_Q]]
    return np.block(rows) if isinstance(Qi, np.ndarray) else cp.bmat(rows)


@dataclass
class _Lmis:
    G: cp.Variable
    Z: list
    P: list
    Q: list | None
    matrices: list
    bounded: list


def _lmis(verts: list[SFVertex], method: str, disk: tuple[float, float] | None, scheduled: bool,
          gamma: cp.Expression | float) -> _Lmis:
    """Variables and LMI matrices (H_ij), (D̃_i) of ``method`` (module docstring)."""
    n, _, nu, _ = verts[0].dims
    N = len(verts)
    quadratic = method == "quadratic"
    G = cp.Variable((n, n), symmetric=quadratic)
    if scheduled:
        Z = [cp.Variable((nu, n)) for _ in range(N)]
    else:
        Z = [cp.Variable((nu, n))] * N
    P = [G] * N if quadratic else [cp.Variable((n, n), symmetric=True) for _ in range(N)]
    matrices, bounded = [], ([G] if quadratic else [*P, 0.5 * (G + G.T)])
    for i, v in enumerate(verts):
        AG, CG = v.A @ G + v.B2 @ Z[i], v.C1 @ G + v.D12 @ Z[i]
        cur = G if quadratic else G + G.T - P[i]
        for j in (i,) if quadratic else range(N):
            matrices.append(hinf_block(P[j], AG, v.B1, cur, CG, v.D11, gamma, gamma))
    Q = None
    if disk is not None:
        q, r = disk
        Q = [G] * N if quadratic else [cp.Variable((n, n), symmetric=True) for _ in range(N)]
        bounded += [] if quadratic else Q
        for i, v in enumerate(verts):
            AG = v.A @ G + v.B2 @ Z[i]
            matrices.append(disk_block(Q[i], AG, G, (G if quadratic else G + G.T - Q[i]), q, r))
    return _Lmis(G, Z, P, Q, matrices, bounded)


def _bounds(lmis: _Lmis) -> list[cp.Constraint]:
    n = lmis.G.shape[0]
    return [0.5 * (B + B.T) << _BOUND * np.eye(n) for B in lmis.bounded]


class _Pass:
    """The LMIs of one pass in fixed coordinates x̃ = T⁻¹x, ũ = D_u⁻¹u: γ minimisation (step 1) and the
    feasibility problem at a fixed γ (a cvxpy Parameter: compiled once for the bisection)."""

    def __init__(self, verts: list[SFVertex], T: np.ndarray, du: np.ndarray, spec: dict) -> None:
        self.verts, self.T, self.du, self.spec = verts, T, du, spec
        self.sverts = [_transformed(v, T, du) for v in verts]
        self.gamma = cp.Parameter(nonneg=True)
        self.fixed = _lmis(self.sverts, spec["method"], spec["disk"], spec["scheduled"], self.gamma)
        self.feasibility = cp.Problem(cp.Minimize(0), [psd(M, spec["margin"]) for M in self.fixed.matrices]
                                      + _bounds(self.fixed))
        self.reports: list[SolveReport] = []

    def minimise(self) -> float:
        """Step 1: min γ subject to every LMI ⪰ margin·I (and γ ≤ gamma_max); raises SynthesisError."""
        spec = self.spec
        g = cp.Variable(nonneg=True)
        lmis = _lmis(self.sverts, spec["method"], spec["disk"], spec["scheduled"], g)
        constraints = [psd(M, spec["margin"]) for M in lmis.matrices] + _bounds(lmis)
        if spec["gamma_max"] is not None:
            constraints.append(g <= spec["gamma_max"])
        self.reports.append(solve(cp.Problem(cp.Minimize(g), constraints), spec["solver"], spec["what"]))
        return float(g.value)

    def point(self, gamma: float, gamma_opt: float) -> StateFeedbackResult | None:
        """Step 2: the centred point at γ, unscaled and re-checked; None if no solver returned one."""
        self.gamma.value = gamma
        try:
            what = f"{self.spec['what']} at γ = {gamma:.6g}"
            self.reports.append(solve(self.feasibility, self.spec["solver"], what))
        except SynthesisError:
            return None
        return _result(self.verts, self.fixed, self.T, self.du, gamma, gamma_opt, self.spec)

    def bisect(self, start: float, rel_tol: float) -> StateFeedbackResult | None:
        """Smallest γ with a re-checked point, by geometric bisection (gamma_opt = the last failing γ)."""
        gamma_max = self.spec["gamma_max"]
        lo, hi, best = 0.0, start, None
        for _ in range(4):  # up to 4⁴ = 256·start: beyond that the LMIs are not going to become feasible
            best = self.point(hi, lo)
            if best is not None and best.lmi_max_eig < 0:
                break
            lo, hi, best = hi, 4.0 * hi, None
            if gamma_max is not None and lo >= gamma_max:
                return None
            hi = hi if gamma_max is None else min(hi, gamma_max)
        if best is None:
            return None
        for _ in range(8):
            if lo > 0:
                break
            down = self.point(hi / 4.0, 0.0)
            if down is not None and down.lmi_max_eig < 0:
                hi, best = hi / 4.0, down
            else:
                lo = hi / 4.0
        while lo > 0 and hi / lo > 1.0 + rel_tol:
            mid = np.sqrt(lo * hi)
            cand = self.point(mid, lo)
            if cand is not None and cand.lmi_max_eig < 0:
                hi, best = mid, cand
            else:
                lo = mid
        best.gamma_opt = lo
        return best


def synthesize_state_feedback(
    plant: GeneralizedPlant | Sequence, method: str = "quadratic", disk: tuple[float, float] | None = None,
    solver: str = "CLARABEL", margin: float = 1e-7, gamma_max: float | None = None,
    suboptimality: float = 1e-2, Ts: float | None = None, passes: int = 4, seed_quadratic: bool = True,
) -> StateFeedbackResult:
    """γ-optimal polytopic state feedback u = K(θ)x of ``method`` (``"quadratic"`` or ``"dilated"``).

    Each pass solves, in coordinates x̃ = T⁻¹x, ũ = D_u⁻¹u,

    1. minimise γ subject to every LMI ⪰ margin·I and the Lyapunov matrices, sym G ⪯ β·I: γ_opt;
    2. the same LMIs at the fixed γ = (1 + suboptimality)·γ_opt with zero objective: the interior
       point method returns a strictly feasible, centred point, the candidate certificate, which is
       unscaled and re-evaluated in numpy (:func:`vertex_lmi_max_eig`).

    When step 1 fails numerically (the γ-optimal LMIs are singular at the optimum; Clarabel stalls at a
    relative gap of 4e-4 on an adip_like vertex) or its candidate fails the re-check, γ is found by
    geometric bisection on step 2 instead (to a relative width suboptimality/2; γ_opt is then the
    largest γ without a re-checked point).

    The first pass uses the diagonal T = S of :func:`_scalings`. Near-singular problems (poles near
    z = 1 and small control weights, where the optimal gains are large) need Lyapunov matrices far
    outside β·I in those coordinates, and the solver then stops well above the optimum (maglev_like
    quadratic: γ_opt = 1.875 instead of 1.473). So every further pass re-centres the coordinates on
    the previous pass's certificate: T = L with L Lᵀ = X/γ (X = P_1 = … = P_N for ``"quadratic"``, the
    mean of the P_i for ``"dilated"``, original coordinates), in which that point is X̃ = I and β·I lets
    it grow by 1e6 again. The passes stop when γ_opt improves by less than suboptimality/4, after
    ``passes`` passes, or when a pass finds no point; the best re-checked point is returned.

    ``"dilated"`` with ``seed_quadratic`` first runs ``"quadratic"``: its point, as G = P_i = Q_i = X,
    Z_i = W_i, is a dilated certificate (module docstring), the incumbent, and the first dilated pass
    is centred on it. So γ_dilated ≤ γ_quadratic holds also where the solver stops early (maglev_like
    without the start: 1.47308 against a quadratic 1.47213), and the dilated passes start well scaled.

    Args:
        plant: a :class:`GeneralizedPlant` (state = plant + weight states) or (A, B1, B2, C1, D11, D12)
            per vertex.
        disk: (q, r), closed-loop eigenvalues in {|z − q| < r} at every frozen θ (q real, r > 0), or None.
        margin: strictness, every LMI ⪰ margin·I (in the pass's coordinates).
        gamma_max: demand γ ≤ gamma_max; suboptimality: the returned γ is (1 + suboptimality)·γ_opt.
        Ts: sampling time for plain vertex lists (a GeneralizedPlant brings its own; default 1).
        passes: at most this many passes; seed_quadratic: start ``"dilated"`` from ``"quadratic"``.

    Raises:
        SynthesisError: infeasible LMIs (with the reason in terms of the plant), or no point that passes
            the independent re-check.
    """
    if method not in METHODS:
        raise ModelError(f"unknown state-feedback method {method!r}; use one of {', '.join(METHODS)}")
    if disk is not None:
        q, r = (float(x) for x in disk)
        if not (np.isfinite(q) and np.isfinite(r) and r > 0):
            raise ModelError(f"disk must be (centre q, radius r > 0), got {disk}")
        disk = (q, r)
    verts = as_vertices(plant)
    scheduled = _constant(verts, "B2") and _constant(verts, "D12")
    what = (f"{method} state-feedback H∞ LMIs at {len(verts)} vertices"
            + (f" with poles in the disk |z − {disk[0]:g}| < {disk[1]:g}" if disk else "")
            + (f" and γ ≤ {gamma_max:g}" if gamma_max is not None else ""))
    spec = {"method": method, "disk": disk, "scheduled": scheduled, "margin": margin, "solver": solver,
            "gamma_max": gamma_max, "what": what}
    s, du = _scalings(verts)
    T = np.diag(s)
    best, reports, notes = None, [], []
    if method == "dilated" and seed_quadratic:
        try:
            quad = synthesize_state_feedback(verts, "quadratic", disk, solver, margin, gamma_max,
                                             suboptimality, passes=passes)
        except SynthesisError as exc:
            notes.append(f"no quadratic start ({str(exc)[:60]}…)")
        else:
            X, N = quad.G, len(verts)
            best = dataclasses.replace(quad, method="dilated", P=[X] * N, Q=None if disk is None else [X] * N)
            best.lmi_max_eig = vertex_lmi_max_eig(best)
            reports.append(quad.report)
            notes.append(f"quadratic start γ = {quad.gamma:.6g}")
            T = _sqrt_psd(X / quad.gamma)
    for k in range(passes):
        step = _Pass(verts, T, du, spec)
        candidate = None
        try:
            gamma_opt = step.minimise()
            gamma = gamma_opt * (1.0 + suboptimality)
            candidate = step.point(gamma if gamma_max is None else max(min(gamma, gamma_max), gamma_opt),
                                   gamma_opt)
            note = f"γ minimised ({step.reports[0].status})"
        except SynthesisError as exc:
            if "infeasible" in str(exc):
                if best is None:
                    reason = infeasibility_reason(verts, disk, gamma_max, scheduled)
                    raise SynthesisError(f"{exc}: {reason}", category=exc.category) from None
                reports += step.reports  # a re-centred pass the solver calls infeasible: keep the best
                notes.append(f"pass {k + 1}: stopped, the solver reports infeasible")
                break
            gamma_opt, note = None, f"γ minimisation failed ({str(exc)[-60:]})"
        if candidate is None or not candidate.lmi_max_eig < 0:
            start = gamma_opt if gamma_opt else (best.gamma if best is not None else 1.0)
            candidate = step.bisect(start, 0.5 * suboptimality)
            note += ", bisection used"
        note = f"pass {k + 1}: {note}"
        reports += step.reports
        notes.append(note)
        if candidate is None:
            if best is None:
                raise SynthesisError(f"{what}: no strictly feasible point that passes the independent "
                                     f"vertex-LMI re-check ({'; '.join(notes)}): "
                                     f"{infeasibility_reason(verts, disk, gamma_max, scheduled)}",
                                     category="accuracy")
            break
        previous, best = best, candidate if best is None or candidate.gamma < best.gamma else best
        if previous is not None and candidate.gamma_opt > previous.gamma_opt * (1.0 - 0.25 * suboptimality):
            break
        lyap = np.mean(candidate.P, axis=0) / candidate.gamma
        T = _sqrt_psd(0.5 * (lyap + lyap.T))
    attempts = [a for rep in reports for a in rep.attempts]
    status = "; ".join(notes) + f"; last solve {reports[-1].status}"
    best.report = SolveReport(reports[-1].solver, status, sum(a[2] for a in attempts), attempts)
    if isinstance(plant, GeneralizedPlant):
        best.Ts, best.polytope, best.basis = plant.Ts, plant.polytope, plant.basis
    elif Ts is not None:
        best.Ts = float(Ts)
    return best


def _result(verts: list[SFVertex], lmis: _Lmis, T: np.ndarray, du: np.ndarray, gamma: float,
            gamma_opt: float, spec: dict) -> StateFeedbackResult:
    """Back to x = Tx̃, u = D_uũ: K = D_u K̃ T⁻¹ with K̃ = Z̃G̃⁻¹; P = γ T P̃ Tᵀ, G = γ T G̃ Tᵀ,
    Q = γ T Q̃ Tᵀ (the γ factor turns the γI, γI blocks into I, γ²I; (D̃) is homogeneous, so Q takes
    the same factor as G)."""
    Gs = np.array(lmis.G.value, dtype=float)
    back = lambda M: gamma * T @ np.asarray(M.value, dtype=float) @ T.T  # noqa: E731
    Ti = np.linalg.inv(T)
    K = [du[:, None] * np.linalg.solve(Gs.T, np.asarray(Z.value, dtype=float).T).T @ Ti for Z in lmis.Z]
    P = [back(Pi) for Pi in lmis.P]
    Q = None if lmis.Q is None else [back(Qi) for Qi in lmis.Q]
    result = StateFeedbackResult(spec["method"], gamma, gamma_opt, K, spec["scheduled"], P, back(lmis.G), Q,
                                 spec["disk"], verts, SolveReport("", "", 0.0))
    result.lmi_max_eig = vertex_lmi_max_eig(result)
    return result


def _jacobi_max_eig(M: np.ndarray) -> float:
    """λ_max(−M) after the Jacobi scaling D^{-1/2} M D^{-1/2}, D = diag M (a congruence: keeps the sign)."""
    M = 0.5 * (M + M.T)
    d = np.sqrt(np.clip(np.diag(M), 1e-300, None))
    return float(-np.linalg.eigvalsh(M / d[:, None] / d[None, :])[0])


def vertex_lmi_max_eig(result: StateFeedbackResult) -> float:
    """max over the LMIs (H_ij) and (D̃_i) of λ_max(−M) (Jacobi-scaled), evaluated in numpy with the
    returned K_i, P_i, G, Q_i, γ in the original coordinates (𝒜G = (A_i + B2_iK_i)G: Z is not used)."""
    G, N = result.G, len(result.vertices)
    quadratic = result.method == "quadratic"
    worst = -np.inf
    for i, (v, K) in enumerate(zip(result.vertices, result.K_vertices, strict=True)):
        A, B, C, D = v.closed_loop(K)
        cur = G if quadratic else G + G.T - result.P[i]
        for j in (i,) if quadratic else range(N):
            M = hinf_block(result.P[j], A @ G, B, cur, C @ G, D, 1.0, result.gamma**2)
            worst = max(worst, _jacobi_max_eig(M))
        if result.disk is not None:
            Qi = result.Q[i]
            M = disk_block(Qi, A @ G, G, G if quadratic else G + G.T - Qi, *result.disk)
            worst = max(worst, _jacobi_max_eig(M))
    return worst


def uncontrollable_modes(v: SFVertex, tol: float = 1e-8) -> np.ndarray:
    """Eigenvalues μ of A with rank [A − μI, B2] < n (PBH test), which no state feedback moves."""
    n = v.A.shape[0]
    modes = []
    for mu in np.linalg.eigvals(v.A):
        sv = np.linalg.svd(np.hstack([v.A - mu * np.eye(n), v.B2]), compute_uv=False)
        if sv[-1] <= tol * max(sv[0], 1.0):
            modes.append(mu)
    return np.array(modes)


def infeasibility_reason(verts: list[SFVertex], disk: tuple[float, float] | None, gamma_max: float | None,
                         scheduled: bool) -> str:
    """Why the LMIs may be infeasible, in terms of the plant: uncontrollable modes outside the unit
    circle or the disk (PBH), else a spec or polytope that asks too much."""
    for i, v in enumerate(verts):
        for mu in uncontrollable_modes(v):
            if abs(mu) >= 1:
                return (f"vertex {i} has an uncontrollable unstable mode at z = {mu:.4g} "
                        f"(|z| = {abs(mu):.4g}; B2 does not reach it): no state feedback stabilizes it")
            if disk is not None and abs(mu - disk[0]) >= disk[1]:
                return (f"vertex {i} has an uncontrollable mode at z = {mu:.4g}, outside the disk "
                        f"|z − {disk[0]:g}| < {disk[1]:g}: no state feedback moves it; enlarge the disk")
    radius = max(np.max(np.abs(np.linalg.eigvals(v.A))) for v in verts)
    parts = [f"the plant has vertex poles up to |z| = {radius:.4g}"]
    if gamma_max is not None:  # the spec first: without it the LMIs may be feasible
        parts.append(f"no state feedback reaches γ ≤ {gamma_max:g}: relax the weights or drop gamma_max")
    else:
        if disk is not None:
            parts.append(f"the disk |z − {disk[0]:g}| < {disk[1]:g} may be too small for a gain common to "
                         "the vertices")
        parts.append("one constant gain must serve all vertices (B2 or D12 varies)" if not scheduled
                     else "no common Lyapunov function found for all vertices: shrink the scheduling box")
    return "; ".join(parts)


# ------------------------------------------------------------------------------ independent re-check


