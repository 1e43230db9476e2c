"""LPV Ho–Kalman-like order reduction by a square-root Gram recursion (Schulz et al., Sec. IV, Lemma 1).

For an affine LPVSS x(k+1) = Σ_l ψ_l (A_l x + B_l u + K_l e), y = Σ_l ψ_l (C_l x + D_l u) + e
(Schulz et al., eqs. (10)–(14)):

    M_1 = [B_1 … B_nψ  K_1 … K_nψ],  M_k = [A_1 M_{k−1} … A_nψ M_{k−1}],    R_j = [M_1 … M_j]
    N_1 = [C_1; …; C_nψ],             N_k = [N_{k−1} A_1; …; N_{k−1} A_nψ],  O_i = [N_1; …; N_i]
    H_ij = O_i R_j      (its blocks are the sub-Markov parameters C_m A_{l_1} ⋯ A_{l_s} [B_r | K_r])

O_i has n_y nψ (nψ^i − 1)/(nψ − 1) rows, so it is never formed. Its Gram matrix obeys

    O_iᵀO_i = Σ_{k=1}^{i} P_k,   P_1 = N_1ᵀN_1,   P_k = Σ_l A_lᵀ P_{k−1} A_l

(dually R_jR_jᵀ with A_lᵀ, M_1ᵀ), and it is propagated in square-root form so that the condition
number is never squared: F_1 = qr_R(N_1), F_k = qr_R([F_{k−1}A_1; …; F_{k−1}A_nψ]) (so F_kᵀF_k = P_k),
S_i = qr_R([S_{i−1}; F_i]). S_i is the R_O of Lemma 1 up to an orthogonal left factor, to which
Lemma 1 is invariant. Cost O((i + j) nψ n_x³), memory O(nψ n_x²). Then (15)–(18):

    R_O R_Rᵀ = U Σ Vᵀ,   T = R_Rᵀ V_n Σ_n^{−1/2},   T† = Σ_n^{−1/2} U_nᵀ R_O,   T†T = I_n,
    Â_l = T† A_l T,   B̂_l = T† B_l,   K̂_l = T† K_l,   Ĉ_l = C_l T,   D̂_l = D_l.

Corrections and choices:

* N_1 stacks every C_l (the remark after Lemma 1), so C may depend on ψ; O_i then has
  n_y Σ_{k=1}^{i} nψ^k rows (the row counts printed in (13)/(14) are wrong).
* The working condition is rank(H_ij) = n_G, not rank(O_i) = rank(R_j) = n_G: a model that is
  observable but not reachable (seed Example 2) never satisfies the latter.
* Unstable or marginally stable models (common for identified observable forms) make P_k grow
  geometrically, which would bury the early terms below round-off. With ``scaling="cap"`` (default)
  every term whose factor norm ‖F_k‖_F exceeds ‖F_1‖_F is scaled down to it before it is added and
  propagated: a positive weight on each block row N_k of O_i (block column M_k of R_j). Ranges and
  kernels, hence rank(H_ij) and the exactness of the order-n_G model, are unchanged; truncated
  models weigh every depth at most as much as the first. ``scaling="none"`` is the literal paper.

Automatic depth (i = j = k): k grows from 1 until (a) the numerical ranks of O_k and R_k equal
those of O_{k−1} and R_{k−1} — then the unobservable and reachable subspaces are A_l-invariant and
no deeper term changes rank(H) — and (b) the normalised singular values σ/σ_1 of H_kk moved by less
than ``SETTLE`` since k − 1; at most ``max(2 n_x, 3)`` levels.

Order selection (when ``order`` is None), from σ with values below tol·σ_1 counted as zero (n_G
of them are non-zero): n_gap = the position of the largest drop of log10 σ (the drop to the
numerical zero included); n_energy = the least n with Σ_{k≤n} σ_k² ≥ energy · Σ σ_k²;
order = max(n_gap, n_energy).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lpvflow.errors import ModelError
from lpvflow.identify.order_selection import ENERGY, numerical_rank, select_order
from lpvflow.models import LPVSS

#: Largest change of σ_k/σ_1 between two depths for the singular values to count as settled.
SETTLE = 1e-3


def _qr_r(X: np.ndarray) -> np.ndarray:
    """Upper-triangular R of X = QR, with min(rows, cols) rows (so RᵀR = XᵀX)."""
    return np.linalg.qr(X, mode="r")


class _SquareRootGram:
    """S_k with S_kᵀS_k = Σ_{m≤k} w_m² P_m, P_1 = N_1ᵀN_1, P_m = Σ_l A_lᵀ P_{m−1} A_l (module docstring).

    For the reachability Gram matrix pass A_lᵀ and M_1ᵀ.
    """

    def __init__(self, A: np.ndarray, first: np.ndarray, scaling: str) -> None:
        self._A = A
        self._scaling = scaling
        self.term = _qr_r(first)
        self._cap = np.linalg.norm(self.term)
        self.total = self.term
        self.depth = 1

    def step(self) -> None:
        term = _qr_r(np.matmul(self.term, self._A).reshape(-1, self._A.shape[2]))
        size = np.linalg.norm(term)
        if self._scaling == "cap" and size > self._cap:
            term = term * (self._cap / size)
        self.term = term
        self.total = _qr_r(np.vstack([self.total, term]))
        self.depth += 1

    def advance_to(self, depth: int) -> np.ndarray:
        while self.depth < depth:
            self.step()
        return self.total


def _first_blocks(ss: LPVSS) -> tuple[np.ndarray, np.ndarray]:
    """N_1 = [C_1; …; C_nψ] (n_y nψ, n_x) and M_1 = [B_1 … B_nψ K_1 … K_nψ] (n_x, ·)."""
    N1 = ss.C.reshape(-1, ss.nx)
    blocks = [ss.B] if ss.K is None else [ss.B, ss.K]
    M1 = np.concatenate([np.concatenate(list(b), axis=1) for b in blocks], axis=1)
    return N1, M1


def observability_matrix(ss: LPVSS, i: int) -> np.ndarray:
    """The explicit O_i of (12)–(13) with N_1 = [C_1; …; C_nψ]: exponential size, for inspection only."""
    Nk, blocks = _first_blocks(ss)[0], []
    for _ in range(i):
        blocks.append(Nk)
        Nk = np.vstack([Nk @ A_l for A_l in ss.A])
    return np.vstack(blocks)


def reachability_matrix(ss: LPVSS, j: int) -> np.ndarray:
    """The explicit R_j of (10)–(11) (B and K): exponential size, for inspection only."""
    Mk, blocks = _first_blocks(ss)[1], []
    for _ in range(j):
        blocks.append(Mk)
        Mk = np.hstack([A_l @ Mk for A_l in ss.A])
    return np.hstack(blocks)


def _hankel_factors(ss: LPVSS, depth: tuple[int, int] | None, tol: float, scaling: str
                    ) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """R_O, R_R (square-root Gram factors of O_i, R_jᵀ) and the depth [i, j] used."""
    N1, M1 = _first_blocks(ss)
    obs = _SquareRootGram(ss.A, N1, scaling)
    reach = _SquareRootGram(ss.A.transpose(0, 2, 1), M1.T, scaling)
    if depth is not None:
        return obs.advance_to(depth[0]), reach.advance_to(depth[1]), list(depth)
    prev_ranks, prev_profile = None, None
    for k in range(1, max(2 * ss.nx, 3) + 1):
        R_O, R_R = obs.advance_to(k), reach.advance_to(k)
        ranks = tuple(numerical_rank(np.linalg.svd(F, compute_uv=False), tol) for F in (R_O, R_R))
        s = np.linalg.svd(R_O @ R_R.T, compute_uv=False)
        profile = np.zeros(ss.nx)
        if s[0] > 0:
            profile[: len(s)] = s / s[0]
        if ranks == prev_ranks and np.max(np.abs(profile - prev_profile)) < SETTLE:
            break
        prev_ranks, prev_profile = ranks, profile
    return R_O, R_R, [k, k]


def _check_arguments(ss: LPVSS, order: int | None, tol: float, depth: tuple[int, int] | None,
                     scaling: str) -> None:
    if order is not None and (int(order) != order or order < 1):
        raise ModelError(f"order must be a whole number >= 1, got {order!r}")
    if not 0 < tol < 1:
        raise ModelError(f"tol must lie in (0, 1), got {tol!r}")
    if depth is not None and (len(depth) != 2 or any(int(d) != d or d < 1 for d in depth)):
        raise ModelError(f"depth must be a pair (i, j) of whole numbers >= 1, got {depth!r}")
    if scaling not in ("cap", "none"):
        raise ModelError(f"scaling must be 'cap' or 'none', got {scaling!r}")
    if not np.any(ss.C):
        raise ModelError("the model's C is zero: no state reaches the output, nothing to reduce")


def reduce(
    ss: LPVSS, order: int | None = None, tol: float = 1e-9, depth: tuple[int, int] | None = None,
    method: str = "ho-kalman", *, energy: float = ENERGY, scaling: str = "cap",
) -> LPVSS:
    """Reduce an affine LPVSS by Lemma 1 of Schulz et al. (``"ho-kalman"``) or by balanced truncation.

    Args:
        ss: the model; B and, if present, K drive the reachability structure, all C_l observe it.
        order: the reduced order n_x̂ (≤ the numerical Hankel rank n_G); None selects it
            (module docstring) — n_G itself when the singular values drop to zero.
        tol: singular values below tol·σ_1 count as zero (numerical ranks, n_G).
        depth: (i, j) of O_i and R_j; None chooses i = j automatically (module docstring).
        method: ``"ho-kalman"`` or ``"balanced"`` (:func:`lpvflow.identify.balanced.balanced_truncation`,
            quadratically stable models only; depth and scaling do not apply).
        energy: share of Σσ² the automatic order keeps.
        scaling: ``"cap"`` (bounded Gram terms, for unstable models) or ``"none"`` (literal paper).

    Returns:
        The reduced LPVSS (same basis, Ts, names, io) with ``.reduction`` recording the method,
        singular values, order, depth, ranks and the order selection, as plain JSON types.
    """
    if method == "balanced":
        if depth is not None:
            raise ModelError("depth applies to method='ho-kalman' only; drop it for balanced truncation")
        from lpvflow.identify.balanced import balanced_truncation

        return balanced_truncation(ss, order=order, tol=tol, energy=energy)
    if method != "ho-kalman":
        raise ModelError(f"unknown reduction method {method!r}; use 'ho-kalman' or 'balanced'")
    _check_arguments(ss, order, tol, depth, scaling)
    R_O, R_R, used_depth = _hankel_factors(ss, depth, tol, scaling)
    U, s, Vt = np.linalg.svd(R_O @ R_R.T)
    selection = select_order(s, tol, energy)
    n = selection["order"] if order is None else int(order)
    if n > selection["rank"]:
        raise ModelError(
            f"order {n} exceeds the numerical Hankel rank n_G = {selection['rank']} at depth "
            f"{used_depth}: choose order <= {selection['rank']} or a larger depth"
        )
    scale = 1 / np.sqrt(s[:n])
    T = R_R.T @ Vt[:n].T * scale
    T_left = scale[:, None] * (U[:, :n].T @ R_O)
    record = {
        "method": "ho-kalman",
        "singular_values": s.tolist(),
        "order": n,
        "original_order": ss.nx,
        "depth": [int(d) for d in used_depth],
        "ranks": {"observability": numerical_rank(np.linalg.svd(R_O, compute_uv=False), tol),
                  "reachability": numerical_rank(np.linalg.svd(R_R, compute_uv=False), tol),
                  "hankel": selection["rank"]},
        "scaling": scaling,
        "selection": {k: v for k, v in selection.items() if k != "order"},
    }
    return LPVSS(
        T_left @ ss.A @ T, T_left @ ss.B, ss.C @ T, ss.D.copy(), ss.basis, ss.Ts,
        K=None if ss.K is None else T_left @ ss.K, u_names=list(ss.u_names), y_names=list(ss.y_names),
        p_names=list(ss.p_names), io=ss.io, reduction=record,
    )


def plot_singular_values(record: dict, path: str | os.PathLike) -> Path:
    """Write a PNG of a reduction record's singular values (log scale), marking the chosen order."""
    from matplotlib.figure import Figure

    if "singular_values" not in record or "order" not in record:
        raise ModelError("not a reduction record: it lacks 'singular_values' or 'order'")
    s = np.asarray(record["singular_values"], dtype=float)
    sel = record.get("selection", {})
    floor = sel.get("tol", 1e-16) * s[0]
    fig = Figure(figsize=(5.0, 3.2), layout="constrained")
    ax = fig.add_subplot()
    idx = np.arange(1, len(s) + 1)
    ax.semilogy(idx, np.maximum(s, floor), "o-", color="C0", label="singular values")
    ax.axvline(record["order"] + 0.5, color="C3", ls="--", label=f"order {record['order']}")
    if "gap" in sel:
        ax.axvline(sel["gap"] + 0.5, color="C2", ls=":", label=f"largest gap {sel['gap']}")
    if "energy" in sel:
        ax.axvline(sel["energy"] + 0.5, color="C1", ls="-.",
                   label=f"{100 * sel['energy_threshold']:g} % energy {sel['energy']}")
    ax.set_xlabel("index")
    ax.set_ylabel("σ")
    ax.set_title(f"{record.get('method', 'reduction')}: singular values")
    ax.set_xticks(idx)
    ax.legend(fontsize="small")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path


