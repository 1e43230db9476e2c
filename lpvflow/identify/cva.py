"""LPV canonical variate analysis on the corrected future (Larimore, Cox, Tóth, Algorithm 1).

Notation of Larimore, Cox and Tóth, "CVA Identification of Nonlinear Systems with LPV State-Space
Models of Affine Dependence": ρ_t = ψ(p_t) (ψ_0 = 1), ρ⊗x = [ρ_1 x; …; ρ_s x].

1. LPV-ARX in shifted form, eq. (5) with the "+" sign convention of (13):

       y_t = Σ_{i=1}^{ℓ} a_i (ρ_{t−i}⊗y_{t−i}) + Σ_{i=0|1}^{ℓ} b_i (ρ_{t−i}⊗u_{t−i}) + e_t,

   fitted for ℓ = 1 … ℓ_max on the common sample t = ℓ_max … N−1 by one QR of the regressor
   ordered by lag (the order-recursive residuals of §III-A), ℓ chosen by
   AIC(ℓ) = N_e log det Σ̂_ee(ℓ) + 2 n_y m(ℓ), m(ℓ) regressors per output. The b_0 term is left out
   unless ``feedthrough``; when the scheduling contains an output (quasi-LPV) only its ρ_1 = 1 part
   is kept, since ρ_t⊗u_t would contain y_t (the paper does not discuss this case).
2. Corrected future, eqs. (13)–(14): ỹ_{t+j} = Σ_{i=1}^{j} a_i(ρ_{t+j−i}⊗ỹ_{t+j−i})
   + Σ_{i=0}^{j} b_i(ρ_{t+j−i}⊗u_{t+j−i}) from zero initial conditions, ȳ = y − ỹ, j = 0 … ℓ.
3. CVA (§III-D, Theorem 1) between the augmented past p_t = [ρ_{t−1}⊗y_{t−1}; …; ρ_{t−ℓ}⊗y_{t−ℓ};
   ρ_{t−1}⊗u_{t−1}; …] and the augmented corrected future f_t = [ρ_{t+ℓ}⊗ȳ_{t+ℓ}; …; ρ_t⊗ȳ_t] on raw
   second moments: Σ_pp^{-1/2} Σ_pf Σ_ff^{-1/2} = U R Vᵀ, J = Uᵀ Σ_pp^{-1/2}, x̂_t = J_{1:k} p_t (17);
   r_i² are the squared canonical correlations.
4. State-space matrices by least squares (18) read as a regression:
   x̂_{t+1} = A(ρ_t⊗x̂_t) + B(ρ_t⊗u_t) + w_t and y_t = C(ρ_t⊗x̂_t) [+ D(ρ_t⊗u_t)] + v_t. In the
   quasi-LPV case C (and D) are constant: ρ_t⊗x̂_t in the output row would contain y_t itself.
   The innovation gain K = Σ_wv Σ_vv⁻¹ (constant) comes from the residuals.
5. State order by AIC(k) = N_e log det Σ̂_vv(k) + 2 M_k with M_k = k·(number of state-equation
   regressors) + n_y·(number of output-equation regressors) − k² (similarity) + n_y(n_y+1)/2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.models import LPVSS

#: Relative eigenvalue floor when inverting the past/future covariances.
COV_FLOOR = 1e-12


def kron_rows(rho: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Row-wise ρ_t ⊗ s_t: (N, n_ρ) and (N, n) → (N, n_ρ n)."""
    return np.einsum("tl,ti->tli", rho, s).reshape(len(s), -1)


@dataclass(frozen=True)
class ArxFit:
    """Shifted-form LPV-ARX: a[i] (n_y, s n_y) for lag i+1, b[i] (n_y, s n_u) for lag i (b[0] may be 0)."""

    a: np.ndarray
    b: np.ndarray
    order: int
    aic: np.ndarray
    noise_cov: np.ndarray


@dataclass(frozen=True)
class CVAFit:
    """Everything CVA computed: the model plus what a reader needs to check it.

    ``state_map`` is J_{1:k}; ``past(data)`` builds the matching past vectors, so
    x̂_t = state_map @ past_t is the state estimate from measured data (eq. (17)).
    """

    model: LPVSS
    arx: ArxFit
    canonical_correlations: np.ndarray
    state_aic: np.ndarray
    state_map: np.ndarray
    output_scheduling: dict[int, int]
    feedthrough: bool

    @property
    def squared_correlations(self) -> np.ndarray:
        return self.canonical_correlations**2

    def past(self, data: Dataset) -> np.ndarray:
        """Augmented past p_t (rows t = ℓ … N, the last one for the sample after the data)."""
        rho = self.model.basis.eval(data.p, check_range=False)
        return _past_rows(kron_rows(rho, data.y), kron_rows(rho, data.u), self.arx.order)


