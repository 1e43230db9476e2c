"""Closed-loop gain of adopting a diagnosed extension (issue 8, item 4), over experiment seeds.

The tanks FMU with a hidden 3 s pump dead time; the design of tests/test_design.py
(``dead_time_design``: nominal na = nb = 2, nk = 1, offsets removed, [diagnose] adopt = true, the
same polytopic H∞ weights before and after) with the affine and the poly:2 basis. Per case the
adoption stage's table: the LPV controller designed on the identified model (before) and on the
adopted one (after), both run on the FMU (lower level 8 → 12 cm and 8 → 5 cm): settling time,
overshoot, IAE and ISE of the tracking error.

Run: ``.venv/bin/python benchmarks/bench_adoption.py [--seeds 5]`` → results/adoption.json
(about 45 s per case on 2 cores, most of it the order-5 synthesis).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from lpvflow.pipeline.design import run_design
from tests.test_design import dead_time_design

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py")], check=True, capture_output=True)
    fmu = ROOT / "fmu_plants" / "build" / "tanks.fmu"
    cases = []
    for basis in ("affine", "poly:2"):
        for seed in range(1, args.seeds + 1):
            with tempfile.TemporaryDirectory() as tmp:
                summary = run_design(dead_time_design(Path(tmp), fmu, seed, basis), log=lambda _: None)
            diagnosis = summary["stages"]["diagnose"]["outputs"]
            adoption = summary["stages"].get("adoption", {}).get("outputs", {})
            cases.append({"basis": basis, "seed": seed, "failed": summary["failed"],
                          "cause": diagnosis.get("cause"), "parameters": diagnosis.get("parameters"),
                          "synth_seconds": summary["stage_seconds"].get("synth"), **adoption})
            print(f"{basis} seed {seed}: {diagnosis.get('cause')} {diagnosis.get('parameters')}", flush=True)
            for row in adoption.get("rows", []):
                b, a = row["before"], row["after"]
                print(f"  {row['scenario']:<18} settling {b['settling_time']} → {a['settling_time']} s, "
                      f"overshoot {b['overshoot_percent']:.2f} → {a['overshoot_percent']:.2f} %, "
                      f"IAE {b['iae']:.4f} → {a['iae']:.4f} ({100 * (a['iae'] / b['iae'] - 1):+.1f} %), "
                      f"ISE {b['ise']:.5f} → {a['ise']:.5f}", flush=True)
    out = ROOT / "benchmarks" / "results" / "adoption.json"
    out.write_text(json.dumps({"cases": cases}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
