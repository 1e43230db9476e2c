"""Kernelized LPV-LFR identification: kernel CCA state estimation, then the LFR matrices.

Mejari, Piga, Tóth and Bemporad, "Kernelized Identification of Linear Parameter-Varying Models with
Linear Fractional Representation", with the two corrections stated below.

Stage 1 (§IV-A, eqs. (12)–(19)). For each k with a full past and future window of length d,
z̄_p(k) = [u(k−d … k−1); y(k−d … k−1)], z̄_f(k) = [u(k … k+d−1); y(k … k+d−1)], and the scheduling
windows p̄_p(k), p̄_f(k). The kernels are (17), with φᵀ(p̄_l)φ(p̄_m) = k̄(p̄_l, p̄_m) I:

    K_pp = [c exp(−‖p̄_p(l) − p̄_p(m)‖² / σ²)]_{lm} ∘ Z_p Z_pᵀ,   K_ff likewise,

and the regularised KCCA is the generalized eigenproblem (16)

    [0 K_pp; K_ff 0] [η; κ] = λ blkdiag(γ_f K_ff + I, γ_p K_pp + I) [η; κ].

The paper's eq. (20) (right singular vectors of R⁻¹L) cannot be used literally: R⁻¹L is block
anti-diagonal, so each singular vector has η or κ identically zero. We solve
(16) itself, in the equivalent symmetric-definite form obtained with K_ff = F Fᵀ, K_pp = G Gᵀ
(symmetric eigendecompositions) and v = Fᵀη, w = Gᵀκ:

    [0 FᵀG; GᵀF 0] [v; w] = λ blkdiag(γ_f FᵀF + I, γ_p GᵀG + I) [v; w]      (scipy.linalg.eigh)

whose eigenvalues are those of (16). The state is the average of the future and past canonical
scores, x̂_j = (F v_j + G w_j)/2 = (K_ff η_j + K_pp κ_j)/2 (eqs. (18)–(19) on the training points),
scaled to unit RMS per component (the state basis is arbitrary).

Stage 2, general LFR (§IV-B, eq. (21), Algorithm 1): coordinate descent on

    J = Σ‖x̂(k+1) − A x̂ − B1 Δ z − B2 u‖²_Qx + Σ‖z − C1 x̂ − D11 Δ z − D12 u‖²_Qz
        + Σ‖y − C2 x̂ − D21 Δ z − D22 u‖²_Qy,

alternating linear least squares for Θ given Z and for each z(k) given Θ. J has no minimiser
(z → s z with B1, D21 → B1/s, D21/s lowers it without bound as s → 0), so
Z is normalised to unit RMS per channel after every Z step.

Stage 2, affine case D11 = 0 (eqs. (22)–(25)) with Δ(p) = diag(p_1, …, p_np): one least squares

    [x̂(k+1); y(k)] = Θ1 [x̂; u] + Σ_i p_i(k) Θ2,i [x̂; u],    Θ2,i = [B1 e_i; D21 e_i][C1,i D12,i],

followed by a rank-1 SVD truncation of each Θ2,i (the paper's (25), truncated to rank n_Δ).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.fit_check import UselessFitWarning, useless_fit_message
from lpvflow.lfr import LPVLFR
from lpvflow.validate.metrics import fit_report

#: Kernel eigenvalues below this fraction of the largest are treated as zero.
KERNEL_RANK_TOL = 1e-12
#: Largest number of KCCA windows: the kernels are dense M×M matrices and Stage 1 costs O(M³).
MAX_WINDOWS = 8000


@dataclass(frozen=True)
class KCCAStates:
    """Stage-1 result: states x̂(k) for k = first … first + len(x) − 1, and the eigenvalues λ_j of (16)."""

    first: int
    x: np.ndarray
    eigenvalues: np.ndarray


def _windows(signal: np.ndarray, starts: np.ndarray, d: int) -> np.ndarray:
    """Rows [s(k), …, s(k+d−1)] (channels of one sample kept together) for every start k."""
    idx = starts[:, None] + np.arange(d)[None, :]
    return signal[idx].reshape(len(starts), -1)


def _kernel(z: np.ndarray, pw: np.ndarray, c: float, sigma: float) -> np.ndarray:
    """c exp(−‖p̄_l − p̄_m‖²/σ²) · z̄_lᵀ z̄_m, eq. (17)."""
    sq = np.sum(pw**2, axis=1)
    dist2 = np.maximum(sq[:, None] + sq[None, :] - 2 * pw @ pw.T, 0.0)
    return c * np.exp(-dist2 / sigma**2) * (z @ z.T)


def _psd_factor(K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F with K ≈ F Fᵀ and the diagonal of FᵀF, keeping the eigendirections of K above KERNEL_RANK_TOL.

    A direction with zero kernel eigenvalue has a zero row in FᵀG and only adds λ = 0 to (16).
    """
    e, V = scipy.linalg.eigh((K + K.T) / 2)
    keep = e > KERNEL_RANK_TOL * e[-1]
    return V[:, keep] * np.sqrt(e[keep]), e[keep]


