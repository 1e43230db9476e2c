"""Ctrl-C during a real ``lpvflow design`` (a small two-tank design, every stage real), sent as SIGINT
at random moments: exit 130 with one "interrupted" line every time, never a verdict, no traceback, no
partial file (every file left belongs to a stage whose record lists it with its bytes), the folder lock
released."""

from __future__ import annotations

import hashlib
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lpvflow.pipeline.cache import LOCK_NAME, folder_lock
from tests.test_cli_errors import TANKS, design_text

ROOT = Path(__file__).resolve().parents[1]
#: Stages of the design whose start line may precede the signal (export and the report are too short to
#: wait in: a signal after the verdict's window opened would not be an interrupted run).
STAGES = ("experiment", "identify", "reduce", "validate", "synth", "verify")


def design_file(folder: Path) -> Path:
    path = folder / "design.toml"
    text = design_text(TANKS, folder / "out")
    path.write_text(text.replace("weights.K = { num = [0.1], den = [1] }",
                                 "weights.K = { num = [0.1], den = [1] }\n"
                                 "weights.B = { num = [0, 0.3], den = [1, -0.7] }"))
    return path


def interrupted_run(folder: Path, stage: str, delay: float) -> tuple[int, list[str]]:
    """Start ``lpvflow design``, wait for ``stage``'s start line, then ``delay`` s, then send SIGINT."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-m", "lpvflow.pipeline.cli", "design",
                                str(design_file(folder))], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                               text=True, env=env)
    lines = []
    for line in process.stderr:
        lines.append(line.rstrip("\n"))
        if line.startswith("[") and line.rstrip().endswith(f"] {stage} …"):
            time.sleep(delay)
            process.send_signal(signal.SIGINT)
            break
    lines += process.stderr.read().splitlines()
    return process.wait(timeout=120), lines


def check_interrupted(folder: Path, status: int, lines: list[str]) -> None:
    assert status == 130, lines
    assert lines[-1] == "lpvflow design: interrupted by Ctrl-C", lines
    assert not any(line.startswith("design ") for line in lines), lines  # no verdict
    assert not any("Traceback" in line or "Exception ignored" in line for line in lines), "\n".join(lines)
    design = folder / "out" / "tanks"
    accounted = {LOCK_NAME}
    for record_path in design.glob("*.json"):
        record = json.loads(record_path.read_text())
        if record.get("format") != "lpvflow/stage":
            continue
        accounted.add(record_path.name)
        for artifact, digest in record["artifact_sha256"].items():
            assert hashlib.sha256((design / artifact).read_bytes()).hexdigest() == digest
            accounted.add(artifact)
    left = {p.name for p in design.iterdir()}
    assert left <= accounted, f"partial files {sorted(left - accounted)}; log {lines}"
    with folder_lock(design):  # released
        pass


def check_random_interrupts(tmp_path: Path, count: int, seed: int) -> None:
    rng = random.Random(seed)
    for n in range(count):
        folder = tmp_path / f"run{n}"
        folder.mkdir()
        status, lines = interrupted_run(folder, rng.choice(STAGES), rng.uniform(0.0, 0.25))
        check_interrupted(folder, status, lines)


def test_ctrl_c_at_three_random_moments_of_a_design(tmp_path):
    check_random_interrupts(tmp_path, 3, seed=34)


@pytest.mark.slow
def test_ctrl_c_at_twenty_random_moments_of_a_design(tmp_path):
    check_random_interrupts(tmp_path, 20, seed=2026)
