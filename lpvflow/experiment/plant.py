"""The plant an experiment drives: an FMI 2.0 Co-Simulation FMU stepped through fmpy's instance API.

:class:`Plant` is the small interface the experiment loop needs (names, operating values, one
communication step with new inputs, the current outputs). :func:`open_plant` provides it for an FMU;
tests may supply any object with the same attributes.
"""

from __future__ import annotations

import hashlib
import math
import shutil
from pathlib import Path
from typing import Protocol

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from lpvflow.errors import ModelError


class Plant(Protocol):
    """What the experiment loop uses from a plant."""

    model_name: str
    input_names: list[str]
    output_names: list[str]

    def start_value(self, name: str) -> float: ...

    def parameter_values(self) -> dict[str, float | int | bool]: ...

    def outputs(self) -> np.ndarray: ...

    def step(self, u: np.ndarray, t: float, Ts: float) -> None: ...

    def close(self) -> None: ...


def sha256_of(path: str | Path) -> str:
    """Hex SHA-256 of a file (recorded in the sidecar so the exact FMU can be identified)."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _bound(text: str | None, default: float) -> float:
    return default if text is None else float(text)


class FmuPlant:
    """An instantiated FMU in a fixed-step co-simulation; parameters are set before initialisation."""

    def __init__(self, path: str | Path, parameters: dict[str, float] | None = None) -> None:
        path = Path(path)
        if not path.is_file():
            raise ModelError(f"FMU {path} does not exist; build it with `make fmus` or give the right path")
        try:
            self._md = read_model_description(str(path), validate=False)
        except Exception as exc:  # fmpy raises several types for a non-FMU file
            raise ModelError(f"{path} is not a readable FMU ({type(exc).__name__}: {exc})") from None
        if self._md.coSimulation is None:
            raise ModelError(f"FMU {path} does not support FMI 2.0 Co-Simulation")
        self.model_name: str = self._md.modelName
        self._vars = {v.name: v for v in self._md.modelVariables}
        self.input_names = [v.name for v in self._md.modelVariables if v.causality == "input"]
        self.output_names = [v.name for v in self._md.modelVariables if v.causality == "output"]
        self._u_refs = [self._vars[n].valueReference for n in self.input_names]
        self._y_refs = [self._vars[n].valueReference for n in self.output_names]
        parameters = dict(parameters or {})
        for name, value in parameters.items():
            self._check_parameter(name, value)
        self._dir = extract(str(path))
        try:
            self._fmu = FMU2Slave(
                guid=self._md.guid, unzipDirectory=self._dir,
                modelIdentifier=self._md.coSimulation.modelIdentifier, instanceName=self.model_name,
            )
            self._fmu.instantiate()
            self._fmu.setupExperiment(startTime=0.0)
            for name, value in parameters.items():
                self._set(name, value)
            self._fmu.enterInitializationMode()
            self._fmu.exitInitializationMode()
        except FMICallException as exc:
            self._cleanup()
            raise ModelError(f"FMU {path.name} refused the initialisation or a parameter ({exc})") from None

    def _check_parameter(self, name: str, value: float) -> None:
        var = self._vars.get(name)
        if var is None or var.causality != "parameter":
            known = sorted(v.name for v in self._md.modelVariables if v.causality == "parameter")
            raise ModelError(f"FMU {self.model_name} has no parameter {name!r}; it has {', '.join(known)}")
        if var.type not in ("Real", "Integer", "Boolean"):
            raise ModelError(f"FMU parameter {name} has type {var.type}; set Real/Integer/Boolean only")
        if not math.isfinite(value):
            raise ModelError(f"FMU parameter {name}={value} must be finite")
        if var.type != "Real" and value != int(value):
            raise ModelError(f"FMU parameter {name}={value} must be an integer ({var.type})")
        lo, hi = _bound(var.min, -math.inf), _bound(var.max, math.inf)
        if not lo <= value <= hi:
            raise ModelError(f"FMU parameter {name}={value:g} is outside its range [{lo:g}, {hi:g}]")

    def _set(self, name: str, value: float) -> None:
        var = self._vars[name]
        ref = [var.valueReference]
        if var.type == "Real":
            self._fmu.setReal(ref, [float(value)])
        elif var.type == "Integer":
            self._fmu.setInteger(ref, [int(value)])
        else:
            self._fmu.setBoolean(ref, [bool(value)])

    def _get(self, name: str) -> float | int | bool:
        var = self._vars[name]
        ref = [var.valueReference]
        if var.type == "Real":
            return float(self._fmu.getReal(ref)[0])
        if var.type == "Integer":
            return int(self._fmu.getInteger(ref)[0])
        return bool(self._fmu.getBoolean(ref)[0])

    def start_value(self, name: str) -> float:
        """Start value of a variable from the model description (0 when none is declared)."""
        start = self._vars[name].start
        return 0.0 if start is None else float(start)

    def parameter_values(self) -> dict[str, float | int | bool]:
        """Current values of every Real/Integer/Boolean parameter, read back from the instance."""
        return {
            v.name: self._get(v.name) for v in self._md.modelVariables
            if v.causality == "parameter" and v.type in ("Real", "Integer", "Boolean")
        }

    def outputs(self) -> np.ndarray:
        return np.array(self._fmu.getReal(self._y_refs), dtype=float)

    def step(self, u: np.ndarray, t: float, Ts: float) -> None:
        """Apply u as the inputs and advance one communication step from t to t + Ts."""
        try:
            self._fmu.setReal(self._u_refs, [float(x) for x in u])
            self._fmu.doStep(currentCommunicationPoint=t, communicationStepSize=Ts)
        except FMICallException as exc:
            raise ModelError(f"FMU {self.model_name} failed at t={t:g} s ({exc})") from None

    def _cleanup(self) -> None:
        shutil.rmtree(self._dir, ignore_errors=True)

    def close(self) -> None:
        try:
            self._fmu.terminate()
            self._fmu.freeInstance()
        finally:
            self._cleanup()


def open_plant(path: str | Path, parameters: dict[str, float] | None = None) -> Plant:
    """Open an FMU for a fixed-step experiment with the given parameters (effect_* and physical)."""
    return FmuPlant(path, parameters)
