"""`lpvflow synth MODEL.json --config DESIGN.toml -o CONTROLLER.json`: gain-scheduled H∞ synthesis.

DESIGN.toml is a design file (docs/design_file.md); synth reads its ``[synth]`` table, the same one
``lpvflow design`` uses, so a whole design file works too::

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
    from lpvflow.synth.design import synthesize_design

    settings = load_tables(args.config, need=("synth",))["synth"]
    model = load(args.model)
    if not isinstance(model, LPVSS):
        raise ModelError(f"{args.model} holds a {type(model).__name__}; synth needs an LPVSS")
    design = synthesize_design(model, settings)
    poly = design.plant.polytope
    method = {"common": "one common Lyapunov matrix",
              "rate-bounded": "rate-bounded parameter-dependent Lyapunov function "
                              f"(ν = {settings['rate_bound']})",
              "observer": "observer-based: frozen LQG designs at the breakpoints, interpolated"}
    print(f"{method[settings['method']]}, polytope {poly.kind} with {poly.n_vertices} vertices, "
          f"{settings['structure']}")
    bound = ("largest frozen closed-loop norm" if design.gamma_lower is None
             else f"lower bound {design.gamma_lower:.6g}")
    print(f"gamma = {design.gamma:.6g}  ({bound}, {design.seconds:.2f} s)")
    for line in design.certificate.lines():
        print(line)
    if design.controller.info.get("status") == "optimal_inaccurate":
        print("lpvflow synth: warning: the SDP solver returned the controller LMIs' solution as inaccurate "
              "(optimal_inaccurate); the certificate checks above decide whether the controller is usable",
              file=sys.stderr)
    cert = design.certificate
    design.controller.info["certificate"] = cert.__dict__ | {"ok": cert.ok}
    design.controller.info["signals"] = describe_signals(model)  # ports named after the model's signals
    design.controller.save(args.output)
    print(f"controller of order {design.controller.order} written to {args.output}")
    return 0 if cert.ok else 1
