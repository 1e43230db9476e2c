"""Instrumental-variable LPV identification: IV-ARX, IV-OE (thesis Ch. 4) and refined IV (LPV-RIV/SRIV).

All estimators share the LPV-ARX regression of :mod:`lpvflow.identify.arx` (shifted or static
form, SISO and MIMO): for output r, y_r(k) = φ_r(k)ᵀ θ_r + v_r(k), φ_r built from −y lags and u
lags, each multiplied by ψ. Least squares is biased when v is not white equation error (thesis
(4.17)–(4.18)). The IV estimate (thesis (4.27))

    θ̂_r = [Σ_k ζ_r(k) φ_r(k)ᵀ]⁻¹ Σ_k ζ_r(k) y_r(k)

is consistent when the instrument ζ_r is uncorrelated with v_r; ζ_r is the same regressor with y
replaced by the noise-free simulated output ŷ of an auxiliary model:

* :func:`identify_iv_arx` — auxiliary model from LS LPV-ARX (Butcher et al. 2008). MIMO.
* :func:`identify_iv_oe` — Algorithm 4.1: auxiliary LPV-OE model from the recursive output-error
  parameter adaptation algorithm (PAA, thesis (4.21)–(4.25) in the corrected Landau form,
  :func:`oe_paa`), or ``auxiliary="batch"``: batch pseudo-linear OE regression
  (:func:`oe_pseudolinear`), whose fixed point satisfies the same normal equations Φ̃ᵀ(y − ŷ) = 0.
  One IV solve, no iteration. MIMO.
* :func:`identify_riv` — refined IV of Laurain et al. (2010), quoted in thesis Table 4.4: the LPV
  model is an LTI MISO system A₀(q)χ = −Σ_{i,l≥1} a_{i,l} χ_{i,l} + Σ b_{j,l} u_{j,l} in the
  extended signals χ_{i,l}(k) = ψ_l · χ(k−i), so the LTI prefilter L(q) = D̂(q)/Â₀(q) (RIV, AR
  noise model D̂ estimated from y − χ̂) or 1/Â₀(q) (SRIV) whitens the equation error; iterated
  until θ̂ settles. SISO only.

Quasi-LPV scheduling (thesis §4.6): pass ``scheduling`` = a function mapping an output trajectory
(N, ny) to the scheduling signals (N, n_p); the IV step then evaluates ψ at the scheduling
recomputed from the auxiliary model's noise-free output.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
import scipy.linalg
import scipy.signal

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.identify.arx import RANK_TOL, RegressorColumn, fill_regressor, order_matrix, row_columns
from lpvflow.lpvio import LPVIO
from lpvflow.models import lagged_sum
from lpvflow.simulate import io_recursion

Scheduling = Callable[[np.ndarray], np.ndarray]
#: Relative condition threshold of the instrument–regressor correlation matrix (canonical
#: correlations, :func:`solve_instrumental`) below which the instruments are too weak.
IV_RCOND = 1e-12


@dataclass(frozen=True)
class Structure:
    """Orders, basis and form of an LPV-IO model, and the regressor columns of each output.

    ``columns[r]`` lists the parameters of output r in the order of :func:`identify_arx`
    (y lags then u lags, basis index fastest); a parameter vector θ_r follows that order.
    """

    na: np.ndarray
    nb: np.ndarray
    nk: np.ndarray
    basis: Basis
    form: str
    columns: tuple[tuple[RegressorColumn, ...], ...]
    max_lag: int
    Ts: float
    names: dict

    @property
    def shifted(self) -> bool:
        return self.form == "shifted"

    @property
    def ny(self) -> int:
        return self.na.shape[0]

    @property
    def nu(self) -> int:
        return self.nb.shape[1]

    @classmethod
    def from_data(cls, data: Dataset, na: int | np.ndarray, nb: int | np.ndarray, nk: int | np.ndarray,
                  basis: Basis | str, form: str) -> Structure:
        """Validate the orders against ``data`` exactly as :func:`identify_arx` does."""
        if form not in ("shifted", "static"):
            raise DataError(f"form must be 'shifted' or 'static', got {form!r}")
        ny, nu = data.y.shape[1], data.u.shape[1]
        basis = Basis.from_spec(basis, data.p.shape[1]) if isinstance(basis, str) else basis
        if basis.n_p != data.p.shape[1]:
            raise DataError(f"the basis is for {basis.n_p} scheduling signal(s), "
                            f"the data has {data.p.shape[1]}")
        basis = basis.with_range(data.p)
        na = order_matrix("na", na, (ny, ny), 0)
        nb = order_matrix("nb", nb, (ny, nu), 0)
        nk = order_matrix("nk", nk, (ny, nu), 0)
        shifted = form == "shifted"
        columns = tuple(tuple(row_columns(r, na, nb, nk, basis.n_psi, shifted)) for r in range(ny))
        max_lag = int(max(na.max(initial=0), (nk + nb - 1)[nb > 0].max(initial=0)))
        n_max = max(len(c) for c in columns)
        if n_max == 0:
            raise DataError("the model has no parameters: raise na or nb")
        data.require_samples(max_lag + n_max, f"{n_max} parameters per output with lags up to {max_lag}")
        names = {"u_names": data.u_names, "y_names": data.y_names, "p_names": data.p_names}
        return cls(na, nb, nk, basis, form, columns, max_lag, data.Ts, names)

    def regressor(self, r: int, y: np.ndarray, u: np.ndarray, psi: np.ndarray) -> np.ndarray:
        """Φ_r (N, n_r) for every sample k = 0…N−1 with zero past before k = 0.

        ``y`` plays the role of the output in the lags (measured, simulated or filtered).
        """
        n, pad = len(y), self.max_lag
        cols = list(self.columns[r])
        # F order: contiguous columns (numpy 2.4 in-place negative on strided views is wrong)
        out = np.empty((n, len(cols)), order="F")
        if not cols:
            return out
        ypad = np.vstack([np.zeros((pad, y.shape[1])), y])
        upad = np.vstack([np.zeros((pad, u.shape[1])), u])
        psipad = np.vstack([np.zeros((pad, psi.shape[1])), psi])
        fill_regressor(out, cols, ypad, upad, psipad, pad, pad + n, 0, self.shifted)
        return out

    def model(self, thetas: list[np.ndarray], C: np.ndarray | None = None) -> LPVIO:
        """The :class:`LPVIO` whose parameters of output r are ``thetas[r]``."""
        n_psi, ny, nu = self.basis.n_psi, self.ny, self.nu
        A = np.zeros((self.na.max(initial=0), n_psi, ny, ny))
        B = np.zeros((max(int((self.nk + self.nb - 1).max(initial=0)), 0) + 1, n_psi, ny, nu))
        for r, cols in enumerate(self.columns):
            for col, value in zip(cols, thetas[r], strict=True):
                if col.signal == "y":
                    A[col.lag - 1, col.psi, r, col.channel] = value
                else:
                    B[col.lag, col.psi, r, col.channel] = value
        return LPVIO(A, B, self.basis, self.Ts, C=C, form=self.form, na=self.na, nb=self.nb, nk=self.nk,
                     **self.names)

    def thetas(self, io: LPVIO) -> list[np.ndarray]:
        """Inverse of :meth:`model`: the parameter vector of each output."""
        out = []
        for r, cols in enumerate(self.columns):
            out.append(np.array([io.A[c.lag - 1, c.psi, r, c.channel] if c.signal == "y"
                                 else io.B[c.lag, c.psi, r, c.channel] for c in cols]))
        return out


def parameter_vector(io: LPVIO) -> np.ndarray:
    """All free A/B parameters of ``io`` in regressor order (output by output), e.g. for Monte Carlo.

    For the thesis Ch. 4 system this is [a_{1,0..2}, a_{2,0..2}, b_{0,0..2}, b_{1,0..2}].
    """
    na = io.na if io.na is not None else np.full((io.ny, io.ny), io.A.shape[0])
    nb = io.nb if io.nb is not None else np.full((io.ny, io.nu), io.B.shape[0])
    nk = io.nk if io.nk is not None else np.zeros((io.ny, io.nu), dtype=int)
    shifted = io.form == "shifted"
    parts = []
    for r in range(io.ny):
        for c in row_columns(r, np.asarray(na), np.asarray(nb), np.asarray(nk), io.basis.n_psi, shifted):
            parts.append(io.A[c.lag - 1, c.psi, r, c.channel] if c.signal == "y"
                         else io.B[c.lag, c.psi, r, c.channel])
    return np.asarray(parts)


def simulate_psi(io: LPVIO, u: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Noise-free simulated output of ``io`` for given basis values ψ (N, n_psi), zero initial past."""
    forced = lagged_sum(psi, io.B, u, io.form == "shifted")
    return io_recursion(forced, psi, io.A, io.form == "shifted")


