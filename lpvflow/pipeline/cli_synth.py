"""`lpvflow synth MODEL.json --config DESIGN.toml -o CONTROLLER.json`: gain-scheduled H∞ synthesis.

DESIGN.toml is a design file (docs/design_file.md); synth reads its ``[synth]`` table, the same one
``lpvflow design`` uses, and writes the controller the design's synth stage writes
(:func:`lpvflow.pipeline.controller_design.design_controller`): with a whole design file, its ports carry
the ``[experiment] scheduling`` expressions, the units of the ``[design] plant`` and the operating points
and anti-windup of ``[verify.loop]``::

    [synth]
    solver = "CLARABEL"          # or "SCS"
    box = [[-1.0, 1.0]]          # optional; default: the scheduling range recorded in the model
    method = "rate-bounded"      # optional; default "common" (one Lyapunov matrix)
    rate_bound = 0.01            # rate-bounded: largest |p(k+1) − p(k)| per sample
    structure = "2dof"           # optional; default "1dof" (the controller reads r − y)
    weights.S = [{ num = [0.02, 0.02], den = [1, -1] }]
    weights.K = { bandwidth = 50.0, dc_gain = 0.01, hf_gain = 1.0 }
    weights.B = { num = [0, 0.3], den = [1, -0.7] }
    weights.integrator_shift = 1e-3

Prints γ, the independent certificate checks and the solve time; exit 1 when a check fails.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lpvflow.errors import DataError, ModelError
from lpvflow.models import LPVSS, load
from lpvflow.pipeline.cli_paths import declare
from lpvflow.pipeline.config import load_tables
from lpvflow.pipeline.controller_design import design_controller
from lpvflow.synth.methods import SYNTHESIS_METHODS


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="identified LPVSS model (JSON)")
    p.add_argument("--config", required=True, help="design file with a [synth] table (TOML)")
    p.add_argument("-o", "--output", required=True, help="controller file to write (JSON)")
    p.set_defaults(func=run)
    declare(p, inputs=("model", "config"), outputs=("output",))


def run(args: argparse.Namespace) -> int:
    tables = load_tables(args.config, need=("synth",))
    settings = tables["synth"]
    model = load(args.model)
    if not isinstance(model, LPVSS):
        raise ModelError(f"{args.model} holds a {type(model).__name__}; synth needs an LPVSS")
    plant = tables["design"]["plant"] if tables["design"] else None
    if plant is not None and not Path(plant).is_file():
        raise DataError(f"{Path(args.config).name}: [design] plant {plant!r} does not exist (relative paths "
                        "are relative to the working directory); the controller's units come from it")
    loop = tables["verify"]["loop"] if tables["verify"] else None
    scheduling = tables["experiment"]["scheduling"] if tables["experiment"] else None
    design = design_controller(model, settings, loop=loop, scheduling=scheduling, plant_fmu=plant)
    poly = design.plant.polytope
    method = SYNTHESIS_METHODS[settings["method"]]
    keys = "".join(f" ({key} = {settings[key]})" for key in method.keys if settings[key] is not None)
    print(f"{method.summary}{keys}, polytope {poly.kind} with {poly.n_vertices} vertices, "
          f"{settings['structure']}")
    print(f"gamma = {design.gamma:.6g}  ({method.gamma_is}, {design.seconds:.2f} s)")
    for line in design.certificate.lines():
        print(line)
    if design.controller.info.get("status") == "optimal_inaccurate":
        print("lpvflow synth: warning: the SDP solver returned the controller LMIs' solution as inaccurate "
              "(optimal_inaccurate); the certificate checks above decide whether the controller is usable",
              file=sys.stderr)
    design.controller.save(args.output)
    print(f"controller of order {design.controller.order} written to {args.output}")
    return 0 if design.certificate.ok else 1
