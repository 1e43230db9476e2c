"""`lpvflow diagnose`: what the model's simulation gets wrong, the cause, and the measured gain."""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from pathlib import Path

from lpvflow.data import Dataset, read_columns, time_column
from lpvflow.errors import DataError, ModelError
from lpvflow.experiment.run import sidecar_path
from lpvflow.experiment.scheduling import parse_assignment
from lpvflow.lpvio import LPVIO
from lpvflow.models import LPVSS, atomic_write_json, load, report_header
from lpvflow.pipeline.cli_identify import parse_order
from lpvflow.pipeline.cli_paths import check_paths
from lpvflow.pipeline.model_diagnosis import diagnose_model, extended_model, loop_controller
from lpvflow.validate.extensions import EXTENSIONS, Structure

#: Every verdict and what it means (``lpvflow diagnose --help``).
VERDICTS = {
    "none": "the model is adequate: its simulation error passes the residual tests (no part of it is "
            "explained by the input history over the settling time) and no extension gains significantly",
    "input_delay": "the dead time differs from nk (the data's nk is reported)",
    "model_order": "the orders na/nb are too low",
    "scheduling_dependence": "the coefficients need a richer basis in the given scheduling",
    "scheduling_variable": "a recorded channel is a missing scheduling variable",
    "input_nonlinearity": "a dead zone or saturation at an actuator (width/limit reported)",
    "backlash": "play in an actuator (width reported)",
    "sensor_saturation": "a clipping sensor",
    "friction": "Coulomb friction against the motion of an output (level in input units)",
    "offset": "a constant bias: an equation constant, or a sensor offset when the data determine it "
              "(when they do not, the summary says so: not_identifiable in the JSON)",
    "output_noise_bias": "white output noise biases least squares: refit the same structure by OE/IV "
                         "(noise level reported)",
    "colored_noise": "coloured output noise biases least squares (AR noise model and spectrum reported)",
    "ambiguous": "two causes gain significantly and no test separates them: both are reported",
    "unexplained": "the model is inadequate but no cause of the vocabulary explains it (or the best "
                   "extension leaves the adequacy test failing, or a named dead time does not hold after "
                   "small and large input moves alike); with --controller the error is tested "
                   "against the loop's excitation and set-points",
}


