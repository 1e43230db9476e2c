"""Open an FMI 2.0 Co-Simulation FMU and step it from Python with little per-step overhead.

`open_fmu(path)` checks the file and returns an `FmuPlant`: name lists (`input_names`,
`output_names`, `parameter_names`), `set_parameters`, `reset`, `step(inputs, dt)` and `get(names)`.
Value references and ctypes buffers are built once, and each step makes three direct calls into
the FMU (fmi2SetReal, fmi2DoStep, fmi2GetReal). Every failure is reported as one line:
`DataError` for bad user input (path, names, step size, parameter values the FMU rejects) and
`ModelError` for a file that is not a usable FMI 2.0 Co-Simulation FMU.

By convention of the lpvflow plants (fmu_plants/*/README.md) outputs whose names start with
``diag_`` are noise-free diagnostics (states, derivatives, energy); `output_names` defaults to the
other, measured outputs.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.model_description import ModelDescription

from lpvflow.errors import DataError, ModelError

#: Prefix of the diagnostic (not measured) outputs of the lpvflow plants.
DIAGNOSTIC_PREFIX = "diag_"

#: The ``generationTool`` of the controller FMUs lpvflow exports (pipeline/controller_fmu template).
EXPORT_TOOL = "lpvflow export"

#: The only platform the bundled plants are built for (fmu_plants/build.py).
PLATFORM = "linux64"


class FmuPlant:
    """One instance of a Co-Simulation FMU, stepped with a fixed or varying communication step."""

    def __init__(self, path: Path, outputs: Sequence[str] | None = None) -> None:
        self.path = path
        self._slave = None
        description = check_fmu(path)
        self.name = description.coSimulation.modelIdentifier
        self.generation_tool = description.generationTool
        self._variables = {v.name: v for v in description.modelVariables}
        self.input_names = tuple(v.name for v in description.modelVariables if v.causality == "input")
        all_outputs = [v.name for v in description.modelVariables if v.causality == "output"]
        self.parameter_names = tuple(v.name for v in description.modelVariables if v.causality == "parameter")
        if outputs is None:
            outputs = [name for name in all_outputs if not name.startswith(DIAGNOSTIC_PREFIX)]
        for name in outputs:
            if name not in all_outputs:
                raise DataError(f"{self.name}: unknown output {name!r}; "
                                f"known outputs: {', '.join(all_outputs)}")
        self.output_names = tuple(outputs)
        self._parameters: dict[str, float] = {}
        self._messages: list[str] = []
        self._unzipdir = extract(str(path))
        self._callbacks = fmi2CallbackFunctions()
        self._logger = fmi2CallbackLoggerTYPE(self._log)
        self._callbacks.logger = self._logger
        work_dir = os.getcwd()
        try:
            slave = FMU2Slave(guid=description.guid, unzipDirectory=self._unzipdir,
                              modelIdentifier=self.name, instanceName=self.name)
            slave.instantiate(callbacks=self._callbacks)
        except BaseException as exc:  # the extracted files must not outlive a failed start
            os.chdir(work_dir)  # fmpy leaves the process in the binary's folder when loading fails
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            if isinstance(exc, Exception):
                raise ModelError(f"{path}: the FMU's binary cannot be loaded ({exc}); rebuild it with "
                                 "`make fmus`") from exc
            raise
        self._slave = slave
        self._component = self._slave.component
        self._set_real = self._slave._functions["fmi2SetReal"]
        self._do_step = self._slave._functions["fmi2DoStep"]
        self._get_real = self._slave._functions["fmi2GetReal"]
        self._input_vr, self._input_values, self._inputs = self._buffers(self.input_names)
        self._output_vr, self._output_values, self._outputs = self._buffers(self.output_names)
        self._n_inputs, self._n_outputs = len(self.input_names), len(self.output_names)
        self.time = 0.0
        try:
            self.reset()
        except BaseException:
            self.close()
            raise

    def _buffers(self, names: Sequence[str]) -> tuple[ctypes.Array, ctypes.Array, np.ndarray]:
        refs = (ctypes.c_uint * len(names))(*(self._variables[n].valueReference for n in names))
        values = (ctypes.c_double * len(names))()
        return refs, values, np.ctypeslib.as_array(values) if names else np.zeros(0)

    def _log(self, env: object, instance: bytes, status: int, category: bytes, message: bytes) -> None:
        self._messages.append(message.decode("utf-8", "replace"))

    def _fail(self, what: str) -> DataError:
        detail = self._messages[-1] if self._messages else "the FMU reported an error"
        return DataError(f"{self.name}: {what}: {detail}")

    def set_parameters(self, values: Mapping[str, float]) -> None:
        """Set parameters (effects, physical values, x0_*) and restart at t = 0 with them."""
        for name in values:
            if name not in self.parameter_names:
                raise DataError(f"{self.name}: unknown parameter {name!r}; " + (
                    f"known: {', '.join(self.parameter_names)}" if self.parameter_names else
                    f"{self.path.name} declares no parameters" + (
                        " (it is a controller written by `lpvflow export`, not a plant; give the plant's "
                        "FMU)" if self.generation_tool == EXPORT_TOOL else "")))
        previous = dict(self._parameters)
        self._parameters.update(values)
        try:
            self.reset()
        except DataError:
            self._parameters = previous
            self.reset()
            raise

    def reset(self, inputs: Mapping[str, float] | Sequence[float] | np.ndarray | None = None) -> np.ndarray:
        """Re-initialise at t = 0 with the parameters given so far; returns the outputs at t = 0.

        `inputs` (default: the start values) are the inputs during initialisation; the outputs
        at t = 0 use them and a dead time replays them for its first steps.
        """
        values = self._input_vector(inputs) if inputs is not None else None
        self._messages.clear()
        try:
            self._slave.reset()
            self._slave.setupExperiment(startTime=0.0)
            self._slave.enterInitializationMode()
            for name, value in self._parameters.items():
                variable = self._variables[name]
                if variable.type == "Integer":
                    if float(value) != int(value):
                        raise DataError(f"{self.name}: parameter {name} must be an integer, got {value}")
                    self._slave.setInteger([variable.valueReference], [int(value)])
                else:
                    self._slave.setReal([variable.valueReference], [float(value)])
            if values is not None:
                self._slave.setReal(list(self._input_vr), list(values))
            self._slave.exitInitializationMode()
        except FMICallException as exc:
            raise self._fail("initialisation failed") from exc
        self.time = 0.0
        return self.get(self.output_names)

    def step(self, inputs: Mapping[str, float] | Sequence[float] | np.ndarray, dt: float) -> np.ndarray:
        """Hold `inputs` (by name or in `input_names` order) for `dt` seconds; returns the next outputs."""
        if not dt > 0.0:
            raise DataError(f"{self.name}: communication step dt = {dt} must be > 0")
        if type(inputs) in (list, tuple, np.ndarray) and len(inputs) == self._n_inputs:
            try:  # fast path: no intermediate array
                self._inputs[:] = inputs
            except (TypeError, ValueError):
                self._inputs[:] = self._input_vector(inputs)
        else:
            self._inputs[:] = self._input_vector(inputs)
        component = self._component
        if (self._set_real(component, self._input_vr, self._n_inputs, self._input_values)
                or self._do_step(component, self.time, dt, 1)
                or self._get_real(component, self._output_vr, self._n_outputs, self._output_values)):
            raise self._fail(f"step at t = {self.time:g} s failed")
        self.time += dt
        return self._outputs.copy()

    def _input_vector(self, inputs: Mapping[str, float] | Sequence[float] | np.ndarray) -> np.ndarray:
        if isinstance(inputs, Mapping):
            if set(inputs) != set(self.input_names):
                raise DataError(f"{self.name}: inputs must be exactly {', '.join(self.input_names)}; "
                                f"got {', '.join(inputs)}")
            inputs = [inputs[n] for n in self.input_names]
        try:
            vector = np.asarray(inputs, dtype=float).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise DataError(f"{self.name}: inputs must be numbers for {', '.join(self.input_names)}") from exc
        if vector.shape != (len(self.input_names),):
            raise DataError(f"{self.name}: expected {len(self.input_names)} input values "
                            f"({', '.join(self.input_names)}), got shape {np.shape(inputs)}")
        return vector

    def get(self, names: Iterable[str]) -> np.ndarray:
        """Current values of any Real variables (e.g. the diag_* outputs or parameters)."""
        names = list(names)
        for name in names:
            if name not in self._variables or self._variables[name].type != "Real":
                raise DataError(f"{self.name}: unknown Real variable {name!r}")
        return np.array(self._slave.getReal([self._variables[n].valueReference for n in names]))

    def start_value(self, name: str) -> float:
        """Start value declared in modelDescription.xml (parameters and inputs)."""
        if name not in self._variables or self._variables[name].start is None:
            raise DataError(f"{self.name}: {name!r} is not a variable with a start value")
        return float(self._variables[name].start)

    def close(self) -> None:
        """Free the instance and delete the extracted files."""
        if self._slave is not None:
            self._slave.freeInstance()
            self._slave = None
            shutil.rmtree(self._unzipdir, ignore_errors=True)

    def __enter__(self) -> FmuPlant:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def check_fmu(path: str | Path) -> ModelDescription:
    """The model description of a usable FMU: FMI 2.0 Co-Simulation with a binary for this platform
    (``binaries/linux64/<modelIdentifier>.so``); anything else raises one-line ModelError."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"FMU file not found: {path}; build the plants with `make fmus` or check the path")
    try:
        description = read_model_description(str(path))
    except Exception as exc:  # fmpy raises bare Exceptions for broken archives and XML
        raise ModelError(f"{path} is not a readable FMU ({exc}); rebuild it with `make fmus`") from None
    if description.fmiVersion != "2.0" or description.coSimulation is None:
        raise ModelError(f"{path} is not an FMI 2.0 Co-Simulation FMU; give one built by fmu_plants/build.py")
    binary = f"binaries/{PLATFORM}/{description.coSimulation.modelIdentifier}.so"
    with zipfile.ZipFile(path) as archive:
        if binary not in archive.namelist():
            raise ModelError(f"{path} has no {PLATFORM} binary ({binary}); build the FMU for {PLATFORM} "
                             "(`make fmus` for the bundled plants)")
    return description


def declared_step(path: str | Path) -> float:
    """The communication step the FMU declares (``DefaultExperiment stepSize``)."""
    experiment = check_fmu(path).defaultExperiment
    if experiment is None or not experiment.stepSize:
        raise DataError(f"{path} declares no step size (DefaultExperiment stepSize); give Ts (--Ts) "
                        "in seconds")
    return float(experiment.stepSize)


def open_fmu(path: str | Path, outputs: Sequence[str] | None = None) -> FmuPlant:
    """Open the FMU at `path`, initialised at t = 0 with its default parameters.

    `outputs` selects what `step` returns (default: every output not starting with ``diag_``).
    """
    return FmuPlant(Path(path), outputs)
