"""`lpvflow synth MODEL.json --config DESIGN.toml -o CONTROLLER.json`: polytopic H∞ synthesis.

DESIGN.toml::

    [polytope]
    box = [[-1.0, 1.0]]          # optional; default: the scheduling range recorded in the model
    [synth]
    solver = "clarabel"          # or "scs"
    gamma_max = 1.0              # optional: the spec ‖·‖∞ ≤ gamma_max must be met
    [weights]
    integrator_shift = 1e-3
    S = [{num = [0.02, 0.02], den = [1, -1]}]
    K = {bandwidth = 50.0, dc_gain = 0.01, hf_gain = 1.0}
    B = {num = [0, 0.3], den = [1, -0.7]}

Prints γ, the independent certificate checks and the solve time; exit 1 when a check fails.
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

from lpvflow.errors import ModelError
from lpvflow.models import LPVSS, load


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="identified LPVSS model (JSON)")
    p.add_argument("--config", required=True, help="design spec (TOML)")
    p.add_argument("-o", "--output", required=True, help="controller file to write (JSON)")
    p.set_defaults(func=run)


def _read_config(path: str) -> dict:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{path} is not valid TOML ({exc})") from None


def run(args: argparse.Namespace) -> int:
    from lpvflow.pipeline.export import describe_signals
    from lpvflow.synth.certify import certify
    from lpvflow.synth.hinf import synthesize
    from lpvflow.synth.plant import generalized_plant

    if Path(args.output).resolve() == Path(args.model).resolve():
        raise ModelError("the output file is the model file: choose another -o path")
    model = load(args.model)
    if not isinstance(model, LPVSS):
        raise ModelError(f"{args.model} holds a {type(model).__name__}; synth needs an LPVSS")
    config = _read_config(args.config)
    weights = config.get("weights", {})
    settings = config.get("synth", {})
    plant = generalized_plant(model, weights, config.get("polytope", {}).get("box"))
    result = synthesize(plant, solver=settings.get("solver", "CLARABEL"), gamma_max=settings.get("gamma_max"))
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
