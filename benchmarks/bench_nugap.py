"""ν-gap evaluation time and accuracy (issue 5 goals: 4-state SISO < 20 ms, 8-state 2×2 < 100 ms).

For each case, 40 seeded random discrete-time pairs (Ts = 0.1): a stable system and a perturbation
of it (A, B, C, D + 0.05·N(0, 1)). Time per `nugap` call is the median over the pairs of the best
of 3 calls. Accuracy: the largest |δν − max κ on a dense grid| over the pairs whose winding condition
held, with the dense grid 20 000 log-spaced frequencies up to Nyquist (an independent lower bound
of the supremum; δν should exceed it by at most the grid's miss). The continuous-time cases and
`stability_margin` are timed the same way, for reference.

Run:  .venv/bin/python benchmarks/bench_nugap.py     → benchmarks/results/nugap.json + a table
"""

from __future__ import annotations

import json
import platform
from pathlib import Path

import control as ct
import numpy as np
from timing import best_of

from lpvflow.validate.margins import stability_margin
from lpvflow.validate.nugap import chordal_distance, nugap

OUT = Path(__file__).parent / "results" / "nugap.json"
PAIRS, REPEATS, DENSE = 40, 3, 20_000
CASES = [  # (name, states, outputs, inputs, dt, goal in ms)
    ("4-state SISO, discrete", 4, 1, 1, 0.1, 20.0),
    ("8-state 2x2, discrete", 8, 2, 2, 0.1, 100.0),
    ("4-state SISO, continuous", 4, 1, 1, 0, None),
    ("8-state 2x2, continuous", 8, 2, 2, 0, None),
]


def random_pair(rng: np.random.Generator, n: int, p: int, m: int, dt: float) -> tuple[ct.StateSpace, ...]:
    A = rng.standard_normal((n, n))
    eig = np.linalg.eigvals(A)
    A = A * rng.uniform(0.3, 0.95) / np.max(np.abs(eig)) if dt else A - (eig.real.max() + 0.5) * np.eye(n)
    B, C, D = rng.standard_normal((n, m)), rng.standard_normal((p, n)), rng.standard_normal((p, m))
    P1 = ct.ss(A, B, C, D, dt)
    P2 = ct.ss(*(M + 0.05 * rng.standard_normal(M.shape) for M in (A, B, C, D)), dt)
    return P1, P2


def dense_max(P1: ct.StateSpace, P2: ct.StateSpace) -> float:
    top = np.pi / P1.dt * (1 - 1e-12) if P1.isdtime() else 1e4
    omega = np.logspace(-4, np.log10(top), DENSE)
    responses = [
        np.moveaxis(ct.frequency_response(P, omega).complex.reshape(P.noutputs, P.ninputs, -1), -1, 0)
        for P in (P1, P2)
    ]
    return float(chordal_distance(*responses).max())


def run_case(name: str, n: int, p: int, m: int, dt: float, goal: float | None) -> dict:
    rng = np.random.default_rng(n * 10 + p + (1 if dt else 0))
    pairs = [random_pair(rng, n, p, m, dt) for _ in range(PAIRS)]
    nugap(*pairs[0])  # warm-up (imports, caches)
    gap_times = [best_of(lambda pair=pair: nugap(*pair), REPEATS) for pair in pairs]
    K = ct.ss([], [], [], 0.1 * np.ones((m, p)), dt)
    margin_times = [best_of(lambda pair=pair: stability_margin(pair[0], K), REPEATS) for pair in pairs]
    errors, held = [], 0
    for pair in pairs:
        result = nugap(*pair)
        if result.winding_condition_held:
            held += 1
            errors.append(result.value - dense_max(*pair))
    median_ms = 1e3 * float(np.median(gap_times))
    return {
        "case": name,
        "pairs": PAIRS,
        "nugap_median_ms": median_ms,
        "nugap_p90_ms": 1e3 * float(np.percentile(gap_times, 90)),
        "goal_ms": goal,
        "meets_goal": None if goal is None else bool(median_ms < goal),
        "stability_margin_median_ms": 1e3 * float(np.median(margin_times)),
        "winding_condition_held": held,
        "max_value_minus_dense_max": float(np.max(errors)) if errors else None,
        "min_value_minus_dense_max": float(np.min(errors)) if errors else None,
    }


def main() -> None:
    rows = [run_case(*case) for case in CASES]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"machine": platform.platform(), "python": platform.python_version(),
                               "control": ct.__version__, "rows": rows}, indent=2))
    print("| case | nugap median ms | p90 ms | goal ms | b(P,K) median ms | winding held | "
          "δν − dense max (min / max) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        verdict = "met" if r["meets_goal"] else "MISSED"
        goal = "–" if r["goal_ms"] is None else f"< {r['goal_ms']:.0f} ({verdict})"
        print(f"| {r['case']} | {r['nugap_median_ms']:.2f} | {r['nugap_p90_ms']:.2f} | {goal} | "
              f"{r['stability_margin_median_ms']:.2f} | {r['winding_condition_held']}/{r['pairs']} | "
              f"{r['min_value_minus_dense_max']:.1e} / {r['max_value_minus_dense_max']:.1e} |")


if __name__ == "__main__":
    main()
