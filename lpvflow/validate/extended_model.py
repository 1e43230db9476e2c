"""The extended model a diagnosis saves: the fitted input-output model and the input or output map
it needs to run (file format ``lpvflow/extended-model``, version 1).

Maps (:mod:`lpvflow.validate.extensions` gives the equations), applied around the LPV-IO model's
simulation from a zero past:

    dead_zone / saturation / backlash   u_j ← f(u_j) on the named input before the model
    offset_inputs                       u ← [u, 1 (, t/N)]: the constant (and trend) inputs, N the
                                        diagnosed record's length
    actuator_delay                      u_j ← u_j(k − d_j) on every input and p_c ← p_c(k − d_c) on
                                        the scheduling columns computed from a delayed input
    sensor_offset                       y_meas = y + o on the named output (no name: o (ny,) on
                                        every output)
    sensor_clip                         y_meas = clip(y_i, lo, hi) on the named output
    friction                            the last input sign v(k), v the motion of output i taken
                                        from the model's own simulated output
                                        (:func:`~lpvflow.validate.extensions_maps.friction_simulation`)

The diagnosis scores its open-loop extensions with :meth:`ModelMap.simulate` itself, so the saved
file reproduces the reported validation fit: simulate the whole record, score from sample
``validation_start``.

A closed-loop diagnosis (``simulation = "closed loop"``) scored every model in the identification loop
of the record's controller (:func:`~lpvflow.validate.closed_loop.simulate_in_loop`); its file records
that loop (``loop``: the scheduling expressions recomputed from the simulated outputs, and whether the
model's inputs are without the controller's trim, and the controller's fingerprint
:func:`controller_fingerprint`) and runs there again, given the same controller:
:func:`simulate_mapped_in_loop` is the one simulation both the diagnosis and the file use, the map
becoming the loop's drive (:meth:`ModelMap.loop_drive`):

    dead_zone / saturation   the map on the plant input the loop produces
    offset_inputs            the constant (and trend) inputs as exogenous inputs
    friction (position)      the sign of the simulated motion
                             (:func:`~lpvflow.validate.closed_loop.velocity_sign`)
    sensor_offset            the controller reads y + o, the output returned is y + o
                             (every output; ``simulate_in_loop``'s ``sensor_offset``)
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.lpvio import LPVIO
from lpvflow.models import atomic_write_json, check_format
from lpvflow.validate.closed_loop import InputMap, Loop, simulate_in_loop
from lpvflow.validate.signal_maps import dead_zone, delayed, friction_simulation, play, saturation

FORMAT = "extended-model"
VERSION = 1
INPUT_MAPS = ("dead_zone", "saturation", "backlash")
KINDS = (*INPUT_MAPS, "offset_inputs", "actuator_delay", "sensor_offset", "sensor_clip", "friction")


@dataclass(frozen=True)
class ModelMap:
    """An input or output map around an LPV-IO model (module docstring); ``channel`` is the input
    (input maps) or output (output maps) it acts on, ``values`` its level(s)."""

    kind: str
    channel: str | None = None
    values: dict = field(default_factory=dict)

    def inputs(self, u: np.ndarray, u_names: list[str], start: int = 0) -> np.ndarray:
        """The model's inputs for the record's inputs ``u`` (its samples start, start+1, …): the named
        input mapped (input maps), the offset inputs appended, or ``u`` itself (output maps)."""
        u = np.array(u, dtype=float)
        if self.kind in INPUT_MAPS:

            nonlin = {"dead_zone": dead_zone, "saturation": saturation, "backlash": play}[self.kind]
            j = u_names.index(self.channel)
            u[:, j] = nonlin(u[:, j], self.values["level"])
            return u
        if self.kind == "offset_inputs":
            k = np.arange(start, start + len(u))
            columns = {"const": np.ones(len(k)), "trend": k / self.values["record_length"]}
            return np.hstack([u, np.column_stack([columns[name] for name in self.values["inputs"]])])
        if self.kind == "actuator_delay":
            return delayed(u, self.values["input_delays"])
        return u

    def scheduling(self, p: np.ndarray) -> np.ndarray:
        """The model's scheduling for the record's ``p`` (whole record): the columns computed from a
        delayed input delayed with it (``actuator_delay``), else ``p`` itself."""
        if self.kind == "actuator_delay":
            return delayed(p, self.values["scheduling_delays"])
        return np.asarray(p, dtype=float)

    def simulate(self, model: LPVIO, u: np.ndarray, p: np.ndarray, u_names: list[str],
                 y_names: list[str]) -> np.ndarray:
        """The mapped model's simulation of the record (u, p) from a zero past."""
        if self.kind == "friction":

            return friction_simulation(model, u, p, y_names.index(self.channel),
                                       self.values["motion"] == "velocity")
        y = model.simulate(self.inputs(u, u_names), self.scheduling(p))
        if self.kind == "sensor_offset":
            return y + np.asarray(self.values["offset"], float)
        if self.kind == "sensor_clip":
            i, lo, hi = y_names.index(self.channel), self.values["lower"], self.values["upper"]
            y[:, i] = np.clip(y[:, i], -np.inf if lo is None else lo, np.inf if hi is None else hi)
        return y

    def simulate_validation(self, model: LPVIO, est: Dataset, val: Dataset) -> np.ndarray:
        """The validation part of the whole record's simulation (as the diagnosis scores it)."""
        u, p = np.vstack([est.u, val.u]), np.vstack([est.p, val.p])
        return self.simulate(model, u, p, est.u_names, est.y_names)[est.N :]

    def loop_drive(self, u: np.ndarray, u_names: list[str], y_names: list[str]) -> dict[str, Any]:
        """The map as the drive of :func:`~lpvflow.validate.closed_loop.simulate_in_loop` on a record
        with inputs ``u`` (whole record, names ``u_names``) and outputs ``y_names`` (module docstring);
        a map the loop does not apply (one with memory, a sensor map other than an offset on every
        output, a velocity output's friction) is one ModelError line."""
        if self.kind in ("dead_zone", "saturation"):
            return {"input_map": InputMap(self.kind, u_names.index(self.channel), self.values["level"])}
        if self.kind == "offset_inputs":
            return {"exogenous": self.inputs(u, u_names)[:, len(u_names) :]}
        if self.kind == "friction" and self.values["motion"] == "position":
            return {"sign_of": y_names.index(self.channel)}
        if self.kind == "sensor_offset" and self.channel is None:
            return {"sensor_offset": np.broadcast_to(np.asarray(self.values["offset"], float), len(y_names))}
        raise ModelError(f"the {self.kind} map is not simulated in the identification loop (it applies "
                         "memoryless input maps, exogenous inputs and the sign of a position's motion)")

    def to_dict(self) -> dict:
        return {"kind": self.kind, "channel": self.channel, "values": self.values}

    @classmethod
    def from_dict(cls, d: dict) -> ModelMap:
        if d.get("kind") not in KINDS:
            raise ModelError(f"unknown model map {d.get('kind')!r}; this lpvflow knows {', '.join(KINDS)}")
        return cls(d["kind"], d.get("channel"), dict(d.get("values", {})))


