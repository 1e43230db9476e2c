"""Input and output paths of a CLI command, checked before it does any work.

Each subcommand declares which of its arguments are input files, output files and output folders
(:func:`declare`); :func:`check_declared` then refuses, with one line, an output that is an input of
the same command (or an input's experiment sidecar ``<file>.json``), an output that is a folder, and
an output whose folder cannot be written (probed by creating and deleting a temporary file there).
Only the standard library is imported: ``lpvflow --help`` stays fast.
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Iterable
from pathlib import Path

from lpvflow.errors import DataError


def declare(parser: argparse.ArgumentParser, inputs: tuple[str, ...] = (), outputs: tuple[str, ...] = (),
            folders: tuple[str, ...] = ()) -> None:
    """Record the argument names (``dest``) holding input files, output files and output folders."""
    parser.set_defaults(path_roles=(inputs, outputs, folders))


def _values(args: argparse.Namespace, names: Iterable[str]) -> list[str]:
    return [value for name in names if (value := getattr(args, name, None))]


def check_declared(args: argparse.Namespace) -> None:
    """:func:`check_paths` on the paths the invoked subcommand declared."""
    inputs, outputs, folders = getattr(args, "path_roles", ((), (), ()))
    check_paths(_values(args, inputs), _values(args, outputs), _values(args, folders))


def writable_folder(folder: str | Path, what: str) -> Path:
    """Create ``folder`` if needed and prove it writable; one-line DataError naming ``what`` if not."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise DataError(f"{what}: {folder} is a file, not a folder; give a folder path")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise DataError(f"cannot write {what} in {folder} ({exc.strerror}); "
                        "choose a writable folder") from None
    return folder


def check_paths(inputs: Iterable[str | Path], outputs: Iterable[str | Path],
                folders: Iterable[str | Path] = ()) -> None:
    """Refuse outputs that would overwrite an input (or its sidecar), repeat, are folders or unwritable."""
    protected: dict[Path, str] = {}
    for name in inputs:
        path = Path(name).resolve()
        protected[path] = f"the input file {name}"
        protected.setdefault(path.with_name(path.name + ".json"), f"the sidecar of the input file {name}")
    seen: set[Path] = set()
    for name in outputs:
        target = Path(name).resolve()
        if target in protected:
            raise DataError(f"output {name} would overwrite {protected[target]} of this command; "
                            "choose another output path")
        if target in seen:
            raise DataError(f"output {name} is given twice; give each output its own path")
        seen.add(target)
        if target.is_dir():
            raise DataError(f"output {name} is a folder; give a file path")
        writable_folder(target.parent, f"output {name}")
    for name in folders:
        writable_folder(name, "the output folder")
