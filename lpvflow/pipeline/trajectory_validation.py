"""The robustness stage's validation along trajectories: the design's reduced model in the loop of the
shipped controller against the plant FMU in the same loop, on every ``[verify]`` scenario.

The model runs as the plant of :mod:`lpvflow.validate.trajectory` in the signals it was identified in:
scheduled by the ``[experiment] scheduling`` expressions of its own outputs (as the validate stage's
closed-loop fit, :func:`lpvflow.pipeline.model_loop.scheduling_expression`), its input the controller's
command minus the experiment controller's trim at its outputs with ``[identify] remove_trim``
(:func:`experiment_trim`) and minus the estimation data's mean input with ``remove_offsets``, which also
adds the mean output back (:func:`lpvflow.pipeline.coordinates.read_data`). The frozen ν-gap of the
validate stage compares model and plant at equilibria only; here they are compared along the moves the
controller is verified on, where the plant is far from them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from lpvflow.errors import LpvflowError
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.fmu import check_fmu
from lpvflow.loop.model_plant import ModelPlant
from lpvflow.models import LPVSS
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.coordinates import read_data
from lpvflow.pipeline.model_loop import check_wiring, scheduling_expression
from lpvflow.validate.trajectory import trajectory_agreement


def experiment_trim(path: str, model: LPVSS) -> Callable[[np.ndarray], np.ndarray]:
    """y ↦ u_op(θ(y)) over the model inputs (0 for inputs it does not drive): the trim of the experiment
    controller in ``path`` at the model outputs y, its set-points equal to its measurements (the
    equilibrium convention of :meth:`~lpvflow.experiment.controller.GriddedController.linearized`), as
    :func:`lpvflow.pipeline.coordinates.controller_trim` removed it from the identification data."""
    K = load_experiment_controller(path)
    check_wiring(K, model.u_names, model.y_names, "[identify] remove_trim in the model-in-the-loop runs")
    law = K.loop_law()
    schedule = law.scheduling(model.y_names)
    read = [model.y_names.index(name) for name in law.inputs]
    driven = [model.u_names.index(name) for name in law.outputs]

    def trim(y: np.ndarray) -> np.ndarray:
        u = np.zeros(len(model.u_names))
        u[driven] = law.trim(schedule(y, y[read]))
        return u

    return trim


def model_plant_factory(ctx: StageContext, model: LPVSS) -> Callable[[], ModelPlant]:
    """Fresh :class:`~lpvflow.loop.model_plant.ModelPlant` runs of ``model`` in its identification
    signals (module docstring), its inputs' start values those of the plant FMU."""
    identify, experiment = ctx.config["identify"], ctx.config["experiment"]
    expressions = [scheduling_expression(name, experiment["scheduling"], model.y_names)
                   for name in model.p_names]
    trim = experiment_trim(experiment["controller"], model) if identify["remove_trim"] else None
    offsets = read_data(ctx, model_signals=True)[0].offsets if identify["remove_offsets"] else None
    starts = {v.name: float(v.start or 0.0) for v in check_fmu(ctx.config["design"]["plant"]).modelVariables
              if v.causality == "input"}
    return lambda: ModelPlant(model, expressions, trim, offsets, starts)


def trajectory_validation(ctx: StageContext, model: LPVSS, controller: Any) -> dict:
    """``{"trajectory": rows}``, one row per ``[verify] scenario``:
    :meth:`~lpvflow.validate.trajectory.TrajectoryAgreement.to_dict` (the largest |y_plant − y_model| of
    every measured output, in the plant's units, and each run's failure); or ``{"trajectory_note": why}``
    when the model cannot run in the loop (a feed-through, a scheduling signal its outputs do not give, a
    measured signal it lacks). Reporting only: nothing here changes the verdict."""
    verify = ctx.config["verify"]
    try:
        make = model_plant_factory(ctx, model)
        rows = trajectory_agreement(controller, ctx.config["design"]["plant"], make, verify["scenario"],
                                    verify["loop"])
    except LpvflowError as exc:
        return {"trajectory_note": f"the model-in-the-loop runs were not made: {exc}"}
    return {"trajectory": [row.to_dict() for row in rows]}
