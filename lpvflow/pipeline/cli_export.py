"""``lpvflow export CONTROLLER.json --format fmu|json|mat -o PATH``: the controller for other tools."""

from __future__ import annotations

import argparse
from pathlib import Path

from lpvflow.pipeline.cli_paths import declare
from lpvflow.pipeline.export import FORMATS, export_controller, load_lpv_controller


def run(args: argparse.Namespace) -> int:
    controller = load_lpv_controller(args.controller)
    path = export_controller(controller, Path(args.output), args.format)
    inputs = "[r − y_op; y − y_op]" if controller.structure == "2dof" else "r − y"
    trim = ", trim feed-forward" if controller.trim is not None else ""
    print(
        f"wrote {path} ({args.format}: {controller.structure}, {controller.order} states, {controller.n_in} "
        f"inputs {inputs}, {controller.basis.n_p} scheduling, {controller.n_out} outputs, "
        f"{controller.polytope.n_vertices} vertices ({controller.polytope.kind}){trim})"
    )
    return 0


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "fmu: inputs <output>_ref and <output> per measured output and the scheduling signals by name "
        "(the same ports for a 1-DOF controller, which forms r − y, and a 2-DOF one, which reads "
        "[r − y_op; y − y_op]), "
        "outputs the actuated inputs by name (with their operating point and trim feed-forward u_eq(p)), "
        "units and descriptions, step = Ts, binary and sources inside, validated with fmpy; mat: Ak (n,n,N), "
        "Bk, Ck, Dk, psi_vertices, polytope, breakpoints, interpolation rule, basis, Ts, structure, trim_p, "
        "trim_u, names, units, scheduling expressions, operating points; json: the controller file, "
        "re-validated. Layouts: lpvflow/pipeline/export.py."
    )
    parser.add_argument("controller", help="lpvflow/lpv-controller JSON file")
    parser.add_argument("--format", required=True, choices=FORMATS)
    parser.add_argument("-o", "--output", required=True, metavar="PATH")
    parser.set_defaults(func=run)
    declare(parser, inputs=("controller",), outputs=("output",))
