"""Batched frequency responses and the bilinear map for state-space LTI systems.

Shared by the ν-gap (nugap.py) and the stability margin (margins.py). Both need the frequency
response at many points at once and a continuous-time equivalent of a discrete-time system in
which the unit circle becomes the imaginary axis.
"""

from __future__ import annotations

import control
import numpy as np

from lpvflow.errors import ModelError


def as_statespace(system: object, name: str) -> control.StateSpace:
    """Return `system` as a `control.StateSpace` (transfer functions are realized)."""
    if isinstance(system, control.StateSpace):
        return system
    if isinstance(system, control.TransferFunction):
        return control.ss(system)
    raise ModelError(
        f"{name} is a {type(system).__name__}, not an LTI system; "
        "pass a control.StateSpace or TransferFunction"
    )


def is_discrete(system: control.StateSpace) -> bool:
    """True for a discrete-time system (dt > 0 or dt = True)."""
    return system.dt is not None and system.dt is not False and system.dt != 0


def frequency_response(system: control.StateSpace, points: np.ndarray) -> np.ndarray:
    """G(λ) = C (λI − A)⁻¹ B + D at every complex point λ, as an array of shape (N, outputs, inputs).

    One batched LU solve per point (numpy), no Python loop; λ is s = jω in continuous time and
    z = e^{jωTs} in discrete time (the caller chooses).
    """
    points = np.asarray(points, dtype=complex).ravel()
    D = np.broadcast_to(np.asarray(system.D, dtype=complex), (points.size, *system.D.shape))
    n = system.nstates
    if n == 0:
        return D.copy()
    pencil = points[:, None, None] * np.eye(n) - np.asarray(system.A, dtype=complex)
    B = np.broadcast_to(np.asarray(system.B, dtype=complex), (points.size, *system.B.shape))
    return np.asarray(system.C, dtype=complex) @ np.linalg.solve(pencil, B) + D


def contour_points(system: control.StateSpace, omega: np.ndarray) -> np.ndarray:
    """Points of the stability boundary at angular frequencies ω (rad/s; rad/sample if dt is True)."""
    if not is_discrete(system):
        return 1j * np.asarray(omega, dtype=float)
    Ts = 1.0 if system.dt is True else float(system.dt)
    return np.exp(1j * np.asarray(omega, dtype=float) * Ts)


def bilinear_to_continuous(
    A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, rotation: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Realization of Gc(s) = G(e^{jφ}(1+s)/(1−s)) from a discrete-time realization of G(z).

    With Ã = e^{−jφ}A, B̃ = e^{−jφ}B (the rotation z = e^{jφ}z̃ keeps the unit disk):
    Ac = (Ã+I)⁻¹(Ã−I), Bc = √2 (Ã+I)⁻¹B̃, Cc = √2 C(Ã+I)⁻¹, Dc = D − C(Ã+I)⁻¹B̃.
    The map sends |z| > 1 to Re s > 0 and the unit circle to the imaginary axis (z = −e^{jφ} to
    s = ∞), so pole and zero counts outside the unit disk equal counts in the open right half plane
    (Boonto's thesis Sec. 6.1: the ν-gap in discrete time via s = (z−1)/(z+1)). Needs −e^{jφ} not to
    be a pole.
    """
    n = A.shape[0]
    turn = np.exp(-1j * rotation) if rotation else 1.0
    At, Bt = turn * A, turn * B
    if n == 0:
        return At, Bt, C, D
    shifted_inv = np.linalg.inv(At + np.eye(n))
    Ac = shifted_inv @ (At - np.eye(n))
    Bc = np.sqrt(2.0) * shifted_inv @ Bt
    Cc = np.sqrt(2.0) * C @ shifted_inv
    Dc = D - C @ shifted_inv @ Bt
    return Ac, Bc, Cc, Dc


def continuous_equivalent(system: control.StateSpace) -> control.StateSpace:
    """A continuous-time system with the same H∞ norm and stability (Tustin map, rotation 0).

    Used to compute discrete-time H∞ norms with `control.norm`, whose SciPy path refuses
    discrete-time systems with poles at z = 0; the bilinear map preserves ‖·‖∞ and maps the open
    unit disk onto the open left half plane. Requires no pole at z = −1.
    """
    if not is_discrete(system):
        return system
    if system.nstates and np.min(np.abs(np.linalg.eigvals(system.A) + 1.0)) < 1e-9:
        raise ModelError("the system has a pole at z = -1 on the unit circle; its H-infinity norm is inf")
    Ac, Bc, Cc, Dc = bilinear_to_continuous(system.A, system.B, system.C, system.D)
    return control.ss(np.real(Ac), np.real(Bc), np.real(Cc), np.real(Dc))
