"""The plant an experiment drives: an FMI 2.0 Co-Simulation FMU opened with :func:`lpvflow.fmu.open_fmu`.

:class:`Plant` is the small interface the experiment loop needs (names, operating values, one
communication step with new inputs, the current outputs). :func:`open_plant` provides it for an
FMU, with every output (measured and ``diag_*``) so that scheduling expressions and diagnostics can
use them; tests may supply any object with the same attributes.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Protocol

import numpy as np
from fmpy import read_model_description

from lpvflow.fmu import EXPORT_TOOL, open_fmu


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


class FmuExperimentPlant:
    """An FMU instance initialised with ``parameters``; outputs are all FMU outputs, diag_* included."""

    def __init__(self, path: str | Path, parameters: Mapping[str, float]) -> None:
        probe = open_fmu(path)  # checks the file and that it is FMI 2.0 Co-Simulation
        probe.close()
        variables = read_model_description(str(path), validate=False).modelVariables
        self._types = {v.name: v.type for v in variables if v.causality == "parameter"}
        self._fmu = open_fmu(path, outputs=[v.name for v in variables if v.causality == "output"])
        self.model_name: str = self._fmu.name
        #: True for a controller FMU written by `lpvflow export` (given as the plant by mistake, mostly).
        self.exported_controller = self._fmu.generation_tool == EXPORT_TOOL
        self.input_names = list(self._fmu.input_names)
        self.output_names = list(self._fmu.output_names)
        self._set = dict(parameters)
        try:
            if self._set:
                self._fmu.set_parameters(self._set)
            self._y = self._fmu.reset()
        except BaseException:
            self._fmu.close()
            raise

    def start_value(self, name: str) -> float:
        """Declared start value of an input (its operating value in open loop)."""
        return self._fmu.start_value(name)

    def parameter_values(self) -> dict[str, float | int | bool]:
        """Every parameter as used: Real ones read back from the instance, the others as set or declared."""
        values: dict[str, float | int | bool] = {}
        for name, kind in self._types.items():
            if kind == "Real":
                values[name] = float(self._fmu.get([name])[0])
            elif name in self._set:
                values[name] = int(self._set[name]) if kind == "Integer" else bool(self._set[name])
            else:
                start = self._fmu.start_value(name)
                values[name] = int(start) if kind == "Integer" else bool(start)
        return values

    def outputs(self) -> np.ndarray:
        return self._y

    def step(self, u: np.ndarray, t: float, Ts: float) -> None:
        """Hold u for one communication step from t to t + Ts (the FMU keeps its own clock, equal to t)."""
        self._y = self._fmu.step(u, Ts)

    def close(self) -> None:
        self._fmu.close()


def open_plant(path: str | Path, parameters: Mapping[str, float] | None = None) -> Plant:
    """Open an FMU for a fixed-step experiment with the given parameters (effect_* and physical)."""
    return FmuExperimentPlant(path, dict(parameters or {}))
