"""The controllers an experiment (and the design's stages) can run, read through the one controller
loader (:func:`lpvflow.loop.loader.load_controller_file`)."""

from __future__ import annotations

from pathlib import Path

from lpvflow.errors import ModelError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.loop.loader import load_controller_file
from lpvflow.synth.controller import LPVController

#: Controllers an experiment can run.
ExperimentController = LtiController | GriddedController | SynthesizedController


def load_experiment_controller(path: str | Path) -> ExperimentController:
    """An ``lpvflow/lti-controller``, ``lpvflow/gridded-controller`` or ``lpvflow/lpv-controller`` JSON
    file (the last wired by its ``info["signals"]``, :mod:`lpvflow.experiment.synthesized`)."""
    controller = load_controller_file(path)
    if isinstance(controller, LPVController):
        return SynthesizedController.from_controller(controller, f"controller file {path}")
    if not isinstance(controller, LtiController | GriddedController):
        raise ModelError(f"controller file {path} is a controller FMU; an experiment runs the JSON "
                         "controller files (lpvflow/lti-controller, lpvflow/gridded-controller, "
                         "lpvflow/lpv-controller)")
    return controller
