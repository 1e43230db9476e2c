"""A synthesized LPV controller (format ``lpvflow/lpv-controller``,
:class:`lpvflow.synth.controller.LPVController`, written by ``lpvflow synth`` and the design pipeline) as
the controller of an identification experiment.

Its wiring comes from the port record ``info["signals"]``
(:func:`lpvflow.pipeline.ports.controller_signals`): the plant outputs it reads (``measured``, with
operating points y_op), the plant inputs it drives (``actuated``, with operating points u_op) and its
scheduling signals (``scheduling``, each an expression of plant outputs, e.g. ``sin(arm_angle)``). The
law is the one :mod:`lpvflow.pipeline.verify` runs:

    p(k) = the scheduling expressions of the measured plant outputs y_m(k),
    w(k) = r(k) − y(k) (``"1dof"``) or [r(k) − y_op; y(k) − y_op] (``"2dof"``), y the outputs read, r
           their set-points (y_op where none is given) (:meth:`LPVController.input_of`),
    v(k) = u_eq(p(k)) + C(λ) x(k) + D(λ) w(k)   (:meth:`LPVController.step`, which advances x),
    u(k) = u_op + v_a(k) + e(k),

v_a = clip(u_op + v, u_min, u_max) − u_op with the controller's anti-windup range (the saturation its
anti-windup law assumes; v_a = v without anti-windup) and e the experiment's excitation, added after the
actuator range like an input disturbance, so the anti-windup sees exactly its own saturation.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from lpvflow.errors import DataError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.scheduling import compile_expression, evaluate
from lpvflow.loop.protocol import ExperimentController, SynthesizedLaw

if TYPE_CHECKING:  # python-control (imported by lpvflow.synth) takes ~1 s; loaded only with a controller
    from lpvflow.synth.controller import LPVController

#: Step of the central differences of the trim's feedback (in the units of the outputs read).
_STEP = 1e-6


@dataclass
class SynthesizedController(ExperimentController):
    """An :class:`LPVController` wired to plant signals by its ``info["signals"]`` (module docstring).

    Attributes:
        law: the controller (its state x advances with :meth:`command`).
        inputs: plant outputs read, in the controller's order; outputs: plant inputs driven.
        scheduling: one expression of plant outputs per scheduling signal p_i.
        y_op: (ny,) references of the outputs read where no set-point is given.
        u_op: (nu,) operating point added to the controller's output.
    """

    law: LPVController
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    scheduling: tuple[str, ...]
    y_op: np.ndarray
    u_op: np.ndarray

    #: The law depends on p (an LPV controller with its trim u_eq(p)).
    scheduled = True

    @classmethod
    def from_controller(cls, law: LPVController, source: str = "controller") -> SynthesizedController:
        """Wire ``law`` by its ``info["signals"]``; one DataError line when it has no such record (an
        experiment needs the plant signals it reads, drives and schedules on)."""
        from lpvflow.pipeline.ports import controller_signals

        if not law.info.get("signals"):
            raise DataError(f"{source} has no info['signals'] record (the plant outputs it reads, the inputs "
                            "it drives, its scheduling expressions): an experiment cannot wire it; use the "
                            "controller.json of `lpvflow design`, whose synth stage writes it")
        signals = controller_signals(law)
        return cls(law, tuple(port.name for port in signals.measured),
                   tuple(port.name for port in signals.actuated),
                   tuple(port.expression or port.name for port in signals.scheduling),
                   np.array([port.operating_point for port in signals.measured], dtype=float),
                   np.array([port.operating_point for port in signals.actuated], dtype=float))

    @property
    def Ts(self) -> float:
        return self.law.Ts

    def loop_law(self) -> SynthesizedLaw:
        """The controller in the loop protocol (:class:`lpvflow.loop.protocol.SynthesizedLaw`)."""
        return SynthesizedLaw(self)

    def to_dict(self) -> dict:
        """The controller's ``lpvflow/lpv-controller`` document (its signal record included)."""
        return self.law.to_dict()

    def design_box_exit(self, time: np.ndarray, columns: Mapping[str, np.ndarray]) -> str | None:
        """Where a record made under this controller leaves the scheduling box the law was designed on
        (its polytope's design box, p(k) from the scheduling expressions of the record's ``columns``), in
        words, or None when it stays inside (or the law was designed at one point). Outside its box the law
        extrapolates its vertex matrices: a loop that got there has left what the design vouches for."""
        box = self.law.design_box
        if box is None:
            return None
        n = len(time)
        p = np.column_stack([np.broadcast_to(evaluate(expression, columns), (n,))
                             for expression in self.scheduling])
        slack = 1e-9 * np.maximum(box[:, 1] - box[:, 0], 1.0)
        outside = np.any((p < box[:, 0] - slack) | (p > box[:, 1] + slack), axis=1)
        if not outside.any():
            return None
        k = int(np.argmax(outside))
        where = ", ".join(f"{e} = {v:.4g} in [{lo:.4g}, {hi:.4g}]"
                          for e, v, (lo, hi) in zip(self.scheduling, p[k], box, strict=True))
        return (f"left the scheduling box the controller was designed on at t = {time[k]:.4g} s ({where}) "
                f"and was outside it for {int(outside.sum())} of {n} samples")

    def as_gridded(self) -> GriddedController:
        """The same law as a gridded controller, exactly (no tabulation), for the compiled in-loop
        simulation (:mod:`lpvflow.validate.loop_recursion`); one DataError line when λ(p) is not the hat
        functions of one scheduling signal (:attr:`Polytope.vertex_breakpoints`: then no grid is exact).

        θ is the first scheduling expression p₁; the grid is the polytope's breakpoints joined with the
        trim's, at each point the vertex mix Σ λ_i(θ) M_i and u_op + u_eq(θ): both are piecewise linear
        in θ with kinks only there, and the grid clips θ at its ends as the hat functions and the trim
        table do, so the interpolation is the law itself. With y_op the measured operating points:

        * ``"1dof"`` (w = r − y): B = −B(λ), D = −D(λ) on y − ȳ, ȳ = r (y_op where none is given);
        * ``"2dof"`` (w = [r − y_op; y − y_op]): the outputs are read twice, dy = [y − y_op; y − r],
          B = [B_r + B_y, −B_r], D = [D_r + D_y, −D_r], since B_r (r − y_op) + B_y (y − y_op)
          = (B_r + B_y)(y − y_op) − B_r (y − r); the references go to the second half
          (:meth:`gridded_setpoints`), and where none is given ȳ = y_op there, r = y_op as in
          :meth:`LPVController.input_of`.

        The anti-windup correction is not part of it: the grid law is exact while the command stays
        inside the anti-windup range (the loop never saturates its actuator)."""
        law = self.law
        breakpoints = law.polytope.vertex_breakpoints
        if breakpoints is None:
            raise DataError(f"the LPV controller's {law.polytope.kind!r} polytope interpolates its vertices "
                            "in ψ(p), not along one scheduling signal: no grid is the same law; the in-loop "
                            "simulation needs a controller designed with [synth] breakpoints (a piecewise "
                            "polytope)")
        b = np.asarray(breakpoints, dtype=float).reshape(len(breakpoints), -1)[:, 0]
        grid = np.unique(np.concatenate([b, [] if law.trim is None else law.trim.p]))
        lam = np.array([law.coordinates(np.array([theta])) for theta in grid])
        A, B, C, D = (np.tensordot(lam, M, axes=1) for M in (law.Ak, law.Bk, law.Ck, law.Dk))
        ny = len(self.inputs)
        if law.structure == "2dof":
            B = np.concatenate([B[:, :, :ny] + B[:, :, ny:], -B[:, :, :ny]], axis=2)
            D = np.concatenate([D[:, :, :ny] + D[:, :, ny:], -D[:, :, :ny]], axis=2)
            inputs, y_op = self.inputs * 2, np.concatenate([self.y_op, self.y_op])
        else:
            B, D, inputs, y_op = -B, -D, self.inputs, self.y_op
        trim = np.zeros((len(grid), len(self.u_op))) if law.trim is None else law.trim.along(grid)
        return GriddedController(grid=grid, A=A, B=B, C=C, D=D, y_op=np.tile(y_op, (len(grid), 1)),
                                 u_op=self.u_op + trim, Ts=self.Ts, inputs=inputs, outputs=self.outputs,
                                 scheduling=self.scheduling[0], description="synthesized LPV controller")

    def gridded_setpoints(self, references: np.ndarray) -> np.ndarray:
        """The set-points of :meth:`as_gridded`'s inputs for the references (N, ny) of the outputs read
        (NaN: none): the same for a 1-DOF law, [NaN; references] for a 2-DOF one (module docstring)."""
        references = np.asarray(references, dtype=float)
        if self.law.structure != "2dof":
            return references
        return np.concatenate([np.full_like(references, np.nan), references], axis=1)

    def check_plant(self, output_names: Sequence[str], input_names: Sequence[str], model: str) -> None:
        """One DataError line when the plant lacks an output the controller reads or its scheduling uses,
        or an input it drives."""
        for kind, names, available in (("reads plant output", self.inputs, output_names),
                                       ("drives plant input", self.outputs, input_names)):
            unknown = [name for name in names if name not in available]
            if unknown:
                raise DataError(f"the LPV controller {kind} {unknown[0]!r} (its info['signals']), which FMU "
                                f"{model} lacks; it has {', '.join(available) or 'none'}")
        self.scheduling_function(list(output_names))

    def scheduling_function(self, names: list[str]) -> Callable[[np.ndarray], np.ndarray]:
        """p as a function of one sample of the signals ``names``; one DataError line when an expression
        uses another name."""
        compiled = []
        for i, expression in enumerate(self.scheduling):
            try:
                compiled.append(compile_expression(expression, names))
            except DataError as exc:
                raise DataError(f"the LPV controller's scheduling signal {i + 1}: {exc}") from None
        return lambda sample: np.array([value_of(sample) for value_of in compiled])

    def reset(self) -> None:
        """Controller state to zero (start of a run)."""
        self.law.reset()

    def command(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        """u_op + v_a(k) for references r(k) and measurements y(k) of the outputs read at p(k), without
        the excitation; advances the controller state (module docstring)."""
        v = self.law.step(self.law.input_of(r, y), p)
        aw = self.law.antiwindup
        return self.u_op + (v if aw is None else aw.applied(v))

    def trim(self, p: np.ndarray) -> np.ndarray:
        """u_op + u_eq(p): the input the controller applies at p with x = 0 and w = 0 (its trim)."""
        return self.u_op + self.law.feedforward(p)

    def trim_along(self, columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        """(n, nu) trim u_op + u_eq(p(k)) of the first n samples of a record, p(k) the scheduling
        expressions of its columns (the measured plant outputs)."""
        signals = {name: values[:n] for name, values in columns.items()}
        p = np.column_stack([np.broadcast_to(evaluate(expression, signals), (n,))
                             for expression in self.scheduling])
        trim = self.law.trim
        return self.u_op + (np.zeros((n, len(self.u_op))) if trim is None else trim.along(p[:, 0]))

    def frozen_at(self, p: np.ndarray) -> LtiController:
        """The law frozen at p as a map from the measurements, without the trim and without what constant
        references add: x⁺ = A x + B_y (y − y_op), v = C x + D_y (y − y_op), B_y, D_y the measurement
        columns (−B, −D of w = r − y for a 1-DOF controller; the y half of [r; y] for a 2-DOF one)."""
        A, B, C, D = self.law.matrices(np.asarray(p, dtype=float))
        ny = len(self.inputs)
        B_y, D_y = (B[:, ny:], D[:, ny:]) if self.law.structure == "2dof" else (-B, -D)
        return LtiController(A=A, B=B_y, C=C, D=D_y, Ts=self.Ts, inputs=self.inputs, outputs=self.outputs,
                             y_op=self.y_op, u_op=self.trim(p))

    def operating_laws(self, outputs: Mapping[str, float]) -> tuple[LtiController, LtiController]:
        """(linearized, frozen) at the plant outputs ``outputs`` (name → value, every plant output the
        scheduling uses): the frozen law at p(outputs) (:meth:`frozen_at`) and the same with the trim's
        feedback (∂u_eq/∂p)(∂p/∂y) added to D (a trim scheduled on a measured signal acts as a static
        feedback of it; the matrices' own dependence on p acts on the state and is left out)."""
        names = list(outputs)
        sample = np.array([outputs[name] for name in names], dtype=float)
        p_of = self.scheduling_function(names)
        p = p_of(sample)
        frozen = self.frozen_at(p)
        columns = []
        for name in self.inputs:
            step = _STEP * np.eye(len(names))[names.index(name)]
            columns.append((self.law.feedforward(p_of(sample + step))
                            - self.law.feedforward(p_of(sample - step))) / (2 * _STEP))
        return replace(frozen, D=frozen.D + np.column_stack(columns)), frozen
