"""``[synth] margin_goal`` of the loop-shaping design: the robust stability margin as a design input.

Vinnicombe's criterion (*Uncertainty and Feedback: H∞ loop-shaping and the ν-gap metric*, 2001, §3.3 and
§6.1 of the thesis): the controller K stabilizes every plant G with δν(G, Ĝ) < b(Ĝ, K). The goal
``{ nugap_factor = f, at_least = b_min }`` asks, at every validate point θ_j with ν-gap δν_j,

    b(Ĝ(θ_j), K_fb(θ_j)) ≥ g_j = max(f·δν_j, b_min)

(without ``nugap_factor`` g_j = b_min everywhere; without ``at_least`` b_min = 0), K_fb = W1·K∞·W2 the
feedback the robustness stage judges (W2 = I unless ``[synth] integral_outputs``, ``washout_outputs``
or ``output_weights``). The ν-gap is known
only at the validate points, so the design holds breakpoint i to the largest g_j of the points whose
convex coordinates λ_i(θ_j) > 0 — the points the controller of breakpoint i takes part in — and to b_min
where there is none (:func:`vertex_goals`).

**What is lowered to meet it: the phase lead.** The weight of the design is the integrator-plus-lead W1 of
:func:`lpvflow.synth.loop_shaping.integrator_lead_weight`,

    W1(s) = (s + ω_c/r_i)/s · (s + p/β)/(s + p) · r ω_c/(s + r ω_c),   p = ω_c√α,  r = ``rolloff_ratio``,

with β = α (the lead ratio, phase lead arcsin((α − 1)/(α + 1)) at ω_c; without its first factor when W2
carries the integral action). The unshaped margin b(G, W1·K∞·W2) of the shipped loop lies below the
shaped loop's b(W2·G·W1, K∞) by as much as the weights turn in phase and gain near the crossover; on
the bundled ADIP model at ±75° the lead costs 0.04 of b (0.108 at β = 4, 0.140 at β = 1.4, seed 2),
while a lower crossover lowers b_opt(G·W1) there (benchmarks/README.md). So breakpoint
i keeps the crossover and takes the largest β_i on the ladder β = α^{1 − k/LADDER_STEPS}, k = 0 … LADDER_STEPS
(β = 1: no lead), whose central controller reaches b(G_i, W1_i·K∞_i·W2) ≥ g_i; where none does, the β of
the largest b, and a :class:`MarginGoalWarning` names the breakpoint.

Only the zero p/β moves, so in the realization of :func:`lead_weight` (the partial fractions of W1: poles
{0, −p, −rω_c}, or {−p, −rω_c} without the integral factor, sampled with a zero-order hold) every β has the
same A and B and D = 0: the interpolated W1(λ)·K∞(λ)·W2 is still Σλ_i W1_i·K∞_i·W2 exactly
(:mod:`lpvflow.synth.loop_shaping_design`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import control
import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import DataError, ModelError
from lpvflow.synth.loop_shaping import (
    LEAD_RATIO,
    ROLLOFF_RATIO,
    crossover_normalized,
    integrator_lead_weight,
    shaped_plant,
)
from lpvflow.synth.polytope import Polytope
from lpvflow.validate.robust_stability import generalized_margin

#: Steps of the lead-ratio ladder from α down to 1.
LADDER_STEPS = 16
#: λ_i(θ) above this counts as the breakpoint taking part at θ.
TOUCH_TOL = 1e-9


class MarginGoalWarning(UserWarning):
    """The margin goal is not attainable by the lead at a breakpoint."""


def lead_weight(Ts: float, crossover: float, inputs: int, lead_used: float, *,
                integral_ratio: float, integral: bool = True) -> control.StateSpace:
    """W1 of the module docstring with the lead zero at p/β, β = ``lead_used`` ∈ [1, α], per input, in the
    realization (A, B) of :func:`~lpvflow.synth.loop_shaping.integrator_lead_weight` (β = α: that weight
    itself, to the bit; ``integral`` False: without its integral factor, as that function). Only C moves:
    with the partial fractions of W1,

        W1(s) = Σ_k c_k(β)/(s − s_k),  s_k ∈ {0, −p, −rω_c} ({−p, −rω_c} without the integral factor),
        c_k = N(s_k)/∏_{l≠k}(s_k − s_l),  N(s) = rω_c(s + ω_c/r_i)(s + p/β) (rω_c(s + p/β)),

    sampled exactly with a zero-order hold (A_m = diag(e^{s_kTs}), B_m = [∫₀^Ts e^{s_kτ}dτ], C_m = [c_k]) and
    T = 𝒞(A, B)·𝒞(A_m, B_m)⁻¹ the similarity onto W1's realization (𝒞 the controllability matrix),
    C(β) = C_W1 + (C_m(β) − C_m(α))·T⁻¹.

    Raises:
        ModelError: β outside [1, α], or the crossover integrator_lead_weight refuses.
    """
    if not 1.0 <= lead_used <= LEAD_RATIO:
        raise ModelError(f"lead_used = {lead_used} must lie in [1, {LEAD_RATIO:g}] (the lead ratio)")
    nominal = integrator_lead_weight(Ts, crossover, 1, integral_ratio=integral_ratio, lead_ratio=LEAD_RATIO,
                                     rolloff_ratio=ROLLOFF_RATIO, integral=integral)
    p, r = crossover * np.sqrt(LEAD_RATIO), ROLLOFF_RATIO * crossover
    poles = np.array([0.0, -p, -r] if integral else [-p, -r])

    def residues(beta: float) -> np.ndarray:
        numerator = (r * (poles + crossover / integral_ratio) * (poles + p / beta) if integral
                     else r * (poles + p / beta))
        return np.array([[n / np.prod([sk - sl for sl in poles if sl != sk])
                          for n, sk in zip(numerator, poles, strict=True)]])

    A_m = np.diag(np.exp(poles * Ts))
    B_m = np.array([[Ts] if sk == 0.0 else [-np.expm1(sk * Ts) / -sk] for sk in poles])
    A, B = (np.asarray(M, dtype=float) for M in (nominal.A, nominal.B))
    T = control.ctrb(A, B) @ np.linalg.inv(control.ctrb(A_m, B_m))
    shift = residues(lead_used) - residues(LEAD_RATIO)
    C = np.asarray(nominal.C, dtype=float) + np.linalg.solve(T.T, shift.T).T
    channel = control.ss(A, B, C, nominal.D, Ts)
    return control.append(*[channel] * inputs) if inputs > 1 else channel


def point_goals(goal: Mapping[str, float], nugap: Sequence[float] | None) -> np.ndarray | None:
    """g_j = max(f·δν_j, b_min) at the validate points (module docstring); None without points.

    Raises:
        DataError: ``nugap_factor`` without a ν-gap to apply it to.
    """
    if nugap is None:
        if "nugap_factor" in goal:
            raise DataError("[synth] margin_goal.nugap_factor needs the validate stage's ν-gap: run it in "
                            "`lpvflow design` with [validate] reference = \"linearization\" or \"local\", or "
                            "give only at_least")
        return None
    factor, floor = goal.get("nugap_factor", 0.0), goal.get("at_least", 0.0)
    return np.maximum(factor * np.asarray(nugap, dtype=float), floor)


def vertex_goals(goal: Mapping[str, float], points: Sequence[Sequence[float]] | None,
                 nugap: Sequence[float] | None, polytope: Polytope, basis: Basis) -> np.ndarray:
    """The goal of every vertex (breakpoint): the largest g_j of :func:`point_goals` over the points θ_j
    with λ_i(θ_j) > 0, and ``at_least`` (0 without it) at a vertex no point touches."""
    floor = goal.get("at_least", 0.0)
    goals = np.full(polytope.n_vertices, floor)
    g = point_goals(goal, nugap)
    if g is None:
        return goals
    for theta, g_j in zip(points, g, strict=True):
        touched = polytope.coordinates_at(basis, np.asarray(theta, dtype=float)) > TOUCH_TOL
        goals[touched] = np.maximum(goals[touched], g_j)
    return goals


@dataclass(frozen=True)
class Shaping:
    """What the loop-shaping weights of every breakpoint share: the crossover ω_c (rad/s), the integral
    corner ratio r_i and the output weight W2 (the same at every breakpoint): W2 = I, and the integral
    action is W1's at the plant's inputs, or W2 integrates chosen outputs
    (:func:`lpvflow.synth.loop_shaping.output_integral_weight`) and W1 is lead and roll-off only; W2 may
    also wash out chosen outputs (:func:`lpvflow.synth.loop_shaping.output_washout_weight`)."""

    crossover: float
    integral_ratio: float
    W2: control.StateSpace

    @property
    def input_integral(self) -> bool:
        """W1 carries the integral action: W2 has no integrator (no pole at z = 1; a washout's pole is
        inside the unit circle)."""
        return not np.any(np.isclose(np.linalg.eigvals(self.W2.A), 1.0, rtol=0.0, atol=1e-12))

    def weight(self, G: control.StateSpace, lead_used: float = LEAD_RATIO) -> control.StateSpace:
        """W1 with lead ratio ``lead_used`` (:func:`lead_weight`), normalized so that W2·G·W1 crosses 1 at
        ω_c (:func:`lpvflow.synth.loop_shaping.crossover_normalized`)."""
        W1 = lead_weight(float(G.dt), self.crossover, G.ninputs, lead_used,
                         integral_ratio=self.integral_ratio, integral=self.input_integral)
        return crossover_normalized(G, W1, self.crossover, self.W2)


@dataclass
class LeadChoice:
    """The weight W1_i (normalized to cross at ω_c), the central controller K∞_i, its level γ_i, the
    shipped margin b(G_i, W1_i·K∞_i·W2) and the lead ratio β_i a breakpoint ends up with."""

    weight: control.StateSpace
    controller: control.StateSpace
    gamma: float
    b: float
    lead_used: float


def lead_for_goal(G: control.StateSpace, goal: float, shaping: Shaping,
                  controller: Callable[[control.StateSpace], tuple[control.StateSpace, float]]) -> LeadChoice:
    """The first β on the ladder α^{1 − k/LADDER_STEPS} (k = 0, 1, …) whose W1 (``shaping.weight``) and K∞,
    γ = ``controller``(W2·G·W1) give b(G, W1·K∞·W2) ≥ ``goal``; the β of the largest b when none does (the
    caller tells)."""
    best = None
    for k in range(LADDER_STEPS + 1):
        beta = LEAD_RATIO ** (1.0 - k / LADDER_STEPS)
        W1 = shaping.weight(G, beta)
        K, gamma = controller(shaped_plant(G, W1, shaping.W2))
        choice = LeadChoice(W1, K, gamma, generalized_margin(G, W1 * K * shaping.W2), beta)
        if choice.b >= goal:
            return choice
        best = choice if best is None or choice.b > best.b else best
    return best


@dataclass
class MarginGoalReport:
    """Per breakpoint: the goal, the shipped margin b(G_i, W1_i·K∞_i) and the lead ratio used; ``names``
    says where each breakpoint lies."""

    goals: list[float]
    b: list[float]
    lead_used: list[float]
    names: list[str]

    @property
    def unmet(self) -> list[int]:
        return [i for i, (b, g) in enumerate(zip(self.b, self.goals, strict=True)) if b < g]

    def lines(self) -> list[str]:
        reduced = [f"{name} β {beta:.3g}" for name, beta in zip(self.names, self.lead_used, strict=True)
                   if beta < LEAD_RATIO]
        met = len(self.goals) - len(self.unmet)
        return [f"margin goal: b(G_i, W1_i·K∞_i) ≥ goal at {met} of {len(self.goals)} breakpoints (smallest "
                f"b − goal {min(b - g for b, g in zip(self.b, self.goals, strict=True)):+.3g}); lead ratio "
                f"lowered from {LEAD_RATIO:g} at " + (", ".join(reduced) if reduced else "no breakpoint")]

    def warn(self) -> None:
        """One :class:`MarginGoalWarning` line naming the breakpoints where the goal is not met."""
        if self.unmet:
            where = "; ".join(f"{self.names[i]}: b {self.b[i]:.3g} < goal {self.goals[i]:.3g}"
                              for i in self.unmet)
            warnings.warn(MarginGoalWarning(
                f"[synth] margin_goal is not met at {len(self.unmet)} breakpoint(s) with any lead ratio "
                f"({where}; the lead of the largest b kept); lower the goal there or change crossover / "
                "integral_ratio"),
                stacklevel=3)


def breakpoint_names(breakpoints: object, polytope: Polytope) -> list[str]:
    """"<signal> = v" for breakpoints given as values of a plant signal, "p_1 = b" for other breakpoints,
    else "vertex i"."""
    source = getattr(breakpoints, "source", None)
    if source is not None and len(source.values) == polytope.n_vertices:
        return [f"{source.signal} = {v:.4g}" for v in source.values]
    if polytope.breakpoints is not None:
        return [f"p_1 = {b:.4g}" for b in polytope.breakpoints]
    return [f"vertex {i}" for i in range(polytope.n_vertices)]
