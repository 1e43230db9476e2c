"""Rate-bounded stability of the bundled ADIP design's loop (lpvflow.validate.scheduled_stability), next to
how fast its ±70° steps move the arm.

The loop: the design's reduced model frozen at θ(φ1) (the design file's ``[experiment] scheduling``
expressions of the arm angle) with the feedback part of the shipped controller
(:func:`lpvflow.pipeline.robustness.measurement_feedback`, u = K_fb y), p = φ1 in rad, the storage's
breakpoints the controller's (arcsin of its polytope breakpoints in sin φ1), ``--knots`` times finer on
request. :func:`~lpvflow.validate.scheduled_stability.triangular_blocks` splits it; each block is
certified on its own. The peak rate: the largest |φ1(k+1) − φ1(k)| of the plant FMU in the loop of the
same controller on the design's ±70° verify scenarios (fmpy). The ladder: ``--fractions`` of that peak,
ascending, then any rate; it stops at the first rate not certified. One thread, one run.

Run:  .venv/bin/python benchmarks/bench_rate_certificate.py [--design build/design/adip] [--knots 1]
      → benchmarks/results/rate_certificate[_knots<k>].json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import control
import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.experiment.scheduling import evaluate
from lpvflow.models import load
from lpvflow.pipeline.config import bundled_config, load_config
from lpvflow.pipeline.robustness import measurement_feedback
from lpvflow.pipeline.verify import simulate_loop
from lpvflow.synth.rate_bounded import segment_grid
from lpvflow.validate.scheduled_stability import largest_certified_rate, triangular_blocks

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--design", default=str(ROOT / "build" / "design" / "adip"))
    parser.add_argument("--knots", type=int, default=1, help="storage breakpoints per controller interval")
    parser.add_argument("--fractions", type=float, nargs="+", default=[1 / 16, 1 / 4, 1.0])
    args = parser.parse_args()
    os.chdir(ROOT)  # the design file's plant path is relative to the repository
    config = load_config(bundled_config("adip"))
    folder = Path(args.design)
    model, controller = load(folder / "model.json"), load(folder / "controller.json")
    expressions = list(config["experiment"]["scheduling"].values())

    def theta(phi: float) -> np.ndarray:
        return np.array([float(evaluate(e, {"arm_angle": np.array([phi])})[0]) for e in expressions])

    def loop_at(phi: float) -> np.ndarray:
        G = model.frozen(theta(phi))
        plant = control.ss(G.A, G.B, G.C, G.D, model.Ts)
        return np.asarray(control.feedback(plant, measurement_feedback(controller, theta(phi)), sign=+1).A)

    peaks = {}
    for scenario in config["verify"]["scenario"]:
        if "70" in scenario.name and "perturbed" not in scenario.name:
            run = simulate_loop(controller, config["design"]["plant"], scenario, config["verify"]["loop"])
            arm = run.outputs[:, run.measured.index("arm_angle")]
            peaks[scenario.name] = float(np.max(np.abs(np.diff(arm))))
    peak = max(peaks.values())
    breakpoints = segment_grid(np.arcsin(np.asarray(controller.polytope.breakpoints)), args.knots)
    rates = [f * peak for f in sorted(args.fractions)] + [None]
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        blocks = triangular_blocks([loop_at(p) for p in segment_grid(breakpoints, 10)])
        ladder = largest_certified_rate(loop_at, breakpoints, rates)
    seconds = time.perf_counter() - start

    def per_second(rate: float | None) -> float | None:
        return None if rate is None else float(np.rad2deg(rate) / model.Ts)

    out = {"peak_rate_rad_per_sample": peaks, "peak_deg_per_s": {k: per_second(v) for k, v in peaks.items()},
           "storage_breakpoints": len(breakpoints), "blocks": [len(b) for b in blocks],
           "ladder_deg_per_s": [per_second(r) for r in rates],
           "results": [{"rate_deg_per_s": per_second(r), "certified": res.certified, "reason": res.reason,
                        "seconds": res.seconds,
                        "blocks": [None if b is None else
                                   {"states": len(b.states), "t": b.t, "margin": b.margin,
                                    "where_deg": float(np.rad2deg(b.where))} for b in res.blocks]}
                       for r, res in zip(rates, ladder.results, strict=False)],
           "largest_certified_deg_per_s": per_second(ladder.largest), "seconds": seconds}
    name = "rate_certificate" + ("" if args.knots == 1 else f"_knots{args.knots}") + ".json"
    (ROOT / "benchmarks" / "results" / name).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