def kcca_states(data: Dataset, order: int, horizon: int = 3, c: float = 2.0, sigma: float = 10.5,
                gamma_p: float = 500.0, gamma_f: float = 500.0) -> KCCAStates:
    """Stage 1: KCCA state sequence of dimension ``order`` from past/future windows of length ``horizon``.

    Defaults are the paper's Example 1 values (c = 2, σ = 10.5, γ_p = γ_f = 500, d = 3).
    """
    d = horizon
    if d < 1 or order < 1:
        raise DataError(f"horizon and order must be >= 1, got horizon={horizon}, order={order}")
    if min(c, sigma, gamma_p, gamma_f) <= 0:
        raise DataError("kernel scale c, width sigma and regularisation gamma_p, gamma_f must be > 0")
    n_win = data.N - 2 * d + 1
    data.require_samples(2 * d + 2 * order, f"KCCA windows of length {d} and state order {order}")
    if n_win > MAX_WINDOWS:
        raise DataError(f"KCCA builds dense {n_win}x{n_win} kernels; use at most {MAX_WINDOWS + 2 * d - 1} "
                        "samples (Dataset.select or Dataset.decimate)")
    k = np.arange(d, d + n_win)
    z_p = np.hstack([_windows(data.u, k - d, d), _windows(data.y, k - d, d)])
    z_f = np.hstack([_windows(data.u, k, d), _windows(data.y, k, d)])
    F, ef = _psd_factor(_kernel(z_f, _windows(data.p, k, d), c, sigma))
    G, eg = _psd_factor(_kernel(z_p, _windows(data.p, k - d, d), c, sigma))
    nf, n_all = F.shape[1], F.shape[1] + G.shape[1]
    if order > min(nf, G.shape[1]):
        raise DataError(f"state order {order} exceeds the rank of the KCCA kernels; lower the order")
    lhs = np.zeros((n_all, n_all))
    lhs[:nf, nf:] = F.T @ G
    lhs[nf:, :nf] = lhs[:nf, nf:].T
    rhs = np.concatenate([gamma_f * ef + 1.0, gamma_p * eg + 1.0])
    lam, vec = scipy.linalg.eigh(lhs, np.diag(rhs), subset_by_index=[n_all - order, n_all - 1])
    lam, vec = lam[::-1], vec[:, ::-1]
    x = (F @ vec[:nf] + G @ vec[nf:]) / 2
    rms = np.sqrt(np.mean(x**2, axis=0))
    if np.any(rms <= 1e-300):
        raise DataError("KCCA found no correlation between past and future windows: excite the system")
    return KCCAStates(first=d, x=x / rms, eigenvalues=lam)


# ============================================================================= Stage 2
def _delta_diag(p: np.ndarray) -> np.ndarray:
    """Δ(p(k)) = diag(p(k)) for every sample: (N, n_p, n_p)."""
    out = np.zeros((len(p), p.shape[1], p.shape[1]))
    idx = np.arange(p.shape[1])
    out[:, idx, idx] = p
    return out


