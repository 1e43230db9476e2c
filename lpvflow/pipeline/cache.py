"""Stage cache: a stage is skipped when its key — a hash of everything it depends on — is unchanged.

key(stage) = sha256(JSON of its config section, a digest of lpvflow's own source code, the keys of
the stages it reads from, the bytes of the files it reads). A stage's record
(``<stage>.json`` in the design folder) stores the key and the stage's outputs; it is reused only
when the key matches and every artifact it lists still exists. Because downstream keys contain
upstream keys, a config change reruns exactly the stages it affects.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from lpvflow.experiment.plant import sha256_of
from lpvflow.models import atomic_write_json


def code_digest() -> str:
    """sha256 over lpvflow's Python sources and package data: a code change invalidates every stage."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".c", ".h", ".xml", ".toml")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def stage_key(section: Any, upstream: list[str], files: list[str | Path]) -> str:
    payload = json.dumps({"config": section, "upstream": upstream,
                          "files": [sha256_of(f) for f in files]}, sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()


def load_record(folder: Path, stage: str, key: str) -> dict | None:
    """The stored outputs of ``stage`` if its key matches and its artifacts exist, else None."""
    path = folder / f"{stage}.json"
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
    except json.JSONDecodeError:
        return None
    if record.get("key") != key:
        return None
    if not all((folder / a).exists() for a in record.get("artifacts", [])):
        return None
    return record


def save_record(folder: Path, stage: str, key: str, outputs: dict, artifacts: list[str],
                seconds: float) -> dict:
    record = {"key": key, "outputs": outputs, "artifacts": artifacts, "seconds": seconds}
    atomic_write_json(folder / f"{stage}.json", record)
    return record
