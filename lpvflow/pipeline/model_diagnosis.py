"""The diagnosis of a user's model on its record, as `lpvflow diagnose` and a design's ``[diagnose]``
stage both run it: the record put in the signals the model was identified in (the loop controller's
trim u_op(θ(k)) taken off the inputs, then the operating point's means off inputs and outputs), the
recorded set-points and the candidate channels read from the record, then
:func:`lpvflow.validate.diagnose.diagnose` in the controller's loop; and the extended model it saves
run on the record in the same signals and loop (:func:`simulate_extended`, `lpvflow simulate`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.controller import FORMAT, GRIDDED_FORMAT, GriddedController, LtiController
from lpvflow.loop.loader import load_controller_file
from lpvflow.lpvio import LPVIO
from lpvflow.pipeline.coordinates import about_operating_point, without_offsets
from lpvflow.validate.diagnose import MIN_VALIDATION, Diagnosis, diagnose
from lpvflow.validate.extended_model import ExtendedModel, controller_fingerprint
from lpvflow.validate.extensions import Structure


def loop_controller(path: str | Path, runner: str) -> LtiController | GriddedController:
    """The controller a record was made under, of a kind a diagnosis simulates its loop with (an
    ``lpvflow/lti-controller`` or ``lpvflow/gridded-controller``); another kind is one ModelError line
    saying what ``runner`` runs."""
    return load_controller_file(path, (FORMAT, GRIDDED_FORMAT), runner)


def diagnose_model(
    table: Mapping[str, np.ndarray], data: Dataset, structure: Structure, *, split: float,
    candidates: Sequence[str], model: LPVIO | None = None,
    controller: LtiController | GriddedController | None = None, scheduling: Mapping[str, str] | None = None,
    remove_trim: bool = False, remove_offsets: bool = False, operating_point: float | None = None,
    causes: list[str] | None = None, progress: bool = False,
) -> tuple[Diagnosis, Dataset]:
    """The diagnosis of ``model`` (of ``structure``; None: the structure refitted on the estimation
    part) on the record ``data`` read from the columns ``table``, and the record as diagnosed.

    Args:
        split: estimation fraction; the nominal fit reported is the model's simulation on the rest.
        candidates: columns of ``table`` that may be missing scheduling variables.
        controller: the controller the record was made under (:func:`loop_controller`); every model is
            simulated in its loop, the record's ``<output>_setpoint`` columns its references, the
            ``scheduling`` expressions recomputed from the simulated outputs.
        remove_trim: the model's inputs are the recorded ones minus the controller's trim
            u_op(θ(k)) (its ``trim_along`` the recorded columns), as ``[identify] remove_trim``.
        remove_offsets: subtract the operating point's mean inputs and outputs (after the trim): the means
            of the first ``operating_point`` fraction of the record (the design's estimation part), of
            the whole record when None (``lpvflow identify --remove-offsets``). A ``model`` that records
            the operating point it was identified about (``LPVIO.operating_point``) is always diagnosed
            about that one.
    """
    if remove_trim:
        if controller is None:
            raise DataError("remove_trim takes off the trim of the controller the data were recorded under: "
                            "give that controller (--controller; in a design [experiment] controller)")
        data = replace(data, u=data.u - recorded_trim(controller, data, table))
    if model is not None and model.operating_point:
        data = about_operating_point(data, model.operating_point)
    elif remove_offsets:
        data = without_offsets(data, data if operating_point is None else data.split(operating_point)[0])
    missing = [c for c in candidates if c not in table]
    if missing:
        raise DataError(f"candidate column(s) {missing} not found; available: {sorted(table)}")
    if data.N * (1 - split) < MIN_VALIDATION:
        raise DataError(f"{data.N} samples leave fewer than {MIN_VALIDATION} for validation at split "
                        f"{split}: record longer data or lower the split")
    setpoints = recorded_setpoints(table, controller, data.N) if controller is not None else None
    result = diagnose(data, structure, {c: table[c] for c in candidates}, split=split, causes=causes,
                      controller=controller, scheduling=scheduling if controller is not None else None,
                      model=model, progress=progress, setpoints=setpoints, remove_trim=remove_trim)
    return result, data


def extended_model(result: Diagnosis, data: Dataset, split: float, remove_trim: bool,
                   controller: LtiController | GriddedController | None = None) -> ExtendedModel | None:
    """The extended model of the diagnosis' named cause (None when it names none), as `lpvflow diagnose`
    and the design's ``[diagnose]`` stage save it: the winner's model and map, the columns of the
    diagnosed record ``data`` (an added scheduling channel included), the validation part of ``split``
    with the reported fit, the removed means, and — closed loop — the loop it was scored in (its
    scheduling expressions, ``remove_trim``, the fingerprint of ``controller``, the one it ran)."""
    if result.winner is None:
        return None
    model = result.winner.fit.model
    p_names = model.p_names or data.p_names  # the model's scheduling includes an added channel
    removed = {k: data.offsets[k] for k in "uy" if k in data.offsets}
    return ExtendedModel(model, result.winner.model_map, data.u_names, data.y_names, p_names, result.cause,
                         data.split(split)[0].N, result.bfr_after, result.simulation, removed,
                         result.loop_scheduling, remove_trim and result.simulation == "closed loop",
                         controller_fingerprint(controller) if result.simulation == "closed loop" else None)


def recorded_setpoints(table: Mapping[str, np.ndarray], controller: LtiController | GriddedController,
                       n: int) -> np.ndarray:
    """The set-points of the outputs ``controller`` reads, (n, its inputs), from the record's
    ``<output>_setpoint`` columns (NaN where there is none; a law that takes none as references ignores
    them)."""
    return np.column_stack([np.asarray(table[f"{name}_setpoint"], float)[:n]
                            if f"{name}_setpoint" in table else np.full(n, np.nan)
                            for name in controller.inputs])


def simulate_extended(extended: ExtendedModel, table: Mapping[str, np.ndarray], data: Dataset,
                      controller: LtiController | GriddedController) -> np.ndarray:
    """The simulation of a closed-loop diagnosis' extended model on the record ``data`` read from
    ``table`` (recorded signals) in the loop of ``controller``, the one it was diagnosed under, as
    :func:`diagnose_model` scored it: the controller's trim off the inputs when it was removed, the
    recorded set-points (:meth:`~lpvflow.validate.extended_model.ExtendedModel.simulate`; an open-loop
    model is one DataError line)."""
    trim = recorded_trim(controller, data, table) if extended.remove_trim else None
    return extended.simulate(data, controller, recorded_setpoints(table, controller, data.N), trim)


def recorded_trim(controller: LtiController | GriddedController, data: Dataset, table: Mapping) -> np.ndarray:
    """The controller's trim over the record (N, inputs of ``data``; 0 on inputs it does not drive)."""
    missing = [name for name in controller.outputs if name not in data.u_names]
    if missing:
        raise DataError(f"remove_trim: the controller drives {missing}, which are not the model's inputs "
                        f"{data.u_names}")
    trim = np.zeros_like(data.u)
    trim[:, [data.u_names.index(name) for name in controller.outputs]] = controller.trim_along(table, data.N)
    return trim
