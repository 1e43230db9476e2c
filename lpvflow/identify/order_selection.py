"""Automatic model order from Hankel singular values, shared by the Ho-Kalman reduction
(:mod:`lpvflow.identify.reduce`) and balanced truncation (:mod:`lpvflow.identify.balanced`)."""

from __future__ import annotations

import numpy as np

from lpvflow.errors import ModelError

#: Default share of Σσ² an automatically selected order keeps.
ENERGY = 0.999


SELECTION_RULE = (
    "order = max(n_gap, n_energy); n_gap = largest drop of log10(sigma) (values below tol*sigma_1 "
    "count as tol*sigma_1), n_energy = least n keeping the energy share of sum(sigma^2)"
)


def numerical_rank(s: np.ndarray, tol: float) -> int:
    """Number of singular values ``s`` (descending) above tol·s_1."""
    return int(np.sum(s > tol * s[0])) if s.size and s[0] > 0 else 0


def select_order(singular_values: np.ndarray, tol: float, energy: float = ENERGY) -> dict:
    """n_G, n_gap, n_energy and the chosen order from Hankel singular values: n_G the numerical rank,
    n_gap the largest drop of log10 σ, n_energy the least n keeping ``energy`` of Σσ² (Schulz et al., LPV
    Ho-Kalman reduction; :mod:`lpvflow.identify.reduce`)."""
    s = np.asarray(singular_values, dtype=float)
    n_g = numerical_rank(s, tol)
    if n_g == 0:
        raise ModelError("every Hankel singular value is zero: the model has no input-to-output path")
    logs = np.log10(np.maximum(s, tol * s[0]))
    drops = logs[:-1] - logs[1:]
    n_gap = int(np.argmax(drops[:n_g])) + 1 if n_g < len(s) or n_g > 1 else 1
    share = np.cumsum(s[:n_g] ** 2) / np.sum(s[:n_g] ** 2)
    n_energy = int(np.searchsorted(share, energy - 1e-15)) + 1
    return {"rank": n_g, "gap": n_gap, "energy": min(n_energy, n_g), "energy_threshold": energy,
            "tol": tol, "order": max(n_gap, min(n_energy, n_g)), "rule": SELECTION_RULE}
