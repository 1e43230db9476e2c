"""Diagnosis hit rates over seeds and noise levels, and its cost at N = 20 000 (issue 8).

Hit: the named cause is the hidden one and its parameter is right (delay exact, degree exact,
channel exact, dead-zone width within 20 %, friction level within 10 %, offset within 20 %; for
model order: na ≥ the true order). Control: 'none' on data without an effect.
Cost: one diagnosis of N = 20 000 samples (SISO, all candidates) and the time of each extension.

Run: ``.venv/bin/python benchmarks/bench_diagnose.py [--seeds 10]`` → results/diagnose.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from lpvflow.validate import extensions
from lpvflow.validate.diagnose import diagnose
from tests.diagnosis_cases import NOMINAL, make_case

CAUSES = ["none", "input_delay", "model_order", "scheduling_dependence", "scheduling_variable",
          "input_nonlinearity", "friction", "offset", "colored_noise"]
TOLERANCE = {"input_nonlinearity": ("width", 0.2), "friction": ("coulomb_level_input_units", 0.1),
             "offset": ("output_offset", 0.2)}


def is_hit(cause: str, result, expected) -> bool:
    if result.cause != cause:
        return False
    par = result.parameters
    if cause == "input_delay":
        return par["nk"] == expected
    if cause == "model_order":
        return par["na"] >= expected
    if cause == "scheduling_dependence":
        return par.get("degree") == expected
    if cause == "scheduling_variable":
        return par["channel"] == expected
    if cause in TOLERANCE:
        key, rel = TOLERANCE[cause]
        return abs(par[key] - expected) <= rel * abs(expected)
    return True


def hit_rates(seeds: int, snrs: list[float]) -> dict:
    table = {}
    for cause in CAUSES:
        for snr in snrs:
            snr_case = 10.0 if cause == "colored_noise" else snr
            named = []
            hits = 0
            for seed in range(seeds):
                data, channels, expected = make_case(cause, seed=1000 + seed, snr_db=snr_case)
                result = diagnose(data, NOMINAL, channels)
                hits += is_hit(cause, result, expected)
                named.append(result.cause)
            row = {"hits": hits, "runs": seeds, "named": {c: named.count(c) for c in set(named)}}
            table[f"{cause}@{snr_case:g}dB"] = row
            print(f"{cause:22s} {snr_case:4g} dB: {hits}/{seeds}  {row['named']}", flush=True)
    return table


def cost(n: int = 20_000) -> dict:
    data, channels, _ = make_case("input_delay", seed=7, n=n)
    per = {}
    original = dict(extensions.EXTENSIONS)
    for name, fn in original.items():
        def timed(ctx, fn=fn, name=name):
            t0 = time.perf_counter()
            out = fn(ctx)
            per[name] = time.perf_counter() - t0
            return out
        extensions.EXTENSIONS[name] = timed
    try:
        t0 = time.perf_counter()
        diagnose(data, NOMINAL, channels)
        total = time.perf_counter() - t0
    finally:
        extensions.EXTENSIONS.update(original)
    return {"N": n, "total_s": total, "per_extension_s": per}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    results = {"cost": cost(), "hit_rates": hit_rates(args.seeds, [20.0, 30.0])}
    out = Path(__file__).parent / "results" / "diagnose.json"
    out.write_text(json.dumps(results, indent=1))
    c = results["cost"]
    print(f"\nN = {c['N']}: {c['total_s']:.1f} s in all; per extension: "
          + ", ".join(f"{k} {v:.2f} s" for k, v in sorted(c["per_extension_s"].items(),
                                                           key=lambda kv: -kv[1])))
    print("\n| hidden effect | noise | hits | named |\n|---|---|---|---|")
    for key, row in results["hit_rates"].items():
        cause, snr = key.split("@")
        print(f"| {cause} | {snr} | {row['hits']}/{row['runs']} | "
              + ", ".join(f"{k} {v}" for k, v in sorted(row["named"].items())) + " |")


if __name__ == "__main__":
    main()
