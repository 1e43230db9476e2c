"""The identified model simulated in the identification experiment's loop (model-in-the-loop validation)."""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.loop.engine import close_loop
from lpvflow.loop.model_plant import ModelPlant
from lpvflow.models import LPVSS
from lpvflow.pipeline.context import StageContext

#: A simulated output this large ends the model's loop: it diverges.
_DIVERGED = 1e12


def closed_loop_simulation(model: LPVSS, data: Dataset, ctx: StageContext) -> np.ndarray:
    """Simulate the model in the experiment's loop: the identification controller and its excitation.

    An unstable plant's model cannot be simulated open loop; the thesis validates the ADIP model by
    the closed loop T(Ĝ, K_id). The scheduling p(k) is recomputed from the simulated
    outputs with the experiment's scheduling expressions (quasi-LPV, as on the plant); y(k) uses C at
    p(k−1), which is exact for the observable-form realizations (C independent of p). A gridded
    (gain-scheduled) controller runs its own law on the simulated outputs and the recorded set-points
    (``<output>_setpoint``) and excitation (``<input>_excitation``); so does an LPV controller
    (:class:`~lpvflow.experiment.synthesized.SynthesizedController`: references from the recorded set-points,
    else its operating points, scheduling from the simulated outputs). With ``[identify] remove_trim`` the
    model's input is the controller's output without its trim u_op (:func:`model_coordinates`). With
    ``[identify] remove_offsets`` ``data`` and the returned outputs are deviations from the identify stage's
    operating point (u₀, y₀) = ``data.offsets`` and the model runs as the plant y₀ + y, fed u − u₀; the
    inputs the controller does not drive take their recorded values. The loop is
    :func:`lpvflow.loop.engine.close_loop` with the model as the plant
    (:class:`lpvflow.loop.model_plant.ModelPlant`) and the controller's protocol object
    (``loop_law()``).
    """
    cfg = ctx.config["experiment"]
    if not cfg["controller"]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            return model.simulate(data.u, data.p)
    experiment_controller = load_experiment_controller(cfg["controller"])
    check_wiring(experiment_controller, data.u_names, data.y_names, "[validate] closed-loop fit")
    K = experiment_controller.loop_law()
    table = ctx.columns()
    start = len(table["time"]) - data.N

    def recorded(column: str, default: float) -> np.ndarray:
        return table[column][start:] if column in table else np.full(data.N, default)

    excitation = np.column_stack([recorded(f"{name}_excitation", 0.0) for name in K.outputs])
    # the recorded set-points as K took them in the experiment (an LTI law's are in the excitation)
    references = K.references_of(np.column_stack([recorded(f"{name}_setpoint", np.nan) for name in K.inputs]))
    # the operating point the model works around (what remove_offsets took off the data, data.offsets; empty
    # without it): the loop runs in the plant's signals, data and fit in the deviations from it
    offsets = data.offsets or {}
    u0, y0 = (np.asarray(offsets.get(s, np.zeros(n)), dtype=float) for s, n in (("u", model.nu),
                                                                               ("y", len(data.y_names))))
    plant = ModelPlant(model, [scheduling_expression(name, cfg["scheduling"], data.y_names)
                               for name in data.p_names], offsets=offsets)
    u_index = [data.u_names.index(name) for name in K.outputs]
    u_recorded = data.u + u0  # the inputs K does not drive, as recorded, in the plant's signals
    with_trim = not ctx.config["identify"]["remove_trim"]
    y_sim = np.zeros_like(data.y)

    def actuate(k: int, u_c: np.ndarray, p: np.ndarray) -> np.ndarray:
        u = u_recorded[k].copy()
        u[u_index] = u_c + excitation[k] - (0.0 if with_trim else K.trim(p))
        return u

    def stop(k: int, y: np.ndarray) -> str | None:
        return None if np.all(np.abs(y) < _DIVERGED) else f"diverges at sample {k}"

    def record(k: int, y: np.ndarray, p: np.ndarray, u_c: np.ndarray, u: np.ndarray) -> None:
        y_sim[k] = y - y0

    failure = close_loop(K, plant, data.N, references, actuate=actuate, stop=stop, record=record)
    if failure:
        raise DataError(f"the identified model's closed loop {failure}: it does not describe the plant "
                        "under the identification controller")
    return y_sim


def check_wiring(K, u_names: list[str], y_names: list[str], where: str) -> None:
    """One DataError line when the experiment controller ``K`` reads an output or drives an input that
    is not a model signal (``where`` names the check)."""
    unknown = [n for n in K.inputs if n not in y_names] + [n for n in K.outputs if n not in u_names]
    if unknown:
        raise DataError(f"{where}: the experiment controller reads {list(K.inputs)} and drives "
                        f"{list(K.outputs)}; {unknown[0]!r} is not a model signal {u_names + y_names}")


def scheduling_expression(name: str, definitions: Mapping[str, str], outputs: list[str]) -> str:
    """How the model-in-the-loop simulation computes the scheduling column ``name`` from the simulated
    outputs: its ``[experiment] scheduling`` expression, or the output itself when p is a model output;
    anything else is one DataError line."""
    if name in definitions:
        return definitions[name]
    if name in outputs:
        return name
    raise DataError(f"[identify] p column {name!r} is neither an [experiment] scheduling column nor a model "
                    f"output {outputs}: the closed-loop fit recomputes p from the simulated outputs; define "
                    f"it in [experiment] scheduling (e.g. {name} = \"…\") or add it to [identify] y")
