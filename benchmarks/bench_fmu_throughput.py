"""Co-simulation throughput of the FMU plants through fmpy's instance API (not simulate_fmu).

For every plant: steps per second of a loop that sets new inputs, calls fmi2DoStep and reads the
measured outputs every communication step, (a) through `lpvflow.fmu.FmuPlant.step` (prebuilt value
references and ctypes buffers) and (b) through fmpy's convenience methods `setReal/doStep/getReal`
with Python lists. The floor is three ctypes calls per step into an FMU that do no work (empty
fmi2SetReal/fmi2GetReal, fmi2GetStatus instead of fmi2DoStep), i.e. the per-step cost of Python +
ctypes alone; `floor ratio` = floor rate / plant rate (1 = the plant costs nothing beyond the calls).

Run: .venv/bin/python benchmarks/bench_fmu_throughput.py   (writes benchmarks/results/fmu_throughput.json)
"""

from __future__ import annotations

import ctypes
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from lpvflow.fmu import open_fmu

ROOT = Path(__file__).resolve().parents[1]
STEPS = 20_000
REPEATS = 3
#: communication step and a representative input sequence per plant
CASES = {
    "adip": (0.005, lambda k: np.c_[0.5 * np.sin(0.01 * k)]),
    "maglev": (0.002, lambda k: np.c_[0.93 + 0.02 * np.sin(0.01 * k), -0.045 + 0.02 * np.cos(0.01 * k)]),
    "airpath": (0.01, lambda k: np.c_[25 + 5 * np.sin(0.01 * k), 80 + 0 * k, 2500 + 0 * k]),
    "tanks": (0.2, lambda k: np.c_[8.0 + np.sin(0.01 * k)]),
}
GOALS = {"tanks": 50_000, "adip": 20_000}


def best_rate(loop) -> float:
    """Steps per CPU second of the fastest of REPEATS runs of `loop()` (which makes STEPS steps).

    CPU time of this process, so that other jobs on a shared machine do not distort the ratio.
    """
    best = np.inf
    for _ in range(REPEATS):
        start = time.process_time()
        loop()
        best = min(best, time.process_time() - start)
    return STEPS / best


def lpvflow_rate(path: Path, dt: float, inputs: np.ndarray) -> float:
    rows = list(inputs)  # one numpy row per step, as a controller loop would produce
    with open_fmu(path) as plant:
        def loop() -> None:
            plant.reset()
            for u in rows:
                plant.step(u, dt)
        return best_rate(loop)


def fmpy_rate(path: Path, dt: float, inputs: np.ndarray) -> float:
    with open_fmu(path) as plant:
        slave = plant._slave
        in_vr = [plant._variables[n].valueReference for n in plant.input_names]
        out_vr = [plant._variables[n].valueReference for n in plant.output_names]
        rows = inputs.tolist()

        def loop() -> None:
            plant.reset()
            t = 0.0
            for u in rows:
                slave.setReal(in_vr, u)
                slave.doStep(t, dt)
                slave.getReal(out_vr)
                t += dt
        return best_rate(loop)


def floor_rate(path: Path) -> float:
    """Three ctypes calls per step into the FMU that do no work (empty set/get, a status query)."""
    with open_fmu(path) as plant:
        component, set_real, get_real = plant._component, plant._set_real, plant._get_real
        status = plant._slave._functions["fmi2GetStatus"]
        refs, values, value = (ctypes.c_uint * 1)(), (ctypes.c_double * 1)(), ctypes.c_int()
        holder = np.zeros(1)

        def loop() -> None:
            for _ in range(STEPS):
                set_real(component, refs, 0, values)
                status(component, 0, ctypes.byref(value))
                get_real(component, refs, 0, values)
                holder.copy()
        return best_rate(loop)


def main() -> None:
    subprocess.run([sys.executable, str(ROOT / "fmu_plants" / "build.py")], check=True, capture_output=True)
    build = ROOT / "fmu_plants" / "build"
    floor = floor_rate(build / "tanks.fmu")
    results = {"steps": STEPS, "repeats": REPEATS, "python": platform.python_version(),
               "machine": platform.machine(), "floor_steps_per_s": floor, "plants": {}}
    for name, (dt, make_inputs) in CASES.items():
        inputs = make_inputs(np.arange(STEPS))
        rate = lpvflow_rate(build / f"{name}.fmu", dt, inputs)
        results["plants"][name] = {
            "communication_step_s": dt,
            "lpvflow_steps_per_s": rate,
            "fmpy_list_api_steps_per_s": fmpy_rate(build / f"{name}.fmu", dt, inputs),
            "floor_ratio": floor / rate,
            "goal_steps_per_s": GOALS.get(name),
        }
    target = ROOT / "benchmarks" / "results" / "fmu_throughput.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(results, indent=1) + "\n")
    print(f"FMU co-simulation throughput ({STEPS} steps, best of {REPEATS}); "
          f"floor (do-nothing FMU calls): {floor:,.0f} steps/s\n")
    print("| plant | step [s] | lpvflow.fmu [steps/s] | fmpy setReal/doStep/getReal [steps/s] "
          "| floor ratio | goal |")
    print("|---|---|---|---|---|---|")
    for name, r in results["plants"].items():
        goal = f"≥ {r['goal_steps_per_s']:,}" if r["goal_steps_per_s"] else "–"
        print(f"| {name} | {r['communication_step_s']} | {r['lpvflow_steps_per_s']:,.0f} | "
              f"{r['fmpy_list_api_steps_per_s']:,.0f} | {r['floor_ratio']:.2f} | {goal} |")


if __name__ == "__main__":
    main()
