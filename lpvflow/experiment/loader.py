"""One loader for every controller file an experiment (and the design's stages) can run."""

from __future__ import annotations

from pathlib import Path

from lpvflow.errors import ModelError
from lpvflow.experiment.controller import (
    FORMAT,
    GRIDDED_FORMAT,
    GriddedController,
    LtiController,
    read_controller_json,
)
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.synth.controller import LPVController

#: Controllers an experiment can run.
ExperimentController = LtiController | GriddedController | SynthesizedController


#: Format of the synthesized LPV controllers (:class:`lpvflow.synth.controller.LPVController`).
LPV_FORMAT = "lpvflow/lpv-controller"


def load_experiment_controller(path: str | Path) -> ExperimentController:
    """Read an ``lpvflow/lti-controller``, ``lpvflow/gridded-controller`` or ``lpvflow/lpv-controller`` JSON
    file (the last wired by its ``info["signals"]``, :mod:`lpvflow.experiment.synthesized`)."""
    path = Path(path)
    doc = read_controller_json(path)
    kind = doc.get("format") if isinstance(doc, dict) else None
    if kind == GRIDDED_FORMAT:
        return GriddedController.from_dict(doc, f"controller file {path}")
    if kind == LPV_FORMAT:
        try:
            law = LPVController.from_dict(doc)
        except (TypeError, ValueError, IndexError) as exc:  # ModelError is a ValueError: one line either way
            raise ModelError(f"controller file {path}: {str(exc).splitlines()[0]}") from None
        return SynthesizedController.from_controller(law, f"controller file {path}")
    if kind not in (FORMAT, None):
        raise ModelError(f"controller file {path} has format {kind!r}; an experiment runs "
                         f"{FORMAT!r}, {GRIDDED_FORMAT!r} or {LPV_FORMAT!r} controllers")
    return LtiController.from_dict(doc, f"controller file {path}")
