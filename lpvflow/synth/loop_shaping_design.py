"""``[synth] method = "loop-shaping"``: H∞ loop-shaping designs (McFarlane & Glover 1990) at the breakpoints
(vertices) of the design's polytope, in state coordinates the breakpoints share, interpolated.

At every vertex i with frozen model G_i, in the signal scaling of ``scaling`` (D_y⁻¹ G_i D_u, the scales of
:class:`lpvflow.validate.scaling.SignalScaling`; the validate stage's scaling makes the shaped loop's b the
b that the robustness stage compares with the ν-gap):

* W1_i = W1/σ_max(W2 G_i W1)(e^{jω_c Ts}), W1 the integrator-plus-lead weight of
  :func:`lpvflow.synth.loop_shaping.integrator_lead_weight` at the crossover ω_c = ``crossover``, its
  integral corner at ω_c/``integral_ratio`` (default 10)
  (:func:`lpvflow.synth.loop_shaping.crossover_normalized`), W2 = I (in the scaled signals); with
  ``integral_outputs`` the integral action moves from W1 (every plant input) to W2 = diag((s + ω_c/r_i)/s
  on the named outputs, 1 on the others) (:func:`lpvflow.synth.loop_shaping.output_integral_weight`), the
  same at every breakpoint, and W1 keeps the lead and the roll-off: then the named outputs settle at their
  references whatever the other outputs read — with the integral action at the inputs the steady state
  only zeroes K∞(1)·e, a combination of every output's error, and a sensor offset on one output moves the
  others (on the ADIP, a 0.002 rad pendulum offset moved the held arm ≈ 9°); with ``washout_outputs``
  W2 = diag(s/(s + ω_c/``washout_ratio``) on the named outputs, 1 on the others)
  (:func:`lpvflow.synth.loop_shaping.output_washout_weight`) and the integral action stays at the inputs:
  the loop ignores the steady value of the named outputs (stabilized, not tracked), so K∞(1)·W2(1)·e = 0
  zeroes the other outputs' errors and an offset on the named ones moves nothing in steady state; with
  ``output_weights`` W2 also carries the constant diag(w_j) of McFarlane & Glover's procedure (the outputs'
  relative importance, 1 for outputs not named): the loop is shaped as if output j's scale were divided by
  w_j, while b is still judged in the ``scaling`` signals. With
  ``margin_goal`` the
  lead zero of W1_i moves towards its pole (A, B of W1 unchanged) until the shipped b(G_i, W1_i·K∞_i·W2)
  reaches the breakpoint's goal (:mod:`lpvflow.synth.margin_goal`);
* K∞_i from hinfsyn's LMIs (:func:`lpvflow.synth.loop_shaping.lmi_central_controller`): the certified
  optimum γ_LMI,i of the four-block NCF plant of Gs_i = G_i·W1_i, then the central LMI controller at
  γ_i = 1.01·γ_LMI,i (:mod:`lpvflow.synth.central`: the largest R, S of the LMIs at γ_i, explicit
  controller formulas, the certificate re-checked in numpy), so b(Gs_i, K∞_i) ≥ 1/γ_i. Its state lives in
  the coordinates of Gs_i's own state [x_W1; x_G] (:func:`lpvflow.synth.loop_shaping.in_plant_coordinates`):
  the weight's states and the model's observable-form states, the same at every breakpoint — which makes
  Σλ_i K∞_i an interpolation of the gains of one observer structure rather than of realizations chosen
  by separate solves (Rugh & Shamma 2000, "Research on gain scheduling", Automatica 36(10));
* the witnesses: the Riccati optimum γ_opt(Gs_i) from the two NCF Riccati equations (γ_LMI,i within 1 %
  of it), and the Riccati central controller at the same level γ_i
  (:func:`lpvflow.synth.loop_shaping.central_ncf_controller`), whose distance from K∞_i is reported;
* the feedback K_i = D_u·W1_i·K∞_i·W2·D_y⁻¹ on the plant's physical signals (u = K y, positive feedback as
  in :mod:`lpvflow.validate.robust_stability`).

The W1_i share A, B and have D = 0 and W2 is one system, so Σλ_i(W1_i·K∞_i·W2) = W1(λ)·K∞(λ)·W2 exactly:
the exported controller Σλ_iK_i is the interpolated shaped design. Between vertices it is not certified by
the LMIs: :func:`frozen_margin_check` evaluates the shaped loop b(W2·G(λ)·W1(λ), K∞(λ)) on a grid ten times
finer than the vertices and requires b ≥ 1/(1.1·γ), γ the larger level of the two vertices around the point
(b = 0 when the frozen loop is unstable).
With ``scheduling = "common"`` (:mod:`lpvflow.synth.loop_shaping_common`) one W1 (normalized at the centre
breakpoint, no ``margin_goal``) shapes every breakpoint, so G(λ)·W1 = Σλ_iG_i·W1 exactly, and K∞_i come from
one hinfsyn solve over all breakpoints with one Lyapunov matrix: the loop is certified for every value and
every rate of change of the scheduling signal at the one level γ (:class:`CommonMarginCheck`; the frozen grid
check runs as well).
The mixed-sensitivity ``weights`` of the table are not used (the generalized plant is still built from
them).

Reference (2-DOF, Vinnicombe 2001, §1.5: the feedback gives robustness, the reference path the speed):
``structure = "1dof"`` reads e = r − y (u = −K e); ``"2dof"`` reads [r; y] and injects the reference after
K∞, u = D_u·W1·(K∞ v − K∞(1) D_y⁻¹r_f), v = W2 D_y⁻¹y − (W2 − D_W2) D_y⁻¹r_f (W2's integrators read the
error; :func:`controller_matrices`), r_f the reference passed through
``reference_filter`` (ω²/(s² + 2ζωs + ω²), zero-order hold; none: r_f = r). The feedback part from y is K
in both, so the robustness stage's b is the design's; K∞(1) is interpolated with the rest (W1's B is
shared, so the 2dof vertex matrices are affine in K∞_i, K∞_i(1) and W1_i's C).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import control
import numpy as np

from lpvflow.errors import CentralLevelError, ModelError, SynthesisError
from lpvflow.models import LPVSS
from lpvflow.synth.certify import design_coordinates
from lpvflow.synth.controller import LPVController, mix
from lpvflow.synth.design import Design
from lpvflow.synth.loop_shaping import (
    WASHOUT_RATIO,
    CentralLoopShaping,
    central_ncf_controller,
    controller_distance,
    lmi_central_controller,
    output_integral_weight,
    output_washout_weight,
    shaped_plant,
)
from lpvflow.synth.loop_shaping_common import common_central_controllers, common_weight
from lpvflow.synth.margin_goal import (
    MarginGoalReport,
    Shaping,
    breakpoint_names,
    lead_for_goal,
    vertex_goals,
)
from lpvflow.synth.observer import antiwindup_gains, reference_filter, with_reference_filter
from lpvflow.synth.plant import GeneralizedPlant
from lpvflow.synth.polytope import vertex_matrices
from lpvflow.validate.robust_stability import generalized_margin, ncf_riccati
from lpvflow.validate.scaling import SignalScaling

#: Frozen-check grid: points per breakpoint interval (ten times finer than the breakpoints).
FROZEN_PER_SEGMENT = 11
#: The frozen check requires b(Gs(λ), K∞(λ)) ≥ 1/(MARGIN_FACTOR·γ), γ of :func:`segment_gamma`.
MARGIN_FACTOR = 1.1
#: Default crossover as a fraction of the Nyquist frequency π/Ts.
DEFAULT_CROSSOVER_FRACTION = 0.05
#: Default ratio crossover / integral corner of W1 (``[synth] integral_ratio``).
DEFAULT_INTEGRAL_RATIO = 10.0
#: The central controllers' level γ_i = GAMMA_FACTOR·γ_LMI(Gs_i) (default of ``[synth] level_factor``).
GAMMA_FACTOR = 1.01
#: Relative residual below which a reference channel's steady state is reachable (reference model).
REACH_TOL = 1e-8
#: The LMI witness: hinfsyn's γ at every vertex within this fraction of γ_opt(Gs_i).
WITNESS_TOLERANCE = 0.01


@dataclass
class FrozenMarginCheck:
    """The interpolated design on a grid ten times finer than the vertices, and the witnesses at the
    vertices. The shaped loop at λ is Gs(λ) = G(λ)·W1(λ) with K∞(λ) (scaled signals; W1(λ) = Σλ_iW1_i: the
    W1_i share A, B and D = 0, so Σλ_i(W1_i·K∞_i) = W1(λ)·K∞(λ) exactly, and the shaped loop and the
    exported loop G(λ), K(λ) have the same closed-loop matrix). ``worst_ratio`` = min over the grid of
    b(Gs, K∞)·MARGIN_FACTOR·γ_segment (γ_segment of :func:`segment_gamma`; ≥ 1 passes; b = 0 when the
    frozen loop is unstable), ``worst_at`` its grid index, ``b_min`` the smallest b(Gs, K∞),
    ``b_plant_min`` the smallest b(G, K) of the unshaped loop (reported, not judged), ``gammas`` the
    vertex controllers' certified levels γ_i, ``lmi_gammas`` hinfsyn's optima γ_LMI,i and
    ``optimal_gammas`` the Riccati optima γ_opt,i (the witness: γ_LMI within WITNESS_TOLERANCE of γ_opt),
    ``riccati_distance`` the distance of each K∞_i from the Riccati central controller at γ_i
    (:func:`lpvflow.synth.loop_shaping.controller_distance`; reported)."""

    b_min: float
    b_plant_min: float
    worst_ratio: float
    worst_at: int
    points: int
    gammas: list[float]
    lmi_gammas: list[float]
    optimal_gammas: list[float]
    riccati_distance: list[float]
    margin_goal: MarginGoalReport | None = None

    @property
    def witness_error(self) -> float:
        """max_i |γ_LMI,i/γ_opt,i − 1|."""
        return max(abs(lmi / g - 1.0) for lmi, g in zip(self.lmi_gammas, self.optimal_gammas, strict=True))

    @property
    def ok(self) -> bool:
        """Every frozen loop is stable with b(Gs, K∞) ≥ 1/(1.1·γ_segment), and the LMI
        witness agrees with the Riccati optimum within 1 % at every vertex."""
        return self.worst_ratio >= 1.0 and self.witness_error <= WITNESS_TOLERANCE

    def grid_lines(self, level: str) -> list[str]:
        """The frozen-grid check and the unshaped loops' b, ``level`` naming the γ the grid is held to."""
        return [f"frozen shaped loops at {self.points} points (10× the vertices): smallest b(Gs, K∞) "
                f"{self.b_min:.4g}; worst b·{MARGIN_FACTOR}·{level} {self.worst_ratio:.4g} at point "
                f"{self.worst_at} (must be ≥ 1; b = 0 is an unstable loop)",
                f"unshaped loops: smallest b(G, K) {self.b_plant_min:.4g} (K = W1·K∞, scaled signals)"]

    def lines(self) -> list[str]:
        return [f"loop-shaping controllers from hinfsyn's LMIs (central solution at γ_i = "
                f"{self.gammas[0] / self.lmi_gammas[0]:.4g}·γ_LMI,i, explicit formulas, certificate passed "
                f"at every vertex): γ_i "
                f"{min(self.gammas):.4g} … "
                f"{max(self.gammas):.4g} (b(Gs_i, K∞_i) ≥ 1/γ_i)",
                f"Riccati witness: γ_LMI {min(self.lmi_gammas):.4g} … {max(self.lmi_gammas):.4g} against "
                f"γ_opt {min(self.optimal_gammas):.4g} … {max(self.optimal_gammas):.4g}, largest deviation "
                f"{100 * self.witness_error:.2f} % (must be ≤ {100 * WITNESS_TOLERANCE:.0f} %); K∞_i within "
                f"{100 * max(self.riccati_distance):.2g} % of the Riccati central controllers at γ_i",
                *self.grid_lines("γ_segment"),
                "no LMI certificate between vertices or for a moving scheduling signal: the FMU runs are the "
                "witness"] + ([] if self.margin_goal is None else self.margin_goal.lines())


