"""The identified model simulated in the identification experiment's loop (model-in-the-loop validation)."""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.controller import GriddedController
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.experiment.scheduling import compile_expression
from lpvflow.experiment.synthesized import SynthesizedController
from lpvflow.models import LPVSS
from lpvflow.pipeline.context import StageContext


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
    model's input is the controller's output without its trim u_op (:func:`model_coordinates`).
    """
    cfg = ctx.config["experiment"]
    if not cfg["controller"]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            return model.simulate(data.u, data.p)
    K = load_experiment_controller(cfg["controller"])
    table = ctx.columns()
    start = len(table["time"]) - data.N
    zero = np.zeros(len(table["time"]))
    excitation = np.column_stack([table.get(f"{n}_excitation", zero)[start:] for n in K.outputs])
    check_wiring(K, data.u_names, data.y_names, "[validate] closed-loop fit")
    u_index = [data.u_names.index(n) for n in K.outputs]
    y_index = [data.y_names.index(n) for n in K.inputs]
    expressions = [scheduling_expression(name, cfg["scheduling"], data.y_names) for name in data.p_names]
    expressions = [compile_expression(expression, data.y_names) for expression in expressions]
    gridded = isinstance(K, GriddedController)
    with_trim = not ctx.config["identify"]["remove_trim"]
    if gridded:
        given = [j for j, n in enumerate(K.inputs) if f"{n}_setpoint" in table]
        setpoints = np.zeros((data.N, len(K.inputs)))
        for j in given:
            setpoints[:, j] = table[f"{K.inputs[j]}_setpoint"][start:]
        theta_of = K.scheduling_function()
    synthesized = isinstance(K, SynthesizedController)
    if synthesized:
        references = np.column_stack([table[f"{n}_setpoint"][start:] if f"{n}_setpoint" in table
                                      else np.full(data.N, y0)
                                      for n, y0 in zip(K.inputs, K.y_op, strict=True)])
        schedule = K.scheduling_function(data.y_names)
        K.reset()
    x, xc = np.zeros(model.nx), np.zeros(0 if synthesized else K.A.shape[-2])
    y_sim = np.zeros_like(data.y)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        C = model.matrices(data.p[0])[2]
        for k in range(data.N):
            y = C @ x  # C at p(k−1): one matrix evaluation per sample
            y_sim[k] = y
            p = np.array([scheduling_of(y) for scheduling_of in expressions])
            A, B, C, _ = model.matrices(p)
            u = np.zeros(model.nu)
            if gridded:
                Ak, Bk, Ck, Dk, y_bar, u_op = K.at(theta_of(np.concatenate([y[y_index], setpoints[k]])))
                y_bar[given] = setpoints[k, given]
                dy = y[y_index] - y_bar
                u[u_index] = with_trim * u_op + Ck @ xc + Dk @ dy + excitation[k]
                xc = Ak @ xc + Bk @ dy
            elif synthesized:
                p_K = schedule(y)
                u[u_index] = K.command(references[k], y[y_index], p_K) + excitation[k]
                if not with_trim:
                    u[u_index] -= K.trim(p_K)
            else:
                dy = y[y_index] - K.y_op
                u[u_index] = with_trim * K.u_op + K.C @ xc + K.D @ dy + excitation[k]
                xc = K.A @ xc + K.B @ dy
            x = A @ x + B @ u
            if not np.all(np.abs(x) < 1e12):
                raise DataError(f"the identified model's closed loop diverges at sample {k}: it does not "
                                "describe the plant under the identification controller")
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
