"""LPV-ARX with cubic-spline scheduling dependence whose knots are estimated (thesis Ch. 3, §3.2–3.3).

Every coefficient is a cubic spline in the truncated-power form (thesis (3.13)–(3.14))

    ψ(p) = [1, p, |p − η_1|³, …, |p − η_K|³]      (per scheduling signal; knots shared by all
                                                    coefficients)

so the model is linear in the coefficients 𝔓 and nonlinear in the knots η. Separable least
squares (Golub–Pereyra; thesis Theorem 3.1) eliminates 𝔓: for fixed η, 𝔓̂(η) = Φ(η)⁺Y (3.17) and
the knots minimise the reduced cost (3.18)

    V(η) = 1/(2N) ‖(I − Φ(η)Φ(η)⁺) Y‖²_F.

Batch variant (:func:`fit_spline_knots`, thesis (3.19)–(3.23)): Levenberg–Marquardt on η,

    η ← η − (J_Sᵀ J_S + μ s I)⁻¹ J_Sᵀ E,    J_S = (I − Ξ) J_NL    (Kaufman's projected Jacobian),

with E the stacked residuals, Ξ = QQᵀ the projector onto range Φ (from the QR of Φ, never formed
as an N×N matrix) and J_NL = ∂E/∂η at fixed 𝔓, computed analytically from
∂|p − η|³/∂η = −3(p − η)|p − η|. μ follows the thesis schedule (μ₀ = 0.01,
γ = 10: divide on success, multiply and retry on failure); s = mean diag(J_SᵀJ_S) makes μ
dimensionless [our choice]. Knots are handled in units of the scheduling range, kept inside the
data range and strictly ordered after every step (a rejected or clipped step is simply a trial
point). Several starts (data quantiles, then uniform random draws); the lowest cost wins.

Recursive variant (``recursive=True``, thesis §3.3.2, Algorithm 3.1), with two corrections:
the update (3.29a) takes the descent sign, η ← η − R⁻¹ J̃ᵀ ε with J̃ = ∂ε/∂η. The
per-sample projection (3.30) is degenerate (I − Ξ̃ = 0 once n_y < n_𝔓), so the projection is
applied to the *accumulated* information instead: with M(k) = λ M(k−1) + G(k)ᵀG(k), where G(k) is
the Jacobian of ŷ(k) with respect to [𝔓; η], the Kaufman Hessian J_Sᵀ J_S of the λ-weighted batch
is the Schur complement R = M_ηη − M_η𝔓 M_𝔓𝔓⁻¹ M_𝔓η, and 𝔓 is the λ-weighted least-squares
solution M_𝔓𝔓⁻¹ b_𝔓. The gradient needs no projection (at 𝔓̂ the 𝔓-gradient vanishes). The
recursion runs ``passes`` times over the data with μ·s·I added to R (3.29b); the accept/reject
test of Algorithm 3.1 on the recursive cost is replaced by keeping the end-of-pass knots with the
lowest batch cost. The final 𝔓 of both variants is the batch LS fit of :func:`identify_arx`.

Works for the shifted (LPR) and static forms and MIMO models (outputs with equal regressors are
solved together, as in :func:`identify_arx`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.arx import RegressorColumn, fill_regressor, identify_arx, order_matrix, row_columns
from lpvflow.lpvio import LPVIO

#: Levenberg–Marquardt schedule (thesis §3.3.1): initial damping and its growth/shrink factor.
MU0, GAMMA = 0.01, 10.0
#: Smallest distance between two knots, and between a knot and nothing, in units of the range.
MIN_SEPARATION = 1e-3
#: Largest knot move of one recursive update, in units of the scheduling range.
MAX_STEP = 0.01
#: Relative diagonal of R below which Φ(η) counts as rank deficient (cost = +inf for that η).
RANK_TOL = 1e-10


@dataclass(frozen=True)
class KnotFit:
    """Result of the knot search: knots per scheduling signal, reduced cost V(η), diagnostics."""

    knots: tuple[tuple[float, ...], ...]
    cost: float
    iterations: int
    start_costs: tuple[float, ...]


@dataclass(frozen=True)
class _Slot:
    """Knot j of scheduling signal i, which is basis column ``psi``."""

    signal: int
    psi: int


class SeparableProblem:
    """Reduced cost V(η) and Kaufman Jacobian of an LPV-ARX with a spline basis, knots η free.

    Knots enter as z ∈ [0, 1]^(n_p·K): η = p_min + z (p_max − p_min) per scheduling signal.
    """

    def __init__(self, data: Dataset, na, nb, nk, n_knots: int, form: str) -> None:
        if form not in ("shifted", "static"):
            raise DataError(f"form must be 'shifted' or 'static', got {form!r}")
        if int(n_knots) != n_knots or n_knots < 1:
            raise DataError(f"n_knots must be a whole number >= 1, got {n_knots}")
        ny, nu, n_p = data.y.shape[1], data.u.shape[1], data.p.shape[1]
        self.data, self.n_knots, self.shifted = data, int(n_knots), form == "shifted"
        self.na = order_matrix("na", na, (ny, ny), 0)
        self.nb = order_matrix("nb", nb, (ny, nu), 0)
        self.nk = order_matrix("nk", nk, (ny, nu), 0)
        self.lo, self.hi = data.p.min(axis=0), data.p.max(axis=0)
        flat = [data.p_names[i] for i in range(n_p) if not self.hi[i] > self.lo[i]]
        if flat:
            raise DataError(f"scheduling signal {flat[0]!r} is constant: knots need a range to lie in")
        self.span = self.hi - self.lo
        n_psi = 1 + n_p * (1 + self.n_knots)
        self.slots = [_Slot(i, 1 + i * (1 + self.n_knots) + 1 + j)
                      for i in range(n_p) for j in range(self.n_knots)]
        self.max_lag = int(max(self.na.max(initial=0), (self.nk + self.nb - 1)[self.nb > 0].max(initial=0)))
        row_cols = [row_columns(r, self.na, self.nb, self.nk, n_psi, self.shifted) for r in range(ny)]
        n_max = max(len(c) for c in row_cols)
        if n_max == 0:
            raise DataError("the model has no parameters: raise na or nb")
        data.require_samples(self.max_lag + n_max,
                             f"{n_max} parameters per output with lags up to {self.max_lag}")
        groups: dict[tuple[RegressorColumn, ...], list[int]] = {}
        for r, cols in enumerate(row_cols):
            groups.setdefault(tuple(cols), []).append(r)
        self.groups = [(list(cols), outputs) for cols, outputs in groups.items()]
        self.row_cols = row_cols
        self.n_eff = data.N - self.max_lag

    # ------------------------------------------------------------------ knots <-> unit coordinates
    def knots(self, z: np.ndarray) -> list[list[float]]:
        """Knots η per scheduling signal from unit coordinates z."""
        z = np.asarray(z).reshape(len(self.lo), self.n_knots)
        return [list(self.lo[i] + z[i] * self.span[i]) for i in range(len(self.lo))]

    def unit(self, knots: list[list[float]]) -> np.ndarray:
        """Unit coordinates z of knots given per scheduling signal."""
        return np.concatenate([(np.asarray(k, float) - self.lo[i]) / self.span[i]
                               for i, k in enumerate(knots)])

    def admissible(self, z: np.ndarray) -> np.ndarray:
        """z clipped into [0, 1], sorted per signal and spread to MIN_SEPARATION (inside the range)."""
        z = np.clip(np.sort(np.asarray(z, float).reshape(len(self.lo), self.n_knots), axis=1), 0.0, 1.0)
        sep = min(MIN_SEPARATION, 1.0 / (self.n_knots + 1))
        for row in z:
            for j in range(1, len(row)):
                row[j] = max(row[j], row[j - 1] + sep)
            row[-1] = min(row[-1], 1.0)
            for j in range(len(row) - 2, -1, -1):
                row[j] = min(row[j], row[j + 1] - sep)
        return z.ravel()

    # -------------------------------------------------------------------------- basis evaluation
    def basis(self, z: np.ndarray) -> Basis:
        return Basis.spline(self.knots(z), len(self.lo))

    def psi_derivative(self, p: np.ndarray, z: np.ndarray, m: int) -> np.ndarray:
        """∂ψ/∂z_m (rows of p): only column ``slots[m].psi`` is non-zero, −3(p−η)|p−η|·span."""
        slot = self.slots[m]
        eta = self.knots(z)[slot.signal][m % self.n_knots]
        d = np.zeros((len(p), 1 + len(self.lo) * (1 + self.n_knots)))
        diff = p[:, slot.signal] - eta
        d[:, slot.psi] = -3.0 * diff * np.abs(diff) * self.span[slot.signal]
        return d

    # ------------------------------------------------------------------ reduced cost and Jacobian
    def residuals(self, z: np.ndarray, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Stacked residuals E(η) = (I − ΦΦ⁺)Y (n_eff·ny) and Kaufman's J_S = (I − QQᵀ) J_NL.

        Returns E = +inf everywhere when Φ(η) is rank deficient (coincident knots).
        """
        data, k0, k1 = self.data, self.max_lag, self.data.N
        psi = self.basis(z).eval(data.p, check_range=False)
        E = np.empty((self.n_eff, data.y.shape[1]))
        J = np.zeros((self.n_eff, data.y.shape[1], len(self.slots))) if jacobian else None
        for cols, outputs in self.groups:
            phi = np.empty((self.n_eff, len(cols)))
            fill_regressor(phi, cols, data.y, data.u, psi, k0, k1, 0, self.shifted)
            Q, R = scipy.linalg.qr(phi, mode="economic", check_finite=False)
            diag = np.abs(np.diag(R))
            if diag.min() <= RANK_TOL * diag.max():
                return np.full(E.size, np.inf), None if J is None else J.reshape(E.size, -1)
            Y = data.y[k0:k1, outputs]
            QtY = Q.T @ Y
            E[:, outputs] = Y - Q @ QtY
            if J is None:
                continue
            theta = scipy.linalg.solve_triangular(R, QtY)
            for m, slot in enumerate(self.slots):
                idx = [c for c, col in enumerate(cols) if col.psi == slot.psi]
                if not idx:
                    continue
                dphi = np.empty((self.n_eff, len(idx)))
                fill_regressor(dphi, [cols[c] for c in idx], data.y, data.u,
                                self.psi_derivative(data.p, z, m), k0, k1, 0, self.shifted)
                j_nl = -dphi @ theta[idx]  # ∂E/∂z_m at fixed 𝔓, one column per output of the group
                J[:, outputs, m] = j_nl - Q @ (Q.T @ j_nl)
        return E.ravel(), None if J is None else J.reshape(E.size, -1)

    def cost(self, z: np.ndarray) -> float:
        """Reduced cost V(η) = 1/(2N) ‖E‖² (thesis (3.18))."""
        E, _ = self.residuals(z, jacobian=False)
        return float(E @ E) / (2 * self.n_eff)


