"""Closed-loop verification: the controller and a plant FMU co-simulated at the controller's Ts.

The plant is an FMI 2.0 Co-Simulation FMU stepped through fmpy's instance API
(:func:`lpvflow.experiment.plant.open_plant`, built on :func:`lpvflow.fmu.open_fmu`); the loop law
and the scenario file are described in :mod:`lpvflow.pipeline.scenarios`. Sampling convention (as the
experiment runner): read y(k) at t_k, form u(k), hold it from t_k to t_k + Ts.

Controllers: an :class:`~lpvflow.synth.controller.LPVController` (u = u_eq(p) + K(p) w with w = r − y
for ``structure = "1dof"``, w = [r − y_op; y − y_op] for ``"2dof"``, y_op its recorded operating point of
the measured outputs, u_eq the controller's trim feed-forward); a discrete
``control.StateSpace`` (1-DOF, no scheduling); an ``lpvflow/lti-controller`` file
(:class:`~lpvflow.experiment.controller.LtiController`, 1-DOF), run with its own operating input u_op and
its y_op replaced by the reference: u = u_op + C xc + D (y − r), xc⁺ = A xc + B (y − r); or an exported
controller FMU (:class:`~lpvflow.loop.fmu_controller.FmuController`), handed r and y on its separate ports.

Plant parameters of a run (:func:`plant_parameters`): ``[verify.loop] plant_parameters``, overridden by
the scenario's, then every scenario ``parameter_factors`` entry f multiplies its parameter's value
(the FMU's start value when neither table sets it): a perturbed plant, e.g. ``pendulum_mass = 1.1``.

Metrics and verdicts of a run: :mod:`lpvflow.pipeline.loop_metrics`.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import control
import numpy as np

from lpvflow.errors import DataError, ModelError
from lpvflow.experiment import scheduling as expressions
from lpvflow.experiment.controller import LtiController
from lpvflow.experiment.plant import Plant, open_plant
from lpvflow.experiment.run import step_count
from lpvflow.fmu import check_fmu
from lpvflow.loop.engine import close_loop
from lpvflow.loop.fmu_controller import FmuController
from lpvflow.loop.protocol import FixedLaw, VerificationLaw
from lpvflow.models import report_header, user_mode
from lpvflow.pipeline.loop_metrics import ClosedLoopRun, run_metrics, tracked_outputs
from lpvflow.pipeline.scenarios import Loop, Scenario, Signal, run_passed
from lpvflow.synth.controller import LPVController

_TS_TOLERANCE = 1e-9


#: Controllers the loop can run.
Baseline = LPVController | control.StateSpace | LtiController | FmuController


def _law(controller: Baseline, loop: Loop) -> VerificationLaw:
    """The controller as a verification law (:class:`~lpvflow.loop.protocol.VerificationLaw`):
    a discrete StateSpace reads e = r − y; the controller classes give their own
    (``verification_law``)."""
    if isinstance(controller, control.StateSpace):
        if not controller.isdtime(strict=True):
            raise ModelError("the baseline StateSpace is continuous; discretise it at the controller's Ts")
        return FixedLaw(controller.A, controller.B, controller.C, controller.D, float(controller.dt), 1.0)
    return controller.verification_law(loop.measured, loop.actuated)


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
        tracked = set(tracked_outputs(scenario, loop))
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
    plant = open_plant(plant_fmu, plant_parameters(plant_fmu, loop, scenario))
    try:
        return simulate_loop_on(controller, plant, scenario, loop, label)
    finally:
        plant.close()


def simulate_loop_on(
    controller: Baseline, plant: Plant, scenario: Scenario, loop: Loop, label: str = "controller"
) -> ClosedLoopRun:
    """:func:`simulate_loop` on an open ``plant`` (an FMU, or any object with the experiment's
    :class:`~lpvflow.experiment.plant.Plant` protocol, e.g. a model); the caller closes it."""
    law = _law(controller, loop)
    inputs = len(loop.measured) * (2 if law.structure == "2dof" else 1)
    if law.n_in != inputs or law.n_out != len(loop.actuated):
        raise ModelError(
            f"{label} ({law.structure}) has {law.n_in} input(s) and {law.n_out} output(s); the loop measures "
            f"{len(loop.measured)} plant output(s) {list(loop.measured)} ({inputs} {law.structure} "
            f"controller inputs) and drives {len(loop.actuated)} input(s) {list(loop.actuated)}"
        )
    n_p = law.n_p
    if n_p is not None and not callable(loop.scheduling) and n_p != len(loop.scheduling):
        raise ModelError(
            f"{label} is scheduled on {n_p} signal(s); the loop gives "
            f"{len(loop.scheduling)} scheduling expression(s)"
        )
    return _run(law, plant, scenario, loop, step_count(law.Ts, scenario.duration), label)


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


class _LoopLaw:
    """A verified controller in the loop protocol (:mod:`lpvflow.loop.protocol`): it reads the loop's
    ``measured`` outputs, drives its ``actuated`` inputs, is scheduled by the loop's expressions of the
    plant signals and commands u = u_op + law(w, p), w = law.input_of(r, y) (r − y for a 1-DOF input,
    [r − y_op; y − y_op] for a 2-DOF LPV controller, [r; y] for a controller FMU, which subtracts its
    operating point itself)."""

    def __init__(self, law: VerificationLaw, loop: Loop, u_op: np.ndarray) -> None:
        self.law, self.Ts, self.u_op = law, law.Ts, u_op
        self.inputs, self.outputs = tuple(loop.measured), tuple(loop.actuated)
        self._schedule = _scheduling_function(loop)

    def scheduling(self, names: Sequence[str]) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        names = list(names)
        return lambda sample, r: self._schedule(dict(zip(names, sample, strict=True)))

    def reset(self) -> None:
        self.law.reset()

    def step(self, r: np.ndarray, y: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self.u_op + self.law.step(self.law.input_of(r, y), p)

    def trim(self, p: np.ndarray) -> np.ndarray:
        return self.u_op + self.law.feedforward(p)


def _run(
    law: VerificationLaw,
    plant: Plant,
    scenario: Scenario,
    loop: Loop,
    n: int,
    label: str,
) -> ClosedLoopRun:
    """One scenario through the closed-loop engine (:func:`lpvflow.loop.engine.close_loop`): output
    disturbances on the measurement, output bounds as the stopping rule, exogenous inputs among the
    scheduling signals, actuator limits and input disturbances on the command."""
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
    u_op = np.asarray(law.u_offset if law.u_offset is not None else u_op, dtype=float)
    lo = np.array([loop.actuator_limits.get(name, (-np.inf, np.inf))[0] for name in loop.actuated])
    hi = np.array([loop.actuator_limits.get(name, (-np.inf, np.inf))[1] for name in loop.actuated])
    inputs = _sampled(
        scenario.exogenous, plant.input_names, t, [plant.start_value(name) for name in plant.input_names]
    )
    y_index = [plant.output_names.index(name) for name in loop.measured]
    u_index = [plant.input_names.index(name) for name in loop.actuated]
    exogenous = [j for j, name in enumerate(plant.input_names) if name not in loop.actuated]
    bounds = [(loop.measured.index(name), b) for name, b in scenario.output_bounds.items()]

    y = np.full((n, len(loop.measured)), np.nan)
    u_c, u = np.full((n, len(loop.actuated)), np.nan), np.full((n, len(loop.actuated)), np.nan)
    p_log: list[np.ndarray] = []

    def measure(k: int, y_all: np.ndarray) -> np.ndarray:
        y_all[y_index] += d_out[k]
        y[k] = y_all[y_index]
        return y_all

    def stop(k: int, y_all: np.ndarray) -> str | None:
        if not np.all(np.isfinite(y_all)):
            return f"diverged: plant output non-finite at t = {t[k]:g} s"
        outside = [loop.measured[i] for i, (b_lo, b_hi) in bounds if not b_lo <= y[k, i] <= b_hi]
        return f"unbounded: {outside[0]} left its output_bounds at t = {t[k]:g} s" if outside else None

    def actuate(k: int, command: np.ndarray, p: np.ndarray) -> np.ndarray:
        u[k] = np.clip(command, lo, hi)
        inputs[k, u_index] = u[k] + d_in[k]
        return inputs[k]

    def record(k: int, y_all: np.ndarray, p: np.ndarray, command: np.ndarray, _: np.ndarray | None) -> None:
        p_log.append(p)
        u_c[k] = command

    names = [*plant.output_names, *(plant.input_names[j] for j in exogenous)]
    failure = close_loop(
        _LoopLaw(law, loop, u_op), plant, n, r, scheduling_names=names, measure=measure,
        signals=lambda k, y_all: np.concatenate([y_all, inputs[k, exogenous]]),
        actuate=actuate, stop=stop, record=record,
        plant_failure=lambda k, exc: f"diverged: the plant FMU failed at t = {t[k]:g} s ({exc})")
    n_p = len(p_log[0]) if p_log else 0
    p_arr = np.full((n, n_p), np.nan)
    p_arr[: len(p_log)] = p_log
    return ClosedLoopRun(label, t, r, y, u_c, u, p_arr, loop.measured, loop.actuated, failure,
                         law.design_box)


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


def fmu_units(path: str | Path | None) -> dict[str, str]:
    """Unit of every variable of an FMU that declares one (its own or its declared type's); none without
    an FMU (a design on recorded data)."""
    from fmpy import read_model_description

    if path is None:
        return {}
    units = {}
    for variable in read_model_description(str(path)).modelVariables:
        declared = getattr(variable, "declaredType", None)
        unit = variable.unit or getattr(declared, "unit", None)
        if unit:
            units[variable.name] = unit
    return units
