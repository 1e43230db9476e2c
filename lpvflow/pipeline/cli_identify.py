"""`lpvflow identify` and `lpvflow simulate`: LPV-ARX from data to a realized model file, and its fit."""

from __future__ import annotations

import argparse
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset, read_columns
from lpvflow.errors import DataError, ModelError
from lpvflow.identify.fit_check import UselessFitWarning, useless_fit_message
from lpvflow.identify.methods import IDENTIFICATION_METHODS, estimate, method_of
from lpvflow.lfr import LPVLFR
from lpvflow.lpvio import LPVIO
from lpvflow.models import LPVSS, atomic_write_json, load, report_header
from lpvflow.pipeline.cli_paths import declare
from lpvflow.validate.metrics import fit_report


def parse_order(text: str) -> int | np.ndarray:
    """``"2"`` → 2; ``"2,2;1,1"`` → [[2, 2], [1, 1]] (rows separated by ';', as in MATLAB)."""
    try:
        if ";" not in text and "," not in text:
            return int(text)
        return np.array([[int(v) for v in row.split(",")] for row in text.split(";")])
    except ValueError:
        raise DataError(f"bad order {text!r}: use a whole number or a matrix like 2,2;1,1") from None


def add_data_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", help="CSV (header row), Parquet or .mat file")
    p.add_argument("--u", nargs="+", required=True, metavar="COL", help="input column(s)")
    p.add_argument("--y", nargs="+", required=True, metavar="COL", help="output column(s)")
    p.add_argument("--p", nargs="+", required=True, metavar="COL", help="scheduling column(s)")
    p.add_argument("--time", default="auto", metavar="COL",
                   help="time column giving Ts (default: 'time' or 't' if present)")
    p.add_argument("--Ts", type=float, help="sampling time in seconds when there is no time column")


def configure_identify(p: argparse.ArgumentParser) -> None:
    add_data_arguments(p)
    p.add_argument("--na", default="2", help="output lags: N or a matrix N,N;N,N (default 2)")
    p.add_argument("--nb", default="2", help="number of input lags: N or a matrix (default 2)")
    p.add_argument("--nk", default="1", help="input delay in samples: N or a matrix (default 1)")
    p.add_argument("--basis", default="affine", help="affine | poly:D | poly:D:nocross | spline:K1,K2,..")
    p.add_argument("--method", default=next(iter(IDENTIFICATION_METHODS)),
                   choices=list(IDENTIFICATION_METHODS),
                   help="; ".join(f"{name}: {m.summary}" for name, m in IDENTIFICATION_METHODS.items())
                   + " (default: the first)")
    p.add_argument("--ridge", type=float, default=0.0, help="Tikhonov weight for lpr/static-arx (default 0)")
    p.add_argument("--nc", type=int, help="noise polynomial order for armax (default na)")
    p.add_argument("--excitation", metavar="COL", help="external excitation column for two-step")
    p.add_argument("--past", type=int, help="past window for pbsid (default chosen from the order)")
    p.add_argument("--order", type=int,
                   help="state order: reduce the realization to it (IO methods) or the model order "
                        "(pbsid, cva, kcca-lfr)")
    p.add_argument("--remove-offsets", action="store_true",
                   help="subtract the record's mean inputs and outputs: the model works in deviations and "
                        "records the means, which simulate, validate and diagnose add back")
    p.add_argument("--controller", metavar="CONTROLLER.json",
                   help="closed-loop data recorded under this lpvflow/lti-controller: the fit is checked by "
                        "simulating the model in that loop (scheduling expressions from the data's sidecar)")
    p.add_argument("-o", "--output", required=True, help="model file to write (JSON)")
    p.set_defaults(func=run_identify)
    declare(p, inputs=("data", "controller"), outputs=("output",))


def configure_simulate(s: argparse.ArgumentParser) -> None:
    s.add_argument("model", help="model file written by `lpvflow identify`, or the extended model `lpvflow "
                                 "diagnose` saves (with its input/output map; its validation part is "
                                 "reported next to the diagnosed BFR)")
    add_data_arguments(s)
    s.add_argument("--controller", metavar="CONTROLLER.json",
                   help="an extended model of a closed-loop diagnosis runs in the loop it was scored in: "
                        "give the controller file diagnose took (the record's <output>_setpoint columns are "
                        "its references); required for such a model, refused for any other")
    s.add_argument("--json", dest="json_out", help="write the fit report here")
    s.add_argument("--plot", help="write a PNG of measured vs simulated outputs here")
    s.set_defaults(func=run_simulate)
    declare(s, inputs=("model", "data", "controller"), outputs=("json_out", "plot"))


