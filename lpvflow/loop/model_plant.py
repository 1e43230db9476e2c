"""An identified model as the plant of a closed loop (:func:`lpvflow.loop.engine.close_loop`): the
validate stage's closed-loop fit (the model in the identification loop) and the validation along
trajectories (the model in the verification loop) both run it.

The model as a plant is the quasi-LPV simulation

    p(k) = scheduling(y(k)),  x(k+1) = A(p(k)) x(k) + B(p(k)) (u(k) − u₀ − u_trim(y(k))),
    y(k+1) = y₀ + C(p(k)) x(k+1),

u_trim the trim the model was identified without (``[identify] remove_trim``; zero when absent) and
(u₀, y₀) the operating point it was identified around (``[identify] remove_offsets``; zero when absent).
C at p(k) instead of p(k+1) is exact for the observable-form realizations lpvflow identifies (C
independent of p). Strictly proper models only (D = 0, as identified with an input delay): y(k) must not
depend on u(k), which the loop computes from y(k). A diverging model gives non-finite outputs (no
overflow warning); the loop's stopping rule ends the run. The model runs wherever the loop takes its
scheduling, inside or outside the range it was identified on, without a range warning: the loop's record
holds the scheduling it reached (a verification run's coverage says where it left a box).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from lpvflow.errors import ModelError
from lpvflow.experiment.scheduling import compile_expression
from lpvflow.models import LPVSS


class ModelPlant:
    """An :class:`~lpvflow.models.LPVSS` behind the loop's plant protocol (module docstring)."""

    model_name = "identified model"

    def __init__(self, model: LPVSS, scheduling: Sequence[str],
                 trim: Callable[[np.ndarray], np.ndarray] | None = None,
                 offsets: Mapping[str, Sequence[float]] | None = None,
                 start_values: Mapping[str, float] | None = None) -> None:
        """``scheduling``: one expression per model scheduling signal in the model's output names;
        ``trim``: y ↦ u_trim(y) (nu,) of the outputs y (ny,), subtracted from the input; ``offsets``:
        ``{"u": u₀, "y": y₀}`` (either may be absent); ``start_values``: the inputs' values before the
        loop sets them (the plant FMU's start values; 0 for those not given)."""
        if len(scheduling) != model.basis.n_p:
            raise ModelError(f"the model is scheduled on {model.basis.n_p} signal(s) {model.p_names}; "
                             f"give one scheduling expression each, got {len(scheduling)}")
        if np.max(np.abs(model.D), initial=0.0) > 0.0:
            raise ModelError("the model has a feed-through D ≠ 0; the loop needs y(k) before u(k): identify "
                             "it with an input delay nk >= 1")
        self.model = model
        self.input_names, self.output_names = list(model.u_names), list(model.y_names)
        self._scheduling = [compile_expression(e, self.output_names) for e in scheduling]
        self._trim = trim
        offsets = offsets or {}
        self._u0 = np.asarray(offsets.get("u", np.zeros(model.nu)), dtype=float)
        self._y0 = np.asarray(offsets.get("y", np.zeros(len(self.output_names))), dtype=float)
        self._starts = dict(start_values or {})
        self._x = np.zeros(model.nx)
        self._y = self._y0.copy()

    def start_value(self, name: str) -> float:
        return float(self._starts.get(name, 0.0))

    def parameter_values(self) -> dict[str, float | int | bool]:
        return {}

    def outputs(self) -> np.ndarray:
        return self._y.copy()

    def schedule(self, y: np.ndarray) -> np.ndarray:
        """p = scheduling(y) for the outputs y (ny,)."""
        return np.array([value_of(y) for value_of in self._scheduling])

    def rest_at(self, outputs: Mapping[str, float]) -> None:
        """Set the state to rest at the given outputs (name → value; the others free): the least-squares
        (x, v) of x = A(p) x + B(p) v, y₀ + C(p) x = y on the given outputs, p = scheduling(y) with the
        unnamed outputs at y₀. Exact when the frozen model can hold those outputs at a constant input."""
        y = self._y0.copy()
        rows = [self.output_names.index(name) for name in outputs]
        y[rows] = [outputs[name] for name in outputs]
        A, B, C, _ = self.model.matrices(self.schedule(y), check_range=False)
        nx = self.model.nx
        lhs = np.block([[A - np.eye(nx), B], [C[rows], np.zeros((len(rows), B.shape[1]))]])
        rhs = np.concatenate([np.zeros(nx), (y - self._y0)[rows]])
        self._x = np.linalg.lstsq(lhs, rhs, rcond=None)[0][:nx]
        self._y = self._y0 + C @ self._x

    def step(self, u: np.ndarray, t: float, Ts: float) -> None:
        p = self.schedule(self._y)
        A, B, C, _ = self.model.matrices(p, check_range=False)
        trim = self._trim(self._y) if self._trim is not None else 0.0
        u_model = np.asarray(u, dtype=float) - self._u0 - trim
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model ends its run (non-finite y)
            self._x = A @ self._x + B @ u_model
            self._y = self._y0 + C @ self._x

    def close(self) -> None:
        """Nothing to release."""
