"""LPV PBSIDopt: predictor-based subspace identification, primal and kernel forms.

J.-W. van Wingerden and M. Verhaegen, "Subspace identification of Bilinear and LPV systems for open-
and closed-loop data", Automatica 45 (2009) 372–381.

Model (eqs. (1)–(2), innovation form with scheduling μ_k = ψ(p_k), μ_k^(1) = 1):

    x_{k+1} = Σ_i μ_k^(i) (A^(i) x_k + B^(i) u_k + K^(i) e_k),     y_k = C x_k + D u_k + e_k.

With the predictor Ã^(i) = A^(i) − K^(i)C uniformly exponentially stable, x_{k+p} ≈ K^p N_k^p z̄_k^p
(eq. (8)), so y_{k+p} ≈ CK^p Z_k + D u_{k+p} + e_{k+p} is a linear regression (13). Steps
(Algorithms 1 and 2, with N̄ = N − p columns for the paper's N − p + 1; helpers in :mod:`pbsid_kernel`):

1. Regression (13): primal, Θ = [CK^p, D] from the rows [Z; U] (q̃ = (r+ℓ)Σ_j m^j of them,
   exponential in p); kernel (dual), α = Y (ZᵀZ + UᵀU + λI)^+ on an N̄×N̄ kernel built in closed form
   (Theorem 10). Tikhonov λ is fixed, GCV-chosen, or 0 (minimum-norm).
2. Γ^f K^p Z (eq. (14)/(25)), block row i = 1 … f: Σ_{j≥i} C(Ã^(1))^{i−1} L_{p−j+1} Z^{1,j}; the
   coefficient is the leading (r+ℓ)m^{p−j+1} columns of block j−i+1 of CK^p (primal) or
   α S_i (kernel, Lemma 8). f ≤ p is the future window (f = p in the paper).
3. State (15)–(16): Γ^f K^p Z = 𝒰 Σ Vᵀ, X̂ = Σ_n V_nᵀ; n from the largest gap of log σ if not given.
4. [C D] = Y [X̂; U]^+, Ê = Y − C X̂ − D U, and
   [A^(·) B^(·) K^(·)] = X̂_{+} [μ⊙X̂; μ⊙U; μ⊙Ê]^+ (Sec. 4.3; ⊙ column-wise Kronecker).

Closed-loop data: nothing assumes u independent of e; the estimate is consistent up to the
truncation bias when u_{k+p} holds no feedthrough of e_{k+p}, i.e. a strictly causal controller
(or ``feedthrough=False`` when D = 0 is known, which drops U from the regression).

Bilinear systems (Sec. 7.3) are the special case μ_k = [1, u_kᵀ]ᵀ: pass the input columns as the
scheduling signals with the affine basis — :func:`bilinear_data` does this for a Dataset (CLI:
``--p`` naming the same columns as ``--u``).

Row selection (Sec. 6, Algorithm 3) for periodic or piecewise-constant scheduling keeps only
kernel rows that span its row space: ``periodic_rows=True`` selects them greedily, an integer M
takes the first M rows (Sec. 6.1's P·(r+ℓ)·p for period P, plus r when D is estimated: the UᵀU term
adds up to r dimensions).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.identify.pbsid_kernel import (
    RANK_TOL,
    kernel_row_sums,
    primal_blocks,
    select_rows,
    solve_dual,
    solve_primal,
)
from lpvflow.models import LPVSS

#: Past window when none is given: p = 3 did better than p = 5 on noisy data in the paper's Table 2.
DEFAULT_PAST = 3
#: Singular values below this fraction of the largest are never counted as states by the gap rule.
ORDER_FLOOR = 1e-3
#: Largest primal data matrix [Z; U] (bytes) before the kernel form is required.
PRIMAL_MEMORY_LIMIT = 2 * 2**30
#: Largest N̄×N̄ kernel (bytes) per matrix before shorter data or the primal form is required.
KERNEL_MEMORY_LIMIT = 2 * 2**30


def default_past(ny: int, order: int | None) -> int:
    """DEFAULT_PAST, or the least p with p·ℓ > n when the order needs more block rows (A4)."""
    if order is None:
        return DEFAULT_PAST
    return max(DEFAULT_PAST, order // ny + 1)


def bilinear_data(data: Dataset) -> Dataset:
    """The dataset with the inputs as scheduling signals, so that μ_k = [1, u_kᵀ]ᵀ (Sec. 7.3)."""
    return Dataset(data.u, data.y, data.u.copy(), data.Ts, data.u_names, data.y_names,
                   [f"{name}(sched)" for name in data.u_names], dict(data.offsets))


def gap_order(singular_values: np.ndarray, max_order: int) -> int:
    """The n ≤ max_order after which log10 σ drops most, σ below ORDER_FLOOR·σ_1 counting as that floor.

    The floor keeps the truncation error of the φ ≈ 0 approximation (8), which gives small but
    nonzero singular values on noise-free data, from being taken for states.
    """
    s = np.maximum(singular_values[: max_order + 1], ORDER_FLOOR * singular_values[0])
    if len(s) < 2:
        return 1
    drops = -np.diff(np.log10(s))
    return int(np.argmax(drops[:max_order])) + 1


def _check(data: Dataset, order: int | None, past: int, future: int, form: str,
           regularization: str | float | None, periodic_rows: bool | int, m: int) -> None:
    ny, nu = data.y.shape[1], data.u.shape[1]
    if past < 1:
        raise ModelError(f"past window must be >= 1, got {past}")
    if not 1 <= future <= past:
        raise ModelError(f"future window must satisfy 1 <= future <= past ({past}), got {future}")
    if form not in ("primal", "kernel"):
        raise ModelError(f"form must be 'primal' or 'kernel', got {form!r}")
    if order is not None and not 1 <= order <= future * ny:
        raise ModelError(f"order {order} needs 1 <= order <= future*ny = {future * ny}: "
                         "raise the past/future window or lower the order")
    if not (regularization is None or regularization == "gcv"
            or (isinstance(regularization, int | float) and regularization >= 0)):
        raise ModelError(f"regularization must be None, 'gcv' or a weight >= 0, got {regularization!r}")
    if periodic_rows is not False:
        if form != "kernel":
            raise ModelError("periodic_rows selects kernel rows; use form='kernel'")
        if regularization is not None:
            raise ModelError("periodic_rows replaces regularization (van Wingerden & Verhaegen 2009, "
                             "Sec. 7.2); pass only one")
        if not isinstance(periodic_rows, bool) and periodic_rows < 1:
            raise ModelError(f"periodic_rows must be True or a row count >= 1, got {periodic_rows}")
    n_cols = data.N - past
    needed = m * ((order or future * ny) + nu + ny) + 1
    data.require_samples(past + needed, f"PBSIDopt with past {past} and m = {m} scheduling functions")
    if form == "primal":
        rows = regression_rows(nu, ny, m, past)
        if 8 * rows * n_cols > PRIMAL_MEMORY_LIMIT:
            raise ModelError(f"the primal data matrix would have {rows} x {n_cols} entries; use "
                             "form='kernel' or a smaller past window")
    elif 8 * 4 * n_cols**2 > KERNEL_MEMORY_LIMIT:
        raise ModelError(f"the kernel would be {n_cols} x {n_cols}; use form='primal', shorter data "
                         "or periodic_rows")


def _gamma_k_z_primal(z, mu, U, Y, past, future, regularization):
    blocks = primal_blocks(z, mu, past)
    W = np.vstack(blocks + ([U] if U is not None else []))
    theta, lam, score = solve_primal(W, Y, regularization)
    sizes = [b.shape[0] for b in blocks]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    rows = []
    for i in range(1, future + 1):
        acc = np.zeros((Y.shape[0], Y.shape[1]))
        for j in range(i, past + 1):
            first = starts[j - i]  # block j−i+1 of CK^p (0-based j−i), leading d_j columns
            acc += theta[:, first : first + sizes[j - 1]] @ blocks[j - 1]
        rows.append(acc)
    return np.vstack(rows), {"lambda": lam, "gcv": score, "rows": int(W.shape[0])}


def _gamma_k_z_kernel(z, mu, U, Y, past, future, regularization, periodic_rows):
    sums = kernel_row_sums(z, mu, past, future)
    gram = sums[0] + (U.T @ U if U is not None else 0.0)
    info: dict = {"rows": int(gram.shape[0])}
    if periodic_rows is False:
        solved = solve_dual(gram, Y, regularization)
        alpha, rows = solved.alpha, slice(None)
        info.update({"lambda": solved.lam, "gcv": solved.gcv})
    else:
        rows = (select_rows(gram) if periodic_rows is True
                else np.arange(min(int(periodic_rows), gram.shape[0])))
        alpha = scipy.linalg.lstsq(gram[rows].T, Y.T, lapack_driver="gelsd")[0].T
        info.update({"lambda": 0.0, "gcv": None, "rows": len(rows)})
    return np.vstack([alpha @ s[rows] for s in sums]), info


def state_matrix(
    data: Dataset, mu: np.ndarray, past: int, future: int, form: str = "primal",
    regularization: str | float | None = None, periodic_rows: bool | int = False, feedthrough: bool = True,
) -> tuple[np.ndarray, dict]:
    """Γ^f K^p Z (f·ℓ × N̄, eqs. (14)/(25)) by the primal or kernel regression, and solve details.

    ``mu`` is (N, m) with first column ones; column c of the result belongs to time c + past.
    """
    z = np.hstack([data.u, data.y])
    Y = data.y[past:].T
    U = data.u[past:].T if feedthrough else None
    if form == "primal":
        return _gamma_k_z_primal(z, mu, U, Y, past, future, regularization)
    return _gamma_k_z_kernel(z, mu, U, Y, past, future, regularization, periodic_rows)


def _system_matrices(X, Y, U, M, feedthrough):
    """Least squares of (2) then (1) on the estimated states (Sec. 4.3, step 5)."""
    regressor = np.vstack([X, U]) if feedthrough else X
    CD = scipy.linalg.lstsq(regressor.T, Y.T)[0].T
    E = Y - CD @ regressor
    n, r, l, m = X.shape[0], U.shape[0], Y.shape[0], M.shape[0]
    R = np.vstack([scipy.linalg.khatri_rao(M, X), scipy.linalg.khatri_rao(M, U),
                   scipy.linalg.khatri_rao(M, E)])[:, :-1]
    ABK = scipy.linalg.lstsq(R.T, X[:, 1:].T)[0].T
    A = ABK[:, : m * n].reshape(n, m, n).transpose(1, 0, 2)
    B = ABK[:, m * n : m * (n + r)].reshape(n, m, r).transpose(1, 0, 2)
    K = ABK[:, m * (n + r) :].reshape(n, m, l).transpose(1, 0, 2)
    C = np.zeros((m, l, n))
    D = np.zeros((m, l, r))
    C[0] = CD[:, :n]
    if feedthrough:
        D[0] = CD[:, n:]
    return A, B, C, D, K


def identify_pbsid(
    data: Dataset, order: int | None = None, past: int | None = None, future: int | None = None,
    basis: Basis | str | None = None, form: str = "primal", regularization: str | float | None = None,
    periodic_rows: bool | int = False, feedthrough: bool = True,
) -> LPVSS:
    """LPV PBSIDopt (van Wingerden & Verhaegen 2009, Algorithms 1–3) from open- or closed-loop data.

    Args:
        data: estimation data; with a controller in the loop it must be strictly causal.
        order: state order n; None takes the largest gap of the singular values of Γ^f K^p Z.
        past: past window p (default :func:`default_past`).
        future: number of block rows f ≤ p of Γ (default p, as in the paper).
        basis: scheduling basis ψ giving μ_k = ψ(p_k) (default affine, μ = [1, pᵀ]ᵀ).
        form: ``"primal"`` (Algorithm 1, (r+ℓ)Σ_j m^j regression rows: exponential in p) or
            ``"kernel"`` (Algorithm 2, O(p² N̄² + N̄³) time and O(N̄²) memory, not exponential in p).
        regularization: None (minimum norm), ``"gcv"`` (Tikhonov, λ by generalized
            cross-validation) or a fixed Tikhonov weight λ ≥ 0 on ‖[CK^p D]‖_F².
        periodic_rows: kernel only: True keeps the independent kernel rows (Algorithm 3), an
            integer M keeps the first M rows; replaces regularization.
        feedthrough: estimate D (True) or fix D = 0 and drop u_{k+p} from the regression.

    Returns:
        An innovation-form :class:`LPVSS` (A, B, K depend on ψ; C, D constant). ``.reduction``
        records the singular values, the order and how it was chosen, windows, form, λ and rows.
    """
    return identify_pbsid_orders(data, [order], past, future, basis, form, regularization,
                                 periodic_rows, feedthrough)[0]


def identify_pbsid_orders(
    data: Dataset, orders: list[int | None], past: int | None = None, future: int | None = None,
    basis: Basis | str | None = None, form: str = "primal", regularization: str | float | None = None,
    periodic_rows: bool | int = False, feedthrough: bool = True,
) -> list[LPVSS]:
    """:func:`identify_pbsid` for several orders, sharing the regression and the SVD of Γ^f K^p Z."""
    basis = Basis.from_spec(basis, data.p.shape[1]) if isinstance(basis, str) else basis
    basis = (basis or Basis.affine(data.p.shape[1]))
    if basis.n_p != data.p.shape[1]:
        raise DataError(f"the basis is for {basis.n_p} scheduling signal(s), the data has {data.p.shape[1]}")
    basis = basis.with_range(data.p)
    mu = basis.eval(data.p)
    ny = data.y.shape[1]
    given = [o for o in orders if o is not None]
    past = default_past(ny, max(given, default=None)) if past is None else int(past)
    future = past if future is None else int(future)
    for order in orders or [None]:
        _check(data, order, past, future, form, regularization, periodic_rows, mu.shape[1])

    Y, U = data.y[past:].T, data.u[past:].T
    gkz, info = state_matrix(data, mu, past, future, form, regularization, periodic_rows, feedthrough)
    _, s, Vt = scipy.linalg.svd(gkz, full_matrices=False)
    models = []
    for order in orders:
        n = gap_order(s, min(future * ny, len(s) - 1)) if order is None else int(order)
        if s[n - 1] <= RANK_TOL * s[0]:
            shown = np.round(s[: n + 1], 6).tolist()
            raise ModelError(f"Γ K Z has numerical rank below the order {n}: the data do not excite "
                             f"{n} states; lower the order (singular values {shown})")
        X = s[:n, None] * Vt[:n]
        A, B, C, D, K = _system_matrices(X, Y, U, mu[past:].T, feedthrough)
        record = {
            "method": "pbsid",
            "form": form,
            "singular_values": s.tolist(),
            "order": n,
            "order_rule": ("given" if order is not None
                           else f"largest gap of log10 singular values above {ORDER_FLOOR:g} of the first"),
            "past": past,
            "future": future,
            "regularization": regularization if isinstance(regularization, str | None) else float(
                regularization),
            "lambda": info["lambda"],
            "gcv": info["gcv"],
            "kernel_rows" if form == "kernel" else "regression_rows": info["rows"],
        }
        models.append(LPVSS(A, B, C, D, basis, data.Ts, K=K, u_names=list(data.u_names),
                            y_names=list(data.y_names), p_names=list(data.p_names), reduction=record))
    return models


def regression_rows(nu: int, ny: int, m: int, past: int) -> int:
    """Rows of [Z; U] in the primal regression: (r+ℓ) Σ_{j=1}^{p} m^j + r (Sec. 4.4, Table 1)."""
    return (nu + ny) * (m * (m**past - 1) // (m - 1) if m > 1 else past) + nu
