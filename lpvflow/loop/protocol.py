"""One controller protocol for every closed loop lpvflow runs (experiment, model-in-the-loop validation,
verification): ``reset()`` and ``step(r, y, p) -> u``, with the same meaning for every controller kind.

At sample k the loop hands the controller

* ``r`` (ny,): the references of the plant outputs it reads, in :attr:`inputs` order; NaN where none is
  given (the controller then holds its own operating point of that output);
* ``y`` (ny,): their measurements;
* ``p`` (n_p,): its scheduling values, computed by the loop with :meth:`scheduling` from the plant
  signals of that sample and ``r``;

and gets ``u`` (nu,): the command of the plant inputs it drives (:attr:`outputs`), operating point and
trim included, before the actuator limits. ``step`` advances the controller state to k + 1; ``trim(p)``
is the part of ``u`` that does not depend on the state and the error (operating point and trim at p).

Adapters (:func:`as_loop_controller`): an ``lpvflow/lti-controller`` (:class:`LtiLaw`: u = u_op + C xc +
D (y − ȳ), xc⁺ = A xc + B (y − ȳ), ȳ = r, y_op where r is NaN), a gridded controller (:class:`GriddedLaw`:
the same at θ = its scheduling expression of the measurements and set-points, matrices and operating
points interpolated in θ) and a synthesized LPV controller wired by its port record
(:class:`SynthesizedLaw`: u = u_op + u_eq(p) + K(p) w with w = r − y or [r − y_op; y − y_op], anti-windup
applied).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from lpvflow.errors import ModelError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.synthesized import SynthesizedController

#: p from one sample of the plant signals the loop names and the references r of that sample.
Schedule = Callable[[np.ndarray, np.ndarray], np.ndarray]


class LoopController(Protocol):
    """The protocol (module docstring)."""

    Ts: float
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]

    def scheduling(self, names: Sequence[str]) -> Schedule: ...

    def reset(self) -> None: ...

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray: ...

    def trim(self, p: np.ndarray) -> np.ndarray: ...


class FeedthroughController(LoopController, Protocol):
    """A controller whose command can be evaluated without advancing its state: ``output(r, y, p)`` is
    what ``step(r, y, p)`` returns (the fixed-point passes of :func:`lpvflow.loop.engine.close_loop`)."""

    def output(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray: ...


def _held(r: np.ndarray, operating: np.ndarray) -> np.ndarray:
    """The references, the operating point where none is given (NaN)."""
    r = np.asarray(r, dtype=float)
    return np.where(np.isnan(r), operating, r)


class LtiLaw:
    """An ``lpvflow/lti-controller``: u = u_op + C xc + D (y − ȳ), xc⁺ = A xc + B (y − ȳ), ȳ = r (y_op
    where r is NaN); no scheduling."""

    def __init__(self, K: LtiController) -> None:
        self.K, self.Ts, self.inputs, self.outputs = K, K.Ts, tuple(K.inputs), tuple(K.outputs)
        # one product per step: [xc(k+1); u(k) − u_op] = [[A, B], [C, D]] [xc(k); y(k) − ȳ(k)]
        self._law = np.block([[K.A, K.B], [K.C, K.D]])
        self._nx = K.A.shape[0]
        self.reset()

    def scheduling(self, names: Sequence[str]) -> Schedule:
        return lambda sample, r: np.zeros(0)

    def reset(self) -> None:
        self._w = np.zeros(self._nx + len(self.inputs))

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        np.subtract(y, _held(r, self.K.y_op), out=self._w[self._nx:])
        z = self._law @ self._w
        self._w[: self._nx] = z[: self._nx]
        return self.K.u_op + z[self._nx:]

    def output(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        """u(k) = u_op + C xc(k) + D (y − ȳ) at the present state, without advancing it (the fixed-point
        passes of a plant with direct feedthrough: :func:`lpvflow.loop.engine.close_loop`)."""
        w = self._w.copy()
        w[self._nx:] = y - _held(r, self.K.y_op)
        return self.K.u_op + self._law[self._nx:] @ w

    def trim(self, p: np.ndarray) -> np.ndarray:
        return self.K.u_op


class GriddedLaw:
    """A gridded controller: θ = its scheduling expression of the measurements and the set-points
    (0 where no reference is given), the matrices and operating points at θ; ȳ = y_op(θ) with the given
    references in place (:class:`~lpvflow.experiment.controller.GriddedController`)."""

    def __init__(self, K: GriddedController) -> None:
        self.K, self.Ts, self.inputs, self.outputs = K, K.Ts, tuple(K.inputs), tuple(K.outputs)
        self._theta = K.scheduling_function()
        self.reset()

    def scheduling(self, names: Sequence[str]) -> Schedule:
        index = [list(names).index(name) for name in self.inputs]
        return lambda sample, r: np.array([self._theta(np.concatenate(
            [np.asarray(sample)[index], np.nan_to_num(np.asarray(r, dtype=float), nan=0.0)]))])

    def reset(self) -> None:
        self._x = np.zeros(self.K.order)

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        A, B, C, D, y_op, u_op = self.K.at(p[0])
        dy = y - _held(r, y_op)
        u = u_op + C @ self._x + D @ dy
        self._x = A @ self._x + B @ dy
        return u

    def trim(self, p: np.ndarray) -> np.ndarray:
        return self.K.at(p[0])[5]


class SynthesizedLaw:
    """A synthesized LPV controller wired by its port record
    (:class:`~lpvflow.experiment.synthesized.SynthesizedController`): u = u_op + u_eq(p) + K(p) w, the
    anti-windup range applied; r = y_op where none is given."""

    def __init__(self, K: SynthesizedController) -> None:
        self.K, self.Ts, self.inputs, self.outputs = K, K.Ts, tuple(K.inputs), tuple(K.outputs)

    def scheduling(self, names: Sequence[str]) -> Schedule:
        schedule = self.K.scheduling_function(list(names))
        return lambda sample, r: schedule(sample)

    def reset(self) -> None:
        self.K.reset()

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self.K.command(_held(r, self.K.y_op), y, p)

    def trim(self, p: np.ndarray) -> np.ndarray:
        return self.K.trim(p)


class OpenLoop:
    """No controller (an open-loop experiment): it reads and drives no plant signal."""

    Ts = None
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()

    def scheduling(self, names: Sequence[str]) -> Schedule:
        return lambda sample, r: np.zeros(0)

    def reset(self) -> None:
        pass

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.zeros(0)

    def trim(self, p: np.ndarray) -> np.ndarray:
        return np.zeros(0)


def as_loop_controller(K: LtiController | GriddedController | SynthesizedController) -> LoopController:
    """The protocol object of an experiment controller."""
    if isinstance(K, LtiController):
        return LtiLaw(K)
    if isinstance(K, GriddedController):
        return GriddedLaw(K)
    if isinstance(K, SynthesizedController):
        return SynthesizedLaw(K)
    raise ModelError(f"cannot run a {type(K).__name__} in a loop; give an lpvflow/lti-controller, "
                     "lpvflow/gridded-controller or lpvflow/lpv-controller")