def configure(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = "verdicts:\n" + "\n".join(textwrap.fill(text, 100, initial_indent=f"  {name:22s} ",
                                                           subsequent_indent=" " * 25)
                                             for name, text in VERDICTS.items())
    p.add_argument("files", nargs="+", metavar="[MODEL] DATA",
                   help="the model `lpvflow identify` wrote (its structure and columns are used), then the "
                        "data (CSV, Parquet or .mat); without MODEL give --u/--y/--p and the structure")
    p.add_argument("--u", nargs="+", metavar="COL", help="input column(s) (default: the model's)")
    p.add_argument("--y", nargs="+", metavar="COL", help="output column(s) (default: the model's)")
    p.add_argument("--p", nargs="+", metavar="COL", help="scheduling column(s) (default: the model's)")
    p.add_argument("--time", default="auto", metavar="COL",
                   help="time column giving Ts (default: 'time' or 't' if present)")
    p.add_argument("--Ts", type=float, help="sampling time in seconds when there is no time column")
    structure = (("na", "2", "output lags"), ("nb", "2", "input lags"), ("nk", "1", "input delay"),
                 ("basis", "affine", "basis"))
    for name, default, text in structure:
        p.add_argument(f"--{name}", help=f"{text} of the structure without MODEL (default {default})")
    p.add_argument("--remove-offsets", action="store_true",
                   help="subtract the record's mean inputs and outputs (as `identify --remove-offsets`); "
                        "a MODEL identified that way is always diagnosed about the means it records")
    p.add_argument("--candidates", nargs="+", metavar="COL",
                   help="recorded channels that may be scheduling variables (default: all unused columns)")
    p.add_argument("--causes", nargs="+", choices=sorted(EXTENSIONS), help="test only these causes")
    p.add_argument("--split", type=float, default=0.5, help="estimation fraction (default 0.5)")
    p.add_argument("--controller", metavar="CONTROLLER.json",
                   help="the controller the data were recorded under (lpvflow/lti-controller or "
                        "lpvflow/gridded-controller): every model is then simulated in that loop, a gridded "
                        "controller with the record's <output>_setpoint columns as its references")
    p.add_argument("--remove-trim", action="store_true",
                   help="with --controller: the model's inputs are the recorded ones minus the controller's "
                        "trim (as a design's [identify] remove_trim); applied before --remove-offsets")
    p.add_argument("--scheduling", nargs="+", metavar="NAME=EXPR",
                   help="with --controller: scheduling columns computed from the outputs, recomputed from "
                        "the simulated outputs in the loop (default: the sidecar's 'scheduling', if any)")
    p.add_argument("--json", dest="json_out", required=True, help="write the diagnosis here")
    p.add_argument("--model-out", help="where to save the extended model (default: next to --json)")
    p.add_argument("--plot", help="write the figure behind the verdict here (PNG)")
    p.set_defaults(func=run_diagnose)


def _user_model(args: argparse.Namespace) -> tuple[str | None, str, LPVIO | None]:
    """(model path, data path, the model's input-output form) from the positional files."""
    if len(args.files) > 2:
        raise DataError(f"diagnose takes [MODEL] DATA, got {len(args.files)} files")
    if len(args.files) == 1:
        return None, args.files[0], None
    model_path, data_path = args.files
    given = [f"--{n}" for n in ("na", "nb", "nk", "basis") if getattr(args, n) is not None]
    if given:
        raise DataError(f"{', '.join(given)}: the structure comes from the model {model_path}; drop them")
    model = load(model_path)
    io = model.io if isinstance(model, LPVSS) else model
    if not isinstance(io, LPVIO):
        raise ModelError(f"{model_path} holds no input-output model: diagnose needs the model `lpvflow "
                         "identify` writes with an IO method (lpr-arx, oe, iv-oe, ...)")
    return model_path, data_path, io


def run_diagnose(args: argparse.Namespace) -> int:
    model_path, data_path, io = _user_model(args)
    model_out = args.model_out or str(Path(args.json_out).with_suffix("")) + ".extended.json"
    inputs = [path for path in (data_path, model_path, args.controller) if path]
    check_paths(inputs, [args.json_out, model_out, *([args.plot] if args.plot else [])])
    u, y, p = (args.u or (io.u_names if io else None), args.y or (io.y_names if io else None),
               args.p or (io.p_names if io else None))
    if not (u and y and p):
        raise DataError("give the columns --u, --y and --p (or a MODEL whose columns are used)")
    table = read_columns(data_path)  # the file is read once: the dataset and the candidates come from it
    data = Dataset.from_columns(table, Path(data_path).name, u, y, p, args.time, args.Ts)
    used = {*u, *y, *p, args.time if args.time != "auto" else time_column(table)}
    names = args.candidates if args.candidates is not None else [c for c in table if c not in used]
    structure = (Structure.of_model(io) if io is not None else
                 Structure(parse_order(args.na or "2"), parse_order(args.nb or "2"),
                           parse_order(args.nk or "1"), args.basis or "affine"))
    controller = loop_controller(args.controller, "diagnose --controller") if args.controller else None
    result, data = diagnose_model(
        table, data, structure, split=args.split, candidates=names, model=io, controller=controller,
        scheduling=_scheduling(args, data_path) if controller else None, remove_trim=args.remove_trim,
        remove_offsets=args.remove_offsets, causes=args.causes, progress=sys.stderr.isatty())
    report = report_header("diagnosis") | {"model": model_path} | result.to_dict()
    report["extended_model"] = None
    extended = extended_model(result, data, args.split, args.remove_trim, controller)
    if extended is not None:
        extended.save(model_out)
        report["extended_model"] = model_out
    atomic_write_json(args.json_out, report)
    if args.plot:
        from lpvflow.validate.diagnose_plot import plot_diagnosis

        plot_diagnosis(result, data, args.plot, args.split)
    print(result.summary)
    return 0


def _scheduling(args: argparse.Namespace, data_path: str) -> dict[str, str]:
    """Scheduling expressions: ``--scheduling``, else the experiment sidecar's, else none."""
    if args.scheduling:
        return dict(parse_assignment(text) for text in args.scheduling)
    side = sidecar_path(data_path)
    return dict(json.loads(side.read_text()).get("scheduling", {})) if side.is_file() else {}
