"""`lpvflow synth MODEL.json --config DESIGN.toml -o CONTROLLER.json`: polytopic H∞ synthesis.

DESIGN.toml is a design file (docs/design_file.md); synth reads its ``[synth]`` table, the same one
``lpvflow design`` uses, so a whole design file works too::

    [synth]
    solver = "CLARABEL"          # or "SCS"
    box = [[-1.0, 1.0]]          # optional; default: the scheduling range recorded in the model
    weights.S = [{ num = [0.02, 0.02], den = [1, -1] }]
    weights.K = { bandwidth = 50.0, dc_gain = 0.01, hf_gain = 1.0 }
    weights.B = { num = [0, 0.3], den = [1, -0.7] }
    weights.integrator_shift = 1e-3

Prints γ, the independent certificate checks and the solve time; exit 1 when a check fails.
"""

from __future__ import annotations

import argparse

from lpvflow.errors import ModelError
from lpvflow.models import LPVSS, load
from lpvflow.pipeline.cli_paths import declare
from lpvflow.pipeline.config import load_tables


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="identified LPVSS model (JSON)")
    p.add_argument("--config", required=True, help="design file with a [synth] table (TOML)")
    p.add_argument("-o", "--output", required=True, help="controller file to write (JSON)")
    p.set_defaults(func=run)
    declare(p, inputs=("model", "config"), outputs=("output",))


def run(args: argparse.Namespace) -> int:
    from lpvflow.pipeline.export import describe_signals
    from lpvflow.synth.certify import certify
    from lpvflow.synth.hinf import synthesize
    from lpvflow.synth.plant import generalized_plant

    settings = load_tables(args.config, need=("synth",))["synth"]
    model = load(args.model)
    if not isinstance(model, LPVSS):
        raise ModelError(f"{args.model} holds a {type(model).__name__}; synth needs an LPVSS")
    weights = settings["weights"]
    plant = generalized_plant(model, weights, settings["box"])
    result = synthesize(plant, solver=settings["solver"])
    cert = certify(result, model, weights)
    print(f"common Lyapunov matrix, polytope {plant.polytope.kind} with {plant.polytope.n_vertices} vertices")
    print(f"gamma = {result.gamma:.6g}  ({result.report.solver}, {result.report.status}, "
          f"{result.report.seconds:.2f} s)")
    for line in cert.lines():
        print(line)
    result.controller.info["certificate"] = cert.__dict__ | {"ok": cert.ok}
    result.controller.info["signals"] = describe_signals(model)  # ports named after the model's signals
    result.controller.save(args.output)
    print(f"controller of order {result.controller.order} written to {args.output}")
    return 0 if cert.ok else 1