def _detect_output_scheduling(data: Dataset) -> dict[int, int]:
    """{scheduling column: output column} for scheduling signals that are a measured output."""
    found = {}
    for j in range(data.p.shape[1]):
        for i in range(data.y.shape[1]):
            if np.array_equal(data.p[:, j], data.y[:, i]):
                found[j] = i
    return found


def _past_rows(ry: np.ndarray, ru: np.ndarray, order: int) -> np.ndarray:
    """Rows [ρ⊗y at t−1 … t−ℓ, ρ⊗u at t−1 … t−ℓ] for t = ℓ … N."""
    n = len(ry)
    cols = [ry[order - i : n + 1 - i] for i in range(1, order + 1)]
    cols += [ru[order - i : n + 1 - i] for i in range(1, order + 1)]
    return np.hstack(cols)


def fit_arx(ry: np.ndarray, ru: np.ndarray, u0: np.ndarray | None, y: np.ndarray, max_order: int,
            order: int | None) -> ArxFit:
    """Step 1: all orders 1 … max_order on a common sample from one QR; AIC picks ℓ unless given.

    ``u0`` is the lag-0 input regressor (ρ_t⊗u_t, u_t or None: no b_0).
    """
    n, ny = len(y), y.shape[1]
    t = slice(max_order, n)
    blocks = [] if u0 is None else [u0[t]]
    for i in range(1, max_order + 1):
        blocks += [ry[max_order - i : n - i], ru[max_order - i : n - i]]
    phi = np.hstack(blocks)
    n_b0 = 0 if u0 is None else u0.shape[1]
    per_lag = ry.shape[1] + ru.shape[1]
    m = phi.shape[1]
    n_e = n - max_order
    if n_e <= m + 1:
        raise DataError(f"{n} samples are too few for an LPV-ARX of order {max_order} with {m} regressors; "
                        "record longer data or lower max_arx_order")
    R = scipy.linalg.qr(np.hstack([phi, y[t]]), mode="r")[0][: m + ny]
    Rpp, Z, T = R[:m, :m], R[:m, m:], R[m:, m:]
    if np.min(np.abs(np.diag(Rpp))) <= 1e-11 * np.max(np.abs(np.diag(Rpp))):
        raise DataError("the LPV-ARX regressor is rank deficient: excite the input more or lower "
                        "max_arx_order")
    aic = np.full(max_order, np.inf)
    for ell in range(1, max_order + 1):
        used = n_b0 + ell * per_lag
        rest = Z[used:]
        cov = (rest.T @ rest + T.T @ T) / n_e
        aic[ell - 1] = n_e * np.linalg.slogdet(cov)[1] + 2 * ny * used
    ell = int(np.argmin(aic)) + 1 if order is None else order
    if not 1 <= ell <= max_order:
        raise DataError(f"arx_order must be between 1 and max_arx_order={max_order}, got {ell}")
    used = n_b0 + ell * per_lag
    theta = scipy.linalg.solve_triangular(Rpp[:used, :used], Z[:used]).T  # (ny, used)
    rest = Z[used:]
    noise_cov = (rest.T @ rest + T.T @ T) / n_e
    nry, s_nu = ry.shape[1], ru.shape[1]
    b = np.zeros((ell + 1, ny, s_nu))
    if u0 is not None:  # pad the lag-0 block (u_t only in the quasi-LPV case) to the ρ⊗u layout
        b[0, :, : n_b0] = theta[:, :n_b0]
    lagged = theta[:, n_b0:].reshape(ny, ell, per_lag)
    a = np.ascontiguousarray(lagged[:, :, :nry].transpose(1, 0, 2))
    b[1:] = lagged[:, :, nry:].transpose(1, 0, 2)
    return ArxFit(a, b, ell, aic, noise_cov)


