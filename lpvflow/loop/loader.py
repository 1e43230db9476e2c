"""One loader for every controller file lpvflow runs: an ``lpvflow/lti-controller``,
``lpvflow/gridded-controller`` or ``lpvflow/lpv-controller`` JSON file, or a controller FMU written by
``lpvflow export``. The experiment (:func:`lpvflow.experiment.loader.load_experiment_controller`), verify
and export read controller files through :func:`load_controller_file` and refuse, in one line, the kinds
they cannot run."""

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
from lpvflow.loop.fmu_controller import FmuController
from lpvflow.synth.controller import LPVController

#: Format of the synthesized LPV controllers (:class:`lpvflow.synth.controller.LPVController`).
LPV_FORMAT = "lpvflow/lpv-controller"

#: What a controller file holds.
ControllerFile = LtiController | GriddedController | LPVController | FmuController


def load_controller_file(path: str | Path) -> ControllerFile:
    """The controller in ``path`` (module docstring); a missing, unreadable or malformed file, or one of
    another format, is one ModelError line."""
    path = Path(path)
    if path.suffix.lower() == ".fmu":
        return FmuController(path)
    doc = read_controller_json(path)
    kind = doc.get("format") if isinstance(doc, dict) else None
    source = f"controller file {path}"
    if kind == GRIDDED_FORMAT:
        return GriddedController.from_dict(doc, source)
    if kind == LPV_FORMAT:
        try:
            return LPVController.from_dict(doc)
        except (TypeError, ValueError, IndexError, KeyError) as exc:  # one line whatever the defect
            raise ModelError(f"{source}: {str(exc).splitlines()[0]}") from None
    if kind == FORMAT:
        return LtiController.from_dict(doc, source)
    raise ModelError(f"{source} has format {kind!r}; an experiment runs {FORMAT!r}, {GRIDDED_FORMAT!r} or "
                     f"{LPV_FORMAT!r} controllers, verify also exported controller FMUs")
