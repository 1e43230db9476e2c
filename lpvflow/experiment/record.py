"""Write an experiment record: a CSV (header row, ``time`` first, one column per signal) and a JSON
sidecar ``<csv>.json`` with the metadata (``"format": "lpvflow/experiment"``, read by ``lpvflow.load``).
Both are written to temporary files in the target folder and renamed into place only when complete,
so a failed run leaves no partial file; neither may be one of the experiment's input files (the FMU,
the controller)."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from lpvflow.errors import DataError
from lpvflow.experiment.run import ExperimentRecord, sidecar_path
from lpvflow.models import report_header, user_mode


def csv_text(record: ExperimentRecord) -> str:
    """The CSV as text; floats in their shortest round-trip form (``repr``), so bytes are reproducible
    and ``numpy.loadtxt`` gives back the recorded values exactly."""
    names = list(record.columns)
    table = np.column_stack([record.columns[name] for name in names]).tolist()
    lines = [",".join(names)] + [",".join(map(repr, row)) for row in table]
    return "\n".join(lines) + "\n"


def _atomic_write(path: Path, text: str) -> None:
    handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    user_mode(handle)
    try:
        with os.fdopen(handle, "w", newline="") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _same_file(a: Path, b: Path) -> bool:
    return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))


def check_output_path(csv_path: str | Path, protected: Iterable[str | Path] = ()) -> Path:
    """Refuse an output (CSV or its sidecar) in a missing folder, on top of a protected input file, or
    not named ``*.csv`` (``-o data.csv.json`` would write CSV over another record's sidecar)."""
    csv_path = Path(csv_path)
    if not csv_path.parent.is_dir():
        raise DataError(f"output folder {csv_path.parent} does not exist; create it first")
    for target in (csv_path, sidecar_path(csv_path)):
        if target.is_dir():
            raise DataError(f"output {target} is a folder; give a file name such as data.csv")
        for source in map(Path, protected):
            if _same_file(target, source):
                raise DataError(f"output {target} would overwrite the input {source}; choose another name")
    if csv_path.suffix.lower() != ".csv":
        raise DataError(f"output {csv_path.name}: an experiment is written as CSV; name the output "
                        "DATA.csv (its record goes to DATA.csv.json)")
    return csv_path


def write_record(
    record: ExperimentRecord, csv_path: str | Path, protected: Iterable[str | Path] = ()
) -> Path:
    """Write ``csv_path`` and its sidecar JSON; returns the sidecar path."""
    csv_path = check_output_path(csv_path, protected)
    side = sidecar_path(csv_path)
    meta = report_header("experiment") | {"csv": csv_path.name} | record.metadata
    _atomic_write(side, json.dumps(meta, indent=2, sort_keys=False) + "\n")
    _atomic_write(csv_path, csv_text(record))
    return side
