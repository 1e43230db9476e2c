"""The README's Quick start runs as written: its shell commands (verbatim, in a fresh folder that sees the
repository's fmu_plants/ as a clone does) and then its Python snippet.

The set-up block (``make venv fmus``, activating .venv) is what the test session already is; the
whole-design block runs with the slow tests (``make bench``).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def quick_start_blocks() -> list[tuple[str, str]]:
    """(language, code) of every fenced block in the README's Quick start section, in order."""
    readme = (ROOT / "README.md").read_text()
    section = readme.split("\n## Quick start\n")[1].split("\n## ")[0]
    return re.findall(r"```(\w+)\n(.*?)```", section, re.S)


def run_shell(block: str, cwd: Path) -> subprocess.CompletedProcess:
    """Each line of ``block`` with bash in ``cwd``, lpvflow on PATH as after activating .venv."""
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    return subprocess.run(["bash", "-e", "-c", block], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)


@pytest.fixture
def clone(tmp_path: Path) -> Path:
    """A working folder laid out like a fresh clone after `make fmus`."""
    (ROOT / "fmu_plants" / "build" / "tanks.fmu").stat()  # built by the session (make test: fmus)
    (tmp_path / "fmu_plants").symlink_to(ROOT / "fmu_plants")
    return tmp_path


def test_the_quick_start_blocks_are_set_up_commands_python() -> None:
    languages = [language for language, _ in quick_start_blocks()]
    assert languages == ["sh", "sh", "python", "sh"]
    assert quick_start_blocks()[0][1].splitlines() == ["make venv fmus", ". .venv/bin/activate"]


def test_quick_start_runs_as_written(clone: Path) -> None:
    (_, _), (_, commands), (_, python), _ = quick_start_blocks()
    done = run_shell(commands, clone)
    assert done.returncode == 0, done.stderr
    bfr = float(re.search(r"lower_level: BFR ([\d.]+) %", done.stdout).group(1))
    assert bfr > 90  # fresh data: the model describes the plant
    assert (clone / "fit.png").stat().st_size > 0 and (clone / "fit.json").is_file()
    snippet = python + "\nassert y_sim.shape == val.y.shape and g.dt == data.Ts\n"
    done = subprocess.run([sys.executable, "-c", snippet], cwd=clone, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr


@pytest.mark.slow
def test_quick_start_design_runs_as_written(clone: Path) -> None:
    done = run_shell(quick_start_blocks()[3][1], clone)
    assert done.returncode == 0, done.stderr
    assert (clone / "build" / "design" / "airpath" / "report.html").is_file()
