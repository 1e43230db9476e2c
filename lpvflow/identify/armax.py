"""LPV-ARMAX by iterative pseudo-linear regression (Schulz et al., §2.1, eq. (8)).

Model (shifted form; static form evaluates every coefficient at ψ(p(k))):

    y(k) + Σ_i A_i(ψ(k−i)) y(k−i) = Σ_j B_j(ψ(k−j)) u(k−j) + e(k) + Σ_m C_m(ψ(k−m)) e(k−m).

Predictor (8): ŷ(k|k−1) = (I − A) y + B u + (C − I) ê, ê = y − ŷ. Each iteration solves the LS
problem of the ARX regressor extended by the columns ê_c(k−m)·ψ (ê from the previous iteration;
initially the LS-ARX residuals), then recomputes ê as the exact prediction error of the new model,
ê(k) = y(k) − ŷ_ARX-part(k) − Σ_m C_m ê(k−m) (the C⁻¹ filter, one compiled recursion). SISO and
MIMO (all outputs share the noise lags nc). The returned LPVIO carries C, so ``to_ss()`` gives the
innovation-form gain K (Schulz eq. (4)).
"""

from __future__ import annotations

import numpy as np

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.identify.arx import RegressorColumn, fill_regressor
from lpvflow.identify.iv import Structure, least_squares_thetas, solve_instrumental
from lpvflow.lpvio import LPVIO
from lpvflow.simulate import io_recursion


def _noise_columns(ny: int, nc: int, n_psi: int) -> list[RegressorColumn]:
    # "u"-type columns (no sign flip) read from the residual signal ê.
    return [RegressorColumn("u", c, m, l) for c in range(ny) for m in range(1, nc + 1) for l in range(n_psi)]


def _noise_regressor(
    cols: list[RegressorColumn], e: np.ndarray, psi: np.ndarray, shifted: bool
) -> np.ndarray:
    """Columns ê_c(k−m) ψ_l(k−m or k) for every sample, zero past before k = 0."""
    n, pad = len(e), max(c.lag for c in cols)
    # F order: contiguous columns (numpy 2.4 in-place negative on strided views is wrong)
    out = np.empty((n, len(cols)), order="F")
    epad = np.vstack([np.zeros((pad, e.shape[1])), e])
    psipad = np.vstack([np.zeros((pad, psi.shape[1])), psi])
    fill_regressor(out, cols, epad, epad, psipad, pad, pad + n, 0, shifted)
    return out


def identify_armax(data: Dataset, na: int | np.ndarray, nb: int | np.ndarray, nk: int | np.ndarray,
                   nc: int, basis: Basis | str = "affine", form: str = "shifted", iterations: int = 30,
                   tol: float = 1e-8) -> LPVIO:
    """LPV-ARMAX by pseudo-linear regression; returns A, B and the noise coefficients C.

    Args:
        nc: number of noise lags C_1 … C_nc (≥ 1).
        iterations, tol: stop after this many LS solves or when the relative parameter change
            drops below ``tol``.
    """
    if nc < 1:
        raise DataError(f"nc must be >= 1 for ARMAX (got {nc}); use identify_arx for nc = 0")
    struct = Structure.from_data(data, na, nb, nk, basis, form)
    ny, n_psi, shifted = struct.ny, struct.basis.n_psi, struct.shifted
    psi = struct.basis.eval(data.p, check_range=False)
    start = max(struct.max_lag, nc)
    data.require_samples(start + max(len(c) for c in struct.columns) + ny * nc * n_psi,
                         "the ARMAX parameters")
    e_cols = _noise_columns(ny, nc, n_psi)
    phi_ab = [struct.regressor(r, data.y, data.u, psi) for r in range(ny)]
    arx = least_squares_thetas(struct, data, psi)  # iteration 0: ARX, i.e. ê = 0 in the regressor
    e_hat = data.y - np.column_stack([p @ t for p, t in zip(phi_ab, arx, strict=True)])
    previous = None
    for _ in range(iterations):
        phi_e = _noise_regressor(e_cols, e_hat, psi, shifted)
        thetas = [solve_instrumental(phi, phi, data.y[start:, r])
                  for r, phi in enumerate(np.hstack([p, phi_e])[start:] for p in phi_ab)]
        C = np.zeros((nc, n_psi, ny, ny))
        for r, theta in enumerate(thetas):
            for col, value in zip(e_cols, theta[len(struct.columns[r]):], strict=True):
                C[col.lag - 1, col.psi, r, col.channel] = value
        arx_part = np.column_stack([p @ t[: p.shape[1]] for p, t in zip(phi_ab, thetas, strict=True)])
        e_hat = io_recursion(np.ascontiguousarray(data.y - arx_part), psi, C, shifted)
        if not np.isfinite(e_hat).all():
            raise ModelError("the estimated noise model C is not minimum phase along this scheduling "
                             "trajectory; lower nc or use identify_arx")
        x = np.concatenate(thetas)
        if previous is not None and np.linalg.norm(x - previous) <= tol * np.linalg.norm(previous):
            break
        previous = x
    io = struct.model([t[: len(struct.columns[r])] for r, t in enumerate(thetas)], C=C)
    err = e_hat[start:]
    io.noise_cov = err.T @ err / len(err)
    return io
