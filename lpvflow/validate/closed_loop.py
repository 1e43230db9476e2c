"""Simulation of an LPV input-output model in the loop of a closed-loop experiment.

Data recorded under a known LTI controller K (:class:`~lpvflow.experiment.controller.LtiController`,
law xc⁺ = A xc + B (y − y_op), u = u_op + C xc + D (y − y_op) + r) cannot be scored by the model's
open-loop simulation when the plant is unstable (the ADIP): the simulation diverges whatever the
model. The model is simulated instead in the identification loop T(Ĝ, K), as the plant ran: the
controller reads the *simulated* outputs, the recorded excitation r is added to its output, and
the model's inputs are made from the simulated plant input u (so an input map, a dead time or a
velocity-sign input of an extension acts on the input the loop produces, not on the recorded one).
A scheduling column that is a function of outputs (quasi-LPV, e.g. ``sin_arm = "sin(arm_angle)"``)
is recomputed from the simulated outputs; other scheduling columns are taken as recorded.

The excitation is recovered from the record itself, r(k) = u(k) − K(y)(k) (the controller run on the
recorded outputs it read), so no excitation column is needed and r is exact up to rounding.

The controller is an ``lpvflow/lti-controller`` or a gain-scheduled ``lpvflow/gridded-controller``
(:class:`~lpvflow.experiment.controller.GriddedController`, scheduled on the outputs it reads and their
set-points: the recorded set-points are its references in every loop). Data identified with the
controller's trim removed (``[identify] remove_trim``: the model input is u − u_op(θ(k))) are run with
the trim at the loop's own θ taken off the command; data with their offsets removed
(``Dataset.offsets``) are run with the controller and the scheduling expressions reading the outputs
plus the removed output means (the plant's signals), the removed input means being part of r.

The loop runs compiled (:mod:`lpvflow.validate.loop_recursion`, numba): the model's recursion, the
scheduling expressions (:mod:`lpvflow.experiment.expression_program`), the controller's law as
:class:`lpvflow.loop.protocol.LtiLaw`/:class:`~lpvflow.loop.protocol.GriddedLaw` state it and the
sampling convention of :func:`lpvflow.loop.engine.close_loop`, at a few microseconds per sample instead
of that engine's Python step; the controller alone on the record's outputs recovers the excitation and
the loop's signals the same way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.expression_program import expression_program, program_values
from lpvflow.loop.protocol import LoopController
from lpvflow.lpvio import LPVIO
from lpvflow.validate.loop_recursion import (
    DEAD_ZONE,
    NO_MAP,
    SATURATION,
    controller_commands,
    simulate_loop,
)
from lpvflow.validate.signal_maps import dead_zone, saturation

#: A simulated state beyond this magnitude means the model's closed loop diverged.
DIVERGED = 1e12


@dataclass(frozen=True)
class Loop:
    """The identification loop of a closed-loop record: controller, excitation, scheduling expressions,
    the controller's references, whether the model's inputs are without its trim, and the output means
    the data's outputs are deviations from (module docstring)."""

    controller: LtiController | GriddedController
    excitation: np.ndarray  # (N, len(controller.outputs)) r(k) over the whole record
    scheduling: Mapping[str, str]  # scheduling column → expression in the output names
    references: np.ndarray | None = None  # (N, len(controller.inputs)) K's references, NaN: none
    trim_removed: bool = False  # the model's inputs are the plant's minus the controller's trim
    output_offset: np.ndarray | None = None  # (ny,) added to the data's outputs to get the plant's

    @classmethod
    def from_record(cls, data: Dataset, controller: LtiController | GriddedController,
                    scheduling: Mapping[str, str] | None = None, setpoints: np.ndarray | None = None,
                    trim_removed: bool = False) -> Loop:
        """The loop of ``data`` (whole record): r(k) = u(k) − K(y, s)(k), K's command on the recorded
        outputs (plus ``data.offsets``' output means) and set-points ``setpoints`` (N, len(controller.inputs),
        NaN where none; default none), less its trim when ``trim_removed``."""
        missing = ([n for n in controller.inputs if n not in data.y_names]
                   + [n for n in controller.outputs if n not in data.u_names])
        if missing:
            raise DataError(f"the controller reads or drives {missing}, which are not outputs/inputs of the "
                            f"data (y {data.y_names}, u {data.u_names})")
        law = controller.loop_law()
        given = np.full((data.N, len(controller.inputs)), np.nan) if setpoints is None else setpoints
        if np.shape(given) != (data.N, len(controller.inputs)):
            raise DataError(f"set-points of shape {np.shape(given)}; the controller reads "
                            f"{len(controller.inputs)} outputs over {data.N} samples")
        offset = np.asarray(data.offsets.get("y", np.zeros(len(data.y_names))), dtype=float)
        loop = cls(controller, np.zeros((data.N, len(controller.outputs))), dict(scheduling or {}),
                   law.references_of(np.asarray(given, dtype=float)), trim_removed, offset)
        u_index = [data.u_names.index(n) for n in controller.outputs]
        commands = _commands(loop, loop.plant_outputs(data.y), data)
        return replace(loop, excitation=data.u[:, u_index] - commands)

    def plant_outputs(self, y: np.ndarray) -> np.ndarray:
        """The data's outputs ``y`` in the plant's signals (the removed output means added back)."""
        return y if self.output_offset is None else y + self.output_offset


