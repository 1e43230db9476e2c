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

Every loop here is :func:`lpvflow.loop.engine.close_loop` with the controller's protocol object
(:class:`lpvflow.loop.protocol.LtiLaw`): the model in the loop as the plant :class:`InLoopModel`, the
record's outputs played back (:class:`PlayedBack`) to recover the excitation and the loop's signals.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.scheduling import compile_expression
from lpvflow.loop.engine import close_loop
from lpvflow.loop.protocol import LoopController
from lpvflow.lpvio import LPVIO

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
        return replace(loop, excitation=data.u[:, u_index] - _commands(loop, data.y, data))

    def command(self, law: LoopController, u_c: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The command in the model's input coordinates: ``u_c`` less the trim at θ = ``p`` when the
        trim is removed."""
        return u_c - law.trim(p) if self.trim_removed else u_c

    def plant_outputs(self, y: np.ndarray) -> np.ndarray:
        """The data's outputs ``y`` in the plant's signals (the removed output means added back)."""
        return y if self.output_offset is None else y + self.output_offset


def velocity_sign(y: np.ndarray) -> np.ndarray:
    """sign of the velocity over the *next* sample, extrapolated: 2 y(k) − 3 y(k−1) + y(k−2).

    The friction input enters y(k+1) (delay 1), so it must have the sign of the motion over
    [k, k+1]. The backward difference y(k) − y(k−1) lags by a sample: on the ADIP arm under its
    stabilizing loop (5 ms, 0.04 N·m Coulomb torque) it has the wrong sign at 5.2 % of the samples
    and the fitted level is 0.24 V for 0.31 V; the extrapolated one at 0.4 %, level 0.306 V.
    Missing past samples repeat the first one.
    """
    y = np.asarray(y, float)
    y1 = np.concatenate([y[:1], y[:-1]])
    y2 = np.concatenate([y[:1], y1[:-1]])
    return np.sign(2 * y - 3 * y1 + y2)


def simulate_in_loop(
    model: LPVIO, data: Dataset, loop: Loop,
    input_map: Callable[[np.ndarray], np.ndarray] | None = None,
    exogenous: np.ndarray | None = None,
    sign_of: int | None = None,
) -> np.ndarray:
    """Outputs (N, ny) of ``model`` in ``loop`` over the whole record ``data``, from a zero past.

    The model's input vector is [input_map(u(k)), exogenous(k), sign(y_i(k) − y_i(k−1))] with u the
    plant input (controller output + excitation on the driven inputs, recorded values on the others),
    the last term only with ``sign_of`` = i (Coulomb friction against the motion of output i:
    :func:`velocity_sign` of the simulated output). A model whose closed loop diverges gets ``inf``
    from then on.

    Shifted (LPR) form only: the coefficient of lag j is evaluated at ψ(p(k−j)), so y(k) follows
    from the past; a lag-0 term, B_0(ψ(k)) v(k), is resolved by three fixed-point passes (p(k) and
    u(k) depend on y(k)).
    """
    if model.form != "shifted":
        raise DataError("closed-loop simulation needs the shifted (LPR) form: in the static form the "
                        "coefficients of past outputs depend on the current, simulated scheduling")
    law = loop.controller.loop_law()
    plant = InLoopModel(model, data, loop, input_map, exogenous, sign_of, law)
    y = np.full((data.N, data.y.shape[1]), np.inf)
    offset = loop.plant_outputs(np.zeros(data.y.shape[1]))

    def record(k: int, y_k: np.ndarray, p: np.ndarray, u_c: np.ndarray, u: np.ndarray | None) -> None:
        if u is not None:  # a non-finite command ends the run: the model's loop diverged at k
            y[k] = y_k - offset

    close_loop(law, plant, data.N, _references(loop, data.N), actuate=plant.actuate, record=record,
               respond=plant.respond, passes=plant.passes,
               stop=lambda k, y_k: None if np.all(np.abs(y_k - offset) < DIVERGED) else "diverged")
    return y


class InLoopModel:
    """A shifted-form LPVIO as the plant of :func:`lpvflow.loop.engine.close_loop` over a record (its
    outputs in the plant's signals, :meth:`Loop.plant_outputs`; the recursion in the data's):
    ``outputs()`` is y(k) from the past, −Σ_i A_i(ψ(k−i)) y(k−i) + Σ_{j≥1} B_j(ψ(k−j)) v(k−j);
    ``respond(k, u)`` adds B_0(ψ(k)) v(k) for the present plant input u, with ψ(k) of the scheduling
    recomputed from the output the plant last gave and v(k) = [input_map(u), exogenous(k),
    :func:`velocity_sign` of output ``sign_of``]. ``passes`` (3 with a lag-0 term, else 0) resolves
    that term; a plant whose output was resolved so keeps, at its step, the input it was resolved with
    (the model equation holds at the output the loop saw), otherwise ``step(u)`` makes u its present
    input. ``actuate`` puts the controller's command plus the excitation on the driven inputs and the
    recorded values on the others, less the trim when it is removed (:func:`simulate_in_loop`)."""

    def __init__(self, model: LPVIO, data: Dataset, loop: Loop,
                 input_map: Callable[[np.ndarray], np.ndarray] | None,
                 exogenous: np.ndarray | None, sign_of: int | None, law: LoopController) -> None:
        n, ny = data.N, data.y.shape[1]
        self.model, self.loop, self.input_map, self.sign_of = model, loop, input_map, sign_of
        self.law, self._offset = law, loop.plant_outputs(np.zeros(ny))
        self.input_names, self.output_names = list(data.u_names), list(data.y_names)
        self._u_index, self._computed = _wiring(data, loop)
        self._extra = np.zeros((n, 0)) if exogenous is None else np.asarray(exogenous, float).reshape(n, -1)
        n_a, n_b, n_psi = model.A.shape[0], model.B.shape[0], model.basis.n_psi
        self._a_flat = np.moveaxis(model.A, 1, 0).reshape(n_psi, -1)  # ψ @ a_flat: A_1 … A_na at ψ
        self._b_flat = np.moveaxis(model.B, 1, 0).reshape(n_psi, -1)
        self._a_at = np.zeros((n, n_a, ny, ny))  # A_i(ψ(k)) and B_j(ψ(k)) of every sample
        self._b_at = np.zeros((n, n_b, ny, model.nu))
        self.passes = 3 if np.any(model.B[0]) else 0
        self._u, self._p = data.u.copy(), data.p.copy()
        self._v = np.zeros((n, model.nu))
        self._y = np.full((n, ny), np.inf)
        self._k, self._past, self._resolved = 0, np.zeros(ny), False
        self._last = self._past

    def outputs(self) -> np.ndarray:
        self._last = self._past
        return self._past + self._offset

    def actuate(self, k: int, u_c: np.ndarray, p: np.ndarray) -> np.ndarray:
        u = self._u[k].copy()
        u[self._u_index] = self.loop.command(self.law, u_c, p) + self.loop.excitation[k]
        return u

    def respond(self, k: int, u: np.ndarray) -> np.ndarray:
        self._last = self._past + self._present(u)
        self._resolved = True
        return self._last + self._offset

    def step(self, u: np.ndarray, t: float, dt: float) -> None:
        if not self._resolved:
            self._present(u)
        k = self._k
        self._y[k], self._k, self._resolved = self._last, k + 1, False
        self._past = self._from_past(k + 1)

    def _present(self, u: np.ndarray) -> np.ndarray:
        """Scheduling, plant input and model input at the present sample for the plant input u and the
        output last given; B_0(ψ(k)) v(k)."""
        k, y_k = self._k, self._last
        for i, expression in self._computed:
            self._p[k, i] = expression(y_k + self._offset)
        psi = self.model.basis.eval(self._p[k], check_range=False)[0]
        self._a_at[k] = (psi @ self._a_flat).reshape(self._a_at.shape[1:])
        self._b_at[k] = (psi @ self._b_flat).reshape(self._b_at.shape[1:])
        self._u[k] = u
        parts = [self.input_map(u) if self.input_map is not None else u, self._extra[k]]
        if self.sign_of is not None:
            i = self.sign_of
            recent = np.concatenate([self._y[max(k - 2, 0) : k, i], y_k[i : i + 1]])
            parts.append(velocity_sign(recent)[-1:])
        self._v[k] = np.concatenate(parts)
        return self._b_at[k, 0] @ self._v[k]

    def _from_past(self, k: int) -> np.ndarray:
        """−Σ_i A_i(ψ(k−i)) y(k−i) + Σ_{j≥1} B_j(ψ(k−j)) v(k−j)."""
        past = np.zeros(self._y.shape[1])
        for i in range(1, min(self._a_at.shape[1], k) + 1):
            past -= self._a_at[k - i, i - 1] @ self._y[k - i]
        for j in range(1, min(self._b_at.shape[1] - 1, k) + 1):
            past += self._b_at[k - j, j] @ self._v[k - j]
        return past


def loop_signals(y: np.ndarray, data: Dataset, loop: Loop) -> tuple[np.ndarray, np.ndarray]:
    """Plant input and scheduling of the loop for the output trajectory ``y`` (N, ny) over ``data``.

    u(k) = K(y)(k) + r(k) on the driven inputs (recorded values on the others), the scheduling columns
    with an expression recomputed from y, the others as recorded: the signals :func:`simulate_in_loop`
    fed its model, rebuilt from its output.
    """
    u_index, computed = _wiring(data, loop)
    u, p = data.u.copy(), data.p.copy()
    u[:, u_index] = _commands(loop, y, data) + loop.excitation[: data.N]
    for i, expression in computed:
        p[:, i] = [expression(row) for row in loop.plant_outputs(y)]
    return u, p


class PlayedBack:
    """Output trajectories (N, ny) played back as a plant of :func:`lpvflow.loop.engine.close_loop`:
    ``outputs()`` is the k-th row, the input is ignored."""

    def __init__(self, y: np.ndarray, data: Dataset) -> None:
        self.output_names, self.input_names = list(data.y_names), list(data.u_names)
        self._y, self._k = y, 0

    def outputs(self) -> np.ndarray:
        return self._y[self._k]

    def step(self, u: np.ndarray, t: float, dt: float) -> None:
        self._k += 1


def _commands(loop: Loop, y: np.ndarray, data: Dataset) -> np.ndarray:
    """(N, len(controller.outputs)) commands of ``loop``'s controller run from rest on the outputs ``y``
    (N, ny) (names ``data.y_names``, in the plant's signals :meth:`Loop.plant_outputs`) and the loop's
    references, less the trim when it is removed (:meth:`Loop.command`); NaN after a non-finite command."""
    law = loop.controller.loop_law()
    commands = np.full((len(y), len(loop.controller.outputs)), np.nan)

    def record(k: int, y_k: np.ndarray, p: np.ndarray, u_c: np.ndarray, u: np.ndarray | None) -> None:
        commands[k] = loop.command(law, u_c, p)

    close_loop(law, PlayedBack(loop.plant_outputs(y), data), len(y), _references(loop, len(y)),
               actuate=lambda k, u_c, p: u_c, record=record)
    return commands


def _references(loop: Loop, n: int) -> np.ndarray:
    """The loop's references over n samples (NaN where none: the controller holds its operating point)."""
    if loop.references is None:
        return np.full((n, len(loop.controller.inputs)), np.nan)
    return loop.references[:n]


def _wiring(data: Dataset, loop: Loop) -> tuple[list[int], list[tuple[int, Callable]]]:
    """Columns of the controller's driven inputs in ``data.u``, and the scheduling columns recomputed in
    the loop with their compiled expressions."""
    u_index = [data.u_names.index(name) for name in loop.controller.outputs]
    computed = [(i, compile_expression(loop.scheduling[name], data.y_names))
                for i, name in enumerate(data.p_names) if name in loop.scheduling]
    return u_index, computed
