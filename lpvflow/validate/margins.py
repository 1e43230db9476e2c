"""Generalized stability margin b(P, K) and classical/disk margins of a frozen feedback loop.

Feedback convention (used everywhere in lpvflow.validate, and in the Vinnicombe test): negative
feedback u = −K y, as MATLAB `ncfmargin` (default sign −1) and the loop of the thesis's Fig. 6.1.
With disturbances d_y at the controller input and d_u at the plant input,

    u = d_u − K (y + d_y),   y = P u,
    T(P, K): [d_u; d_y] ↦ [y; u] = [P; I] (I + K P)⁻¹ [I, −K].

‖T(P,K)‖∞ equals the H∞ norm of the thesis's (6.1) [K; I](I + PK)⁻¹[P, I] (block signs and the
P↔K symmetry of b do not change it; tests check this on a dense grid), so

    b(P, K) = 1 / ‖T(P, K)‖∞ if the loop is internally stable, else 0      (thesis (6.2);
    Vinnicombe, "Uncertainty and Feedback", 2001, §2.4, with K replaced by −K).

Vinnicombe's theorem: if b(P1, K) > δν(P1, P2) then (P2, K) is internally stable.
"""

from __future__ import annotations

import warnings

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.validate.lti_eval import as_statespace, continuous_equivalent, is_discrete

#: Closed-loop eigenvalues must be this far inside the stability boundary to count as stable.
STABILITY_TOL = 1e-9


def closed_loop(P: object, K: object) -> control.StateSpace:
    """T(P, K) from [d_u; d_y] to [y; u] for u = d_u − K(y + d_y), with n_P + n_K states.

    The loop is closed by `control.feedback` (exact algebra, feedthrough included) around the
    augmented plant [v; w] ↦ [P v; v; P v + w] with the controller [v; w] = [d_u; d_y] − [K e; 0],
    e = y + w the third output block. Raises ModelError when I + D_K D_P is singular (ill-posed loop).
    """
    P, K = _checked_loop(P, K)
    p, m, nP, nK = P.noutputs, P.ninputs, P.nstates, K.nstates
    augmented_plant = control.ss(
        P.A,
        np.hstack([P.B, np.zeros((nP, p))]),
        np.vstack([P.C, np.zeros((m, nP)), P.C]),
        np.block([[P.D, np.zeros((p, p))], [np.eye(m), np.zeros((m, p))], [P.D, np.eye(p)]]),
        P.dt,
    )
    controller_on_e = control.ss(
        K.A,
        np.hstack([np.zeros((nK, p + m)), K.B]),
        np.vstack([K.C, np.zeros((p, nK))]),
        np.block([[np.zeros((m, p + m)), K.D], [np.zeros((p, 2 * p + m))]]),
        P.dt,
    )
    if abs(np.linalg.det(np.eye(m) + K.D @ P.D)) < 1e-12:
        raise ModelError("the loop is ill-posed: I + D_K D_P is singular; change the controller feedthrough")
    loop = control.feedback(augmented_plant, controller_on_e, sign=-1)
    return control.ss(loop.A, loop.B, loop.C[: p + m], loop.D[: p + m], P.dt)


def is_internally_stable(P: object, K: object) -> bool:
    """True when every eigenvalue of the closed loop T(P, K) lies strictly in the stable region."""
    return _stable(closed_loop(P, K))


def stability_margin(P: object, K: object) -> float:
    """b(P, K) = 1/‖T(P, K)‖∞ for an internally stable loop, 0 otherwise; 0 ≤ b ≤ 1.

    The norm is python-control's `control.norm(·, 'inf')` (Hamiltonian bisection); a discrete loop
    is first mapped to continuous time by the norm-preserving bilinear map.
    """
    T = closed_loop(P, K)
    if not _stable(T):
        return 0.0
    peak = control.norm(continuous_equivalent(T), "inf", tol=1e-8, print_warning=False)
    return float(min(1.0, 1.0 / peak))


