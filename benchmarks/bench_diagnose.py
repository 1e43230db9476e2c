"""Diagnosis hit rates over seeds and noise levels, and its cost at N = 20 000 (issue 8).

Hit: the named cause is the hidden one and its parameter is right (delay exact, degree exact,
channel exact, dead-zone width within 20 %, friction level within 10 %, offset within 20 %; for
model order: na ≥ the true order). Control: 'none' on data without an effect.
Cost: one diagnosis of N = 20 000 samples (SISO, all candidates) and the time of each extension.

FMU section: the plants of fmu_plants/ with an effect parameter set (experiments and nominal
structures of tests/test_diagnose_fmu.py; tanks poly:3 in the level, also for the na = nb = 1
case), over experiment seeds (input signals and noise draw) and
sensor-noise levels (effect_noise_std, in the output's unit). Same hit definition; model order:
na ≥ 2 (two tanks); scheduling dependence: a polynomial degree ≥ 2 (the physical coefficient
functions are not polynomials). The ADIP cases are closed-loop records (unstable plant, stabilizing
controller): every model is simulated in the identification loop (``diagnose(..., controller=...)``);
friction level within 10 % of F_c / 0.1284 N·m/V, offset within 20 % on both angles.

Run: ``.venv/bin/python benchmarks/bench_diagnose.py [--seeds 10] [--fmu-seeds 5]``
→ results/diagnose.json; ``--fmu-only adip`` runs the ADIP cases alone → results/diagnose_fmu_adip.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from lpvflow.validate import extensions
from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.extensions import Structure
from tests.diagnosis_cases import NOMINAL, make_case
from tests.test_diagnose_fmu import (
    ADIP,
    ADIP_SCHEDULING,
    AIRPATH,
    DEAD_ZONE_PUMP,
    SRV02_TORQUE_PER_VOLT,
    TANKS,
    adip_controller,
    adip_data,
    airpath_data,
    tanks_data,
)

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


#: Angle-sensor noise levels [rad] of the ADIP cases.
ADIP_NOISE = [0.0, 1e-4]


def _friction_hit(par: dict, coulomb: float) -> bool:
    """Friction against the arm, level within 10 % of the Coulomb torque in volts."""
    expected = coulomb / SRV02_TORQUE_PER_VOLT
    return par["output"] == "arm_angle" and abs(par["coulomb_level_input_units"] - expected) <= 0.1 * expected
#: label → (hidden cause, plant, effect parameters, nominal structure, check of the parameters,
#: sensor-noise levels, keyword arguments of the data function).
FMU_CASES = {
    "tanks none": ("none", "tanks", {}, TANKS, None, [0.0, 5e-4], {}),
    "tanks dead time 3 s": ("input_delay", "tanks", {"effect_input_delay": 3.0}, TANKS,
                            lambda par: par["nk"] == 4, [0.0, 5e-4], {}),
    "tanks na = nb = 1": ("model_order", "tanks", {}, Structure(1, 1, 1, TANKS.basis),
                          lambda par: par["na"] >= 2, [0.0, 5e-4], {}),
    "tanks saturation 8 V": ("input_nonlinearity", "tanks", {"effect_saturation": 8.0}, TANKS,
                             lambda par: par["kind"] == "saturation" and abs(par["limit"] - 8) <= 0.4,
                             [0.0, 5e-4], {}),
    "tanks none, dead-zone design": ("none", "tanks", {}, TANKS, None, [0.0], {"pump": DEAD_ZONE_PUMP}),
    "tanks dead zone 3 V": ("input_nonlinearity", "tanks", {"effect_deadzone": 3.0}, TANKS,
                            lambda par: par["kind"] == "dead_zone" and abs(par["width"] - 3) <= 0.6,
                            [0.0, 5e-4], {"pump": DEAD_ZONE_PUMP}),
    "tanks offset 0.05 m": ("offset", "tanks", {"effect_sensor_offset": 0.05}, TANKS,
                            lambda par: abs(par["output_offset"] - 0.05) <= 0.01, [0.0, 5e-4], {}),
    "airpath none": ("none", "airpath", {}, AIRPATH, None, [0.0, 0.5], {}),
    "airpath speed-only scheduling": ("scheduling_variable", "airpath", {}, AIRPATH,
                                      lambda par: par["channel"] == "throttle", [0.0, 0.5],
                                      {"throttle_scheduling": False}),
    "airpath affine basis": ("scheduling_dependence", "airpath", {}, Structure(1, 1, 1, "affine"),
                             lambda par: par.get("degree", 0) >= 2, [0.0, 0.5], {}),
    "airpath pressure noise": ("colored_noise", "airpath", {}, AIRPATH, None, [2.0, 4.0, 6.0], {}),
    "airpath offset 5 kPa": ("offset", "airpath", {"effect_sensor_offset": 5.0}, AIRPATH,
                             lambda par: abs(par["output_offset"] - 5) <= 1, [0.0, 0.5], {}),
    "adip none (closed loop)": ("none", "adip", {}, ADIP, None, ADIP_NOISE, {}),
    "adip Coulomb 0.04 N·m": ("friction", "adip", {"effect_coulomb": 0.04}, ADIP,
                              lambda par: _friction_hit(par, 0.04), ADIP_NOISE, {}),
    "adip Coulomb 0.02 N·m": ("friction", "adip", {"effect_coulomb": 0.02}, ADIP,
                              lambda par: _friction_hit(par, 0.02), ADIP_NOISE, {}),
    "adip sensor offset 0.01 rad": ("offset", "adip", {"effect_sensor_offset": 0.01}, ADIP,
                                    lambda par: np.allclose(par["output_offset"], 0.01, rtol=0, atol=0.002),
                                    ADIP_NOISE, {}),
}


def fmu_hit_rates(seeds: int, prefix: str = "") -> dict:
    """Hit rates of the FMU cases whose label starts with ``prefix``; BFR is the mean over outputs."""
    root = Path(__file__).resolve().parents[1]
    subprocess.run([sys.executable, str(root / "fmu_plants" / "build.py")], check=True, capture_output=True)
    table = {}
    for label, (cause, plant, effects, structure, check, noise_levels, kwargs) in FMU_CASES.items():
        if not label.startswith(prefix):
            continue
        for noise in noise_levels:
            named, hits, p_hits, before, after, seconds = [], 0, [], [], [], []
            for seed in range(seeds):
                parameters = {**effects, "effect_noise_std": noise, "effect_noise_seed": 100 + seed}
                t0 = time.perf_counter()
                loop = {}
                if plant == "tanks":
                    data, channels = tanks_data(parameters, seed=seed, **kwargs), {}
                elif plant == "airpath":
                    data, channels = airpath_data(parameters, seed=seed, **kwargs)
                else:
                    data, channels = adip_data(parameters, seed=seed, **kwargs), {}
                    loop = {"controller": adip_controller(), "scheduling": ADIP_SCHEDULING}
                result = diagnose(data, structure, channels, **loop)
                seconds.append(time.perf_counter() - t0)
                hit = result.cause == cause and (check is None or check(result.parameters))
                hits += hit
                named.append(result.cause)
                before.append(np.mean(result.bfr_before))
                after.append(np.mean(result.bfr_after))
                if hit and cause != "none":
                    # a cause named in the noise round is scored there (refit_ranking)
                    rows = result.refit_ranking if result.cause != "colored_noise" else []
                    rows = rows if any(r["cause"] == cause for r in rows) else result.ranking
                    p_hits.append(next(r for r in rows if r["cause"] == cause)["p_value"])
            row = {"cause": cause, "noise_std": noise, "hits": hits, "runs": seeds,
                   "named": {c: named.count(c) for c in set(named)},
                   "bfr_before_median": float(np.median(before)), "bfr_after_median": float(np.median(after)),
                   "largest_p_of_hits": max(p_hits, default=None),
                   "seconds_per_run": float(np.mean(seconds))}
            table[f"{label} @ noise {noise:g}"] = row
            print(f"{label:32s} noise {noise:<6g}: {hits}/{seeds}  {row['named']}  BFR "
                  f"{row['bfr_before_median']:.1f} → {row['bfr_after_median']:.1f}  "
                  f"{row['seconds_per_run']:.1f} s/run", flush=True)
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
    parser.add_argument("--fmu-seeds", type=int, default=5)
    parser.add_argument("--fmu-only", metavar="PREFIX",
                        help="only the FMU cases whose label starts with PREFIX (e.g. adip) → "
                             "results/diagnose_fmu_PREFIX.json")
    args = parser.parse_args()
    if args.fmu_only:
        results = {"fmu_hit_rates": fmu_hit_rates(args.fmu_seeds, args.fmu_only)}
        out = Path(__file__).parent / "results" / f"diagnose_fmu_{args.fmu_only}.json"
    else:
        results = {"cost": cost(), "hit_rates": hit_rates(args.seeds, [20.0, 30.0]),
                   "fmu_hit_rates": fmu_hit_rates(args.fmu_seeds)}
        out = Path(__file__).parent / "results" / "diagnose.json"
    out.write_text(json.dumps(results, indent=1))
    if args.fmu_only:
        _print_fmu_table(results)
        return
    c = results["cost"]
    print(f"\nN = {c['N']}: {c['total_s']:.1f} s in all; per extension: "
          + ", ".join(f"{k} {v:.2f} s" for k, v in sorted(c["per_extension_s"].items(),
                                                           key=lambda kv: -kv[1])))
    print("\n| hidden effect | noise | hits | named |\n|---|---|---|---|")
    for key, row in results["hit_rates"].items():
        cause, snr = key.split("@")
        print(f"| {cause} | {snr} | {row['hits']}/{row['runs']} | "
              + ", ".join(f"{k} {v}" for k, v in sorted(row["named"].items())) + " |")
    _print_fmu_table(results)


def _print_fmu_table(results: dict) -> None:
    print("\n| FMU case | noise std | hits | named | BFR before → after (median) |\n|---|---|---|---|---|")
    for key, row in results["fmu_hit_rates"].items():
        label = key.split(" @ ")[0]
        print(f"| {label} | {row['noise_std']:g} | {row['hits']}/{row['runs']} | "
              + ", ".join(f"{k} {v}" for k, v in sorted(row["named"].items()))
              + f" | {row['bfr_before_median']:.1f} → {row['bfr_after_median']:.1f} |")


if __name__ == "__main__":
    main()