@dataclass
class CommonMarginCheck(FrozenMarginCheck):
    """:class:`FrozenMarginCheck` of ``scheduling = "common"`` (:mod:`lpvflow.synth.loop_shaping_common`):
    one W1 and one certificate 𝒳 over all vertices at the level γ (every γ_i and γ_LMI,i the polytope's);
    ``certificate`` the vertex margins of the bounded-real inequality with 𝒳 re-checked in numpy (> 0
    certifies every λ and every rate of the scheduling signal). The witness is a bound: no common
    certificate beats the frozen Riccati optimum at a vertex, so γ_LMI ≥ (1 − WITNESS_TOLERANCE)·max_i
    γ_opt,i."""

    certificate: list[float] = field(default_factory=list)

    @property
    def witness_error(self) -> float:
        """How far γ_LMI lies below the largest frozen optimum, relative to it (0 when above)."""
        return max(0.0, 1.0 - self.lmi_gammas[0] / max(self.optimal_gammas))

    @property
    def ok(self) -> bool:
        """The certificate holds at every vertex, the witness bound holds and the frozen grid passes."""
        return min(self.certificate) > 0 and super().ok

    def lines(self) -> list[str]:
        return [f"loop-shaping controllers from hinfsyn's LMIs over all {len(self.gammas)} breakpoints with "
                f"one W1 and one Lyapunov matrix (central solution at γ = "
                f"{self.gammas[0] / self.lmi_gammas[0]:.4g}·γ_LMI): "
                f"γ {self.gammas[0]:.4g}, certified for every value and every rate of change of the "
                f"scheduling signal (vertex margins ≥ {min(self.certificate):.3g}, re-checked in numpy)",
                f"frozen Riccati optima γ_opt {min(self.optimal_gammas):.4g} … "
                f"{max(self.optimal_gammas):.4g}: the common level costs "
                f"{self.gammas[0] / max(self.optimal_gammas):.3g}× the largest; K∞_i up to "
                f"{100 * max(self.riccati_distance):.2g} % from the frozen Riccati central controllers at γ "
                "(reported)",
                *self.grid_lines("γ")]


