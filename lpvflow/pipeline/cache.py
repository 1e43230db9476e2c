"""Stage cache and the design-folder lock.

A stage is skipped when its key — a hash of everything it depends on — is unchanged:
key(stage) = sha256(JSON of its config tables, a digest of lpvflow's own source code, the keys of the
stages it reads from, the bytes of the input files it reads and of the upstream artifacts it reads).
A stage's record (``<stage>.json`` in the design folder) stores the key, the stage's outputs and the
sha256 of every artifact it wrote; it is reused only when the key matches and every artifact is still
there with the same bytes (so a file replaced by another run or by hand reruns the stage). Because
downstream keys contain upstream keys, a config change reruns exactly the stages it affects.

:func:`folder_lock` keeps a second run out of a design folder while one writes it.
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from lpvflow.errors import DataError
from lpvflow.experiment.plant import sha256_of
from lpvflow.models import atomic_write_json, report_header

#: The lock file inside a design folder (held with flock while a run writes the folder).
LOCK_NAME = ".lock"


def code_digest() -> str:
    """sha256 over lpvflow's Python sources and package data: a code change invalidates every stage."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".c", ".h", ".xml", ".toml")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def stage_key(section: Any, upstream: list[str], files: list[str | Path]) -> str:
    """The cache key of a stage: its settings, its upstream keys and the bytes of the files it reads.
    Parsed settings (dataclasses such as :class:`~lpvflow.pipeline.scenarios.Loop`) enter with every
    field."""
    payload = json.dumps({"config": section, "upstream": upstream,
                          "files": [sha256_of(f) for f in files]}, sort_keys=True, default=_plain)
    return hashlib.sha256(payload.encode()).hexdigest()


def _plain(value: Any) -> Any:
    """A JSON-ready stand-in for a value ``json`` cannot write: a dataclass's fields, else its text."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
        return {"type": type(value).__name__, **fields}
    return str(value)


def load_record(folder: Path, stage: str, key: str) -> dict | None:
    """The stored outputs of ``stage`` if its key matches and its artifacts are unchanged, else None."""
    path = folder / f"{stage}.json"
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
    except json.JSONDecodeError:
        return None
    if record.get("key") != key:
        return None
    digests = record.get("artifact_sha256", {})
    for artifact in record.get("artifacts", []):
        file = folder / artifact
        if not file.is_file() or digests.get(artifact) != sha256_of(file):
            return None
    return record


def save_record(folder: Path, stage: str, key: str, outputs: dict, artifacts: list[str],
                seconds: float) -> dict:
    """Store a stage's key, outputs, artifacts (with their sha256) and run time as ``<stage>.json``
    (format ``lpvflow/stage``, so :func:`lpvflow.load` reads it)."""
    record = {**report_header("stage"), "stage": stage, "key": key, "outputs": outputs,
              "artifacts": artifacts, "seconds": seconds,
              "artifact_sha256": {a: sha256_of(folder / a) for a in artifacts}}
    atomic_write_json(folder / f"{stage}.json", record)
    return record


@contextmanager
def folder_lock(folder: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``folder`` (flock on its ``.lock`` file); refuse if another run holds it."""
    fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "another process"
            raise DataError(f"design folder {folder} is being written by another lpvflow run (pid {holder}); "
                            "wait for it to finish or give this design another [design] name") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        os.close(fd)  # closing releases the lock