def least_squares_thetas(struct: Structure, data: Dataset, psi: np.ndarray) -> list[np.ndarray]:
    """Per-output LS estimates on the measured data (thesis (3.9)); rows k ≥ max lag."""
    start = struct.max_lag
    out = []
    for r in range(struct.ny):
        phi = struct.regressor(r, data.y, data.u, psi)[start:]
        out.append(solve_instrumental(phi, phi, data.y[start:, r]))
    return out


def solve_instrumental(zeta: np.ndarray, phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """θ = (ζᵀφ)⁻¹ ζᵀ y, refusing weak instruments or a rank-deficient regressor with one line.

    Solved through the QR factors of the column-scaled ζ = Q_ζ R_ζ and φ = Q_φ R_φ: ζᵀφ =
    R_ζᵀ C R_φ with C = Q_ζᵀ Q_φ, whose singular values are the canonical correlations between the
    instruments and the regressors (the IV estimate needs ζᵀφ of full rank: Söderström & Stoica,
    *System Identification*, 1989, Sec. 8.2), so θ = R_φ⁻¹ C⁻¹ Q_ζᵀ y. Refused when R_φ or R_ζ is
    rank deficient (relative singular value ≤ RANK_TOL, the test of :func:`identify_arx`) or the
    instruments miss a direction of the regressors (C's condition ≤ IV_RCOND). Testing ζᵀφ's
    condition instead counts the regressor's own collinearity twice: maglev FMU, poly:2 in a
    position of 0.08 ± 0.0045 m, cond(φ) ≈ 10⁶ — ζᵀφ looked singular (rcond 5·10⁻¹³) while the
    canonical correlations were 0.57–1.00. Solving the normal equations ζᵀφ θ = ζᵀy loses those
    digits twice too: 3 % error at cond(φ) = 3·10⁶ against 10⁻⁶ here (tests/test_iv.py).
    """
    if phi.shape[1] == 0:
        return np.zeros(0)
    # Columns scaled to unit norm first: the rank tests then judge the excitation, not the units.
    d_zeta, d_phi = _column_scale(zeta), _column_scale(phi)
    q_zeta, r_zeta = scipy.linalg.qr(zeta * d_zeta, mode="economic", check_finite=False)
    q_phi, r_phi = scipy.linalg.qr(phi * d_phi, mode="economic", check_finite=False)
    c = q_zeta.T @ q_phi
    for m, tol in ((r_phi, RANK_TOL), (r_zeta, RANK_TOL), (c, IV_RCOND)):
        s = np.linalg.svd(m, compute_uv=False)
        if not np.isfinite(s).all() or s[-1] <= tol * s[0]:
            raise DataError("the instrument matrix is singular: the data do not excite every coefficient; "
                            "lower the orders or basis degree, or excite more")
    return d_phi * scipy.linalg.solve_triangular(r_phi, np.linalg.solve(c, q_zeta.T @ y))


def _column_scale(x: np.ndarray) -> np.ndarray:
    """1 / column norm (1 for an all-zero column, which the condition test then rejects)."""
    norms = np.linalg.norm(x, axis=0)
    return np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)


