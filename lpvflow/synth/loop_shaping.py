"""H∞ loop shaping (McFarlane & Glover 1990) for discrete plants: the Riccati design and its LMI form.

Feedback convention u = K y (positive feedback), as :mod:`lpvflow.validate.robust_stability`, whose
b(G, K) and b_opt(G) this module's designs attain.

**Riccati (central) controller.** For the continuous bilinear image (A, B, C, D) of the plant, X, Z the
stabilizing solutions of its GCARE/GFARE (:func:`lpvflow.validate.robust_stability.ncf_riccati`) and
γ > γ_opt = (1 + λmax(XZ))^{1/2} (Zhou, Doyle & Glover, "Robust and Optimal Control", 1996, Thm. 18.3
with D ≠ 0 after Cor. 13.29; McFarlane & Glover 1990, §3.3):

    R = I + DᵀD,  F = −R⁻¹(DᵀC + BᵀX),  W = I + XZ − γ²I,  L = γ² W⁻ᵀ Z Cᵀ,
    K_c = [A + BF + L(C + DF) | L ; BᵀX | −Dᵀ],

and b(G_c, K_c) ≥ 1/γ; the discrete controller is the inverse bilinear image of K_c (the map keeps the
closed loop and ‖T‖∞, module docstring of robust_stability).

**LMI form** (:func:`loop_shaping`). The same robust-stabilization problem of the shaped plant
Gs = W2·G·W1 is the H∞ problem ‖T_zw‖∞ < γ of the four-block generalized plant of
:func:`ncf_generalized_plant`, solved by :func:`lpvflow.synth.hinf.hinfsyn` — for one plant, for the
vertices of a polytope (one Lyapunov matrix) or at breakpoints with a rate bound (the LPV form of
LPVTools' ``lpvncfsyn``). The feedback for the plant is K = W1·K∞·W2. At a frozen point the LMI γ must
equal the Riccati γ_opt (tests).

**The LMI controller in the plant's coordinates** (:func:`in_plant_coordinates`). A full-order controller
is fixed by the LMI solution only up to its state basis: with the closed-loop Lyapunov matrix
𝒳 = [S N; Nᵀ X₂₂] (state [x; x_K]) and 𝒳⁻¹ = [R M; Mᵀ ∗], every factorization MNᵀ = I − RS gives the same
closed loop in another controller basis (Scherer, Gahinet & Chilali 1997, "Multiobjective
output-feedback control via LMI optimization", IEEE TAC 42(7): the reconstruction of their eq. (35) holds
for any such M, N). The factorization M = R, N = R⁻¹ − S (P = S − R⁻¹ = N X₂₂⁻¹Nᵀ ≻ 0 for a strict
solution) is the state change x_K = T x̃_K, T = −X₂₂⁻¹Nᵀ, after which

    𝒳̃ = [S  −P; −P  P],   V(x, x̃_K) = xᵀR⁻¹x + (x − x̃_K)ᵀP(x − x̃_K):

the certificate penalizes x − x̃_K, so x̃_K is an estimate of the plant's state in the plant's own basis
(the observer form of the central H∞ controller: Doyle, Glover, Khargonekar & Francis 1989, "State-space
solutions to standard H2 and H∞ control problems", IEEE TAC 34(8)), and a plant state change
x = Qx̂ changes x̃_K by the same Q. Controllers of plants that share their state coordinates (the
breakpoints of a scheduled design) then share theirs, and Σλ_iK_i interpolates gains of one structure;
interpolated in the bases the separate SDP solves return, they are not (on the bundled ADIP design the
frozen loop is unstable at the first grid point off a breakpoint).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.synth.hinf import central_near_optimum, hinfsyn
from lpvflow.validate.lti_eval import as_statespace, frequency_response
from lpvflow.validate.robust_stability import ncf_riccati


def central_ncf_controller(G: object, gamma_factor: float = 1.01) -> tuple[control.StateSpace, float]:
    """The central loop-shaping controller of the discrete plant G at γ = gamma_factor·γ_opt, and that γ.

    The returned K (u = K y, dt = G.dt) has b(G, K) ≥ 1/γ (module docstring). gamma_factor must be > 1:
    at γ_opt itself W is singular.
    """
    if not gamma_factor > 1.0:
        raise ModelError(f"gamma_factor is {gamma_factor}; it must be > 1 (the central controller at "
                         "gamma_opt itself does not exist), e.g. 1.01")
    G = as_statespace(G, "G")
    ric = ncf_riccati(G)
    A, B, C, D, X, Z = ric.A, ric.B, ric.C, ric.D, ric.X, ric.Z
    gamma = gamma_factor * ric.gamma_opt
    n = A.shape[0]
    F = -np.linalg.solve(np.eye(B.shape[1]) + D.T @ D, D.T @ C + B.T @ X)
    L = gamma**2 * np.linalg.solve((np.eye(n) + X @ Z - gamma**2 * np.eye(n)).T, Z @ C.T)
    Ak, Bk, Ck, Dk = A + B @ F + L @ (C + D @ F), L, B.T @ X, -D.T
    return control.ss(*_inverse_bilinear(Ak, Bk, Ck, Dk), G.dt), float(gamma)


def _inverse_bilinear(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, ...]:
    """The discrete system whose bilinear image (lti_eval.bilinear_to_continuous, rotation 0) is (A, B, C, D).

    z = (1 + s)/(1 − s):  A_d = (I + A)(I − A)⁻¹, B_d = √2 (I − A)⁻¹B, C_d = √2 C(I − A)⁻¹,
    D_d = D + C(I − A)⁻¹B.
    """
    M = np.linalg.inv(np.eye(A.shape[0]) - A)
    return (np.eye(A.shape[0]) + A) @ M, np.sqrt(2.0) * M @ B, np.sqrt(2.0) * C @ M, D + C @ M @ B


# ------------------------------------------------------------------------------------ LMI form
@dataclass
class LoopShapingDesign:
    """An H∞ loop-shaping design by :func:`lpvflow.synth.hinf.hinfsyn`.

    Attributes:
        gamma: the certified ‖[I; K∞](I − GsK∞)⁻¹[I  Gs]‖∞ bound (1/γ is the guaranteed b(Gs, K∞)).
        shaped: the shaped plant(s) Gs = W2·G·W1 (one per breakpoint for a scheduled design).
        K_inf: the controller(s) K∞ of the shaped plant(s) (u_s = K∞ y_s), at the breakpoints; without
            breakpoints (one plant, or one Lyapunov matrix over several) in the shaped plant's state
            coordinates (:func:`in_plant_coordinates`), with breakpoints as the rate-bounded design returns
            them.
        feedback: the feedback(s) K = W1·K∞·W2 for the plant itself (u = K y), at the breakpoints.
        result: what hinfsyn returned (its ``certificate``, ``gamma_estimate``, …).
    """

    gamma: float
    shaped: list[control.StateSpace]
    K_inf: list[control.StateSpace]
    feedback: list[control.StateSpace]
    result: object


def shaped_plant(G: object, W1: object, W2: object) -> control.StateSpace:
    """Gs = W2·G·W1 with state [x_W1; x_G; x_W2] (the same order at every breakpoint); with subscripts 1, 2
    for W1, W2 and g for G:

        A = [A1  0  0;  Bg C1  Ag  0;  B2 Dg C1  B2 Cg  A2],   B = [B1;  Bg D1;  B2 Dg D1],
        C = [D2 Dg C1,  D2 Cg,  C2],                          D = D2 Dg D1.
    """
    G, W1, W2 = (as_statespace(M, name) for M, name in ((G, "G"), (W1, "W1"), (W2, "W2")))
    if (W1.noutputs, W2.ninputs) != (G.ninputs, G.noutputs) or W1.ninputs != W1.noutputs \
            or W2.ninputs != W2.noutputs:
        raise ModelError(f"W1 must be square with {G.ninputs} outputs (the plant's inputs) and W2 square "
                         f"with {G.noutputs} inputs (its outputs); got W1 {W1.noutputs}x{W1.ninputs}, "
                         f"W2 {W2.noutputs}x{W2.ninputs}")
    A1, B1, C1, D1 = (np.asarray(M, dtype=float) for M in (W1.A, W1.B, W1.C, W1.D))
    Ag, Bg, Cg, Dg = (np.asarray(M, dtype=float) for M in (G.A, G.B, G.C, G.D))
    A2, B2, C2, D2 = (np.asarray(M, dtype=float) for M in (W2.A, W2.B, W2.C, W2.D))
    n1, ng, n2 = A1.shape[0], Ag.shape[0], A2.shape[0]
    A = np.block([[A1, np.zeros((n1, ng)), np.zeros((n1, n2))],
                  [Bg @ C1, Ag, np.zeros((ng, n2))],
                  [B2 @ Dg @ C1, B2 @ Cg, A2]])
    B = np.vstack([B1, Bg @ D1, B2 @ Dg @ D1])
    C = np.hstack([D2 @ Dg @ C1, D2 @ Cg, C2])
    return control.ss(A, B, C, D2 @ Dg @ D1, G.dt)


def ncf_generalized_plant(Gs: control.StateSpace) -> control.StateSpace:
    """The four-block generalized plant whose closed loop under u = K y is T_zw = [I; K](I − GsK)⁻¹[I  Gs].

    Inputs [w1; w2; u], outputs [z1; z2; y]; w1 at the plant output, w2 at its input:

        x⁺ = A x + [0  B] w + B u,
        z1 = y = C x + [I  0] w,     z2 = u,     (Gs strictly proper: D = 0)
        y  = C x + [I  0] w,

    so B1 = [0 B], B2 = B, C1 = [C; 0], C2 = C, D11 = [I 0; 0 0], D12 = [0; I], D21 = [I 0], D22 = 0.
    ``hinfsyn`` needs B2, C2, D12, D21 the same at every breakpoint and D22 = 0: that holds when Gs is
    strictly proper with B and C constant — a strictly proper W1 whose B is the same at every breakpoint
    (its A, C may vary), a constant W2, and a plant with constant C and D = 0 (observable form), since
    then B_s = [B_W1; 0; 0] and C_s = [0, D_W2 C_G, C_W2] (:func:`shaped_plant`).
    """
    if np.max(np.abs(Gs.D), initial=0.0) > 0.0:
        raise ModelError("the shaped plant W2·G·W1 has a feed-through; make W1 strictly proper (D = 0) or "
                         "identify the plant with an input delay nk >= 1")
    A, B, C = (np.asarray(M, dtype=float) for M in (Gs.A, Gs.B, Gs.C))
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    Bw = np.hstack([np.zeros((n, p)), B, B])
    Cz = np.vstack([C, np.zeros((m, n)), C])
    D = np.block([[np.eye(p), np.zeros((p, m)), np.zeros((p, m))],
                  [np.zeros((m, p + m)), np.eye(m)],
                  [np.eye(p), np.zeros((p, 2 * m))]])
    return control.ss(A, Bw, Cz, D, Gs.dt)


def loop_shaping(plants: Sequence[object], W1: Sequence[object], W2: object, *,
                 breakpoints: Sequence[float] | None = None, rate_bound: float | None = None,
                 **hinfsyn_options: object) -> LoopShapingDesign:
    """H∞ loop shaping by LMIs: K∞ from ``hinfsyn`` on the four-block plants of Gs_i = W2·G_i·W1_i.

    One plant: an LTI design (γ → γ_opt = 1/b_opt(Gs) as the suboptimality shrinks). Several plants at
    ``breakpoints`` (ascending values of one scheduling signal): hinfsyn's rate-bounded design with
    ``rate_bound`` (per sample; None: any rate); several plants without breakpoints: one common Lyapunov
    matrix over their polytope (the vertex controllers share the certificate, so one basis change,
    :func:`in_plant_coordinates`, puts them all in the shaped plant's coordinates). The feedback for the
    plant itself is K = W1·K∞·W2 (u = K y) at each breakpoint (interpolating K∞ and W1 between breakpoints
    is the scheduled controller).
    """
    if len(plants) != len(W1) or not plants:
        raise ModelError(f"give one W1 per plant: {len(plants)} plants, {len(W1)} weights W1")
    shaped = [shaped_plant(G, W, W2) for G, W in zip(plants, W1, strict=True)]
    generalized = [ncf_generalized_plant(Gs) for Gs in shaped]
    p, m = shaped[0].noutputs, shaped[0].ninputs
    if len(generalized) == 1 and breakpoints is None:
        result = hinfsyn(generalized[0], p, m, **hinfsyn_options)
    else:
        result = hinfsyn(generalized, p, m, breakpoints=breakpoints, rate_bound=rate_bound, **hinfsyn_options)
    Ts = shaped[0].dt
    K_vertices = result.K_vertices
    if breakpoints is None:  # one certificate 𝒳 = FᵀF for every vertex
        lyapunov = result.lyapunov_factor.T @ result.lyapunov_factor
        K_vertices = [in_plant_coordinates(K, lyapunov) for K in K_vertices]
    K_inf = [control.ss(*K, Ts) for K in K_vertices]
    W2 = as_statespace(W2, "W2")
    feedback = [as_statespace(W, "W1") * K * W2 for W, K in zip(W1, K_inf, strict=True)]
    return LoopShapingDesign(float(result.gamma), shaped, K_inf, feedback, result)


def in_plant_coordinates(K: tuple[np.ndarray, ...], lyapunov: np.ndarray) -> tuple[np.ndarray, ...]:
    """The full-order controller K = (A_K, B_K, C_K, D_K) in the basis x_K = T x̃_K, T = −X₂₂⁻¹Nᵀ, where
    its closed-loop Lyapunov matrix ``lyapunov`` = 𝒳 = [S N; Nᵀ X₂₂] (state [x; x_K], x the generalized
    plant's state) becomes [S −P; −P P], P = S − R⁻¹ (module docstring): (T⁻¹A_KT, T⁻¹B_K, C_KT, D_K).

    Raises:
        ModelError: a controller whose order differs from the plant's, or an N that is singular in floating
            point (no strict LMI solution).
    """
    A, B, C, D = K
    nk = A.shape[0]
    n = lyapunov.shape[0] - nk
    if n != nk:
        raise ModelError(f"the controller has order {nk} and the plant {n}: only a full-order controller has "
                         "the plant's coordinates")
    N, X22 = lyapunov[:n, n:], lyapunov[n:, n:]
    T = -np.linalg.solve(X22, N.T)
    if not np.linalg.cond(T) < 1.0 / np.finfo(float).eps:
        raise ModelError("the certificate's coupling block N is singular: the LMI solution is not strict")
    Ti = np.linalg.inv(T)
    return Ti @ A @ T, Ti @ B, C @ T, D


@dataclass
class CentralLoopShaping:
    """K∞ of one shaped plant from hinfsyn's LMIs (:func:`lmi_central_controller`).

    Attributes:
        K_inf: the central LMI controller (u_s = K∞ y_s) in the shaped plant's state coordinates.
        gamma: its certified level γ = gamma_factor·γ_LMI (b(Gs, K∞) ≥ 1/γ).
        lmi_gamma: hinfsyn's certified optimum γ_LMI of the NCF plant.
        certificate: the certificate margins of :func:`lpvflow.synth.central.central_vertices` (all > 0).
    """

    K_inf: control.StateSpace
    gamma: float
    lmi_gamma: float
    certificate: list[float]


def lmi_central_controller(Gs: control.StateSpace, gamma_factor: float, solver: str = "CLARABEL"
                           ) -> CentralLoopShaping:
    """K∞ of the shaped plant Gs from the LMIs alone: hinfsyn's certified optimum γ_LMI of the four-block
    NCF plant (:func:`ncf_generalized_plant`), then the central LMI controller at γ = gamma_factor·γ_LMI
    (:func:`lpvflow.synth.hinf.central_near_optimum`, one preconditioning for both: the largest R, S at γ
    and explicit controller formulas),
    written in the shaped plant's coordinates (:func:`in_plant_coordinates`), so controllers of
    breakpoints that share their state coordinates share theirs. At a frozen point it is within a few
    per cent of the Riccati central controller at the same level (:func:`central_ncf_controller`, the
    design's witness).

    Raises:
        ModelError: gamma_factor ≤ 1 (from central_near_optimum), or a shaped plant with feed-through.
        SynthesisError: from hinfsyn or from the central solution.
    """
    P = ncf_generalized_plant(Gs)
    p, m = Gs.noutputs, Gs.ninputs
    result, lmi_gamma = central_near_optimum(P, p, m, gamma_factor, solver=solver)
    lyapunov = result.lyapunov_factor.T @ result.lyapunov_factor
    K = control.ss(*in_plant_coordinates(result.K_vertices[0], lyapunov), Gs.dt)
    return CentralLoopShaping(K, float(result.gamma), lmi_gamma, list(result.certificate))


def controller_distance(K: control.StateSpace, reference: control.StateSpace, points: int = 400) -> float:
    """max_ω σ̄(K − K_ref)(e^{jωTs}) / max_ω σ̄(K_ref)(e^{jωTs}) on ``points`` log-spaced frequencies from
    10⁻³·π/Ts to π/Ts: how far a controller is from a reference one, relative to the reference's size."""
    z = np.exp(1j * np.logspace(-3, 0, points) * np.pi)  # e^{jωTs}, ωTs from 10⁻³π to π
    K_z, ref_z = frequency_response(K, z), frequency_response(reference, z)
    largest = np.linalg.norm(ref_z, 2, axis=(1, 2)).max()
    return float(np.linalg.norm(K_z - ref_z, 2, axis=(1, 2)).max() / largest)


# ------------------------------------------------------------------------------------ weights
#: W1's default lead ratio α (37° of phase lead at the crossover) and roll-off ratio.
LEAD_RATIO = 4.0
ROLLOFF_RATIO = 10.0


def integrator_lead_weight(Ts: float, crossover: float, inputs: int = 1, *, integral_ratio: float = 10.0,
                           lead_ratio: float = LEAD_RATIO, rolloff_ratio: float = ROLLOFF_RATIO,
                           integral: bool = True) -> control.StateSpace:
    """Strictly proper W1 with integral action, a phase lead at the crossover and a roll-off, per input:

        W1(s) = (s + ω_c/r_i)/s · (s + ω_c/√α)/(s + ω_c√α) · r_r ω_c/(s + r_r ω_c),

    ω_c = ``crossover`` (rad/s), r_i = ``integral_ratio``, α = ``lead_ratio`` (phase lead
    arcsin((α − 1)/(α + 1)) at ω_c: 37° for α = 4), r_r = ``rolloff_ratio``; without the first factor when
    ``integral`` is False (the integral action is then W2's, :func:`output_integral_weight`); sampled with a
    zero-order hold, which keeps D = 0 (the strictly proper W1 that :func:`ncf_generalized_plant` needs).
    Scale it per breakpoint with :func:`crossover_normalized` (its C changes, its B does not).
    """
    if not 0.0 < crossover * Ts < np.pi / rolloff_ratio:
        raise ModelError(f"crossover {crossover} rad/s with roll-off at {rolloff_ratio}x lies above the "
                         f"Nyquist frequency {np.pi / Ts:.4g} rad/s; lower crossover or rolloff_ratio")
    s = control.tf("s")
    wc, alpha = crossover, lead_ratio
    integrator = (s + wc / integral_ratio) / s if integral else 1
    channel = (integrator * (s + wc / np.sqrt(alpha)) / (s + wc * np.sqrt(alpha))
               * rolloff_ratio * wc / (s + rolloff_ratio * wc))
    sampled = control.sample_system(control.ss(channel), Ts, "zoh")
    return control.append(*[sampled] * inputs) if inputs > 1 else sampled


def output_integral_weight(Ts: float, crossover: float, integrated: Sequence[bool], *,
                           integral_ratio: float = 10.0) -> control.StateSpace:
    """W2 with integral action on the outputs marked in ``integrated`` and 1 on the others:

        W2(s) = diag(w_j(s)),  w_j(s) = (s + ω_c/r_i)/s (integrated), 1 (not),

    sampled with a zero-order hold (x⁺ = x + Ts·e, w = (ω_c/r_i)·x + e). The same W2 at every breakpoint
    keeps the NCF plant's C2 constant (:func:`ncf_generalized_plant`), and with the integral action on an
    output rather than on the plant's inputs the loop's steady state holds that output's error at zero
    whatever the other outputs read (a sensor offset on them moves nothing).

    Raises:
        ModelError: no output marked.
    """
    if not any(integrated):
        raise ModelError("output_integral_weight needs at least one integrated output")
    s = control.tf("s")
    integrator = control.sample_system(control.ss((s + crossover / integral_ratio) / s), Ts, "zoh")
    unit = control.ss([], [], [], [[1.0]], Ts)
    return control.append(*[integrator if flag else unit for flag in integrated])


#: Default ratio crossover / washout corner (``[synth] washout_ratio``).
WASHOUT_RATIO = 20.0


def output_washout_weight(Ts: float, crossover: float, washed_out: Sequence[bool], *,
                          washout_ratio: float = WASHOUT_RATIO) -> control.StateSpace:
    """W2 with a washout on the outputs marked in ``washed_out`` and 1 on the others:

        W2(s) = diag(w_j(s)),  w_j(s) = s/(s + ω_c/r_w) (washed out), 1 (not),

    sampled with a zero-order hold (D = 1, a zero at z = 1). The loop then ignores the steady value of those
    outputs: they are stabilized, not held at a reference, so a sensor offset on them moves nothing in steady
    state — with the integral action at the plant input (W1), K∞(1)·W2(1)·e = 0 then zeroes the other
    outputs' errors alone. For an output whose steady value the plant's equilibrium fixes (an inverted
    pendulum's angle: upright is the only equilibrium) the only steady reading is the sensor's offset.

    Raises:
        ModelError: no output marked.
    """
    if not any(washed_out):
        raise ModelError("output_washout_weight needs at least one washed-out output")
    s = control.tf("s")
    washout = control.sample_system(control.ss(s / (s + crossover / washout_ratio)), Ts, "zoh")
    unit = control.ss([], [], [], [[1.0]], Ts)
    return control.append(*[washout if flag else unit for flag in washed_out])


def crossover_normalized(G: object, W1: control.StateSpace, crossover: float,
                         W2: control.StateSpace | None = None) -> control.StateSpace:
    """W1/σ_max(W2 G W1)(e^{jω_c Ts}): the shaped loop W2·G·W1 crosses 1 at ω_c = ``crossover`` (W2 = I
    when None).

    Only C and D of W1 are scaled, so weights normalized at different breakpoints share A and B.
    """
    G = as_statespace(G, "G")
    z = np.exp(1j * crossover * float(G.dt))
    loop = G(z, squeeze=False) @ W1(z, squeeze=False)
    if W2 is not None:
        loop = W2(z, squeeze=False) @ loop
    gain = np.linalg.norm(loop, 2)
    return control.ss(W1.A, W1.B, W1.C / gain, W1.D / gain, W1.dt)
