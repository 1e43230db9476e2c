"""Rate-bounded gain-scheduled H∞ synthesis (lpvflow.synth.rate_bounded): wall time as a ratio to one
solve of its SDP, and γ against the frozen lower bound (issue 23's benchmark).

Cases: ``random_lpv(3, nx, n_p=1, nu=1, ny=1)`` on p ∈ [−1, 1] with W_S (integral action) and a
strictly proper W_B (two states): 3 breakpoints with nx = 2 (generalized plant of order 4), rate bound
0.02 per sample and any rate; 2 breakpoints with nx = 6 (order 8: no level certified, recorded as
such). Issue 23's case, 11 breakpoints at order 8, does not finish in reasonable time
(benchmarks/README.md). The breakpoints form a
piecewise polytope over the affine model, so the plant is exact between them.

``ratio`` = the synthesis' wall time / the wall time of one Clarabel solve of its margin SDP (the
maximisation of t at one γ level, timed around the solver call in the same run): the floor of any
synthesis that has to solve these LMIs once. One thread (OPENBLAS_NUM_THREADS=1 is set below), one run.

Run:  .venv/bin/python benchmarks/bench_rate_bounded.py   → benchmarks/results/rate_bounded.json
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from lpvflow.synth import rate_bounded
from lpvflow.synth.examples import random_lpv
from lpvflow.synth.plant import generalized_plant

OUT = Path(__file__).parent / "results" / "rate_bounded.json"
WEIGHTS = {"S": {"bandwidth": 1.0, "hf_gain": 2.0}, "K": {"num": [0.05], "den": [1]},
           "B": {"num": [0, 0.4], "den": [1, -0.6]}, "integrator_shift": 1e-3}


def measure(nx: int, breakpoints: int, rate_bound: float | None) -> dict:
    model = random_lpv(3, nx=nx, n_p=1, nu=1, ny=1)
    plant = generalized_plant(model, WEIGHTS, [[-1.0, 1.0]], breakpoints=np.linspace(-1.0, 1.0, breakpoints))
    solves = []
    inner = rate_bounded.solve

    def timed(problem, solver, what):
        start = time.perf_counter()
        out = inner(problem, solver, what)
        if " at γ = " in what:
            solves.append(time.perf_counter() - start)
        return out

    rate_bounded.solve = timed
    row = {"rate_bound": rate_bound, "order": plant.dims[0], "breakpoints": breakpoints,
           "lmis": sum(len(nexts) for _, nexts in rate_bounded.Schedule(
               np.linspace(-1.0, 1.0, breakpoints), rate_bound).pairs())}
    start = time.perf_counter()
    try:
        result, _ = rate_bounded.synthesize_rate_bounded(plant, rate_bound)
    except rate_bounded.SynthesisError as exc:
        return row | {"error": str(exc)[:300], "seconds": time.perf_counter() - start,
                      "level_solves": len(solves), "one_sdp_seconds": min(solves)}
    finally:
        rate_bounded.solve = inner
    seconds = time.perf_counter() - start
    return row | {
            "gamma": result.gamma, "frozen_lower_bound": result.gamma_min, "seconds": seconds,
            "level_solves": len(solves), "one_sdp_seconds": min(solves), "ratio": seconds / min(solves)}


def main() -> None:
    rows = [measure(2, 3, 0.02), measure(2, 3, None), measure(6, 2, 0.02)]
    OUT.write_text(json.dumps({"rows": rows}, indent=1, default=float) + "\n")
    heads = ("ν", "n", "bps", "LMIs", "γ", "frozen", "s", "solves", "SDP s", "ratio")
    print(" ".join(f"{h:>7}" for h in heads))
    for r in rows:
        nu = "any" if r["rate_bound"] is None else f"{r['rate_bound']:g}"
        if "error" in r:
            print(f"{nu:>7} {r['order']:>7} {r['breakpoints']:>7} {r['lmis']:>7}  {r['seconds']:.0f} s, "
                  f"{r['level_solves']} solves of ≥ {r['one_sdp_seconds']:.1f} s: {r['error']}")
            continue
        print(f"{nu:>7} {r['order']:>7} {r['breakpoints']:>7} {r['lmis']:>7} {r['gamma']:7.4g} "
              f"{r['frozen_lower_bound']:7.4g} {r['seconds']:7.1f} {r['level_solves']:>7} "
              f"{r['one_sdp_seconds']:7.2f} {r['ratio']:7.1f}")


if __name__ == "__main__":
    main()
