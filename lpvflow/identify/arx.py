"""LPV-ARX identification by least squares: shifted (LPR) form and static (Bamieh–Giarré) form.

Shifted form (thesis (5.35)/(5.37); Schulz et al. §2.2): equation r is

    y_r(k) = Σ_c Σ_{i=1}^{na[r,c]} −y_c(k−i) ψ(p(k−i))ᵀ a_{r,c,i}
             + Σ_j Σ_{lag=nk[r,j]}^{nk[r,j]+nb[r,j]−1} u_j(k−lag) ψ(p(k−lag))ᵀ b_{r,j,lag} + e_r(k),

each lagged signal multiplied by the basis evaluated *at that signal's own sample*. The static
form (thesis (3.5), (4.5)) multiplies every lagged signal by ψ(p(k)) instead. With nk = 0 the
lag-0 input coefficient is kept constant in the shifted form (Schulz et al. (3b), b_0^{(1)}),
so that the realization stays affine in ψ.

Input lags follow MATLAB's ``arx`` convention: nb terms u(k−nk), …, u(k−nk−nb+1) (thesis
Example 3.1). The least-squares problem min ‖Y − Φθ‖² (thesis (3.6)–(3.9)) is solved by a
chunked Householder QR of [Φ | Y] (tall-skinny QR): the R factor of every block of rows is
stacked on the next block, so memory stays at one chunk of regressor rows whatever N is, and the
result equals the QR solution of the full problem. Optional ridge adds √λ·I rows.

Several records of the same plant (e.g. the experiments of successive identification-for-control
rounds) are one least-squares problem whose rows are each record's regressor rows: the lags never
reach across from one record into another (Ljung, *System Identification*, 2nd ed., §14.3, "merging
experiments").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.lpvio import LPVIO

#: Rows of regressor built at a time.
CHUNK_ROWS = 65536
#: Relative singular-value threshold below which the regressor counts as rank deficient.
RANK_TOL = 1e-11


@dataclass(frozen=True)
class RegressorColumn:
    """One column of the LPV-ARX regressor: signal(channel)(k − lag) · ψ_psi (at k, or at k − lag when
    shifted); shared by the ARX, IV, ARMAX and spline estimators."""

    signal: str  # "y" or "u"
    channel: int
    lag: int
    psi: int  # basis-function index


def order_matrix(name: str, value: int | np.ndarray, shape: tuple[int, int], minimum: int) -> np.ndarray:
    """An order given as N or as a matrix, as an integer matrix of ``shape`` with entries ≥ ``minimum``."""
    m = np.asarray(value)
    if m.ndim == 0:
        m = np.full(shape, int(m))
    if m.shape != shape or not np.all(m == np.round(m)):
        raise DataError(f"{name} must be a whole number or a {shape[0]}x{shape[1]} matrix of them")
    if np.any(m < minimum):
        raise DataError(f"{name} must be >= {minimum}, got {m.tolist()}")
    return m.astype(int)


def row_columns(r: int, na: np.ndarray, nb: np.ndarray, nk: np.ndarray, n_psi: int, shifted: bool
                 ) -> list[RegressorColumn]:
    """The regressor columns of output equation r: y lags 1..na, u lags nk..nk+nb−1, each times every
    basis function (the instantaneous input in the shifted form only times ψ_0 = 1)."""
    cols = [RegressorColumn("y", c, i, l) for c in range(na.shape[1]) for i in range(1, na[r, c] + 1)
            for l in range(n_psi)]
    for j in range(nb.shape[1]):
        for lag in range(nk[r, j], nk[r, j] + nb[r, j]):
            n_l = 1 if (lag == 0 and shifted) else n_psi
            cols += [RegressorColumn("u", j, lag, l) for l in range(n_l)]
    return cols


def fill_regressor(out: np.ndarray, cols: list[RegressorColumn], y: np.ndarray, u: np.ndarray,
                   psi: np.ndarray, k0: int, k1: int, w0: int, shifted: bool) -> None:
    """Write the regressor rows k0..k1-1 into ``out`` (rows, len(cols)); psi covers samples w0..k1-1."""
    for idx, col in enumerate(cols):
        sig = y[k0 - col.lag : k1 - col.lag, col.channel] if col.signal == "y" else \
            u[k0 - col.lag : k1 - col.lag, col.channel]
        if col.signal == "y":
            sig = -sig  # a fresh array: no in-place update of a possibly strided view of ``out``
        t0 = (k0 - col.lag if shifted else k0) - w0
        np.multiply(sig, psi[t0 : t0 + (k1 - k0), col.psi], out=out[:, idx])


def _tsqr(cols: list[RegressorColumn], outputs: list[int], records: Sequence[Dataset], basis: Basis,
          max_lag: int, shifted: bool, ridge: float) -> np.ndarray:
    """Upper-triangular R of [Φ | Y_outputs] (with √ridge·I on top), accumulated chunk by chunk over the
    rows k ≥ max_lag of every record."""
    n, m = len(cols), len(cols) + len(outputs)
    R = np.zeros((0, m))
    if ridge > 0:
        R = np.zeros((n, m))
        R[:, :n] = np.sqrt(ridge) * np.eye(n)
    buf = np.empty((CHUNK_ROWS + m, m), order="F")
    for data in records:
        for k0 in range(max_lag, data.N, CHUNK_ROWS):
            k1 = min(k0 + CHUNK_ROWS, data.N)
            rows = k1 - k0
            w0 = k0 - max_lag
            psi = basis.eval(data.p[w0:k1], check_range=False)
            top = len(R)
            buf[:top] = R
            block = buf[top : top + rows]
            fill_regressor(block[:, :n], cols, data.y, data.u, psi, k0, k1, w0, shifted)
            block[:, n:] = data.y[k0:k1, outputs]
            R = scipy.linalg.qr(buf[: top + rows], mode="r", overwrite_a=True, check_finite=False)[0][:m]
            R = np.triu(R)
    return R


def identify_arx(
    data: Dataset | Sequence[Dataset], na: int | np.ndarray, nb: int | np.ndarray, nk: int | np.ndarray,
    basis: Basis | str = "affine", form: str = "shifted", ridge: float = 0.0,
) -> LPVIO:
    """Least-squares LPV-ARX (LPR/shifted form by default) from one dataset or several records.

    Args:
        data: the estimation data, or several records with the same signals and Ts (one problem; the
            lags stay inside each record, module docstring).
        na: lags of y_c in equation r, a whole number or an (ny, ny) matrix.
        nb, nk: number of input lags and input delay, whole numbers or (ny, nu) matrices.
        basis: a :class:`Basis` or a spec string (``affine``, ``poly:2``, ``spline:0.2,0.5``).
        form: ``"shifted"`` (realizable with static dependence) or ``"static"`` (Bamieh–Giarré).
        ridge: Tikhonov weight λ ≥ 0 (minimises ‖Y − Φθ‖² + λ‖θ‖²).

    Returns:
        An :class:`LPVIO` with residual covariance and per-output parameter covariance
        σ_r² (RᵀR)⁻¹ (ridge-free case: the usual LS covariance).
    """
    if form not in ("shifted", "static"):
        raise DataError(f"form must be 'shifted' or 'static', got {form!r}")
    if not ridge >= 0:
        raise DataError(f"ridge must be >= 0, got {ridge}")
    records = [data] if isinstance(data, Dataset) else list(data)
    data = records[0]
    for other in records[1:]:
        if (other.u_names, other.y_names, other.p_names, other.Ts) != (data.u_names, data.y_names,
                                                                      data.p_names, data.Ts):
            raise DataError("the records differ in their signals or Ts; give records of the same signals "
                            "sampled alike")
    ny, nu = data.y.shape[1], data.u.shape[1]
    basis = Basis.from_spec(basis, data.p.shape[1]) if isinstance(basis, str) else basis
    if basis.n_p != data.p.shape[1]:
        raise DataError(f"the basis is for {basis.n_p} scheduling signal(s), the data has {data.p.shape[1]}")
    basis = basis.with_range(np.concatenate([record.p for record in records]))
    na = order_matrix("na", na, (ny, ny), 0)
    nb = order_matrix("nb", nb, (ny, nu), 0)
    nk = order_matrix("nk", nk, (ny, nu), 0)
    shifted = form == "shifted"
    n_psi = basis.n_psi
    max_lag = int(max(na.max(initial=0), (nk + nb - 1)[nb > 0].max(initial=0)))
    row_cols = [row_columns(r, na, nb, nk, n_psi, shifted) for r in range(ny)]
    n_max = max(len(c) for c in row_cols)
    if n_max == 0:
        raise DataError("the model has no parameters: raise na or nb")
    for record in records:
        record.require_samples(max_lag, f"lags up to {max_lag}")
    n_eff = sum(record.N - max_lag for record in records)
    if n_eff <= n_max:
        raise DataError(f"{n_eff} regressor rows are too few for {n_max} parameters per output with lags "
                        f"up to {max_lag} (needs more than {n_max}): record longer data or lower the "
                        "orders/basis degree")

    groups: dict[tuple, list[int]] = {}
    for r, cols in enumerate(row_cols):
        groups.setdefault(tuple(cols), []).append(r)
    A = np.zeros((na.max(initial=0), n_psi, ny, ny))
    B = np.zeros((max(int((nk + nb - 1).max(initial=0)), 0) + 1, n_psi, ny, nu))
    noise_cov = np.zeros((ny, ny))
    param_cov: list[np.ndarray] = [np.zeros((0, 0))] * ny
    for cols_key, outputs in groups.items():
        cols = list(cols_key)
        n = len(cols)
        R = _tsqr(cols, outputs, records, basis, max_lag, shifted, ridge)
        Rp, Z, T = R[:n, :n], R[:n, n:], R[n:, n:]
        s = np.linalg.svd(Rp, compute_uv=False)
        if s[-1] <= RANK_TOL * s[0]:
            rank = int(np.sum(s > RANK_TOL * s[0]))
            raise DataError(
                f"the regressor is rank deficient (rank {rank} of {n}): the data do not excite every "
                "coefficient; lower the orders or basis degree, excite more, or pass a ridge weight"
            )
        theta = scipy.linalg.solve_triangular(Rp, Z)
        Rinv = scipy.linalg.solve_triangular(Rp, np.eye(n))
        info = Rinv @ Rinv.T
        residual = T.T @ T
        for a, r in enumerate(outputs):
            for idx, col in enumerate(cols):
                if col.signal == "y":
                    A[col.lag - 1, col.psi, r, col.channel] = theta[idx, a]
                else:
                    B[col.lag, col.psi, r, col.channel] = theta[idx, a]
            sigma2 = residual[a, a] / max(n_eff - n, 1)
            param_cov[r] = sigma2 * info
            noise_cov[r, outputs] = residual[a] / n_eff
    io = LPVIO(A, B, basis, data.Ts, form=form, na=na, nb=nb, nk=nk, u_names=data.u_names,
               y_names=data.y_names, p_names=data.p_names, param_cov=param_cov)
    if len(groups) > 1:  # cross-covariances between separately solved outputs: one-step residuals
        e = np.concatenate([prediction_residuals(io, record) for record in records])
        noise_cov = e.T @ e / len(e)
    io.noise_cov = noise_cov
    return io


def prediction_residuals(io: LPVIO, data: Dataset) -> np.ndarray:
    """One-step-ahead prediction errors y(k) − ŷ(k|k−1) of an ARX model, for k ≥ the largest lag."""
    start = io.max_lag
    psi = io.basis.eval(data.p, check_range=False)
    shifted = io.form == "shifted"
    pred = np.zeros((data.N - start, io.ny))
    for i in range(io.A.shape[0]):
        coeff = psi[start - i - 1 : data.N - i - 1] if shifted else psi[start:]
        pred -= np.einsum("tl,lrc,tc->tr", coeff, io.A[i], data.y[start - i - 1 : data.N - i - 1])
    for j in range(io.B.shape[0]):
        coeff = psi[start - j : data.N - j] if shifted else psi[start:]
        pred += np.einsum("tl,lrc,tc->tr", coeff, io.B[j], data.u[start - j : data.N - j])
    return data.y[start:] - pred
