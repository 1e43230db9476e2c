"""Robust stability of a frozen discrete loop: b(G, K), the optimal margin b_opt(G), delay and disk margins.

Feedback convention (positive feedback, the one of the H∞ loop-shaping literature and of
``lpvflow.synth.hinf``): the controller K reads the plant output and drives its input, u = K y. With
disturbances w1 at the plant output and w2 at the plant input,

    y = G (u + w2) + w1,   u = K y,
    T(G, K): [w1; w2] ↦ [y; u] = [I; K] (I − G K)⁻¹ [I  G],

    b(G, K) = 1 / ‖T(G, K)‖∞ if the loop is internally stable, else 0
    (Vinnicombe, "Uncertainty and Feedback", 2001, §2.4; McFarlane & Glover 1990, §3.2).

This is :func:`lpvflow.validate.margins.stability_margin` with K replaced by −K (that module uses
u = −K y); the closed loop and its stability test are the ones of that module. Vinnicombe's theorem:
K stabilizes every plant G' with δν(G, G') < b(G, K) (the ν-gap is :mod:`lpvflow.validate.nugap`).

The optimal margin over all controllers (McFarlane & Glover, "Robust Controller Design Using
Normalized Coprime Factor Plant Descriptions", LNCIS 138, Springer 1990, §3.2; Zhou, Doyle & Glover,
"Robust and Optimal Control", 1996, Thm. 18.2 / Cor. 13.29 for D ≠ 0) is

    b_opt(G) = (1 + λmax(X Z))^{−1/2}

with X, Z the stabilizing solutions of the control and filter Riccati equations of the normalized
coprime factorization of a *continuous* G = (A, B, C, D), R = I + DᵀD, S = I + DDᵀ,
A_r = A − B R⁻¹ Dᵀ C:

    A_rᵀ X + X A_r − X B R⁻¹ Bᵀ X + Cᵀ S⁻¹ C = 0,     (GCARE)
    A_r Z + Z A_rᵀ − Z Cᵀ S⁻¹ C Z + B R⁻¹ Bᵀ = 0.     (GFARE)

A discrete G is first mapped by the bilinear (Tustin, Ts-free) transform z = (1 + s)/(1 − s)
(:func:`lpvflow.validate.lti_eval.bilinear_to_continuous`). The map is a bijection between discrete
and continuous controllers, sends the unit circle onto the imaginary axis and the unit disk onto the
left half plane, so it preserves internal stability and ‖T(G, K)‖∞, hence b(G, K) for every K and
therefore b_opt (and the ν-gap). The Riccati equations are solved by ``scipy.linalg.solve_continuous_are``
with the cross term (its ``s`` argument), whose expansion is exactly the two equations above, on the image
scaled in frequency to ‖A‖₂ = 1: G(αs) has the realization (A/α, B/√α, C/√α, D), and both equations of it
are those of G divided by α, so X and Z do not change — but the solver's ordered QZ does. Unscaled, it gave
up ("Reordering of (A, B) failed … very ill-conditioned") on a shaped ADIP plant with a double pole at
z = 1 (‖A‖₂ = 3.5, ‖B‖ = 0.009), which every α from 0.01 to 10 solves (γ_opt 4.6534457423, as SLICOT's
SG02AD); on the 363 plants the loop-shaping tests pass to it (a scratch probe, session 30) the scaled
γ_opt agrees with the unscaled to 7e-9.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np
import scipy.linalg

from lpvflow.errors import ModelError
from lpvflow.validate.lti_eval import as_statespace, bilinear_to_continuous, is_discrete
from lpvflow.validate.margins import closed_loop, is_internally_stable
from lpvflow.validate.norms import hinf_norm

#: The Riccati closed loops must have every eigenvalue below −STABILIZING_TOL·max(1, ‖A‖) (continuous image).
STABILIZING_TOL = 1e-9
#: Largest extra input delay (samples) :func:`delay_margin_samples` tries by default.
MAX_DELAY_SAMPLES = 50


@dataclass(frozen=True)
class NcfRiccati:
    """Continuous (bilinear) image (A, B, C, D) of a plant and the stabilizing X, Z of its GCARE/GFARE."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    X: np.ndarray
    Z: np.ndarray

    @property
    def gamma_opt(self) -> float:
        """γ_opt = 1/b_opt = (1 + λmax(X Z))^{1/2}."""
        return float(np.sqrt(1.0 + max(0.0, float(np.max(np.linalg.eigvals(self.X @ self.Z).real)))))


@dataclass(frozen=True)
class RobustStability:
    """b(G, K), b_opt(G), the input delay margin (samples) and the balanced disk margin at the plant input."""

    b: float
    b_opt: float
    delay_margin_samples: int
    input_disk_margin: float
    input_disk_gain_margin_db: float
    input_disk_phase_margin_deg: float


def generalized_margin(G: object, K: object) -> float:
    """b(G, K) = 1/‖[I; K](I − GK)⁻¹[I  G]‖∞ for u = K y (module docstring), 0 if the loop is unstable."""
    G, K = as_statespace(G, "G"), as_statespace(K, "K")
    minus_K = -K
    if not is_internally_stable(G, minus_K):
        return 0.0
    return float(min(1.0, 1.0 / hinf_norm(closed_loop(G, minus_K))))


