"""Discrete LTI controller used to stabilise an unstable plant during a closed-loop experiment.

File format ``lpvflow/lti-controller`` version 1 (JSON): ``Ts``, matrices ``A``, ``B``, ``C``, ``D``,
``inputs`` (plant outputs read), ``outputs`` (plant inputs driven), ``y_operating_point``,
``u_operating_point``. The law is

    xc(k+1) = A xc(k) + B (y(k) - y_op),    u(k) = u_op + C xc(k) + D (y(k) - y_op).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lpvflow.errors import ModelError

if TYPE_CHECKING:  # python-control takes ~1 s to import; the controller law needs only numpy
    import control

FORMAT = "lpvflow/lti-controller"
VERSION = 1


@dataclass(frozen=True)
class LtiController:
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
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise ModelError(f"{source} is not of format {FORMAT!r}")
        if doc.get("version") != VERSION:
            raise ModelError(f"{source} has version {doc.get('version')!r}; expected {VERSION}")
        missing = [k for k in ("Ts", "A", "B", "C", "D", "inputs", "outputs") if k not in doc]
        if missing:
            raise ModelError(f"{source} lacks {', '.join(missing)}")
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


def _matrix(doc: dict, key: str, rows: int, cols: int) -> np.ndarray:
    """JSON matrix -> (rows, cols) float array; an empty list stands for a matrix with a zero dimension."""
    value = doc[key]
    if value == [] or value == [[]]:
        return np.zeros((rows, cols))
    try:
        return np.array(value, dtype=float).reshape(np.shape(value)[0], -1)
    except (TypeError, ValueError):
        raise ModelError(f"controller {key} is not a numeric matrix") from None


def load_controller(path: str | Path) -> LtiController:
    """Read a ``lpvflow/lti-controller`` JSON file; refuse other formats and versions."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"controller file {path} does not exist")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ModelError(f"controller file {path} is not valid JSON") from None
    return LtiController.from_dict(doc, f"controller file {path}")
