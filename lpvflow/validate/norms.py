"""H∞ norm of a stable LTI system that stays finite for poles near the unit circle.

``control.norm(G, "inf")`` returns ∞ for every pole with |z| within ``np.isclose`` of 1 (about 1e-5):
every loop sampled at 1 ms with an integral weight has one. SLICOT's AB13DD (Bruinsma & Steinbuch 1990,
the two-step Hamiltonian/symplectic iteration, through ``control.linfnorm``) computes the L∞ norm of such
a system without that test; for a stable system it equals the H∞ norm.
"""

from __future__ import annotations

import warnings

import control
import numpy as np


def spectral_abscissa(sys: control.StateSpace) -> float:
    """max |z| of the poles (discrete) or max Re s (continuous); −inf for a static gain."""
    A = np.asarray(sys.A, dtype=float)
    if A.size == 0:
        return -np.inf
    eig = np.linalg.eigvals(A)
    return float(np.max(np.abs(eig))) if sys.isdtime() else float(np.max(eig.real))


def is_stable(sys: control.StateSpace) -> bool:
    """All poles strictly inside the unit circle (discrete) or the left half plane (continuous)."""
    return spectral_abscissa(sys) < (1.0 if sys.isdtime() else 0.0)


def hinf_norm(sys: control.StateSpace) -> float:
    """‖G‖∞ of ``sys``: ∞ when it is unstable; else python-control's ``norm(G, "inf")``, and where that
    returns ∞ for a stable system (poles within ~1e-5 of the unit circle or the imaginary axis), SLICOT
    AB13DD through ``control.linfnorm``."""
    if not is_stable(sys):
        return float("inf")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # python-control's "poles close to the unit circle"
        value = float(control.norm(sys, "inf", print_warning=False))
    if np.isinf(value):
        value = float(control.linfnorm(sys)[0])
    return value
