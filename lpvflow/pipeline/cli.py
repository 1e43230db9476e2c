"""The `lpvflow` command line: one subcommand per stage.

``COMMANDS`` names each subcommand, its help line and the stage module function that adds its arguments
and sets ``func(args) -> int`` as the parser default; only the invoked subcommand's module is imported.
Exit status: 0 success, 1 a finding that fails its check, 2 bad input (one line on stderr, no traceback).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from lpvflow.errors import LpvflowError

#: Subcommand -> (module, function configuring its parser, one-line help), in ``lpvflow --help`` order.
#: Only the invoked subcommand's module is imported (``lpvflow --help`` and usage errors stay fast).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "identify": ("cli_identify", "configure_identify",
                 "identify an LPV-ARX model and realize it as an LPV state space"),
    "simulate": ("cli_identify", "configure_simulate",
                 "simulate a model on data and report BFR/VAF/MSE per output"),
    "synth": ("cli_synth", "configure", "polytopic gain-scheduled H∞ controller by LMIs"),
    "diagnose": ("cli_diagnose", "configure", "find what a model structure's simulation gets wrong and why"),
    "design": ("cli_design", "configure", "run experiment → identify → … → export → report on a design file"),
    "experiment": ("cli_experiment", "configure",
                   "run an open- or closed-loop identification experiment on an FMU plant"),
    "verify": ("cli_verify", "configure",
               "co-simulate a controller with a plant FMU on scenarios; metrics and verdicts"),
    "export": ("cli_export", "configure",
               "export a controller as an FMI 2.0 Co-Simulation FMU, MATLAB .mat or JSON"),
    "validate": ("cli_validate", "configure",
                 "fit, frozen nu-gap vs b(P,K), margins and stability certificate"),
}


class _Parser(argparse.ArgumentParser):
    """argparse with exit status 2 and one line for usage errors (argparse's own convention)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        command = self.prog.split()[-1]  # "lpvflow" for the top-level parser
        prefix = "lpvflow" if command == "lpvflow" else f"lpvflow {command}"
        sys.stderr.write(f"{prefix}: error: {message}\n")
        raise SystemExit(2)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Every subcommand with its help line; ``command``'s own arguments too (its module imported)."""
    parser = _Parser(prog="lpvflow", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name, (module, function, help_line) in COMMANDS.items():
        subparser = sub.add_parser(name, help=help_line)
        if name == command:
            getattr(importlib.import_module(f"lpvflow.pipeline.{module}"), function)(subparser)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = next((arg for arg in argv if not arg.startswith("-")), None)  # lpvflow [-h] COMMAND ...
    parser = build_parser(command)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except LpvflowError as exc:
        sys.stderr.write(f"lpvflow {args.command}: error: {exc}\n")
        return 2
    except FileNotFoundError as exc:
        sys.stderr.write(f"lpvflow {args.command}: error: file not found: {exc.filename}\n")
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
