"""The `lpvflow` entry point: subcommand table, lazy imports, top-level usage errors."""

from __future__ import annotations

import subprocess
import sys

import pytest

from lpvflow.pipeline.cli import COMMANDS, build_parser, main


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_subcommand_configures_its_parser_and_runner(command: str) -> None:
    parser = build_parser(command)
    subparsers = next(a for a in parser._actions if a.dest == "command")
    configured = subparsers.choices[command]
    assert configured.get_default("func") is not None  # the module set its runner
    assert len(configured._actions) > 1  # and its arguments, beyond -h


def test_help_and_usage_errors_do_not_load_the_numerical_stack() -> None:
    code = (
        "import sys\n"
        "from lpvflow.pipeline.cli import main\n"
        "for argv in (['--help'], ['bogus']):\n"
        "    try:\n"
        "        main(argv)\n"
        "    except SystemExit:\n"
        "        pass\n"
        "stack = ('numpy', 'scipy', 'numba', 'control', 'cvxpy', 'fmpy')\n"
        "heavy = sorted(m for m in stack if m in sys.modules)\n"
        "print('heavy:', heavy)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "heavy: []" in done.stdout, done.stdout + done.stderr


def test_an_unknown_subcommand_gives_one_line_and_status_2(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as info:
        main(["bogus"])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert err.startswith("lpvflow: error: argument command: invalid choice: 'bogus'")
    assert len(err.strip().splitlines()) == 1
