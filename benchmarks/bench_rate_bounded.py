"""Rate-bounded gain-scheduled H∞ synthesis (lpvflow.synth.rate_bounded): wall time against the number and
the largest of its SDP solves, and γ against the frozen estimate.

Cases (``tests/rate_bounded_cases.random_scheduled_plant``: a random stable, down to lightly damped, plant
of ``states`` states with one scheduling signal p ∈ [−1, 1], mixed-sensitivity weights W_S, W_K and an
actuator lag W_B, Ts = 10 ms, |Δp| ≤ 0.05 per sample, the frozen plants at equally spaced breakpoints):
``order`` is the generalized plant's (states + 2). The 13-breakpoint case of an 8-state plant is run in a
child process stopped after ``LIMIT`` seconds; a row that did not finish says so.

Columns: γ certified; ``estimate`` the largest frozen estimate (``ScheduledResult.gamma_estimate``, not a
bound); ``s`` wall time; ``SDPs`` every cvxpy solve of the synthesis (frozen estimates, the
common-Lyapunov bracket, the levels); ``largest`` the longest single one; ``ratio`` = s / largest. One
thread (OPENBLAS_NUM_THREADS=1), one run.

The limit on the ADIP (issue 23's ±75° test): the exact linearizations at −75°, 0°, 75° with the bundled
weights (1-DOF, ``tests/adip_cases.py``), breakpoints at sin φ1, and the largest margin t of the LMIs
(Ψ_δ ⪰ t·I, t ≤ 1) at γ = 2 × the largest frozen bound at these three points (over the whole range the
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

Run:  .venv/bin/python benchmarks/bench_rate_bounded.py [--limit SECONDS]
      → benchmarks/results/rate_bounded.json
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cvxpy as cp
import numpy as np

from lpvflow.synth import rate_bounded

OUT = Path(__file__).parent / "results" / "rate_bounded.json"
TS = 0.01
RATE = 0.05
#: Wall-clock limit of one case, seconds.
LIMIT = 900.0
#: (name, seed, plant states, breakpoints).
CASES = [("small", 1, 2, 3), ("13 breakpoints", 4, 2, 13), ("order 6", 2, 4, 5),
         ("13 breakpoints, 8 states", 0, 8, 13)]


def _run(seed: int, states: int, breakpoints: int, out) -> None:
    """One synthesis with every cvxpy solve timed (in a child process)."""
    from tests.rate_bounded_cases import random_scheduled_plant

    vertices, b = random_scheduled_plant(seed, states, breakpoints, TS)
    solves = []
    inner = cp.Problem.solve

    def timed(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return inner(self, *args, **kwargs)
        finally:
            solves.append(time.perf_counter() - start)

    cp.Problem.solve = timed
    start = time.perf_counter()
    try:
        result = rate_bounded.synthesize_scheduled(vertices, b, TS, rate_bound=RATE)
        row = {"gamma": result.gamma, "gamma_estimate": result.gamma_estimate}
    except rate_bounded.SynthesisError as exc:
        row = {"error": str(exc)[:300]}
    seconds = time.perf_counter() - start
    out.put(row | {"order": vertices[0].dims[0], "seconds": seconds, "sdps": len(solves),
                   "largest_sdp": max(solves), "ratio": seconds / max(solves)})


def measure(name: str, seed: int, states: int, breakpoints: int, limit: float = LIMIT) -> dict:
    row = {"case": name, "seed": seed, "breakpoints": breakpoints, "order": states + 2, "rate_bound": RATE}
    out = multiprocessing.Queue()
    child = multiprocessing.Process(target=_run, args=(seed, states, breakpoints, out))
    child.start()
    child.join(limit)
    if child.is_alive():
        child.terminate()
        child.join()
        return row | {"error": f"not finished in {limit:.0f} s", "seconds": limit}
    return row | out.get()


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
    levels = rate_bounded._Levels(verts, schedule, schedule.pairs(), rate_bounded.delta_step(verts, 1))
    levels.gamma.value = 2.0 * bound
    start = time.perf_counter()
    rate_bounded.solve(levels.margin_problem, "CLARABEL", "the ADIP margin SDP")
    return {"rate_bound": rate_bound, "frozen_estimate": bound, "gamma": 2.0 * bound,
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
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--limit", type=float, default=LIMIT, help=f"seconds per case (default {LIMIT:g})")
    rows = [measure(*case, limit=parser.parse_args().limit) for case in CASES]
    adip = [adip_margin(0.006), adip_margin(0.0006)]
    interpolated = adip_interpolated(0.0006)
    OUT.write_text(json.dumps({"rows": rows, "adip": adip, "adip_interpolated": interpolated}, indent=1,
                              default=float) + "\n")
    heads = ("case", "bps", "order", "γ", "estimate", "s", "SDPs", "largest", "ratio")
    print(f"{heads[0]:>26} " + " ".join(f"{h:>8}" for h in heads[1:]))
    for r in rows:
        lead = f"{r['case']:>26} {r['breakpoints']:>8} {r['order']:>8} "
        if "error" in r:
            print(lead + f"{r['seconds']:.0f} s: {r['error']}")
            continue
        estimate = "—" if r["gamma_estimate"] is None else f"{r['gamma_estimate']:.4g}"
        print(lead + f"{r['gamma']:8.4g} {estimate:>8} {r['seconds']:8.1f} {r['sdps']:>8} "
              f"{r['largest_sdp']:8.2f} {r['ratio']:8.1f}")
    for r in adip:
        print(f"ADIP ±75°, ν = {r['rate_bound']:g}: γ = 2 × {r['frozen_estimate']:.4g}, margin t = "
              f"{r['margin_t']:.3g} ({r['seconds']:.0f} s)")
    r = interpolated
    print(f"ADIP ±75°, interpolated SB10DD ({r['breakpoints']} breakpoints): worst frozen Riccati optimum "
          f"{r['worst_frozen_riccati']:.4g}, worst frozen loop {r['worst_frozen_interpolated']:.4g}; "
          f"ν = {r['rate_bound']:g}: " + (f"γ = {r['gamma']:.4g}" if "gamma" in r else r["error"])
          + f" ({r['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
