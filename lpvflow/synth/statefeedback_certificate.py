"""Independent closed-loop checks of a polytopic state-feedback design
(:func:`lpvflow.synth.lmi_statefeedback.synthesize_state_feedback`): the vertex LMIs re-evaluated in numpy,
frozen H∞ norms and eigenvalues by python-control on a grid of the polytope (or of the model's box),
quadratic stability of the vertex closed loops, and a simulation under a scheduling redrawn every sample."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.synth.lmi_statefeedback import SFVertex, StateFeedbackResult, vertex_lmi_max_eig
from lpvflow.synth.plant import VertexPlant, augment
from lpvflow.synth.polytope import box_grid
from lpvflow.synth.weights import WeightSystems
from lpvflow.validate.stability import check_common_lyapunov, quadratic_stability


@dataclass
class StateFeedbackCertificate:
    """Results of :func:`certify_state_feedback`.

    Attributes:
        lmi_max_eig: :func:`vertex_lmi_max_eig` recomputed (must be ≤ −eps).
        quadratically_stable: common-Lyapunov certificate of the closed-loop vertices A_i + B2_iK_i
            (:func:`_quadratic_stability`, ``stability_note`` says which); required for ``"quadratic"``
            designs, informative for ``"dilated"`` ones (they guarantee poly-quadratic stability only).
        frozen_hinf_max: max over the θ grid of the python-control ‖T_zw‖∞ of the frozen closed loop.
        pole_max: max over the grid of max |eig − q| / r (the disk; q = 0, r = 1 without a disk).
        switching_peak, switching_final: ‖ξ‖/‖ξ(0)‖ in the random-switching simulation.
    """

    method: str
    gamma: float
    eps: float
    lmi_max_eig: float
    quadratically_stable: bool
    stability_note: str
    frozen_hinf_max: float
    pole_max: float
    switching_peak: float
    switching_final: float
    n_grid: int

    @property
    def ok(self) -> bool:
        return (self.lmi_max_eig <= -self.eps and self.frozen_hinf_max <= self.gamma * (1 + 1e-3)
                and self.pole_max < 1.0 and self.switching_final < 1.0
                and (self.quadratically_stable or self.method == "dilated"))

    def lines(self) -> list[str]:
        return [
            f"vertex LMIs re-evaluated: max eigenvalue {self.lmi_max_eig:.3e} (must be ≤ −{self.eps:.1e})",
            f"closed loop quadratically stable: {self.quadratically_stable} ({self.stability_note})",
            f"frozen closed-loop H∞ max {self.frozen_hinf_max:.6g} vs γ = {self.gamma:.6g} "
            f"({self.n_grid} points)",
            f"frozen closed-loop poles: max |z − q|/r = {self.pole_max:.4f} (must be < 1)",
            f"switching simulation: peak ‖ξ‖/‖ξ0‖ = {self.switching_peak:.3g}, "
            f"final = {self.switching_final:.3g}",
        ]


def _simplex_grid(N: int, per_axis: int, rng: np.random.Generator) -> np.ndarray:
    """Barycentric lattice with spacing 1/(per_axis − 1) on the simplex of N vertices (at most 2000
    points: else the vertices and uniform random points)."""
    m = per_axis - 1
    if math.comb(m + N - 1, N - 1) <= 2000:
        pts = [np.array(c) / m for c in itertools.product(range(m + 1), repeat=N) if sum(c) == m] if N > 1 \
            else [np.ones(1)]
        return np.array(pts)
    return np.vstack([np.eye(N), rng.dirichlet(np.ones(N), 2000 - N)])


def _frozen(result: StateFeedbackResult, model: LPVSS | None, W: WeightSystems | None, per_axis: int,
            rng: np.random.Generator) -> list[tuple[SFVertex, np.ndarray]]:
    """(frozen plant, gain) on the grid: from ``model.frozen(p)`` and the weights (p on a grid of the
    box, gain at λ(p)), or, for plain vertex lists, the vertex combination at λ on a simplex grid."""
    if model is None:
        verts = result.vertices
        out = []
        for lam in _simplex_grid(len(verts), per_axis, rng):
            v = SFVertex(*(sum(li * getattr(w, f) for li, w in zip(lam, verts, strict=True))
                           for f in SFVertex.__dataclass_fields__))
            out.append((v, result.gain(lam)))
        return out
    if W is None or result.polytope is None:
        raise ModelError("certifying against a model needs its weights and a design from a GeneralizedPlant")
    _, nw, _, nz = result.vertices[0].dims
    out = []
    for p in box_grid(result.polytope.box, per_axis):
        v = VertexPlant.from_ss(augment(model.frozen(p), W, model.Ts), nw=nw, nz=nz)
        out.append((SFVertex(v.A, v.B1, v.B2, v.C1, v.D11, v.D12), result.gain_at(p)))
    return out


def switching_simulation(
    result: StateFeedbackResult, n_steps: int = 3000, seed: int = 0,
) -> tuple[float, float]:
    """ξ⁺ = (A(λ_k) + B2(λ_k)K(λ_k))ξ, λ_k redrawn every sample: λ(p) for p uniform in the scheduling box
    (designs from a GeneralizedPlant, whose vertices interpolate the plant exactly), else uniform on the
    simplex. Returns (peak ‖ξ‖/‖ξ(0)‖, final ‖ξ‖/‖ξ(0)‖)."""
    rng = np.random.default_rng(seed)
    verts = result.vertices
    A = np.array([v.A for v in verts])
    B2 = np.array([v.B2 for v in verts])
    xi = rng.standard_normal(A.shape[1])
    norm0, peak = np.linalg.norm(xi), 1.0
    box = None if result.polytope is None else result.polytope.box
    for _ in range(n_steps):
        lam = rng.dirichlet(np.ones(len(verts))) if box is None else result.coordinates(
            rng.uniform(box[:, 0], box[:, 1]))
        xi = (np.tensordot(lam, A, axes=1) + np.tensordot(lam, B2, axes=1) @ result.gain(lam)) @ xi
        peak = max(peak, np.linalg.norm(xi) / norm0)
        if not np.isfinite(peak) or peak > 1e12:
            break
    return float(peak), float(np.linalg.norm(xi) / norm0)


def certify_state_feedback(
    result: StateFeedbackResult, model: LPVSS | None = None, weights: WeightSystems | None = None,
    per_axis: int = 41, eps: float = 1e-10, n_steps: int = 3000, seed: int = 0,
) -> StateFeedbackCertificate:
    """Re-check a state-feedback design trusting neither the solver nor the change of variables.

    1. the vertex LMIs (H_ij), (D̃_i) evaluated in numpy with the returned K_i, P_i, G, Q_i, γ
       (:func:`vertex_lmi_max_eig`): max eigenvalue ≤ −eps;
    2. quadratic stability of the closed-loop vertices A_i + B2_iK_i (common Lyapunov LMI with its own
       eigenvalue re-check, :func:`_quadratic_stability`);
    3. on a θ grid (``per_axis`` points per scheduling axis, from ``model.frozen(p)`` and ``weights``, the
       design plant's :attr:`~lpvflow.synth.plant.GeneralizedPlant.weights`, when given, else convex
       combinations of the vertices): the frozen closed-loop ‖T_zw‖∞ from
       ``control.norm`` ≤ γ(1 + 1e-3), and every closed-loop eigenvalue in the disk (unit disk without one);
    4. :func:`switching_simulation` under a θ redrawn every sample: final ‖ξ‖/‖ξ(0)‖ < 1.
    """
    rng = np.random.default_rng(seed)
    q, r = result.disk if result.disk is not None else (0.0, 1.0)
    norms, poles = [], []
    frozen = _frozen(result, model, weights, per_axis, rng)
    for v, K in frozen:
        A, B, C, D = v.closed_loop(K)
        norms.append(float(control.norm(control.ss(A, B, C, D, result.Ts), "inf")))
        poles.append(float(np.max(np.abs(np.linalg.eigvals(A) - q))) / r)
    A_cl = [v.closed_loop(K)[0] for v, K in zip(result.vertices, result.K_vertices, strict=True)]
    peak, final = switching_simulation(result, n_steps, seed)
    stable, note = _quadratic_stability(result, A_cl)
    return StateFeedbackCertificate(result.method, result.gamma, eps, vertex_lmi_max_eig(result), stable,
                                    note, max(norms), max(poles), peak, final, len(frozen))


def _quadratic_stability(result: StateFeedbackResult, A_cl: list[np.ndarray]) -> tuple[bool, str]:
    """Common Lyapunov function of the closed-loop vertices: a fresh LMI solve with its eigenvalue
    re-check (:func:`lpvflow.validate.stability.quadratic_stability`); when that solve fails (it can
    near the unit circle: adip_like over ±0.5, where Clarabel fails and SCS returns a wrong P), the
    design's own P = X⁻¹ when it has one (G = P_1 = … = P_N = X: every ``"quadratic"`` design, and a
    ``"dilated"`` one that kept its quadratic start), scaled to λ_min(P) = 1, through the same
    eigenvalue re-check (:func:`~lpvflow.validate.stability.check_common_lyapunov`:
    A_iᵀPA_i − P ⪯ −1e-12·I)."""
    fresh = quadratic_stability(A_cl)
    if fresh.certified or not all(np.array_equal(Pi, result.G) for Pi in result.P):
        return fresh.certified, f"common Lyapunov LMI: {fresh.reason or 'certified'}"
    P = np.linalg.inv(0.5 * (result.G + result.G.T))
    check = check_common_lyapunov(A_cl, P / np.linalg.eigvalsh(P)[0], 1e-12)
    return check.passed, (f"the design's P = X⁻¹: {check.reason or 'certified'} "
                          f"(fresh LMI: {fresh.reason})")
