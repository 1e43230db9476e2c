"""Rate-bounded gain-scheduled H∞ synthesis (lpvflow.synth.rate_bounded): wall time as a ratio to one
solve of its SDP, and γ against the frozen lower bound (issue 23's benchmark).

Cases: ``random_lpv(3, nx, n_p=1, nu=1, ny=1)`` on p ∈ [−1, 1] with W_S (integral action) and a
strictly proper W_B (two states): 3 breakpoints with nx = 2 (generalized plant of order 4), rate bound
0.02 per sample and any rate; 2 breakpoints with nx = 6 (order 8: no level certified, recorded as
such). Issue 23's case, 11 breakpoints at order 8, does not finish in reasonable time
(benchmarks/README.md). The breakpoints form a
piecewise polytope over the affine model, so the plant is exact between them.

The limit on the ADIP (issue 23's ±75° test): the exact linearizations at −75°, 0°, 75° with the bundled
weights (1-DOF, ``tests/adip_cases.py``), breakpoints at sin φ1, and the largest margin t of the LMIs
(Φ ⪰ t·I, t ≤ 1) at γ = 2 × the largest frozen bound at these three points (over the whole range the
frozen optimum peaks higher, at ±70°: see the next row) for the rate of a 70° move in 2.0 s with a
triangular velocity profile (0.006 per sample) and a tenth of it. t < 0: no controller of this class
reaches that level, whatever the reconstruction.

The same ±75° range with another controller class (``adip_interpolated``): SLICOT SB10DD controllers at
every 5° (each at 1.5 × its frozen optimum; SB10DD's formulae are continuous in the plant data, so
interpolating them between breakpoints is meaningful), the worst frozen ‖T_zw‖∞ of the exact
linearizations with the interpolated controller on 121 points (python-control), and
:func:`lpvflow.synth.analysis.rate_bounded_gain` of that loop at ν = 0.0006 (a tenth of the rate above)
with the Lyapunov breakpoints at the controller's, 2 LMI points per interval: its certified γ, or where it
fails.

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
            "gamma": result.gamma, "frozen_lower_bound": result.gamma_lower, "seconds": seconds,
            "level_solves": len(solves), "one_sdp_seconds": min(solves), "ratio": seconds / min(solves)}


def adip_margin(rate_bound: float) -> dict:
    """The ADIP row of the module docstring: t of the margin SDP at γ = 2 × the frozen bound."""
    from lpvflow.synth.bilinear import cayley_vertex
    from lpvflow.synth.eliminated import preconditioned
    from lpvflow.synth.levels import GAMMA_MAX
    from tests.adip_cases import adip_vertex

    degrees = (-75.0, 0.0, 75.0)
    vertices = [adip_vertex(d) for d in degrees]
    frozen = [preconditioned([cayley_vertex(v)], GAMMA_MAX, "CLARABEL") for v in vertices]
    bound = max(f.estimate.gamma for f in frozen)
    schedule = rate_bounded.Schedule(np.sin(np.deg2rad(degrees)), rate_bound)
    coords = frozen[1].coordinates.discrete()  # those of the 0° vertex
    verts = [coords.apply(v) for v in vertices]
    levels = rate_bounded._Levels(verts, schedule, schedule.pairs())
    levels.gamma.value = 2.0 * bound
    start = time.perf_counter()
    rate_bounded.solve(levels.margin_problem, "CLARABEL", "the ADIP margin SDP")
    return {"rate_bound": rate_bound, "frozen_lower_bound": bound, "gamma": 2.0 * bound,
            "margin_t": float(levels.t.value), "seconds": time.perf_counter() - start}


def adip_interpolated(rate_bound: float) -> dict:
    """The interpolated-SB10DD row of the module docstring."""
    import control

    from lpvflow.synth.analysis import rate_bounded_gain
    from lpvflow.synth.bilinear import closed_loop
    from lpvflow.synth.controller import mix
    from lpvflow.synth.polytope import hat_coordinates
    from lpvflow.synth.riccati import riccati_controller, riccati_gamma
    from tests.adip_cases import TS, adip_vertex

    degrees = np.arange(-75.0, 75.01, 5.0)
    b = np.deg2rad(degrees)
    optima = [riccati_gamma(adip_vertex(d), TS, 1e-3) for d in degrees]
    K = [riccati_controller(adip_vertex(d), TS, 1.5 * g) for d, g in zip(degrees, optima, strict=True)]

    def loop_at(p: float):
        return closed_loop(adip_vertex(float(np.rad2deg(p))), mix(K, hat_coordinates(b, p)))

    grid = np.linspace(b[0], b[-1], 121)
    frozen = max(float(control.norm(control.ss(*loop_at(p), TS), "inf")) for p in grid)
    row = {"rate_bound": rate_bound, "breakpoints": len(b), "worst_frozen_riccati": max(optima),
           "worst_frozen_interpolated": frozen}
    start = time.perf_counter()
    try:
        result = rate_bounded_gain(loop_at, b, rate_bound, design_per_segment=2)
    except rate_bounded.SynthesisError as exc:
        return row | {"error": str(exc), "seconds": time.perf_counter() - start}
    return row | {"gamma": result.gamma, "seconds": time.perf_counter() - start}


def main() -> None:
    rows = [measure(2, 3, 0.02), measure(2, 3, None), measure(6, 2, 0.02)]
    adip = [adip_margin(0.006), adip_margin(0.0006)]
    interpolated = adip_interpolated(0.0006)
    OUT.write_text(json.dumps({"rows": rows, "adip": adip, "adip_interpolated": interpolated}, indent=1,
                              default=float) + "\n")
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
    for r in adip:
        print(f"ADIP ±75°, ν = {r['rate_bound']:g}: γ = 2 × {r['frozen_lower_bound']:.4g}, margin t = "
              f"{r['margin_t']:.3g} ({r['seconds']:.0f} s)")
    r = interpolated
    print(f"ADIP ±75°, interpolated SB10DD ({r['breakpoints']} breakpoints): worst frozen Riccati optimum "
          f"{r['worst_frozen_riccati']:.4g}, worst frozen loop {r['worst_frozen_interpolated']:.4g}; "
          f"ν = {r['rate_bound']:g}: " + (f"γ = {r['gamma']:.4g}" if "gamma" in r else r["error"])
          + f" ({r['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