def velocity_sign(y: np.ndarray) -> np.ndarray:
    """sign of the velocity over the *next* sample, extrapolated: 2 y(k) − 3 y(k−1) + y(k−2).

    The friction input enters y(k+1) (delay 1), so it must have the sign of the motion over
    [k, k+1]. The backward difference y(k) − y(k−1) lags by a sample: on the ADIP arm under its
    stabilizing loop (5 ms, 0.04 N·m Coulomb torque) it has the wrong sign at 5.2 % of the samples
    and the fitted level is 0.24 V for 0.31 V; the extrapolated one at 0.4 %, level 0.306 V.
    Missing past samples repeat the first one; the first sample, with no past motion, gets 0 (not
    the sign of 2 y(0) − 3 y(0) + y(0)'s rounding), as in the compiled loop.
    """
    y = np.asarray(y, float)
    y1 = np.concatenate([y[:1], y[:-1]])
    y2 = np.concatenate([y[:1], y1[:-1]])
    sign = np.sign(2 * y - 3 * y1 + y2)
    sign[:1] = 0.0
    return sign


def simulate_in_loop(
    model: LPVIO, data: Dataset, loop: Loop,
    input_map: InputMap | None = None,
    exogenous: np.ndarray | None = None,
    sign_of: int | None = None,
    sensor_offset: np.ndarray | None = None,
    integrated: tuple[str, ...] = (),
) -> np.ndarray:
    """Outputs (N, ny) of ``model`` in ``loop`` over the whole record ``data``, from a zero past.

    ``integrated``: outputs the model gives as increments y(k) − y(k−1) (``[identify] increments``); the
    plant's output is their sum from rest, which the controller and the scheduling read and which is
    returned.

    The model's input vector is [input_map(u(k)), exogenous(k), sign(y_i(k) − y_i(k−1))] with u the
    plant input (controller output + excitation on the driven inputs, recorded values on the others),
    the last term only with ``sign_of`` = i (Coulomb friction against the motion of output i:
    :func:`velocity_sign` of the simulated output, 0 at the first sample). A model whose closed loop
    diverges gets ``inf`` from then on.

    ``sensor_offset`` o (ny,): constant sensor offsets, y_meas = y + o. The model's dynamics and the
    scheduling expressions act on its output y, the controller reads y_meas, and y_meas is returned:
    in the loop the offset acts twice (the controller regulates the measured, not the plant's, output).

    Shifted (LPR) form only: the coefficient of lag j is evaluated at ψ(p(k−j)), so y(k) follows
    from the past; a lag-0 term, B_0(ψ(k)) v(k), is resolved by three fixed-point passes (p(k) and
    u(k) depend on y(k)). The recursion is compiled (:func:`lpvflow.validate.loop_recursion.simulate_loop`).
    """
    if model.form != "shifted":
        raise DataError("closed-loop simulation needs the shifted (LPR) form: in the static form the "
                        "coefficients of past outputs depend on the current, simulated scheduling")
    law = loop.controller.loop_law()
    y = InLoopModel(model, data, loop, input_map, exogenous, sign_of, law, sensor_offset,
                    integrated).simulate()
    return y if sensor_offset is None else y + np.asarray(sensor_offset, float)


