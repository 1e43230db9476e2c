"""Independent re-check of a synthesized controller, trusting neither the solver nor the change of variables.

1. **Vertex certificates in closed-loop coordinates** (:func:`lpvflow.synth.bilinear.certificate_margin`):
   every vertex closed loop is rebuilt from the returned plant and controller numbers and its
   bounded-real matrix with the returned Lyapunov factor must be negative definite with a margin above
   round-off (Jacobi-scaled, in the bilinear image where small Ts does not hide it).
2. **Frozen H∞ norms** of the true frozen closed loop (the generalized plant rebuilt from
   ``model.frozen(p)`` by ``control.interconnect``, the controller at λ(p), ``StateSpace.lft`` and
   ``control.norm``) on a θ grid; with scheduled weights, or scheduling signals tied along breakpoints
   (whose box corners lie off the curve they follow), of the design's own generalized plant Σλ_iP_i
   along the breakpoints instead (:func:`interpolated_hinf_norms`).
3. **Quadratic stability** of the closed-loop vertex matrices 𝒜_i. For a common-Lyapunov design it is the
   certificate of check 1 itself (its bounded-real inequality with one 𝒳 at every vertex contains
   𝒜_iᵀ𝒳𝒜_i − 𝒳 ≺ 0), so the two lines cannot disagree; for a rate-bounded design it is the separate
   LMI and eigenvalue re-check of :func:`lpvflow.validate.stability.quadratic_stability`, informative
   (the rate-bounded certificate does not need it).
4. **Switching simulation** (:func:`switching_simulation`): the vertex closed loops under convex
   coordinates drawn afresh every sample, judged by the decay of the certificate's Lyapunov function.

:func:`lpvflow.synth.riccati.riccati_gamma` gives an LMI-free reference for one vertex.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import control
import numpy as np

from lpvflow.basis import Basis
from lpvflow.models import LPVSS
from lpvflow.synth.bilinear import certificate_margin, closed_loop
from lpvflow.synth.controller import mix
from lpvflow.synth.hinf import HinfResult
from lpvflow.synth.plant import VertexPlant, augment, interpolate
from lpvflow.synth.polytope import Polytope, box_grid
from lpvflow.synth.rate_bounded import ScheduledResult, fine_check
from lpvflow.synth.weights import WeightSystems
from lpvflow.validate.norms import hinf_norm
from lpvflow.validate.stability import quadratic_stability


def vertex_margins(result: HinfResult) -> list[float]:
    """:func:`lpvflow.synth.bilinear.certificate_margin` at every vertex, recomputed from the result's
    numbers."""
    return [certificate_margin(v, K, result.lyapunov_factor, result.gamma)
            for v, K in zip(result.vertices, result.K_vertices, strict=True)]


def frozen_hinf_norms(controller_at: Callable[[np.ndarray], tuple[np.ndarray, ...]], model: LPVSS,
                      W: WeightSystems, grid: np.ndarray, structure: str = "1dof") -> np.ndarray:
    """‖T_zw‖_∞ of the frozen closed loop at every grid point (python-control lft,
    :func:`lpvflow.validate.norms.hinf_norm`):
    ``controller_at(p)`` gives (Ak, Bk, Ck, Dk) from the measured signals to u before W_B (augment puts
    W_B in the plant). The grid is the design's box, which may reach past the model's identified range
    as the design does (the synth stage reports where: :func:`lpvflow.pipeline.controller_design.
    extrapolation_note`), so the model is evaluated there without a range warning. ``W`` are the design's
    weights at the model's Ts (:attr:`lpvflow.synth.plant.GeneralizedPlant.weights`)."""
    nu = model.nu
    ny = 2 * model.ny if structure == "2dof" else model.ny
    norms = []
    for p in grid:
        P = augment(model.frozen(p, check_range=False), W, model.Ts, structure)
        K = control.ss(*controller_at(p), model.Ts)
        norms.append(hinf_norm(P.lft(K, nu, ny)))
    return np.array(norms)


def interpolated_loops(vertices: list[VertexPlant], K_vertices: list[tuple[np.ndarray, ...]],
                       lams: list[np.ndarray], Ts: float) -> list[control.StateSpace]:
    """The closed loops (``StateSpace.lft``) of the generalized plant Σλ_iP_i with the controller Σλ_iK_i,
    at every λ of ``lams``."""
    nu, ny = vertices[0].dims[2], vertices[0].dims[4]
    return [interpolate(vertices, lam).ss(Ts).lft(control.ss(*mix(K_vertices, lam), Ts), nu, ny)
            for lam in lams]


