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
4. Data to ±75°: what an identification experiment under a gain-scheduled controller would give. On the
   nonlinear equations (bench_adip_reach.nonlinear_run; the FMU experiment runner holds only LTI
   controllers), the full-state scheduled LQR of bench_adip_reach section 5 (weights (100, 300, 0.3))
   tracks a slow arm set-point 75° sin(2π t / 40 s) with the section 1 multisine (1 V rms) added to its
   voltage, 120 s. LPR-ARX fits as in section 1 with the affine, poly:2 and poly:4 bases in sin φ1, affine
   in cos φ1 and affine in (sin φ1, cos φ1), frozen poles to 75°. Caveat: a model identified over a wide
   range is a quasi-LPV description of the nonlinear plant, whose frozen models need not equal the
   linearizations (the arm's gravity torque sin φ1 can be carried by a coefficient sin φ1 / φ1 on φ1 —
   a secant, not the tangent cos φ1), so the pole comparison weakens as the angle grows. Then the
   pipeline's synthesis (common Lyapunov matrix, bundled weights) on the poly:2 model over
   sin φ1 ∈ [−0.5, 0.5], with the spectral radius of its polytope's vertex plants; and, to tell the
   polytope's over-bound from the model's variation, the frozen H∞ optimum (SB10DD Riccati, no LMI: the
   LMI γ of single ADIP points is known to be inaccurate, bench_adip_oracle) at three points and at the
   triangle's middle vertex, and the synthesis on tangent polygons of 2 and 4 segments (5 and 9 vertices).

Run: .venv/bin/python benchmarks/bench_adip_scheduling.py   → results/adip_scheduling.json (≈ 4 minutes)
"""

from __future__ import annotations

import itertools
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
from lpvflow.errors import LpvflowError, ModelError  # noqa: E402
from lpvflow.experiment import run_fmu_experiment, signals  # noqa: E402
from lpvflow.experiment.controller import LtiController  # noqa: E402
from lpvflow.identify.arx import identify_arx, prediction_residuals  # noqa: E402
from lpvflow.pipeline.stages import without_offsets  # noqa: E402
from lpvflow.synth.certify import riccati_gamma  # noqa: E402
from lpvflow.synth.lmi_hinf import synthesize  # noqa: E402
from lpvflow.synth.plant import (  # noqa: E402
    GeneralizedPlant,
    VertexPlant,
    augment,
    check_a3,
    generalized_plant,
    weight_systems,
)
from lpvflow.synth.polytope import Polytope, polytope_of, vertex_matrices  # noqa: E402
from lpvflow.synth.sdp import SynthesisError  # noqa: E402

FMU = ROOT / "fmu_plants" / "build" / "adip.fmu"
P = rm.default_parameters("adip")
TS, DURATION, SEED, SPLIT = 0.005, 120.0, 1, 0.7
SCHEDULING = {"sin_arm": "sin(arm_angle)", "cos_arm": "cos(arm_angle)"}
ANGLES_DEG = (0, 30, 45, 60)
DESIGN_ANGLES_DEG = (0, 30, 45, 50, 55, 60, 65, 70)
WIDE_DESIGN_DEG = 50
#: Section 4: set-point amplitude (°) and period (s), multisine rms (V), scheduled-LQR weights, fits, box.
SWEEP_DEG, SWEEP_PERIOD, SWEEP_RMS, SWEEP_WEIGHTS = 75.0, 40.0, 1.0, (100, 300, 0.3)
SWEEP_ANGLES_DEG = (0, 30, 45, 60, 75)
SWEEP_FITS = ((["sin_arm"], "affine"), (["sin_arm"], "poly:2"), (["sin_arm"], "poly:4"),
              (["cos_arm"], "affine"), (["sin_arm", "cos_arm"], "affine"))
SWEEP_BOX = 0.5
TANGENT_SEGMENTS = (2, 4)


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


#: Scheduling signals as functions of the arm angle.
FUNCTIONS = {"sin_arm": np.sin, "cos_arm": np.cos}


def fit(columns: dict, names: list[str], basis: str, angles: tuple[int, ...]) -> dict:
    """LPR-ARX (na = nb = 2, nk = 1) scheduled on ``names`` (keys of FUNCTIONS, columns of ``columns``):
    scheduling range, one-step BFR on the last 30 % and the frozen unstable poles at ``angles`` (°)."""
    data = Dataset.from_columns(columns, "adip", ["voltage"], ["arm_angle", "pendulum_angle"], names,
                                time="time")
    est, val = data.split(SPLIT)
    est, val = without_offsets(est, est), without_offsets(val, est)
    io = identify_arx(est, 2, 2, 1, basis)
    residuals = prediction_residuals(io, val)
    y = val.y[io.max_lag :]
    one_step = 100 * (1 - np.linalg.norm(residuals, axis=0) / np.linalg.norm(y - y.mean(axis=0), axis=0))
    ss = io.to_ss()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        poles = {deg: unstable_poles(ss.matrices(np.array([FUNCTIONS[n](np.deg2rad(deg)) for n in names]))[0])
                 for deg in angles}
    return {"range": np.column_stack([est.p.min(axis=0), est.p.max(axis=0)]).squeeze().tolist(),
            "one_step_bfr": one_step.tolist(), "unstable_poles_rad_s": poles, "model": ss}


def fits(record) -> dict:
    """Section 1 on one record: per scheduling variable, range, one-step BFR and frozen unstable poles."""
    out = {}
    for name in SCHEDULING:
        row = fit(record.columns, [name], "affine", ANGLES_DEG)
        row.pop("model")
        out[name] = row
    return out


def sweep() -> dict:
    """Section 4: data to ±75° under the scheduled LQR and a slow set-point sweep; fits; synthesis."""
    lqr = reach.scheduled_lqr(SWEEP_WEIGHTS)
    n = round(DURATION / TS)
    excitation = signals.multisine(n, TS, 0.02, 20.0, rms=SWEEP_RMS, rng=np.random.default_rng(SEED))
    amplitude = np.deg2rad(SWEEP_DEG)

    def law(k: int, x: np.ndarray) -> float:
        return lqr(x, amplitude * np.sin(2 * np.pi * k * TS / SWEEP_PERIOD)) + excitation[k]

    rows, lost_at = reach.nonlinear_run(law, DURATION, lambda k, x: abs(x[1]) > 0.5)
    if lost_at is not None:
        return {"pendulum_lost_at_s": lost_at}
    t, arm, pendulum, voltage = rows.T
    columns = {"time": t, "voltage": voltage, "arm_angle": arm, "pendulum_angle": pendulum}
    columns |= {name: f(arm) for name, f in FUNCTIONS.items()}
    out: dict = {"arm_deg": [float(np.rad2deg(arm.min())), float(np.rad2deg(arm.max()))],
                 "max_pendulum_deg": float(np.rad2deg(np.abs(pendulum).max())),
                 "peak_voltage": float(np.abs(voltage).max()), "fits": {}}
    for names, basis in SWEEP_FITS:
        row = fit(columns, names, basis, SWEEP_ANGLES_DEG)
        model = row.pop("model")
        out["fits"][f"{' and '.join(names)}, {basis}"] = row
        if (names, basis) == (["sin_arm"], "poly:2"):
            quadratic = model
    box = [[-SWEEP_BOX, SWEEP_BOX]]
    polytope = polytope_of(quadratic, box)
    synthesis = {"box": box, "polytope": polytope.kind,
                 "vertex_spectral_radius": [float(np.max(np.abs(np.linalg.eigvals(A))))
                                            for A, *_ in vertex_matrices(quadratic, polytope)]}
    synthesis["gamma"] = common_gamma(generalized_plant(quadratic, reach.bundled_weights(), box))
    # what makes it infeasible: the frozen optimum (Riccati, LMI-free) at three points and at the triangle's
    # middle vertex ψ = (0, −0.25) (p² < 0: not a plant), and tighter tangent polygons around the parabola
    synthesis["frozen_riccati_gamma"] = {p: riccati_optimum(vertex_plants(quadratic, [[1.0, p, p * p]], box))
                                         for p in (-SWEEP_BOX, 0.0, SWEEP_BOX)}
    synthesis["middle_vertex_riccati_gamma"] = riccati_optimum(
        vertex_plants(quadratic, [[1.0, 0.0, -SWEEP_BOX**2]], box))
    synthesis["tangent_polygon_gamma"] = {
        m: common_gamma(vertex_plants(quadratic, tangent_polygon(*box[0], m), box)) for m in TANGENT_SEGMENTS}
    out["poly2_synthesis"] = synthesis
    return out


def common_gamma(plant: GeneralizedPlant) -> float | str:
    """γ of the pipeline's common-Lyapunov synthesis, or the reason it fails."""
    try:
        return float(synthesize(plant, "common").gamma)
    except SynthesisError as exc:
        return str(exc)


