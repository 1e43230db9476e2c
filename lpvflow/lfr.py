"""LPV linear fractional representation (LFR): an LTI block in feedback with a known Δ(p).

Mejari, Piga, Tóth and Bemporad, "Kernelized Identification of Linear Parameter-Varying Models with
Linear Fractional Representation", eq. (1):

    [x(k+1)]   [A   B1   B2 ] [x(k)]
    [ z(k) ] = [C1  D11  D12] [w(k)],     w(k) = Δ(p(k)) z(k),
    [ y(k) ]   [C2  D21  D22] [u(k)]

with Δ(p) = Σ_l ψ_l(p) Δ_l on a scheduling basis ψ (Δ(p) = p for the paper's examples). When
I − D11 Δ(p) is invertible (assumption A2, well-posedness) the loop closes to the LPV state space
with rational dependence, eqs. (2)–(3):

    𝒜(p) = A + B1 Δ (I − D11 Δ)⁻¹ C1,    ℬ(p) = B2 + B1 Δ (I − D11 Δ)⁻¹ D12,
    𝒞(p) = C2 + D21 Δ (I − D11 Δ)⁻¹ C1,  𝒟(p) = D22 + D21 Δ (I − D11 Δ)⁻¹ D12.

With D11 = 0 this is affine in ψ and :meth:`LPVLFR.to_lpvss` returns the exact :class:`LPVSS`;
otherwise only frozen (pointwise) analysis applies, and :func:`require_affine` refuses the model
for polytopic synthesis.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numba
import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import (
    FORMAT_VERSION,
    LPVSS,
    atomic_write_json,
    check_format,
    default_names,
    simulation_inputs,
)

if TYPE_CHECKING:
    import control

#: Smallest singular value of I − D11 Δ(p), relative to its largest, that still counts as well posed.
WELL_POSED_TOL = 1e-8
#: Grid points in :meth:`LPVLFR.check_well_posed`: at most this many in total, at least 5 per axis.
GRID_BUDGET = 20_000

_BLOCKS = ("A", "B1", "B2", "C1", "D11", "D12", "C2", "D21", "D22")


@numba.njit(cache=True)
def _ltv_recursion(Ak: np.ndarray, Bk: np.ndarray, Ck: np.ndarray, Dk: np.ndarray, u: np.ndarray,
                   x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x(k+1) = A_k x(k) + B_k u(k), y(k) = C_k x(k) + D_k u(k) with per-sample matrices."""
    n = u.shape[0]
    x = np.zeros((n + 1, Ak.shape[1]))
    y = np.zeros((n, Ck.shape[1]))
    x[0] = x0
    for k in range(n):
        y[k] = Ck[k] @ x[k] + Dk[k] @ u[k]
        x[k + 1] = Ak[k] @ x[k] + Bk[k] @ u[k]
    return y, x


