"""The signals a design's model is identified in: estimation/validation parts of the experiment record,
offsets, the experiment controller's trim removed, outputs as increments."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.experiment.loader import load_experiment_controller
from lpvflow.pipeline.context import StageContext

#: The ``[identify]`` entry the design adds for ``rounds = "all"`` (not a design-file key): the records of
#: the earlier identification-for-control rounds, :func:`lpvflow.pipeline.design.earlier_record`.
EARLIER_RECORDS = "earlier_records"


def read_data(ctx: StageContext, model_signals: bool = False) -> tuple[Dataset, Dataset]:
    """Estimation and validation parts, as measured or (``model_signals``) in the signals the model is
    identified in (:func:`model_coordinates`); with ``remove_offsets`` both have the estimation part's mean
    inputs and outputs subtracted (the model then works in deviations from that operating point)."""
    cfg = ctx.config["identify"]
    data = ctx.dataset(cfg["u"], cfg["y"], cfg["p"])
    est, val = (model_coordinates(ctx, data) if model_signals else data).split(cfg["split"])
    if not cfg["remove_offsets"]:
        return est, val
    return without_offsets(est, est), without_offsets(val, est)


def estimation_records(ctx: StageContext, est: Dataset) -> list[Dataset]:
    """The estimation data of the identify stage in the model's signals: this record's estimation part
    ``est`` (:func:`read_data` with ``model_signals``, read by the caller) after, with ``[identify]
    rounds = "all"``, the estimation part of every earlier round's record (:data:`EARLIER_RECORDS`), each
    in the signals of :func:`model_coordinates` with the trim of the controller it was recorded under.
    The records stay apart (one least-squares problem whose lags never cross from one record into the
    next, :func:`lpvflow.identify.arx.identify_arx`)."""
    cfg = ctx.config["identify"]
    earlier = cfg[EARLIER_RECORDS] if EARLIER_RECORDS in cfg else []
    records = []
    for record in earlier:
        view = StageContext(Path(record["data"]).parent,
                            {"identify": cfg, "experiment": {"controller": record["controller"]}})
        records.append(read_data(view, model_signals=True)[0])
    return [*records, est]


def two_step_excitation(ctx: StageContext, n: int) -> np.ndarray:
    """The external excitation the two-step estimator needs, the first ``n`` samples of the column
    ``[identify] excitation`` of data.csv (default: the experiment's ``<input>_excitation`` column of the
    first input); a missing column is one DataError line."""
    cfg = ctx.config["identify"]
    column = cfg["excitation"] or f"{cfg['u'][0]}_excitation"
    table = ctx.columns()
    if column not in table:
        raise DataError(f"[identify] method = {cfg['method']!r} needs the excitation column {column!r}, "
                        "which the data lack; set [identify] excitation to a column of data.csv")
    return table[column][:n]


def model_coordinates(ctx: StageContext, data: Dataset) -> Dataset:
    """The whole record ``data`` in the signals the model is identified in.

    * ``[identify] remove_trim``: each input the experiment controller drives minus that controller's
      trim u_op(θ(k)) (:func:`controller_trim`). The model then describes the plant with the trim closed
      around it. On the ADIP the trim V_eq(φ1) = −d1 sin φ1 / (motor gain) cancels the arm's gravity torque
      d1 sin φ1; left in, that torque has to be carried by LPV coefficients of the absolute arm angle, whose
      frozen value is the secant d1 sin φ1/φ1 instead of the linearization's d1 cos φ1 (ν-gap 0.19 at ±75°
      between the two exact frozen models).
    * ``[identify] increments``: the listed outputs replaced by their increments y(k) − y(k−1) (0 at k = 0);
      :func:`identify` integrates the model back (:func:`lpvflow.identify.realize.integrate_outputs`).
      Coefficients scheduled on a measured, fast-moving p(k) multiply the increments (small, like the
      other signals) instead of an absolute angle of up to 1.3 rad, so an error in their timing stays small.
    """
    cfg = ctx.config["identify"]
    changes: dict[str, np.ndarray] = {}
    if cfg["remove_trim"]:
        changes["u"] = data.u - controller_trim(ctx, data)
    if cfg["increments"]:
        unknown = [name for name in cfg["increments"] if name not in data.y_names]
        if unknown:
            raise DataError(f"[identify] increments {unknown} are not model outputs {data.y_names}")
        y = data.y.copy()
        rows = [data.y_names.index(name) for name in cfg["increments"]]
        y[:, rows] = np.diff(data.y[:, rows], axis=0, prepend=data.y[:1, rows])
        changes["y"] = y
    return replace(data, **changes)


def controller_trim(ctx: StageContext, data: Dataset) -> np.ndarray:
    """The experiment controller's trim at every sample of ``data`` (the whole record), (N, nu) over the
    model inputs (0 for inputs it does not drive), as the controller ran: its ``trim_along`` of the
    recorded columns (an LTI controller's constant u_op; a gridded controller's u_op(θ(k)),
    :meth:`~lpvflow.experiment.controller.GriddedController.trim_along`; an LPV controller's
    u_op + u_eq(p(k)), :meth:`~lpvflow.experiment.synthesized.SynthesizedController.trim_along`)."""
    path = ctx.config["experiment"]["controller"]
    if not path:
        raise DataError("[identify] remove_trim needs an [experiment] controller (its trim is removed)")
    K = load_experiment_controller(path)
    missing = [name for name in K.outputs if name not in data.u_names]
    if missing:
        raise DataError(f"[identify] remove_trim: the experiment controller drives {missing}, which are not "
                        f"model inputs {data.u_names}")
    trim = np.zeros_like(data.u)
    trim[:, [data.u_names.index(name) for name in K.outputs]] = K.trim_along(ctx.columns(), data.N)
    return trim


def without_offsets(data: Dataset, est: Dataset) -> Dataset:
    """``data`` minus the mean inputs and outputs of ``est`` (the operating point), recorded in
    ``offsets``."""
    u0, y0 = est.u.mean(axis=0), est.y.mean(axis=0)
    return replace(data, u=data.u - u0, y=data.y - y0, offsets={"u": u0.tolist(), "y": y0.tolist()})


def about_operating_point(data: Dataset, point: dict[str, list[float]]) -> Dataset:
    """``data`` minus a model's recorded operating point (``LPVIO.operating_point``: the input and output
    means it was identified about), recorded in ``offsets``."""
    u0, y0 = np.asarray(point["u"]), np.asarray(point["y"])
    if u0.size != data.u.shape[1] or y0.size != data.y.shape[1]:
        raise DataError(f"the model's operating point has {u0.size} input(s) and {y0.size} output(s); the "
                        f"data have {data.u.shape[1]} and {data.y.shape[1]}: give the model's columns")
    return replace(data, u=data.u - u0, y=data.y - y0, offsets={"u": u0.tolist(), "y": y0.tolist()})
