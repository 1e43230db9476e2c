"""Validation along trajectories: the identified model in the loop against the plant FMU in the same loop.

The frozen ν-gap compares model and plant at equilibria only. Here the model takes the plant's place in
the verification loop of :mod:`lpvflow.pipeline.verify` — the same controller, reference moves, actuator
limits and scheduling expressions — and the largest difference of every measured output between the
model-in-the-loop and the plant-in-the-loop runs is reported per scenario. Under a high-gain controller
feedback hides model error, so this is meant to be judged under a robust design.

The model as a plant (:class:`ModelPlant`) is the quasi-LPV simulation

    p(k) = scheduling(y(k)),  x(k+1) = A(p(k)) x(k) + B(p(k)) (u(k) − u_trim(p(k))),  y(k+1) = C(p(k)) x(k+1),

from x(0) = 0, u_trim the trim the model was identified without (``[identify] remove_trim``; zero when
absent). C at p(k) instead of p(k+1), as in the validate stage's closed-loop fit, is exact for the
observable-form realizations lpvflow identifies (C independent of p). Strictly proper models only (D = 0,
as identified with an input delay): y(k) must not depend on u(k), which the loop computes from y(k).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
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
                 trim: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        """``scheduling``: one expression per model scheduling signal in the model's output names;
        ``trim``: p ↦ u_trim(p) (nu,), subtracted from the input."""
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
        self._x = np.zeros(model.nx)
        self._y = np.zeros(len(self.output_names))

    def start_value(self, name: str) -> float:
        return 0.0

    def parameter_values(self) -> dict[str, float | int | bool]:
        return {}

    def outputs(self) -> np.ndarray:
        return self._y.copy()

    def step(self, u: np.ndarray, t: float, Ts: float) -> None:
        p = np.array([value_of(self._y) for value_of in self._scheduling])
        A, B, C, _ = self.model.matrices(p)
        u_model = np.asarray(u, dtype=float) - (self._trim(p) if self._trim is not None else 0.0)
        self._x = A @ self._x + B @ u_model
        self._y = C @ self._x

    def close(self) -> None:
        """Nothing to release."""


@dataclass(frozen=True)
class TrajectoryAgreement:
    """One scenario: the largest |y_plant − y_model| per measured output, and each run's failure (or None)."""

    scenario: str
    largest_difference: dict[str, float]
    plant_failure: str | None
    model_failure: str | None

    def to_dict(self) -> dict:
        return {"scenario": self.scenario, "largest_difference": self.largest_difference,
                "plant_failure": self.plant_failure, "model_failure": self.model_failure}


def trajectory_agreement(controller: object, plant_fmu: str | Path, model_plant: Callable[[], ModelPlant],
                         scenarios: Sequence[Scenario], loop: Loop) -> list[TrajectoryAgreement]:
    """Per scenario, the model-in-the-loop against the plant-in-the-loop under ``controller``.

    ``model_plant`` makes a fresh :class:`ModelPlant` (state 0) for each run. The differences are taken
    over the samples both runs completed (a run stops early when it diverges or leaves its output bounds;
    its ``failure`` says so).
    """
    results = []
    for scenario in scenarios:
        on_plant = simulate_loop(controller, plant_fmu, scenario, loop, "plant in the loop")
        on_model = simulate_loop_on(controller, model_plant(), scenario, loop, "model in the loop")
        results.append(TrajectoryAgreement(scenario.name, _largest_difference(on_plant, on_model),
                                           on_plant.failure, on_model.failure))
    return results


def _largest_difference(a: ClosedLoopRun, b: ClosedLoopRun) -> dict[str, float]:
    both = np.isfinite(a.outputs).all(axis=1) & np.isfinite(b.outputs).all(axis=1)
    gap = np.abs(a.outputs[both] - b.outputs[both])
    return {name: float(gap[:, i].max(initial=0.0)) for i, name in enumerate(a.measured)}
