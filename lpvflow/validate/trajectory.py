"""Validation along trajectories: the identified model in the loop against the plant FMU in the same loop.

The frozen ν-gap compares model and plant at equilibria only. Here the model takes the plant's place in
the verification loop of :mod:`lpvflow.pipeline.verify` — the same controller, reference moves, actuator
limits and scheduling expressions — and the largest difference of every measured output between the
model-in-the-loop and the plant-in-the-loop runs is reported per scenario. Under a high-gain controller
feedback hides model error, so this is meant to be judged under a robust design.

The model as a plant (:class:`ModelPlant`) is the quasi-LPV simulation

    p(k) = scheduling(y(k)),  x(k+1) = A(p(k)) x(k) + B(p(k)) (u(k) − u₀ − u_trim(y(k))),
    y(k+1) = y₀ + C(p(k)) x(k+1),

u_trim the trim the model was identified without (``[identify] remove_trim``; zero when absent) and
(u₀, y₀) the operating point it was identified around (``[identify] remove_offsets``; zero when absent).
C at p(k) instead of p(k+1), as in the validate stage's closed-loop fit, is exact for the observable-form
realizations lpvflow identifies (C independent of p). Strictly proper models only (D = 0, as identified
with an input delay): y(k) must not depend on u(k), which the loop computes from y(k). Each model run
starts at rest at the plant run's initial measured outputs (:meth:`ModelPlant.rest_at`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lpvflow.errors import ModelError
from lpvflow.experiment.scheduling import compile_expression
from lpvflow.models import LPVSS
from lpvflow.pipeline.scenarios import Loop, Scenario
from lpvflow.pipeline.verify import ClosedLoopRun, simulate_loop, simulate_loop_on


class ModelPlant:
    """An :class:`~lpvflow.models.LPVSS` behind the experiment's Plant protocol (module docstring)."""

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
        A, B, C, _ = self.model.matrices(self.schedule(y))
        nx = self.model.nx
        lhs = np.block([[A - np.eye(nx), B], [C[rows], np.zeros((len(rows), B.shape[1]))]])
        rhs = np.concatenate([np.zeros(nx), (y - self._y0)[rows]])
        self._x = np.linalg.lstsq(lhs, rhs, rcond=None)[0][:nx]
        self._y = self._y0 + C @ self._x

    def step(self, u: np.ndarray, t: float, Ts: float) -> None:
        p = self.schedule(self._y)
        A, B, C, _ = self.model.matrices(p)
        trim = self._trim(self._y) if self._trim is not None else 0.0
        u_model = np.asarray(u, dtype=float) - self._u0 - trim
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model ends its run (non-finite y)
            self._x = A @ self._x + B @ u_model
            self._y = self._y0 + C @ self._x

    def close(self) -> None:
        """Nothing to release."""


@dataclass(frozen=True)
class TrajectoryAgreement:
    """One scenario: the largest |y_plant − y_model| per measured output, the largest change per sample
    |y(k+1) − y(k)| of each measured output in the plant-in-the-loop run (e.g. how fast a scheduling
    signal moves), and each run's failure (or None)."""

    scenario: str
    largest_difference: dict[str, float]
    largest_step: dict[str, float]
    plant_failure: str | None
    model_failure: str | None

    def to_dict(self) -> dict:
        return {"scenario": self.scenario, "largest_difference": self.largest_difference,
                "largest_step": self.largest_step, "plant_failure": self.plant_failure,
                "model_failure": self.model_failure}


def trajectory_agreement(controller: object, plant_fmu: str | Path, model_plant: Callable[[], ModelPlant],
                         scenarios: Sequence[Scenario], loop: Loop) -> list[TrajectoryAgreement]:
    """Per scenario, the model-in-the-loop against the plant-in-the-loop under ``controller``.

    ``model_plant`` makes a fresh :class:`ModelPlant` for each run, which starts at rest at the plant run's
    first measured outputs (:meth:`ModelPlant.rest_at`). The differences are taken over the samples both
    runs completed (a run stops early when it diverges or leaves its output bounds; its ``failure`` says
    so).
    """
    results = []
    for scenario in scenarios:
        on_plant = simulate_loop(controller, plant_fmu, scenario, loop, "plant in the loop")
        model = model_plant()
        model.rest_at({name: value for name, value in zip(on_plant.measured, on_plant.outputs[0], strict=True)
                       if np.isfinite(value)})
        on_model = simulate_loop_on(controller, model, scenario, loop, "model in the loop")
        results.append(TrajectoryAgreement(scenario.name, _largest_difference(on_plant, on_model),
                                           _largest_step(on_plant), on_plant.failure, on_model.failure))
    return results


def _largest_step(run: ClosedLoopRun) -> dict[str, float]:
    """max_k |y(k+1) − y(k)| of each measured output over the samples the run completed (finite)."""
    finite = np.isfinite(run.outputs).all(axis=1)
    steps = np.abs(np.diff(run.outputs, axis=0))[finite[:-1] & finite[1:]]
    return {name: float(steps[:, i].max(initial=0.0)) for i, name in enumerate(run.measured)}


def _largest_difference(a: ClosedLoopRun, b: ClosedLoopRun) -> dict[str, float]:
    both = np.isfinite(a.outputs).all(axis=1) & np.isfinite(b.outputs).all(axis=1)
    gap = np.abs(a.outputs[both] - b.outputs[both])
    return {name: float(gap[:, i].max(initial=0.0)) for i, name in enumerate(a.measured)}