def ncf_riccati(G: object) -> NcfRiccati:
    """The continuous (bilinear) image of G and the stabilizing solutions X, Z of its GCARE and GFARE.

    Raises ModelError when G is not discrete or the Riccati equations have no stabilizing solution
    (G not stabilizable and detectable, or a hidden mode on the unit circle).
    """
    G = as_statespace(G, "G")
    if not is_discrete(G):
        raise ModelError("ncf_riccati needs a discrete-time plant (dt = Ts > 0)")
    A, B, C, D = (np.real(M) for M in bilinear_to_continuous(
        *(np.asarray(M, dtype=float) for M in (G.A, G.B, G.C, G.D))))
    R = np.eye(B.shape[1]) + D.T @ D
    S = np.eye(C.shape[0]) + D @ D.T
    alpha = np.linalg.norm(A, 2) or 1.0  # the frequency scale s → αs (module docstring)
    Aa, Ba, Ca = A / alpha, B / np.sqrt(alpha), C / np.sqrt(alpha)
    try:
        X = scipy.linalg.solve_continuous_are(Aa, Ba, Ca.T @ Ca, R, s=Ca.T @ D)
        Z = scipy.linalg.solve_continuous_are(Aa.T, Ca.T, Ba @ Ba.T, S, s=Ba @ D.T)
    except (np.linalg.LinAlgError, ValueError) as error:
        raise ModelError(f"the plant's normalized coprime factor Riccati equations have no stabilizing "
                         f"solution that scipy finds ({error}): the plant is not stabilizable and "
                         "detectable, or its equations are too ill-conditioned for the solver") from error
    X, Z = (X + X.T) / 2, (Z + Z.T) / 2
    control_loop = A - B @ np.linalg.solve(R, B.T @ X + D.T @ C)
    filter_loop = A - np.linalg.solve(S.T, (Z @ C.T + B @ D.T).T).T @ C
    worst = max(np.max(np.linalg.eigvals(M).real, initial=-np.inf) for M in (control_loop, filter_loop))
    if worst >= -STABILIZING_TOL * max(1.0, alpha):
        raise ModelError("the plant's normalized coprime factor Riccati equations have no stabilizing "
                         "solution (a mode on the unit circle is uncontrollable or unobservable, so no "
                         "controller stabilizes it: b_opt = 0); pass a minimal plant")
    return NcfRiccati(A, B, C, D, X, Z)


def optimal_margin(G: object) -> float:
    """b_opt(G) = (1 + λmax(X Z))^{−1/2} (module docstring): the largest b(G, K) of any controller."""
    return 1.0 / ncf_riccati(G).gamma_opt


def delay_margin_samples(G: object, K: object, max_samples: int = MAX_DELAY_SAMPLES) -> int:
    """The largest d such that the loop stays internally stable with every extra input delay 0 … d samples.

    The delay z^{−k} acts on every plant input at once (u reaches the plant k samples late); the loop
    with delay k is G·z^{−k} under u = K y. Returns 0 when one sample already destabilizes it, −1 when
    the undelayed loop is unstable, and ``max_samples`` when no delay up to it does.
    """
    G, K = as_statespace(G, "G"), as_statespace(K, "K")
    if not is_internally_stable(G, -K):
        return -1
    m = G.ninputs
    Ts = G.dt
    for k in range(1, max_samples + 1):
        delay = control.ss(np.eye(m * k, k=-m), np.eye(m * k, m), np.eye(m, m * k, k=m * (k - 1)),
                           np.zeros((m, m)), Ts)
        if not is_internally_stable(G * delay, -K):
            return k - 1
    return max_samples


def input_disk_margin(G: object, K: object, omega: np.ndarray | None = None) -> tuple[float, float, float]:
    """Balanced (skew 0) disk margin at the plant input, with its gain (dB) and phase (deg) margins.

    The loop broken at the plant input is L = −K G in negative-feedback form (u = K y);
    ``control.disk_margins`` (AB13MD for MIMO: independent perturbations in every input channel).
    Zeros for an unstable loop. ``omega``: rad/s, default 2000 log points up to the Nyquist frequency.
    """
    G, K = as_statespace(G, "G"), as_statespace(K, "K")
    if not is_internally_stable(G, -K):
        return 0.0, 0.0, 0.0
    if omega is None:
        Ts = 1.0 if G.dt is True else float(G.dt)
        omega = np.logspace(-4, np.log10(np.pi / Ts) - 1e-9, 2000)
    alpha, gain_db, phase_deg = control.disk_margins(-K * G, omega, skew=0.0)
    return float(alpha), float(gain_db), float(phase_deg)


def robust_stability(G: object, K: object) -> RobustStability:
    """All the margins of this module for the loop u = K y around the discrete plant G."""
    return RobustStability(generalized_margin(G, K), optimal_margin(G), delay_margin_samples(G, K),
                           *input_disk_margin(G, K))
