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
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.controller import LtiController
from lpvflow.experiment.scheduling import compile_expression
from lpvflow.lpvio import LPVIO

#: A simulated state beyond this magnitude means the model's closed loop diverged.
DIVERGED = 1e12


@dataclass(frozen=True)
class Loop:
    """The identification loop of a closed-loop record: controller, excitation, scheduling expressions."""

    controller: LtiController
    excitation: np.ndarray  # (N, len(controller.outputs)) r(k) over the whole record
    scheduling: Mapping[str, str]  # scheduling column → expression in the output names

    @classmethod
    def from_record(cls, data: Dataset, controller: LtiController,
                    scheduling: Mapping[str, str] | None = None) -> Loop:
        """The loop of ``data`` (whole record): r(k) = u(k) − u_op − C xc(k) − D (y(k) − y_op)."""
        missing = ([n for n in controller.inputs if n not in data.y_names]
                   + [n for n in controller.outputs if n not in data.u_names])
        if missing:
            raise DataError(f"the controller reads or drives {missing}, which are not outputs/inputs of the "
                            f"data (y {data.y_names}, u {data.u_names})")
        y_index = [data.y_names.index(n) for n in controller.inputs]
        u_index = [data.u_names.index(n) for n in controller.outputs]
        law = controller.u_op + controller.response(data.y[:, y_index] - controller.y_op)
        return cls(controller, data.u[:, u_index] - law, dict(scheduling or {}))


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
    K = loop.controller
    n, ny = data.N, data.y.shape[1]
    y_index, u_index, computed = _wiring(data, loop)
    extra = np.zeros((n, 0)) if exogenous is None else np.asarray(exogenous, float).reshape(n, -1)
    n_a, n_b, n_psi = model.A.shape[0], model.B.shape[0], model.basis.n_psi
    a_flat = np.moveaxis(model.A, 1, 0).reshape(n_psi, -1)  # ψ @ a_flat = A_1 … A_na at ψ, flattened
    b_flat = np.moveaxis(model.B, 1, 0).reshape(n_psi, -1)
    a_at = np.zeros((n, n_a, ny, ny))  # A_i(ψ(k)) and B_j(ψ(k)) of every sample
    b_at = np.zeros((n, n_b, ny, model.nu))
    has_b0 = bool(np.any(model.B[0]))
    u, p = data.u.copy(), data.p.copy()
    v = np.zeros((n, model.nu))
    y = np.full((n, ny), np.inf)
    xc = np.zeros(K.A.shape[0])

    def close(k: int, y_k: np.ndarray) -> np.ndarray:
        """Scheduling, plant input and model input at k for the output y_k; B_0(ψ(k)) v(k)."""
        for i, expression in computed:
            p[k, i] = expression(y_k)
        psi = model.basis.eval(p[k], check_range=False)[0]
        a_at[k] = (psi @ a_flat).reshape(a_at.shape[1:])
        b_at[k] = (psi @ b_flat).reshape(b_at.shape[1:])
        u[k, u_index] = K.u_op + K.C @ xc + K.D @ (y_k[y_index] - K.y_op) + loop.excitation[k]
        mapped = input_map(u[k]) if input_map is not None else u[k]
        parts = [mapped, extra[k]]
        if sign_of is not None:
            recent = np.concatenate([y[max(k - 2, 0) : k, sign_of], y_k[sign_of : sign_of + 1]])
            parts.append(velocity_sign(recent)[-1:])
        v[k] = np.concatenate(parts)
        return b_at[k, 0] @ v[k]

    for k in range(n):
        past = np.zeros(ny)
        for i in range(1, min(n_a, k) + 1):
            past -= a_at[k - i, i - 1] @ y[k - i]
        for j in range(1, min(n_b - 1, k) + 1):
            past += b_at[k - j, j] @ v[k - j]
        y_k = past
        for _ in range(3 if has_b0 else 1):
            y_k = past + close(k, y_k)
        if not np.all(np.abs(y_k) < DIVERGED):
            break
        y[k] = y_k
        xc = K.A @ xc + K.B @ (y_k[y_index] - K.y_op)
    return y


def loop_signals(y: np.ndarray, data: Dataset, loop: Loop) -> tuple[np.ndarray, np.ndarray]:
    """Plant input and scheduling of the loop for the output trajectory ``y`` (N, ny) over ``data``.

    u(k) = u_op + C xc(k) + D (y(k) − y_op) + r(k) on the driven inputs (recorded values on the
    others), the scheduling columns with an expression recomputed from y, the others as recorded:
    the signals :func:`simulate_in_loop` fed its model, rebuilt from its output.
    """
    K = loop.controller
    y_index, u_index, computed = _wiring(data, loop)
    u, p = data.u.copy(), data.p.copy()
    xc = np.zeros(K.A.shape[0])
    for k in range(data.N):
        dy = y[k, y_index] - K.y_op
        u[k, u_index] = K.u_op + K.C @ xc + K.D @ dy + loop.excitation[k]
        xc = K.A @ xc + K.B @ dy
    for i, expression in computed:
        p[:, i] = [expression(row) for row in y]
    return u, p


def _wiring(data: Dataset, loop: Loop) -> tuple[list[int], list[int], list[tuple[int, Callable]]]:
    """Columns of the controller's measured outputs in ``data.y`` and of its driven inputs in
    ``data.u``, and the scheduling columns recomputed in the loop with their compiled expressions."""
    K = loop.controller
    y_index = [data.y_names.index(name) for name in K.inputs]
    u_index = [data.u_names.index(name) for name in K.outputs]
    computed = [(i, compile_expression(loop.scheduling[name], data.y_names))
                for i, name in enumerate(data.p_names) if name in loop.scheduling]
    return y_index, u_index, computed
