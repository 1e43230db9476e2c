"""The `lpvflow` command line: one subcommand per stage.

``COMMANDS`` names each subcommand, its help line and the stage module function that adds its arguments
and sets ``func(args) -> int`` as the parser default; only the invoked subcommand's module is imported.
Exit status: 0 success, 1 a finding that fails its check, 2 bad input (one line on stderr, no traceback),
130 interrupted (Ctrl-C). Warnings reach the user as one line each, without source paths
(:func:`warning_line`); the library warnings lpvflow answers itself (:data:`SILENCED`) not at all.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from importlib.metadata import PackageNotFoundError, version

from lpvflow.errors import LpvflowError
from lpvflow.pipeline import interrupt
from lpvflow.pipeline.cli_paths import check_declared

#: Subcommand -> (module, function configuring its parser, one-line help), in ``lpvflow --help`` order.
#: Only the invoked subcommand's module is imported (``lpvflow --help`` and usage errors stay fast).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "experiment": ("cli_experiment", "configure",
                   "run an open- or closed-loop identification experiment on an FMU plant"),
    "identify": ("cli_identify", "configure_identify",
                 "identify an LPV-ARX model and realize it as an LPV state space"),
    "simulate": ("cli_identify", "configure_simulate",
                 "simulate a model on data and report BFR/VAF/MSE per output"),
    "validate": ("cli_validate", "configure",
                 "fit, frozen nu-gap vs b(P,K), margins and stability certificate"),
    "diagnose": ("cli_diagnose", "configure", "find what a model structure's simulation gets wrong and why"),
    "synth": ("cli_synth", "configure", "polytopic gain-scheduled H∞ controller by LMIs"),
    "verify": ("cli_verify", "configure",
               "co-simulate a controller with a plant FMU on scenarios; metrics and verdicts"),
    "export": ("cli_export", "configure",
               "export a controller as an FMI 2.0 Co-Simulation FMU, MATLAB .mat or JSON"),
    "design": ("cli_design", "configure", "run experiment → identify → … → export → report on a design file"),
}

#: Library warnings lpvflow answers itself: cvxpy's "Solution may be inaccurate" comes with a status every
#: lpvflow solve returns to its caller, which re-checks the numbers; a command whose result rests on an
#: inaccurate solve says so from that status (``lpvflow synth``), not for every auxiliary SDP.
SILENCED = ("Solution may be inaccurate",)


class _Parser(argparse.ArgumentParser):
    """argparse with exit status 2 and one line for usage errors (argparse's own convention)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        command = self.prog.split()[-1]  # "lpvflow" for the top-level parser
        prefix = "lpvflow" if command == "lpvflow" else f"lpvflow {command}"
        sys.stderr.write(f"{prefix}: error: {message}\n")
        raise SystemExit(2)


def package_version() -> str:
    """The installed distribution's version."""
    try:
        return version("lpvflow")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Every subcommand with its help line; ``command``'s own arguments too (its module imported)."""
    parser = _Parser(prog="lpvflow", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"lpvflow {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name, (module, function, help_line) in COMMANDS.items():
        subparser = sub.add_parser(name, help=help_line)
        if name == command:
            getattr(importlib.import_module(f"lpvflow.pipeline.{module}"), function)(subparser)
    return parser


def warning_line(message: Warning | str) -> str:
    """A warning as lpvflow tells it: its own first line, without the source path."""
    text = str(message).strip()
    return text.splitlines()[0] if text else type(message).__name__


def main(argv: list[str] | None = None) -> int:
    """Run ``lpvflow ARGV``; returns the exit status (usage errors exit 2 through argparse)."""
    argv = sys.argv[1:] if argv is None else argv
    command = next((arg for arg in argv if not arg.startswith("-")), None)  # lpvflow [-h] COMMAND ...
    prefix = "lpvflow" if command not in COMMANDS else f"lpvflow {command}"
    try:
        return _run(build_parser(command).parse_args(argv), prefix)
    except Exception:
        if not interrupt.requested():  # an error of its own, not the aftermath of a Ctrl-C
            raise
    except KeyboardInterrupt:
        pass
    sys.stderr.write(f"{prefix}: interrupted by Ctrl-C\n")
    return 130


def _run(args: argparse.Namespace, prefix: str) -> int:
    """The subcommand's runner with its paths checked, errors as one line and warnings as one line."""
    shown: set[str] = set()

    def show(message: Warning | str, *_: object, **__: object) -> None:
        line = warning_line(message)
        if line not in shown:  # once per run, however often a loop repeats it
            shown.add(line)
            sys.stderr.write(f"{prefix}: warning: {line}\n")

    with warnings.catch_warnings():
        warnings.showwarning = show
        for text in SILENCED:
            warnings.filterwarnings("ignore", message=text)
        try:
            check_declared(args)
            return int(args.func(args) or 0)
        except LpvflowError as exc:
            sys.stderr.write(f"{prefix}: error: {exc}\n")
            return 2
        except OSError as exc:
            where = f" ({exc.filename})" if exc.filename else ""
            sys.stderr.write(f"{prefix}: error: {exc.strerror or exc}{where}; check the path exists and "
                             "can be written\n")
            return 2


def entry() -> None:
    """The ``lpvflow`` console script: the process ends with :func:`main`'s status. After a Ctrl-C it ends
    with ``os._exit(130)`` once its output is flushed: CPython may end the process by SIGINT at exit
    (status −2, not 130) when an interpreter-level run it made on a library's behalf ended in the
    KeyboardInterrupt that lpvflow then handled (``_Py_UnhandledKeyboardInterrupt``; observed in 2 of 70
    interrupted designs, after the "interrupted" line)."""
    status = main()
    if status == 130:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    raise SystemExit(status)


if __name__ == "__main__":
    entry()