@dataclass(frozen=True)
class InputMap:
    """A memoryless map of plant input ``index`` in the loop: ``"dead_zone"`` of half-width ``level``,
    sign(u)·max(|u| − w, 0), or ``"saturation"`` at ±``level``; called on one plant-input vector."""

    kind: str
    index: int
    level: float

    def __post_init__(self) -> None:
        if self.kind not in _INPUT_MAPS:
            raise DataError(f"input map {self.kind!r} in the loop; use one of {', '.join(_INPUT_MAPS)}")

    def __call__(self, u: np.ndarray) -> np.ndarray:
        u = np.array(u, dtype=float)
        u[self.index] = (dead_zone if self.kind == "dead_zone" else saturation)(u[self.index], self.level)
        return u


_INPUT_MAPS = {"dead_zone": DEAD_ZONE, "saturation": SATURATION}


class InLoopModel:
    """A shifted-form LPVIO in the loop of a record, as the arrays of the compiled recursion
    (:func:`lpvflow.validate.loop_recursion.simulate_loop`): the model's coefficients and basis, the
    record's inputs and scheduling (the columns with an expression recomputed from the simulated
    outputs in the plant's signals, :meth:`Loop.plant_outputs`), the model's extra inputs
    [``exogenous``, velocity sign of output ``sign_of``] after ``input_map``, and ``law``'s controller
    (an LTI controller as a one-point grid, reading the outputs plus ``sensor_offset``) with the
    loop's references, excitation and trim, the outputs ``integrated`` summed from increments; 3
    fixed-point passes with a lag-0 term, else none (:func:`simulate_in_loop`)."""

    def __init__(self, model: LPVIO, data: Dataset, loop: Loop, input_map: InputMap | None,
                 exogenous: np.ndarray | None, sign_of: int | None, law: LoopController,
                 sensor_offset: np.ndarray | None = None, integrated: tuple[str, ...] = ()) -> None:
        n, ny = data.N, data.y.shape[1]
        extra = np.zeros((n, 0)) if exogenous is None else np.asarray(exogenous, float).reshape(n, -1)
        nv = data.u.shape[1] + extra.shape[1] + (sign_of is not None)
        if model.nu != nv:
            raise DataError(f"the model has {model.nu} inputs; the loop gives it {nv} (the record's "
                            f"{data.u.shape[1]}, {extra.shape[1]} exogenous, {int(sign_of is not None)} "
                            "velocity sign)")
        u_index, computed = _wiring(data, loop)
        columns = [i for i, _ in computed]
        programs = [program for _, program in computed]
        codes = np.concatenate([c for c, _ in programs] + [np.zeros(0, np.int64)])
        arguments = np.concatenate([a for _, a in programs] + [np.zeros(0)])
        starts = np.cumsum([0] + [len(c) for c, _ in programs]).astype(np.int64)
        mapped = ((NO_MAP, -1, 0.0) if input_map is None
                  else (_INPUT_MAPS[input_map.kind], input_map.index, float(input_map.level)))
        self.passes = 3 if np.any(model.B[0]) else 0
        self.integrated = np.array([data.y_names.index(name) for name in integrated], dtype=np.int64)
        self._arguments = (
            np.ascontiguousarray(model.A, float), np.ascontiguousarray(model.B, float),
            _basis_program(model.basis), np.array(data.p, dtype=float, order="C"),
            np.array(columns, dtype=np.int64), (codes, arguments, starts),
            np.ascontiguousarray(data.u, float), np.ascontiguousarray(extra),
            np.asarray(loop.plant_outputs(np.zeros(ny)), float),
            # a writable copy: a read-only offset array is another numba type, a second compile of the loop
            np.zeros(ny) if sensor_offset is None else np.array(sensor_offset, dtype=float).reshape(ny),
            (np.int64(mapped[0]), np.int64(mapped[1]), mapped[2]),
            np.int64(-1 if sign_of is None else sign_of), controller_arrays(law.K),
            np.array([data.y_names.index(name) for name in law.inputs], dtype=np.int64),
            np.array(u_index, dtype=np.int64), np.ascontiguousarray(_references(loop, n), float),
            np.ascontiguousarray(loop.excitation[:n], float), bool(loop.trim_removed))

    def simulate(self) -> np.ndarray:
        """Outputs (N, ny) of the model in the loop, ``inf`` from a divergence on."""
        return simulate_loop(*self._arguments, np.int64(self.passes), float(DIVERGED), self.integrated)


