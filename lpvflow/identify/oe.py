"""LPV output-error identification by prediction error on the simulated output (thesis (4.11)–(4.14)).

Minimises V(θ) = Σ_k ‖y(k) − ŷ(k, θ)‖² over the A/B parameters, ŷ the noise-free simulation of
the model (shifted or static form, SISO or MIMO, zero initial past) with
scipy.optimize.least_squares. The Jacobian is analytic: differentiating the simulation
ŷ(k) = φ̃(k)ᵀθ where φ̃ is built from −ŷ lags and u lags (the OE predictor) gives

    ∂ŷ(k)/∂θ_m + Σ_i A_i(ψ) ∂ŷ(k−i)/∂θ_m = φ̃_m(k) e_r      (θ_m a parameter of output r),

i.e. the sensitivity is the model's own LPV filter A⁻¹(q, ψ) (same form) applied to the regressor
column φ̃_m — one compiled recursion over all the parameters of an output (:func:`_filtered_columns`).
Started from IV-OE (thesis Alg. 4.1), which is consistent, so the local search starts in the right
basin.

The search is Levenberg–Marquardt (:func:`levenberg_marquardt`) on the normal equations of the
column-scaled Jacobian: with N·ny residuals and a hundred parameters, forming JᵀJ costs a few
milliseconds where the SVD of J that ``scipy.optimize.least_squares``' trust-region step takes costs
30 times as much (2×2 maglev refit: most of the search's time).
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import ModelError
from lpvflow.identify.iv import Structure, identify_iv_oe, simulate_psi
from lpvflow.lpvio import LPVIO

#: Residual value used where a trial model's simulation diverges (steers the search back).
DIVERGED_RESIDUAL = 1e6


def _split(struct: Structure, x: np.ndarray) -> list[np.ndarray]:
    sizes = np.cumsum([len(c) for c in struct.columns])[:-1]
    return np.split(x, sizes)


def sensitivities(struct: Structure, io: LPVIO, y_sim: np.ndarray, u: np.ndarray,
                  psi: np.ndarray) -> np.ndarray:
    """∂ŷ/∂θ (N, ny, n_par) of the simulated output, parameters in :class:`Structure` order."""
    parts = [_filtered_columns(np.ascontiguousarray(struct.regressor(r, y_sim, u, psi), dtype=float), psi,
                               np.ascontiguousarray(io.A, dtype=float), struct.shifted, r)
             for r in range(struct.ny)]
    return np.concatenate(parts, axis=2)


@numba.njit(cache=True, fastmath=False)
def _filtered_columns(phi: np.ndarray, psi: np.ndarray, A: np.ndarray, shifted: bool, r: int) -> np.ndarray:
    """S (N, ny, m): S(k) = e_r φ(k) − Σ_i A_i(ψ(k−i) or ψ(k)) S(k−i) for every column of φ (N, m) at once,
    zero initial past — the LPV filter of :func:`lpvflow.simulate.io_recursion` (same form convention)
    with A_i(ψ) formed once per sample and lag for all the columns."""
    n, m = phi.shape
    na, n_psi, ny = A.shape[0], A.shape[1], A.shape[2]
    out = np.zeros((n, ny, m))
    a_k = np.zeros((ny, ny))
    for k in range(n):
        out[k, r, :] = phi[k, :]
        for i in range(1, na + 1):
            if k - i < 0:
                break
            t = k - i if shifted else k
            for o in range(ny):
                for c in range(ny):
                    acc = 0.0
                    for l in range(n_psi):
                        acc += psi[t, l] * A[i - 1, l, o, c]
                    a_k[o, c] = acc
            for o in range(ny):
                for c in range(ny):
                    a = a_k[o, c]
                    if a != 0.0:
                        for j in range(m):
                            out[k, o, j] -= a * out[k - i, c, j]
    return out


def levenberg_marquardt(residual: Callable[[np.ndarray], np.ndarray],
                        jacobian: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, max_nfev: int,
                        xtol: float, ftol: float = 1e-8, gtol: float = 1e-8) -> np.ndarray:
    """Minimise ½‖f(x)‖² by Levenberg–Marquardt with Nielsen's damping update (Madsen, Nielsen &
    Tingleff 2004, "Methods for non-linear least squares problems", Sec. 3.2, Alg. 3.16).

    In the variables scaled by the Jacobian's column norms D (non-decreasing over the iterations, as
    ``least_squares``' ``x_scale="jac"``), J_h = J D⁻¹, the step h solves (J_hᵀJ_h + μI) h = −J_hᵀf through
    the eigendecomposition J_hᵀJ_h = V diag(w) Vᵀ (one per Jacobian, every trial μ then costs a
    product); a step is taken when the cost drops, μ ← μ·max(1/3, 1 − (2ρ − 1)³) with ρ the actual over
    the predicted reduction, else μ ← μ·ν, ν ← 2ν. μ₀ = 10⁻³·max w. Stops after ``max_nfev`` evaluations
    of f, or when a step changes the cost by less than ``ftol``·cost, moves x by less than
    ``xtol``·(``xtol`` + ‖x‖), or ‖Jᵀf‖∞ < ``gtol`` (``least_squares``' tests).
    """
    x, f = np.array(x0, dtype=float), residual(x0)
    cost, nfev, scale, mu, nu = 0.5 * f @ f, 1, np.zeros(len(x0)), None, 2.0
    while nfev < max_nfev:
        J = jacobian(x)
        scale = np.maximum(scale, np.linalg.norm(J, axis=0))
        d = 1.0 / np.where(scale > 0, scale, 1.0)
        J_h = J * d
        g_h = J_h.T @ f
        if np.linalg.norm(g_h / d, np.inf) < gtol:
            break
        w, V = scipy.linalg.eigh(J_h.T @ J_h)
        w = np.maximum(w, 0.0)
        g_v = V.T @ g_h
        mu = 1e-3 * w[-1] if mu is None else mu
        while nfev < max_nfev:
            q = -g_v / (w + mu)
            step = d * (V @ q)
            f_new = residual(x + step)
            nfev += 1
            cost_new = 0.5 * f_new @ f_new
            predicted = -(g_v @ q + 0.5 * (w * q) @ q)
            if cost_new < cost:
                rho = (cost - cost_new) / predicted if predicted > 0 else 1.0
                mu, nu = mu * max(1 / 3, 1 - (2 * rho - 1) ** 3), 2.0
                converged = (cost - cost_new < ftol * cost
                             or np.linalg.norm(step) < xtol * (xtol + np.linalg.norm(x)))
                x, f, cost = x + step, f_new, cost_new
                break
            mu, nu = mu * nu, 2 * nu
        else:
            break
        if converged:
            break
    return x


def identify_oe(data: Dataset, na: int | np.ndarray, nb: int | np.ndarray, nk: int | np.ndarray,
                basis: Basis | str = "affine", form: str = "shifted", init: LPVIO | None = None,
                max_nfev: int = 50, xtol: float = 1e-10) -> LPVIO:
    """LPV-OE by prediction-error minimisation of the simulation error. SISO and MIMO.

    Args:
        init: starting model with the same structure (default: IV-OE on the same data).
        max_nfev, xtol: evaluations of the simulation error and step tolerance of the search
            (:func:`levenberg_marquardt`).

    Returns:
        The minimising :class:`LPVIO`; ``noise_cov`` is the simulation-error covariance.
    """
    struct = Structure.from_data(data, na, nb, nk, basis, form)
    psi = struct.basis.eval(data.p, check_range=False)
    start = struct.max_lag
    if init is None:
        init = identify_iv_oe(data, na, nb, nk, struct.basis, form)
    x0 = np.concatenate(struct.thetas(init))
    cache: dict = {}

    def simulate(x: np.ndarray) -> tuple[LPVIO, np.ndarray]:
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            io = struct.model(_split(struct, x))
            cache[key] = (io, simulate_psi(io, data.u, psi))
        return cache[key]

    def residual(x: np.ndarray) -> np.ndarray:
        res = (data.y - simulate(x)[1])[start:].ravel()
        return np.where(np.isfinite(res), np.clip(res, -DIVERGED_RESIDUAL, DIVERGED_RESIDUAL),
                        DIVERGED_RESIDUAL)

    def jacobian(x: np.ndarray) -> np.ndarray:
        io, y_sim = simulate(x)
        jac = -sensitivities(struct, io, y_sim, data.u, psi)[start:].reshape(-1, len(x))
        return np.where(np.isfinite(jac), jac, 0.0)

    io, y_sim = simulate(levenberg_marquardt(residual, jacobian, x0, max_nfev, xtol))
    err = (data.y - y_sim)[start:]
    if not np.isfinite(err).all():
        raise ModelError("output-error search ended on a model whose simulation diverges; "
                         "lower the orders or give a stable init")
    io.noise_cov = err.T @ err / len(err)
    return io
