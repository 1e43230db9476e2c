"""Vinnicombe's ν-gap metric δν(P1, P2) for continuous- and discrete-time MIMO state-space systems.

Definition (Vinnicombe, "Frequency domain uncertainty and the graph topology", IEEE TAC 38, 1993;
"Uncertainty and Feedback", 2001, §3.3; Boonto's thesis §6.1, eq. (6.3)):

    δν(P1, P2) = max_ω κ(P1(jω), P2(jω))   if det(I + P2*P1)(jω) ≠ 0 for all ω (incl. ∞) and
                                            wno det(I + P2~P1) + η(P1) − η̃(P2) = 0,
                 1                          otherwise,

with the pointwise chordal distance
κ(G1, G2) = σ_max((I + G2 G2*)^{−1/2} (G1 − G2) (I + G1* G1)^{−1/2}), P~(s) = P(−s̄)*, η(P) the number
of open right-half-plane poles, η̃(P) the number of closed right-half-plane poles, and wno g the
number of zeros minus poles of g inside the Nyquist D-contour indented into the right half plane
around imaginary-axis poles. In discrete time the unit circle replaces the imaginary axis and
|z| > 1 the right half plane (bilinear map s = (z−1)/(z+1), thesis §6.1).

Winding number by eigenvalues. With H = P2~P1 realized by (A_H, B_H, C_H, D_H), the identity
det(I + H(s)) = det(sI − A_H + B_H (I + D_H)⁻¹ C_H) / det(sI − A_H) counts zeros and poles exactly.
The eigenvalues of A_H are those of P1 and the mirror images −λ̄ of those of P2, so the poles of
det(I + H) in the open RHP are η(P1) plus the n2 − η̃(P2) stable poles of P2 mirrored. The condition
wno + η(P1) − η̃(P2) = 0 therefore reduces to

    #{zeros of det(I + P2~P1) in Re s > 0} = n2   (the state dimension of P2),

valid when P1 has no hidden open-RHP modes and P2 no hidden closed-RHP modes (checked; such a
realization is refused). This matches MATLAB `gapmetric` on its documented example:
δν(1/(s−0.001), 1/(s+0.001)) = 0.0020.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.validate.lti_eval import (
    as_statespace,
    bilinear_to_continuous,
    contour_points,
    frequency_response,
    is_discrete,
)

#: Relative distance to the stability boundary below which an eigenvalue counts as on it.
BOUNDARY_TOL = 1e-8
#: Rotations e^{jφ} tried for the discrete-time bilinear map when z = −1 is (nearly) a pole.
_ROTATIONS = (0.0, 0.3141, 0.7071, 1.1235, 1.7321, 2.2361)


@dataclass(frozen=True)
class NuGapResult:
    """δν with where it is attained and whether Vinnicombe's winding-number condition held.

    `frequency` is in rad/s (rad/sample when dt is True; `inf` for s = ∞ in continuous time).
    `chordal_max` is max_ω κ whatever the winding condition; `value` is δν. `grid`/`chordal` hold
    the evaluated frequencies and κ values when asked for.
    """

    value: float
    frequency: float
    winding_condition_held: bool
    chordal_max: float
    reason: str
    grid: np.ndarray | None = None
    chordal: np.ndarray | None = None


def chordal_distance(G1: np.ndarray, G2: np.ndarray) -> np.ndarray:
    """κ = σ_max((I + G2 G2*)^{−1/2} (G1 − G2) (I + G1* G1)^{−1/2}) for stacks of shape (N, p, m).

    For SISO this is |g1 − g2| / √((1 + |g1|²)(1 + |g2|²)).
    """
    if G1.shape[1:] == (1, 1):
        g1, g2 = G1[:, 0, 0], G2[:, 0, 0]
        return np.abs(g1 - g2) / np.sqrt((1.0 + np.abs(g1) ** 2) * (1.0 + np.abs(g2) ** 2))
    left = _inverse_sqrt(np.eye(G2.shape[1]) + G2 @ np.conj(np.swapaxes(G2, 1, 2)))
    right = _inverse_sqrt(np.eye(G1.shape[2]) + np.conj(np.swapaxes(G1, 1, 2)) @ G1)
    return np.linalg.svd(left @ (G1 - G2) @ right, compute_uv=False)[:, 0]


def _inverse_sqrt(hermitian: np.ndarray) -> np.ndarray:
    """M^{−1/2} of a stack of Hermitian positive definite matrices (eigendecomposition)."""
    w, V = np.linalg.eigh(hermitian)
    return (V * (1.0 / np.sqrt(w))[:, None, :]) @ np.conj(np.swapaxes(V, 1, 2))


def nugap(P1: object, P2: object, *, return_grid: bool = False, points_per_decade: int = 25) -> NuGapResult:
    """Vinnicombe ν-gap δν(P1, P2) ∈ [0, 1] of two LTI systems of equal size and time base.

    Frequency grid: logarithmic (`points_per_decade`) over the span of the poles of P1, P2 and the
    zeros of det(I + P2~P1), plus those frequencies themselves, points one distance-to-boundary
    either side of them (resonance peaks), ω = 0 and the Nyquist frequency (or s = ∞); the largest
    local maxima are then refined by zooming in (`_refine_maximum`). Raises ModelError for systems of
    different sizes, sampling times, or a continuous/discrete mix.
    """
    P1, P2, Ts = _checked_pair(P1, P2)
    held, reason, g_zeros = _winding_condition(P1, P2)
    omega = _frequency_grid(P1, P2, g_zeros, Ts, points_per_decade)
    kappa = _chordal_on_grid(P1, P2, omega)
    best_omega, best_kappa = _refine_maximum(P1, P2, omega, kappa)
    if held and best_kappa >= 1.0 - 1e-12:
        held, reason = False, "det(I + P2*P1) vanishes on the stability boundary (chordal distance 1)"
    return NuGapResult(
        value=float(min(best_kappa, 1.0)) if held else 1.0,
        frequency=float(best_omega),
        winding_condition_held=held,
        chordal_max=float(min(best_kappa, 1.0)),
        reason=reason,
        grid=omega if return_grid else None,
        chordal=kappa if return_grid else None,
    )


def _checked_pair(P1: object, P2: object) -> tuple[control.StateSpace, control.StateSpace, float | None]:
    """Both systems as StateSpace with the same size and time base; Ts (None in continuous time)."""
    P1, P2 = as_statespace(P1, "P1"), as_statespace(P2, "P2")
    if (P1.noutputs, P1.ninputs) != (P2.noutputs, P2.ninputs):
        raise ModelError(
            f"P1 is {P1.noutputs}x{P1.ninputs} (outputs x inputs) but P2 is {P2.noutputs}x{P2.ninputs}; "
            "compare systems with the same inputs and outputs"
        )
    kinds = ("discrete" if is_discrete(P1) else "continuous", "discrete" if is_discrete(P2) else "continuous")
    if kinds[0] != kinds[1]:
        raise ModelError(
            f"P1 is {kinds[0]}-time but P2 is {kinds[1]}-time; discretize one (control.sample_system) first"
        )
    if kinds[0] == "continuous":
        return P1, P2, None
    Ts = [None if dt is True else float(dt) for dt in (P1.dt, P2.dt)]
    if None not in Ts and not np.isclose(Ts[0], Ts[1], rtol=1e-9, atol=0.0):
        raise ModelError(f"P1 has Ts = {Ts[0]} but P2 has Ts = {Ts[1]}; resample one so both share Ts")
    return P1, P2, next((t for t in Ts if t is not None), 1.0)


def _winding_condition(P1: control.StateSpace, P2: control.StateSpace) -> tuple[bool, str, np.ndarray]:
    """(condition held, reason if not, zeros of det(I + P2~P1) mapped to the original s- or z-plane)."""
    discrete = is_discrete(P1)
    rotation = _choose_rotation(P1, P2) if discrete else 0.0
    A1, B1, C1, D1 = _continuous_realization(P1, rotation)
    A2, B2, C2, D2 = _continuous_realization(P2, rotation)
    _refuse_hidden_unstable_modes(A1, B1, C1, "P1", closed=False)
    _refuse_hidden_unstable_modes(A2, B2, C2, "P2", closed=True)
    # P2~ = (−A2*, −C2*, B2*, D2*); H = P2~ P1 in series.
    A2t, B2t, C2t, D2t = -A2.conj().T, -C2.conj().T, B2.conj().T, D2.conj().T
    n1, n2 = A1.shape[0], A2.shape[0]
    A_H = np.block([[A1, np.zeros((n1, n2))], [B2t @ C1, A2t]])
    B_H = np.vstack([B1, B2t @ D1])
    C_H = np.hstack([D2t @ C1, C2t])
    I_plus_D = np.eye(D1.shape[1]) + D2t @ D1
    at_infinity = "z = -1" if discrete else "s = infinity"
    if np.linalg.svd(I_plus_D, compute_uv=False)[-1] < 1e-10 * max(1.0, np.linalg.norm(I_plus_D, 2)):
        return False, f"det(I + P2*P1) vanishes at {at_infinity} on the stability boundary", np.empty(0)
    if n1 + n2 == 0:
        return True, "", np.empty(0)
    zeros = np.linalg.eigvals(A_H - B_H @ np.linalg.solve(I_plus_D, C_H))
    in_rhp = int(np.sum(zeros.real > BOUNDARY_TOL * np.maximum(1.0, np.abs(zeros))))
    with np.errstate(divide="ignore", invalid="ignore"):  # w = 1 is a zero at z = ∞ (pure delays in P2)
        original = np.exp(1j * rotation) * (1.0 + zeros) / (1.0 - zeros) if discrete else zeros
    if in_rhp == n2:
        return True, "", original
    return (
        False,
        f"winding-number condition fails: det(I + P2~P1) has {in_rhp} unstable zeros where Vinnicombe's "
        f"condition needs {n2} (wno + eta(P1) - eta~(P2) = {in_rhp - n2})",
        original,
    )


def _continuous_realization(system: control.StateSpace, rotation: float) -> tuple[np.ndarray, ...]:
    """Complex (A, B, C, D) of the system, mapped to continuous time if it is discrete."""
    A, B, C, D = (np.asarray(M, dtype=complex) for M in (system.A, system.B, system.C, system.D))
    if is_discrete(system):
        return bilinear_to_continuous(A, B, C, D, rotation)
    return A, B, C, D


def _choose_rotation(P1: control.StateSpace, P2: control.StateSpace) -> float:
    """A rotation φ such that z = −e^{jφ} is well away from every pole and from det(I + P2*P1) = 0."""
    poles = np.concatenate([np.linalg.eigvals(P.A) if P.nstates else np.empty(0) for P in (P1, P2)])

    def clearance(phi: float) -> float:
        point = np.array([-np.exp(1j * phi)])
        pole_gap = np.min(np.abs(poles - point[0])) if poles.size else np.inf
        if pole_gap < 1e-9:
            return 0.0
        G1, G2 = frequency_response(P1, point)[0], frequency_response(P2, point)[0]
        det_gap = np.linalg.svd(np.eye(G1.shape[1]) + G2.conj().T @ G1, compute_uv=False)[-1]
        return min(pole_gap, det_gap / (1.0 + np.linalg.norm(G1, 2) * np.linalg.norm(G2, 2)))

    if clearance(0.0) >= 1e-3:
        return 0.0
    return max(_ROTATIONS, key=clearance)


def _refuse_hidden_unstable_modes(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, name: str, closed: bool
) -> None:
    """ModelError if an (open/closed) right-half-plane mode is uncontrollable or unobservable (PBH test)."""
    n = A.shape[0]
    scale = max(1.0, np.linalg.norm(A, 2), np.linalg.norm(B, 2), np.linalg.norm(C, 2))
    for lam in np.linalg.eigvals(A) if n else []:
        limit = -BOUNDARY_TOL if closed else BOUNDARY_TOL
        if lam.real <= limit * max(1.0, abs(lam)):
            continue
        shifted = A - lam * np.eye(n)
        ctrb = np.linalg.svd(np.hstack([shifted, B]), compute_uv=False)[-1]
        obsv = np.linalg.svd(np.vstack([shifted, C]), compute_uv=False)[-1]
        if min(ctrb, obsv) < 1e-9 * scale:
            raise ModelError(
                f"{name} has an uncontrollable or unobservable unstable mode "
                f"(continuous-equivalent pole {lam:.4g}); pass a minimal realization (remove hidden modes)"
            )


def _frequency_grid(
    P1: control.StateSpace, P2: control.StateSpace, g_zeros: np.ndarray, Ts: float | None, per_decade: int
) -> np.ndarray:
    """Sorted frequencies (rad/s): log grid + critical frequencies + offsets, endpoints included."""
    poles = np.concatenate([np.linalg.eigvals(P.A) if P.nstates else np.empty(0) for P in (P1, P2)])
    critical = np.concatenate([poles, g_zeros])
    critical = critical[np.isfinite(critical)]
    if Ts is None:
        centres = np.concatenate([np.abs(critical.imag), np.abs(critical)])
        widths = np.concatenate([np.abs(critical.real), np.abs(critical.real)])
        positive = centres[centres > 0]
        lo = 10.0 ** (np.floor(np.log10(positive.min())) - 2) if positive.size else 1e-3
        hi = 10.0 ** (np.ceil(np.log10(positive.max())) + 2) if positive.size else 1e3
        upper = np.inf
    else:
        safe = critical[np.abs(critical + 1.0) > 1e-12]
        corner = 2.0 * np.arctan(np.abs((safe - 1.0) / (safe + 1.0)))
        centres = np.concatenate([np.abs(np.angle(critical)), corner])
        widths = np.concatenate([np.abs(np.abs(critical) - 1.0), np.abs(np.abs(safe) - 1.0)])
        positive = centres[centres > 0]
        lo = min(1e-4, positive.min() / 100.0) if positive.size else 1e-4
        hi = upper = np.pi
    log_grid = np.logspace(np.log10(lo), np.log10(hi), max(2, int(np.log10(hi / lo) * per_decade)))
    offsets = np.concatenate([centres - widths, centres + widths, centres - widths / 2, centres + widths / 2])
    theta = np.concatenate([[0.0, hi], log_grid, centres, offsets])
    theta = np.unique(theta[(theta >= 0.0) & (theta <= hi)])
    if Ts is None:
        theta = np.append(theta, upper)
    theta = _away_from_boundary_poles(theta, poles, Ts)
    distinct = np.concatenate([[True], np.diff(theta) > 1e-12 * np.maximum(1.0, theta[1:])])
    theta = theta[distinct | ~np.isfinite(theta)]
    return theta if Ts is None else theta / Ts


def _away_from_boundary_poles(theta: np.ndarray, poles: np.ndarray, Ts: float | None) -> np.ndarray:
    """Replace grid points that sit on a pole on the stability boundary by points just beside it.

    `theta` is ω (continuous time, may end with ∞) or ωTs in rad/sample (discrete time).
    """
    finite = theta[np.isfinite(theta)]
    if not poles.size:
        return theta
    boundary = 1j * finite if Ts is None else np.exp(1j * finite)
    distance = np.min(np.abs(boundary[:, None] - poles[None, :]), axis=1)
    clash = distance < 1e-9 * np.maximum(1.0, np.abs(boundary))
    if not clash.any():
        return theta
    shift = 1e-6 * np.maximum(1.0, finite[clash])
    nudged = np.concatenate([finite[clash] - shift, finite[clash] + shift])
    limit = np.pi if Ts is not None else np.inf
    kept = np.concatenate([finite[~clash], nudged[(nudged > 0) & (nudged < limit)]])
    return np.concatenate([np.unique(kept), theta[~np.isfinite(theta)]])


def _chordal_on_grid(P1: control.StateSpace, P2: control.StateSpace, omega: np.ndarray) -> np.ndarray:
    """κ(ω) on the grid; ω = ∞ (continuous time) evaluates the feedthrough matrices D."""
    finite = np.isfinite(omega)
    kappa = np.empty(omega.size)
    points = contour_points(P1, omega[finite])
    kappa[finite] = chordal_distance(frequency_response(P1, points), frequency_response(P2, points))
    if not finite.all():
        kappa[~finite] = chordal_distance(np.asarray(P1.D, complex)[None], np.asarray(P2.D, complex)[None])[0]
    return kappa


def _refine_maximum(
    P1: control.StateSpace, P2: control.StateSpace, omega: np.ndarray, kappa: np.ndarray,
    n_peaks: int = 3, rounds: int = 5, points: int = 33,
) -> tuple[float, float]:
    """Refine the largest local maxima of κ by zooming in between their grid neighbours.

    Each round evaluates κ at `points` equispaced frequencies in every bracket (one batched call
    for all brackets) and shrinks each bracket to the two neighbours of its best point, a factor
    (points − 1)/2 per round; five rounds shrink a bracket 16⁵ ≈ 10⁶-fold.
    """
    best = int(np.argmax(kappa))
    best_omega, best_kappa = omega[best], kappa[best]
    padded = np.concatenate([[-np.inf], kappa, [-np.inf]])
    peaks = np.flatnonzero((padded[1:-1] >= padded[:-2]) & (padded[1:-1] >= padded[2:]))
    peaks = peaks[np.argsort(kappa[peaks])[::-1][:n_peaks]]
    lo = omega[np.maximum(peaks - 1, 0)]
    hi = omega[np.minimum(peaks + 1, omega.size - 1)]
    usable = np.isfinite(hi) & (hi > lo)
    lo, hi = lo[usable], hi[usable]
    if not lo.size:
        return best_omega, best_kappa
    for _ in range(rounds):
        trial = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, points)[None, :]
        points_on_boundary = contour_points(P1, trial.ravel())
        values = chordal_distance(
            frequency_response(P1, points_on_boundary), frequency_response(P2, points_on_boundary)
        ).reshape(trial.shape)
        top = np.argmax(values, axis=1)
        rows = np.arange(trial.shape[0])
        if values[rows, top].max() > best_kappa:
            row = int(np.argmax(values[rows, top]))
            best_omega, best_kappa = trial[row, top[row]], values[row, top[row]]
        lo = trial[rows, np.maximum(top - 1, 0)]
        hi = trial[rows, np.minimum(top + 1, points - 1)]
    return best_omega, best_kappa