def iv_thetas(struct: Structure, data: Dataset, y_aux: np.ndarray, psi: np.ndarray,
              psi_aux: np.ndarray | None = None) -> list[np.ndarray]:
    """One IV solve (thesis (4.27)): φ from measured y, ζ from the noise-free auxiliary output y_aux.

    ``psi_aux`` (quasi-LPV) replaces ψ in both φ and ζ when given.
    """
    start = struct.max_lag
    psi_iv = psi if psi_aux is None else psi_aux
    out = []
    for r in range(struct.ny):
        phi = struct.regressor(r, data.y, data.u, psi_iv)[start:]
        zeta = struct.regressor(r, y_aux, data.u, psi_iv)[start:]
        out.append(solve_instrumental(zeta, phi, data.y[start:, r]))
    return out


def _noise_free_output(io: LPVIO, data: Dataset, psi: np.ndarray, scheduling: Scheduling | None,
                       sweeps: int = 3) -> tuple[np.ndarray, np.ndarray | None]:
    """Simulated auxiliary output, and (quasi-LPV) ψ recomputed from it by fixed-point sweeps."""
    y_aux = simulate_psi(io, data.u, psi)
    if scheduling is None:
        return y_aux, None
    for _ in range(sweeps):
        psi_aux = io.basis.eval(_checked_scheduling(scheduling, y_aux, data), check_range=False)
        y_aux = simulate_psi(io, data.u, psi_aux)
    return y_aux, io.basis.eval(_checked_scheduling(scheduling, y_aux, data), check_range=False)


