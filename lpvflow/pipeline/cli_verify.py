"""``lpvflow verify CTRL --plant PLANT.fmu --scenario SCEN.toml --json OUT.json``: closed-loop check."""

from __future__ import annotations

import argparse
from pathlib import Path

from lpvflow.loop.loader import VERIFY_KINDS, load_controller_file
from lpvflow.models import atomic_write_json
from lpvflow.pipeline.cli_paths import declare
from lpvflow.pipeline.config import load_scenarios
from lpvflow.pipeline.verify import coverage_note, plot_runs, run_verification


def _summary(name: str, metrics: dict) -> str:
    parts = []
    for output, m in metrics["outputs"].items():
        settling = "not settled" if m["settling_time"] is None else f"settles in {m['settling_time']:.3g} s"
        overshoot = "" if m["overshoot_percent"] is None else f", overshoot {m['overshoot_percent']:.3g} %"
        parts.append(f"{output} {settling}{overshoot}")
    verdict = "stable" if metrics["stable"] else f"FAILED ({metrics['reason']})"
    missed = metrics.get("requirements_failed")
    if missed and metrics["stable"]:
        verdict += f", misses its requirements: {', '.join(missed)}"
    elif missed is not None and not missed:
        verdict += ", meets its requirements"
    note = coverage_note(metrics)
    return f"  {name} [{metrics['controller']}]: " + "; ".join([verdict, *parts, *([note] if note else [])])


def run(args: argparse.Namespace) -> int:
    scenario_file = load_scenarios(args.scenario)
    controller = load_controller_file(args.controller, VERIFY_KINDS, "verify")
    baseline = load_controller_file(args.baseline, VERIFY_KINDS, "verify") if args.baseline else None
    verification = run_verification(
        controller, args.plant, scenario_file.scenarios, scenario_file.loop, baseline
    )
    if args.figures:
        for i, result in enumerate(verification.results):
            plot_runs(result.runs, Path(args.figures) / f"scenario_{i + 1}.png", result.scenario.name,
                      plant=args.plant)
    atomic_write_json(args.json, verification.to_dict())
    for result in verification.results:
        for metrics in result.metrics:
            print(_summary(result.scenario.name, metrics))
    print(f"wrote {args.json}" + (f" and figures in {args.figures}" if args.figures else ""))
    return 0 if verification.passed else 1


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Run the controller (and an optional LTI baseline) in closed loop with the plant FMU "
        "on every [[verify.scenario]] of a design file (docs/design_file.md); exit 1 when "
        "the controller fails a scenario's stability verdict or misses its requirements."
    )
    parser.add_argument("controller", help="lpvflow/lpv-controller JSON (or an exported controller .fmu)")
    parser.add_argument("--plant", required=True, help="FMI 2.0 Co-Simulation FMU of the plant")
    parser.add_argument(
        "--scenario", required=True, metavar="DESIGN.toml",
        help="design file with [verify.loop] and [[verify.scenario]] tables"
    )
    parser.add_argument("--json", required=True, metavar="OUT.json", help="metrics and verdicts")
    parser.add_argument(
        "--baseline",
        metavar="CTRL.json",
        help="baseline controller: lpvflow/lti-controller or lpv-controller JSON, or .fmu",
    )
    parser.add_argument(
        "--figures", metavar="DIR", help="write one PNG per scenario (controller vs baseline)"
    )
    parser.set_defaults(func=run)
    declare(parser, inputs=("controller", "plant", "scenario", "baseline"), outputs=("json",),
            folders=("figures",))
