"""Exact realization of LPR (shifted-form) input-output models as observable-form LPVSS.

Thesis Sec. 5.4: for the left matrix fraction H = Ã⁻¹(q,θ) B̃(q,θ) in LPR with
row degrees n_i and 𝒜_h = I,

    Ã(q,θ) = Λ̃(q) + S̆(q) 𝒜_l(θ(k)),        B̃(q,θ) = Λ̃(q) D + S̆(q) ℬ_l(θ(k)),

the realization (5.24)–(5.26), extended with a constant feed-through D and an innovation input e
with lag-0 coefficient I (Schulz et al. eq. (4)), is

    A(θ) = Ā_o − 𝒜_l(θ) C̄_o,    B(θ) = ℬ_l(θ) − 𝒜_l(θ) D,    K(θ) = 𝒞_l(θ) − 𝒜_l(θ),
    C = C̄_o,                     D,

with Ā_o = blockdiag(shift matrices of size n_i) (ones on the sub-diagonal) and
C̄_o = blockdiag([0 … 0 1]). Every matrix is affine in ψ(p(k)); nothing depends on p(k±j).
For a SISO model this is thesis (5.17)/(5.36).

The identified shifted-form equation r, y_r(k) + Σ_i A_i(ψ(k−i))[r,:] y(k−i) = Σ_j B_j(ψ(k−j))[r,:] u(k−j),
multiplied by q^{n_r}, gives the coefficient of q^m (m = 0 … n_r−1) as the lag-(n_r − m) coefficient:
𝒜_l[r-block, m] = A_{n_r−m}[r, :], ℬ_l[r-block, m] = B_{n_r−m}[r, :].
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS

if TYPE_CHECKING:  # realize_io is LPVIO.to_ss; the LPVIO module imports this one
    from lpvflow.lpvio import LPVIO


def observable_form(
    row_degrees: list[int], Al: np.ndarray, Bl: np.ndarray, D: np.ndarray, basis: Basis, Ts: float,
    Kl: np.ndarray | None = None, **names: list[str],
) -> LPVSS:
    """The observable-form LPVSS (5.24)–(5.26) from the LFD coefficients of an LPR model.

    Args:
        row_degrees: n_i, the degree of row i of Ã (the state order is Σ n_i).
        Al: (n_psi, n, ny) basis components of 𝒜_l (row block i, row m: coefficient of q^m in Ã_i).
        Bl: (n_psi, n, nu) basis components of ℬ_l, same layout.
        D: (ny, nu) constant feed-through (coefficient of q^{n_i} in B̃_i).
        Kl: (n_psi, n, ny) components of 𝒞_l for an ARMAX noise polynomial, or None.
    """
    n = int(sum(row_degrees))
    n_psi = basis.n_psi
    ny, nu = len(row_degrees), Bl.shape[2]
    if Al.shape != (n_psi, n, ny) or Bl.shape != (n_psi, n, nu) or np.shape(D) != (ny, nu):
        raise ModelError("LFD coefficient shapes do not match the row degrees")
    if min(row_degrees) < 1:
        raise ModelError(f"every output needs at least one state (row degrees {row_degrees})")
    ends = np.cumsum(row_degrees) - 1
    shift = np.zeros((n, n))
    for start, size in zip(ends - np.asarray(row_degrees) + 1, row_degrees, strict=True):
        shift[start + 1 : start + size, start : start + size - 1] += np.eye(size - 1)
    Cbar = np.zeros((ny, n))
    Cbar[np.arange(ny), ends] = 1.0

    A = -np.einsum("lnr,rs->lns", Al, Cbar)
    A[0] += shift
    B = Bl - np.einsum("lnr,rj->lnj", Al, D)
    C = np.zeros((n_psi, ny, n))
    C[0] = Cbar
    Dm = np.zeros((n_psi, ny, nu))
    Dm[0] = D
    K = None if Kl is None else Kl - Al
    return LPVSS(A, B, C, Dm, basis, Ts, K=K, **names)


def realize_io(io: LPVIO) -> LPVSS:
    """Realize a shifted-form LPVIO exactly (see module docstring); refuses the static form."""
    if io.form != "shifted":
        raise ModelError(
            "a static-dependence (Bamieh–Giarré) LPV-ARX has no realization with static dependence "
            "(thesis §5.2, Example 5.1); identify it in shifted (LPR) form instead"
        )
    if np.any(io.B[:1, 1:]):
        raise ModelError(
            "the lag-0 input coefficient depends on p: its realization would be quadratic in ψ; "
            "use nk >= 1 or a constant feed-through"
        )
    ny, nu, n_psi = io.ny, io.nu, io.basis.n_psi
    row_degrees = []
    for r in range(ny):
        lags = [i + 1 for i in range(io.A.shape[0]) if np.any(io.A[i, :, r, :])]
        lags += [j for j in range(1, io.B.shape[0]) if np.any(io.B[j, :, r, :])]
        lags += [m + 1 for m in range(io.C.shape[0]) if np.any(io.C[m, :, r, :])]
        if io.na is not None:
            lags.append(int(np.max(io.na[r])))
        row_degrees.append(max([*lags, 1]))
    n = sum(row_degrees)
    Al = np.zeros((n_psi, n, ny))
    Bl = np.zeros((n_psi, n, nu))
    Kl = np.zeros((n_psi, n, ny)) if io.C.shape[0] else None
    offset = 0
    for r, n_r in enumerate(row_degrees):
        for m in range(n_r):
            lag = n_r - m
            if lag <= io.A.shape[0]:
                Al[:, offset + m, :] = io.A[lag - 1, :, r, :]
            if lag < io.B.shape[0]:
                Bl[:, offset + m, :] = io.B[lag, :, r, :]
            if Kl is not None and lag <= io.C.shape[0]:
                Kl[:, offset + m, :] = io.C[lag - 1, :, r, :]
        offset += n_r
    ss = observable_form(row_degrees, Al, Bl, io.B[0, 0], io.basis, io.Ts, Kl=Kl,
                         u_names=io.u_names, y_names=io.y_names, p_names=io.p_names)
    ss.io = io
    return ss


def integrate_outputs(ss: LPVSS, outputs: list[str]) -> LPVSS:
    """The model of y from a model ``ss`` whose outputs ``outputs`` are increments w_j(k) = y_j(k) − y_j(k−1).

    With one extra state s_j(k) = y_j(k−1) per integrated output (J the rows of ``outputs``, E_J the
    columns that put s_j into row j), y_j(k) = s_j(k) + w_j(k) and s_j(k+1) = y_j(k) give

        [x; s](k+1) = [[A(θ), 0], [C_J(θ), I]] [x; s](k) + [B(θ); D_J(θ)] u(k),
        y(k)        = [C(θ), E_J] [x; s](k) + D(θ) u(k),

    affine in ψ(p(k)) like ``ss`` (the identity blocks are the ψ_0 = 1 component). The frozen transfer
    function of row j is that of ``ss`` divided by (1 − q⁻¹); the other rows are unchanged. The
    innovation gain K, if any, is dropped (the increments' noise model is not y's); ``io`` too.
    """
    missing = [name for name in outputs if name not in ss.y_names]
    if missing:
        raise ModelError(f"cannot integrate {missing}: the model's outputs are {ss.y_names}")
    rows = [ss.y_names.index(name) for name in outputs]
    n_psi, nx, nj = ss.A.shape[0], ss.nx, len(rows)
    A = np.zeros((n_psi, nx + nj, nx + nj))
    A[:, :nx, :nx] = ss.A
    A[:, nx:, :nx] = ss.C[:, rows, :]
    A[0, nx:, nx:] = np.eye(nj)
    B = np.concatenate([ss.B, ss.D[:, rows, :]], axis=1)
    C = np.zeros((n_psi, ss.ny, nx + nj))
    C[:, :, :nx] = ss.C
    C[0, rows, nx + np.arange(nj)] = 1.0
    return LPVSS(A, B, C, ss.D.copy(), ss.basis, ss.Ts, u_names=list(ss.u_names), y_names=list(ss.y_names),
                 p_names=list(ss.p_names))
