"""The Python API of ``lpvflow experiment``: open an FMU, run the experiment, write CSV + sidecar."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import control

from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.experiment.plant import open_plant, sha256_of
from lpvflow.experiment.record import check_output_path, write_record
from lpvflow.experiment.run import ExperimentRecord, run_experiment
from lpvflow.experiment.specs import SignalSpec
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.fmu import declared_step
from lpvflow.synth.controller import LPVController


def run_fmu_experiment(
    fmu: str | Path,
    Ts: float | None,
    duration: float,
    inputs: Mapping[str, str | SignalSpec] | None = None,
    controller: (str | Path | LtiController | GriddedController | SynthesizedController | LPVController
                 | control.StateSpace | None) = None,
    excitation: Mapping[str, str | SignalSpec] | None = None,
    parameters: Mapping[str, float] | None = None,
    scheduling_columns: Mapping[str, str] | None = None,
    seed: int = 0,
    output: str | Path | None = None,
    progress: bool | None = None,
    record_diagnostics: bool = False,
    setpoint: Mapping[str, str | SignalSpec] | None = None,
    quantization: Mapping[str, float] | None = None,
    noise: Mapping[str, float] | None = None,
    output_bounds: Mapping[str, tuple[float, float]] | None = None,
) -> ExperimentRecord:
    """Run :func:`~lpvflow.experiment.run.run_experiment` on the FMU at ``fmu`` with ``parameters``
    set before initialisation, and write ``output`` (+ ``<output>.json``) when given.

    ``controller`` is a ``lpvflow/lti-controller``, ``lpvflow/gridded-controller`` or
    ``lpvflow/lpv-controller`` JSON path, an :class:`LtiController`, a :class:`GriddedController`, an
    :class:`LPVController` with its ``info["signals"]`` (:mod:`lpvflow.experiment.synthesized`) or a
    discrete python-control ``StateSpace`` whose input/output labels are plant output/input names
    (operating points zero). ``Ts=None`` takes the controller's sampling time, else the step the FMU declares.
    """
    fmu = Path(fmu)
    protected = [fmu]
    source: dict[str, object] | None = None
    if isinstance(controller, str | Path):
        protected.append(Path(controller))
        controller_path, controller = controller, load_experiment_controller(controller)
        source = {"path": str(controller_path), "sha256": sha256_of(controller_path)}
    elif isinstance(controller, control.StateSpace):
        controller = LtiController.from_statespace(controller)
    elif controller is not None:
        controller = controller.experiment_controller()
    if Ts is None:
        Ts = controller.Ts if controller is not None else declared_step(fmu)
    if output is not None:
        check_output_path(output, protected)
    plant = open_plant(fmu, dict(parameters or {}))
    try:
        record = run_experiment(plant, Ts, duration, inputs, controller, excitation, scheduling_columns, seed,
                                progress, record_diagnostics, setpoint, quantization, noise,
                                output_bounds)
    finally:
        plant.close()
    effects = {k: v for k, v in record.metadata["parameters"].items() if k.startswith("effect_")}
    record.metadata = {
        "fmu": {"path": str(fmu), "sha256": sha256_of(fmu)},
        "parameters_set": dict(parameters or {}),
        "effects": effects,
    } | record.metadata
    if source is not None:
        record.metadata["controller_file"] = source
    if output is not None:
        write_record(record, output, protected)
    return record