def _checked_scheduling(scheduling: Scheduling, y: np.ndarray, data: Dataset) -> np.ndarray:
    p = np.asarray(scheduling(y), dtype=float).reshape(data.N, -1)
    if p.shape != data.p.shape or not np.isfinite(p).all():
        raise DataError(f"scheduling(y) must return finite values of shape {data.p.shape}, got {p.shape}")
    return p


#: A simulated output this many times larger than the measured one counts as diverged.
DIVERGENCE_FACTOR = 1e4


def _is_bounded(y_sim: np.ndarray, data: Dataset) -> bool:
    """True when the simulation stayed finite and within DIVERGENCE_FACTOR of the data's scale."""
    scale = DIVERGENCE_FACTOR * max(float(np.abs(data.y).max()), 1e-300)
    return bool(np.isfinite(y_sim).all() and np.abs(y_sim).max(initial=0.0) <= scale)


def _check_bounded(y_aux: np.ndarray, data: Dataset, what: str) -> None:
    if not _is_bounded(y_aux, data):
        raise ModelError(f"the {what} auxiliary model is unstable on these data; lower the orders, "
                         "or use auxiliary='batch'/another method")


# ================================================================================= IV-ARX
def identify_iv_arx(data: Dataset, na: int | np.ndarray, nb: int | np.ndarray, nk: int | np.ndarray,
                    basis: Basis | str = "affine", form: str = "shifted",
                    scheduling: Scheduling | None = None) -> LPVIO:
    """IV-ARX: instruments from the simulated output of the LS LPV-ARX model (Butcher et al. 2008).

    SISO and MIMO; shifted or static form. See the module docstring for ``scheduling``.
    """
    struct = Structure.from_data(data, na, nb, nk, basis, form)
    psi = struct.basis.eval(data.p, check_range=False)
    aux = struct.model(least_squares_thetas(struct, data, psi))
    y_aux, psi_aux = _noise_free_output(aux, data, psi, scheduling)
    _check_bounded(y_aux, data, "LS-ARX")
    return struct.model(iv_thetas(struct, data, y_aux, psi, psi_aux))


# =================================================================== OE auxiliary models
def _column_table(struct: Structure) -> tuple[np.ndarray, np.ndarray]:
    """Int table (ny, n_max, 4) of (is_input, channel, lag, basis index) and column counts (ny,)."""
    counts = np.array([len(c) for c in struct.columns], dtype=np.int64)
    table = np.zeros((struct.ny, max(counts.max(), 1), 4), dtype=np.int64)
    for r, cols in enumerate(struct.columns):
        for i, c in enumerate(cols):
            table[r, i] = (c.signal == "u", c.channel, c.lag, c.psi)
    return table, counts


