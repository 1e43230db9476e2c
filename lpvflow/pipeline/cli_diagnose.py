"""`lpvflow diagnose`: what the model's simulation gets wrong, the cause, and the measured gain."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from lpvflow.data import Dataset, read_columns, time_column
from lpvflow.errors import DataError
from lpvflow.experiment.controller import load_controller
from lpvflow.experiment.run import sidecar_path
from lpvflow.experiment.scheduling import parse_assignment
from lpvflow.models import atomic_write_json, report_header
from lpvflow.pipeline.cli_identify import add_data_arguments, parse_order
from lpvflow.pipeline.cli_paths import check_paths
from lpvflow.validate.diagnose import MIN_VALIDATION, diagnose
from lpvflow.validate.extensions import EXTENSIONS, Structure


def configure(p: argparse.ArgumentParser) -> None:
    add_data_arguments(p)
    p.add_argument("--na", default="2", help="output lags of the structure (default 2)")
    p.add_argument("--nb", default="2", help="input lags of the structure (default 2)")
    p.add_argument("--nk", default="1", help="input delay of the structure (default 1)")
    p.add_argument("--basis", default="affine", help="basis of the structure (default affine)")
    p.add_argument("--candidates", nargs="+", metavar="COL",
                   help="recorded channels that may be scheduling variables (default: all unused columns)")
    p.add_argument("--causes", nargs="+", choices=sorted(EXTENSIONS), help="test only these causes")
    p.add_argument("--split", type=float, default=0.5, help="estimation fraction (default 0.5)")
    p.add_argument("--controller", metavar="CONTROLLER.json",
                   help="the LTI controller the data were recorded under (lpvflow/lti-controller): every "
                        "model is then simulated in that loop")
    p.add_argument("--scheduling", nargs="+", metavar="NAME=EXPR",
                   help="with --controller: scheduling columns computed from the outputs, recomputed from "
                        "the simulated outputs in the loop (default: the sidecar's 'scheduling', if any)")
    p.add_argument("--json", dest="json_out", required=True, help="write the diagnosis here")
    p.add_argument("--model-out", help="where to save the extended model (default: next to --json)")
    p.add_argument("--plot", help="write the figure behind the verdict here (PNG)")
    p.set_defaults(func=run_diagnose)


def run_diagnose(args: argparse.Namespace) -> int:
    model_out = args.model_out or str(Path(args.json_out).with_suffix("")) + ".extended.json"
    check_paths([args.data, *([args.controller] if args.controller else [])],
                [args.json_out, model_out, *([args.plot] if args.plot else [])])
    table = read_columns(args.data)  # the file is read once: the dataset and the candidates come from it
    data = Dataset.from_columns(table, Path(args.data).name, args.u, args.y, args.p, args.time, args.Ts)
    used = {*args.u, *args.y, *args.p, args.time if args.time != "auto" else time_column(table)}
    names = args.candidates if args.candidates is not None else [c for c in table if c not in used]
    missing = [c for c in names if c not in table]
    if missing:
        raise DataError(f"candidate column(s) {missing} not found; available: {sorted(table)}")
    if data.N * (1 - args.split) < MIN_VALIDATION:
        raise DataError(f"{data.N} samples leave fewer than {MIN_VALIDATION} for validation at split "
                        f"{args.split}: record longer data or lower --split")
    structure = Structure(parse_order(args.na), parse_order(args.nb), parse_order(args.nk), args.basis)
    controller = load_controller(args.controller) if args.controller else None
    result = diagnose(data, structure, {c: table[c] for c in names}, split=args.split, causes=args.causes,
                      controller=controller, scheduling=_scheduling(args) if controller else None)
    report = report_header("diagnosis") | result.to_dict()
    report["extended_model"] = None
    if result.winner is not None:
        model = result.winner.fit.model
        (model.to_ss() if model.form == "shifted" else model).save(model_out)
        report["extended_model"] = model_out
    atomic_write_json(args.json_out, report)
    if args.plot:
        from lpvflow.validate.diagnose_plot import plot_diagnosis

        plot_diagnosis(result, data, args.plot, args.split)
    print(result.summary)
    return 0


def _scheduling(args: argparse.Namespace) -> dict[str, str]:
    """Scheduling expressions: ``--scheduling``, else the experiment sidecar's, else none."""
    if args.scheduling:
        return dict(parse_assignment(text) for text in args.scheduling)
    side = sidecar_path(args.data)
    return dict(json.loads(side.read_text()).get("scheduling", {})) if side.is_file() else {}
