"""Output-feedback H∞ synthesis cost, Clarabel vs SCS, and γ_dilated/γ_common (issue 6).

Part 1, the issue's case: a 4-state LPVSS with 2 inputs, 2 outputs and 2 scheduling parameters
(``random_lpv(SEED, nx=4, n_p=2, nu=2, ny=2)`` on the box [−0.25, 0.25]² → 4 vertices; on [−1, 1]² its
vertex poles reach |z| = 1.4 and no common controller exists) with 8th-order weights:
W_S second order per output (2 × 2 = 4 states), W_K first order per input (2 states), W_B strictly
proper first order per input (2 states) → generalized plant of order 12, closed loop 24. Method
``"common"`` with Clarabel and with SCS as the first solver, ``"dilated"`` with Clarabel. Each synthesis
runs in a fresh subprocess that reports its own peak RSS (``ru_maxrss``, what RUSAGE_CHILDREN gives the parent
for that one child) minus the peak RSS of a subprocess that only imports the same modules. cvxpy
compilation time (``problem.compilation_time``) and solver time (``solver_stats.solve_time``) are
summed over the SDP solves of one synthesis; ``cpu_s`` is the process's CPU time for it (what wall time
would be on idle cores: the machine is shared).

Part 2: γ_dilated/γ_common on the thesis-like weight sets (``examples.maglev_like``, ``adip_like`` on a
box where a common controller exists) and on random polytopes (``random_lpv(seed, nx=3)`` on
[−0.5, 0.5]), Clarabel, one subprocess per case.

Run:  .venv/bin/python benchmarks/bench_synth.py   → benchmarks/results/synth.json + tables
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

OUT = Path(__file__).parent / "results" / "synth.json"
SEED = 7
ISSUE_WEIGHTS = {
    "S": {"num": [0.1, 0.0, 0.0], "den": [1.0, -1.5, 0.5]},  # (0.1 z²)/((z − 1)(z − 0.5)), pole 1 → 0.999
    "K": {"num": [0.05, -0.04], "den": [1.0, -0.2]},
    "B": {"num": [0.0, 0.5], "den": [1.0, -0.5]},
}
SMALL_WEIGHTS = {"S": {"num": [0.1, 0.1], "den": [1, -1]}, "K": {"num": [0.01], "den": [1]},
                 "B": {"num": [0, 0.5], "den": [1, -0.5]}}
TIMEOUT = 300.0  # per synthesis; a case that takes longer is reported as such


def _plant(case: str):
    """(model, weights, box) of a case name."""
    from lpvflow.synth.examples import adip_like, maglev_like, random_lpv

    if case == "issue":
        return random_lpv(SEED, nx=4, n_p=2, nu=2, ny=2), ISSUE_WEIGHTS, [[-0.25, 0.25]] * 2
    if case == "maglev_like":
        return (*maglev_like(), None)
    if case == "adip_like":
        model, weights = adip_like()
        return model, weights, [[-0.3, 0.3]]  # the full ±0.96 box has no common controller
    seed = int(case.split("_")[-1])
    return random_lpv(seed, nx=3), SMALL_WEIGHTS, [[-0.5, 0.5]]


def worker(case: str, method: str, solver: str) -> dict:
    """One synthesis in this process: times, γ, status, peak RSS."""
    import lpvflow.synth.lmi_hinf as lmi_hinf
    from lpvflow.synth.plant import generalized_plant
    from lpvflow.synth.sdp import SynthesisError

    if method == "imports":
        return {"maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}
    compile_s, solver_s, solves = 0.0, 0.0, 0
    inner = lmi_hinf.solve

    def timed(problem, name="CLARABEL", what="the LMIs", tolerance=None):
        nonlocal compile_s, solver_s, solves
        try:
            return inner(problem, name, what, tolerance)
        finally:
            solves += 1
            compile_s += problem.compilation_time or 0.0
            stats = problem.solver_stats
            solver_s += (stats.solve_time or 0.0) if stats is not None else 0.0

    lmi_hinf.solve = timed
    model, weights, box = _plant(case)
    gp = generalized_plant(model, weights, box)
    start, cpu_start = time.perf_counter(), time.process_time()
    row = {"case": case, "method": method, "solver": solver, "n": gp.dims[0], "vertices": len(gp.vertices)}
    try:
        res = lmi_hinf.synthesize(gp, method, solver)
        row.update(gamma=res.gamma, gamma_opt=res.gamma_opt, lmi_max_eig=res.lmi_max_eig,
                   status=res.report.status, solver_used=res.report.solver)
    except SynthesisError as exc:
        row.update(gamma=None, error=str(exc)[:300])
    row.update(wall_s=time.perf_counter() - start, cpu_s=time.process_time() - cpu_start, compile_s=compile_s,
               solver_s=solver_s, solves=solves, maxrss_kb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    return row


def run(case: str, method: str, solver: str = "CLARABEL") -> dict:
    """``worker`` in a fresh subprocess (one thread for BLAS, as the tests)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    try:
        out = subprocess.run([sys.executable, __file__, "--worker", case, method, solver],
                             capture_output=True, text=True, env=env, timeout=TIMEOUT, check=True).stdout
    except subprocess.TimeoutExpired:
        return {"case": case, "method": method, "solver": solver, "gamma": None,
                "error": f"> {TIMEOUT:.0f} s", "wall_s": TIMEOUT}
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    base_kb = run("issue", "imports")["maxrss_kb"]
    part1 = [run("issue", "common", "CLARABEL"), run("issue", "common", "SCS"),
             run("issue", "dilated", "CLARABEL")]
    for r in part1:
        r["extra_rss_mb"] = (r["maxrss_kb"] - base_kb) / 1024 if "maxrss_kb" in r else None
    cases = ["maglev_like", "adip_like", *(f"random_{s}" for s in (2, 3, 4, 5, 6))]
    part2 = []
    for case in cases:
        common, dilated = run(case, "common"), run(case, "dilated")
        both = common.get("gamma") and dilated.get("gamma")
        part2.append({"case": case, "common": common, "dilated": dilated,
                      "ratio": dilated["gamma"] / common["gamma"] if both else None})
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"machine": platform.platform(), "python": platform.python_version(),
                               "imports_maxrss_mb": base_kb / 1024, "issue_case": part1,
                               "ratios": part2}, indent=2))
    print(f"issue case: n = {part1[0].get('n')}, {part1[0].get('vertices')} vertices; "
          f"imports-only peak RSS {base_kb / 1024:.0f} MB")
    print("| method | first solver | γ | wall s | CPU s | cvxpy compile s | solver s | solves | "
          "extra peak RSS MB | status |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in part1:
        gamma = f"{r['gamma']:.5g}" if r.get("gamma") else "–"
        print(f"| {r['method']} | {r['solver']} | {gamma} | {r.get('wall_s', float('nan')):.1f} | "
              f"{r.get('cpu_s', float('nan')):.1f} | "
              f"{r.get('compile_s', float('nan')):.2f} | {r.get('solver_s', float('nan')):.1f} | "
              f"{r.get('solves', '–')} | {r.get('extra_rss_mb') or float('nan'):.0f} | "
              f"{r.get('status', r.get('error', ''))[:70]} |")
    print("\n| case | n, vertices | γ common | γ dilated | γ_dilated/γ_common | time common s | "
          "time dilated s |")
    print("|---|---|---|---|---|---|---|")
    for r in part2:
        c, d = r["common"], r["dilated"]
        fmt = (lambda x: f"{x:.5g}" if x else "–")  # noqa: E731
        ratio = f"{r['ratio']:.4f}" if r["ratio"] else "–"
        print(f"| {r['case']} | {c.get('n')}, {c.get('vertices')} | {fmt(c.get('gamma'))} | "
              f"{fmt(d.get('gamma'))} | {ratio} | {c.get('wall_s', float('nan')):.1f} | "
              f"{d.get('wall_s', float('nan')):.1f} |")


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--worker":
        print(json.dumps(worker(*sys.argv[2:])))
    else:
        main()