def _levenberg_marquardt(problem: SeparableProblem, z: np.ndarray, max_iter: int, tol: float
                         ) -> tuple[np.ndarray, float, int]:
    """Minimise V(η) from z by the projected-Jacobian LM of thesis (3.21)–(3.23)."""
    z = problem.admissible(z)
    E, J = problem.residuals(z)
    V = float(E @ E) / (2 * problem.n_eff)
    if not np.isfinite(V):
        return z, V, 0
    mu = MU0
    for it in range(1, max_iter + 1):
        if V <= np.finfo(float).tiny:
            return z, V, it - 1
        g, H = J.T @ E, J.T @ J
        scale = max(float(np.mean(np.diag(H))), np.finfo(float).tiny)
        while mu < 1e12:
            z_new = problem.admissible(z - np.linalg.solve(H + mu * scale * np.eye(len(z)), g))
            E_new, J_new = problem.residuals(z_new)
            V_new = float(E_new @ E_new) / (2 * problem.n_eff)
            if V_new < V:
                mu = max(mu / GAMMA, 1e-12)
                break
            mu *= GAMMA
        else:
            return z, V, it
        done = V - V_new <= tol * V or np.max(np.abs(z_new - z)) < 1e-12
        z, E, J, V = z_new, E_new, J_new, V_new
        if done:
            return z, V, it
    return z, V, max_iter