def interpolated_hinf_norms(vertices: list[VertexPlant], K_vertices: list[tuple[np.ndarray, ...]],
                            lams: list[np.ndarray], Ts: float) -> np.ndarray:
    """‖T_zw‖_∞ (:func:`lpvflow.validate.norms.hinf_norm`) of :func:`interpolated_loops`."""
    return np.array([hinf_norm(loop) for loop in interpolated_loops(vertices, K_vertices, lams, Ts)])


def design_coordinates(polytope: Polytope, basis: Basis, per_axis: int) -> list[np.ndarray]:
    """λ(p) at the polytope's own grid of the design (:meth:`Polytope.design_points`)."""
    return [polytope.coordinates_at(basis, p) for p in polytope.design_points(per_axis)]


def vertex_interpolation(result: HinfResult) -> Callable[[np.ndarray], tuple[np.ndarray, ...]]:
    """p ↦ Σ λ_i(p) K_i of a polytopic result (λ of its controller's polytope)."""
    def at(p: np.ndarray) -> tuple[np.ndarray, ...]:
        lam = result.controller.coordinates(p)
        return mix(result.K_vertices, lam)
    return at


def switching_simulation(result: HinfResult, n_steps: int = 4000, seed: int = 0
                         ) -> tuple[float, float, float]:
    """The closed loop of the vertex plants and controllers under convex coordinates λ(k) drawn afresh
    every sample (uniform on the simplex), from a random state, w = 0: ξ⁺ = 𝒜(λ(k))ξ with 𝒜(λ) the loop
    of Σλ_i P_i and Σλ_i K_i (exactly affine in λ: B2, C2, D12, D21 are constant). Judged by the decay
    bound the certificate implies: V = ‖Fξ‖² (𝒳 = FᵀF) must not grow from one sample to the next.

    Returns (peak ‖ξ‖/‖ξ(0)‖, final ‖ξ‖/‖ξ(0)‖, max V(k+1)/V(k)).
    """
    rng = np.random.default_rng(seed)
    N = len(result.vertices)
    loops = [closed_loop(v, K)[0] for v, K in zip(result.vertices, result.K_vertices, strict=True)]
    xi = rng.standard_normal(loops[0].shape[0])
    norm0, F = np.linalg.norm(xi), result.lyapunov_factor
    V, peak, growth = float(np.sum((F @ xi) ** 2)), 1.0, 0.0
    for _ in range(n_steps):
        lam = rng.dirichlet(np.ones(N))
        xi = np.tensordot(lam, loops, axes=1) @ xi
        V_next = float(np.sum((F @ xi) ** 2))
        growth, V = max(growth, V_next / V), V_next
        peak = max(peak, np.linalg.norm(xi) / norm0)
        if V == 0.0:
            break
    return float(peak), float(np.linalg.norm(xi) / norm0), float(growth)


@dataclass
class Certificate:
    """Results of the independent re-check (module docstring); ``margin`` is the smallest vertex margin."""

    margin: float
    frozen_hinf_max: float
    gamma: float
    switching_peak: float
    switching_final: float
    switching_growth: float
    quadratically_stable: bool
    quadratic_source: str = "the vertex certificates' common Lyapunov matrix"

    @property
    def ok(self) -> bool:
        """Checks 1, 2 and 4 (check 3 is informative)."""
        return (self.margin > 0 and self.frozen_hinf_max <= self.gamma * (1 + 1e-3)
                and self.switching_growth <= 1.0 + 1e-9)

    def lines(self) -> list[str]:
        return [
            f"vertex certificates re-evaluated: smallest margin {self.margin:.3e} (must be > 0)",
            f"frozen closed-loop H∞ max {self.frozen_hinf_max:.6g} vs γ = {self.gamma:.6g}",
            f"closed loop quadratically stable ({self.quadratic_source}): {self.quadratically_stable}",
            f"switching simulation: peak ‖ξ‖/‖ξ0‖ = {self.switching_peak:.3g}, "
            f"final = {self.switching_final:.3g}, largest V(k+1)/V(k) = {self.switching_growth:.9f} "
            "(must be ≤ 1)",
        ]