def corrected_future(arx: ArxFit, rho: np.ndarray, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Augmented corrected future rows f_t = [ρ⊗ȳ at t+ℓ; …; at t] for t = ℓ … N−1−ℓ (eqs. (13)–(14))."""
    ell, n = arx.order, len(y)
    starts = np.arange(ell, n - ell)
    ru = kron_rows(rho, u)
    y_tilde = []
    for j in range(ell + 1):
        acc = ru[starts + j] @ arx.b[0].T
        for i in range(1, j + 1):
            acc += kron_rows(rho[starts + j - i], y_tilde[j - i]) @ arx.a[i - 1].T
            acc += ru[starts + j - i] @ arx.b[i].T
        y_tilde.append(acc)
    blocks = [kron_rows(rho[starts + j], y[starts + j] - y_tilde[j]) for j in range(ell, -1, -1)]
    return np.hstack(blocks)


def _inv_sqrt(cov: np.ndarray) -> np.ndarray:
    e, V = scipy.linalg.eigh(cov)
    e = np.maximum(e, COV_FLOOR * e[-1])
    return (V / np.sqrt(e)) @ V.T


def canonical_variates(past: np.ndarray, future: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CVA on raw second moments: (J with rows the past canonical directions, correlations r_i)."""
    n = len(past)
    wp, wf = _inv_sqrt(past.T @ past / n), _inv_sqrt(future.T @ future / n)
    U, r, _ = np.linalg.svd(wp @ (past.T @ future / n) @ wf, full_matrices=False)
    return U.T @ wp, np.minimum(r, 1.0)


def _state_space_ls(x: np.ndarray, rho: np.ndarray, u: np.ndarray, y: np.ndarray, constant_output: bool,
                    feedthrough: bool) -> tuple[np.ndarray, ...]:
    """Eq. (18) as least squares; returns ([A B], [C D], state residual, output residual, #params)."""
    x0, x1 = x[:-1], x[1:]
    state_reg = np.hstack([kron_rows(rho, x0), kron_rows(rho, u)])
    out_rho = rho[:, :1] if constant_output else rho
    out_reg = [kron_rows(out_rho, x0)] + ([kron_rows(out_rho, u)] if feedthrough else [])
    out_reg = np.hstack(out_reg)
    ab = scipy.linalg.lstsq(state_reg, x1)[0].T
    cd = scipy.linalg.lstsq(out_reg, y)[0].T
    w, v = x1 - state_reg @ ab.T, y - out_reg @ cd.T
    k, ny = x.shape[1], y.shape[1]
    n_par = k * state_reg.shape[1] + ny * out_reg.shape[1] - k * k + ny * (ny + 1) // 2
    return ab, cd, w, v, n_par


def identify_cva(data: Dataset, basis: Basis | str = "affine", *, arx_order: int | None = None,
                 max_arx_order: int = 40, state_order: int | None = None, max_state_order: int = 10,
                 feedthrough: bool = False) -> LPVSS:
    """LPV-SS (affine in ψ) by CVA on the corrected future; see :func:`cva_fit` for the details."""
    return cva_fit(data, basis, arx_order=arx_order, max_arx_order=max_arx_order, state_order=state_order,
                   max_state_order=max_state_order, feedthrough=feedthrough).model


def cva_fit(data: Dataset, basis: Basis | str = "affine", *, arx_order: int | None = None,
            max_arx_order: int = 40, state_order: int | None = None, max_state_order: int = 10,
            feedthrough: bool = False) -> CVAFit:
    """Algorithm 1 of Larimore, Cox and Tóth (steps in the module docstring).

    Args:
        data: estimation data. A scheduling column identical to an output column is detected as
            quasi-LPV scheduling (ρ depends on y_t): C and D are then constant.
        basis: scheduling basis ψ giving ρ_t = ψ(p_t) (``affine``: ρ = [1, p]).
        arx_order, max_arx_order: fix ℓ, or choose it by AIC among 1 … max_arx_order.
        state_order, max_state_order: fix k, or choose it by AIC among 1 … max_state_order.
        feedthrough: estimate D (b_0 in the ARX); off by default (strictly proper plant).
    """
    basis = Basis.from_spec(basis, data.p.shape[1]) if isinstance(basis, str) else basis
    if basis.n_p != data.p.shape[1]:
        raise DataError(f"the basis is for {basis.n_p} scheduling signal(s), the data has {data.p.shape[1]}")
    if max_arx_order < 1 or max_state_order < 1:
        raise DataError("max_arx_order and max_state_order must be >= 1")
    basis = basis.with_range(data.p)
    scheduled_by_output = _detect_output_scheduling(data)
    quasi = bool(scheduled_by_output)
    rho = basis.eval(data.p)
    ry, ru = kron_rows(rho, data.y), kron_rows(rho, data.u)
    u0 = (data.u if quasi else ru) if feedthrough else None
    arx = fit_arx(ry, ru, u0, data.y, max_arx_order, arx_order)
    ell = arx.order
    data.require_samples(4 * ell + 2, f"CVA with past/future horizon {ell}")
    past_all = _past_rows(ry, ru, ell)  # t = ℓ … N
    future = corrected_future(arx, rho, data.y, data.u)  # t = ℓ … N−1−ℓ
    J, r = canonical_variates(past_all[: len(future)], future)
    if state_order is not None and not 1 <= state_order <= len(r):
        raise DataError(f"state_order must be between 1 and {len(r)}, got {state_order}")
    candidates = [state_order] if state_order is not None else range(1, min(max_state_order, len(r)) + 1)
    x_all = past_all[: data.N - ell] @ J[: max(candidates)].T  # x̂_t for t = ℓ … N−1
    t = slice(ell, data.N - 1)
    n_e = data.N - ell - 1
    aic = np.full(max(candidates), np.inf)
    fits = {}
    for k in candidates:
        fits[k] = _state_space_ls(x_all[:, :k], rho[t], data.u[t], data.y[t], quasi, feedthrough)
        v, n_par = fits[k][3], fits[k][4]
        aic[k - 1] = n_e * np.linalg.slogdet(v.T @ v / n_e)[1] + 2 * n_par
    k = int(np.argmin(aic)) + 1
    ab, cd, w, v, _ = fits[k]
    model = _to_lpvss(ab, cd, w, v, k, basis, data, quasi, feedthrough)
    return CVAFit(model, arx, r, aic, J[:k], scheduled_by_output, feedthrough)


def _to_lpvss(ab: np.ndarray, cd: np.ndarray, w: np.ndarray, v: np.ndarray, k: int, basis: Basis,
              data: Dataset, quasi: bool, feedthrough: bool) -> LPVSS:
    """Split the row collections [A_1 … A_s] etc. into LPVSS basis stacks; K = Σ_wv Σ_vv⁻¹ in ψ_0."""
    s, nu, ny = basis.n_psi, data.u.shape[1], data.y.shape[1]
    A = ab[:, : s * k].reshape(k, s, k).transpose(1, 0, 2)
    B = ab[:, s * k :].reshape(k, s, nu).transpose(1, 0, 2)
    s_out = 1 if quasi else s
    C, D = np.zeros((s, ny, k)), np.zeros((s, ny, nu))
    C[:s_out] = cd[:, : s_out * k].reshape(ny, s_out, k).transpose(1, 0, 2)
    if feedthrough:
        D[:s_out] = cd[:, s_out * k :].reshape(ny, s_out, nu).transpose(1, 0, 2)
    K = np.zeros((s, k, ny))
    K[0] = scipy.linalg.lstsq(v, w)[0].T
    return LPVSS(A, B, C, D, basis, data.Ts, K=K, u_names=data.u_names, y_names=data.y_names,
                 p_names=data.p_names)


def predict_ahead(fit: CVAFit, data: Dataset, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """``horizon``-step-ahead predictions ŷ(t+h−1 | y up to t−1, u up to t+h−1).

    x̂_t = J p_t from the measured past, then the model is run h−1 steps without measurements;
    output-scheduled signals inside the horizon use the predicted output (a true predictor).
    Returns (sample indices t+h−1, predictions).
    """
    if horizon < 1:
        raise DataError(f"prediction horizon must be >= 1, got {horizon}")
    model, ell = fit.model, fit.arx.order
    starts = np.arange(ell, data.N - horizon + 1)
    x = fit.past(data)[: len(starts)] @ fit.state_map.T
    for h in range(horizon):
        tt = starts + h
        p = data.p[tt].copy()
        if fit.output_scheduling:  # constant C, D: the output needs no scheduling
            y_hat = x @ model.C[0].T + data.u[tt] @ model.D[0].T
            for pj, yi in fit.output_scheduling.items():
                p[:, pj] = y_hat[:, yi]
        psi = model.basis.eval(p, check_range=False)
        if not fit.output_scheduling:
            y_hat = (np.einsum("tl,lok,tk->to", psi, model.C, x)
                     + np.einsum("tl,loj,tj->to", psi, model.D, data.u[tt]))
        if h == horizon - 1:
            return tt, y_hat
        x = np.einsum("tl,lrk,tk->tr", psi, model.A, x) + np.einsum("tl,lrj,tj->tr", psi, model.B, data.u[tt])
    raise AssertionError("unreachable")
