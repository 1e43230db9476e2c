"""Frozen-point references from an FMU plant, for `compare_frozen`: p ↦ discrete control.StateSpace.

Two references, both at an equilibrium of the plant whose scheduling value equals p:

1. `FmuLinearization`: the Jacobians of ẋ = f(x, u), y = g(x, u) by central differences through
   the FMU (states set with the `x0_<s>` parameters, ẋ read from `diag_der_<s>`, as in
   fmu_plants/README.md),
       A = ∂f/∂x,  B = ∂f/∂u,  C = ∂g/∂x,  D = ∂g/∂u,   step h_x = 10⁻⁶ max(|x_j|, 10⁻²),
                                                        h_u = 10⁻⁶ max(|u_j|, 1),
   sampled with a zero-order hold at Ts (`control.sample_system`, "zoh"), so the result compares
   with a model identified from data sampled at Ts. The FMU outputs at t_k use the input held over
   the step that ended at t_k (fmu_plants/README.md), so a feedthrough D acts with one sample of
   delay: y(k) = C x(k) + D u(k−1). When D ≠ 0 the discrete model carries u(k−1) as extra states.
   An actuator dead time set with the FMU's ``effect_input_delay`` (whole samples d) is appended as
   z^(−d) on every input (`with_input_delay`): the Jacobians cannot see it, the data do.

2. `FmuLocalModels`: a local LTI model identified from a small-signal experiment at the
   equilibrium: a PRBS of amplitude a around u* (`run_fmu_experiment`, states started at x*),
   and a least-squares ARX on the deviations ỹ = y − y*, ũ = u − u*,
       ỹ(k) + Σ_{i=1}^{na} A_i ỹ(k−i) = Σ_{j=nk}^{nk+nb−1} B_j ũ(k−j),
   realized in observable form (`LPVIO.to_ss` with constant coefficients).

Equilibrium at p: unknowns z = (x, u), equations f(x, u) = 0 and s(x, u) = p, s the scheduling
expressions (arithmetic on input and output names, `lpvflow.experiment.scheduling`), solved by
`scipy.optimize.least_squares` from the `start` values (the FMU's start values where not given)
and, later, from the equilibrium found at the nearest p. Accepted when ‖f‖∞·Ts ≤ 10⁻⁹ (1 + ‖x‖∞)
and |s − p| ≤ 10⁻⁹ (1 + |p|). With more inputs than scheduling signals the solution is one of many:
``hold`` (output name → value) adds the equations y_j(x, u) = value, pinning the equilibrium (e.g. a
two-disk levitation scheduled on the upper disk, with its lower disk held where the controller keeps it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import control
import numpy as np
from fmpy import read_model_description
from scipy.optimize import least_squares

from lpvflow.basis import Basis
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment import scheduling
from lpvflow.experiment.fmu_experiment import run_fmu_experiment
from lpvflow.fmu import FmuPlant, open_fmu
from lpvflow.lpvio import LPVIO

#: Equilibrium acceptance: ‖f‖∞·Ts ≤ TOL (1 + ‖x‖∞) and |s − p| ≤ TOL (1 + |p|).
EQUILIBRIUM_TOL = 1e-9
#: Start values below this magnitude are taken as exactly zero by the equilibrium search.
ROUND_OFF = 1e-12


@dataclass(frozen=True)
class OperatingPoint:
    """An equilibrium of the plant: scheduling p, states x, inputs u, measured outputs y."""

    p: np.ndarray
    x: np.ndarray
    u: np.ndarray
    y: np.ndarray


class FmuOperatingPoints:
    """Opens the FMU and finds equilibria (x*, u*) with scheduling value p (module docstring)."""

    def __init__(
        self,
        fmu: str | Path,
        Ts: float,
        scheduling_expressions: str | Sequence[str],
        start: Mapping[str, float] | None = None,
        parameters: Mapping[str, float] | None = None,
        hold: Mapping[str, float] | None = None,
    ) -> None:
        if not (np.isfinite(Ts) and Ts > 0):
            raise DataError(f"sampling time Ts = {Ts} must be a positive number of seconds")
        self.fmu, self.Ts = Path(fmu), float(Ts)
        self.expressions = [scheduling_expressions] if isinstance(scheduling_expressions, str) \
            else list(scheduling_expressions)
        self.hold = {name: float(value) for name, value in (hold or {}).items()}
        self.plant: FmuPlant = open_fmu(self.fmu)
        try:
            self._setup(start or {}, parameters or {})
        except Exception:
            self.plant.close()
            raise
        self._solved: list[OperatingPoint] = []

    def _setup(self, start: Mapping[str, float], parameters: Mapping[str, float]) -> None:
        plant = self.plant
        self.parameters = dict(parameters)
        plant.set_parameters(self.parameters)
        all_outputs = [v.name for v in read_model_description(str(self.fmu)).modelVariables
                       if v.causality == "output"]
        names = set(all_outputs)
        self.states = [name.removeprefix("x0_") for name in plant.parameter_names
                       if name.startswith("x0_") and f"diag_state_{name[3:]}" in names
                       and f"diag_der_{name[3:]}" in names]
        if not self.states:
            raise ModelError(f"{plant.name}: no states exposed (x0_<s> parameters with diag_state_<s> and "
                             "diag_der_<s> outputs); this FMU cannot be linearized here")
        self.signal_names = list(plant.input_names) + all_outputs
        unknown_held = sorted(set(self.hold) - set(all_outputs))
        if unknown_held:
            raise DataError(f"{plant.name}: held outputs {', '.join(unknown_held)} are not outputs of the "
                            f"FMU; its outputs: {', '.join(all_outputs)}")
        unknown = sorted(set(start) - set(self.states) - set(plant.input_names))
        if unknown:
            raise DataError(f"{plant.name}: start values for unknown names {', '.join(unknown)}; "
                            f"states: {', '.join(self.states)}; inputs: {', '.join(plant.input_names)}")
        self.start = np.array([start.get(s, plant.start_value(f"x0_{s}")) for s in self.states]
                              + [start.get(i, plant.start_value(i)) for i in plant.input_names])
        self.evaluate(self.start[: len(self.states)], self.start[len(self.states):])  # checks the expressions

    @property
    def n_inputs(self) -> int:
        return len(self.plant.input_names)

    def evaluate(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ẋ, measured y, s) of the FMU initialised at state x with input u: s the scheduling expressions,
        then the held outputs (``hold``)."""
        plant = self.plant
        plant.set_parameters({f"x0_{s}": float(v) for s, v in zip(self.states, x, strict=True)})
        y = plant.reset(inputs=np.asarray(u, dtype=float))
        current = np.concatenate([np.asarray(u, dtype=float), plant.get(self.signal_names[self.n_inputs:])])
        values = {name: value.reshape(1) for name, value in zip(self.signal_names, current, strict=True)}
        s = np.array([float(scheduling.evaluate(e, values)[0]) for e in self.expressions]
                     + [float(values[name][0]) for name in self.hold])
        return plant.get([f"diag_der_{s}" for s in self.states]), y, s

    def equilibrium(self, p: np.ndarray) -> OperatingPoint:
        """The equilibrium with scheduling value p (and the held outputs at their values): one solved before
        at exactly p (validate asks for it for the plant and again for the experiment controller), else
        solved from the nearest solved point, else from the start values."""
        p = np.atleast_1d(np.asarray(p, dtype=float))
        if p.shape != (len(self.expressions),):
            raise DataError(f"scheduling value {p.tolist()} has {p.size} entries; the FMU reference has "
                            f"{len(self.expressions)} scheduling expression(s)")
        for point in self._solved:
            if np.array_equal(point.p, p):
                return point
        n = len(self.states)
        target = np.concatenate([p, list(self.hold.values())])
        starts = [self.start]
        if self._solved:
            nearest = min(self._solved, key=lambda op: float(np.linalg.norm(op.p - p)))
            starts.insert(0, np.concatenate([nearest.x, nearest.u]))

        def residual(z: np.ndarray) -> np.ndarray:
            dx, _, s = self.evaluate(z[:n], z[n:])
            return np.concatenate([dx * self.Ts, s - target])

        for z0 in starts:
            # Round-off entries (an equilibrium at 0 solved as 1e-22) would make least_squares' first trust
            # region ‖z0 / x_scale‖ that small, and it stops at once on xtol.
            z0 = np.where(np.abs(z0) < ROUND_OFF, 0.0, z0)
            solution = least_squares(residual, z0, x_scale=np.maximum(np.abs(z0), 1e-3), xtol=1e-15,
                                     ftol=1e-15, gtol=1e-15, max_nfev=400)
            x, u = solution.x[:n], solution.x[n:]
            dx, y, s = self.evaluate(x, u)
            ok = (np.max(np.abs(dx)) * self.Ts <= EQUILIBRIUM_TOL * (1 + np.max(np.abs(x)))
                  and np.all(np.abs(s - target) <= EQUILIBRIUM_TOL * (1 + np.abs(target))))
            if ok:
                break
        if not ok:
            raise ModelError(
                f"{self.plant.name}: no equilibrium with scheduling {p.tolist()} found from the start values "
                f"(residual |dx/dt| {np.max(np.abs(dx)):.3g}, scheduling/held-output error "
                f"{np.max(np.abs(s - target)):.3g}); "
                "give start values near it for the states and inputs (--fmu-start NAME=VALUE)"
            )
        point = OperatingPoint(p, x, u, y)
        self._solved.append(point)
        return point

    def close(self) -> None:
        self.plant.close()

    def __enter__(self) -> FmuOperatingPoints:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class FmuLinearization(FmuOperatingPoints):
    """Callable p ↦ ZOH-discretized finite-difference linearization of the FMU at its equilibrium."""

    def continuous(self, point: OperatingPoint) -> control.StateSpace:
        """(A, B, C, D) by central differences at (x*, u*) (module docstring, item 1)."""
        x, u = point.x, point.u
        columns: dict[str, list[np.ndarray]] = {"A": [], "C": [], "B": [], "D": []}
        for j in range(len(x)):
            h = 1e-6 * max(abs(x[j]), 1e-2)
            (fp, yp, _), (fm, ym, _) = self.evaluate(x + h * _unit(len(x), j), u), \
                self.evaluate(x - h * _unit(len(x), j), u)
            columns["A"].append((fp - fm) / (2 * h))
            columns["C"].append((yp - ym) / (2 * h))
        for j in range(len(u)):
            h = 1e-6 * max(abs(u[j]), 1.0)
            (fp, yp, _), (fm, ym, _) = self.evaluate(x, u + h * _unit(len(u), j)), \
                self.evaluate(x, u - h * _unit(len(u), j))
            columns["B"].append((fp - fm) / (2 * h))
            columns["D"].append((yp - ym) / (2 * h))
        A, B, C, D = (np.array(columns[k]).T for k in "ABCD")
        return control.ss(A, B, C, D, inputs=list(self.plant.input_names),
                          outputs=list(self.plant.output_names))

    def __call__(self, p: np.ndarray) -> control.StateSpace:
        sampled = sample_like_fmu(self.continuous(self.equilibrium(p)), self.Ts)
        return with_input_delay(sampled, self.input_delay_samples())

    def input_delay_samples(self) -> int:
        """The FMU's actuator dead time ``effect_input_delay`` (s) in whole samples of Ts (0 if absent);
        the plant applies u(k − d) (fmu_plants/README.md, effects), which a Jacobian cannot see."""
        delay = float(self.parameters.get("effect_input_delay", 0.0))
        samples = round(delay / self.Ts)
        if abs(samples * self.Ts - delay) > 1e-9 * max(1.0, delay):
            raise ModelError(f"{self.plant.name}: effect_input_delay = {delay:g} s is not a whole number of "
                             f"samples of Ts = {self.Ts:g} s; the linearization cannot represent it")
        return samples


