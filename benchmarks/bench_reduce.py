"""Gram-recursion Ho–Kalman reduction vs the explicit extended matrices, same depth (i = j = d).

Three ways to get the same reduced model (Schulz et al. Lemma 1), for a random stable affine LPVSS
with n_x = 12, n_u = n_y = 2 and a noise gain K, nψ = 2 … 5:

* ``recursion``  lpvflow.identify.reduce.reduce (square-root Gram recursion, O(d nψ n_x³) time,
  O(nψ n_x²) memory), with ``scaling="none"`` so that it computes exactly what the others do;
* ``explicit QR`` forms O_d (n_y Σ_{k≤d} nψ^k rows) and R_d ((n_u+n_y) Σ_{k≤d} nψ^k columns), QR-factors
  them and applies Lemma 1 (the paper's QR route);
* ``explicit SVD`` forms H_dd = O_d R_d and takes its SVD (the original Ho–Kalman), only while H has
  at most 2·10⁷ entries.

An explicit variant is skipped (marked "skipped") when its predicted array memory exceeds 2 GB.
Times are the best of a few runs without tracemalloc; memory is the tracemalloc peak of a separate
run (numpy buffers are traced; LAPACK workspace is not). Every run checks that the singular values
agree with the recursion's. The last row times the default call (automatic depth, capped terms).

Run:  .venv/bin/python benchmarks/bench_reduce.py     → benchmarks/results/reduce.json + a table
"""

from __future__ import annotations

import itertools
import json
import platform
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lpvflow.basis import Basis
from lpvflow.identify.reduce import observability_matrix, reachability_matrix, reduce
from lpvflow.models import LPVSS

NX, NU, NY, ORDER = 12, 2, 2, 6
DEPTHS = (4, 6, 8)
MEMORY_CAP = 2e9
SVD_CAP = 2e7
OUT = Path(__file__).parent / "results" / "reduce.json"


def random_model(n_psi: int, seed: int = 0) -> LPVSS:
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n_psi, NX, NX))
    A[1:] *= 0.3
    corners = Basis.affine(n_psi - 1).eval(np.array(list(itertools.product([-1, 1], repeat=n_psi - 1))))
    A *= 0.9 / max(np.linalg.norm(np.tensordot(c, A, axes=1), 2) for c in corners)
    basis = Basis.affine(n_psi - 1)
    return LPVSS(A, rng.standard_normal((n_psi, NX, NU)), rng.standard_normal((n_psi, NY, NX)),
                 np.zeros((n_psi, NY, NU)), basis, 1.0, K=rng.standard_normal((n_psi, NX, NY)))


def lemma1(R_O: np.ndarray, R_R: np.ndarray, ss: LPVSS) -> tuple[np.ndarray, np.ndarray]:
    """(18) and (16) from any square-root factors; returns the singular values and Â."""
    U, s, Vt = np.linalg.svd(R_O @ R_R.T)
    scale = 1 / np.sqrt(s[:ORDER])
    T = R_R.T @ Vt[:ORDER].T * scale
    T_left = scale[:, None] * (U[:, :ORDER].T @ R_O)
    return s, T_left @ ss.A @ T


def explicit_qr(ss: LPVSS, d: int) -> np.ndarray:
    R_O = np.linalg.qr(observability_matrix(ss, d), mode="r")
    R_R = np.linalg.qr(reachability_matrix(ss, d).T, mode="r")
    return lemma1(R_O, R_R, ss)[0]


def explicit_svd(ss: LPVSS, d: int) -> np.ndarray:
    H = observability_matrix(ss, d) @ reachability_matrix(ss, d)
    return np.linalg.svd(H, compute_uv=False)[:NX]


def recursion(ss: LPVSS, d: int) -> np.ndarray:
    return np.asarray(reduce(ss, order=ORDER, depth=(d, d), scaling="none").reduction["singular_values"])


def measure(fn: Callable[[], np.ndarray], repeats: int) -> tuple[float, float, np.ndarray]:
    """(best time in s, tracemalloc peak in bytes, result)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return min(times), peak, result


def main() -> None:
    rows = []
    for n_psi, d in itertools.product(range(2, 6), DEPTHS):
        ss = random_model(n_psi)
        blocks = sum(n_psi**k for k in range(1, d + 1))
        o_rows, r_cols = NY * blocks, (NU + NY) * blocks
        row = {"n_psi": n_psi, "depth": d, "O_rows": o_rows, "R_cols": r_cols}
        reps = 3
        t, m, s_ref = measure(lambda ss=ss, d=d: recursion(ss, d), reps)
        row["recursion"] = {"time_s": t, "peak_bytes": m}
        predicted = {"explicit_qr": 8 * NX * (o_rows + r_cols) * 2,
                     "explicit_svd": 8 * (o_rows * r_cols + NX * (o_rows + r_cols))}
        for name, fn in (("explicit_qr", explicit_qr), ("explicit_svd", explicit_svd)):
            too_big = predicted[name] > MEMORY_CAP or (name == "explicit_svd" and o_rows * r_cols > SVD_CAP)
            if too_big:
                row[name] = {"skipped": f"predicted {predicted[name] / 1e9:.2g} GB / {o_rows}x{r_cols}"}
                continue
            t, m, s = measure(lambda fn=fn, ss=ss, d=d: fn(ss, d), 1 if predicted[name] > 1e8 else reps)
            agree = float(np.max(np.abs(s[:ORDER] - s_ref[:ORDER]) / s_ref[0]))
            row[name] = {"time_s": t, "peak_bytes": m, "sigma_rel_diff": agree,
                         "time_ratio": t / row["recursion"]["time_s"],
                         "memory_ratio": m / max(row["recursion"]["peak_bytes"], 1)}
        rows.append(row)
        print(f"nψ={n_psi} d={d} done", flush=True)

    ss = random_model(4)
    goal_t, goal_m, _ = measure(lambda: np.asarray(reduce(ss).reduction["singular_values"]), 5)
    goal = {"n_x": NX, "n_psi": 4, "time_s": goal_t, "peak_bytes": goal_m,
            "depth": reduce(ss).reduction["depth"], "target_s": 0.5, "met": goal_t < 0.5}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"benchmark": "reduce", "n_x": NX, "n_u": NU, "n_y": NY, "order": ORDER,
                               "memory_cap_bytes": MEMORY_CAP, "svd_cap_entries": SVD_CAP,
                               "machine": platform.platform(), "rows": rows, "goal": goal}, indent=1))

    def cell(r: dict, key: str) -> str:
        v = r[key]
        if "skipped" in v:
            return "skipped (" + v["skipped"] + ")"
        return f"{v['time_ratio']:.3g}× / {v['memory_ratio']:.3g}×"

    print("\n| nψ | d | O_d rows | recursion time | recursion peak | explicit QR time/mem ratio "
          "| explicit H SVD time/mem ratio |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        rec = r["recursion"]
        print(f"| {r['n_psi']} | {r['depth']} | {r['O_rows']} | {1e3 * rec['time_s']:.2f} ms "
              f"| {rec['peak_bytes'] / 1e3:.0f} kB | {cell(r, 'explicit_qr')} | {cell(r, 'explicit_svd')} |")
    print(f"\nGoal: n_x = {NX}, nψ = 4, automatic depth {goal['depth']}: {1e3 * goal_t:.1f} ms "
          f"(target < 500 ms: {'met' if goal['met'] else 'NOT met'})")


if __name__ == "__main__":
    main()