@dataclass
class LPVLFR:
    """Discrete-time LPV-LFR: LTI block (A … D22) closed by w = Δ(p) z, Δ(p) = Σ_l ψ_l(p) Δ_l.

    Attributes:
        A, B1, B2, C1, D11, D12, C2, D21, D22: LTI block, shapes (nx, nx), (nx, nΔ), (nx, nu),
            (nΔ, nx), (nΔ, nΔ), (nΔ, nu), (ny, nx), (ny, nΔ), (ny, nu).
        delta: (n_psi, nΔ, nΔ) components of Δ(p) on ``basis``.
        basis: scheduling basis ψ (its recorded range is the default box for well-posedness).
        Ts: sampling time in seconds.
    """

    A: np.ndarray
    B1: np.ndarray
    B2: np.ndarray
    C1: np.ndarray
    D11: np.ndarray
    D12: np.ndarray
    C2: np.ndarray
    D21: np.ndarray
    D22: np.ndarray
    delta: np.ndarray
    basis: Basis
    Ts: float
    u_names: list[str] = field(default_factory=list)
    y_names: list[str] = field(default_factory=list)
    p_names: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in (*_BLOCKS, "delta"):
            value = np.asarray(getattr(self, name), dtype=float)
            setattr(self, name, value if name == "delta" else np.atleast_2d(value))
        nx, nd, nu, ny = self.A.shape[0], self.D11.shape[0], self.B2.shape[1], self.C2.shape[0]
        expected = {"A": (nx, nx), "B1": (nx, nd), "B2": (nx, nu), "C1": (nd, nx), "D11": (nd, nd),
                    "D12": (nd, nu), "C2": (ny, nx), "D21": (ny, nd), "D22": (ny, nu),
                    "delta": (self.basis.n_psi, nd, nd)}
        for name, shape in expected.items():
            if getattr(self, name).shape != shape:
                raise ModelError(f"LPVLFR {name} has shape {getattr(self, name).shape}; expected {shape}")
        if not all(np.all(np.isfinite(getattr(self, n))) for n in expected):
            raise ModelError("LPVLFR matrices contain NaN or inf; re-identify the model")
        if self.Ts <= 0:
            raise ModelError(f"sampling time must be positive, got Ts={self.Ts}")
        default_names(self, nu, ny, self.basis.n_p)

    @property
    def nx(self) -> int:
        return self.A.shape[0]

    @property
    def nu(self) -> int:
        return self.B2.shape[1]

    @property
    def ny(self) -> int:
        return self.C2.shape[0]

    @property
    def n_delta(self) -> int:
        return self.D11.shape[0]

    @property
    def is_affine(self) -> bool:
        """True when D11 = 0: the closed loop is then affine in ψ(p) (Mejari et al. §IV-B, eq. (22))."""
        return not np.any(self.D11)

    # ------------------------------------------------------------------------------- evaluation
    def delta_at(self, p: np.ndarray) -> np.ndarray:
        """Δ(p) for every row of p (N, n_p): returns (N, nΔ, nΔ)."""
        psi = self.basis.eval(np.asarray(p, dtype=float).reshape(-1, self.basis.n_p), check_range=False)
        return np.einsum("tl,lij->tij", psi, self.delta)

    def _loop_gain(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Δ(p)(I − D11 Δ(p))⁻¹ per row of p, and the rows where I − D11 Δ is singular."""
        dl = self.delta_at(p)
        m = np.eye(self.n_delta) - np.einsum("ij,tjk->tik", self.D11, dl)
        s = np.linalg.svd(m, compute_uv=False)
        singular = s[:, -1] <= WELL_POSED_TOL * np.maximum(s[:, 0], 1.0)
        gain = np.zeros_like(dl)
        ok = ~singular
        # Δ(I − D11Δ)⁻¹ = ((I − D11Δ)⁻ᵀ Δᵀ)ᵀ
        gain[ok] = np.linalg.solve(np.transpose(m[ok], (0, 2, 1)), np.transpose(dl[ok], (0, 2, 1))
                                   ).transpose(0, 2, 1)
        return gain, singular

    def _raise_ill_posed(self, point: np.ndarray, where: str) -> None:
        raise ModelError(
            f"the LFR is not well posed {where} p = {np.round(point, 6).tolist()}: I - D11*Delta(p) is "
            "singular there; restrict the scheduling range or re-identify with another D11"
        )

    def pointwise_matrices(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Frozen 𝒜, ℬ, 𝒞, 𝒟 (eq. (3)) at every row of p (N, n_p): shapes (N, nx, nx) … (N, ny, nu)."""
        p = np.asarray(p, dtype=float).reshape(-1, self.basis.n_p)
        g, singular = self._loop_gain(p)
        if singular.any():
            k = int(np.argmax(singular))
            self._raise_ill_posed(p[k], f"at sample {k},")
        B1g, D21g = np.einsum("ij,tjk->tik", self.B1, g), np.einsum("ij,tjk->tik", self.D21, g)
        return (self.A + B1g @ self.C1, self.B2 + B1g @ self.D12,
                self.C2 + D21g @ self.C1, self.D22 + D21g @ self.D12)

    def matrices(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(𝒜, ℬ, 𝒞, 𝒟) frozen at one scheduling point p (n_p,): the rational LPV-SS of eq. (3)."""
        return tuple(M[0] for M in self.pointwise_matrices(np.atleast_1d(p).reshape(1, -1)))

    def frozen(self, p: np.ndarray) -> control.StateSpace:
        """The LTI model at constant scheduling p, as a discrete python-control StateSpace (dt = Ts)."""
        import control

        A, B, C, D = self.matrices(p)
        return control.ss(A, B, C, D, self.Ts, inputs=self.u_names, outputs=self.y_names)

    def simulate(self, u: np.ndarray, p: np.ndarray, x0: np.ndarray | None = None,
                 return_states: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Simulate the closed LFR along a scheduling trajectory; returns y (N, ny) [and x (N+1, nx)]."""
        u, p = simulation_inputs(u, p, self.nu, self.basis.n_p)
        Ak, Bk, Ck, Dk = (np.ascontiguousarray(M) for M in self.pointwise_matrices(p))
        x0 = np.zeros(self.nx) if x0 is None else np.asarray(x0, dtype=float).reshape(self.nx)
        y, x = _ltv_recursion(Ak, Bk, Ck, Dk, np.ascontiguousarray(u), x0)
        return (y, x) if return_states else y

    # ------------------------------------------------------------------------- well-posedness
    def check_well_posed(self, box: np.ndarray | None = None, points: int | None = None) -> None:
        """Raise ModelError unless I − D11 Δ(p) is invertible on the scheduling box (assumption A2).

        The box (default: the basis's recorded range) is gridded with ``points`` per axis (default:
        GRID_BUDGET^(1/n_p), at least 5); a point
        fails if the smallest singular value is tiny, and a sign change of det(I − D11 Δ(p)) between
        neighbouring grid points reveals a singularity the grid stepped over (det is continuous).
        """
        if box is None:
            if self.basis.p_min is None:
                raise ModelError("no scheduling range recorded; pass box=[[min, max], ...]")
            box = np.column_stack([self.basis.p_min, self.basis.p_max])
        box = np.asarray(box, dtype=float).reshape(self.basis.n_p, 2)
        points = points or max(5, int(GRID_BUDGET ** (1 / self.basis.n_p)))
        axes = [np.linspace(lo, hi, points) for lo, hi in box]
        mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        flat = mesh.reshape(-1, self.basis.n_p)
        _, singular = self._loop_gain(flat)
        if singular.any():
            self._raise_ill_posed(flat[int(np.argmax(singular))], "in the scheduling box at")
        dl = self.delta_at(flat)
        det = np.linalg.det(np.eye(self.n_delta) - np.einsum("ij,tjk->tik", self.D11, dl))
        det = det.reshape(mesh.shape[:-1])
        for axis in range(self.basis.n_p):
            flips = np.diff(np.sign(det), axis=axis) != 0
            if flips.any():
                idx = np.unravel_index(int(np.argmax(flips)), flips.shape)
                a = mesh[idx]
                b = mesh[tuple(i + (1 if ax == axis else 0) for ax, i in enumerate(idx))]
                self._raise_ill_posed((a + b) / 2, "in the scheduling box near")

    # --------------------------------------------------------------------------- conversions
    def to_lpvss(self) -> LPVSS:
        """Exact affine :class:`LPVSS` on the same basis; only for D11 = 0 (Mejari et al. eq. (23)).

        M_l = M_0-part δ_{l0} + (B1 or D21) Δ_l (C1 or D12), since 𝒜(p) = A + Σ_l ψ_l B1 Δ_l C1 etc.
        """
        if not self.is_affine:
            raise ModelError(
                "this LFR has rational dependence (D11 != 0) and no affine LPVSS form; use frozen "
                "models (frozen/matrices) for analysis"
            )
        def stack(const: np.ndarray, left: np.ndarray, right: np.ndarray) -> np.ndarray:
            out = np.einsum("ij,ljk,km->lim", left, self.delta, right)
            out[0] += const
            return out

        return LPVSS(stack(self.A, self.B1, self.C1), stack(self.B2, self.B1, self.D12),
                     stack(self.C2, self.D21, self.C1), stack(self.D22, self.D21, self.D12),
                     self.basis, self.Ts, u_names=self.u_names, y_names=self.y_names,
                     p_names=self.p_names)

    # --------------------------------------------------------------------------- serialisation
    def to_dict(self) -> dict:
        d = {"format": "lpvflow/lpvlfr", "version": FORMAT_VERSION, "Ts": self.Ts,
             "basis": self.basis.to_dict(), "u_names": self.u_names, "y_names": self.y_names,
             "p_names": self.p_names, "delta": self.delta.tolist()}
        d.update({name: getattr(self, name).tolist() for name in _BLOCKS})
        return d

    @classmethod
    def from_dict(cls, d: dict) -> LPVLFR:
        check_format(d, "lpvlfr")
        try:
            return cls(*(d[name] for name in _BLOCKS), delta=d["delta"], basis=Basis.from_dict(d["basis"]),
                       Ts=float(d["Ts"]), u_names=d["u_names"], y_names=d["y_names"], p_names=d["p_names"])
        except KeyError as exc:
            raise ModelError(f"LFR model file lacks the field {exc.args[0]!r}") from None

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_json(path, self.to_dict())



def require_affine(model: LPVSS | LPVLFR) -> LPVSS:
    """The affine LPVSS polytopic synthesis needs; refuse an LFR with rational dependence.

    An LPVSS passes unchanged; an LFR with D11 = 0 is converted exactly (:meth:`LPVLFR.to_lpvss`).
    """
    if isinstance(model, LPVLFR):
        if not model.is_affine:
            raise ModelError(
                "polytopic synthesis needs affine dependence; this is an LFR with rational dependence "
                "(D11 != 0): design on frozen models or approximate it by an affine LPVSS first"
            )
        return model.to_lpvss()
    if not isinstance(model, LPVSS):
        raise ModelError(f"polytopic synthesis needs an LPVSS model, got {type(model).__name__}")
    return model
