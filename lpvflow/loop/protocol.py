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

Every controller an experiment runs gives its protocol object with ``loop_law()``: an
``lpvflow/lti-controller`` (:class:`LtiLaw`: u = u_op + C xc + D (y − ȳ), xc⁺ = A xc + B (y − ȳ), ȳ = r,
y_op where r is NaN), a gridded controller (:class:`GriddedLaw`: the same at θ = its scheduling expression
of the measurements and set-points, matrices and operating points interpolated in θ) and a synthesized LPV
controller wired by its port record (:class:`SynthesizedLaw`: u = u_op + u_eq(p) + K(p) w with w = r − y
or [r − y_op; y − y_op], anti-windup applied).

Set-points of an experiment (a signal s per output read, NaN where none is given) reach a law in one of
two ways, each law saying which: as its references (:meth:`LoopController.references_of`), or, for the
LTI law, as a command added to its output (:meth:`LoopController.setpoint_command`: the response of the
law to y_op − s, so that the recorded excitation holds them and the law keeps its operating point).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np

from lpvflow.errors import ModelError

if TYPE_CHECKING:
    from lpvflow.experiment.controller import GriddedController, LtiController
    from lpvflow.experiment.synthesized import SynthesizedController

#: p from one sample of the plant signals the loop names and the references r of that sample.
Schedule = Callable[[np.ndarray, np.ndarray], np.ndarray]


class LoopController(Protocol):
    """The protocol (module docstring)."""

    Ts: float
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    #: (ny,) the level an experiment's set-point signal of each output read starts from.
    setpoint_origin: np.ndarray

    def scheduling(self, names: Sequence[str]) -> Schedule: ...

    def reset(self) -> None: ...

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray: ...

    def trim(self, p: np.ndarray) -> np.ndarray: ...

    def check_plant(self, output_names: Sequence[str], input_names: Sequence[str], model: str) -> None:
        """One error line when the plant ``model`` lacks a signal the controller reads, drives or
        schedules on."""

    def references_of(self, setpoints: np.ndarray) -> np.ndarray:
        """(n, ny) references r handed to :meth:`step` for the set-points (n, ny) (NaN: none given)."""

    def setpoint_command(self, setpoints: np.ndarray) -> np.ndarray | None:
        """(n, nu) command the set-points (n, ny) add to the output, or None: they are references."""


class ExperimentController(Protocol):
    """What an identification experiment runs (:func:`lpvflow.experiment.run.run_experiment`): the plant
    outputs it reads (``inputs``) and the plant inputs it drives (``outputs``), its sampling time, its law
    in the loop protocol (``loop_law()``), its file document (``to_dict()``) and, through the defaults
    below, itself as the controller to run and where a record left its design box.
    :class:`~lpvflow.experiment.controller.LtiController`,
    :class:`~lpvflow.experiment.controller.GriddedController` and
    :class:`~lpvflow.experiment.synthesized.SynthesizedController` are such controllers; a synthesized
    :class:`~lpvflow.synth.controller.LPVController` gives one wired by its port record with its
    ``experiment_controller()``."""

    Ts: float
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]

    def loop_law(self) -> LoopController: ...

    def to_dict(self) -> dict: ...

    def experiment_controller(self) -> ExperimentController:
        """The controller an experiment runs: this one."""
        return self

    def design_box_exit(self, time: np.ndarray, columns: Mapping[str, np.ndarray]) -> str | None:
        """Where a record made under the controller (``columns`` by signal name, sampled at ``time``)
        leaves the scheduling box the controller was designed on, in words; None when it stays inside.

        This default is the answer for a controller designed without a scheduling box: an LTI controller
        (one operating point) and a gridded controller (its gains are a table over its own θ grid, held at
        the end gains beyond it; it records no design box) have no box a record could leave. A controller
        with a design box (:class:`~lpvflow.experiment.synthesized.SynthesizedController`) overrides it."""
        return None


