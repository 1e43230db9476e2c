"""One loader for every controller file lpvflow runs: an ``lpvflow/lti-controller``,
``lpvflow/gridded-controller`` or ``lpvflow/lpv-controller`` JSON file, or a controller FMU written by
``lpvflow export``. Each caller names the kinds it runs (the experiment
(:func:`lpvflow.experiment.loader.load_experiment_controller`) the three JSON kinds, ``lpvflow validate``
the LTI and LPV ones, ``lpvflow export`` the LPV one, verify these and FMUs); any other file is one ModelError
line naming its kind and the kinds the caller runs."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
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
#: The kind of a controller FMU (it has no format key).
FMU_KIND = "controller FMU"
#: Every kind of controller file.
ALL_KINDS = (FORMAT, GRIDDED_FORMAT, LPV_FORMAT, FMU_KIND)
#: The kinds verification runs (a gridded controller is scheduled by its own expression, not the loop's).
VERIFY_KINDS = (FORMAT, LPV_FORMAT, FMU_KIND)
#: The kinds an experiment runs (an FMU cannot be wired to the plant's signals).
JSON_KINDS = (FORMAT, GRIDDED_FORMAT, LPV_FORMAT)

#: What a controller file holds.
ControllerFile = LtiController | GriddedController | LPVController | FmuController


def lpv_controller(doc: dict, source: str) -> LPVController:
    """The :class:`LPVController` of an ``lpvflow/lpv-controller`` document; any defect is one line."""
    try:
        return LPVController.from_dict(doc)
    except (TypeError, ValueError, IndexError, KeyError) as exc:  # one line whatever the defect
        raise ModelError(f"{source}: {str(exc).splitlines()[0]}") from None


#: A reader of one JSON kind: (document, source named in errors) -> controller.
Reader = Callable[[dict, str], object]
#: The reader of each JSON kind.
READERS: dict[str, Reader] = {FORMAT: LtiController.from_dict, GRIDDED_FORMAT: GriddedController.from_dict,
                              LPV_FORMAT: lpv_controller}


def load_controller_file(path: str | Path, accept: Sequence[str] = ALL_KINDS, runner: str = "lpvflow",
                         readers: Mapping[str, Reader] = READERS) -> ControllerFile:
    """The controller in ``path``, one of the kinds ``accept`` (module docstring), read by ``readers``
    (e.g. the experiment's, which wires an LPV controller to the plant signals); a missing, unreadable
    or malformed file, or one of another kind, is one ModelError line saying what ``runner`` runs."""
    path = Path(path)
    source = f"controller file {path}"
    runs = f"{runner} runs {', '.join(map(repr, accept[:-1]))}{' or ' if len(accept) > 1 else ''}" \
           f"{accept[-1]!r} controllers"
    if path.suffix.lower() == ".fmu":
        if FMU_KIND not in accept:
            raise ModelError(f"{source} is a {FMU_KIND}; {runs}")
        return FmuController(path)
    doc = read_controller_json(path)
    kind = doc.get("format") if isinstance(doc, dict) else None
    if kind not in READERS:
        raise ModelError(f"{source} has format {kind!r}, which holds no controller; {runs}")
    if kind not in accept:
        raise ModelError(f"{source} is an {kind} file; {runs}")
    return readers[kind](doc, source)