def with_input_delay(system: control.StateSpace, d: int) -> control.StateSpace:
    """G(z) z^(−d) on every input: d shift-register states per input in front of B (and D)."""
    if d == 0:
        return system
    n, m = system.nstates, system.ninputs
    A = np.zeros((n + d * m, n + d * m))
    A[:n, :n] = system.A
    A[:n, n + (d - 1) * m:] = system.B  # the oldest register feeds the plant
    A[n + m:, n:n + (d - 1) * m] = np.eye((d - 1) * m)  # shift
    B = np.zeros((n + d * m, m))
    B[n:n + m] = np.eye(m)
    C = np.hstack([system.C, np.zeros((system.noutputs, (d - 1) * m)), system.D])
    return control.ss(A, B, C, np.zeros_like(system.D), system.dt, inputs=system.input_labels,
                      outputs=system.output_labels)


def sample_like_fmu(system: control.StateSpace, Ts: float) -> control.StateSpace:
    """ZOH sampling at Ts with the FMU's output timing: y(k) = C x(k) + D u(k−1) (module docstring)."""
    strictly_proper = control.ss(system.A, system.B, system.C, np.zeros_like(system.D))
    sampled = control.sample_system(strictly_proper, Ts, "zoh")
    A, B, C = sampled.A, sampled.B, sampled.C
    if np.any(system.D != 0):
        n, m = A.shape[0], B.shape[1]
        A = np.block([[A, np.zeros((n, m))], [np.zeros((m, n + m))]])
        B = np.vstack([B, np.eye(m)])
        C = np.hstack([C, system.D])
    return control.ss(A, B, C, np.zeros_like(system.D), Ts, inputs=system.input_labels,
                      outputs=system.output_labels)


