"""An exported controller FMU (:func:`lpvflow.pipeline.export.export_fmu`) run as a controller."""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from fmpy import extract
from fmpy.fmi2 import FMU2Slave

from lpvflow.errors import ModelError
from lpvflow.fmu import check_fmu


class FmuController:
    """A controller FMU written by :func:`lpvflow.pipeline.export.export_fmu`, stepped through fmpy.

    Inputs are told apart by their description: ``scheduling …`` are p, ``measured …`` the outputs y and
    the others (``reference …``) the references r, in modelDescription order. The FMU reads r and y on
    separate ports whatever the structure of the controller inside (a 1-DOF one forms r − y itself), so
    the loop hands it w = [r; y] (``structure = "2dof"``) in plant units (a 2-DOF controller inside takes
    its operating point off both itself): per sample r(k), y(k) and p(k) are set, u(k) read, then
    ``fmi2DoStep(t_k, Ts)``. An FMU without measured ports (written before they existed) reads
    e = r − y on its reference ports (``structure = "1dof"``). The FMU's outputs include its operating
    point and trim feed-forward, so ``u_offset`` is zero and the loop adds no operating point of its own.
    The FMU does not record the scheduling box it was designed on (``design_box`` None).
    """

    design_box = None

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        description = check_fmu(path)  # a readable FMI 2.0 Co-Simulation FMU with a binary here
        if description.defaultExperiment is None or description.defaultExperiment.stepSize is None:
            raise ModelError(f"{path} is not a controller FMU written by `lpvflow export --format fmu`")
        variables = description.modelVariables
        inputs = [v for v in variables if v.causality == "input"]
        role = {v.valueReference: (v.description or "").split(" ")[0] for v in inputs}
        self._p_vr = [vr for vr, kind in role.items() if kind == "scheduling"]
        self._y_vr = [vr for vr, kind in role.items() if kind == "measured"]
        self._e_vr = [vr for vr, kind in role.items() if kind not in ("scheduling", "measured")]
        self._u_vr = [v.valueReference for v in variables if v.causality == "output"]
        self.structure = "2dof" if self._y_vr else "1dof"
        self.n_in, self.n_out = len(self._e_vr) + len(self._y_vr), len(self._u_vr)
        self.u_offset = np.zeros(self.n_out) if self._y_vr else None  # FMUs before named ports: no trim
        self.Ts = float(description.defaultExperiment.stepSize)
        self.n_p = len(self._p_vr)
        self._unzipdir = extract(str(path))
        identifier = description.coSimulation.modelIdentifier
        self._slave = FMU2Slave(
            guid=description.guid,
            unzipDirectory=self._unzipdir,
            modelIdentifier=identifier,
            instanceName=identifier,
        )
        self._slave.instantiate()
        self._time = 0.0

    def verification_law(self, measured: Sequence[str], actuated: Sequence[str]) -> FmuController:
        """The law verification steps (:class:`lpvflow.loop.protocol.VerificationLaw`): itself, its ports
        taking the loop's ``measured`` and ``actuated`` signals in modelDescription order."""
        return self

    def reset(self) -> None:
        if self._time > 0.0:
            self._slave.reset()
        self._slave.setupExperiment(startTime=0.0)
        self._slave.enterInitializationMode()
        self._slave.exitInitializationMode()
        self._time = 0.0

    def input_of(self, r: np.ndarray, y: np.ndarray) -> np.ndarray:
        """w = [r; y] for an FMU with measured ports, else e = r − y (class docstring)."""
        return np.concatenate([r, y]) if self.structure == "2dof" else r - y

    def step(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """u(k) for the input w(k) ([r; y], or e for an FMU without measured ports) at p(k); then one step."""
        self._slave.setReal(self._e_vr + self._y_vr + self._p_vr,
                            [*np.asarray(w, float), *np.asarray(p, float)])
        u = np.array(self._slave.getReal(self._u_vr))
        self._slave.doStep(self._time, self.Ts)
        self._time += self.Ts
        return u

    def feedforward(self, p: np.ndarray) -> np.ndarray:
        """Zero: the trim feed-forward is in the FMU's outputs (class docstring)."""
        return np.zeros(self.n_out)

    def close(self) -> None:
        if self._slave is not None:
            self._slave.terminate()
            self._slave.freeInstance()
            self._slave = None
            shutil.rmtree(self._unzipdir, ignore_errors=True)