def _estimate(args: argparse.Namespace, data: Dataset) -> LPVIO | LPVSS | LPVLFR:
    """The model of --method (:func:`lpvflow.identify.methods.estimate`, which the design's identify stage
    calls too) with the external excitation column when the method needs one."""
    excitation = None
    if method_of(args.method).needs_excitation:
        if not args.excitation:
            raise DataError(f"--method {args.method} needs --excitation COL (the external excitation signal)")
        excitation = read_columns(args.data, [args.excitation]).get(args.excitation)
        if excitation is None:
            raise DataError(f"excitation column {args.excitation!r} not found in {args.data}")
    with warnings.catch_warnings():  # the fit is checked by run_identify for every method
        warnings.simplefilter("ignore", UselessFitWarning)
        return estimate(data, args.method, parse_order(args.na), parse_order(args.nb), parse_order(args.nk),
                        args.basis, ridge=args.ridge, nc=args.nc, excitation=excitation, past=args.past,
                        order=args.order)


def run_identify(args: argparse.Namespace) -> int:
    data = Dataset.read(args.data, args.u, args.y, args.p, time=args.time, Ts=args.Ts)
    if args.remove_offsets:
        data = data.remove_offsets()
    io_method = method_of(args.method).result == "io"
    if args.controller and not io_method:
        raise DataError(f"--controller checks an input-output model in the loop; --method {args.method} "
                        "gives a state-space model: use an IO method (lpr-arx, iv-oe, ...)")
    if not io_method:
        model = _estimate(args, data)
        description = f"state order {getattr(model, 'nx', '?')}"
    else:
        io = replace(_estimate(args, data), operating_point=data.offsets)  # --remove-offsets' means
        if io.form == "static":
            if args.order is not None:
                raise DataError("--order needs a realizable model; use --method lpr-arx")
            io.save(args.output)
            print(f"static-dependence LPV-ARX written to {args.output} (no static state-space realization "
                  "exists for this form; use --method lpr-arx for one)")
            return _fit_status(args.method, _estimation_fit(io, data))
        model = io.to_ss()
        if args.order is not None:
            from lpvflow.identify.reduce import reduce

            model = reduce(model, order=args.order)
        description = f"basis {io.basis.kind} ({io.basis.n_psi} functions), state order {model.nx}"
    fit = _loop_fit(io, data, args) if args.controller else _estimation_fit(model, data)
    model.save(args.output)
    print(f"{args.method}: {data.y.shape[1]}x{data.u.shape[1]}, {description}; "
          "estimation-data simulation BFR "
          + ", ".join(f"{n} {v:.2f} %" for n, v in zip(fit["outputs"], fit["bfr"], strict=True))
          + f"; written to {args.output}")
    return _fit_status(args.method, fit)


def _estimation_fit(model: LPVSS | LPVIO | LPVLFR, data: Dataset) -> dict:
    """BFR, VAF and MSE of the model's simulation on the estimation data."""
    with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        return fit_report(data.y, model.simulate(data.u, data.p), data.y_names)


def _loop_fit(io: LPVIO, data: Dataset, args: argparse.Namespace) -> dict:
    """BFR, VAF and MSE of the model simulated in the identification loop of ``args.controller``
    (:func:`~lpvflow.validate.closed_loop.simulate_in_loop`): an unstable plant's model cannot be
    judged by an open-loop simulation."""
    import json

    from lpvflow.experiment.controller import load_controller
    from lpvflow.experiment.run import sidecar_path
    from lpvflow.validate.closed_loop import Loop, simulate_in_loop

    side = sidecar_path(args.data)
    scheduling = json.loads(side.read_text()).get("scheduling", {}) if side.is_file() else {}
    loop = Loop.from_record(data, load_controller(args.controller),
                            {k: v for k, v in scheduling.items() if k in data.p_names})
    with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        return fit_report(data.y, simulate_in_loop(io, data, loop), data.y_names)


def _fit_status(method: str, fit: dict) -> int:
    """1 with a one-line warning on stderr when the fit is useless (a finding), else 0."""
    message = useless_fit_message(fit, method)
    if message:
        print(f"warning: {message}", file=sys.stderr)
        return 1
    return 0


