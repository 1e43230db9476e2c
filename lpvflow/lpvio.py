"""The LPV input-output model: MIMO LPV-ARX/ARMAX coefficients in shifted (left polynomial) or static
form, y(k) + Σ_i A_i(ψ(p(k−i))) y(k−i) = Σ_j B_j(ψ(p(k−j))) u(k−j) (+ noise part), its simulation,
prediction, exact state-space realization (:func:`lpvflow.identify.realize.realize_io`) and file."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.identify.realize import realize_io
from lpvflow.models import (
    FORMAT_VERSION,
    LPVSS,
    atomic_write_json,
    check_format,
    default_names,
    lagged_sum,
    noise_input,
    simulation_inputs,
)
from lpvflow.simulate import io_recursion


@dataclass
class LPVIO:
    """MIMO LPV-ARX/ARMAX input-output model.

    Attributes:
        A: (na_max, n_psi, ny, ny); ``A[i-1, l]`` is the ψ_l component of A_i (lag i).
        B: (nb_lag_max+1, n_psi, ny, nu); ``B[j, l]`` is the ψ_l component of B_j (lag j ≥ 0).
        C: (nc, n_psi, ny, ny) noise coefficients C_1 … C_nc (ARMAX), or an empty stack.
        basis: the scheduling basis ψ.
        Ts: sampling time in seconds.
        form: ``"shifted"`` (LPR, realizable with static dependence) or ``"static"``.
        na: (ny, ny) lags of y_c in equation r; nb, nk: (ny, nu) number of input lags and delay.
        noise_cov: (ny, ny) residual covariance of the fit, if identified.
        param_cov: per output, the covariance of its free parameters (same order as
            :meth:`free_parameters`), if identified.
        operating_point: the means subtracted from the data it was identified on, ``{"u": u₀, "y": y₀}``
            (``identify --remove-offsets`` / ``[identify] remove_offsets``): the model maps u − u₀ to
            y − y₀; empty when identified in the recorded signals.
    """

    A: np.ndarray
    B: np.ndarray
    basis: Basis
    Ts: float
    C: np.ndarray | None = None
    form: str = "shifted"
    na: np.ndarray | None = None
    nb: np.ndarray | None = None
    nk: np.ndarray | None = None
    u_names: list[str] = field(default_factory=list)
    y_names: list[str] = field(default_factory=list)
    p_names: list[str] = field(default_factory=list)
    noise_cov: np.ndarray | None = None
    param_cov: list[np.ndarray] | None = None
    operating_point: dict[str, list[float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.A = np.asarray(self.A, dtype=float)
        self.B = np.asarray(self.B, dtype=float)
        if self.A.ndim != 4 or self.B.ndim != 4:
            raise ModelError("LPVIO coefficients must be 4-D stacks (lag, basis, rows, cols)")
        ny, nu, n_psi = self.B.shape[2], self.B.shape[3], self.basis.n_psi
        if self.A.shape[0] == 0:
            self.A = np.zeros((0, n_psi, ny, ny))
        self.C = np.zeros((0, n_psi, ny, ny)) if self.C is None else np.asarray(self.C, dtype=float)
        for name, M, cols in (("A", self.A, ny), ("B", self.B, nu), ("C", self.C, ny)):
            if M.shape[1:] != (n_psi, ny, cols):
                raise ModelError(
                    f"LPVIO {name} has shape {M.shape[1:]} per lag; expected ({n_psi}, {ny}, {cols})"
                )
        if self.form not in ("shifted", "static"):
            raise ModelError(f"LPVIO form must be 'shifted' or 'static', got {self.form!r}")
        if self.Ts <= 0:
            raise ModelError(f"sampling time must be positive, got Ts={self.Ts}")
        default_names(self, nu, ny, self.basis.n_p)
        self.operating_point = checked_operating_point(self.operating_point, nu, ny)

    @property
    def ny(self) -> int:
        return self.B.shape[2]

    @property
    def nu(self) -> int:
        return self.B.shape[3]

    @property
    def max_lag(self) -> int:
        return max(self.A.shape[0], self.B.shape[0] - 1, self.C.shape[0])

    def simulate(self, u: np.ndarray, p: np.ndarray, e: np.ndarray | None = None) -> np.ndarray:
        """Simulated output for inputs ``u`` (N, nu), scheduling ``p`` (N, n_p), zero initial past.

        ``e`` (N, ny) is the innovation of an ARMAX model (added at the output with C(q) filtering).
        """
        u, p = simulation_inputs(u, p, self.nu, self.basis.n_p)
        psi = self.basis.eval(p)
        shifted = self.form == "shifted"
        forced = lagged_sum(psi, self.B, u, shifted)
        if e is not None:
            e = noise_input(e, len(p), self.ny)
            forced += e + lagged_sum(psi, np.concatenate([np.zeros_like(self.C[:1]), self.C]), e, shifted)
        return io_recursion(forced, psi, self.A, shifted)

    def to_ss(self) -> LPVSS:
        """Exact observable-form LPVSS with static affine dependence on ψ(p(k)) (thesis (5.24)–(5.26))."""
        return realize_io(self)

    # --------------------------------------------------------------------------- serialisation
    def to_dict(self) -> dict:
        d = {
            "format": "lpvflow/lpvio",
            "version": FORMAT_VERSION,
            "form": self.form,
            "Ts": self.Ts,
            "basis": self.basis.to_dict(),
            "u_names": self.u_names,
            "y_names": self.y_names,
            "p_names": self.p_names,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
        }
        for name in ("na", "nb", "nk", "noise_cov"):
            value = getattr(self, name)
            if value is not None:
                d[name] = np.asarray(value).tolist()
        if self.param_cov is not None:
            d["param_cov"] = [np.asarray(c).tolist() for c in self.param_cov]
        if self.operating_point:
            d["operating_point"] = self.operating_point
        return d

    @classmethod
    def from_dict(cls, d: dict) -> LPVIO:
        check_format(d, "lpvio")
        basis = Basis.from_dict(d["basis"])
        n_psi = basis.n_psi
        B = np.asarray(d["B"], dtype=float)
        ny = B.shape[2]

        def stack(key: str, cols: int) -> np.ndarray:
            a = np.asarray(d.get(key, []), dtype=float)
            return a if a.size else np.zeros((0, n_psi, ny, cols))

        opt = {k: np.asarray(d[k]) for k in ("na", "nb", "nk", "noise_cov") if k in d}
        cov = [np.asarray(c, dtype=float) for c in d["param_cov"]] if "param_cov" in d else None
        return cls(stack("A", ny), B, basis, float(d["Ts"]), C=stack("C", ny), form=d["form"],
                   u_names=d["u_names"], y_names=d["y_names"], p_names=d["p_names"],
                   param_cov=cov, operating_point=d.get("operating_point", {}), **opt)

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_json(path, self.to_dict())


def checked_operating_point(point: object, nu: int, ny: int) -> dict[str, list[float]]:
    """``point`` as ``{"u": nu finite numbers, "y": ny finite numbers}`` (or empty); ModelError otherwise."""
    if not point:
        return {}
    if not isinstance(point, dict) or set(point) != {"u", "y"}:
        raise ModelError("operating_point must give the input and output means as {'u': [...], 'y': [...]}, "
                         f"got {point!r}")
    checked = {}
    for key, size in (("u", nu), ("y", ny)):
        values = np.asarray(point[key], dtype=float).ravel()
        if values.size != size or not np.all(np.isfinite(values)):
            raise ModelError(f"operating_point[{key!r}] must hold {size} finite number(s), "
                             f"got {point[key]!r}")
        checked[key] = values.tolist()
    return checked
