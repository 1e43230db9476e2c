"""Independent re-check of a synthesized controller, trusting neither the solver nor the change of variables.

1. **Vertex LMIs in closed-loop coordinates.** The closed loop of vertex plant i and vertex controller i,

       𝒜 = [A + B2DkC2  B2Ck; BkC2  Ak],  ℬ = [B1 + B2DkD21; BkD21],
       𝒞 = [C1 + D12DkC2  D12Ck],          𝒟 = D11 + D12DkD21,

   is built from the returned controller numbers, and the extended bounded-real LMI (E_ij) of
   :mod:`lpvflow.synth.lmi_hinf` is evaluated with the returned 𝒫_i, 𝒢, γ. Its smallest eigenvalue after
   a Jacobi (diagonal) scaling, which keeps the sign, must be positive: reported as
   ``lmi_max_eig`` = −min λ (≤ −ε means satisfied with margin ε).
2. **Frozen H∞ norms** of the true frozen closed loop (the generalized plant rebuilt from
   ``model.frozen(p)``, the controller at λ(p), ``StateSpace.lft`` and ``control.norm``) on a θ grid.
3. **Quadratic stability** of the closed-loop vertex matrices 𝒜_i by the common-Lyapunov LMI and
   eigenvalue re-check of :func:`lpvflow.validate.stability.quadratic_stability` (for ``"dilated"``
   designs only poly-quadratic stability is guaranteed, so this may legitimately fail there).
4. **Switching simulation**: the LPVSS plant and the implementable ``LPVController`` under a scheduling
   value drawn afresh every sample, uniformly over the box.

:func:`riccati_gamma` gives an LMI-free reference for one vertex: the optimal γ of the same discrete H∞
problem by the Riccati solution (SLICOT SB10DD, :func:`riccati_controller`), a lower bound for every
polytope containing that plant.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.synth.lmi_hinf import HinfResult
from lpvflow.synth.plant import VertexPlant, augment
from lpvflow.validate.stability import quadratic_stability


def closed_loop(v: VertexPlant, K: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """(𝒜, ℬ, 𝒞, 𝒟) of the vertex plant with u = K e (module docstring, state [x; x_K])."""
    Ak, Bk, Ck, Dk = K
    A = np.block([[v.A + v.B2 @ Dk @ v.C2, v.B2 @ Ck], [Bk @ v.C2, Ak]])
    B = np.vstack([v.B1 + v.B2 @ Dk @ v.D21, Bk @ v.D21])
    C = np.hstack([v.C1 + v.D12 @ Dk @ v.C2, v.D12 @ Ck])
    return A, B, C, v.D11 + v.D12 @ Dk @ v.D21


def jacobi_min_eig(M: np.ndarray) -> float:
    """Smallest eigenvalue of the symmetric part of M after the Jacobi scaling D⁻¹MD⁻¹, D² = diag M (the
    sign is that of M's smallest eigenvalue; the scaling removes the blocks' disparate magnitudes)."""
    M = 0.5 * (M + M.T)
    d = np.sqrt(np.clip(np.diag(M), 1e-300, None))
    return float(np.linalg.eigvalsh(M / d[:, None] / d[None, :])[0])


def bounded_real_lmi(loop: tuple[np.ndarray, ...], P_next: np.ndarray, P_now: np.ndarray, G: np.ndarray,
                     gamma: float) -> np.ndarray:
    """The extended bounded-real matrix (E) of :mod:`lpvflow.synth.lmi_hinf` for the closed loop
    ``loop`` = (𝒜, ℬ, 𝒞, 𝒟), with 𝒫 of the next sample in (1,1), 𝒢 + 𝒢ᵀ − 𝒫 of the current one in (2,2):
    ‖T_zw‖ < γ is certified where it is positive definite."""
    A, B, C, D = loop
    n2, nw, nz = A.shape[0], B.shape[1], C.shape[0]
    return np.block([
        [P_next, A @ G, B, np.zeros((n2, nz))],
        [G.T @ A.T, G + G.T - P_now, np.zeros((n2, nw)), G.T @ C.T],
        [B.T, np.zeros((nw, n2)), np.eye(nw), D.T],
        [np.zeros((nz, n2)), C @ G, D, gamma**2 * np.eye(nz)],
    ])


def vertex_lmi_max_eig(result: HinfResult) -> float:
    """max over vertex pairs of λ_max(−E_ij) (Jacobi-scaled), evaluated with the returned numbers."""
    N = len(result.K_vertices)
    dilated = result.method == "dilated"
    pairs = [(i, j) for i in range(N) for j in (range(N) if dilated else (i,))]
    return max(-jacobi_min_eig(bounded_real_lmi(closed_loop(result.plant.vertices[i], result.K_vertices[i]),
                                                result.P[j], result.P[i], result.G, result.gamma))
               for i, j in pairs)


def scheduling_grid(box: np.ndarray, per_axis: int) -> np.ndarray:
    """(per_axis^{n_p}, n_p) grid of the scheduling box."""
    axes = [np.linspace(lo, hi, per_axis) for lo, hi in box]
    return np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(box), -1).T


def frozen_hinf_norms(result: HinfResult, model: LPVSS, weights: dict, grid: np.ndarray) -> np.ndarray:
    """‖T_zw‖_∞ of the frozen closed loop at every grid point (python-control lft and norm)."""
    from lpvflow.synth.plant import weight_systems

    W = weight_systems(weights, model.ny, model.nu, model.Ts)
    nu, ny = model.nu, model.ny
    norms = []
    for p in grid:
        P = augment(model.frozen(p), W, model.Ts)
        lam = result.controller.coordinates(p)
        mats = (sum(li * k[m] for li, k in zip(lam, result.K_vertices, strict=True)) for m in range(4))
        K = control.ss(*mats, model.Ts)
        norms.append(float(control.norm(P.lft(K, nu, ny), "inf")))
    return np.array(norms)


def riccati_controller(vertex: VertexPlant, Ts: float, gamma: float) -> tuple[np.ndarray, ...] | None:
    """(Ak, Bk, Ck, Dk) from y to u of SLICOT SB10DD (slycot; the discrete-time H∞ controller formulae
    from two Riccati equations) for ``vertex`` at level γ, if its closed loop is stable with
    ‖T_zw‖∞ ≤ γ (``StateSpace.lft``, ``control.norm``, relative slack 1e-3); None otherwise."""
    import slycot

    n, nw, nu, nz, ny = vertex.dims
    B, C = np.hstack([vertex.B1, vertex.B2]), np.vstack([vertex.C1, vertex.C2])
    D = np.block([[vertex.D11, vertex.D12], [vertex.D21, vertex.D22]])
    try:
        K = tuple(np.asarray(m) for m in slycot.sb10dd(n, nw + nu, nz + ny, nu, ny, gamma,
                                                        A=vertex.A, B=B, C=C, D=D)[1:5])
    except slycot.exceptions.SlycotError:
        return None
    loop = vertex.ss(Ts).lft(control.ss(*K, Ts), nu, ny)
    stable = np.max(np.abs(np.linalg.eigvals(loop.A))) < 1.0
    return K if stable and float(control.norm(loop, "inf")) <= gamma * (1 + 1e-3) else None


def riccati_gamma(vertex: VertexPlant, Ts: float, lo: float = 1.0, hi: float = 100.0,
                  rel: float = 0.005) -> float:
    """Smallest γ in [lo, hi] (to relative width ``rel``) at which :func:`riccati_controller` returns a
    controller: the frozen optimum the LMI synthesis should reach at one vertex, found without any LMI.

    Raises:
        ModelError: not even ``hi`` is achieved.
    """
    def achieved(gamma: float) -> bool:
        return riccati_controller(vertex, Ts, gamma) is not None

    if not achieved(hi):
        raise ModelError(f"SB10DD finds no controller with γ ≤ {hi:g} for this vertex")
    while hi / lo > 1 + rel:
        mid = (lo * hi) ** 0.5
        lo, hi = (lo, mid) if achieved(mid) else (mid, hi)
    return hi


def switching_simulation(
    result: HinfResult, model: LPVSS, n_steps: int = 4000, seed: int = 0,
) -> tuple[float, float]:
    """Zero reference, random initial states, p(k) redrawn uniformly in the box every sample.

    Returns (peak ‖ξ‖ / ‖ξ(0)‖, final ‖ξ‖ / ‖ξ(0)‖) for ξ = [x_plant; x_controller].
    """
    rng = np.random.default_rng(seed)
    box = result.plant.polytope.box
    K = result.controller
    K.reset(rng.standard_normal(K.order))
    x = rng.standard_normal(model.nx)
    norm0 = np.hypot(np.linalg.norm(x), np.linalg.norm(K.x))
    peak = 1.0
    zero_e = np.zeros(model.ny)
    for _ in range(n_steps):
        p = rng.uniform(box[:, 0], box[:, 1])
        A, B, C, D = model.matrices(p)
        y = C @ x + D @ K.output(zero_e, p)  # D22 = 0: the plant sees only the strictly proper part
        u = K.step(-y, p)
        x = A @ x + B @ u
        peak = max(peak, np.hypot(np.linalg.norm(x), np.linalg.norm(K.x)) / norm0)
        if not np.isfinite(peak) or peak > 1e12:
            break
    final = np.hypot(np.linalg.norm(x), np.linalg.norm(K.x)) / norm0
    K.reset()
    return float(peak), float(final)


@dataclass
class Certificate:
    """Results of the independent re-check (module docstring)."""

    lmi_max_eig: float
    frozen_hinf_max: float
    gamma: float
    switching_peak: float
    switching_final: float
    quadratically_stable: bool

    @property
    def ok(self) -> bool:
        """Checks 1, 2 and 4 (check 3 is informative for dilated designs)."""
        return (self.lmi_max_eig < 0 and self.frozen_hinf_max <= self.gamma * (1 + 1e-3)
                and self.switching_final < 1.0)

    def lines(self) -> list[str]:
        return [
            f"vertex LMIs re-evaluated: max eigenvalue {self.lmi_max_eig:.3e} (must be < 0)",
            f"frozen closed-loop H∞ max {self.frozen_hinf_max:.6g} vs γ = {self.gamma:.6g}",
            f"closed loop quadratically stable (common Lyapunov LMI): {self.quadratically_stable}",
            f"switching simulation: peak ‖ξ‖/‖ξ0‖ = {self.switching_peak:.3g}, "
            f"final = {self.switching_final:.3g}",
        ]


def certify(result: HinfResult, model: LPVSS, weights: dict, per_axis: int = 21) -> Certificate:
    """Run checks 1–4 of the module docstring."""
    norms = frozen_hinf_norms(result, model, weights, scheduling_grid(result.plant.polytope.box, per_axis))
    peak, final = switching_simulation(result, model)
    A_cl = [closed_loop(v, K)[0] for v, K in zip(result.plant.vertices, result.K_vertices, strict=True)]
    quadratic = quadratic_stability(A_cl).certified
    return Certificate(vertex_lmi_max_eig(result), float(norms.max()), result.gamma, peak, final, quadratic)