def certify(result: HinfResult, model: LPVSS | None, per_axis: int = 21) -> Certificate:
    """Run checks 1–4 of the module docstring (check 2 on the design's own plant when ``model`` is None,
    else on ``model`` with the design's weights)."""
    poly = result.plant.polytope
    if model is None:
        lams = design_coordinates(poly, result.plant.basis, per_axis)
        norms = interpolated_hinf_norms(result.vertices, result.K_vertices, lams, result.plant.Ts)
    else:
        grid = box_grid(poly.box, per_axis)
        norms = frozen_hinf_norms(vertex_interpolation(result), model, result.plant.weights, grid,
                                  result.plant.structure)
    peak, final, growth = switching_simulation(result)
    margin = min(vertex_margins(result))
    return Certificate(margin, float(norms.max()), result.gamma, peak, final, growth, margin > 0)


def rate_bounded_walk(result: ScheduledResult, n_steps: int = 4000, seed: int = 0
                      ) -> tuple[float, float, float]:
    """The closed loop along a random scheduling walk p(k+1) = clip(p(k) + ν·u(k)), u uniform in [−1, 1]
    (ν the rate bound; any jump inside the range for ν = None), from a random state, w = 0, judged by the
    certificate's decay: V(k) = ξᵀ𝒫(p(k))⁻¹ξ must not grow.

    Returns (peak ‖ξ‖/‖ξ(0)‖, final ‖ξ‖/‖ξ(0)‖, max V(k+1)/V(k))."""
    rng = np.random.default_rng(seed)
    b, nu = result.schedule.breakpoints, result.schedule.rate_bound
    p = float(rng.uniform(b[0], b[-1]))
    xi = rng.standard_normal(len(result.lyapunov[0]))
    norm0, peak, growth = np.linalg.norm(xi), 1.0, 0.0
    value = result.slack.lyapunov_value(xi, result.lyapunov_at(p))
    for _ in range(n_steps):
        xi = closed_loop(result.plant_at(p), result.controller_at(p))[0] @ xi
        step = rng.uniform(b[0], b[-1]) - p if nu is None else nu * rng.uniform(-1, 1)
        p = float(np.clip(p + step, b[0], b[-1]))
        value_next = result.slack.lyapunov_value(xi, result.lyapunov_at(p))
        growth, value = max(growth, value_next / value), value_next
        peak = max(peak, np.linalg.norm(xi) / norm0)
        if value == 0.0:
            break
    return float(peak), float(np.linalg.norm(xi) / norm0), float(growth)


def certify_rate_bounded(result: ScheduledResult, model: LPVSS | None, weights: WeightSystems,
                         structure: str = "1dof", per_axis: int = 21) -> Certificate:
    """Checks 1–4 for a rate-bounded design: 1. Φ(p, p⁺) rebuilt from the returned numbers on a grid ten
    times finer than the breakpoints (:func:`lpvflow.synth.rate_bounded.fine_check`); 2. frozen H∞ norms
    of ``model`` with the design's ``weights`` at its Ts (python-control; with scheduled weights, ``model``
    None: of the design's generalized plant interpolated at p); 3. quadratic stability of the breakpoint
    loops (informative); 4. :func:`rate_bounded_walk`."""
    margin, _ = fine_check(result)
    b = result.schedule.breakpoints
    grid = box_grid(np.array([[b[0], b[-1]]]), per_axis)

    def controller_at(p: np.ndarray) -> tuple[np.ndarray, ...]:
        return result.controller_at(float(np.asarray(p).reshape(-1)[0]))

    if model is not None:
        norms = frozen_hinf_norms(controller_at, model, weights, grid, structure)
    else:
        lams = [result.schedule.weights(float(p[0])) for p in grid]
        norms = interpolated_hinf_norms(result.vertices, result.K_vertices, lams, result.Ts)
    peak, final, growth = rate_bounded_walk(result)
    A_cl = [closed_loop(v, K)[0] for v, K in zip(result.vertices, result.K_vertices, strict=True)]
    quadratic = quadratic_stability(A_cl).certified
    return Certificate(margin, float(norms.max()), result.gamma, peak, final, growth, quadratic,
                       "separate LMI, informative: the rate-bounded certificate does not need it")
