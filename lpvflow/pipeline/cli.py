"""The `lpvflow` command line: one subcommand per stage.

Each stage module exposes ``add_parser(subparsers)`` which registers its subcommand and sets
``func(args) -> int`` as the parser default. Exit status: 0 success, 1 a finding that fails its
check, 2 bad input (one line on stderr, no traceback).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from lpvflow.errors import LpvflowError

#: Modules that register subcommands, in the order they appear in ``lpvflow --help``.
STAGE_MODULES = [
    "lpvflow.pipeline.cli_identify",
    "lpvflow.pipeline.cli_synth",
    "lpvflow.pipeline.cli_diagnose",
    "lpvflow.pipeline.cli_design",
    "lpvflow.pipeline.cli_experiment",
    "lpvflow.pipeline.cli_verify",
    "lpvflow.pipeline.cli_export",
    "lpvflow.pipeline.cli_validate",
]


class _Parser(argparse.ArgumentParser):
    """argparse with exit status 2 and one line for usage errors (argparse's own convention)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"lpvflow {self.prog.split()[-1]}: error: {message}\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="lpvflow", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name in STAGE_MODULES:
        importlib.import_module(name).add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
