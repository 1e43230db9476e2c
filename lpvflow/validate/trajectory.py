"""Validation along trajectories: the identified model in the loop against the plant FMU in the same loop.

The frozen ν-gap compares model and plant at equilibria only. Here the model takes the plant's place in
the verification loop of :mod:`lpvflow.pipeline.verify` — the same controller, reference moves, actuator
limits and scheduling expressions — and the largest difference of every measured output between the
model-in-the-loop and the plant-in-the-loop runs is reported per scenario. Under a high-gain controller
feedback hides model error, so this is meant to be judged under a robust design.

The model is the plant :class:`lpvflow.loop.model_plant.ModelPlant` (the quasi-LPV simulation in the
identification coordinates, the one the validate stage's closed-loop fit runs). Each model run starts
at rest at the plant run's initial measured outputs (:meth:`~lpvflow.loop.model_plant.ModelPlant.rest_at`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lpvflow.loop.model_plant import ModelPlant
from lpvflow.pipeline.scenarios import Loop, Scenario
from lpvflow.pipeline.verify import ClosedLoopRun, simulate_loop, simulate_loop_on


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
