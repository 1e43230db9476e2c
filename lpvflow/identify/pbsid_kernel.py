"""Data matrices, kernels and regularized solves of LPV PBSIDopt (van Wingerden & Verhaegen 2009, Secs. 2–6).

Notation (Sec. 2.2): μ_k ∈ R^m with μ_k^(1) = 1, z_k = [u_kᵀ y_kᵀ]ᵀ ∈ R^{r+ℓ}, past window p,
N̄ = N − p regression columns (the N − p + 1 of (12) and Lemma 8 is an index slip). Column c
(0-based) of every matrix belongs to the prediction of y at time c + p.

Primal data matrix (12) in Khatri–Rao form (⊙ = column-wise Kronecker, latest μ outermost):

    Z = [Z^{1,1}; …; Z^{1,p}],   Z^{1,j} = M_{p−1} ⊙ ⋯ ⊙ M_{j−1} ⊙ 𝒵_{j−1},
    M_s = [μ_{s}, …, μ_{N̄−1+s}],  𝒵_s = [z_{s}, …, z_{N̄−1+s}]

so Z has q̃ = (r+ℓ) Σ_{j=1}^{p} m^j rows. Kernel blocks, Theorem 10 read with Hadamard products
(Sec. 5.2), for 1 ≤ i ≤ j ≤ p:

    [(Z^{i,j})ᵀ Z^{1,j}]_{s,t} = Π_{v=0}^{p−j} μ_{s+j−i+v}ᵀ μ_{t+j−1+v} · z_{s+j−i}ᵀ z_{t+j−1}.

The μ-product for j is the one for j + 1 times one more shifted window of G_μ = [μ_k]ᵀ[μ_k], so
S_i = Σ_{j=i}^{p} (Z^{i,j})ᵀ Z^{1,j} costs O(p) Hadamard products of N̄×N̄ windows (O(p²) for all i).

Regularized solve (Sec. 5.3 names Tikhonov regularization with GCV but gives no formula): with the kernel
G = ZᵀZ + UᵀU = Q Λ Qᵀ, Tikhonov α_λ = Y (G + λI)⁻¹ is the dual of min ‖Y − Θ[Z; U]‖² + λ‖Θ‖²;
λ = 0 means the minimum-norm solution (21). Generalized cross-validation picks λ minimising

    GCV(λ) = N̄ ‖Y (I − H_λ)‖_F² / tr(I − H_λ)²,   H_λ = G (G + λI)⁻¹ (eigenvalues λ_i/(λ_i + λ)).

Row selection for structured scheduling (Sec. 6, Algorithm 3): rows of G are taken in order and
kept when their distance to the span of the rows kept so far exceeds ``tol`` times their norm
(the paper's absolute ε made scale-free).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

#: Eigen/singular values below this fraction of the largest count as zero (minimum-norm solve).
RANK_TOL = 1e-12
#: Number of λ values on the GCV grid, spanning GCV_SPAN decades below the largest eigenvalue.
GCV_POINTS = 141
GCV_SPAN = 14.0
#: Relative distance below which a kernel row counts as dependent (Algorithm 3).
ROW_TOL = 1e-9


def shifted(a: np.ndarray, s: int, n_cols: int) -> np.ndarray:
    """[a_s, …, a_{s+n_cols−1}] as a (dim, n_cols) matrix from time-major ``a`` (N, dim)."""
    return a[s : s + n_cols].T


def primal_blocks(z: np.ndarray, mu: np.ndarray, past: int) -> list[np.ndarray]:
    """[Z^{1,1}, …, Z^{1,p}] of eq. (12); Z^{1,j} has (r+ℓ) m^{p−j+1} rows and N − p columns."""
    n_cols = len(z) - past
    blocks = []
    for j in range(1, past + 1):
        block = shifted(z, j - 1, n_cols)
        for s in range(j - 1, past):
            block = scipy.linalg.khatri_rao(shifted(mu, s, n_cols), block)
        blocks.append(block)
    return blocks


def kernel_row_sums(z: np.ndarray, mu: np.ndarray, past: int, future: int) -> list[np.ndarray]:
    """S_i = Σ_{j=i}^{p} (Z^{i,j})ᵀ Z^{1,j} for i = 1 … future (Theorem 10, eq. (25)); S_1 = ZᵀZ."""
    n_cols = len(z) - past
    gram_mu = mu @ mu.T
    gram_z = z @ z.T
    sums = []
    for i in range(1, future + 1):
        product = np.ones((n_cols, n_cols))
        total = np.zeros((n_cols, n_cols))
        for j in range(past, i - 1, -1):
            row, col = j - i, j - 1  # window offsets of the factor added for this j
            product *= gram_mu[row : row + n_cols, col : col + n_cols]
            total += product * gram_z[row : row + n_cols, col : col + n_cols]
        sums.append(total)
    return sums


@dataclass(frozen=True)
class Regularized:
    """The solve α = Y (G + λI)^+ and how λ was found."""

    alpha: np.ndarray
    lam: float
    gcv: float | None = None


def _filter(eigenvalues: np.ndarray, lam: float) -> np.ndarray:
    """1/(λ_i + λ), or the pseudo-inverse 1/λ_i (zero below RANK_TOL·λ_max) when λ = 0."""
    if lam > 0:
        return 1.0 / (eigenvalues + lam)
    keep = eigenvalues > RANK_TOL * eigenvalues.max()
    return np.where(keep, 1.0 / np.where(keep, eigenvalues, 1.0), 0.0)


def gcv_curve(eigenvalues: np.ndarray, y_coords: np.ndarray, y_outside: float, n_total: int,
              lambdas: np.ndarray) -> np.ndarray:
    """GCV(λ) for every λ on the grid.

    Args:
        eigenvalues: the nonzero-space eigenvalues λ_i of G (its other N̄ − len(λ_i) are zero).
        y_coords: (ℓ, len(λ_i)) coordinates of Y on the matching eigenvectors.
        y_outside: ‖Y‖² outside those eigenvectors (left untouched by H_λ).
        n_total: N̄.
    """
    shrink = lambdas[:, None] / (eigenvalues[None, :] + lambdas[:, None])  # eigenvalues of I − H_λ
    weight = np.sum(y_coords**2, axis=0)
    residual = (shrink**2) @ weight + y_outside
    trace = shrink.sum(axis=1) + (n_total - len(eigenvalues))
    return n_total * residual / trace**2


def gcv_grid(eigenvalues: np.ndarray) -> np.ndarray:
    top = float(eigenvalues.max())
    return top * np.logspace(-GCV_SPAN, 0.0, GCV_POINTS)


def solve_dual(gram: np.ndarray, Y: np.ndarray, regularization: str | float | None) -> Regularized:
    """α = Y (G + λI)^+ on the N̄×N̄ kernel (eqs. (19)–(21)), λ from GCV when asked."""
    eigenvalues, Q = scipy.linalg.eigh(gram)
    eigenvalues = np.clip(eigenvalues, 0.0, None)
    Yq = Y @ Q
    lam, score = _choose_lambda(eigenvalues, Yq, 0.0, len(eigenvalues), regularization)
    return Regularized((Yq * _filter(eigenvalues, lam)) @ Q.T, lam, score)


def solve_primal(W: np.ndarray, Y: np.ndarray, regularization: str | float | None) -> tuple[np.ndarray, float,
                                                                                           float | None]:
    """Θ = argmin ‖Y − ΘW‖² + λ‖Θ‖² (minimum norm for λ = 0) by the SVD W = U S Vᵀ (eq. (13)/(18))."""
    try:
        U, s, Vt = scipy.linalg.svd(W, full_matrices=False)
    except np.linalg.LinAlgError:  # gesdd did not converge: the slower, more robust driver
        U, s, Vt = scipy.linalg.svd(W, full_matrices=False, lapack_driver="gesvd")
    eigenvalues = s**2
    Yv = Y @ Vt.T
    outside = max(float(np.sum(Y**2) - np.sum(Yv**2)), 0.0)
    lam, score = _choose_lambda(eigenvalues, Yv, outside, W.shape[1], regularization)
    gain = s * _filter(eigenvalues, lam)
    return (Yv * gain) @ U.T, lam, score


def _choose_lambda(eigenvalues: np.ndarray, y_coords: np.ndarray, y_outside: float, n_total: int,
                   regularization: str | float | None) -> tuple[float, float | None]:
    if regularization is None:
        return 0.0, None
    if regularization == "gcv":
        grid = gcv_grid(eigenvalues)
        curve = gcv_curve(eigenvalues, y_coords, y_outside, n_total, grid)
        best = int(np.argmin(curve))
        return float(grid[best]), float(curve[best])
    return float(regularization), None


def select_rows(gram: np.ndarray, tol: float = ROW_TOL) -> np.ndarray:
    """Algorithm 3: indices of the rows of G kept in order, each independent of those before it.

    A row is kept when ‖(I − QQᵀ) g‖ > tol ‖g‖, with Q an orthonormal basis of the kept rows
    (classical Gram–Schmidt applied twice for numerical orthogonality).
    """
    n = gram.shape[0]
    basis = np.zeros((n, min(n, gram.shape[1])))
    kept: list[int] = []
    for index in range(n):
        row = gram[index]
        norm = np.linalg.norm(row)
        if norm == 0.0:
            continue
        residual = row.copy()
        current = basis[:, : len(kept)]
        for _ in range(2):
            residual -= current @ (current.T @ residual)
        distance = np.linalg.norm(residual)
        if distance > tol * norm and len(kept) < basis.shape[1]:
            basis[:, len(kept)] = residual / distance
            kept.append(index)
    return np.asarray(kept, dtype=int)
