"""H∞ synthesis (lpvflow.synth.hinf.hinfsyn): γ against an LMI-free reference and time as a ratio to one SDP
solve of the same plant.

Cases (all discrete generalized plants, inputs [w, u], outputs [z, y]):

* ``adip_0``, ``adip_75``: the exact ADIP linearization (Ts = 5 ms) at 0° and 75.5° with the bundled
  weights, one vertex; reference γ: SLICOT SB10DD bisected (``riccati.riccati_gamma``).
* ``adip_0_45``: the two vertices 0° and 45.6° (a 2-vertex pendulum family).
* ``issue``: ``random_lpv(7, nx=4, n_p=2, nu=2, ny=2)`` on [−0.25, 0.25]² with 8th-order weights → four
  vertices, generalized plant of order 12.
* ``maglev``: the three vertices (parabola triangle) of the bundled maglev design: the identified model
  ``build/design/maglev/model.json`` written by ``lpvflow design --example maglev`` (skipped when absent).
* ``readme``: the README's augw example.
* ``random_<i>``: the 14 weighted plants of tests/hinf_cases.py, seed 2026 (two of each kind); with
  ``--random N --seed S`` only N plants of seed S (the slow test's draw: ``--random 63 --seed 2027``,
  written to ``results/synth_random63_seed2027.json``).

``ratio`` = hinfsyn's wall time (compilation included) / the longest single SDP solve of the same run (the
controller LMIs at one level, as reported in ``res.report.attempts``): how many solves of its largest SDP
a synthesis costs. One thread (OPENBLAS_NUM_THREADS=1 is set below), one run each.

``maglev_ceiling``: what any LPV controller of the maglev design can reach at best relative to the LTI
point design: an LPV controller frozen at y2 is an LTI controller for the plant frozen there, so its γ is
at least the frozen SB10DD optimum at every y2 of the box; the ceiling is the largest of these over a grid
of the box divided by the LTI point design's γ at ``baseline_at``.

Run:  .venv/bin/python benchmarks/bench_synth.py   → benchmarks/results/synth.json + a table
      .venv/bin/python benchmarks/bench_synth.py --random 63 --seed 2027   (random plants only, ~3 min)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import tomllib
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import control
import numpy as np

from lpvflow.errors import SynthesisError
from lpvflow.models import load
from lpvflow.pipeline.config import bundled_config
from lpvflow.synth.examples import random_lpv
from lpvflow.synth.plant import VertexPlant, generalized_plant
from lpvflow.synth.riccati import riccati_gamma
from lpvflow.synth.vertex_synthesis import synthesize_vertices
from tests.adip_cases import TS, adip_vertex
from tests.hinf_cases import weighted_cases

OUT = Path(__file__).parent / "results" / "synth.json"
MAGLEV_MODEL = Path(__file__).resolve().parents[1] / "build" / "design" / "maglev" / "model.json"
ISSUE_WEIGHTS = {
    "S": {"num": [0.1, 0.0, 0.0], "den": [1.0, -1.5, 0.5]},
    "K": {"num": [0.05, -0.04], "den": [1.0, -0.2]},
    "B": {"num": [0.0, 0.5], "den": [1.0, -0.5]},
}


def random_cases(count: int, seed: int) -> dict:
    """name → (vertex plants, Ts) for ``count`` weighted plants of tests/hinf_cases.py drawn with ``seed``."""
    out = {}
    for i, case in enumerate(weighted_cases(count, seed)):
        v = VertexPlant.from_ss(case.P, case.P.ninputs - case.ncon, case.P.noutputs - case.nmeas)
        out[f"random_{i}"] = ([v], case.P.dt)
    return out


def cases() -> dict:
    """name → (vertex plants, Ts)."""
    issue = generalized_plant(random_lpv(7, nx=4, n_p=2, nu=2, ny=2), ISSUE_WEIGHTS, [[-0.25, 0.25]] * 2)
    G = control.c2d(control.tf([4.0], [1.0, 0.4, 4.0]), 0.01)
    readme = control.augw(G, control.c2d(control.tf([0.5, 1.0], [1.0, 0.01]), 0.01), control.tf(0.1, 1, 0.01))
    out = {
        "adip_0": ([adip_vertex(0.0)], TS),
        "adip_75": ([adip_vertex(75.5)], TS),
        "adip_0_45": ([adip_vertex(0.0), adip_vertex(45.6)], TS),
        "issue": (issue.vertices, issue.Ts),
        "readme": ([VertexPlant.from_ss(readme, 1, 2)], 0.01),
    }
    if MAGLEV_MODEL.is_file():
        synth = tomllib.loads(bundled_config("maglev").read_text())["synth"]
        maglev = generalized_plant(load(MAGLEV_MODEL), synth["weights"], synth["box"])
        out["maglev"] = (maglev.vertices, maglev.Ts)
    return out | random_cases(14, 2026)


def maglev_ceiling(points: int = 23) -> dict:
    """The frozen SB10DD optimum on a grid of the maglev box, the LTI point design (hinfsyn at
    ``baseline_at``) and their ratio (module docstring)."""
    synth = tomllib.loads(bundled_config("maglev").read_text())["synth"]
    model = load(MAGLEV_MODEL)
    (lo, hi), = synth["box"]
    grid = np.linspace(lo, hi, points)
    frozen = [riccati_gamma(generalized_plant(model, synth["weights"], [[p, p]]).vertices[0], model.Ts)
              for p in grid]
    at = synth["baseline_at"][0]
    point = generalized_plant(model, synth["weights"], [[at, at]])
    lti = synthesize_vertices(point.vertices, point.Ts).gamma
    worst = int(np.argmax(frozen))
    return {"y2_worst": float(grid[worst]), "frozen_optimum_worst": frozen[worst], "baseline_at": at,
            "lti_gamma": lti, "lti_riccati": riccati_gamma(point.vertices[0], point.Ts),
            "ceiling_ratio": frozen[worst] / lti}


def measure(name: str, vertices: list, Ts: float) -> dict:
    row = {"case": name, "vertices": len(vertices), "order": vertices[0].dims[0]}
    start = time.perf_counter()
    try:
        result = synthesize_vertices(vertices, Ts)
    except SynthesisError as exc:
        return row | {"error": f"{exc.category}: {str(exc)[:200]}"}
    seconds = time.perf_counter() - start
    one = max(a[2] for a in result.report.attempts)
    row |= {"gamma": result.gamma, "gamma_estimate": result.gamma_estimate, "seconds": seconds,
            "sdps": len(result.report.attempts), "one_sdp_seconds": one, "ratio": seconds / one}
    if len(vertices) == 1:
        row["riccati_gamma"] = riccati_gamma(vertices[0], Ts)
        row["gamma_over_riccati"] = result.gamma / row["riccati_gamma"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--random", type=int, help="only this many random plants (tests/hinf_cases.py)")
    parser.add_argument("--seed", type=int, default=2026, help="their seed (default 2026)")
    args = parser.parse_args()
    only_random = args.random is not None
    chosen = random_cases(args.random, args.seed) if only_random else cases()
    out = OUT.with_name(f"synth_random{args.random}_seed{args.seed}.json") if only_random else OUT
    rows = [measure(name, *case) for name, case in chosen.items()]
    ceiling = maglev_ceiling() if MAGLEV_MODEL.is_file() and not only_random else None
    ratios = np.array([r["ratio"] for r in rows if "ratio" in r])
    near = [r["gamma_over_riccati"] <= 1.01 for r in rows if "gamma_over_riccati" in r]
    summary = {"median_ratio": float(np.median(ratios)), "worst_ratio": float(ratios.max()),
               "answered": len(ratios), "cases": len(rows), "within_one_percent_of_sb10dd": int(sum(near)),
               "single_plant_cases": len(near)}
    out.write_text(json.dumps({"rows": rows, "summary": summary, "maglev_ceiling": ceiling}, indent=1,
                              default=float) + "\n")
    print(f"{'case':12} {'N':>2} {'n':>3} {'γ':>9} {'γ/SB10DD':>9} {'s':>7} {'SDPs':>4} {'one SDP s':>9} "
          f"{'ratio':>6}")
    for r in rows:
        if "error" in r:
            print(f"{r['case']:12} {r['vertices']:>2} {r['order']:>3}  {r['error']}")
            continue
        ric = f"{r['gamma_over_riccati']:.4f}" if "gamma_over_riccati" in r else "–"
        print(f"{r['case']:12} {r['vertices']:>2} {r['order']:>3} {r['gamma']:9.5g} {ric:>9} "
              f"{r['seconds']:7.3f} {r['sdps']:>4} {r['one_sdp_seconds']:9.3f} {r['ratio']:6.1f}")
    print(f"ratio: median {summary['median_ratio']:.1f}, worst {summary['worst_ratio']:.1f} "
          f"({summary['answered']} of {summary['cases']} answered); γ within 1 % of SB10DD (or below): "
          f"{summary['within_one_percent_of_sb10dd']} of {summary['single_plant_cases']} single plants")
    if ceiling is None:
        if not only_random:
            print(f"maglev: not measured — {MAGLEV_MODEL} is absent; run `lpvflow design --example "
                  "maglev` first")
        return
    c = ceiling
    print(f"maglev: worst frozen SB10DD optimum {c['frozen_optimum_worst']:.5f} at y2 = {c['y2_worst']:.4f}; "
          f"LTI point design at {c['baseline_at']:g}: {c['lti_gamma']:.5f} (SB10DD {c['lti_riccati']:.5f}); "
          f"ceiling ratio {c['ceiling_ratio']:.4f}")
    print(f"numpy {np.__version__}")


if __name__ == "__main__":
    main()