def _recursive_lm(problem: SeparableProblem, z: np.ndarray, forgetting: float, passes: int
                  ) -> tuple[np.ndarray, float, int]:
    """Recursive LM on the knots (thesis Algorithm 3.1, corrected as in the module docstring).

    Each pass over the data is one LM trial that starts afresh (no information) from the accepted
    knots: if it lowers the batch cost V(η) its end knots are accepted and μ ← μ/γ, otherwise they
    are discarded and μ ← γμ. (Carrying the information across passes diverged in our tests: it
    mixes regressors evaluated at knots far apart.)
    """
    data, L = problem.data, problem.max_lag
    ny = data.y.shape[1]
    offsets = np.cumsum([0] + [len(c) for c in problem.row_cols])
    n_lin, n_eta = int(offsets[-1]), len(problem.slots)
    lin, eta = slice(0, n_lin), slice(n_lin, n_lin + n_eta)
    knot_columns = [[[c for c, col in enumerate(cols) if col.psi == slot.psi] for slot in problem.slots]
                    for cols in problem.row_cols]
    z = problem.admissible(z)
    V, mu = problem.cost(z), MU0
    G = np.zeros((ny, n_lin + n_eta))
    z_best = z
    for _ in range(passes):
        z = z_best
        M, b, theta = 1e-6 * np.eye(n_lin + n_eta), np.zeros(n_lin), np.zeros(n_lin)
        for k in range(L, data.N):
            window = data.p[k - L : k + 1]
            psi = problem.basis(z).eval(window, check_range=False)
            dpsi = [problem.psi_derivative(window, z, m) for m in range(n_eta)]
            G[:] = 0.0
            for r, cols in enumerate(problem.row_cols):
                block = slice(offsets[r], offsets[r + 1])
                fill_regressor(G[r : r + 1, block], cols, data.y, data.u, psi, k, k + 1, k - L,
                                problem.shifted)
                for m, idx in enumerate(knot_columns[r]):
                    if idx:
                        row = np.empty((1, len(idx)))
                        fill_regressor(row, [cols[c] for c in idx], data.y, data.u, dpsi[m], k, k + 1, k - L,
                                        problem.shifted)
                        G[r, n_lin + m] = row[0] @ theta[offsets[r] + np.asarray(idx)]
            eps = data.y[k] - np.array([G[r, offsets[r] : offsets[r + 1]] @ theta[offsets[r] : offsets[r + 1]]
                                        for r in range(ny)])
            M *= forgetting
            M += G.T @ G
            b *= forgetting
            b += G[:, lin].T @ data.y[k]
            coupling = np.linalg.solve(M[lin, lin], np.column_stack([b, M[lin, eta]]))
            theta = coupling[:, 0]
            if k - L < 2 * n_lin:  # too little information yet for a knot step
                continue
            R = M[eta, eta] - M[eta, lin] @ coupling[:, 1:]
            scale = max(float(np.mean(np.diag(R))), np.finfo(float).tiny)
            # corrected (3.29a)/(3.30): J̃_S = −(G_η − G_𝔓 M_𝔓𝔓⁻¹ M_𝔓η) = ∂ε/∂η projected with the
            # accumulated information; descent step −(R + μsI)⁻¹ J̃_Sᵀ ε, at most MAX_STEP long
            projected = G[:, eta] - G[:, lin] @ coupling[:, 1:]
            step = np.linalg.solve(R + mu * scale * np.eye(n_eta), projected.T @ eps)
            z = problem.admissible(z + np.clip(step, -MAX_STEP, MAX_STEP))
        V_new = problem.cost(z)
        if V_new < V:
            z_best, V, mu = z, V_new, max(mu / GAMMA, 1e-12)
        else:
            mu *= GAMMA
    return z_best, V, passes


