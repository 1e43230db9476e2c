"""Discrete LTI controller used to stabilise an unstable plant during a closed-loop experiment.

File format ``lpvflow/lti-controller`` version 1 (JSON): ``Ts``, matrices ``A``, ``B``, ``C``, ``D``,
``inputs`` (plant outputs read), ``outputs`` (plant inputs driven), ``y_operating_point``,
``u_operating_point``. The law is

    xc(k+1) = A xc(k) + B (y(k) - y_op),    u(k) = u_op + C xc(k) + D (y(k) - y_op).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lpvflow.errors import DataError, ModelError
from lpvflow.loop.protocol import ExperimentController, FixedLaw, GriddedLaw, LtiLaw

if TYPE_CHECKING:  # python-control takes ~1 s to import; the controller law needs only numpy
    import control

FORMAT = "lpvflow/lti-controller"
VERSION = 1


@dataclass(frozen=True)
class LtiController(ExperimentController):
    """xc(k+1) = A xc + B (y - y_op), u = u_op + C xc + D (y - y_op), sampled at Ts."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    Ts: float
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    y_op: np.ndarray
    u_op: np.ndarray

    #: The law is the same at every operating point (no scheduling, a constant trim u_op).
    scheduled = False
    #: Scheduled on no signal.
    n_p = None

    def __post_init__(self) -> None:
        n, ny, nu = self.A.shape[0], len(self.inputs), len(self.outputs)
        expected = {"A": (n, n), "B": (n, ny), "C": (nu, n), "D": (nu, ny), "y_operating_point": (ny,),
                    "u_operating_point": (nu,)}
        actual = {"A": self.A.shape, "B": self.B.shape, "C": self.C.shape, "D": self.D.shape,
                  "y_operating_point": self.y_op.shape, "u_operating_point": self.u_op.shape}
        for key, shape in expected.items():
            if actual[key] != shape:
                raise ModelError(
                    f"controller {key} has shape {actual[key]}, expected {shape} for {n} states, "
                    f"{ny} inputs, {nu} outputs"
                )
        if not (np.isfinite(self.Ts) and self.Ts > 0):
            raise ModelError(f"controller Ts={self.Ts} must be a positive sampling time (discrete)")
        for key, value in (("A", self.A), ("B", self.B), ("C", self.C), ("D", self.D),
                           ("y_operating_point", self.y_op), ("u_operating_point", self.u_op)):
            if not np.all(np.isfinite(value)):
                raise ModelError(f"controller {key} has non-finite entries")

    @classmethod
    def from_statespace(
        cls,
        sys: control.StateSpace,
        inputs: list[str] | None = None,
        outputs: list[str] | None = None,
        y_op: np.ndarray | None = None,
        u_op: np.ndarray | None = None,
    ) -> LtiController:
        """Wrap a discrete python-control StateSpace; names default to its input/output labels,
        operating points to zero."""
        if not sys.isdtime(strict=True):
            raise ModelError("controller StateSpace must be discrete (dt > 0); discretise it first")
        inputs = list(sys.input_labels if inputs is None else inputs)
        outputs = list(sys.output_labels if outputs is None else outputs)
        return cls(
            A=np.asarray(sys.A, float), B=np.asarray(sys.B, float), C=np.asarray(sys.C, float),
            D=np.asarray(sys.D, float), Ts=float(sys.dt), inputs=tuple(inputs), outputs=tuple(outputs),
            y_op=np.zeros(len(inputs)) if y_op is None else np.asarray(y_op, float).reshape(-1),
            u_op=np.zeros(len(outputs)) if u_op is None else np.asarray(u_op, float).reshape(-1),
        )

    def loop_law(self) -> LtiLaw:
        """The controller in the loop protocol (:class:`lpvflow.loop.protocol.LtiLaw`)."""
        return LtiLaw(self)

    def verification_law(self, measured: Sequence[str], actuated: Sequence[str]) -> FixedLaw:
        """The law verification steps in a loop that measures ``measured`` and drives ``actuated``
        (:class:`lpvflow.loop.protocol.FixedLaw` on y − r, its own u_op); one ModelError line when they
        are not the signals it reads and drives."""
        if tuple(self.inputs) != tuple(measured) or tuple(self.outputs) != tuple(actuated):
            raise ModelError(f"the LTI controller reads {list(self.inputs)} and drives "
                             f"{list(self.outputs)}; the loop measures {list(measured)} and drives "
                             f"{list(actuated)}: they must match")
        return FixedLaw(self.A, self.B, self.C, self.D, self.Ts, -1.0, self.u_op)

    def close(self) -> None:
        """Nothing to release (the controller holds no instance or file)."""

    def as_gridded(self) -> GriddedController:
        """The same law as a gridded controller of one grid point (θ = 0, scheduling "0")."""
        return GriddedController(grid=np.zeros(1), A=self.A[None], B=self.B[None], C=self.C[None],
                                 D=self.D[None], y_op=self.y_op[None], u_op=self.u_op[None], Ts=self.Ts,
                                 inputs=self.inputs, outputs=self.outputs, scheduling="0")

    def frozen(self, p: np.ndarray) -> control.StateSpace:
        """The law on e = r − y (its operating points dropped), the same at every p: K in u = −K y over
        its own signals (:meth:`negative_feedback`), as :meth:`LPVController.frozen` of a 1-DOF law."""
        return self.negative_feedback()

    def trim_along(self, columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        """(n, nu) trim of the first n samples of a record: the constant u_op (``columns`` unused)."""
        return np.broadcast_to(self.u_op, (n, len(self.u_op)))

    def response(self, w: np.ndarray) -> np.ndarray:
        """The controller's outputs (N, n_u) for the input sequence ``w`` (N, n_y) from rest, without the
        operating points: xc(k+1) = A xc(k) + B w(k), v(k) = C xc(k) + D w(k)."""
        xc = np.zeros(self.A.shape[0])
        out = np.empty((len(w), self.C.shape[0]))
        for k, w_k in enumerate(w):
            out[k] = self.C @ xc + self.D @ w_k
            xc = self.A @ xc + self.B @ w_k
        return out

    def negative_feedback(
        self, y_names: list[str] | None = None, u_names: list[str] | None = None,
    ) -> control.StateSpace:
        """The law as K in u = −K y (the convention of :mod:`lpvflow.validate.margins`), from the plant
        outputs ``y_names`` to the plant inputs ``u_names`` (default: the controller's own signals);
        channels the controller does not read or drive get zero gain. Operating points are dropped."""
        import control

        y_names = list(self.inputs) if y_names is None else list(y_names)
        u_names = list(self.outputs) if u_names is None else list(u_names)
        cols = [y_names.index(n) for n in self.inputs]
        rows = [u_names.index(n) for n in self.outputs]
        n = self.A.shape[0]
        B, C = np.zeros((n, len(y_names))), np.zeros((len(u_names), n))
        D = np.zeros((len(u_names), len(y_names)))
        B[:, cols], C[rows] = self.B, self.C
        D[np.ix_(rows, cols)] = self.D
        return control.ss(self.A, B, -C, -D, self.Ts)

    @classmethod
    def from_dict(cls, doc: dict, source: str = "controller") -> LtiController:
        """The controller of a ``lpvflow/lti-controller`` document (``source`` names it in errors)."""
        _check_document(doc, FORMAT, VERSION, ("Ts", "A", "B", "C", "D", "inputs", "outputs"), source)
        inputs, outputs = tuple(doc["inputs"]), tuple(doc["outputs"])
        A = _matrix(doc, "A", 0, 0)
        n = A.shape[0]
        return cls(
            A=A, B=_matrix(doc, "B", n, len(inputs)), C=_matrix(doc, "C", len(outputs), n),
            D=_matrix(doc, "D", len(outputs), len(inputs)), Ts=float(doc["Ts"]), inputs=inputs,
            outputs=outputs,
            y_op=np.asarray(doc.get("y_operating_point", [0.0] * len(inputs)), float).reshape(-1),
            u_op=np.asarray(doc.get("u_operating_point", [0.0] * len(outputs)), float).reshape(-1),
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "format": FORMAT, "version": VERSION, "Ts": self.Ts,
            "A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(), "D": self.D.tolist(),
            "inputs": list(self.inputs), "outputs": list(self.outputs),
            "y_operating_point": self.y_op.tolist(), "u_operating_point": self.u_op.tolist(),
        }


def _check_document(doc: object, fmt: str, version: int, keys: tuple[str, ...], source: str) -> None:
    """One ModelError line when ``doc`` is not a ``fmt`` document of ``version`` holding ``keys``."""
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise ModelError(f"{source} is not of format {fmt!r}")
    if doc.get("version") != version:
        raise ModelError(f"{source} has version {doc.get('version')!r}; expected {version}")
    missing = [k for k in keys if k not in doc]
    if missing:
        raise ModelError(f"{source} lacks {', '.join(missing)}")


def _matrix(doc: dict, key: str, rows: int, cols: int) -> np.ndarray:
    """JSON matrix -> (rows, cols) float array; an empty list stands for a matrix with a zero dimension."""
    value = doc[key]
    if value == [] or value == [[]]:
        return np.zeros((rows, cols))
    try:
        return np.array(value, dtype=float).reshape(np.shape(value)[0], -1)
    except (TypeError, ValueError):
        raise ModelError(f"controller {key} is not a numeric matrix") from None


def read_controller_json(path: Path) -> object:
    """The parsed JSON of a controller file; ModelError when it is missing or not JSON."""
    if not path.is_file():
        raise ModelError(f"controller file {path} does not exist")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ModelError(f"controller file {path} is not valid JSON") from None


def load_controller(path: str | Path) -> LtiController:
    """Read a ``lpvflow/lti-controller`` JSON file; refuse other formats and versions."""
    path = Path(path)
    return LtiController.from_dict(read_controller_json(path), f"controller file {path}")


# ------------------------------------------------------------------------------ gridded (scheduled)
GRIDDED_FORMAT = "lpvflow/gridded-controller"
GRIDDED_VERSION = 1


@dataclass(frozen=True)
class GriddedController(ExperimentController):
    """A gain-scheduled controller given on a grid of one scheduling value θ (format
    ``lpvflow/gridded-controller`` version 1): per grid point θ_i the matrices A_i, B_i, C_i, D_i and the
    operating points y_op,i (of the plant outputs read) and u_op,i (the trim of the plant inputs driven).

    θ(k) is ``scheduling``, an expression (:mod:`lpvflow.experiment.scheduling`) of the plant outputs
    the controller reads (their measurements) and of ``<output>_setpoint`` for each of them (the set-point
    of that output in the experiment, 0 where none is given), clipped to the grid; every matrix and
    operating point is interpolated linearly in θ between neighbouring grid points. Scheduling on a
    set-point (the reference of a slow sweep) keeps the trim and the gains independent of the
    measurement noise and of the loop's own motion. With ȳ(k) = y_op(θ(k)), where a set-point s replaces
    the entries of the outputs it is given for,

        xc(k+1) = A(θ) xc(k) + B(θ) (y(k) − ȳ(k)),    u(k) = u_op(θ) + C(θ) xc(k) + D(θ) (y(k) − ȳ(k)).
    """

    grid: np.ndarray  # (G,) increasing
    A: np.ndarray  # (G, n, n)
    B: np.ndarray  # (G, n, ny)
    C: np.ndarray  # (G, nu, n)
    D: np.ndarray  # (G, nu, ny)
    y_op: np.ndarray  # (G, ny)
    u_op: np.ndarray  # (G, nu)
    Ts: float
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    scheduling: str
    description: str = ""

    #: The law depends on θ (matrices and trim interpolated on the grid).
    scheduled = True

    def __post_init__(self) -> None:
        G = len(self.grid)
        if G < 1 or self.grid.ndim != 1 or not np.all(np.diff(self.grid) > 0):
            raise ModelError("gridded controller grid must be a non-empty list of increasing numbers")
        n, ny, nu = self.A.shape[1], len(self.inputs), len(self.outputs)
        expected = {"A": (G, n, n), "B": (G, n, ny), "C": (G, nu, n), "D": (G, nu, ny),
                    "y_operating_point": (G, ny), "u_operating_point": (G, nu)}
        actual = {"A": self.A.shape, "B": self.B.shape, "C": self.C.shape, "D": self.D.shape,
                  "y_operating_point": self.y_op.shape, "u_operating_point": self.u_op.shape}
        for key, shape in expected.items():
            if actual[key] != shape:
                raise ModelError(f"gridded controller {key} has shape {actual[key]}, expected {shape} for "
                                 f"{G} grid points, {n} states, {ny} inputs, {nu} outputs")
        if not (np.isfinite(self.Ts) and self.Ts > 0):
            raise ModelError(f"controller Ts={self.Ts} must be a positive sampling time (discrete)")
        for key, value in (("grid", self.grid), ("A", self.A), ("B", self.B), ("C", self.C), ("D", self.D),
                           ("y_operating_point", self.y_op), ("u_operating_point", self.u_op)):
            if not np.all(np.isfinite(value)):
                raise ModelError(f"gridded controller {key} has non-finite entries")
        from lpvflow.experiment.scheduling import evaluate

        try:
            evaluate(self.scheduling, {name: np.zeros(1) for name in self.scheduling_names})
        except DataError as exc:
            raise ModelError(f"gridded controller scheduling: {exc} (it may use the signals it reads and "
                             "their <name>_setpoint)") from None

    @property
    def order(self) -> int:
        return self.A.shape[1]

    def loop_law(self) -> GriddedLaw:
        """The controller in the loop protocol (:class:`lpvflow.loop.protocol.GriddedLaw`)."""
        return GriddedLaw(self)

    @property
    def scheduling_names(self) -> list[str]:
        """The names the scheduling expression may use: the outputs read, then their set-points."""
        return [*self.inputs, *(f"{name}_setpoint" for name in self.inputs)]

    def weights(self, theta: float) -> tuple[int, float]:
        """(i, t): θ clipped to the grid lies between grid[i] and grid[i + 1] at fraction t."""
        grid = self.grid
        if len(grid) == 1 or theta <= grid[0]:
            return 0, 0.0
        if theta >= grid[-1]:
            return len(grid) - 2, 1.0
        i = int(np.searchsorted(grid, theta, side="right")) - 1
        return i, float((theta - grid[i]) / (grid[i + 1] - grid[i]))

    def at(self, theta: float) -> tuple[np.ndarray, ...]:
        """(A, B, C, D, y_op, u_op) interpolated at θ (clipped to the grid)."""
        i, t = self.weights(float(theta))
        j = min(i + 1, len(self.grid) - 1)
        mats = (self.A, self.B, self.C, self.D, self.y_op, self.u_op)
        return tuple((1 - t) * M[i] + t * M[j] for M in mats)

    def trim_along(self, columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        """(n, nu) trim u_op(θ(k)) of the first n samples of a record, θ(k) the scheduling expression of
        its columns (the measurements read and their ``<output>_setpoint``, 0 where not recorded), u_op
        interpolated linearly on the grid and clipped at its ends, as the controller ran (:meth:`at`)."""
        from lpvflow.experiment.scheduling import evaluate

        signals = {name: columns[name][:n] for name in self.inputs}
        signals |= {f"{name}_setpoint": columns.get(f"{name}_setpoint", np.zeros(n))[:n]
                    for name in self.inputs}
        theta = np.broadcast_to(evaluate(self.scheduling, signals), (n,))
        return np.column_stack([np.interp(theta, self.grid, column) for column in self.u_op.T])

    def scheduling_function(self):
        """θ as a function of one sample of [outputs read, their set-points] (:attr:`scheduling_names`)."""
        from lpvflow.experiment.scheduling import compile_expression

        return compile_expression(self.scheduling, self.scheduling_names)

    def as_gridded(self) -> GriddedController:
        """Itself (:meth:`LtiController.as_gridded` gives an LTI controller's one-point grid)."""
        return self

    def frozen_at(self, theta: float) -> LtiController:
        """The LTI controller frozen at θ, with that point's operating points."""
        A, B, C, D, y_op, u_op = self.at(theta)
        return LtiController(A=A, B=B, C=C, D=D, Ts=self.Ts, inputs=self.inputs, outputs=self.outputs,
                             y_op=y_op, u_op=u_op)

    def linearized(self, y: np.ndarray, setpoints: np.ndarray | None = None) -> LtiController:
        """The law linearized at the outputs ``y`` (``inputs`` order) and set-points (default: y):
        frozen at θ(y, setpoints), plus the trim's feedback (∂u_op/∂θ)(∂θ/∂y) in D when θ depends on
        the measurements (a trim scheduled on a measured angle acts as a static feedback of it). The
        matrices' own dependence on θ acts on the controller state and is left out (frozen analysis)."""
        y = np.asarray(y, dtype=float).reshape(-1)
        setpoints = y if setpoints is None else np.asarray(setpoints, dtype=float).reshape(-1)
        theta_of = self.scheduling_function()
        theta = theta_of(np.concatenate([y, setpoints]))
        frozen = self.frozen_at(theta)
        step = 1e-6
        du_dtheta = (self.at(theta + step)[5] - self.at(theta - step)[5]) / (2 * step)
        dtheta_dy = np.array([(theta_of(np.concatenate([y + step * e, setpoints]))
                               - theta_of(np.concatenate([y - step * e, setpoints]))) / (2 * step)
                              for e in np.eye(len(y))])
        return replace(frozen, D=frozen.D + np.outer(du_dtheta, dtheta_dy))

    def operating_laws(self, outputs: Mapping[str, float]) -> tuple[LtiController, LtiController]:
        """(linearized, frozen) at the plant outputs ``outputs`` (name → value) with the set-points equal
        to them: :meth:`linearized` there and the law :meth:`frozen_at` its θ there."""
        read = np.array([outputs[name] for name in self.inputs], dtype=float)
        theta = self.scheduling_function()(np.concatenate([read, read]))
        return self.linearized(read), self.frozen_at(theta)

    def negative_feedback(
        self, y_names: list[str] | None = None, u_names: list[str] | None = None, theta: float = 0.0,
    ) -> control.StateSpace:
        """The law frozen at θ as K in u = −K y (:meth:`LtiController.negative_feedback`)."""
        return self.frozen_at(theta).negative_feedback(y_names, u_names)

    @classmethod
    def from_dict(cls, doc: dict, source: str = "controller") -> GriddedController:
        """The controller of a ``lpvflow/gridded-controller`` document (``source`` names it in errors)."""
        _check_document(doc, GRIDDED_FORMAT, GRIDDED_VERSION,
                        ("Ts", "inputs", "outputs", "scheduling", "grid", "points"), source)
        points = doc["points"]
        if not isinstance(points, list) or len(points) != len(doc["grid"]) or not points:
            raise ModelError(f"{source}: 'points' must hold one entry per grid value")
        inputs, outputs = tuple(doc["inputs"]), tuple(doc["outputs"])
        mats: dict[str, list[np.ndarray]] = {k: [] for k in ("A", "B", "C", "D", "y", "u")}
        for i, point in enumerate(points):
            lacking = [k for k in ("A", "B", "C", "D") if k not in point]
            if lacking:
                raise ModelError(f"{source}: grid point {i} lacks {', '.join(lacking)}")
            A = _matrix(point, "A", 0, 0)
            n = A.shape[0]
            mats["A"].append(A)
            mats["B"].append(_matrix(point, "B", n, len(inputs)))
            mats["C"].append(_matrix(point, "C", len(outputs), n))
            mats["D"].append(_matrix(point, "D", len(outputs), len(inputs)))
            y_op = point.get("y_operating_point", [0.0] * len(inputs))
            u_op = point.get("u_operating_point", [0.0] * len(outputs))
            mats["y"].append(np.asarray(y_op, float).reshape(-1))
            mats["u"].append(np.asarray(u_op, float).reshape(-1))
        try:
            stacked = {k: np.stack(v) for k, v in mats.items()}
        except ValueError:
            raise ModelError(f"{source}: the grid points' matrices differ in size") from None
        return cls(grid=np.asarray(doc["grid"], float).reshape(-1), A=stacked["A"], B=stacked["B"],
                   C=stacked["C"], D=stacked["D"], y_op=stacked["y"], u_op=stacked["u"], Ts=float(doc["Ts"]),
                   inputs=inputs, outputs=outputs, scheduling=str(doc["scheduling"]),
                   description=str(doc.get("description", "")))

    def to_dict(self) -> dict[str, object]:
        points = [{"A": self.A[i].tolist(), "B": self.B[i].tolist(), "C": self.C[i].tolist(),
                   "D": self.D[i].tolist(), "y_operating_point": self.y_op[i].tolist(),
                   "u_operating_point": self.u_op[i].tolist()} for i in range(len(self.grid))]
        return {"format": GRIDDED_FORMAT, "version": GRIDDED_VERSION, "Ts": self.Ts,
                "inputs": list(self.inputs), "outputs": list(self.outputs), "scheduling": self.scheduling,
                "grid": self.grid.tolist(), "points": points, "description": self.description}