def _lstsq(regressor: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Θ minimising ‖target − regressor Θᵀ‖_F (rows are samples)."""
    return scipy.linalg.lstsq(regressor, target)[0].T


@dataclass
class _Theta:
    A: np.ndarray
    B1: np.ndarray
    B2: np.ndarray
    C1: np.ndarray
    D11: np.ndarray
    D12: np.ndarray
    C2: np.ndarray
    D21: np.ndarray
    D22: np.ndarray


def fit_affine_lfr(x: np.ndarray, u: np.ndarray, y: np.ndarray, p: np.ndarray) -> _Theta:
    """D11 = 0, Δ = diag(p): least squares (24) then a rank-1 SVD of each Θ2,i (25).

    x has one more row than u, y, p (x̂(k+1) of the last sample).
    """
    nx, nu, n_p = x.shape[1], u.shape[1], p.shape[1]
    xu = np.hstack([x[:-1], u])
    reg = np.hstack([xu] + [p[:, [i]] * xu for i in range(n_p)])
    theta = _lstsq(reg, np.hstack([x[1:], y]))
    m = nx + nu
    B1, D21 = np.zeros((nx, n_p)), np.zeros((y.shape[1], n_p))
    C1, D12 = np.zeros((n_p, nx)), np.zeros((n_p, nu))
    for i in range(n_p):
        U, s, Vt = np.linalg.svd(theta[:, m * (i + 1) : m * (i + 2)])
        left, right = U[:, 0] * np.sqrt(s[0]), Vt[0] * np.sqrt(s[0])
        B1[:, i], D21[:, i], C1[i], D12[i] = left[:nx], left[nx:], right[:nx], right[nx:]
    return _Theta(theta[:nx, :nx], B1, theta[:nx, nx:m], C1, np.zeros((n_p, n_p)), D12,
                  theta[nx:, :nx], D21, theta[nx:, nx:m])


def _theta_step(x: np.ndarray, u: np.ndarray, y: np.ndarray, w: np.ndarray, z: np.ndarray) -> _Theta:
    """Step 1.1: three linear least-squares problems with regressor φ(k) = [x̂(k); Δ z(k); u(k)]."""
    nx, nd = x.shape[1], z.shape[1]
    phi = np.hstack([x[:-1], w, u])
    st, lat, out = _lstsq(phi, x[1:]), _lstsq(phi, z), _lstsq(phi, y)
    return _Theta(st[:, :nx], st[:, nx:nx + nd], st[:, nx + nd:], lat[:, :nx], lat[:, nx:nx + nd],
                  lat[:, nx + nd:], out[:, :nx], out[:, nx:nx + nd], out[:, nx + nd:])


def _z_step(th: _Theta, x: np.ndarray, u: np.ndarray, y: np.ndarray, dl: np.ndarray,
            weights: tuple[float, float, float]) -> np.ndarray:
    """Step 1.2 of Algorithm 1 (§IV-B): z(k) = (G_kᵀ W G_k)⁻¹ G_kᵀ W b_k per sample."""
    qx, qz, qy = weights
    nd = th.D11.shape[0]
    G = np.concatenate([np.sqrt(qx) * th.B1 @ dl, np.sqrt(qz) * (np.eye(nd) - th.D11 @ dl),
                        np.sqrt(qy) * th.D21 @ dl], axis=1)
    b = np.hstack([np.sqrt(qx) * (x[1:] - x[:-1] @ th.A.T - u @ th.B2.T),
                   np.sqrt(qz) * (x[:-1] @ th.C1.T + u @ th.D12.T),
                   np.sqrt(qy) * (y - x[:-1] @ th.C2.T - u @ th.D22.T)])
    gtg = np.einsum("tri,trj->tij", G, G)
    gtb = np.einsum("tri,tr->ti", G, b)
    return np.linalg.solve(gtg, gtb[..., None])[..., 0]


def fit_lfr_coordinate_descent(
    x: np.ndarray, u: np.ndarray, y: np.ndarray, p: np.ndarray, z0: np.ndarray,
    weights: tuple[float, float, float] = (100.0, 10.0, 10.0), iterations: int = 250, tol: float = 1e-6,
) -> tuple[_Theta, int]:
    """Algorithm 1 with the latent scale normalised after each Z step; returns (Θ, iterations used)."""
    dl = _delta_diag(p)
    z = z0 / np.sqrt(np.mean(z0**2, axis=0))
    sweeps, change = 0, np.inf
    while sweeps < iterations and change > tol:
        th = _theta_step(x, u, y, np.einsum("tij,tj->ti", dl, z), z)
        z_new = _z_step(th, x, u, y, dl, weights)
        z_new /= np.sqrt(np.mean(z_new**2, axis=0))
        change = np.linalg.norm(z_new - z) / np.sqrt(len(z))
        z, sweeps = z_new, sweeps + 1
    return _theta_step(x, u, y, np.einsum("tij,tj->ti", dl, z), z), sweeps


def identify_kcca_lfr(
    data: Dataset, order: int = 2, *, affine: bool = False, horizon: int = 3, c: float = 2.0,
    sigma: float = 10.5, gamma_p: float = 500.0, gamma_f: float = 500.0,
    weights: tuple[float, float, float] = (100.0, 10.0, 10.0), iterations: int = 250, tol: float = 1e-6,
    init: str = "affine", seed: int = 0,
) -> LPVLFR:
    """LPV-LFR with Δ(p) = diag(p_1, …, p_np) from one dataset (Mejari et al., Stages 1 and 2).

    Args:
        data: estimation data; every scheduling signal enters Δ once.
        order: state dimension n̂_x (the number of KCCA components kept).
        affine: fit D11 = 0 by least squares + SVD (Example 2) instead of coordinate descent.
        horizon, c, sigma, gamma_p, gamma_f: KCCA window length d and kernel/regularisation constants.
        weights: (Q_x, Q_z, Q_y) of cost (21) (scalars times identity).
        iterations, tol: at most this many coordinate-descent sweeps; stop when the RMS change of
            the normalised Z is below tol.
        init: ``"affine"`` starts Z from z = C1 x̂ + D12 u of the affine fit; ``"random"`` draws Z⁰
            uniformly in [−1, 1] (the paper) with ``seed``.

    Returns:
        An :class:`LPVLFR` on the affine basis of p with the data's range, checked well posed there;
        a :class:`~lpvflow.identify.fit_check.UselessFitWarning` when its simulation on ``data`` explains
        none of an output.
    """
    if init not in ("affine", "random"):
        raise DataError(f"init must be 'affine' or 'random', got {init!r}")
    states = kcca_states(data, order, horizon, c, sigma, gamma_p, gamma_f)
    rows = slice(states.first, states.first + len(states.x) - 1)
    x, u, y, p = states.x, data.u[rows], data.y[rows], data.p[rows]
    th = fit_affine_lfr(x, u, y, p)
    if not affine:
        if init == "affine":
            z0 = x[:-1] @ th.C1.T + u @ th.D12.T
        else:
            z0 = np.random.default_rng(seed).uniform(-1, 1, size=(len(u), p.shape[1]))
        th, _ = fit_lfr_coordinate_descent(x, u, y, p, z0, weights, iterations, tol)
    n_p = data.p.shape[1]
    delta = np.zeros((n_p + 1, n_p, n_p))
    delta[1 + np.arange(n_p), np.arange(n_p), np.arange(n_p)] = 1.0
    model = LPVLFR(th.A, th.B1, th.B2, th.C1, th.D11, th.D12, th.C2, th.D21, th.D22, delta,
                   Basis.affine(n_p).with_range(data.p), data.Ts, u_names=data.u_names,
                   y_names=data.y_names, p_names=data.p_names)
    model.check_well_posed()
    with np.errstate(over="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        fit = fit_report(data.y, model.simulate(data.u, data.p), data.y_names)
    message = useless_fit_message(fit, "kcca-lfr")
    if message:
        warnings.warn(UselessFitWarning(message), stacklevel=2)
    return model
