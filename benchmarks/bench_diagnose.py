"""Diagnosis hit rates over seeds, clean controls, and its cost at N = 20 000 (issues 8 and 26).

Synthetic cases (tests/diagnosis_cases.py, N = 4000, nominal structure na = nb = 2, nk = 1, affine),
seeds 1000–1009: each hidden effect at 30 dB equation noise, the noise cases at their own level. Hit:
the named cause is the hidden one and its parameter is right — delay, degree and channel exact,
na ≥ the true order, every level within 20 % (dead-zone and backlash width, Coulomb level, offset,
sensor limits, relative noise level); ``unexplained`` for the out-of-vocabulary effect.
Controls: white sensor noise of 1–3 % of the output's standard deviation (seeds 2000–2019, level
1 % + 2 % · s/19), correct structure: 'none'. Cost: one diagnosis of N = 20 000 samples
(SISO, all candidates) divided by the time of one LPR-ARX fit (identify_arx, nominal structure) of
the same data, for three cases (one without and two with a noise round).

FMU section: the plants of fmu_plants/ with an effect parameter set (experiments and nominal
structures of tests/test_diagnose_fmu.py; tanks poly:3 in the level, also for the na = nb = 1
case), over experiment seeds (input signals and noise draw) and
sensor-noise levels (effect_noise_std, in the output's unit). Same hit definition; model order:
na ≥ 2 (two tanks); scheduling dependence: a polynomial degree ≥ 2 (the physical coefficient
functions are not polynomials). The ADIP cases are closed-loop records (unstable plant, stabilizing
controller): every model is simulated in the identification loop (``diagnose(..., controller=...)``);
friction level within 10 % of F_c / 0.1284 N·m/V, offset within 20 % on both angles.

Run: ``.venv/bin/python benchmarks/bench_diagnose.py [--seeds 10] [--fmu-seeds 5]``
→ results/diagnose.json (``--fmu-seeds 0``: synthetic cases and cost only);
``--fmu-only adip`` runs the ADIP cases alone → results/diagnose_fmu_adip.json
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
from lpvflow.errors import LpvflowError
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

#: label → (effect of make_case, SNR [dB], expected verdict). Structural effects at 30 dB equation noise.
CASES = {
    "input_delay": ("input_delay", 30.0, "input_delay"),
    "model_order": ("model_order", 30.0, "model_order"),
    "scheduling_dependence": ("scheduling_dependence", 30.0, "scheduling_dependence"),
    "scheduling_variable": ("scheduling_variable", 30.0, "scheduling_variable"),
    "dead zone 0.3": ("input_nonlinearity", 30.0, "input_nonlinearity"),
    "friction, position output": ("friction", 30.0, "friction"),
    "offset": ("offset", 30.0, "offset"),
    "friction, velocity output": ("friction_velocity", 30.0, "friction"),
    "backlash 0.3": ("backlash", 30.0, "backlash"),
    "sensor saturation": ("sensor_saturation", 30.0, "sensor_saturation"),
    "AR(2) sensor noise 3 dB": ("ar2_noise", 3.0, "colored_noise"),
    "white sensor noise 10 %": ("sensor_noise", 20.0, "output_noise_bias"),
    "white sensor noise 15 %": ("sensor_noise", -20 * np.log10(0.15), "output_noise_bias"),
    "even input map (out of vocabulary)": ("out_of_vocabulary", 30.0, "unexplained"),
    "none, equation noise 20 dB": ("none", 20.0, "none"),
    "none, equation noise 30 dB": ("none", 30.0, "none"),
}
#: Parameter checked within 20 % per verdict (issue 26).
TOLERANCE = {"input_nonlinearity": "width", "backlash": "width", "friction": "coulomb_level_input_units",
             "offset": "output_offset", "colored_noise": "relative_noise",
             "output_noise_bias": "relative_noise"}


def is_hit(cause: str, result, expected) -> bool:
    """The right verdict with the right parameter (module docstring)."""
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
    if cause == "sensor_saturation":
        return all(v is not None and abs(abs(v) - expected) <= 0.2 * expected
                   for v in (par["lower_limit"], par["upper_limit"]))
    if cause in TOLERANCE:
        return abs(par[TOLERANCE[cause]] - expected) <= 0.2 * abs(expected)
    return True


def _run(effect: str, seed: int, snr: float):
    data, channels, expected = make_case(effect, seed=seed, snr_db=snr)
    t0 = time.perf_counter()
    result = diagnose(data, NOMINAL, channels)
    return result, expected, time.perf_counter() - t0


def hit_rates(seeds: int) -> dict:
    table = {}
    for label, (effect, snr, cause) in CASES.items():
        named, hits, seconds, levels = [], 0, [], []
        for seed in range(seeds):
            result, expected, dt = _run(effect, 1000 + seed, snr)
            hits += bool(is_hit(cause, result, expected))
            named.append(result.cause)
            seconds.append(dt)
            key = TOLERANCE.get(cause)
            if result.cause == cause and key:
                levels.append(result.parameters[key])
        row = {"cause": cause, "snr_db": snr, "hits": hits, "runs": seeds,
               "named": {c: named.count(c) for c in set(named)}, "seconds_per_run": float(np.mean(seconds)),
               "parameter_range": [min(levels), max(levels)] if levels else None}
        table[label] = row
        print(f"{label:36s} {hits}/{seeds}  {row['named']}  {row['parameter_range']}  "
              f"{row['seconds_per_run']:.1f} s/run", flush=True)
    return table


def controls(runs: int = 20) -> dict:
    """White sensor noise of 1–3 %, correct structure: 'none' (module docstring)."""
    named, rows = [], []
    for s in range(runs):
        level = 0.01 + 0.02 * s / max(runs - 1, 1)
        result, _, _ = _run("sensor_noise", 2000 + s, -20 * np.log10(level))
        named.append(result.cause)
        rows.append({"seed": 2000 + s, "relative_noise": level, "cause": result.cause,
                     "bias_p_value": result.noise["bias"]["p_value"] if result.noise else None,
                     "input_explained_gain": result.adequacy["bfr_gain"]})
    out = {"none": named.count("none"), "runs": runs, "named": {c: named.count(c) for c in set(named)},
           "rows": rows}
    print(f"controls (white sensor noise 1–3 %): none {out['none']}/{runs}  {out['named']}", flush=True)
    return out


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
    "airpath pressure noise": ("output_noise_bias", "airpath", {}, AIRPATH, None, [2.0, 4.0, 6.0], {}),
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
                hits += bool(hit)
                named.append(result.cause)
                before.append(np.mean(result.bfr_before))
                after.append(np.mean(result.bfr_after))
                if hit and cause != "none":
                    # a cause named in the noise round is scored there (refit_ranking)
                    noise_verdict = result.cause in ("colored_noise", "output_noise_bias")
                    rows = result.refit_ranking if not noise_verdict else []
                    rows = rows if any(r["cause"] == cause for r in rows) else result.ranking
                    key = "output_noise_bias" if noise_verdict else cause  # the refit's row
                    p_hits.append(next(r for r in rows if r["cause"] == key)["p_value"])
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
    """Seconds of one diagnosis at N = n and its ratio to one LPR-ARX fit of the same data (the
    nominal structure on the whole record), per case; per extension for the first case."""
    from lpvflow.identify.arx import identify_arx

    out = {"N": n}
    for label, effect, snr in (("input_delay", "input_delay", 30.0),
                               ("white sensor noise 10 %", "sensor_noise", 20.0),
                               ("AR(2) sensor noise 3 dB", "ar2_noise", 3.0)):
        data, channels, _ = make_case(effect, seed=7, n=n, snr_db=snr)
        t0 = time.perf_counter()
        identify_arx(data, NOMINAL.na, NOMINAL.nb, NOMINAL.nk, NOMINAL.basis)
        t_arx = time.perf_counter() - t0
        per: dict[str, float] = {}
        original = dict(extensions.EXTENSIONS)
        for name, fn in original.items():
            def timed(ctx, fn=fn, name=name, per=per):
                t0 = time.perf_counter()
                result = fn(ctx)
                per[name] = per.get(name, 0.0) + time.perf_counter() - t0
                return result
            extensions.EXTENSIONS[name] = timed
        try:
            t0 = time.perf_counter()
            result = diagnose(data, NOMINAL, channels)
            total = time.perf_counter() - t0
        finally:
            extensions.EXTENSIONS.update(original)
        out[label] = {"total_s": total, "lpr_arx_fit_s": t_arx, "ratio": total / t_arx, "cause": result.cause,
                      "noise_round": result.noise_round, "per_extension_s": per}
        print(f"N = {n}, {label}: {total:.2f} s = {total / t_arx:.0f} × one LPR-ARX fit ({t_arx:.3f} s); "
              f"cause {result.cause}", flush=True)
    return out


def plant_records(seeds: tuple[int, ...], clean_seeds: tuple[int, ...], plants: list[str] | None = None,
                  effects: list[str] | None = None) -> dict:
    """The plant bench of tests/diagnosis_fmu_cases.py: every record diagnosed as the user would (the
    nominal structure, the controller of closed-loop records); per record the verdict, its outcome
    (:func:`~tests.diagnosis_fmu_cases.outcome`) and the seconds of the diagnosis; rates per kind.
    ``plants``/``effects``: only the records of these plants / whose effect name contains one of these."""
    from tests.diagnosis_fmu_cases import bench_records, make_record, outcome

    rows = []
    for plant, effect, seed in bench_records(seeds, clean_seeds):
        if (plants and plant not in plants) or (effects and not any(e in effect for e in effects)):
            continue
        record = make_record(plant, effect, seed)
        start = time.perf_counter()
        try:
            result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
            cause = result.cause
            verdict = outcome(record, result.cause, result.parameters, result.not_identifiable)
            checked = result.parameters.get(record.check[0]) if record.check else None  # the checked value
        except LpvflowError as exc:
            cause, verdict, checked = f"error: {exc}", "error", None
        seconds = time.perf_counter() - start
        found = None if checked is None else np.asarray(checked, float).tolist()
        rows.append({"record": record.label, "expected": record.expected, "cause": cause, "outcome": verdict,
                     "parameter": found, "samples": record.data.N, "seconds": seconds})
        print(f"{record.label}: expected {record.expected}, named {cause} ({verdict}"
              f"{'' if found is None else f', {record.check[0]} = {found}'}, {seconds:.1f} s)", flush=True)
    kinds = {"in vocabulary": lambda r: r["expected"] not in ("none", "unexplained"),
             "clean": lambda r: r["expected"] == "none",
             "out of vocabulary": lambda r: r["expected"] == "unexplained"}
    rates = {kind: {"right": sum(r["outcome"] == "right" for r in rows if pick(r)),
                    "stated_not_identifiable": sum(r["outcome"] == "not identifiable (stated)"
                                                   for r in rows if pick(r)),
                    "records": sum(1 for r in rows if pick(r))} for kind, pick in kinds.items()}
    worst = max(rows, key=lambda r: r["seconds"])
    return {"seeds": list(seeds), "clean_seeds": list(clean_seeds), "rates": rates,
            "worst": {"record": worst["record"], "seconds": worst["seconds"], "samples": worst["samples"]},
            "records": rows}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--records", type=int, metavar="SEEDS",
                        help="the plant bench (tests/diagnosis_fmu_cases.py) at seeds 0 … SEEDS−1 and clean "
                             "seeds 0 … 4 → results/diagnose_fmu_records.json")
    parser.add_argument("--record-seeds", metavar="LIST",
                        help="with --plant/--effect: the plant bench at these seeds (e.g. 5,6: held out)")
    parser.add_argument("--clean-seeds", metavar="LIST", default="",
                        help="clean-record seeds of a --record-seeds run (default none)")
    parser.add_argument("--plant", action="append", help="plant bench: only this plant (repeatable)")
    parser.add_argument("--effect", action="append",
                        help="plant bench: only effects whose name contains this (repeatable)")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--fmu-seeds", type=int, default=5)
    parser.add_argument("--fmu-only", metavar="PREFIX",
                        help="only the FMU cases whose label starts with PREFIX (e.g. adip) → "
                             "results/diagnose_fmu_PREFIX.json")
    args = parser.parse_args()
    if args.records or args.record_seeds:
        partial = bool(args.record_seeds or args.plant or args.effect)
        seeds = _seeds(args.record_seeds) if args.record_seeds else tuple(range(args.records))
        clean = _seeds(args.clean_seeds) if args.record_seeds else tuple(range(5))
        results = plant_records(seeds, clean, args.plant, args.effect)
        if not partial:  # a selection is printed, never written over the full bench's results
            out = Path(__file__).parent / "results" / "diagnose_fmu_records.json"
            out.write_text(json.dumps(results, indent=1))
        for kind, row in results["rates"].items():
            print(f"{kind}: {row['right']}/{row['records']} right, "
                  f"{row['stated_not_identifiable']} stated not identifiable")
        print(f"worst diagnosis: {results['worst']['seconds']:.1f} s ({results['worst']['record']}, "
              f"N = {results['worst']['samples']})")
        return
    if args.fmu_only:
        results = {"fmu_hit_rates": fmu_hit_rates(args.fmu_seeds, args.fmu_only)}
        out = Path(__file__).parent / "results" / f"diagnose_fmu_{args.fmu_only}.json"
    else:
        results = {"cost": cost(), "hit_rates": hit_rates(args.seeds), "controls": controls(),
                   "fmu_hit_rates": fmu_hit_rates(args.fmu_seeds) if args.fmu_seeds else {}}
        out = Path(__file__).parent / "results" / "diagnose.json"
    out.write_text(json.dumps(results, indent=1))
    if args.fmu_only:
        _print_fmu_table(results)
        return
    print("\n| hidden effect | expected | hits | named | parameter range | s/run |")
    print("|---|---|---|---|---|---|")
    for label, row in results["hit_rates"].items():
        rng = row["parameter_range"]
        print(f"| {label} | {row['cause']} | {row['hits']}/{row['runs']} | "
              + ", ".join(f"{k} {v}" for k, v in sorted(row["named"].items()))
              + f" | {'' if rng is None else f'{rng[0]:.3g}–{rng[1]:.3g}'} | {row['seconds_per_run']:.1f} |")
    _print_fmu_table(results)


def _seeds(text: str) -> tuple[int, ...]:
    return tuple(int(s) for s in text.split(",") if s)


def _print_fmu_table(results: dict) -> None:
    print("\n| FMU case | noise std | hits | named | BFR before → after (median) |\n|---|---|---|---|---|")
    for key, row in results["fmu_hit_rates"].items():
        label = key.split(" @ ")[0]
        print(f"| {label} | {row['noise_std']:g} | {row['hits']}/{row['runs']} | "
              + ", ".join(f"{k} {v}" for k, v in sorted(row["named"].items()))
              + f" | {row['bfr_before_median']:.1f} → {row['bfr_after_median']:.1f} |")


if __name__ == "__main__":
    main()
