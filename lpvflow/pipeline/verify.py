"""Closed-loop verification: the controller and a plant FMU co-simulated at the controller's Ts.

The plant is an FMI 2.0 Co-Simulation FMU stepped through fmpy's instance API
(:func:`lpvflow.experiment.plant.open_plant`, built on :func:`lpvflow.fmu.open_fmu`); the loop law
and the scenario file are described in :mod:`lpvflow.pipeline.scenarios`. Sampling convention (as the
experiment runner): read y(k) at t_k, form u(k), hold it from t_k to t_k + Ts.

Controllers: an :class:`~lpvflow.synth.controller.LPVController` (u = u_eq(p) + K(p) w with w = r − y
for ``structure = "1dof"``, w = [r; y] for ``"2dof"``, u_eq the controller's trim feed-forward); a discrete
``control.StateSpace`` (1-DOF, no scheduling); an ``lpvflow/lti-controller`` file
(:class:`~lpvflow.experiment.controller.LtiController`, 1-DOF), run with its own operating input u_op and
its y_op replaced by the reference: u = u_op + C xc + D (y − r), xc⁺ = A xc + B (y − r); or an exported
controller FMU (:class:`FmuController`), handed r and y on its separate ports.

Plant parameters of a run (:func:`plant_parameters`): ``[verify.loop] plant_parameters``, overridden by
the scenario's, then every scenario ``parameter_factors`` entry f multiplies its parameter's value
(the FMU's start value when neither table sets it): a perturbed plant, e.g. ``pendulum_mass = 1.1``.

Metrics per tracked output (after t_c, the start of the last reference change; Δ its size, r_f the
final reference; the final window is the last 10 % of the run, at least one sample):

    settling_time       time from t_c after which |y − r_f| ≤ band for the rest of the run
                        (band = settling_band if given, else 0.02·|Δ|); None if outside at the end
    overshoot           max(0, max sign(Δ)·(y − r_f)) in output units, and 100·overshoot/|Δ| in %
    peak_deviation      max |y − r_f|
    steady_state_error  |mean(r_f − y)| over the final window
    settled             the output stays inside the band over the whole final window
    iae, ise            integrated tracking error from t_c to the end of the run, Ts·Σ|r_f − y| (output
                        units·s) and Ts·Σ(r_f − y)² (units²·s): one number for speed, overshoot and
                        oscillation together, comparable between controllers on the same scenario

per measured output that is not tracked: after_settling = max |y − r| from the instant the last tracked
output settled to the end of the run (None if one never settles) — e.g. the pendulum while the arm holds;
per actuated input: peak_control max |u| (after the limits) and saturation_time = Ts·#{k: u_c(k) outside
the limits}; per run, the scheduling the loop visited: ``range`` [min p_i, max p_i] per signal and, for a
scheduled LPV controller, its design ``box`` (the scheduling box of its polytope, inside which the
synthesis certificate holds; outside it the convex coordinates are clipped to the nearest face),
``time_outside_box`` = Ts·#{k: p(k) ∉ box} and ``first_outside_box`` (s, or None).
Verdict: stable ⇔ the run finished with finite signals inside ``output_bounds`` and every
tracked output settled. A scenario's ``requirements`` (settling time, overshoot, after-settling bounds)
are checked besides: ``requirements_failed`` lists what the run misses; ``passed`` ⇔ stable and none.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import control
import numpy as np
from fmpy import extract
from fmpy.fmi2 import FMU2Slave

from lpvflow.errors import DataError, LpvflowError, ModelError
from lpvflow.experiment import scheduling as expressions
from lpvflow.experiment.controller import FORMAT as LTI_FORMAT
from lpvflow.experiment.controller import LtiController, load_controller
from lpvflow.experiment.plant import Plant, open_plant
from lpvflow.experiment.run import step_count
from lpvflow.fmu import check_fmu
from lpvflow.models import report_header, user_mode
from lpvflow.pipeline.export import load_lpv_controller
from lpvflow.pipeline.scenarios import Loop, Requirements, Scenario, Signal, run_passed
from lpvflow.synth.controller import LPVController

#: Fraction of the run forming the final window of the steady-state checks.
FINAL_WINDOW = 0.1
#: Default settling band, relative to the size of the last reference change.
RELATIVE_BAND = 0.02
_TS_TOLERANCE = 1e-9


# ------------------------------------------------------------------------------------------ laws
class _FixedLaw:
    """LTI law u = C x + D (s·e), x⁺ = A x + B (s·e), with s = +1 (e = r − y) or −1 (y − r); 1-DOF."""

    structure = "1dof"

    def __init__(
        self,
        A: np.ndarray,
        B: np.ndarray,
        C: np.ndarray,
        D: np.ndarray,
        Ts: float,
        sign: float,
        u_offset: np.ndarray | None = None,
    ) -> None:
        self.A, self.B, self.C, self.D = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (A, B, C, D))
        self.Ts, self.sign, self.u_offset = float(Ts), sign, u_offset
        self.n_in, self.n_out = self.D.shape[1], self.D.shape[0]
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros(self.A.shape[0])

    def step(self, e: np.ndarray, p: np.ndarray) -> np.ndarray:
        w = self.sign * e
        u = self.C @ self.x + self.D @ w
        self.x = self.A @ self.x + self.B @ w
        return u


class FmuController:
    """A controller FMU written by :func:`lpvflow.pipeline.export.export_fmu`, stepped through fmpy.

    Inputs are told apart by their description: ``scheduling …`` are p, ``measured …`` the outputs y and
    the others (``reference …``) the references r, in modelDescription order. The FMU reads r and y on
    separate ports whatever the structure of the controller inside (a 1-DOF one forms r − y itself), so
    the loop hands it w = [r; y] (``structure = "2dof"``): per sample r(k), y(k) and p(k) are set, u(k)
    read, then ``fmi2DoStep(t_k, Ts)``. An FMU without measured ports (written before they existed) reads
    e = r − y on its reference ports (``structure = "1dof"``). The FMU's outputs include its operating
    point and trim feed-forward, so ``u_offset`` is zero and the loop adds no operating point of its own.
    """

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        description = check_fmu(path)  # a readable FMI 2.0 Co-Simulation FMU with a binary here
        if description.defaultExperiment is None or description.defaultExperiment.stepSize is None:
            raise ModelError(f"{path} is not a controller FMU written by `lpvflow export --format fmu`")
        variables = description.modelVariables
        inputs = [v for v in variables if v.causality == "input"]
        role = {v.valueReference: (v.description or "").split(" ")[0] for v in inputs}
        self._p_vr = [vr for vr, kind in role.items() if kind == "scheduling"]
        self._y_vr = [vr for vr, kind in role.items() if kind == "measured"]
        self._e_vr = [vr for vr, kind in role.items() if kind not in ("scheduling", "measured")]
        self._u_vr = [v.valueReference for v in variables if v.causality == "output"]
        self.structure = "2dof" if self._y_vr else "1dof"
        self.n_in, self.n_out = len(self._e_vr) + len(self._y_vr), len(self._u_vr)
        self.u_offset = np.zeros(self.n_out) if self._y_vr else None  # FMUs before named ports: no trim
        self.Ts = float(description.defaultExperiment.stepSize)
        self.n_p = len(self._p_vr)
        self._unzipdir = extract(str(path))
        identifier = description.coSimulation.modelIdentifier
        self._slave = FMU2Slave(
            guid=description.guid,
            unzipDirectory=self._unzipdir,
            modelIdentifier=identifier,
            instanceName=identifier,
        )
        self._slave.instantiate()
        self._time = 0.0

    def reset(self) -> None:
        if self._time > 0.0:
            self._slave.reset()
        self._slave.setupExperiment(startTime=0.0)
        self._slave.enterInitializationMode()
        self._slave.exitInitializationMode()
        self._time = 0.0

    def step(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """u(k) for the input w(k) ([r; y], or e for an FMU without measured ports) at p(k); then one step."""
        self._slave.setReal(self._e_vr + self._y_vr + self._p_vr,
                            [*np.asarray(w, float), *np.asarray(p, float)])
        u = np.array(self._slave.getReal(self._u_vr))
        self._slave.doStep(self._time, self.Ts)
        self._time += self.Ts
        return u

    def close(self) -> None:
        if self._slave is not None:
            self._slave.terminate()
            self._slave.freeInstance()
            self._slave = None
            shutil.rmtree(self._unzipdir, ignore_errors=True)


#: Controllers the loop can run.
Baseline = LPVController | control.StateSpace | LtiController | FmuController


def _law(controller: Baseline, loop: Loop) -> LPVController | _FixedLaw | FmuController:
    """The controller as an object with Ts, n_in, n_out, structure, reset() and step(w, p) -> u − u_op."""
    if isinstance(controller, LPVController | FmuController):
        return controller
    if isinstance(controller, control.StateSpace):
        if not controller.isdtime(strict=True):
            raise ModelError("the baseline StateSpace is continuous; discretise it at the controller's Ts")
        return _FixedLaw(controller.A, controller.B, controller.C, controller.D, float(controller.dt), 1.0)
    if isinstance(controller, LtiController):
        if tuple(controller.inputs) != loop.measured or tuple(controller.outputs) != loop.actuated:
            raise ModelError(
                f"the LTI controller reads {list(controller.inputs)} and drives "
                f"{list(controller.outputs)}; the loop measures {list(loop.measured)} and "
                f"drives {list(loop.actuated)}: they must match"
            )
        return _FixedLaw(
            controller.A, controller.B, controller.C, controller.D, controller.Ts, -1.0, controller.u_op
        )
    raise ModelError(
        f"cannot run a {type(controller).__name__} in the loop; give an LPVController, a "
        "discrete control.StateSpace or an lpvflow/lti-controller file"
    )


def load_controller_file(path: str | Path) -> Baseline:
    """An ``lpvflow/lpv-controller`` or ``lpvflow/lti-controller`` JSON file, or a controller FMU."""
    path = Path(path)
    if path.suffix.lower() == ".fmu":
        return FmuController(path)
    if path.is_file():
        try:
            kind = json.loads(path.read_text()).get("format")
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            kind = None
        if kind == LTI_FORMAT:
            return load_controller(path)
    return load_lpv_controller(path)


# ------------------------------------------------------------------------------------------ runs
@dataclass
class ClosedLoopRun:
    """Signals of one closed-loop run, sample k at time[k]; ``failure`` says why it stopped early."""

    label: str
    time: np.ndarray
    reference: np.ndarray
    outputs: np.ndarray
    commanded: np.ndarray
    control: np.ndarray
    scheduling: np.ndarray
    measured: tuple[str, ...]
    actuated: tuple[str, ...]
    failure: str | None = None
    #: (n_p, 2) design box of a scheduled LPV controller (None for LTI laws and controller FMUs).
    scheduling_box: np.ndarray | None = None


def _sampled(
    signals: Mapping[str, Signal], names: Sequence[str], t: np.ndarray, default: Sequence[float]
) -> np.ndarray:
    return np.column_stack(
        [
            signals[n].sample(t) if n in signals else np.full(len(t), d)
            for n, d in zip(names, default, strict=True)
        ]
    )


def _check_subset(what: str, names: Sequence[str], available: Sequence[str], where: str,
                  hint: str = "") -> None:
    unknown = [n for n in names if n not in available]
    if unknown:
        raise DataError(f"{where}: unknown {what} {unknown[0]!r}; known: {', '.join(available)}{hint}")


def _check_scenario(scenario: Scenario, loop: Loop, plant_inputs: Sequence[str]) -> None:
    where = f"scenario {scenario.name!r}"
    for what, names in (
        ("reference output", scenario.reference),
        ("settling_band output", scenario.settling_band),
        ("output_disturbance output", scenario.output_disturbance),
        ("output_bounds output", scenario.output_bounds),
        ("tracked output", scenario.tracked or ()),
        ("requirements.after_settling output", scenario.requirements.after_settling if scenario.requirements
         else ()),
    ):
        _check_subset(what, list(names), loop.measured, where)
    if scenario.requirements is not None:
        tracked = set(_tracked(scenario, loop))
        both = [name for name in scenario.requirements.after_settling if name in tracked]
        if both:
            raise DataError(f"{where}: requirements.after_settling names the tracked output {both[0]!r}; "
                            "a tracked output is bounded by settling_time and overshoot instead")
    _check_subset("input_disturbance input", list(scenario.input_disturbance), loop.actuated, where)
    exogenous = [n for n in plant_inputs if n not in loop.actuated]
    _check_subset("exogenous input", list(scenario.exogenous), exogenous, where)


def _scheduling_function(loop: Loop) -> Callable[[Mapping[str, float]], np.ndarray]:
    if callable(loop.scheduling):
        return lambda signals: np.asarray(loop.scheduling(signals), dtype=float).reshape(-1)
    exprs = loop.scheduling
    compiled: dict[tuple[str, ...], list[Callable[[np.ndarray], float]]] = {}

    def evaluate(signals: Mapping[str, float]) -> np.ndarray:
        names = tuple(signals)  # the same names at every step: compile once
        if names not in compiled:
            compiled[names] = [expressions.compile_expression(expr, list(names)) for expr in exprs]
        sample = list(signals.values())
        return np.array([value_of(sample) for value_of in compiled[names]])

    return evaluate


def simulate_loop(
    controller: Baseline, plant_fmu: str | Path, scenario: Scenario, loop: Loop, label: str = "controller"
) -> ClosedLoopRun:
    """Co-simulate ``controller`` and the plant FMU over ``scenario`` (module docstring of scenarios)."""
    law = _law(controller, loop)
    inputs = len(loop.measured) * (2 if law.structure == "2dof" else 1)
    if law.n_in != inputs or law.n_out != len(loop.actuated):
        raise ModelError(
            f"{label} ({law.structure}) has {law.n_in} input(s) and {law.n_out} output(s); the loop measures "
            f"{len(loop.measured)} plant output(s) {list(loop.measured)} ({inputs} {law.structure} "
            f"controller inputs) and drives {len(loop.actuated)} input(s) {list(loop.actuated)}"
        )
    n_p = law.basis.n_p if isinstance(law, LPVController) else getattr(law, "n_p", None)
    if n_p is not None and not callable(loop.scheduling) and n_p != len(loop.scheduling):
        raise ModelError(
            f"{label} is scheduled on {n_p} signal(s); the loop gives "
            f"{len(loop.scheduling)} scheduling expression(s)"
        )
    Ts = law.Ts
    n = step_count(Ts, scenario.duration)
    plant = open_plant(plant_fmu, plant_parameters(plant_fmu, loop, scenario))
    try:
        return _run(law, plant, scenario, loop, n, label)
    finally:
        plant.close()


def plant_parameters(plant_fmu: str | Path, loop: Loop, scenario: Scenario) -> dict[str, float]:
    """FMU parameter values of one run: value = f · v for every ``parameter_factors`` entry f, v the value
    from ``[verify.loop]``/scenario ``plant_parameters`` (the scenario's win) or else the FMU's start value;
    the other given values unchanged. An unknown or non-Real parameter, or a factor on a zero value, is one
    DataError line."""
    values = {**loop.plant_parameters, **scenario.plant_parameters}
    if not scenario.parameter_factors:
        return values
    where = f"scenario {scenario.name!r}: parameter_factors"
    real = {v.name: v for v in check_fmu(plant_fmu).modelVariables
            if v.causality == "parameter" and v.type == "Real"}
    for name, factor in scenario.parameter_factors.items():
        if name not in real:
            raise DataError(f"{where} names {name!r}, not a Real parameter of {Path(plant_fmu).name}; "
                            f"its parameters: {', '.join(real) or 'none'}")
        base = values.get(name, float(real[name].start or 0.0))
        if base == 0.0:
            raise DataError(f"{where}: {name} is 0, a factor cannot change it; give its value in "
                            "plant_parameters instead")
        values[name] = factor * base
    return values


def _input(law: LPVController | _FixedLaw | FmuController, r: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The controller input w(k): [r; y] for a 2-DOF input, the tracking error r − y otherwise."""
    return np.concatenate([r, y]) if law.structure == "2dof" else r - y


def _run(
    law: LPVController | _FixedLaw | FmuController,
    plant: Plant,
    scenario: Scenario,
    loop: Loop,
    n: int,
    label: str,
) -> ClosedLoopRun:
    Ts = law.Ts
    hint = (f" ({plant.model_name} is a controller written by `lpvflow export`, not a plant; give the "
            "plant's FMU)") if getattr(plant, "exported_controller", False) else ""
    _check_subset("measured plant output", loop.measured, plant.output_names, "loop", hint)
    _check_subset("actuated plant input", loop.actuated, plant.input_names, "loop", hint)
    _check_subset("actuator limit input", list(loop.actuator_limits), loop.actuated, "loop")
    _check_scenario(scenario, loop, plant.input_names)
    t = np.arange(n) * Ts
    y_op = loop.y_operating_point or (0.0,) * len(loop.measured)
    r = _sampled(scenario.reference, loop.measured, t, y_op)
    d_out = _sampled(scenario.output_disturbance, loop.measured, t, (0.0,) * len(loop.measured))
    d_in = _sampled(scenario.input_disturbance, loop.actuated, t, (0.0,) * len(loop.actuated))
    u_op = loop.u_operating_point or tuple(plant.start_value(name) for name in loop.actuated)
    u_op = np.asarray(law.u_offset if getattr(law, "u_offset", None) is not None else u_op, dtype=float)
    lo = np.array([loop.actuator_limits.get(name, (-np.inf, np.inf))[0] for name in loop.actuated])
    hi = np.array([loop.actuator_limits.get(name, (-np.inf, np.inf))[1] for name in loop.actuated])
    inputs = _sampled(
        scenario.exogenous, plant.input_names, t, [plant.start_value(name) for name in plant.input_names]
    )
    y_index = [plant.output_names.index(name) for name in loop.measured]
    u_index = [plant.input_names.index(name) for name in loop.actuated]
    exogenous = [j for j, name in enumerate(plant.input_names) if name not in loop.actuated]
    bounds = [(loop.measured.index(name), b) for name, b in scenario.output_bounds.items()]
    schedule = _scheduling_function(loop)

    y = np.full((n, len(loop.measured)), np.nan)
    u_c, u = np.full((n, len(loop.actuated)), np.nan), np.full((n, len(loop.actuated)), np.nan)
    p_log: list[np.ndarray] = []
    failure = None
    law.reset()
    for k in range(n):
        y_all = np.array(plant.outputs(), dtype=float)
        y_all[y_index] += d_out[k]
        y[k] = y_all[y_index]
        if not np.all(np.isfinite(y_all)):
            failure = f"diverged: plant output non-finite at t = {t[k]:g} s"
            break
        outside = [loop.measured[i] for i, (b_lo, b_hi) in bounds if not b_lo <= y[k, i] <= b_hi]
        if outside:
            failure = f"unbounded: {outside[0]} left its output_bounds at t = {t[k]:g} s"
            break
        signals = dict(zip(plant.output_names, y_all, strict=True))
        signals |= {plant.input_names[j]: inputs[k, j] for j in exogenous}
        p = schedule(signals)
        p_log.append(p)
        u_c[k] = u_op + law.step(_input(law, r[k], y[k]), p)
        if not np.all(np.isfinite(u_c[k])):
            failure = f"diverged: controller output non-finite at t = {t[k]:g} s"
            break
        u[k] = np.clip(u_c[k], lo, hi)
        inputs[k, u_index] = u[k] + d_in[k]
        try:
            plant.step(inputs[k], t[k], Ts)
        except LpvflowError as exc:
            failure = f"diverged: the plant FMU failed at t = {t[k]:g} s ({exc})"
            break
    n_p = len(p_log[0]) if p_log else 0
    p_arr = np.full((n, n_p), np.nan)
    p_arr[: len(p_log)] = p_log
    return ClosedLoopRun(label, t, r, y, u_c, u, p_arr, loop.measured, loop.actuated, failure,
                         _design_box(law))


def _design_box(law: LPVController | _FixedLaw | FmuController) -> np.ndarray | None:
    """The scheduling box of an LPV controller's polytope; None when the law does not schedule."""
    if isinstance(law, LPVController) and law.polytope.kind != "point":
        return np.asarray(law.polytope.box, dtype=float)
    return None


def scheduling_coverage(run: ClosedLoopRun) -> dict | None:
    """Visited scheduling range, and the time spent outside the controller's design box (module docstring);
    None when the loop has no scheduling signal."""
    p = run.scheduling[np.isfinite(run.scheduling).all(axis=1)]  # the samples before a failure
    if p.size == 0:
        return None
    coverage: dict = {"range": np.column_stack([p.min(axis=0), p.max(axis=0)]).tolist(), "box": None,
                      "time_outside_box": None, "first_outside_box": None}
    if run.scheduling_box is None:
        return coverage
    lo, hi = run.scheduling_box[:, 0], run.scheduling_box[:, 1]
    slack = 1e-9 * np.maximum(1.0, np.abs(run.scheduling_box)).max(axis=1)
    outside = np.any((p < lo - slack) | (p > hi + slack), axis=1)
    Ts = float(run.time[1] - run.time[0])
    coverage.update(box=run.scheduling_box.tolist(), time_outside_box=float(Ts * outside.sum()),
                    first_outside_box=float(run.time[np.argmax(outside)]) if outside.any() else None)
    return coverage


def box_text(rows: Sequence[Sequence[float]]) -> str:
    """A box given as [lo, hi] rows, e.g. "[-0.5, 0.5] × [0, 1]", 3 significant digits."""
    return " × ".join(f"[{lo:.3g}, {hi:.3g}]" for lo, hi in rows)


def coverage_note(metrics: Mapping) -> str:
    """One phrase when a run's scheduling left the controller's design box, else "": where and how far."""
    coverage = metrics.get("scheduling")
    if not coverage or coverage.get("first_outside_box") is None:
        return ""
    return (f"scheduling left the design box {box_text(coverage['box'])} at t = "
            f"{coverage['first_outside_box']:.3g} s and spanned {box_text(coverage['range'])} "
            f"({coverage['time_outside_box']:.3g} s outside)")


# --------------------------------------------------------------------------------------- metrics
def _last_change(signal: Signal | None) -> float | None:
    times = signal.change_times if signal is not None else []
    return max(times) if times else None


def tracking_metrics(
    time: np.ndarray, y: np.ndarray, reference: Signal | None, r_default: float, band: float | None, what: str
) -> dict:
    """Metrics of one output y (module docstring); ``reference`` None means constant r_default."""
    t_c = _last_change(reference)
    r_f = reference.sample(time[-1:])[0] if reference is not None else r_default
    if t_c is None:
        t_c, delta = float(time[0]), 0.0
    else:
        delta = r_f - reference.sample(np.array([t_c - 1e-6]))[0]
    if band is None:
        band = RELATIVE_BAND * abs(delta)
        if band == 0.0:
            raise DataError(f"{what}: the reference does not change; give settling_band for it")
    k_c = int(np.searchsorted(time, t_c - 1e-9))
    err = y[k_c:] - r_f
    Ts = float(time[1] - time[0]) if len(time) > 1 else 0.0
    outside = np.flatnonzero(~(np.abs(err) <= band))
    settle = k_c if outside.size == 0 else k_c + int(outside[-1]) + 1
    window = len(time) - max(1, math.ceil(FINAL_WINDOW * len(time)))
    overshoot = max(0.0, float(np.max(np.sign(delta) * err))) if delta != 0 else None
    return {
        "settling_time": float(time[settle] - t_c) if settle < len(time) else None,
        "settled": bool(settle <= window),
        "band": float(band),
        "reference_change": float(delta),
        "change_time": float(t_c),
        "overshoot": overshoot,
        "overshoot_percent": None if overshoot is None else 100.0 * overshoot / abs(delta),
        "peak_deviation": float(np.max(np.abs(err))),
        "steady_state_error": float(abs(np.mean(r_f - y[window:]))),
        "iae": float(Ts * np.sum(np.abs(err))),
        "ise": float(Ts * np.sum(err**2)),
    }


def _tracked(scenario: Scenario, loop: Loop) -> list[str]:
    if scenario.tracked is not None:
        return list(scenario.tracked)
    changing = [n for n in loop.measured if n in scenario.reference and scenario.reference[n].change_times]
    names = changing + [n for n in loop.measured if n in scenario.settling_band and n not in changing]
    if not names:
        raise DataError(
            f"scenario {scenario.name!r}: nothing to check; give a reference step or a "
            "settling_band for an output"
        )
    return names


def run_metrics(run: ClosedLoopRun, scenario: Scenario, loop: Loop) -> dict:
    """Metrics and stability verdict of one run (module docstring)."""
    Ts = float(run.time[1] - run.time[0])
    y_op = loop.y_operating_point or (0.0,) * len(loop.measured)
    clipped = np.isfinite(run.commanded) & (run.commanded != run.control)
    applied = np.where(np.isfinite(run.control), np.abs(run.control), -np.inf)
    controls = {
        name: {
            "peak_control": float(applied[:, j].max()) if np.isfinite(applied[:, j].max()) else None,
            "saturation_time": float(Ts * np.sum(clipped[:, j])),
        }
        for j, name in enumerate(run.actuated)
    }
    result = {
        "controller": run.label,
        "stable": False,
        "reason": run.failure,
        "outputs": {},
        "controls": controls,
        "scheduling": scheduling_coverage(run),
    }
    if run.failure is not None:
        if scenario.requirements is not None:
            result["requirements_failed"] = ["the run failed (see reason)"]
        return result
    for name in _tracked(scenario, loop):
        i = loop.measured.index(name)
        result["outputs"][name] = tracking_metrics(
            run.time,
            run.outputs[:, i],
            scenario.reference.get(name),
            y_op[i],
            scenario.settling_band.get(name),
            f"scenario {scenario.name!r}, output {name}",
        )
    unsettled = [name for name, m in result["outputs"].items() if not m["settled"]]
    result["stable"] = not unsettled
    result["reason"] = f"not settled: {', '.join(unsettled)}" if unsettled else "bounded and settled"
    result["after_settling"] = after_settling_peaks(run, scenario, loop, result["outputs"])
    if scenario.requirements is not None:
        result["requirements_failed"] = requirement_failures(
            scenario.requirements, result["outputs"], result["after_settling"])
    return result


def after_settling_peaks(run: ClosedLoopRun, scenario: Scenario, loop: Loop, tracked: Mapping[str, dict]
                         ) -> dict[str, float | None]:
    """max |y − r| of every measured output that is not tracked, from the instant the last tracked output
    settled (t_c + settling_time) to the end of the run; None for all when a tracked output never settled."""
    settled_at = [m["change_time"] + m["settling_time"] for m in tracked.values()
                  if m["settling_time"] is not None]
    others = [name for name in loop.measured if name not in tracked]
    if len(settled_at) < len(tracked):
        return dict.fromkeys(others)
    k = int(np.searchsorted(run.time, max(settled_at, default=run.time[0]) - 1e-9))
    y_op = loop.y_operating_point or (0.0,) * len(loop.measured)
    peaks = {}
    for name in others:
        i = loop.measured.index(name)
        signal = scenario.reference.get(name)
        r = signal.sample(run.time[k:]) if signal is not None else y_op[i]
        peaks[name] = float(np.max(np.abs(run.outputs[k:, i] - r)))
    return peaks


def requirement_failures(requirements: Requirements, tracked: Mapping[str, dict],
                         after_settling: Mapping[str, float | None]) -> list[str]:
    """The requirements a finished run misses, one phrase each (empty: all met)."""
    failures = []
    for name, m in tracked.items():
        limit = requirements.settling_time
        if limit is not None and (m["settling_time"] is None or m["settling_time"] > limit):
            settling = m["settling_time"]
            took = "does not settle" if settling is None else f"settles in {settling:.3g} s"
            failures.append(f"{name} {took} (limit {limit:g} s)")
        limit = requirements.overshoot
        if limit is not None and m["overshoot"] is not None and m["overshoot"] > limit:
            failures.append(f"{name} overshoot {m['overshoot']:.3g} (limit {limit:g})")
    for name, limit in requirements.after_settling.items():
        peak = after_settling.get(name)
        if peak is None:
            failures.append(f"{name} after settling: not measured, the tracked outputs do not settle")
        elif peak > limit:
            failures.append(f"{name} after settling {peak:.3g} (limit {limit:g})")
    return failures


# ---------------------------------------------------------------------------------- verification
@dataclass
class ScenarioResult:
    """The runs of one scenario (the controller and the optional baseline) and their metrics."""

    scenario: Scenario
    runs: list[ClosedLoopRun]
    metrics: list[dict]


@dataclass
class Verification:
    """Every scenario's runs and metrics; :meth:`to_dict` is the JSON written by ``lpvflow verify``."""

    plant: str
    loop: Loop
    results: list[ScenarioResult] = field(default_factory=list)

    @property
    def stable(self) -> bool:
        """True when the controller (not the baseline) passes every scenario's stability verdict."""
        return all(r.metrics[0]["stable"] for r in self.results)

    @property
    def passed(self) -> bool:
        """True when the controller is stable on every scenario and meets every scenario's requirements."""
        return all(run_passed(r.metrics[0]) for r in self.results)

    def to_dict(self) -> dict:
        return {
            **report_header("verification"),
            "plant": self.plant,
            "loop": self.loop.to_dict(),
            "stable": self.stable,
            "passed": self.passed,
            "scenarios": [
                {
                    "name": r.scenario.name,
                    "duration": r.scenario.duration,
                    "parameter_factors": dict(r.scenario.parameter_factors),
                    "requirements": r.scenario.requirements and r.scenario.requirements.to_dict(),
                    "controller": r.metrics[0],
                    "baseline": r.metrics[1] if len(r.metrics) > 1 else None,
                }
                for r in self.results
            ],
        }


def run_verification(
    controller: LPVController,
    plant_fmu: str | Path,
    scenarios: Sequence[Scenario],
    loop: Loop,
    baseline: Baseline | None = None,
) -> Verification:
    """Run the controller (and the baseline) on every scenario; see :func:`verify`."""
    if not scenarios:
        raise DataError("no scenarios to verify; give at least one [[scenario]]")
    if baseline is not None:
        base_Ts = _law(baseline, loop).Ts
        if abs(base_Ts - controller.Ts) > _TS_TOLERANCE * controller.Ts:
            raise ModelError(
                f"baseline Ts = {base_Ts:g} s differs from the controller Ts = {controller.Ts:g} s"
            )
    verification = Verification(str(plant_fmu), loop)
    for scenario in scenarios:
        runs = [simulate_loop(controller, plant_fmu, scenario, loop, "lpv")]
        if baseline is not None:
            runs.append(simulate_loop(baseline, plant_fmu, scenario, loop, "baseline"))
        verification.results.append(
            ScenarioResult(scenario, runs, [run_metrics(r, scenario, loop) for r in runs])
        )
    return verification


def verify(
    controller: LPVController,
    plant_fmu: str | Path,
    scenarios: Sequence[Scenario],
    loop: Loop,
    baseline: Baseline | None = None,
) -> dict:
    """Co-simulate ``controller`` with the plant FMU on each scenario; metrics and verdicts as a dict.

    ``baseline`` (an LTI controller, module docstring) runs on the same scenarios; its metrics are
    reported next to the controller's but do not enter the overall ``stable`` verdict.
    """
    return run_verification(controller, plant_fmu, scenarios, loop, baseline).to_dict()


# ---------------------------------------------------------------------------------------- figure
def plot_runs(runs: Sequence[ClosedLoopRun], path: str | Path, title: str = "",
              plant: str | Path | None = None) -> Path:
    """PNG of references, outputs and controls of the runs (e.g. LPV vs baseline), written atomically;
    each axis labelled with the unit the ``plant`` FMU declares for its signal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = runs[0]
    units = fmu_units(plant) if plant is not None else {}
    label = lambda name: f"{name} [{units[name]}]" if units.get(name) else name  # noqa: E731
    rows = len(first.measured) + len(first.actuated)
    fig, axes = plt.subplots(rows, 1, figsize=(7, 1.9 * rows), sharex=True, squeeze=False)
    for i, name in enumerate(first.measured):
        ax = axes[i, 0]
        ax.plot(first.time, first.reference[:, i], "k--", lw=1, label="reference")
        for run in runs:
            ax.plot(run.time, run.outputs[:, i], lw=1.2, label=run.label)
        ax.set_ylabel(label(name))
    for j, name in enumerate(first.actuated):
        ax = axes[len(first.measured) + j, 0]
        for run in runs:
            ax.step(run.time, run.control[:, j], where="post", lw=1.2, label=run.label)
        ax.set_ylabel(label(name))
    axes[0, 0].legend(loc="best", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".png", dir=path.parent)
    user_mode(fd)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
    finally:
        plt.close(fig)
    return path


def fmu_units(path: str | Path) -> dict[str, str]:
    """Unit of every variable of an FMU that declares one (its own or its declared type's)."""
    from fmpy import read_model_description

    units = {}
    for variable in read_model_description(str(path)).modelVariables:
        declared = getattr(variable, "declaredType", None)
        unit = variable.unit or getattr(declared, "unit", None)
        if unit:
            units[variable.name] = unit
    return units