class FeedthroughController(LoopController, Protocol):
    """A controller whose command can be evaluated without advancing its state: ``output(r, y, p)`` is
    what ``step(r, y, p)`` returns (the fixed-point passes of :func:`lpvflow.loop.engine.close_loop`)."""

    def output(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray: ...


class VerificationLaw(Protocol):
    """What verification steps inside its loop adapter (:mod:`lpvflow.pipeline.verify`, whose loop names
    the signals): ``input_of(r, y)`` -> its input w (r − y for ``structure = "1dof"``; for ``"2dof"``
    [r − y_op; y − y_op] of an LPV controller, [r; y] of a controller FMU, which takes its operating
    point off itself); ``step(w, p)`` -> u − u_offset at p; ``feedforward(p)`` the trim u_eq(p); ``n_p``
    the scheduling signals it needs (None: not scheduled), ``design_box`` its design box (None: none
    recorded), ``u_offset`` its own operating point (None: the loop's).
    :class:`~lpvflow.synth.controller.LPVController`, :class:`~lpvflow.loop.fmu_controller.FmuController`
    and :class:`FixedLaw` are such laws."""

    Ts: float
    structure: str
    n_in: int
    n_out: int
    n_p: int | None
    design_box: np.ndarray | None
    u_offset: np.ndarray | None

    def reset(self) -> None: ...

    def input_of(self, r: np.ndarray, y: np.ndarray) -> np.ndarray: ...

    def step(self, w: np.ndarray, p: np.ndarray) -> np.ndarray: ...

    def feedforward(self, p: np.ndarray) -> np.ndarray: ...


class FixedLaw:
    """LTI law u = C x + D (s·e), x⁺ = A x + B (s·e), with s = +1 (e = r − y) or −1 (y − r); 1-DOF, not
    scheduled (no n_p, no design box); ``u_offset`` its operating input (None: the loop's)."""

    structure = "1dof"
    n_p = None
    design_box = None

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, Ts: float, sign: float,
                 u_offset: np.ndarray | None = None) -> None:
        self.A, self.B, self.C, self.D = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (A, B, C, D))
        self.Ts, self.sign, self.u_offset = float(Ts), sign, u_offset
        self.n_in, self.n_out = self.D.shape[1], self.D.shape[0]
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros(self.A.shape[0])

    def input_of(self, r: np.ndarray, y: np.ndarray) -> np.ndarray:
        """e = r − y."""
        return r - y

    def step(self, e: np.ndarray, p: np.ndarray) -> np.ndarray:
        w = self.sign * e
        u = self.C @ self.x + self.D @ w
        self.x = self.A @ self.x + self.B @ w
        return u

    def feedforward(self, p: np.ndarray) -> np.ndarray:
        """No trim apart from the operating point: zero."""
        return np.zeros(self.n_out)


def _held(r: np.ndarray, operating: np.ndarray) -> np.ndarray:
    """The references, the operating point where none is given (NaN)."""
    r = np.asarray(r, dtype=float)
    return np.where(np.isnan(r), operating, r)


def check_names(kind: str, names: Sequence[str], available: Sequence[str], model: str) -> None:
    """One ModelError line when the plant ``model`` lacks one of the ``kind`` signals ``names``."""
    unknown = [n for n in names if n not in available]
    if unknown:
        raise ModelError(f"{kind} {', '.join(map(repr, unknown))} not in FMU {model}; "
                         f"it has {', '.join(available) or 'none'}")


def check_signals(K: LoopController, output_names: Sequence[str], input_names: Sequence[str],
                  model: str) -> None:
    """One ModelError line when the plant ``model`` lacks an output K reads or an input K drives."""
    check_names("controller input (plant output)", K.inputs, output_names, model)
    check_names("controller output (plant input)", K.outputs, input_names, model)


class _TrackingSetpoints:
    """Set-points taken as references (the scheduled laws)."""

    def references_of(self, setpoints: np.ndarray) -> np.ndarray:
        return np.asarray(setpoints, dtype=float)

    def setpoint_command(self, setpoints: np.ndarray) -> None:
        return None


class LtiLaw:
    """An ``lpvflow/lti-controller``: u = u_op + C xc + D (y − ȳ), xc⁺ = A xc + B (y − ȳ), ȳ = r (y_op
    where r is NaN); no scheduling. An experiment's set-points s enter as the command C (zI − A)⁻¹ B + D
    applied to y_op − s (:meth:`setpoint_command`), the references staying at y_op."""

    def __init__(self, K: LtiController) -> None:
        self.K, self.Ts, self.inputs, self.outputs = K, K.Ts, tuple(K.inputs), tuple(K.outputs)
        self.setpoint_origin = K.y_op
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

    def check_plant(self, output_names: Sequence[str], input_names: Sequence[str], model: str) -> None:
        check_signals(self, output_names, input_names, model)

    def references_of(self, setpoints: np.ndarray) -> np.ndarray:
        return np.full(np.shape(setpoints), np.nan)

    def setpoint_command(self, setpoints: np.ndarray) -> np.ndarray:
        shift = np.where(np.isnan(setpoints), 0.0, self.K.y_op - np.asarray(setpoints, dtype=float))
        return self.K.response(shift)