class FmuLocalModels(FmuOperatingPoints):
    """Callable p ↦ ARX model identified from a small-signal PRBS experiment at the equilibrium.

    `amplitude`: PRBS amplitude per input as a fraction of max(|u*|, 1); `clock`: PRBS clock in
    samples; `order`: PRBS register length (period 2^order − 1 clocks, run twice); na, nb, nk the ARX
    orders (nk = 1 matches the FMU's one-sample output timing).
    """

    def __init__(
        self,
        fmu: str | Path,
        Ts: float,
        scheduling_expressions: str | Sequence[str],
        start: Mapping[str, float] | None = None,
        parameters: Mapping[str, float] | None = None,
        hold: Mapping[str, float] | None = None,
        *,
        na: int = 2,
        nb: int = 2,
        nk: int = 1,
        amplitude: float = 0.01,
        clock: int = 10,
        order: int = 8,
        seed: int = 0,
    ) -> None:
        super().__init__(fmu, Ts, scheduling_expressions, start, parameters, hold)
        if min(na, nb) < 0 or nb < 1 or nk < 0 or not amplitude > 0 or clock < 1:
            self.close()
            raise DataError(f"local ARX needs na >= 0, nb >= 1, nk >= 0, amplitude > 0 and clock >= 1; got "
                            f"na={na}, nb={nb}, nk={nk}, amplitude={amplitude}, clock={clock}")
        self.na, self.nb, self.nk = na, nb, nk
        self.amplitude, self.clock, self.order, self.seed = amplitude, clock, order, seed

    def experiment(self, point: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
        """(ũ, ỹ): deviations from (u*, y*) in a PRBS experiment started at the equilibrium."""
        period = (2**self.order - 1) * self.clock * self.Ts
        inputs = {name: f"prbs:order={self.order},clock={self.clock * self.Ts!r},"
                        f"amp={float(self.amplitude * max(abs(value), 1.0))!r},offset={float(value)!r}"
                  for name, value in zip(self.plant.input_names, point.u, strict=True)}
        states = {f"x0_{s}": float(v) for s, v in zip(self.states, point.x, strict=True)}
        parameters = self.parameters | states
        record = run_fmu_experiment(self.fmu, self.Ts, 2 * period, inputs=inputs, parameters=parameters,
                                    scheduling_columns={}, seed=self.seed, progress=False)
        u = np.column_stack([record.columns[n] for n in self.plant.input_names]) - point.u
        y = np.column_stack([record.columns[n] for n in self.plant.output_names]) - point.y
        return u, y

    def __call__(self, p: np.ndarray) -> control.StateSpace:
        point = self.equilibrium(p)
        u, y = self.experiment(point)
        return arx_statespace(u, y, self.na, self.nb, self.nk, self.Ts, list(self.plant.input_names),
                              list(self.plant.output_names))


def arx_statespace(
    u: np.ndarray, y: np.ndarray, na: int, nb: int, nk: int, Ts: float,
    u_names: list[str] | None = None, y_names: list[str] | None = None,
) -> control.StateSpace:
    """Least-squares MIMO ARX (full A_i, B_j; module docstring, item 2) as a discrete StateSpace."""
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    N, ny, nu = len(y), y.shape[1], u.shape[1]
    start = max(na, nk + nb - 1)
    if N - start <= na * ny + nb * nu:
        raise DataError(f"{N} samples are too few for an ARX with na={na}, nb={nb}, nk={nk}")
    rows = np.arange(start, N)
    regressors = [-y[rows - i] for i in range(1, na + 1)] + [u[rows - j] for j in range(nk, nk + nb)]
    Phi = np.hstack(regressors)
    theta = np.linalg.lstsq(Phi, y[rows], rcond=None)[0].T  # (ny, na ny + nb nu)
    A = np.zeros((na, 1, ny, ny))
    B = np.zeros((nk + nb, 1, ny, nu))
    for i in range(na):
        A[i, 0] = theta[:, i * ny:(i + 1) * ny]
    for j in range(nb):
        B[nk + j, 0] = theta[:, na * ny + j * nu: na * ny + (j + 1) * nu]
    # constant coefficients: the ψ_1 = p component of an affine basis is zero, any p gives the LTI model
    basis = Basis.affine(1)
    io = LPVIO(np.concatenate([A, np.zeros_like(A)], axis=1), np.concatenate([B, np.zeros_like(B)], axis=1),
               basis, Ts, u_names=u_names or [], y_names=y_names or [])
    return io.to_ss().frozen(np.zeros(1))


def _unit(n: int, j: int) -> np.ndarray:
    e = np.zeros(n)
    e[j] = 1.0
    return e


class SelectedChannels:
    """A frozen FMU reference restricted to (and ordered like) given inputs and outputs of the FMU."""

    def __init__(self, reference: FmuOperatingPoints, u_names: Sequence[str], y_names: Sequence[str]) -> None:
        plant = reference.plant
        missing = sorted(set(u_names) - set(plant.input_names))
        missing += sorted(set(y_names) - set(plant.output_names))
        if missing:
            raise DataError(f"signal(s) {', '.join(missing)} are not inputs/outputs of {plant.name}; the FMU "
                            "reference needs the model's signal names")
        self.reference = reference
        self.inputs = [list(plant.input_names).index(n) for n in u_names]
        self.outputs = [list(plant.output_names).index(n) for n in y_names]
        self.labels = (list(u_names), list(y_names))

    def __call__(self, p: np.ndarray) -> control.StateSpace:
        G = self.reference(p)
        return control.ss(G.A, G.B[:, self.inputs], G.C[self.outputs], G.D[np.ix_(self.outputs, self.inputs)],
                          G.dt, inputs=self.labels[0], outputs=self.labels[1])

    def close(self) -> None:
        self.reference.close()