def _matrices(M: control.StateSpace) -> tuple[np.ndarray, ...]:
    return tuple(np.asarray(X, dtype=float) for X in (M.A, M.B, M.C, M.D))


def shaping_scale(model: LPVSS, table: Mapping[str, float] | None) -> SignalScaling:
    """D_u, D_y of ``[synth] scaling`` ({signal = scale} naming every model input and output), or the
    identity without the key.

    Raises:
        ModelError: a table that misses a model signal or names one the model does not have.
    """
    if table is None:
        return SignalScaling(np.ones(model.nu), np.ones(model.ny))
    signals = [*model.u_names, *model.y_names]
    missing, extra = [n for n in signals if n not in table], sorted(set(table) - set(signals))
    if missing or extra:
        what = (f"; missing {missing}" if missing else "") + (f"; unknown {extra}" if extra else "")
        raise ModelError(f"[synth] scaling needs one scale per model input and output {signals}{what}")
    return SignalScaling(np.array([table[n] for n in model.u_names]),
                         np.array([table[n] for n in model.y_names]))


def physical_feedback(K: tuple[np.ndarray, ...], scale: SignalScaling) -> tuple[np.ndarray, ...]:
    """D_u·K·diag(D_y⁻¹, …): a controller of the scaled signals (SignalScaling.controller's inverse) on the
    physical ones; K reads y (ny columns) or [r; y] (2·ny columns, both in the outputs' scale)."""
    A, B, C, D = K
    Dy_inv = np.kron(np.eye(B.shape[1] // scale.Dy.shape[0]), np.linalg.inv(scale.Dy))
    return A, B @ Dy_inv, scale.Du @ C, scale.Du @ D @ Dy_inv


def segment_gamma(gammas: list[float], lam: np.ndarray) -> float:
    """The largest γ_i of the vertices that λ mixes (λ_i > 0): the level the frozen check holds a point
    between vertices to."""
    return max(g for g, li in zip(gammas, lam, strict=True) if li > 1e-12)


def frozen_margin_check(model_vertices: list[tuple[np.ndarray, ...]], weights: list[tuple[np.ndarray, ...]],
                        K_inf: list[tuple[np.ndarray, ...]], gammas: list[float], lmi_gammas: list[float],
                        optimal_gammas: list[float], lams: list[np.ndarray], Ts: float,
                        riccati_distance: list[float] | None = None,
                        W2: control.StateSpace | None = None) -> FrozenMarginCheck:
    """:class:`FrozenMarginCheck` of K∞(λ) = Σλ_iK∞_i on Gs(λ) = W2·G(λ)·W1(λ) and of K(λ) =
    W1(λ)·K∞(λ)·W2 on G(λ) (u = K y) at every λ of ``lams``, each held to :func:`segment_gamma` (W2 = I
    when None)."""
    if W2 is None:
        W2 = control.ss([], [], [], np.eye(model_vertices[0][2].shape[0]), Ts)
    b, b_plant = [], []
    for lam in lams:
        G, W1, K = (control.ss(*mix(M, lam), Ts) for M in (model_vertices, weights, K_inf))
        b.append(generalized_margin(W2 * G * W1, K))
        b_plant.append(generalized_margin(G, W1 * K * W2))
    ratio = np.array(b) * MARGIN_FACTOR * np.array([segment_gamma(gammas, lam) for lam in lams])
    worst = int(np.argmin(ratio))
    return FrozenMarginCheck(min(b), min(b_plant), float(ratio[worst]), worst, len(lams), list(gammas),
                             list(lmi_gammas), list(optimal_gammas), list(riccati_distance or [0.0]))


def controller_matrices(K_inf: tuple[np.ndarray, ...], W1: control.StateSpace, W2: control.StateSpace,
                        structure: str) -> tuple[np.ndarray, ...]:
    """The controller of ``structure`` around the shaped plant's K∞ (scaled signals, u_s = K∞ y_s):
    1dof reads e = r − y, u = −W1·K∞·W2 e; 2dof reads [r; y] and injects the reference after K∞,
    u = W1·(K∞ v − K∞(1) D_W2 r), v = W2 y − (W2 − D_W2) r, D_W2 = W2's feed-through (Skogestad &
    Postlethwaite, *Multivariable Feedback Control*, 2nd ed. 2005, §9.4.3: the reference does not pass the
    controller's lead, so a step does not kick; W2's integrators read the error y − r, so the integrated
    outputs settle at the reference; with a constant W2 = D_W2, at DC it is W1·K∞(1)·D_W2·(y − r), the 1dof
    loop). The feedback from y is W1·K∞·W2 in both."""
    A, B, C, D = K_inf
    if structure == "2dof":
        dc = C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + D
        two = control.ss(A, np.hstack([np.zeros_like(B), B]), C, np.hstack([-dc, D]), W1.dt)
        A2, B2, C2, D2 = _matrices(W2)
        ny = D2.shape[0]
        errors = control.ss(A2, np.hstack([-B2, B2]), np.vstack([np.zeros((ny, A2.shape[0])), C2]),
                            np.block([[D2, np.zeros((ny, ny))], [np.zeros((ny, ny)), D2]]), W1.dt)
        return _matrices(W1 * two * errors)
    return _matrices(W1 * control.ss(A, -B, C, -D, W1.dt) * W2)


def reference_model_gains(model_mats: tuple[np.ndarray, ...], scale: SignalScaling, control_weight: float
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(F, N) of the reference model x_m⁺ = A x_m + B u_m, u_m = F x_m + N r of one frozen model: F the LQ
    gain of ``control.dlqr(A, B, CᵀD_y⁻²C, ρ D_u⁻²)`` (ρ = ``control_weight``, the outputs and the input in
    the shaping scale; solved in a scaled state, below), N = u_ss − F x_ss per reference whose steady state
    the model can hold ([A − I  B; C  0][x_ss; u_ss] = [0; e_j]; none for a channel it cannot, e.g. the
    ADIP's pendulum)."""
    A, B, C, _ = model_mats
    n, nu, ny = A.shape[0], B.shape[1], C.shape[0]
    Dy_inv, Du_inv = np.linalg.inv(scale.Dy), np.linalg.inv(scale.Du)
    Cy = Dy_inv @ C
    # Solved in the state x = c·z, c² = ‖B D_u‖/(√ρ ‖D_y⁻¹C‖), which balances the Riccati equation's two
    # terms (an identified model's B can be 1e-4 against C ≈ 1, as the maglev's; slycot then fails to
    # order the Hamiltonian pencil's eigenvalues near the unit circle); the gain is F = F_z/c.
    c = np.sqrt(np.linalg.norm(B @ scale.Du, 2) / (np.sqrt(control_weight) * np.linalg.norm(Cy, 2)))
    Q = (c * Cy).T @ (c * Cy)
    K, _, _ = control.dlqr(A, B / c, (Q + Q.T) / 2, control_weight * Du_inv @ Du_inv)
    F = -np.asarray(K, dtype=float) / c
    M = np.block([[A - np.eye(n), B], [C, np.zeros((ny, nu))]])
    N = np.zeros((nu, ny))
    for j in range(ny):
        target = np.r_[np.zeros(n), np.eye(ny)[j]]
        sol = np.linalg.lstsq(M, target, rcond=None)[0]
        if np.linalg.norm(M @ sol - target) <= REACH_TOL:
            N[:, j] = sol[n:] - F @ sol[:n]
    return F, N


def with_reference_model(K_fb: tuple[np.ndarray, ...], model_mats: tuple[np.ndarray, ...], F: np.ndarray,
                         N: np.ndarray) -> tuple[np.ndarray, ...]:
    """The 2dof controller u = u_m + K_fb(y − y_m) from [r; y] (u = K_fb y the feedback), (x_m, u_m, y_m)
    the reference model of :func:`reference_model_gains`: state [x_m; x_K],

        A = [A + BF  0; −B_K C  A_K],  B = [BN  0; 0  B_K],  C = [F − D_K C  C_K],  D = [N  D_K].

    When the plant is the model, y = y_m and the feedback sees no error: the reference model gives the
    speed, the feedback the robustness (the 2-DOF structure; Vinnicombe 2001, §1.5). With
    ``integral_outputs`` (K_fb = W1·K∞·W2) W2's integrators read y − y_m, so those outputs settle at the
    reference model's, which holds a reachable reference at steady state."""
    Ak, Bk, Ck, Dk = K_fb
    A, B, C, _ = model_mats
    n, nk = A.shape[0], Ak.shape[0]
    ny = C.shape[0]
    Ac = np.block([[A + B @ F, np.zeros((n, nk))], [-Bk @ C, Ak]])
    Bc = np.block([[B @ N, np.zeros((n, ny))], [np.zeros((nk, ny)), Bk]])
    return Ac, Bc, np.hstack([F - Dk @ C, Ck]), np.hstack([N, Dk])


@contextlib.contextmanager
def _level_named(factor: float) -> Iterator[None]:
    """A :class:`~lpvflow.errors.CentralLevelError` (the central controller at its level, not hinfsyn's
    optimum search) with the design's level named: "raise the level" is ``[synth] level_factor`` here."""
    try:
        yield
    except CentralLevelError as exc:
        raise SynthesisError(f"{exc} (loop-shaping: the central controllers are built at [synth] "
                             f"level_factor = {factor:g} × hinfsyn's optimum γ_LMI)", category=exc.category
                             ) from None


def output_shaping(model: LPVSS, crossover: float, integral_ratio: float, integral_outputs: list[str] | None,
                   washout_outputs: list[str] | None = None, washout_ratio: float = WASHOUT_RATIO,
                   output_weights: Mapping[str, float] | None = None) -> Shaping:
    """The :class:`~lpvflow.synth.margin_goal.Shaping` of ``[synth] integral_outputs``, ``washout_outputs``
    and ``output_weights``: without any the integral action is W1's at every plant input and W2 = I; with
    the first W2 integrates the named outputs' errors
    (:func:`lpvflow.synth.loop_shaping.output_integral_weight`) and W1 has none; with the second W2 washes
    the named outputs out
    (:func:`lpvflow.synth.loop_shaping.output_washout_weight`, corner ω_c/``washout_ratio``); the third is
    the constant W2 = diag(w_j) of McFarlane & Glover's procedure (the outputs' relative importance; 1 for an
    output not named; Skogestad & Postlethwaite 2005, §9.4.2), applied in the ``scaling`` signals, so that
    b(G, W1·K∞·W2) is still judged in them. All are diagonal, so W2 is their product.

    Raises:
        ModelError: a name that is not a model output, or an output named by both of the first two keys.
    """
    weights = [(output_weights or {}).get(name, 1.0) for name in model.y_names]
    W2 = control.ss([], [], [], np.diag(weights), model.Ts)
    for key, names in (("integral_outputs", integral_outputs), ("washout_outputs", washout_outputs),
                       ("output_weights", list(output_weights or {}))):
        unknown = [n for n in names or [] if n not in model.y_names]
        if unknown:
            raise ModelError(f"[synth] {key} names {unknown}, which are not model outputs "
                             f"{list(model.y_names)}; name model outputs")
    both = sorted(set(integral_outputs or []) & set(washout_outputs or []))
    if both:
        raise ModelError(f"[synth] integral_outputs and washout_outputs both name {both}: an output is "
                         "either held at its reference (integral) or not held (washout); name it in one")
    if integral_outputs:
        W2 = output_integral_weight(model.Ts, crossover, [n in integral_outputs for n in model.y_names],
                                    integral_ratio=integral_ratio) * W2
    if washout_outputs:
        W2 = W2 * output_washout_weight(model.Ts, crossover, [n in washout_outputs for n in model.y_names],
                                        washout_ratio=washout_ratio)
    return Shaping(crossover, integral_ratio, W2)


def design(model: LPVSS, plant: GeneralizedPlant, settings: Mapping[str, Any],
           frozen_model: LPVSS | None) -> Design:
    """The loop-shaping controller of the module docstring at the vertices of ``plant``'s polytope;
    ``Design.gamma`` the largest vertex level γ_i (1/γ_i the guaranteed b of the shaped loop).
    ``frozen_model`` is not used: the check runs on the model interpolated like the plant.
    ``settings["validated_nugap"]`` (``{"points", "nugap"}``, set by the design's synth stage, not a
    design-file key) is the ν-gap ``margin_goal``'s ``nugap_factor`` applies to.

    Raises:
        ModelError: a crossover above the weight's usable band, a model with feed-through, a ``scaling``
            table that does not name the model's signals, or a reference filter on a 1dof controller.
        DataError: ``margin_goal.nugap_factor`` without ``validated_nugap``.
        SynthesisError: from ``hinfsyn`` at a vertex.
    """
    start = time.perf_counter()
    Ts = model.Ts
    crossover = settings.get("crossover") or DEFAULT_CROSSOVER_FRACTION * np.pi / Ts
    model_vertices = vertex_matrices(model, plant.polytope)
    if any(np.max(np.abs(D), initial=0.0) > 0 for _, _, _, D in model_vertices):
        raise ModelError("loop-shaping needs a strictly proper model (D = 0): identify it with an input "
                         "delay nk >= 1")
    filt_settings = settings.get("reference_filter") or {}
    filt = reference_filter(filt_settings.get("bandwidth"), filt_settings.get("damping", 1.0), model.ny, Ts)
    if filt is not None and plant.structure != "2dof":
        raise ModelError('[synth] reference_filter filters the reference a 2dof controller reads: set '
                         'structure = "2dof" or remove reference_filter')
    reference = settings.get("reference_model")
    if reference is not None and plant.structure != "2dof":
        raise ModelError('[synth] reference_model drives a 2dof controller: set structure = "2dof" or remove '
                         'reference_model')
    scale = shaping_scale(model, settings.get("scaling"))
    shaping = output_shaping(model, crossover, settings.get("integral_ratio") or DEFAULT_INTEGRAL_RATIO,
                             settings.get("integral_outputs"), settings.get("washout_outputs"),
                             settings.get("washout_ratio") or WASHOUT_RATIO, settings.get("output_weights"))
    W2 = shaping.W2
    goal = settings.get("margin_goal")
    validated = settings.get("validated_nugap") or {}
    goals = vertex_goals(goal or {}, validated.get("points"), validated.get("nugap"), plant.polytope,
                         plant.basis)
    solver = settings.get("solver", "CLARABEL")
    factor = settings.get("level_factor") or GAMMA_FACTOR
    scaled, gammas, lmi_gammas, optimal_gammas, distances, weights, K_inf, exported, choices = (
        [] for _ in range(9))
    built: list[CentralLoopShaping] = []  # the central controllers the lead search builds at a breakpoint

    def central(Gs: control.StateSpace) -> tuple[control.StateSpace, float]:
        with _level_named(factor):
            built.append(lmi_central_controller(Gs, factor, solver))
        return built[-1].K_inf, built[-1].gamma

    models = [scale.plant(control.ss(*mats, Ts)) for mats in model_vertices]
    scheduling = settings.get("scheduling") or "frozen"
    if scheduling == "common":
        if goal is not None:
            raise ModelError('[synth] margin_goal lowers the lead of W1 per breakpoint and scheduling = '
                             '"common" shapes every breakpoint with one W1: remove one of the two keys')
        W1 = common_weight(models, shaping)
        with _level_named(factor):
            common = common_central_controllers([shaped_plant(G, W1, W2) for G in models], factor, solver)
        vertex_designs = [(W1, control.ss(*K, Ts), common.gamma, common.lmi_gamma) for K in common.K_inf]
    else:
        vertex_designs = []
        for G, goal_i in zip(models, goals, strict=True):
            built.clear()
            choice = lead_for_goal(G, goal_i, shaping, central)
            [chosen] = [c for c in built if c.K_inf is choice.controller]
            choices.append(choice)
            vertex_designs.append((choice.weight, choice.controller, chosen.gamma, chosen.lmi_gamma))
    for mats, G, (W1_i, K, gamma_i, lmi_gamma_i) in zip(model_vertices, models, vertex_designs, strict=True):
        Gs = shaped_plant(G, W1_i, W2)
        gamma_opt = ncf_riccati(Gs).gamma_opt
        riccati, _ = central_ncf_controller(Gs, gamma_i / gamma_opt)
        scaled.append(_matrices(G))
        gammas.append(gamma_i)
        lmi_gammas.append(lmi_gamma_i)
        optimal_gammas.append(gamma_opt)
        distances.append(controller_distance(K, riccati))
        weights.append(_matrices(W1_i))
        K_inf.append(_matrices(K))
        if reference is None:
            exported.append(physical_feedback(controller_matrices(_matrices(K), W1_i, W2, plant.structure),
                                              scale))
        else:
            feedback = physical_feedback(_matrices(W1_i * K * W2), scale)
            exported.append(with_reference_model(feedback, mats, *reference_model_gains(
                mats, scale, reference["control_weight"])))
    lams = design_coordinates(plant.polytope, plant.basis, FROZEN_PER_SEGMENT)
    check = frozen_margin_check(scaled, weights, K_inf, gammas, lmi_gammas, optimal_gammas, lams, Ts,
                                distances, W2)
    if scheduling == "common":
        check = CommonMarginCheck(**vars(check), certificate=common.margins)
    if goal is not None:
        check.margin_goal = MarginGoalReport([float(g) for g in goals], [c.b for c in choices],
                                             [c.lead_used for c in choices],
                                             breakpoint_names(settings.get("breakpoints"), plant.polytope))
        check.margin_goal.warn()
    if filt is not None:
        exported = [with_reference_filter(K, filt, model.ny) for K in exported]
    stacks = [np.array([k[m] for k in exported]) for m in range(4)]
    info = {"method": "loop-shaping", "gamma": max(gammas), "vertex_gammas": gammas,
            "lmi_gammas": lmi_gammas, "optimal_gammas": optimal_gammas, "riccati_distance": distances,
            "controller_source": "hinfsyn LMIs: central solution, explicit formulas",
            "scheduling": scheduling,
            "crossover": float(crossover), "integral_outputs": settings.get("integral_outputs"),
            "washout_outputs": settings.get("washout_outputs"),
            "output_weights": settings.get("output_weights"),
            "b_min": check.b_min,
            "b_plant_min": check.b_plant_min, "scaling": settings.get("scaling"),
            "reference_filter": None if filt is None else dict(filt_settings),
            "reference_model": None if reference is None else dict(reference)}
    if plant.polytope.breakpoints is not None:
        info["breakpoints"] = [float(b) for b in plant.polytope.breakpoints]
    controller = LPVController(*stacks, plant.polytope, plant.basis, Ts, info=info, structure=plant.structure)
    # with a reference model: its copy of the model is driven by the applied input when the actuator
    # saturates (x_m⁺ += B(u_a − u), :func:`lpvflow.synth.observer.antiwindup_gains`)
    gains = None if reference is None else antiwindup_gains([B for _, B, _, _ in model_vertices],
                                                            controller.order)
    return Design(controller, max(gammas), check, plant, time.perf_counter() - start, gains)
