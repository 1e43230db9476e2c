"""``[identify] refine = "closed-loop-oe"``: the identify stage's least-squares model refined on its own
estimation records simulated in the loops they were recorded in
(:func:`lpvflow.identify.closed_loop_oe.refine_closed_loop_oe`).

Each estimation record (every round's with ``rounds = "all"``) runs the model in the loop of the
controller it was recorded under (its ``[experiment] controller``: the identification controller in
round 0, the synthesized LPV controller of the round before after it, as an exact gridded law
:meth:`~lpvflow.experiment.synthesized.SynthesizedController.as_gridded`), with the record's set-points
(``<output>_setpoint``) and excitation (``<input>_excitation``; not recovered from the record with
:meth:`Loop.from_record`: both ADIP controllers are unstable, and run on the record their states amplify
rounding to 10²⁸ within it), the
``[experiment] scheduling`` expressions recomputed from the simulated outputs, the model's inputs without
the controller's trim (``remove_trim``) and the ``increments`` outputs summed; the simulated outputs are
compared with the measured ones of the estimation part, from rest.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.identify.closed_loop_oe import LoopRecord, Refinement, refine_closed_loop_oe
from lpvflow.lpvio import LPVIO
from lpvflow.pipeline.context import StageContext
from lpvflow.pipeline.coordinates import EARLIER_RECORDS, read_data
from lpvflow.validate.closed_loop import Loop


def check_refine(config: dict) -> None:
    """One DataError line when ``[identify] refine`` cannot run: it needs the least-squares LPV-ARX
    (``method = "lpr-arx"``), an ``[experiment] controller`` (the loop of the records), one scale per
    output in ``refine_scales`` and no ``remove_offsets``."""
    identify = config["identify"]
    if identify["refine"] == "none":
        return
    if identify["method"] != "lpr-arx":
        raise DataError(f'[identify] refine = "closed-loop-oe" starts from the least-squares LPV-ARX; method '
                        f'{identify["method"]!r} is not it: use method = "lpr-arx" or remove refine')
    if not config["experiment"]["controller"]:
        raise DataError('[identify] refine = "closed-loop-oe" simulates the model in the loop its records '
                        "were made in; the experiment has no [experiment] controller: remove refine")
    missing = [name for name in identify["y"] if name not in identify["refine_scales"]]
    if missing:
        raise DataError(f"[identify] refine_scales lacks {missing}: give one scale per output "
                        f"(e.g. refine_scales = {{ {missing[0]} = 0.035 }}, in the output's units)")
    if identify["remove_offsets"]:
        raise DataError('[identify] refine = "closed-loop-oe" runs the loop in the plant\'s signals; remove '
                        "remove_offsets")


def refined_model(ctx: StageContext, model: LPVIO, equation_records: list[Dataset]) -> Refinement:
    """The refinement of ``model`` (module docstring) from the least-squares problem's
    ``equation_records``."""
    cfg = ctx.config["identify"]
    earlier = cfg[EARLIER_RECORDS] if EARLIER_RECORDS in cfg else []
    views = [StageContext(Path(record["data"]).parent,
                          {"identify": cfg, "experiment": {"controller": record["controller"]}})
             for record in earlier] + [ctx]
    scheduling = ctx.config["experiment"]["scheduling"]
    loops = [_loop_record(view, scheduling) for view in views]
    scales = np.array([cfg["refine_scales"][name] for name in cfg["y"]], dtype=float)
    with tqdm(desc="closed-loop output-error refinement (loop simulations)", unit="run",
              leave=False) as bar:
        def progress(runs: int) -> None:
            bar.update(runs - bar.n)

        return refine_closed_loop_oe(model, equation_records, loops, scales, cfg["refine_iterations"],
                                     tuple(cfg["increments"]), progress)


def _loop_record(view: StageContext, scheduling: dict) -> LoopRecord:
    """The estimation part of ``view``'s record in the model's inputs and scheduling with the measured
    outputs, and its loop."""
    model_signals, measured = read_data(view, model_signals=True)[0], read_data(view)[0]
    data = Dataset(model_signals.u, measured.y, model_signals.p, measured.Ts, model_signals.u_names,
                   measured.y_names, model_signals.p_names)
    controller = load_experiment_controller(view.config["experiment"]["controller"])
    table = view.columns()

    def recorded(column: str, default: float) -> np.ndarray:
        return table[column][:data.N] if column in table else np.full(data.N, default)

    setpoints = np.column_stack([recorded(f"{name}_setpoint", np.nan) for name in controller.inputs])
    if hasattr(controller, "gridded_setpoints"):  # a synthesized law runs compiled as its exact gridded law
        controller, setpoints = controller.as_gridded(), controller.gridded_setpoints(setpoints)
    law = controller.loop_law()
    excitation = np.column_stack([recorded(f"{name}_excitation", 0.0) for name in controller.outputs])
    command = law.setpoint_command(setpoints)  # an LTI law's set-points act as a command
    loop = Loop(controller, excitation if command is None else excitation + command, scheduling,
                law.references_of(setpoints), view.config["identify"]["remove_trim"],
                np.zeros(data.y.shape[1]))
    return LoopRecord(data, loop)