@numba.njit(cache=True)
def _paa_pass(y: np.ndarray, u: np.ndarray, psi: np.ndarray, table: np.ndarray, counts: np.ndarray,
              theta: np.ndarray, F: np.ndarray, lam1: float, lam2: float, shifted: bool) -> np.ndarray:
    """One pass of the output-error PAA over the data; updates theta, F in place, returns a posteriori ŷ.

    For each k and output r (Landau form):
      φ̃(k) from −ŷ(k−i), u(k−j) times ψ;  ε°(k) = y(k) − φ̃ᵀθ̂(k−1);
      ε(k) = ε°(k)/(1 + φ̃ᵀFφ̃);  θ̂(k) = θ̂(k−1) + F φ̃ ε(k);
      F ← (F − Fφ̃φ̃ᵀF/(λ₁/λ₂ + φ̃ᵀFφ̃))/λ₁;  ŷ(k) = φ̃ᵀθ̂(k) (a posteriori, fed back).
    """
    n, ny = y.shape
    yhat = np.zeros((n, ny))
    n_max = table.shape[1]
    phi = np.zeros(n_max)
    fphi = np.zeros(n_max)
    for k in range(n):
        for r in range(ny):
            m = counts[r]
            for i in range(m):
                is_u, ch, lag, b = table[r, i, 0], table[r, i, 1], table[r, i, 2], table[r, i, 3]
                t = k - lag
                if t < 0:
                    phi[i] = 0.0
                    continue
                w = psi[t, b] if shifted else psi[k, b]
                phi[i] = w * u[t, ch] if is_u == 1 else -w * yhat[t, ch]
            prior = 0.0
            for i in range(m):
                prior += phi[i] * theta[r, i]
            s = 0.0
            for i in range(m):
                acc = 0.0
                for j in range(m):
                    acc += F[r, i, j] * phi[j]
                fphi[i] = acc
                s += phi[i] * acc
            eps = (y[k, r] - prior) / (1.0 + s)
            post = prior
            for i in range(m):
                theta[r, i] += fphi[i] * eps
                post += phi[i] * fphi[i] * eps
            yhat[k, r] = post
            denom = lam1 / lam2 + s
            for i in range(m):
                for j in range(m):
                    F[r, i, j] = (F[r, i, j] - fphi[i] * fphi[j] / denom) / lam1
    return yhat


def oe_paa(struct: Structure, data: Dataset, psi: np.ndarray, passes: int = 3, f0: float = 100.0,
           lam1: float = 1.0, lam2: float = 1.0, init: list[np.ndarray] | None = None) -> LPVIO:
    """LPV-OE by the recursive output-error PAA (thesis (4.21)–(4.25), corrected).

    Decreasing gain by default (λ₁ = λ₂ = 1, F(0) = f0·I). The thesis gives no tuning values and
    no number of passes; each pass restarts ŷ from zero past and carries θ̂ and F over, so later
    passes refine with a small gain. ``init`` are starting parameters (default zero).
    """
    if passes < 1 or f0 <= 0 or not 0 < lam1 <= 1 or not 0 < lam2 < 2:
        raise DataError("oe_paa needs passes >= 1, f0 > 0, 0 < lam1 <= 1 and 0 < lam2 < 2")
    table, counts = _column_table(struct)
    theta = np.zeros((struct.ny, table.shape[1]))
    if init is not None:
        for r, t in enumerate(init):
            theta[r, : len(t)] = t
    F = np.tile(f0 * np.eye(table.shape[1]), (struct.ny, 1, 1))
    y, u = np.ascontiguousarray(data.y), np.ascontiguousarray(data.u)
    for _ in range(passes):
        _paa_pass(y, u, psi, table, counts, theta, F, lam1, lam2, struct.shifted)
    return struct.model([theta[r, : counts[r]].copy() for r in range(struct.ny)])