def controller_arrays(K: LtiController | GriddedController) -> tuple:
    """(grid, A, B, C, D, y_op, u_op, codes, arguments) of K for the compiled recursion: its grid
    (:meth:`~lpvflow.experiment.controller.LtiController.as_gridded`: an LTI controller is one grid
    point) and its scheduling program in [outputs read, their set-points]."""
    G = K.as_gridded()
    codes, arguments = expression_program(G.scheduling, G.scheduling_names)
    mats = (G.grid, G.A, G.B, G.C, G.D, G.y_op, G.u_op)
    return (*(np.ascontiguousarray(M, float) for M in mats), codes, arguments)


def _basis_program(basis: Basis) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(exponents, signal, knot) of ψ for :func:`~lpvflow.validate.loop_recursion.simulate_loop`: a
    monomial Π_i p_i^e_i (signal −1) or a spline term |p_signal − knot|³ per basis function."""
    if basis.kind != "spline":
        exponents = np.array(basis.exponents, dtype=np.int64).reshape(basis.n_psi, basis.n_p)
        return exponents, np.full(basis.n_psi, -1, np.int64), np.zeros(basis.n_psi)
    exponents, signal, knot = [np.zeros(basis.n_p, np.int64)], [-1], [0.0]
    for i, knots in enumerate(basis.knots):
        exponents.append(np.eye(basis.n_p, dtype=np.int64)[i])
        signal.append(-1)
        knot.append(0.0)
        for eta in knots:
            exponents.append(np.zeros(basis.n_p, np.int64))
            signal.append(i)
            knot.append(float(eta))
    return np.array(exponents), np.array(signal, dtype=np.int64), np.array(knot)


def loop_signals(y: np.ndarray, data: Dataset, loop: Loop) -> tuple[np.ndarray, np.ndarray]:
    """Plant input and scheduling of the loop for the output trajectory ``y`` (N, ny) over ``data``.

    u(k) = K(y)(k) + r(k) on the driven inputs (recorded values on the others), the scheduling columns
    with an expression recomputed from y, the others as recorded: the signals :func:`simulate_in_loop`
    fed its model, rebuilt from its output.
    """
    u_index = _wiring(data, loop)[0]
    u = data.u.copy()
    plant = np.ascontiguousarray(loop.plant_outputs(np.asarray(y, float)))
    u[:, u_index] = _commands(loop, plant, data) + loop.excitation[: data.N]
    return u, loop_scheduling(y, data, loop)


def loop_scheduling(y: np.ndarray, data: Dataset, loop: Loop) -> np.ndarray:
    """The scheduling of ``data`` with the columns that have an expression in ``loop`` recomputed from
    the output trajectory ``y`` (N, ny) (in the plant's signals, :meth:`Loop.plant_outputs`), the others
    as recorded."""
    p = data.p.copy()
    plant = np.ascontiguousarray(loop.plant_outputs(np.asarray(y, float)))
    for i, program in _wiring(data, loop)[1]:
        p[:, i] = program_values(*program, plant)
    return p


def _commands(loop: Loop, plant: np.ndarray, data: Dataset) -> np.ndarray:
    """(N, len(controller.outputs)) commands of ``loop``'s controller run from rest on the plant outputs
    ``plant`` (N, ny) (names ``data.y_names``, already in the plant's signals :meth:`Loop.plant_outputs`)
    and the loop's references, less the trim u_op(θ) when it is removed; NaN after a non-finite command
    (:func:`lpvflow.validate.loop_recursion.controller_commands`)."""
    read = [data.y_names.index(name) for name in loop.controller.inputs]
    read_outputs = np.ascontiguousarray(plant[:, read])
    references = np.ascontiguousarray(_references(loop, len(plant)), float)
    return controller_commands(controller_arrays(loop.controller), read_outputs, references,
                               bool(loop.trim_removed))


def _references(loop: Loop, n: int) -> np.ndarray:
    """The loop's references over n samples (NaN where none: the controller holds its operating point)."""
    if loop.references is None:
        return np.full((n, len(loop.controller.inputs)), np.nan)
    return loop.references[:n]


def _wiring(data: Dataset, loop: Loop) -> tuple[list[int], list[tuple[int, tuple[np.ndarray, np.ndarray]]]]:
    """Columns of the controller's driven inputs in ``data.u``, and the scheduling columns recomputed in
    the loop with their expressions' programs in the output names
    (:func:`~lpvflow.experiment.expression_program.expression_program`)."""
    u_index = [data.u_names.index(name) for name in loop.controller.outputs]
    computed = [(i, expression_program(loop.scheduling[name], data.y_names))
                for i, name in enumerate(data.p_names) if name in loop.scheduling]
    return u_index, computed