#: How much a reduced model's frozen spectral radius may exceed the full model's.
RADIUS_TOLERANCE = 1e-3


def max_frozen_radius(model: LPVSS, points: int = 9) -> float:
    """Largest spectral radius of A(θ) on a grid of ``points`` values along the diagonal of the recorded
    scheduling box."""
    lo, hi = np.asarray(model.basis.p_min), np.asarray(model.basis.p_max)
    grid = lo + np.linspace(0, 1, points)[:, None] * (hi - lo)
    return float(max(np.max(np.abs(np.linalg.eigvals(model.matrices(p)[0]))) for p in grid))


def reduce_keeping_radius(ss: LPVSS, order: int | None) -> tuple[LPVSS, str]:
    """:func:`reduce` to ``order``, or (None) to the singular-value order raised until the reduced
    model's largest frozen spectral radius exceeds the full model's by at most :data:`RADIUS_TOLERANCE`
    (the reduction does not preserve stability: no spurious unstable mode); the reduced model and the
    rule that chose its order."""
    reduced = reduce(ss, order=order)
    if order is not None:
        return reduced, "given"
    rule = "singular values"
    limit = max_frozen_radius(ss) + RADIUS_TOLERANCE
    while reduced.nx < ss.nx and max_frozen_radius(reduced) > limit:
        reduced = reduce(ss, order=reduced.nx + 1)
        rule = "raised until the frozen spectral radius matches the full model's"
    return reduced, rule