def oe_pseudolinear(struct: Structure, data: Dataset, psi: np.ndarray, iterations: int = 20,
                    tol: float = 1e-8, init: list[np.ndarray] | None = None) -> LPVIO:
    """Batch pseudo-linear LPV-OE regression: θ̂_{j+1} = LS of y on φ̃(ŷ_j), ŷ_j simulated from θ̂_j.

    The fixed point satisfies Φ̃(ŷ)ᵀ(y − ŷ) = 0 with Φ̃ built from u only (through ŷ), the batch
    counterpart of the PAA's stationary point (thesis §4.4.1). Starts from IV-ARX by default
    (LS-ARX models of noisy data are often unstable in simulation); an iterate whose simulation
    diverges ends the iteration. The iteration need not converge (it has the same stability
    condition as the PAA), so the iterate with the smallest simulation error is returned.
    """
    start = struct.max_lag
    if init is None:
        y_aux = simulate_psi(struct.model(least_squares_thetas(struct, data, psi)), data.u, psi)
        _check_bounded(y_aux, data, "LS-ARX")
        init = iv_thetas(struct, data, y_aux, psi)
    thetas = init
    y_sim = simulate_psi(struct.model(thetas), data.u, psi)
    best = (np.sum((data.y - y_sim)[start:] ** 2), thetas)
    for _ in range(iterations):
        if not _is_bounded(y_sim, data):
            break
        new = [solve_instrumental(phi, phi, data.y[start:, r])
               for r, phi in enumerate(struct.regressor(r, y_sim, data.u, psi)[start:]
                                       for r in range(struct.ny))]
        y_new = simulate_psi(struct.model(new), data.u, psi)
        if not _is_bounded(y_new, data):
            break
        step = max(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300)
                   for a, b in zip(new, thetas, strict=True))
        thetas, y_sim = new, y_new
        best = min(best, (np.sum((data.y - y_sim)[start:] ** 2), thetas), key=lambda b: b[0])
        if step < tol:
            break
    return struct.model(best[1])


# ================================================================================== IV-OE
def identify_iv_oe(data: Dataset, na: int | np.ndarray, nb: int | np.ndarray, nk: int | np.ndarray,
                   basis: Basis | str = "affine", form: str = "shifted", auxiliary: str = "paa",
                   scheduling: Scheduling | None = None, passes: int = 3, f0: float = 100.0) -> LPVIO:
    """IV-OE, thesis Algorithm 4.1: OE auxiliary model, then one IV solve with its simulated output.

    Args:
        auxiliary: ``"paa"`` (recursive output-error PAA, the thesis's Step 1) or ``"batch"``
            (batch pseudo-linear OE regression).
        passes, f0: PAA passes over the data and initial gain F(0) = f0·I.
        scheduling: quasi-LPV map from an output trajectory to the scheduling (module docstring).

    SISO and MIMO; shifted or static form.
    """
    struct = Structure.from_data(data, na, nb, nk, basis, form)
    psi = struct.basis.eval(data.p, check_range=False)
    if auxiliary == "paa":
        aux = oe_paa(struct, data, psi, passes=passes, f0=f0)
    elif auxiliary == "batch":
        aux = oe_pseudolinear(struct, data, psi)
    else:
        raise DataError(f"auxiliary must be 'paa' or 'batch', got {auxiliary!r}")
    y_aux, psi_aux = _noise_free_output(aux, data, psi, scheduling)
    _check_bounded(y_aux, data, "output-error")
    return struct.model(iv_thetas(struct, data, y_aux, psi, psi_aux))


def identify_oe_paa(data: Dataset, na: int | np.ndarray, nb: int | np.ndarray, nk: int | np.ndarray,
                    basis: Basis | str = "affine", form: str = "shifted", passes: int = 3,
                    f0: float = 100.0) -> LPVIO:
    """The thesis's "OE" estimator: the recursive PAA alone (Step 1 of IV-OE). SISO and MIMO."""
    struct = Structure.from_data(data, na, nb, nk, basis, form)
    return oe_paa(struct, data, struct.basis.eval(data.p, check_range=False), passes=passes, f0=f0)


# ============================================================================ RIV / SRIV
def _stable_monic(poly: np.ndarray) -> np.ndarray:
    """Reflect roots of a monic polynomial in q⁻¹ into the unit circle (keeps the prefilter stable)."""
    roots = np.roots(poly)
    if len(roots) == 0 or np.all(np.abs(roots) < 1):
        return poly
    roots = np.where(np.abs(roots) >= 1, 1 / np.conj(roots) * 0.999, roots)
    return np.real(np.poly(roots))


