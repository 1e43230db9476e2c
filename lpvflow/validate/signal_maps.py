"""The memoryless and hysteretic signal maps of the diagnosis' extensions — dead zone, saturation,
backlash (play operator), a delay per column — and the simulation of a model with a Coulomb-friction
input: the functions an extended model applies to a user's data
(:mod:`lpvflow.validate.extended_model`) and the extensions fit (:mod:`lpvflow.validate.extensions_maps`);
a leaf module, so both can import it."""

from __future__ import annotations

import numba
import numpy as np

from lpvflow.lpvio import LPVIO


@numba.vectorize(["float64(float64, float64)"], cache=True)
def dead_zone(u: float, width: float) -> float:
    """Dead zone of half-width w: sign(u)·max(|u| − w, 0); a ufunc, so the compiled loop
    (:mod:`lpvflow.validate.loop_recursion`) calls the same map on one sample; NaN stays NaN."""
    if np.isnan(u):
        return u
    return np.sign(u) * max(abs(u) - width, 0.0)


@numba.vectorize(["float64(float64, float64)"], cache=True)
def saturation(u: float, limit: float) -> float:
    """Saturation at ±limit (a ufunc, as :func:`dead_zone`); NaN stays NaN."""
    if np.isnan(u):
        return u
    return min(max(u, -limit), limit)


def delayed(x: np.ndarray, delays: list[int]) -> np.ndarray:
    """Each column j of ``x`` (N, n) delayed by ``delays[j]`` samples, x_j(k − d_j); the first d_j
    samples repeat x_j(0) (the value present before the record), a negative d_j advances the column and
    repeats its last value."""
    x = np.array(x, dtype=float)
    out = x.copy()
    for j, d in enumerate(delays):
        if d > 0:
            out[:, j] = np.r_[np.full(d, x[0, j]), x[: len(x) - d, j]]
        elif d < 0:
            out[:, j] = np.r_[x[-d:, j], np.full(-d, x[-1, j])]
    return out


@numba.njit(cache=True)
def play(u: np.ndarray, width: float) -> np.ndarray:
    """Backlash (play operator) of total width w: x(k) = min(max(x(k−1), u(k) − w/2), u(k) + w/2),
    x(−1) = 0 — a dead band of ±w/2 with memory: the output moves only when the input pushes it."""
    out = np.empty_like(u)
    state = 0.0
    for k in range(u.shape[0]):
        state = min(max(state, u[k] - width / 2), u[k] + width / 2)
        out[k] = state
    return out


def friction_simulation(model: LPVIO, u: np.ndarray, p: np.ndarray, i: int, velocity: bool) -> np.ndarray:
    """Simulation of a friction extension (its last input the friction sign) from a zero past, the
    sign taken sample by sample from its own output i: sign y_i(k) (velocity output) or
    sign(y_i(k) − y_i(k−1)) (position output). Causal because the friction input enters with a
    delay ≥ 1: y(k) = −Σᵢ Aᵢ y(k−i) + Σⱼ Bⱼ v(k−j), coefficients at ψ(p(k−i)) (shifted form) or
    ψ(p(k)) (static form), v = [u, sign]."""
    psi = model.basis.eval(p, check_range=False)
    a_at = np.einsum("kl,ilrc->kirc", psi, model.A)
    b_at = np.einsum("kl,jlrc->kjrc", psi, model.B)
    return _friction_recursion(np.ascontiguousarray(a_at), np.ascontiguousarray(b_at),
                               np.ascontiguousarray(u, dtype=float), i, velocity,
                               model.form == "shifted")


@numba.njit(cache=True)
def _friction_recursion(a_at: np.ndarray, b_at: np.ndarray, u: np.ndarray, i: int, velocity: bool,
                        shifted: bool) -> np.ndarray:
    n, n_a, ny = a_at.shape[0], a_at.shape[1], a_at.shape[2]
    n_b, nu = b_at.shape[1], u.shape[1]
    y = np.zeros((n, ny))
    sign = np.zeros(n)
    for k in range(n):
        # the products by BLAS (`@`), the sums element by element: an array expression (y[k] -= …) would
        # compile numba's broadcast check with its formatted error message, ≈ 2.5 s of the first call
        for lag in range(1, n_a + 1):
            if k - lag >= 0:
                at = k - lag if shifted else k
                ay = a_at[at, lag - 1] @ y[k - lag]
                for r in range(ny):
                    y[k, r] -= ay[r]
        for lag in range(n_b):
            if k - lag >= 0:
                at = k - lag if shifted else k
                bu = b_at[at, lag, :, :nu] @ u[k - lag]
                for r in range(ny):
                    y[k, r] += bu[r] + b_at[at, lag, r, nu] * sign[k - lag]
        motion = y[k, i] if velocity else y[k, i] - (y[k - 1, i] if k > 0 else y[k, i])
        sign[k] = np.sign(motion)
    return y
