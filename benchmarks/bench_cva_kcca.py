"""Seed 001 (LPV CVA) and seed 003 (KCCA-LFR) reproductions over 10 seeds (issue 12).

1. CVA on the forced Lorenz example (T = 0.005, N = 10 000, T·A₂ corrected, ρ = [1, y]): the six
   leading squared canonical correlations against the paper's (0.999999, 0.99999, 0.999, 0.999, 0.95,
   0.94), the AIC-selected ARX and state orders, and 1- and 5-step-ahead prediction BFR on 3000
   noise-free validation samples (scheduling inside the horizon from the predicted output).
2. KCCA-LFR on system (26) of seed 003, N = N_val = 400, noise std 0.05, the paper's hyper-parameters:
   Example 1 (D11 = −0.5, coordinate descent with scale normalisation) and Example 2 (D11 = 0,
   least squares + SVD); validation BFR/VAF of the simulated output against the paper's single run.

The data generators are the ones the tests use (tests/test_cva.py, tests/test_kcca_lfr.py).
BLAS runs single-threaded: the timings are per core on a shared machine.

Run: ``.venv/bin/python benchmarks/bench_cva_kcca.py`` → benchmarks/results/cva_kcca.json
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from test_cva import PAPER_R2, lorenz_data  # noqa: E402
from test_kcca_lfr import PAPER_BFR, seed003_data, seed003_system  # noqa: E402

from lpvflow.identify.cva import cva_fit, predict_ahead  # noqa: E402
from lpvflow.identify.kcca_lfr import identify_kcca_lfr  # noqa: E402
from lpvflow.validate.metrics import bfr, vaf  # noqa: E402

SEEDS = range(10)
PAPER_VAF = {"rational": 99.74, "affine": 99.84}


def summary(values: list[float]) -> dict:
    a = np.asarray(values)
    return {"mean": float(a.mean()), "std": float(a.std(ddof=1)), "min": float(a.min()),
            "max": float(a.max())}


def bench_cva() -> dict:
    runs = []
    for seed in tqdm(SEEDS, desc="CVA Lorenz"):
        rng = np.random.default_rng(seed)
        train = lorenz_data(10_000, rng)
        t0 = time.perf_counter()
        fit = cva_fit(train, "affine", max_arx_order=40)
        seconds = time.perf_counter() - t0
        val = lorenz_data(3000, rng, noisy=False)
        pred = {}
        for h in (1, 5):
            rows, y_hat = predict_ahead(fit, val, h)
            pred[h] = float(bfr(val.y[rows], y_hat)[0])
        rows, y_hat = predict_ahead(cva_fit(train, "affine", max_arx_order=40, state_order=4), val, 5)
        pred["paper_order"] = float(bfr(val.y[rows], y_hat)[0])
        naive = float(bfr(val.y[rows], val.y[rows - 5])[0])
        r2 = fit.squared_correlations[:7]
        runs.append({"seed": seed, "arx_order": fit.arx.order, "state_order": fit.model.nx,
                     "r2": r2.tolist(), "max_r2_error_first6": float(np.max(np.abs(r2[:6] - PAPER_R2))),
                     "bfr_1step": pred[1], "bfr_5step": pred[5], "bfr_5step_order4": pred["paper_order"],
                     "bfr_5step_naive": naive,
                     "seconds": seconds})
    r2 = np.array([r["r2"] for r in runs])
    return {
        "setting": "forced Lorenz, T=0.005, N=10000, sigma_u,w,v = 0.1, 1e-6, 1e-2, rho=[1,y], "
                   "max ARX order 40",
        "paper_r2": [*PAPER_R2.tolist(), 0.57],
        "r2_mean": r2.mean(axis=0).tolist(),
        "max_r2_error_first6": max(r["max_r2_error_first6"] for r in runs),
        "mean_r2_error_first6": float(np.max(np.abs(r2.mean(axis=0)[:6] - PAPER_R2))),
        "seeds_within_0.01": sum(r["max_r2_error_first6"] <= 0.01 for r in runs),
        "arx_orders": [r["arx_order"] for r in runs],
        "state_orders": [r["state_order"] for r in runs],
        "bfr_1step": summary([r["bfr_1step"] for r in runs]),
        "bfr_5step": summary([r["bfr_5step"] for r in runs]),
        "bfr_5step_order4": summary([r["bfr_5step_order4"] for r in runs]),
        "bfr_5step_naive": summary([r["bfr_5step_naive"] for r in runs]),
        "seconds": summary([r["seconds"] for r in runs]),
        "runs": runs,
    }


def bench_kcca(kind: str) -> dict:
    d11 = -0.5 if kind == "rational" else 0.0
    runs = []
    for seed in tqdm(SEEDS, desc=f"KCCA-LFR {kind}"):
        rng = np.random.default_rng(seed)
        system = seed003_system(d11)
        train, _, _ = seed003_data(system, 400, rng, 0.05)
        val, y_val, _ = seed003_data(system, 400, rng, 0.0)
        t0 = time.perf_counter()
        model = identify_kcca_lfr(train, 2, affine=kind == "affine")
        seconds = time.perf_counter() - t0
        y_hat = model.simulate(val.u, val.p)
        runs.append({"seed": seed, "bfr": float(bfr(y_val, y_hat)[0]), "vaf": float(vaf(y_val, y_hat)[0]),
                     "d11": float(model.D11[0, 0]), "seconds": seconds})
    return {
        "setting": f"system (26), D11={d11}, N=N_val=400, noise std 0.05, c=2, sigma=10.5, gamma=500, "
                   "d=3, nx=2",
        "paper_bfr": PAPER_BFR[kind], "paper_vaf": PAPER_VAF[kind],
        "bfr": summary([r["bfr"] for r in runs]), "vaf": summary([r["vaf"] for r in runs]),
        "d11": summary([r["d11"] for r in runs]), "seconds": summary([r["seconds"] for r in runs]),
        "runs": runs,
    }


def main() -> None:
    results = {"cva_lorenz": bench_cva(), "kcca_lfr_rational": bench_kcca("rational"),
               "kcca_lfr_affine": bench_kcca("affine")}
    out = ROOT / "benchmarks" / "results" / "cva_kcca.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    c = results["cva_lorenz"]
    print("| reproduction | paper | lpvflow, 10 seeds: mean ± std [min, max] | time per fit |")
    print("|---|---|---|---|")
    print(f"| CVA Lorenz r₁²…r₆² | {', '.join(f'{v:g}' for v in PAPER_R2)} | "
          f"{', '.join(f'{v:.6f}' for v in c['r2_mean'][:6])} "
          f"(mean: max abs. error {c['mean_r2_error_first6']:.4f}; {c['seeds_within_0.01']}/10 seeds within "
          f"0.01, worst {c['max_r2_error_first6']:.4f}) | "
          f"{c['seconds']['mean']:.1f} s |")
    print(f"| CVA Lorenz orders (ARX, state) | 28, 4 | ARX {min(c['arx_orders'])}–{max(c['arx_orders'])}, "
          f"state {min(c['state_orders'])}–{max(c['state_orders'])} | |")
    horizons = (("1-step", "bfr_1step"), ("5-step", "bfr_5step"), ("5-step, k = 4", "bfr_5step_order4"))
    for label, key in horizons:
        s = c[key]
        print(f"| CVA Lorenz {label} prediction BFR | not reported | {s['mean']:.2f} ± {s['std']:.2f} % "
              f"[{s['min']:.2f}, {s['max']:.2f}] | |")
    s = c["bfr_5step_naive"]
    print(f"| naive y(t+4) ≈ y(t−1) BFR (reference) | | {s['mean']:.2f} % | |")
    for kind, label in (("rational", "Example 1, rational, CD"), ("affine", "Example 2, affine, LS+SVD")):
        k = results[f"kcca_lfr_{kind}"]
        b, v = k["bfr"], k["vaf"]
        print(f"| KCCA-LFR {label}: BFR / VAF | {k['paper_bfr']} / {k['paper_vaf']} % | "
              f"{b['mean']:.2f} ± {b['std']:.2f} [{b['min']:.2f}, {b['max']:.2f}] / {v['mean']:.2f} % | "
              f"{k['seconds']['mean']:.2f} s |")
    print(f"\nresults written to {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