def identify_riv(data: Dataset, na: int, nb: int, nk: int, basis: Basis | str = "affine",
                 form: str = "shifted", noise_order: int = 2, simplified: bool = False,
                 iterations: int = 30, tol: float = 1e-7, init: LPVIO | None = None) -> LPVIO:
    """LPV refined IV (Laurain et al. 2010) for y = A⁻¹B u + D⁻¹ e, or SRIV (``simplified``, H = 1).

    Per iteration j (SISO): χ̂ = noise-free output of θ̂_j; the regressor splits into the LTI part
    −Σ a_{i,0} y(k−i) and the extended signals (−χ_{i,l}, l ≥ 1; u_{j,l}); all columns and y are
    prefiltered by L(q) = D̂(q)/Â₀(q) (SRIV: 1/Â₀(q)), with D̂ the AR(noise_order) LS fit of
    y − χ̂, and θ̂_{j+1} = (Σ ζ_f φ_fᵀ)⁻¹ Σ ζ_f y_f with ζ built from χ̂ alone. Starts from IV-OE
    (or ``init``); stops when the relative change of θ̂ is below ``tol``, or before an iterate
    whose simulation diverges. The LTI prefilter only approximates the LPV filter A⁻¹(q, θ) that
    the fixed point needs, so the iteration can drift instead of settling; the iterate with the
    smallest simulation error ‖y − χ̂‖ is returned.
    """
    struct = Structure.from_data(data, na, nb, nk, basis, form)
    if struct.ny != 1:
        raise DataError("refined IV (RIV/SRIV) is implemented for one output; use iv-oe for MIMO")
    if noise_order < 1 and not simplified:
        raise DataError("noise_order must be >= 1 for RIV (or use simplified=True)")
    psi = struct.basis.eval(data.p, check_range=False)
    start, y = struct.max_lag, data.y[:, 0]
    model = init if init is not None else identify_iv_oe(data, na, nb, nk, struct.basis, form)
    theta = struct.thetas(model)[0]
    chi = simulate_psi(model, data.u, psi)
    _check_bounded(chi, data, "refined-IV initial")
    lti_cols = [i for i, c in enumerate(struct.columns[0]) if c.signal == "y" and c.psi == 0]
    a0_lags = [struct.columns[0][i].lag for i in lti_cols]
    phi_y = struct.regressor(0, data.y, data.u, psi)
    best = (np.sum((y[start:] - chi[start:, 0]) ** 2), theta)
    for _ in range(iterations):
        zeta = struct.regressor(0, chi, data.u, psi)
        phi = zeta.copy()
        phi[:, lti_cols] = phi_y[:, lti_cols]
        a0 = np.zeros(struct.na.max() + 1)
        a0[0] = 1.0
        a0[a0_lags] = theta[lti_cols]
        num = np.ones(1) if simplified else _ar_noise_model(y[start:] - chi[start:, 0], noise_order)
        den = _stable_monic(a0)
        filt = [scipy.signal.lfilter(num, den, x[start:], axis=0) for x in (phi, zeta, y)]
        new = solve_instrumental(filt[1], filt[0], filt[2])
        chi_new = simulate_psi(struct.model([new]), data.u, psi)
        if not _is_bounded(chi_new, data):
            break  # keep the last iterate whose simulation stayed bounded
        step = np.linalg.norm(new - theta) / max(np.linalg.norm(theta), 1e-300)
        theta, chi = new, chi_new
        best = min(best, (np.sum((y[start:] - chi[start:, 0]) ** 2), theta), key=lambda b: b[0])
        if step < tol:
            break
    return struct.model([best[1]])


def _ar_noise_model(v: np.ndarray, order: int) -> np.ndarray:
    """D̂ = [1, d_1, …, d_n] from LS on v(k) + Σ d_i v(k−i) = e(k) (the RIV noise-model step)."""
    rows = np.column_stack([-v[order - i : len(v) - i] for i in range(1, order + 1)])
    d = np.linalg.lstsq(rows, v[order:], rcond=None)[0]
    return _stable_monic(np.concatenate([[1.0], d]))
