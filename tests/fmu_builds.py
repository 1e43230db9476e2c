"""The plant FMUs for tests: fmu_plants/build/<name>.fmu, built as `make fmus` would if it is missing."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def built_fmu(name: str) -> Path:
    path = ROOT / "fmu_plants" / "build" / f"{name}.fmu"
    if not path.is_file():
        subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py"), name], check=True)
    return path