def simulate_any(model: LPVSS | LPVIO | LPVLFR, data: Dataset) -> np.ndarray:
    """The model's simulated output on ``data``; a model that records the operating point (u₀, y₀) it was
    identified about (``LPVIO.operating_point``, also an LPVSS's ``io``) gives y₀ + G(u − u₀)."""
    if model.nu != data.u.shape[1] or model.ny != data.y.shape[1] or model.basis.n_p != data.p.shape[1]:
        raise DataError(
            f"the model is {model.ny}x{model.nu} with {model.basis.n_p} scheduling signal(s); the data "
            f"columns give {data.y.shape[1]}x{data.u.shape[1]} with {data.p.shape[1]}"
        )
    io = model if isinstance(model, LPVIO) else getattr(model, "io", None)
    point = io.operating_point if io is not None else {}
    if not point:
        return model.simulate(data.u, data.p)
    return np.asarray(point["y"]) + model.simulate(data.u - np.asarray(point["u"]), data.p)


def run_simulate(args: argparse.Namespace) -> int:
    from lpvflow.validate.extended_model import ExtendedModel

    model = load(args.model)
    if not isinstance(model, LPVSS | LPVIO | LPVLFR | ExtendedModel):
        raise ModelError(f"{args.model} holds no LPV model (it is a {type(model).__name__})")
    if args.controller and not isinstance(model, ExtendedModel):
        raise DataError("--controller runs the extended model of a closed-loop diagnosis in its loop; "
                        f"{args.model} is an identified model, simulated open loop: drop --controller")
    if isinstance(model, ExtendedModel):
        y_sim, data = _simulate_extended(model, args)
    else:
        data = Dataset.read(args.data, args.u, args.y, args.p, time=args.time, Ts=args.Ts)
        y_sim = simulate_any(model, data)
    report = fit_report(data.y, y_sim, data.y_names)
    for name, b, v, m in zip(report["outputs"], report["bfr"], report["vaf"], report["mse"], strict=True):
        print(f"{name}: BFR {b:.2f} %  VAF {v:.2f} %  MSE {m:.4g}")
    if isinstance(model, ExtendedModel):
        report["validation"] = _diagnosed_validation(model, data, y_sim)
    if args.json_out:
        document = {**report_header("simulation"), "model": args.model, "data": args.data, **report}
        atomic_write_json(args.json_out, document)
    if args.plot:
        plot_fit(args.plot, data, y_sim)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


def _simulate_extended(model, args: argparse.Namespace) -> tuple[np.ndarray, Dataset]:
    """The extended model's simulation of the record ``args.data`` and the record: open loop, or in the
    loop of ``args.controller`` (:func:`~lpvflow.pipeline.model_diagnosis.simulate_extended`)."""
    from lpvflow.pipeline.model_diagnosis import loop_controller, simulate_extended

    controller = loop_controller(args.controller, "simulate --controller") if args.controller else None
    model.check_controller(controller)
    if controller is None:
        data = Dataset.read(args.data, args.u, args.y, args.p, time=args.time, Ts=args.Ts)
        return model.simulate(data), data
    table = read_columns(args.data)  # the set-point columns (and the trim's) come from it too
    data = Dataset.from_columns(table, Path(args.data).name, args.u, args.y, args.p, args.time, args.Ts)
    return simulate_extended(model, table, data, controller), data


def _diagnosed_validation(model, data: Dataset, y_sim: np.ndarray) -> dict:
    """The fit of a diagnosis' extended model on the validation part it was diagnosed on (samples from
    ``model.validation_start`` of the same whole-record simulation), printed next to the diagnosis'
    validation BFR."""
    start = model.validation_start
    if not 0 < start < data.N - 1:
        raise DataError(f"the extended model was diagnosed with validation from sample {start}; the data "
                        f"have {data.N} samples: simulate it on the diagnosed record")
    part = fit_report(data.y[start:], y_sim[start:], data.y_names)
    for name, b, diagnosed in zip(part["outputs"], part["bfr"], model.validation_bfr, strict=True):
        print(f"{name}: validation part (samples {start}..{data.N - 1}) BFR {b:.2f} %, diagnosed "
              f"{diagnosed:.2f} % ({model.simulation})")
    return {"start": start, **part, "diagnosed_bfr": model.validation_bfr}


def plot_fit(path: str | Path, data: Dataset, y_sim: np.ndarray, units: dict[str, str] | None = None) -> None:
    """Measured and simulated outputs over time, one panel per output (PNG); ``units`` (output name →
    unit) label the axes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(data.N) * data.Ts
    fig, axes = plt.subplots(data.y.shape[1], 1, figsize=(9, 2.6 * data.y.shape[1]), squeeze=False)
    for ax, name, y, ys in zip(axes[:, 0], data.y_names, data.y.T, y_sim.T, strict=True):
        ax.plot(t, y, lw=1, label="measured")
        ax.plot(t, ys, lw=1, ls="--", label="simulated")
        ax.set_ylabel(f"{name} [{units[name]}]" if units and units.get(name) else name)
        ax.legend(loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