class GriddedLaw(_TrackingSetpoints):
    """A gridded controller: θ = its scheduling expression of the measurements and the set-points
    (0 where no reference is given), the matrices and operating points at θ; ȳ = y_op(θ) with the given
    references in place (:class:`~lpvflow.experiment.controller.GriddedController`). Its set-points are
    signals of their own (they start from 0) and its references."""

    def __init__(self, K: GriddedController) -> None:
        self.K, self.Ts, self.inputs, self.outputs = K, K.Ts, tuple(K.inputs), tuple(K.outputs)
        self.setpoint_origin = np.zeros(len(self.inputs))
        self._theta = K.scheduling_function()
        self.reset()

    def scheduling(self, names: Sequence[str]) -> Schedule:
        index = [list(names).index(name) for name in self.inputs]
        return lambda sample, r: np.array([self._theta(np.concatenate(
            [np.asarray(sample)[index], np.nan_to_num(np.asarray(r, dtype=float), nan=0.0)]))])

    def reset(self) -> None:
        self._x = np.zeros(self.K.order)
        self._matrices: tuple[float, tuple[np.ndarray, ...]] | None = None

    def _at(self, p: np.ndarray) -> tuple[np.ndarray, ...]:
        """K.at(θ = p[0]), interpolated once per θ: a loop asks for it up to three times a sample
        (:meth:`output`, :meth:`step`, :meth:`trim`)."""
        theta = float(p[0])
        if self._matrices is None or self._matrices[0] != theta:
            self._matrices = theta, self.K.at(theta)
        return self._matrices[1]

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        A, B, C, D, y_op, u_op = self._at(p)
        dy = y - _held(r, y_op)
        u = u_op + C @ self._x + D @ dy
        self._x = A @ self._x + B @ dy
        return u

    def output(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        """u(k) at the present state without advancing it (a plant with direct feedthrough:
        :func:`lpvflow.loop.engine.close_loop`)."""
        _, _, C, D, y_op, u_op = self._at(p)
        return u_op + C @ self._x + D @ (y - _held(r, y_op))

    def trim(self, p: np.ndarray) -> np.ndarray:
        return self._at(p)[5]

    def check_plant(self, output_names: Sequence[str], input_names: Sequence[str], model: str) -> None:
        check_signals(self, output_names, input_names, model)


class SynthesizedLaw(_TrackingSetpoints):
    """A synthesized LPV controller wired by its port record
    (:class:`~lpvflow.experiment.synthesized.SynthesizedController`): u = u_op + u_eq(p) + K(p) w, the
    anti-windup range applied; r = y_op where none is given; set-points start from y_op."""

    def __init__(self, K: SynthesizedController) -> None:
        self.K, self.Ts, self.inputs, self.outputs = K, K.Ts, tuple(K.inputs), tuple(K.outputs)
        self.setpoint_origin = K.y_op

    def scheduling(self, names: Sequence[str]) -> Schedule:
        schedule = self.K.scheduling_function(list(names))
        return lambda sample, r: schedule(sample)

    def reset(self) -> None:
        self.K.reset()

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self.K.command(_held(r, self.K.y_op), y, p)

    def trim(self, p: np.ndarray) -> np.ndarray:
        return self.K.trim(p)

    def check_plant(self, output_names: Sequence[str], input_names: Sequence[str], model: str) -> None:
        """The port record's check (:meth:`SynthesizedController.check_plant`, its scheduling included)."""
        self.K.check_plant(output_names, input_names, model)


class OpenLoop(_TrackingSetpoints):
    """No controller (an open-loop experiment): it reads and drives no plant signal."""

    Ts = None
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    setpoint_origin = np.zeros(0)

    def scheduling(self, names: Sequence[str]) -> Schedule:
        return lambda sample, r: np.zeros(0)

    def reset(self) -> None:
        pass

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.zeros(0)

    def trim(self, p: np.ndarray) -> np.ndarray:
        return np.zeros(0)

    def check_plant(self, output_names: Sequence[str], input_names: Sequence[str], model: str) -> None:
        """Nothing to check: it reads and drives nothing."""
