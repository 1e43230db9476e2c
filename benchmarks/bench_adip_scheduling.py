"""Which scheduling variable and which data could give the ADIP design a real LPV model? (issue 7)

1. Frozen poles of LPR-ARX models (na = nb = 2, nk = 1, affine basis, estimation = first 70 % with its
   mean removed, as the bundled design's identify stage) against the exact linearization of
   fmu_plants/reference_models.py at the same arm angle: scheduled on sin φ1 (the bundled choice) and on
   cos φ1 (what the linearization depends on: the plant is odd-symmetric, its linearization even in φ1).
   Data: the bundled experiment (lpvflow/pipeline/examples/adip.toml: its LTI controller, designed at
   0°, 1.5 V rms multisine 0.02–20 Hz, 120 s, seed 1) and the same experiment under a controller with
   the same weights designed at 50° (wider arm range). Also the one-step BFR on the last 30 %.
2. Identification controllers (fmu_plants/adip/stabilizing_controller.design with design_angle): the
   largest arm angle (5° grid) up to which every frozen loop with the exact ZOH linearizations is stable.
3. FMU experiments under the 50° controller: arm range and largest pendulum angle, per excitation rms
   (or the error when the pendulum is lost).

Run: .venv/bin/python benchmarks/bench_adip_scheduling.py   → results/adip_scheduling.json (≈ 15 s)
"""

from __future__ import annotations

import json
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import control
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "fmu_plants"))
sys.path.insert(0, str(ROOT / "fmu_plants" / "adip"))
import bench_adip_reach as reach  # noqa: E402  (same TS and plant parameters)
import reference_models as rm  # noqa: E402
import stabilizing_controller  # noqa: E402

from lpvflow.basis import SchedulingRangeWarning  # noqa: E402
from lpvflow.data import Dataset  # noqa: E402
from lpvflow.errors import LpvflowError  # noqa: E402
from lpvflow.experiment import run_fmu_experiment  # noqa: E402
from lpvflow.experiment.controller import LtiController  # noqa: E402
from lpvflow.identify.arx import identify_arx, prediction_residuals  # noqa: E402
from lpvflow.pipeline.stages import without_offsets  # noqa: E402

FMU = ROOT / "fmu_plants" / "build" / "adip.fmu"
P = rm.default_parameters("adip")
TS, DURATION, SEED, SPLIT = 0.005, 120.0, 1, 0.7
SCHEDULING = {"sin_arm": "sin(arm_angle)", "cos_arm": "cos(arm_angle)"}
ANGLES_DEG = (0, 30, 45, 60)
DESIGN_ANGLES_DEG = (0, 30, 45, 50, 55, 60, 65, 70)
WIDE_DESIGN_DEG = 50


def controller(design_deg: float) -> LtiController:
    doc = stabilizing_controller.design(P, np.deg2rad(design_deg))
    return LtiController(*(np.asarray(doc[k], float) for k in "ABCD"), doc["Ts"], tuple(doc["inputs"]),
                         tuple(doc["outputs"]), np.asarray(doc["y_operating_point"], float),
                         np.asarray(doc["u_operating_point"], float))


def unstable_poles(A: np.ndarray) -> list[float]:
    """Continuous-time equivalents log(z)/Ts of the discrete poles outside the unit circle (rad/s)."""
    s = np.log(np.linalg.eigvals(A).astype(complex)) / TS
    return sorted(float(v.real) for v in s if v.real > 0 and abs(v.imag) < 1e-9)


def experiment(design_deg: float, rms: float) -> dict:
    excitation = {"voltage": f"multisine:f_lo=0.02,f_hi=20,rms={rms}"}
    try:
        record = run_fmu_experiment(FMU, TS, DURATION, controller=controller(design_deg),
                                    excitation=excitation, scheduling_columns=SCHEDULING, seed=SEED,
                                    progress=False)
    except LpvflowError as exc:
        return {"design_deg": design_deg, "rms": rms, "error": str(exc)}
    arm, pendulum = (np.rad2deg(record.columns[c]) for c in ("arm_angle", "pendulum_angle"))
    return {"design_deg": design_deg, "rms": rms, "arm_deg": [float(arm.min()), float(arm.max())],
            "max_pendulum_deg": float(np.abs(pendulum).max()), "record": record}


def fits(record) -> dict:
    """Section 1 on one record: per scheduling variable, range, one-step BFR and frozen unstable poles."""
    out = {}
    for name in SCHEDULING:
        data = Dataset.from_columns(record.columns, "adip", ["voltage"], ["arm_angle", "pendulum_angle"],
                                    [name], time="time")
        est, val = data.split(SPLIT)
        est, val = without_offsets(est, est), without_offsets(val, est)
        io = identify_arx(est, 2, 2, 1, "affine")
        residuals = prediction_residuals(io, val)
        y = val.y[io.max_lag :]
        one_step = 100 * (1 - np.linalg.norm(residuals, axis=0) / np.linalg.norm(y - y.mean(axis=0), axis=0))
        ss = io.to_ss()
        functions = {"sin_arm": np.sin, "cos_arm": np.cos}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SchedulingRangeWarning)
            poles = {deg: unstable_poles(ss.matrices(np.array([functions[name](np.deg2rad(deg))]))[0])
                     for deg in ANGLES_DEG}
        out[name] = {"range": [float(est.p.min()), float(est.p.max())], "one_step_bfr": one_step.tolist(),
                     "unstable_poles_rad_s": poles}
    return out


def stable_up_to(design_deg: float) -> int | None:
    """Section 2: the largest angle of the 5° grid up to which the frozen loops are all stable (None:
    not even at 0°)."""
    doc = stabilizing_controller.design(P, np.deg2rad(design_deg))
    K = control.ss(*(np.asarray(doc[k], float) for k in "ABCD"), TS)
    reached = None
    for deg in range(0, 90, 5):
        if reach.frozen_radius(K, np.deg2rad(deg), +1) >= 1:
            break
        reached = deg
    return reached


def main() -> None:
    start = time.perf_counter()
    exact = {deg: unstable_poles(reach.linearised(np.deg2rad(deg)).A) for deg in ANGLES_DEG}
    results: dict = {"exact_unstable_poles_rad_s": exact, "fits": {}, "experiments": []}
    for design_deg in (0, WIDE_DESIGN_DEG):
        run = experiment(design_deg, 1.5)
        results["fits"][f"controller designed at {design_deg} deg"] = fits(run.pop("record"))
        results["experiments"].append(run)
    for rms in (1.0, 2.5):
        run = experiment(WIDE_DESIGN_DEG, rms)
        run.pop("record", None)
        results["experiments"].append(run)
    results["frozen_stable_up_to_deg"] = {d: stable_up_to(d) for d in DESIGN_ANGLES_DEG}
    results["wall_seconds"] = time.perf_counter() - start
    out = ROOT / "benchmarks" / "results" / "adip_scheduling.json"
    out.write_text(json.dumps(results, indent=1) + "\n")
    print(json.dumps({k: v for k, v in results.items()}, indent=1))


if __name__ == "__main__":
    main()
