"""LPV model objects and their JSON files: LPVSS here, LPVIO in :mod:`lpvflow.lpvio`; save and load.

LPVIO (:mod:`lpvflow.lpvio`), shifted (left polynomial, LPR) form — thesis (5.35)/(5.37) in the time
domain, Schulz et al. eq. (1)/(3):

    y(k) + Σ_i A_i(ψ(p(k−i))) y(k−i) = Σ_j B_j(ψ(p(k−j))) u(k−j) + e(k) + Σ_m C_m(ψ(p(k−m))) e(k−m)

every coefficient evaluated at the sample of the signal it multiplies. The static (Bamieh–Giarré)
form evaluates every coefficient at ψ(p(k)) instead (thesis (3.5)/(4.5)); it has no exact
realization with static dependence (thesis §5.2, Example 5.1).

LPVSS, affine in ψ (design.md; Schulz et al. Sec. II):

    x(k+1) = A(ψ)x + B(ψ)u [+ K(ψ)e],   y = C(ψ)x + D(ψ)u [+ e],   M(ψ) = Σ_l ψ_l(p(k)) M_l.
"""

from __future__ import annotations

import importlib
import json
import operator
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import DataError, ModelError
from lpvflow.simulate import ss_recursion

if TYPE_CHECKING:  # python-control takes ~1 s to import; only frozen models need it
    import control

    from lpvflow.lpvio import LPVIO

FORMAT_VERSION = 1
_LOADERS: dict[str, Callable[[dict], Any]] = {}

#: The loader of each object file kind the commands write, as ``module:attribute``; imported on first use,
#: so :func:`load` reads every kind in a fresh interpreter without importing synthesis or FMU code first.
LOADER_PATHS = {
    "lpvio": "lpvflow.lpvio:LPVIO.from_dict",
    "lpvlfr": "lpvflow.lfr:LPVLFR.from_dict",
    "lpv-controller": "lpvflow.synth.controller:LPVController.from_dict",
    "lti-controller": "lpvflow.experiment.controller:LtiController.from_dict",
    "extended-model": "lpvflow.validate.extended_model:ExtendedModel.from_dict",
}

#: JSON reports the commands write (kind → current version); :func:`load` returns them as dictionaries.
#: validation: ``validate --json``; simulation: ``simulate --json``; diagnosis: ``diagnose --json``;
#: verification: ``verify --json``; experiment: the sidecar ``<data>.csv.json`` of ``experiment``;
#: design: a design folder's ``summary.json``; stage: its stage records ``<stage>.json`` (pipeline/cache.py).
REPORT_VERSIONS = {"validation": 1, "simulation": 1, "diagnosis": 1, "verification": 1, "experiment": 1,
                   "design": 1, "stage": 1}


def register_format(kind: str, loader: Callable[[dict], Any]) -> None:
    """Make :func:`load` understand files with ``"format": "lpvflow/<kind>"``."""
    _LOADERS[kind] = loader


def report_header(kind: str) -> dict[str, Any]:
    """``{"format": "lpvflow/<kind>", "version": …}`` that a JSON report of ``kind`` starts with."""
    return {"format": f"lpvflow/{kind}", "version": REPORT_VERSIONS[kind]}