def loop_margins(P: object, K: object, omega: np.ndarray | None = None) -> dict[str, float]:
    """Classical (SISO) and disk margins of the loop u = −K y, plus b(P, K).

    SISO: classical gain/phase margins and crossover frequencies of L = P K from
    `control.stability_margins`, and the balanced (skew 0) disk margin α = 1/max_ω |(S − T)/2|,
    S = (1 + L)⁻¹, T = L S, with its gain (dB) and phase (deg) margins, from `control.disk_margins`.

    MIMO (square loops): multiloop disk margins from `control.disk_margins` (slycot's AB13MD upper
    bound of μ((S − T)/2) for independent complex perturbations in every channel), once with the
    loop broken at the plant inputs (L = K P, keys `input_disk_*`) and once at the plant outputs
    (L = P K, keys `output_disk_*`); classical one-loop margins are not reported.

    Disk margins are 0 when the loop is not internally stable (no margin to speak of). `omega` is
    the frequency grid in rad/s (default: 2000 log points up to the Nyquist frequency).
    """
    P, K = _checked_loop(P, K)
    if omega is None:
        top = np.pi / (1.0 if P.dt is True else P.dt) if is_discrete(P) else 1e4
        omega = np.logspace(-4, np.log10(top) - 1e-9, 2000)
    b = stability_margin(P, K)
    stable = is_internally_stable(P, K)
    if P.ninputs == 1 and P.noutputs == 1:
        L = P * K
        with warnings.catch_warnings():  # "falling back to 'frd' method" is informational
            warnings.filterwarnings("ignore", message=".*Falling back to 'frd'", category=UserWarning)
            gm, pm, sm, w_phase, w_gain, _ = control.stability_margins(L)
        return {
            "gain_margin": float(gm),
            "gain_margin_db": float(20 * np.log10(gm)) if np.isfinite(gm) and gm > 0 else float("inf"),
            "phase_margin_deg": float(pm),
            "phase_crossover_rad_s": float(w_phase),
            "gain_crossover_rad_s": float(w_gain),
            "sensitivity_margin": float(sm),
            **_disk(L, omega, stable, ""),
            "stability_margin_b": b,
        }
    return {**_disk(K * P, omega, stable, "input_"), **_disk(P * K, omega, stable, "output_"),
            "stability_margin_b": b}


def _disk(L: control.StateSpace, omega: np.ndarray, stable: bool, prefix: str) -> dict[str, float]:
    """Balanced disk margin of the loop L (negative feedback) and its gain/phase margins."""
    names = [f"{prefix}disk_margin", f"{prefix}disk_gain_margin_db", f"{prefix}disk_phase_margin_deg"]
    if not stable:
        return dict.fromkeys(names, 0.0)
    values = control.disk_margins(L, omega, skew=0.0)
    return {name: float(value) for name, value in zip(names, values, strict=True)}


def _checked_loop(P: object, K: object) -> tuple[control.StateSpace, control.StateSpace]:
    """P (p×m) and K (m×p) as StateSpace on one time base; ModelError otherwise."""
    P, K = as_statespace(P, "P"), as_statespace(K, "K")
    if (K.noutputs, K.ninputs) != (P.ninputs, P.noutputs):
        raise ModelError(
            f"the plant is {P.noutputs}x{P.ninputs} (outputs x inputs) so the controller must be "
            f"{P.ninputs}x{P.noutputs}, but it is {K.noutputs}x{K.ninputs}"
        )
    if is_discrete(P) != is_discrete(K):
        kinds = ["discrete" if is_discrete(X) else "continuous" for X in (P, K)]
        raise ModelError(f"the plant is {kinds[0]}-time but the controller is {kinds[1]}-time; use one")
    if is_discrete(P) and P.dt is not True and K.dt is not True and not np.isclose(P.dt, K.dt, rtol=1e-9):
        raise ModelError(f"the plant has Ts = {P.dt} but the controller has Ts = {K.dt}; resample one")
    if is_discrete(P) and P.dt is True and K.dt is not True:
        P = control.ss(P.A, P.B, P.C, P.D, K.dt)
    elif is_discrete(K) and K.dt is True and P.dt is not True:
        K = control.ss(K.A, K.B, K.C, K.D, P.dt)
    return P, K


def _stable(system: control.StateSpace) -> bool:
    """All eigenvalues strictly inside the unit disk (discrete) or the open left half plane."""
    if system.nstates == 0:
        return True
    eigenvalues = np.linalg.eigvals(system.A)
    if is_discrete(system):
        return bool(np.max(np.abs(eigenvalues)) < 1.0 - STABILITY_TOL)
    return bool(np.max(eigenvalues.real) < -STABILITY_TOL)
