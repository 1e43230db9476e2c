"""Gain-scheduled controller in vertex form, run online with convex-coordinate scheduling.

    x_k(k+1) = Σ_i λ_i(p(k)) (Ak_i x_k(k) + Bk_i w(k)),
    u(k)     = u_eq(p(k)) + Σ_i λ_i(p(k)) (Ck_i x_k(k) + Dk_i w(k)),

λ(p) the convex coordinates of p in the design polytope
(:meth:`lpvflow.synth.polytope.Polytope.coordinates_at`: of ψ(p), or the hat functions of p₁ for a
``"piecewise"`` polytope), u the plant input (relative to the loop's operating point u_op) and w the
controller input, by :attr:`LPVController.structure`:

* ``"1dof"``: w = e = r − y (ny inputs), the tracking error of the measured outputs;
* ``"2dof"``: w = [r − y_op; y − y_op] (2·ny inputs), the references (one per measured output, in the
  measured outputs' order), then the measurements, both relative to the measured outputs' operating
  point y_op (:attr:`LPVController.y_operating_point`): the controller was designed on a model in
  deviations from it, so the operating point itself does not enter as a step. (1-DOF: r − y is the same
  either way.)

u_eq(p) is the optional trim feed-forward (:class:`Trim`; zero without one): per input the linear
interpolation of a table over the first scheduling signal, clamped at its ends. Saved as JSON with
``{"format": "lpvflow/lpv-controller", "version": 1}`` (``structure`` absent means ``"1dof"``, ``trim``
absent means none) and read back by ``lpvflow.models.load``.

**Anti-windup** (:class:`AntiWindup`, optional; observer form, Åström & Rundqwist 1989, "Integrator
windup and how to avoid it", ACC; Åström & Wittenmark, *Computer-Controlled Systems*, §9.4): with
the actuator range [u_min, u_max] around the operating point u_op the plant receives
u_a = clip(u_op + u, u_min, u_max) − u_op (u including the trim u_eq(p)), and the state is updated with it,

    x_k(k+1) = A(λ) x_k + B(λ) w + L(λ) (u_a − u),     L(λ) = Σ_i λ_i L_i,

so nothing of u the actuator did not apply is integrated: while saturated the controller runs as
x⁺ = (A − LC)x + (B − LD)w + L (u_a − u_eq), stable by the choice of L_i (:func:`observer_gains`).
Unsaturated, u_a = u and the law is the one above. The Python controller, ``lpvflow verify`` (which
runs it) and the exported FMU apply the same law.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import control
import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.models import FORMAT_VERSION, atomic_write_json, check_format
from lpvflow.synth.polytope import Polytope, polytope_of_kind


@dataclass
class AntiWindup:
    """Actuator range and observer gains of the anti-windup law (module docstring).

    Attributes:
        L: (N, n, nu) vertex gains L_i; u_min, u_max: (nu,) actuator range in plant units; u_offset:
            (nu,) the trim u_op the loop adds to the controller output.
    """

    L: np.ndarray
    u_min: np.ndarray
    u_max: np.ndarray
    u_offset: np.ndarray

    def __post_init__(self) -> None:
        self.L, self.u_min, self.u_max, self.u_offset = (
            np.asarray(M, dtype=float) for M in (self.L, self.u_min, self.u_max, self.u_offset))
        if not np.all(self.u_min < self.u_max):
            raise ModelError(f"anti-windup range needs u_min < u_max, got {self.u_min} and {self.u_max}")

    def applied(self, u: np.ndarray) -> np.ndarray:
        """u_a = clip(u_op + u, u_min, u_max) − u_op."""
        return np.clip(self.u_offset + u, self.u_min, self.u_max) - self.u_offset

    def to_dict(self) -> dict:
        return {k: getattr(self, k).tolist() for k in ("L", "u_min", "u_max", "u_offset")}


@dataclass
class Trim:
    """Trim feed-forward u_eq(p): the steady input that holds the plant at the scheduled operating point.

    u_eq,j(p) = np.interp(p₁, p_table, u_table[:, j]) for every plant input j: linear between the
    breakpoints, constant (the end row) outside them; p₁ is the first scheduling signal. p is measured,
    so the slope of u_eq acts as feedback (docs/design_file.md, ``[synth] trim``).

    Attributes:
        p: (M,) strictly ascending breakpoints of the first scheduling signal (M ≥ 1).
        u: (M, nu) the input at each breakpoint, in the units of the controller's output.
    """

    p: np.ndarray
    u: np.ndarray

    def __post_init__(self) -> None:
        self.p = np.asarray(self.p, dtype=float).reshape(-1)
        self.u = np.asarray(self.u, dtype=float)
        if self.p.size == 0 or not np.all(np.isfinite(self.p)) or np.any(np.diff(self.p) <= 0):
            raise ModelError(f"trim breakpoints p = {self.p.tolist()} must be finite and strictly ascending")
        if self.u.ndim != 2 or self.u.shape[0] != self.p.size or not np.all(np.isfinite(self.u)):
            raise ModelError(f"trim u has shape {self.u.shape}; it needs one finite row per breakpoint: "
                             f"({self.p.size}, number of plant inputs)")

    def value(self, p: np.ndarray) -> np.ndarray:
        """u_eq(p) (nu,) at the scheduling point p (n_p,): interpolation in p[0], clamped at the ends."""
        return self.along(np.asarray(p, dtype=float).reshape(-1)[:1])[0]

    def along(self, p1: np.ndarray) -> np.ndarray:
        """(n, nu) u_eq at n values of the first scheduling signal (:meth:`value` at each)."""
        return np.column_stack([np.interp(p1, self.p, column) for column in self.u.T])

    def to_dict(self) -> dict:
        return {"p": self.p.tolist(), "u": self.u.tolist()}


#: Controller input structures (module docstring): w = r − y, or w = [r; y].
STRUCTURES = ("1dof", "2dof")


def observer_gains(Ak: np.ndarray, Ck: np.ndarray) -> np.ndarray:
    """L_i with A_i − L_iC_i stable: the steady-state Kalman (predictor) gains of (A_i, C_i) with unit
    process and measurement covariances in the controller's own state coordinates,
    L_i = A_iPC_iᵀ(C_iPC_iᵀ + I)⁻¹, P from the dual discrete Riccati equation by SLICOT SB02OD
    (``control.dare``; scipy's ``solve_discrete_are`` gave up — "Reordering of (A, B) failed" — on a
    loop-shaping controller with an integrator and an unstable pole)."""
    import control

    gains = []
    for A, C in zip(Ak, Ck, strict=True):
        n, nu = A.shape[0], C.shape[0]
        _, _, G = control.dare(A.T, C.T, np.eye(n), np.eye(nu))  # G = (I + CPCᵀ)⁻¹CPAᵀ = Lᵀ
        gains.append(np.asarray(G).T)
    return np.array(gains)


def mix(K_vertices: Sequence[tuple[np.ndarray, ...]], lam: Sequence[float]) -> tuple[np.ndarray, ...]:
    """Σ_i λ_i K_i of vertex controllers K_i = (A_K, B_K, C_K, D_K), matrix by matrix: the controller at
    convex coordinates λ (every design interpolates with the plant's own λ)."""
    return tuple(sum(float(li) * K[m] for li, K in zip(lam, K_vertices, strict=True)) for m in range(4))


@dataclass
class LPVController:
    """Vertex matrices Ak (N, n, n), Bk (N, n, nw), Ck (N, nu, n), Dk (N, nu, nw) on a polytope.

    ``structure`` is ``"1dof"`` (w = r − y, nw = ny) or ``"2dof"`` (w = [r − y_op; y − y_op],
    nw = 2·ny); ``trim`` the optional feed-forward u_eq(p) added to the output (module docstring).
    """

    Ak: np.ndarray
    Bk: np.ndarray
    Ck: np.ndarray
    Dk: np.ndarray
    polytope: Polytope
    basis: Basis
    Ts: float
    info: dict = field(default_factory=dict)
    antiwindup: AntiWindup | None = None
    structure: str = "1dof"
    trim: Trim | None = None

    #: No operating input of its own: a loop adds its own (:class:`lpvflow.loop.protocol.VerificationLaw`).
    u_offset = None

    def __post_init__(self) -> None:
        mats = (self.Ak, self.Bk, self.Ck, self.Dk)
        self.Ak, self.Bk, self.Ck, self.Dk = (np.asarray(M, dtype=float) for M in mats)
        N, n = self.Ak.shape[:2]
        ny, nu = self.Bk.shape[2], self.Ck.shape[1]
        shapes = {"Ak": (N, n, n), "Bk": (N, n, ny), "Ck": (N, nu, n), "Dk": (N, nu, ny)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ModelError(f"controller {name} has shape {getattr(self, name).shape}; expected {shape}")
        if N != self.polytope.n_vertices:
            raise ModelError(f"controller has {N} vertex systems but its polytope has "
                             f"{self.polytope.n_vertices}")
        if self.antiwindup is not None and self.antiwindup.L.shape != (N, n, nu):
            raise ModelError(f"anti-windup gains have shape {self.antiwindup.L.shape}; expected {(N, n, nu)}")
        if self.structure not in STRUCTURES:
            raise ModelError(f"controller structure {self.structure!r} is unknown; use one of {STRUCTURES}")
        if self.structure == "2dof" and ny % 2:
            raise ModelError(f"a 2dof controller reads [r; y], an even number of inputs; Bk has {ny} columns")
        if self.trim is not None and self.trim.u.shape[1] != nu:
            raise ModelError(f"the trim table has {self.trim.u.shape[1]} column(s) for the controller's "
                             f"{nu} output(s)")
        self.reset()

    @property
    def order(self) -> int:
        return self.Ak.shape[1]

    @property
    def n_in(self) -> int:
        return self.Bk.shape[2]

    @property
    def n_out(self) -> int:
        return self.Ck.shape[1]

    @property
    def n_p(self) -> int:
        """The number of scheduling signals."""
        return self.basis.n_p

    @property
    def design_box(self) -> np.ndarray | None:
        """The scheduling box (n_p, 2) the controller was designed on; None when designed at one point
        (``"point"`` polytope)."""
        return self.polytope.design_box

    @property
    def n_measured(self) -> int:
        """ny, the number of measured outputs (and of references) the controller reads."""
        return self.n_in // 2 if self.structure == "2dof" else self.n_in

    @property
    def y_operating_point(self) -> np.ndarray:
        """(ny,) y_op, the measured outputs' operating points of the port record ``info["signals"]``
        (:mod:`lpvflow.pipeline.ports`; zero without one)."""
        measured = (self.info.get("signals") or {}).get("measured") or []
        if len(measured) != self.n_measured:
            return np.zeros(self.n_measured)
        return np.array([float(port.get("operating_point", 0.0)) for port in measured])

    def input_of(self, r: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The controller input w from references r (ny,) and measurements y (ny,), both in plant units:
        r − y (1dof) or [r − y_op; y − y_op] (2dof, :attr:`y_operating_point`)."""
        r, y = (np.asarray(v, dtype=float).reshape(self.n_measured) for v in (r, y))
        if self.structure != "2dof":
            return r - y
        y_op = self.y_operating_point
        return np.concatenate([r - y_op, y - y_op])

    def feedforward(self, p: np.ndarray) -> np.ndarray:
        """u_eq(p) (:class:`Trim`), zero without a trim table."""
        return np.zeros(self.n_out) if self.trim is None else self.trim.value(p)

    def reset(self, x0: np.ndarray | None = None) -> None:
        """Set the controller state (zero by default)."""
        self.x = np.zeros(self.order) if x0 is None else np.asarray(x0, dtype=float).reshape(self.order)

    def coordinates(self, p: np.ndarray) -> np.ndarray:
        """λ(p) for one scheduling point p (n_p,) (:meth:`Polytope.coordinates_at`)."""
        return self.polytope.coordinates_at(self.basis, p)

    def verification_law(self, measured: Sequence[str], actuated: Sequence[str]) -> LPVController:
        """The law verification steps (:class:`lpvflow.loop.protocol.VerificationLaw`): itself, wired by
        the loop's ``measured`` and ``actuated`` signals."""
        return self

    def close(self) -> None:
        """Nothing to release (the controller holds no instance or file)."""

    def experiment_controller(self) -> SynthesizedController:
        """The controller an identification experiment runs
        (:class:`lpvflow.loop.protocol.ExperimentController`): this law wired to the plant signals by its
        port record ``info["signals"]`` (:class:`lpvflow.experiment.synthesized.SynthesizedController`;
        one DataError line without the record)."""
        return SynthesizedController.from_controller(self)

    def matrices(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D) of the controller frozen at p: Σ λ_i(p) M_i (the trim u_eq(p) is not part of them)."""
        lam = self.coordinates(p)
        return tuple(np.tensordot(lam, M, axes=1) for M in (self.Ak, self.Bk, self.Ck, self.Dk))

    def frozen(self, p: np.ndarray) -> control.StateSpace:
        return control.ss(*self.matrices(p), self.Ts)

    def output(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """u(k) = u_eq(p) + C(λ) x + D(λ) w for input w(k) (:meth:`input_of`) at p(k), without advancing
        the state."""
        _, _, C, D = self.matrices(p)
        return (C @ self.x + D @ np.asarray(w, dtype=float).reshape(self.n_in)) + self.feedforward(p)

    def step(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """One sample online: returns the command u(k) = u_eq(p) + C(λ) x + D(λ) w (before the actuator)
        for the input w(k) (:meth:`input_of`) and advances the state to k + 1,
        x⁺ = A(λ) x + B(λ) w [+ L(λ)(u_a − u) with anti-windup] (module docstring)."""
        w = np.asarray(w, dtype=float).reshape(self.n_in)
        if not np.all(np.isfinite(w)) or not np.all(np.isfinite(p)):
            raise DataError("controller input or scheduling value is NaN or inf")
        lam = self.coordinates(p)
        A, B, C, D = (np.tensordot(lam, M, axes=1) for M in (self.Ak, self.Bk, self.Ck, self.Dk))
        u = (C @ self.x + D @ w) + self.feedforward(p)  # the FMU's order of the sums
        self.x = A @ self.x + B @ w
        if self.antiwindup is not None:
            self.x = self.x + np.tensordot(lam, self.antiwindup.L, axes=1) @ (self.antiwindup.applied(u) - u)
        return u

    def simulate(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Open-loop response u (N, nu) to the inputs w (N, nw) along p (N, n_p), from the current state."""
        w = np.asarray(w, dtype=float).reshape(len(w), self.n_in)
        p = np.asarray(p, dtype=float).reshape(len(w), -1)
        return np.array([self.step(wk, pk) for wk, pk in zip(w, p, strict=True)])

    # ------------------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        poly = self.polytope
        d = {
            "format": "lpvflow/lpv-controller", "version": FORMAT_VERSION, "Ts": self.Ts,
            "basis": self.basis.to_dict(),
            "polytope": {"kind": poly.kind, "box": poly.box.tolist(),
                         "psi_vertices": poly.psi_vertices.tolist(),
                         "term_box": None if poly.term_box is None else poly.term_box.tolist(),
                         "breakpoints": (None if poly.breakpoints is None
                                         else np.asarray(poly.breakpoints, dtype=float).tolist())},
            "structure": self.structure,
            "Ak": self.Ak.tolist(), "Bk": self.Bk.tolist(), "Ck": self.Ck.tolist(), "Dk": self.Dk.tolist(),
            "info": self.info,
        }
        if self.antiwindup is not None:
            d["antiwindup"] = self.antiwindup.to_dict()
        if self.trim is not None:
            d["trim"] = self.trim.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> LPVController:
        check_format(d, "lpv-controller")
        try:
            pd = d["polytope"]
            term_box, breakpoints = (None if pd.get(key) is None else np.asarray(pd[key], float)
                                     for key in ("term_box", "breakpoints"))
            poly = polytope_of_kind(pd["kind"], np.asarray(pd["box"], float),
                                    np.asarray(pd["psi_vertices"], float), term_box, breakpoints)
            Dk = np.asarray(d["Dk"], float)
            N, nu, ny = Dk.shape
            # JSON drops the empty dimensions of a controller without states: n from the size of Ak
            n = round(np.asarray(d["Ak"], float).reshape(N, -1).shape[1] ** 0.5)
            shapes = {"Ak": (N, n, n), "Bk": (N, n, ny), "Ck": (N, nu, n)}
            mats = {}
            for name, shape in shapes.items():
                value = np.asarray(d[name], float)
                if value.size != np.prod(shape):
                    raise ModelError(f"controller {name} has {value.size} entries; {N} vertices with "
                                     f"{n} states, {ny} inputs and {nu} outputs need shape {shape}")
                mats[name] = value.reshape(shape)
            aw = d.get("antiwindup")
            antiwindup = None if aw is None else AntiWindup(
                np.asarray(aw["L"], float).reshape(N, n, nu), aw["u_min"], aw["u_max"], aw["u_offset"])
            trim = None if d.get("trim") is None else Trim(d["trim"]["p"], d["trim"]["u"])
            return cls(mats["Ak"], mats["Bk"], mats["Ck"], Dk, poly, Basis.from_dict(d["basis"]),
                       float(d["Ts"]), info=d.get("info", {}), antiwindup=antiwindup,
                       structure=d.get("structure", "1dof"), trim=trim)
        except KeyError as exc:
            raise ModelError(f"controller file lacks the field {exc.args[0]!r}") from None
        except ModelError:
            raise  # already names what is wrong
        except ValueError as exc:
            raise ModelError(f"controller file has inconsistent matrix sizes ({exc})") from None

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_json(path, self.to_dict())


def series_input_filter(K: tuple[np.ndarray, ...], WB: control.StateSpace) -> tuple[np.ndarray, ...]:
    """Vertex matrices of W_B ∘ K (state [x_K; x_B]): the plant input is u_p = W_B u.

    A = [Ak 0; B_B Ck  A_B], B = [Bk; B_B Dk], C = [D_B Ck  C_B], D = D_B Dk (affine in K, so the
    series controller interpolates with the same λ).
    """
    Ak, Bk, Ck, Dk = K
    Ab, Bb, Cb, Db = (np.asarray(M, dtype=float) for M in (WB.A, WB.B, WB.C, WB.D))
    A = np.block([[Ak, np.zeros((Ak.shape[0], Ab.shape[0]))], [Bb @ Ck, Ab]])
    return A, np.vstack([Bk, Bb @ Dk]), np.hstack([Db @ Ck, Cb]), Db @ Dk