def fit_spline_knots(
    data: Dataset, na, nb, nk, n_knots: int, form: str = "shifted", starts: int = 5, seed: int = 0,
    recursive: bool = False, forgetting: float = 0.999, max_iter: int = 100, tol: float = 1e-10,
    passes: int = 2,
) -> KnotFit:
    """Estimate the spline knots of an LPV-ARX by separable least squares (module docstring).

    Start 0 puts the knots at the quantiles (j/(K+1)) of each scheduling signal; further starts draw
    them uniformly in the data range (``seed``). ``recursive`` selects the recursive variant with
    forgetting factor ``forgetting`` and ``passes`` sweeps over the data.
    """
    if int(starts) != starts or starts < 1:
        raise DataError(f"starts must be a whole number >= 1, got {starts}")
    if not 0 < forgetting <= 1:
        raise DataError(f"forgetting factor must be in (0, 1], got {forgetting}")
    problem = SeparableProblem(data, na, nb, nk, n_knots, form)
    rng = np.random.default_rng(seed)
    quantiles = np.arange(1, problem.n_knots + 1) / (problem.n_knots + 1)
    first = problem.unit([np.quantile(data.p[:, i], quantiles) for i in range(data.p.shape[1])])
    best, costs, iterations = None, [], 0
    for s in range(int(starts)):
        z0 = first if s == 0 else rng.uniform(0, 1, size=first.size)
        if recursive:
            z, V, it = _recursive_lm(problem, z0, forgetting, passes)
        else:
            z, V, it = _levenberg_marquardt(problem, z0, max_iter, tol)
        costs.append(V)
        iterations += it
        if np.isfinite(V) and (best is None or V < best[1]):
            best = (z, V)
    if best is None:
        raise DataError("every knot start gave a rank-deficient regressor: lower n_knots or excite more")
    knots = tuple(tuple(k) for k in problem.knots(best[0]))
    return KnotFit(knots, best[1], iterations, tuple(costs))


def free_knot_count(spec: str) -> int | None:
    """K from a basis spec ``spline:free:K`` (knots to estimate), or None for any other spec."""
    head, _, rest = spec.partition(":free:")
    if head != "spline" or not _:
        return None
    if not rest.isdigit() or int(rest) < 1:
        raise DataError(f"bad basis spec {spec!r}: use spline:free:K with a whole number K >= 1 of knots")
    return int(rest)


def identify_spline_sls(
    data: Dataset, na, nb, nk, n_knots: int, form: str = "shifted", starts: int = 5, seed: int = 0,
    recursive: bool = False, forgetting: float = 0.999,
) -> LPVIO:
    """LPV-ARX with a cubic-spline basis whose ``n_knots`` knots per scheduling signal are estimated.

    Knots from :func:`fit_spline_knots` (batch LM or, with ``recursive``, the recursive variant),
    coefficients from :func:`identify_arx` at those knots. Orders as in :func:`identify_arx`.
    """
    fit = fit_spline_knots(data, na, nb, nk, n_knots, form, starts, seed, recursive, forgetting)
    return identify_arx(data, na, nb, nk, Basis.spline([list(k) for k in fit.knots], data.p.shape[1]), form)
