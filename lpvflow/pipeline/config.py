"""Design configuration (TOML): one table per stage, checked on load.

Relative paths are taken relative to the directory `lpvflow design` runs in (the repository root for
`make design`). Unknown tables or keys are errors, so that a typo never silently falls back to a
default. The bundled default is ``lpvflow/pipeline/examples/adip.toml``.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from lpvflow.errors import DataError

#: Allowed keys per table, with defaults (``REQUIRED`` marks keys without one).
REQUIRED = object()
SCHEMA: dict[str, dict[str, Any]] = {
    "design": {"name": REQUIRED, "plant": REQUIRED, "output_dir": "build/design"},
    "experiment": {"Ts": REQUIRED, "duration": REQUIRED, "controller": None, "inputs": {}, "excitation": {},
                   "setpoint": {}, "parameters": {}, "scheduling": {}, "seed": 0},
    "identify": {"u": REQUIRED, "y": REQUIRED, "p": REQUIRED, "na": 2, "nb": 2, "nk": 1, "basis": "affine",
                 "split": 0.7, "ridge": 0.0, "remove_offsets": False},
    "diagnose": {"adopt": False, "candidates": [], "split": 0.5},
    "reduce": {"order": None},
    "validate": {"grid": 7, "reference": "none", "operating_point": {}, "scaling": "data"},
    "synth": {"method": "common", "weights": REQUIRED, "box": None, "solver": "CLARABEL",
              "baseline_at": None},
    "verify": {"loop": REQUIRED, "scenario": REQUIRED},
    "export": {"formats": ["fmu", "json", "mat"]},
}

#: Tables a design may leave out: without [diagnose] the identified model goes straight to reduction;
#: without [synth] the run ends after validation (identification only).
OPTIONAL = ("diagnose", "synth", "verify", "export")

BUNDLED = "adip"


def bundled_config(name: str = BUNDLED) -> Path:
    """Path of a bundled example configuration (``adip``, ``maglev``, ``airpath``)."""
    path = Path(str(resources.files("lpvflow.pipeline") / "examples" / f"{name}.toml"))
    if not path.exists():
        raise DataError(f"no bundled design {name!r}; bundled: adip, maglev, airpath")
    return path


def load_config(path: str | Path) -> dict[str, dict[str, Any] | None]:
    """Read and check a design TOML; every table with its defaults filled in (None: optional, absent)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"design file {str(path)!r} does not exist")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise DataError(f"{path.name} is not valid TOML: {exc}") from None
    unknown = sorted(set(raw) - set(SCHEMA))
    if unknown:
        raise DataError(f"{path.name}: unknown table(s) {unknown}; known: {sorted(SCHEMA)}")
    config: dict[str, dict[str, Any] | None] = {}
    for table, keys in SCHEMA.items():
        if table in OPTIONAL and table not in raw:
            config[table] = None
            continue
        given = raw.get(table, {})
        if not isinstance(given, dict):
            raise DataError(f"{path.name}: [{table}] must be a table")
        extra = sorted(set(given) - set(keys))
        if extra:
            raise DataError(f"{path.name}: [{table}] has unknown key(s) {extra}; known: {sorted(keys)}")
        missing = [k for k, v in keys.items() if v is REQUIRED and k not in given]
        if missing:
            raise DataError(f"{path.name}: [{table}] lacks {missing}")
        config[table] = {k: given.get(k, v) for k, v in keys.items()}
    if config["synth"] is None and (config["verify"] or config["export"]):
        raise DataError(f"{path.name}: [verify] and [export] need a [synth] table (a controller to use)")
    for where, value in (("[design] plant", config["design"]["plant"]),
                         ("[experiment] controller", config["experiment"]["controller"])):
        if value and not Path(value).exists():
            raise DataError(f"{path.name}: {where} {value!r} does not exist (paths are relative to "
                            "the directory lpvflow design runs in; run `make fmus` to build the plants)")
    return config