def tangent_polygon(a: float, b: float, segments: int) -> np.ndarray:
    """ψ = (1, p, q) vertices of the polygon bounded by the chord of q = p² over [a, b] and its tangents at
    ``segments`` + 1 equally spaced points (tangents at s, s' meet at ((s + s')/2, s s')); it contains the
    parabola arc and over-bounds p² by at most ((b − a) / segments)² / 4 (1 segment: the triangle)."""
    t = np.linspace(a, b, segments + 1)
    points = [(t[0], t[0] ** 2)]
    for s0, s1 in itertools.pairwise(t):
        points += [(0.5 * (s0 + s1), s0 * s1), (s1, s1**2)]
    return np.array([[1.0, p, q] for p, q in points])


def vertex_plants(model, psi_vertices, box: list) -> GeneralizedPlant:
    """The generalized plants (bundled weights) of ``model`` at the given ψ vertices."""
    W = weight_systems(reach.bundled_weights(), model.ny, model.nu, model.Ts)
    polytope = Polytope("box", np.array(box), np.array(psi_vertices, dtype=float))  # labels the vertices
    vertices = [VertexPlant.from_ss(augment(control.ss(*M, model.Ts), W, model.Ts), nw=model.ny,
                                    nz=model.ny + model.nu) for M in vertex_matrices(model, polytope)]
    check_a3(vertices)
    z_names = ["W_S e[0]", "W_S e[1]", "W_K u[0]"]
    return GeneralizedPlant(vertices, polytope, model.Ts, model.nx, z_names, W.get("B"))


def riccati_optimum(plant: GeneralizedPlant) -> float | str:
    """The frozen H∞ optimum of a one-vertex plant by SB10DD (lpvflow.synth.certify.riccati_gamma, up to
    γ = 1000), or why there is none."""
    try:
        return riccati_gamma(plant.vertices[0], plant.Ts, hi=1000.0)
    except ModelError as exc:
        return str(exc)


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
    results["exact_unstable_poles_rad_s"][75] = unstable_poles(reach.linearised(np.deg2rad(75)).A)
    results["sweep_to_75_deg"] = sweep()
    results["wall_seconds"] = time.perf_counter() - start
    out = ROOT / "benchmarks" / "results" / "adip_scheduling.json"
    out.write_text(json.dumps(results, indent=1) + "\n")
    print(json.dumps({k: v for k, v in results.items()}, indent=1))


if __name__ == "__main__":
    main()