def _as_2d(name: str, x: Any, n_rows: int | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(f"{name} must be an (N, n) array, got shape {a.shape}")
    if n_rows is not None and len(a) != n_rows:
        raise DataError(f"{name} has {len(a)} samples but the scheduling signal has {n_rows}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"{name} contains NaN or inf at sample {int(np.argmin(np.isfinite(a).all(1)))}")
    return a


def _check_width(name: str, a: np.ndarray, n: int) -> None:
    if a.shape[1] != n:
        raise DataError(f"{name} has {a.shape[1]} column(s) but the model expects {n}")


def simulation_inputs(u: Any, p: Any, nu: int, n_p: int) -> tuple[np.ndarray, np.ndarray]:
    """``u`` (N, nu) and ``p`` (N, n_p) as float arrays for a model's ``simulate``; one DataError naming the
    signal for a wrong shape, a length mismatch or a non-finite sample."""
    p = _as_2d("scheduling p", p)
    u = _as_2d("input u", u, len(p))
    _check_width("input u", u, nu)
    _check_width("scheduling p", p, n_p)
    return u, p


def noise_input(e: Any, n_samples: int, ny: int) -> np.ndarray:
    """The innovation ``e`` (N, ny) of a model with a noise model, checked as :func:`simulation_inputs`."""
    e = _as_2d("noise e", e, n_samples)
    _check_width("noise e", e, ny)
    return e


def default_names(model: Any, nu: int, ny: int, n_p: int) -> None:
    """Fill empty ``u_names``/``y_names``/``p_names`` of a model with u0…, y0…, p0…."""
    model.u_names = model.u_names or [f"u{i}" for i in range(nu)]
    model.y_names = model.y_names or [f"y{i}" for i in range(ny)]
    model.p_names = model.p_names or [f"p{i}" for i in range(n_p)]


def lagged_sum(psi: np.ndarray, coeffs: np.ndarray, signal: np.ndarray, shifted: bool) -> np.ndarray:
    """Σ_j M_j(ψ(k−j) or ψ(k)) s(k−j) for coefficient stack ``coeffs`` (n_lag, n_psi, ny, ns)."""
    n = len(signal)
    out = np.zeros((n, coeffs.shape[2]))
    for j in range(coeffs.shape[0]):
        if not np.any(coeffs[j]) or j >= n:
            continue
        if shifted:  # g_j(t) = M_j(ψ(t)) s(t), then delayed by j samples
            g = np.einsum("tl,los,ts->to", psi[: n - j], coeffs[j], signal[: n - j], optimize=True)
        else:
            g = np.einsum("tl,los,ts->to", psi[j:], coeffs[j], signal[: n - j], optimize=True)
        out[j:] += g
    return out


def user_mode(fd: int) -> None:
    """Give a temporary file from mkstemp (mode 0600) the mode open() would: 0666 minus the umask."""
    mask = os.umask(0)
    os.umask(mask)
    os.fchmod(fd, 0o666 & ~mask)


def atomic_write_json(path: str | os.PathLike, payload: dict) -> None:
    """Write JSON to ``path`` via a temporary file and rename: a failure never truncates ``path``."""
    atomic_write_text(path, json.dumps(payload, indent=1))


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file and rename: a failure (or Ctrl-C) never leaves a
    truncated ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    user_mode(fd)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


# ======================================================================================= LPVSS
@dataclass
class LPVSS:
    """Discrete-time LPV state-space model with static affine dependence on ψ(p(k)).

    Attributes:
        A, B, C, D: basis components, shapes (n_psi, nx, nx), (n_psi, nx, nu), (n_psi, ny, nx),
            (n_psi, ny, nu); the matrix at p is Σ_l ψ_l(p) M_l.
        K: (n_psi, nx, ny) innovation gain of x(k+1) = … + K(ψ)e(k), y = … + e(k), or None.
        io: the input-output model this was realized from, if any.
        reduction: what a reduction step recorded (method, singular values, order), if any.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    basis: Basis
    Ts: float
    K: np.ndarray | None = None
    u_names: list[str] = field(default_factory=list)
    y_names: list[str] = field(default_factory=list)
    p_names: list[str] = field(default_factory=list)
    io: LPVIO | None = None
    reduction: dict | None = None

    def __post_init__(self) -> None:
        mats = (self.A, self.B, self.C, self.D)
        self.A, self.B, self.C, self.D = (np.asarray(M, dtype=float) for M in mats)
        n_psi = self.basis.n_psi
        nx, nu, ny = self.A.shape[1], self.B.shape[2], self.C.shape[1]
        expected = {"A": (n_psi, nx, nx), "B": (n_psi, nx, nu), "C": (n_psi, ny, nx), "D": (n_psi, ny, nu)}
        if self.K is not None:
            self.K = np.asarray(self.K, dtype=float)
            expected["K"] = (n_psi, nx, ny)
        for name, shape in expected.items():
            if getattr(self, name).shape != shape:
                raise ModelError(f"LPVSS {name} has shape {getattr(self, name).shape}; expected {shape}")
        if self.Ts <= 0:
            raise ModelError(f"sampling time must be positive, got Ts={self.Ts}")
        default_names(self, nu, ny, self.basis.n_p)

    @property
    def nx(self) -> int:
        return self.A.shape[1]

    @property
    def nu(self) -> int:
        return self.B.shape[2]

    @property
    def ny(self) -> int:
        return self.C.shape[1]

    def matrices(self, p: np.ndarray, *, check_range: bool = True
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D) frozen at one scheduling point p (n_p,); a SchedulingRangeWarning outside the
        identified range unless ``check_range`` is False (a caller that reports the range itself)."""
        p = np.atleast_1d(np.asarray(p, dtype=float)).reshape(1, -1)
        psi = self.basis.eval(p, check_range=check_range)[0]
        return tuple(np.tensordot(psi, M, axes=1) for M in (self.A, self.B, self.C, self.D))

    def frozen(self, p: np.ndarray, *, check_range: bool = True) -> control.StateSpace:
        """The LTI model at constant scheduling p, as a discrete python-control StateSpace (dt = Ts);
        ``check_range`` as in :meth:`matrices`."""
        import control

        A, B, C, D = self.matrices(p, check_range=check_range)
        return control.ss(A, B, C, D, self.Ts, inputs=self.u_names, outputs=self.y_names)

    def simulate(
        self, u: np.ndarray, p: np.ndarray, x0: np.ndarray | None = None, e: np.ndarray | None = None,
        return_states: bool = False,
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Simulate along a scheduling trajectory; returns y (N, ny) [and x (N+1, nx)]."""
        u, p = simulation_inputs(u, p, self.nu, self.basis.n_p)
        psi = self.basis.eval(p)
        A, B, C, D = self.A, self.B, self.C, self.D
        if e is not None:
            if self.K is None:
                raise ModelError("this model has no noise gain K; simulate without e")
            e = noise_input(e, len(p), self.ny)
            eye = np.zeros((self.basis.n_psi, self.ny, self.ny))
            eye[0] = np.eye(self.ny)
            B, D, u = np.concatenate([B, self.K], axis=2), np.concatenate([D, eye], axis=2), np.hstack([u, e])
        x0 = np.zeros(self.nx) if x0 is None else np.asarray(x0, dtype=float).reshape(self.nx)
        y, x = ss_recursion(psi, np.ascontiguousarray(u), A, B, C, D, x0)
        return (y, x) if return_states else y

    def vertices(self, box: np.ndarray | None = None) -> list[tuple[np.ndarray, control.StateSpace]]:
        """Frozen models at the corners of the scheduling box (default: the recorded range).

        Only for a basis affine in p: then the model is affine in p and the corners span a polytope
        that contains every frozen model of the box.
        """
        if not self.basis.is_affine:
            raise ModelError(
                f"vertices need a basis affine in p; this model uses {self.basis.kind} "
                f"(degree {self.basis.degree}): treat its terms as separate parameters"
            )
        if box is None:
            if self.basis.p_min is None:
                raise ModelError("no scheduling range recorded; pass box=[[min, max], ...]")
            box = np.column_stack([self.basis.p_min, self.basis.p_max])
        box = np.asarray(box, dtype=float).reshape(self.basis.n_p, 2)
        corners = np.array(np.meshgrid(*box, indexing="ij")).reshape(self.basis.n_p, -1).T
        return [(c, self.frozen(c)) for c in corners]

    # --------------------------------------------------------------------------- serialisation
    def to_dict(self) -> dict:
        d = {
            "format": "lpvflow/lpvss",
            "version": FORMAT_VERSION,
            "Ts": self.Ts,
            "basis": self.basis.to_dict(),
            "u_names": self.u_names,
            "y_names": self.y_names,
            "p_names": self.p_names,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D.tolist(),
        }
        if self.K is not None:
            d["K"] = self.K.tolist()
        if self.io is not None:
            d["io"] = self.io.to_dict()
        if self.reduction is not None:
            d["reduction"] = self.reduction
        return d

    @classmethod
    def from_dict(cls, d: dict) -> LPVSS:
        check_format(d, "lpvss")
        try:
            return cls(
                d["A"], d["B"], d["C"], d["D"], Basis.from_dict(d["basis"]), float(d["Ts"]),
                K=d.get("K"), u_names=d["u_names"], y_names=d["y_names"], p_names=d["p_names"],
                io=loader("lpvio")(d["io"]) if "io" in d else None, reduction=d.get("reduction"),
            )
        except KeyError as exc:
            raise ModelError(f"model file lacks the field {exc.args[0]!r}") from None

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_json(path, self.to_dict())


def check_format(d: dict, kind: str, version: int = FORMAT_VERSION) -> None:
    """Refuse (one line) a dictionary that is not an ``lpvflow/<kind>`` document of format ``version``."""
    fmt, found = d.get("format"), d.get("version")
    if fmt != f"lpvflow/{kind}":
        raise ModelError(f"expected a lpvflow/{kind} file, got format {fmt!r}")
    if found != version:
        raise ModelError(
            f"lpvflow/{kind} file version {found!r} is not supported (this lpvflow reads version "
            f"{version}); write it again with a matching lpvflow"
        )


register_format("lpvss", LPVSS.from_dict)


def load(path: str | os.PathLike) -> Any:
    """Load any file an lpvflow command writes, by its ``format`` field.

    Models (``lpvflow/lpvio``, ``lpvss``, ``lpvlfr``) and controllers (``lpv-controller``,
    ``lti-controller``) come back as objects; the JSON reports of :data:`REPORT_VERSIONS` (validation,
    simulation, diagnosis, verification, the experiment sidecar, a design's summary and its stage records)
    as dictionaries. A file of another
    version, or not written by lpvflow, is refused with one ModelError line.
    """
    path = Path(path)
    if not path.exists():
        raise ModelError(f"file {str(path)!r} does not exist; check the path")
    try:
        d = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelError(f"{path} is not a lpvflow JSON file ({exc.__class__.__name__})") from None
    fmt = d.get("format", "") if isinstance(d, dict) else ""
    kind = fmt.removeprefix("lpvflow/") if isinstance(fmt, str) and fmt.startswith("lpvflow/") else None
    if kind in REPORT_VERSIONS:
        check_format(d, kind, REPORT_VERSIONS[kind])
        return d
    if kind not in _LOADERS and kind not in LOADER_PATHS:
        known = sorted({*_LOADERS, *LOADER_PATHS, *REPORT_VERSIONS})
        raise ModelError(f"{path}: unknown format {fmt!r}; expected one of "
                         + ", ".join(f"lpvflow/{k}" for k in known))
    return loader(kind)(d)


def loader(kind: str) -> Callable[[dict], Any]:
    """The function that builds an object of file kind ``kind`` (``"lpvio"``, ``"lpvss"``, …) from its
    dictionary: registered, or the :data:`LOADER_PATHS` entry imported on first use."""
    if kind not in _LOADERS:
        module, attribute = LOADER_PATHS[kind].split(":")
        register_format(kind, operator.attrgetter(attribute)(importlib.import_module(module)))
    return _LOADERS[kind]
