"""Experiment tooling performance, measured as ratios in one run (issue 4, item 4).

1. Experiment loop throughput (steps/s) of ``run_fmu_experiment`` — signals, controller law,
   recording, scheduling column — against a bare ``lpvflow.fmu`` loop on the same FMU that only
   sets a precomputed input and steps (the floor any Python-side loop pays): tanks open loop and
   adip closed loop with its stabilising controller.
2. CSV writing (shortest round-trip floats, ``csv_text``) against ``numpy.savetxt(fmt="%.17g")``.
3. Signal generation throughput: multisine (Schroeder, 200 lines) and APRBS, samples/s; one period
   of the order-18 m-sequence (262 143 bits, Python LFSR).

Run: ``.venv/bin/python benchmarks/bench_experiment.py`` → benchmarks/results/experiment.json
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from timing import best_of

from lpvflow.experiment import run_fmu_experiment
from lpvflow.experiment.record import csv_text
from lpvflow.experiment.signals import aprbs, mls_bits, multisine
from lpvflow.fmu import open_fmu

ROOT = Path(__file__).resolve().parents[1]
CONTROLLER = ROOT / "fmu_plants" / "adip" / "stabilizing_controller.json"
TANKS_INPUT = {"pump_voltage": "aprbs:lo=2,hi=8,min_hold=10,max_hold=60"}


def fmu_path(name: str) -> Path:
    path = ROOT / "fmu_plants" / "build" / f"{name}.fmu"
    if not path.is_file():
        subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py"), name], check=True)
    return path


def bare_loop(path: Path, u: np.ndarray, Ts: float) -> None:
    plant = open_fmu(path)
    try:
        for value in u:
            plant.step((value,), Ts)
    finally:
        plant.close()


def bench_loop(name: str, Ts: float, n: int, **experiment) -> dict:
    path = fmu_path(name)
    rec = run_fmu_experiment(path, Ts, n * Ts, progress=False, **experiment)
    u = rec.columns[rec.metadata["columns"]["inputs"][0]]
    t_ours = best_of(lambda: run_fmu_experiment(path, Ts, n * Ts, progress=False, **experiment))
    t_bare = best_of(lambda: bare_loop(path, u, Ts))
    return {"plant": name, "mode": rec.metadata["mode"], "steps": n, "Ts": Ts,
            "time_experiment_s": t_ours, "time_bare_fmu_loop_s": t_bare,
            "steps_per_s": n / t_ours, "bare_steps_per_s": n / t_bare, "time_ratio": t_ours / t_bare}


def bench_csv(n: int = 200_000) -> dict:
    path = fmu_path("tanks")
    rec = run_fmu_experiment(path, 0.2, n * 0.2, inputs=TANKS_INPUT, progress=False)
    table = np.column_stack(list(rec.columns.values()))
    t_ours = best_of(lambda: csv_text(rec))
    t_savetxt = best_of(lambda: np.savetxt(io.StringIO(), table, fmt="%.17g", delimiter=","))
    return {"rows": n, "columns": table.shape[1], "time_csv_text_s": t_ours, "time_savetxt_s": t_savetxt,
            "rows_per_s": n / t_ours, "time_ratio": t_ours / t_savetxt}


def bench_signals(n: int = 1_000_000) -> dict:
    rng = np.random.default_rng(0)
    t_ms = best_of(lambda: multisine(n, 0.001, 1.0, 200.0, period=n, rms=1.0))  # 200 lines over n samples
    t_aprbs = best_of(lambda: aprbs(n, -1.0, 1.0, 5, 50, rng))
    t_mls = best_of(lambda: mls_bits(18, rng))
    return {"n": n, "multisine_lines": 200, "multisine_samples_per_s": n / t_ms,
            "aprbs_samples_per_s": n / t_aprbs, "mls_order18_s": t_mls}


def main() -> None:
    results = {
        "tanks_open_loop": bench_loop("tanks", 0.2, 50_000, inputs=TANKS_INPUT),
        "adip_closed_loop": bench_loop("adip", 0.005, 20_000, controller=CONTROLLER,
                                       excitation={"voltage": "multisine:f_lo=0.1,f_hi=5,rms=0.5"}),
        "csv": bench_csv(),
        "signals": bench_signals(),
    }
    out = Path(__file__).parent / "results" / "experiment.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print("| measurement | ours | baseline (same run) | ratio |")
    print("|---|---|---|---|")
    for key in ("tanks_open_loop", "adip_closed_loop"):
        r = results[key]
        print(f"| `lpvflow experiment` {r['plant']} {r['mode']}, {r['steps']} steps "
              f"| {r['steps_per_s']:,.0f} steps/s | bare `lpvflow.fmu` step loop "
              f"{r['bare_steps_per_s']:,.0f} steps/s | {r['time_ratio']:.2f}× time |")
    c, s = results["csv"], results["signals"]
    print(f"| CSV writing, {c['rows']} rows × {c['columns']} columns | {c['rows_per_s']:,.0f} rows/s "
          f"| `numpy.savetxt` %.17g: {c['time_savetxt_s']:.2f} s | {c['time_ratio']:.2f}× time |")
    rate = s["multisine_samples_per_s"] / 1e6
    print(f"| multisine, 200 lines, 10⁶ samples | {rate:.1f}·10⁶ samples/s | — | — |")
    print(f"| APRBS, 10⁶ samples | {s['aprbs_samples_per_s'] / 1e6:.1f}·10⁶ samples/s | — | — |")
    print(f"| m-sequence order 18 (262 143 bits) | {s['mls_order18_s']:.2f} s | — | — |")


if __name__ == "__main__":
    main()
