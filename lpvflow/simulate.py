"""Compiled time loops for LPV simulation (numba).

Only the recursions live here; everything that can be vectorised over time (basis evaluation,
forced terms) is done by the callers in numpy.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False)
def io_recursion(forced: np.ndarray, psi: np.ndarray, A: np.ndarray, shifted: bool) -> np.ndarray:
    """Solve y(k) = f(k) − Σ_i A_i(ψ(k−i) or ψ(k)) y(k−i) for y, with zero initial past.

    Shifted (LPR) form, thesis §5.5 / Schulz eq. (1): the coefficient of y(k−i) is evaluated at
    ψ(p(k−i)); static (Bamieh–Giarré) form: at ψ(p(k)).

    Args:
        forced: (N, ny) the input/noise part f(k).
        psi: (N, n_psi) basis values.
        A: (na, n_psi, ny, ny) basis components of A_1 … A_na.
    """
    n, ny = forced.shape
    na, n_psi = A.shape[0], A.shape[1]
    y = np.zeros((n, ny))
    for k in range(n):
        for o in range(ny):
            acc = forced[k, o]
            for i in range(1, na + 1):
                if k - i < 0:
                    break
                t = k - i if shifted else k
                for l in range(n_psi):
                    w = psi[t, l]
                    if w == 0.0:
                        continue
                    for c in range(ny):
                        acc -= w * A[i - 1, l, o, c] * y[k - i, c]
            y[k, o] = acc
    return y


@numba.njit(cache=True, fastmath=False)
def ss_recursion(
    psi: np.ndarray, u: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray,
    x0: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """x(k+1) = Σ_l ψ_l(k) (A_l x(k) + B_l u(k)),  y(k) = Σ_l ψ_l(k) (C_l x(k) + D_l u(k)).

    Returns (y, x) with x of shape (N+1, nx) (the final state included).
    """
    n, nu = u.shape
    n_psi, nx = A.shape[0], A.shape[1]
    ny = C.shape[1]
    x = np.zeros((n + 1, nx))
    y = np.zeros((n, ny))
    x[0] = x0
    # Which components are non-zero: skipping structural zeros roughly halves the work for
    # observable-form models whose C and D are parameter independent.
    c_used = np.zeros(n_psi, dtype=np.bool_)
    d_used = np.zeros(n_psi, dtype=np.bool_)
    for l in range(n_psi):
        c_used[l] = np.any(C[l] != 0.0)
        d_used[l] = np.any(D[l] != 0.0)
    for k in range(n):
        for o in range(ny):
            acc = 0.0
            for l in range(n_psi):
                w = psi[k, l]
                if c_used[l]:
                    for s in range(nx):
                        acc += w * C[l, o, s] * x[k, s]
                if d_used[l]:
                    for j in range(nu):
                        acc += w * D[l, o, j] * u[k, j]
            y[k, o] = acc
        for r in range(nx):
            acc = 0.0
            for l in range(n_psi):
                w = psi[k, l]
                for s in range(nx):
                    acc += w * A[l, r, s] * x[k, s]
                for j in range(nu):
                    acc += w * B[l, r, j] * u[k, j]
            x[k + 1, r] = acc
    return y, x