def simulate_mapped_in_loop(model: LPVIO, model_map: ModelMap | None, data: Dataset,
                            loop: Loop) -> np.ndarray:
    """Outputs (N, ny) of ``model`` with ``model_map`` (None: the model alone) in ``loop`` over the whole
    record ``data`` from a zero past: :func:`~lpvflow.validate.closed_loop.simulate_in_loop` with the
    map's :meth:`ModelMap.loop_drive`. The diagnosis scores its closed-loop extensions with it
    (:class:`~lpvflow.validate.extension_core.LoopSimulation`) and :meth:`ExtendedModel.simulate` runs
    the saved file with it."""
    drive = {} if model_map is None else model_map.loop_drive(data.u, data.u_names, data.y_names)
    return simulate_in_loop(model, data, loop, **drive)


def controller_fingerprint(controller: LtiController | GriddedController) -> str:
    """The SHA-256 of the controller's file document (``to_dict()``, keys sorted, floats as Python writes
    them), first 16 hex digits: the same law read back from its file has the same fingerprint, another
    law (one gain changed) another."""
    text = json.dumps(controller.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class ExtendedModel:
    """A diagnosis' extended model: ``model`` with its ``map`` (None: the model alone), the columns
    it runs on, the diagnosed split and the validation BFR the diagnosis reported."""

    model: LPVIO
    map: ModelMap | None
    u_names: list[str]
    y_names: list[str]
    p_names: list[str]
    cause: str
    validation_start: int
    validation_bfr: list[float]
    simulation: str = "open loop"
    #: Means the diagnosis removed (``--remove-offsets``), {"u": [...], "y": [...]}: the model runs on
    #: u − ū and its output is shifted back by ȳ, so it takes the recorded signals.
    offsets: dict[str, list[float]] = field(default_factory=dict)
    #: Closed loop: scheduling column → expression in the output names, recomputed in the loop.
    loop_scheduling: dict[str, str] = field(default_factory=dict)
    #: Closed loop: the model's inputs are the recorded ones minus the controller's trim u_op(θ(k)).
    remove_trim: bool = False
    #: Closed loop: :func:`controller_fingerprint` of the controller the diagnosis ran (None in files
    #: written before it was recorded: any controller is taken).
    controller: str | None = None

    @property
    def closed_loop(self) -> bool:
        return self.simulation == "closed loop"

    def check_controller(self, controller: LtiController | GriddedController | None) -> None:
        """Refuse (one line) a closed-loop model without its controller, a controller given for an
        open-loop one, or a controller other than the one the diagnosis ran (its fingerprint differs)."""
        given = controller is not None
        if self.closed_loop and not given:
            raise DataError(f"the extended model ({self.cause}) was diagnosed in the loop of the controller "
                            "the data were recorded under: pass --controller CONTROLLER.json, the one "
                            "diagnose took")
        if given and not self.closed_loop:
            raise DataError(f"the extended model ({self.cause}) was diagnosed open loop and runs open loop: "
                            "drop --controller")
        if given and self.controller is not None and controller_fingerprint(controller) != self.controller:
            raise DataError(f"the extended model ({self.cause}) was diagnosed in the loop of controller "
                            f"{self.controller} (fingerprint), the one given is "
                            f"{controller_fingerprint(controller)}: pass the controller file diagnose took")

    def check_columns(self, data: Dataset) -> None:
        """Refuse (one line) data whose inputs, outputs or scheduling are not the model's columns."""
        for what, flag, wanted, given in (("input", "u", self.u_names, data.u_names),
                                          ("output", "y", self.y_names, data.y_names),
                                          ("scheduling", "p", self.p_names, data.p_names)):
            if list(given) != list(wanted):
                raise DataError(f"the extended model ({self.cause}) runs on the {what} column(s) {wanted}, "
                                f"the data give {list(given)}: pass --{flag} {' '.join(wanted)}")

    def simulate(self, data: Dataset, controller: LtiController | GriddedController | None = None,
                 setpoints: np.ndarray | None = None, trim: np.ndarray | None = None) -> np.ndarray:
        """Simulation of the whole record from a zero past, with the map (and the removed means).

        Closed loop (:attr:`closed_loop`): in the loop of ``controller`` (the one the data were recorded
        and diagnosed under) with its recorded ``setpoints`` (N, outputs it reads; NaN: none), on the
        record in the diagnosed signals — the inputs less ``trim`` (the controller's trim over the record,
        N × inputs, when :attr:`remove_trim`), then less the removed means — through
        :func:`simulate_mapped_in_loop`, as the diagnosis scored it."""
        self.check_columns(data)
        self.check_controller(controller)
        u = data.u - np.asarray(self.offsets.get("u", 0.0))
        y0 = np.asarray(self.offsets.get("y", 0.0))
        if self.closed_loop:
            model_data = replace(data, u=u - (0.0 if trim is None else trim), y=data.y - y0,
                                 offsets=dict(self.offsets))
            loop = Loop.from_record(model_data, controller, self.loop_scheduling, setpoints, self.remove_trim)
            y = simulate_mapped_in_loop(self.model, self.map, model_data, loop)
        elif self.map is None:
            y = self.model.simulate(u, data.p)
        else:
            y = self.map.simulate(self.model, u, data.p, data.u_names, data.y_names)
        return y + y0

    def to_dict(self) -> dict[str, Any]:
        return {"format": f"lpvflow/{FORMAT}", "version": VERSION, "cause": self.cause,
                "model": self.model.to_dict(), "map": self.map.to_dict() if self.map else None,
                "u_names": self.u_names, "y_names": self.y_names, "p_names": self.p_names,
                "simulation": self.simulation, "offsets": self.offsets,
                "loop": ({"scheduling": self.loop_scheduling, "remove_trim": self.remove_trim,
                          "controller": self.controller} if self.closed_loop else None),
                "validation": {"start": self.validation_start, "bfr": self.validation_bfr}}

    @classmethod
    def from_dict(cls, d: dict) -> ExtendedModel:
        check_format(d, FORMAT, VERSION)
        try:
            loop = d.get("loop") or {}
            if d["simulation"] == "closed loop" and not loop:
                raise ModelError("this closed-loop extended model does not record the loop it was diagnosed "
                                 "in (an older lpvflow wrote it): run diagnose again")
            return cls(LPVIO.from_dict(d["model"]), ModelMap.from_dict(d["map"]) if d["map"] else None,
                       list(d["u_names"]), list(d["y_names"]), list(d["p_names"]), d["cause"],
                       int(d["validation"]["start"]), [float(b) for b in d["validation"]["bfr"]],
                       d["simulation"], {k: [float(v) for v in d["offsets"][k]] for k in d["offsets"]},
                       {str(k): str(v) for k, v in loop.get("scheduling", {}).items()},
                       bool(loop.get("remove_trim", False)), loop.get("controller"))
        except (KeyError, TypeError) as exc:
            raise ModelError(f"lpvflow/{FORMAT} file lacks or mangles the field {exc.args[0]!r}") from None

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_json(path, self.to_dict())

