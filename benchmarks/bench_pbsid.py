"""LPV PBSIDopt (seed 004) against LPV-IO + Ho–Kalman reduction (seed 000), issue 11.

(a) ``table2``: seed 004 Table 2 — mean VAF per output on a fresh noise-free set over Monte Carlo
    runs of the Verdult–Verhaegen benchmark (:mod:`lpvflow.identify.pbsid_examples`), Algorithm 2
    (kernel) with and without Tikhonov + GCV, p = 3, 5, N = 500, 1000, SNR 40 dB and ∞.
(b) ``orders``: seed 000 Sec. V-A style — mean BFR (simulated output, noise-free validation) per
    model order at SNR 20 dB, best setting per order: PBSIDopt (kernel + GCV, p = 2…5, f ∈ {p, p−1})
    vs LPR-ARX (na = nb = 1…4, nk = 1) and LPR-ARMAX (na = nb = nc = 1…3), realized and reduced by
    :func:`lpvflow.identify.reduce.reduce`;
    plus wall time and peak traced memory of one run at p = na = 5, n_μ = 4.
(c) ``scaling``: wall time vs number of scheduling functions n_μ = 2…6 and past window p = 2…5
    (IO side: na = nb = p), N = 1000, PBSIDopt primal and kernel and LPR-ARX + reduction
    → ``benchmarks/pbsid_scaling.png``.

Run: ``.venv/bin/python benchmarks/bench_pbsid.py [table2|orders|scaling|all] [--runs R]``
→ ``benchmarks/results/pbsid_<part>.json`` and a markdown table on stdout. BLAS is single-threaded
and runs go to a process pool (``--workers``), which is faster on a shared machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import tracemalloc
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from timing import best_of
from tqdm import tqdm

from lpvflow.basis import Basis, SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError, ModelError
from lpvflow.identify.armax import identify_armax
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.pbsid import identify_pbsid, identify_pbsid_orders
from lpvflow.identify.pbsid_examples import verdult_benchmark, verdult_experiment, verdult_signals
from lpvflow.identify.reduce import reduce
from lpvflow.models import LPVSS
from lpvflow.validate.metrics import bfr, vaf

RESULTS = Path(__file__).parent / "results"
N_VALIDATION = 1000
MAX_ORDER = 12
#: Families compared per model order; ARMAX is lpvflow.identify.armax (pseudo-linear regression).
FAMILIES = ("pbsid", "lpr-arx", "lpr-armax")

#: Seed 004 Table 2 (notes_004 §6.1): (p, N, SNR) → (Alg. 2 VAF per output, + Tikhonov/GCV).
PAPER_TABLE2 = {
    (3, 500, 40): ([93.2, 93.5, 93.8], [96.8, 96.7, 96.8]),
    (3, 500, None): ([100.0, 100.0, 100.0], [99.9, 100.0, 100.0]),
    (3, 1000, 40): ([98.0, 98.0, 98.0], [98.4, 98.4, 98.5]),
    (3, 1000, None): ([100.0, 100.0, 100.0], [99.9, 99.9, 99.9]),
    (5, 500, 40): ([66.5, 67.2, 67.6], [90.5, 90.6, 90.8]),
    (5, 500, None): ([99.4, 99.4, 99.4], [99.2, 99.3, 99.3]),
    (5, 1000, 40): ([17.2, 19.1, 21.0], [94.8, 95.0, 95.1]),
    (5, 1000, None): ([100.0, 100.0, 100.0], [100.0, 100.0, 100.0]),
}


def simulated(model: LPVSS, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        y = model.simulate(u, p)
    return np.where(np.isfinite(y), y, 1e300)  # a diverging model scores 0


def validation_set(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    u, p = verdult_signals(N_VALIDATION, np.random.default_rng([seed, 1]))
    return u, p, verdult_benchmark().simulate(u, p)


def save(name: str, payload: dict) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"pbsid_{name}.json").write_text(json.dumps(payload, indent=1))


def run_pool(fn, seeds: list[int], workers: int, what: str) -> list:
    with ProcessPoolExecutor(workers) as pool:
        return list(tqdm(pool.map(fn, seeds), total=len(seeds), desc=what))


# ---------------------------------------------------------------------------------- (a) Table 2
#: The paper's "SNR = 40" has no unit or definition: read as 40 dB, and as a power ratio of 40.
SNR_READINGS = {"40 dB": 40.0, "ratio 40 (16.0 dB)": 10 * np.log10(40.0), "∞": np.inf}


def table2_cells() -> list[tuple[int, int, str]]:
    return [(past, n, reading) for (past, n, snr) in PAPER_TABLE2 for reading in SNR_READINGS
            if (snr is None) == (reading == "∞")]


def table2_run(seed: int) -> dict:
    u, p, y = validation_set(seed)
    out = {}
    for past, n, reading in table2_cells():
        rng = np.random.default_rng([seed, past, n, int(10 * min(SNR_READINGS[reading], 999))])
        data, _ = verdult_experiment(n, rng, SNR_READINGS[reading])
        for reg in (None, "gcv"):
            model = identify_pbsid(data, 4, past, form="kernel", regularization=reg)
            out[f"{past}|{n}|{reading}|{reg}"] = vaf(y, simulated(model, u, p)).tolist()
    return out


def bench_table2(runs: int, workers: int) -> dict:
    results = run_pool(table2_run, list(range(runs)), workers, "Table 2 runs")
    rows = []
    for past, n, reading in table2_cells():
        paper_plain, paper_gcv = PAPER_TABLE2[(past, n, None if reading == "∞" else 40)]
        ours = {reg: np.array([r[f"{past}|{n}|{reading}|{reg}"] for r in results]) for reg in (None, "gcv")}
        rows.append({
            "p": past, "N": n, "snr": reading,
            "ours_alg2": ours[None].mean(axis=0).round(2).tolist(),
            "ours_alg2_gcv": ours["gcv"].mean(axis=0).round(2).tolist(),
            "ours_alg2_median": np.median(ours[None], axis=0).round(2).tolist(),
            "ours_alg2_gcv_median": np.median(ours["gcv"], axis=0).round(2).tolist(),
            "paper_alg2": paper_plain, "paper_alg2_gcv": paper_gcv,
        })
    payload = {"runs": runs, "validation_samples": N_VALIDATION, "rows": rows,
               "snr_definition": "10 log10(sum var(y_det) / sum var(y - y_det)), innovation through K"}
    save("table2", payload)
    print(f"\n### Seed 004 Table 2: mean VAF per output (%), {runs} runs (median in brackets)\n")
    print("| p | N | SNR | Alg. 2 ours | Alg. 2 paper | +GCV ours | +GCV paper |")
    print("|---|---|---|---|---|---|---|")

    def fmt(v: list[float]) -> str:
        return " / ".join(f"{x:.1f}" for x in v)

    for r in rows:
        print(f"| {r['p']} | {r['N']} | {r['snr']} | {fmt(r['ours_alg2'])} ({fmt(r['ours_alg2_median'])}) | "
              f"{fmt(r['paper_alg2'])} | {fmt(r['ours_alg2_gcv'])} ({fmt(r['ours_alg2_gcv_median'])}) | "
              f"{fmt(r['paper_alg2_gcv'])} |")
    return payload


# ------------------------------------------------------------------------ (b) fit per model order
def io_reduced_models(data: Dataset, na: int, armax: bool = False) -> dict[int, LPVSS]:
    """Every reduced order of the LPR-ARX (or ARMAX with nc = na) realization, up to MAX_ORDER."""
    try:
        io = identify_armax(data, na, na, 1, na) if armax else identify_arx(data, na, na, 1, "affine")
    except DataError:  # the pseudo-linear regression lost excitation: no model for this setting
        return {}
    full = io.to_ss()
    models = {}
    for order in range(1, min(full.nx, MAX_ORDER) + 1):
        try:
            models[order] = full if order == full.nx else reduce(full, order=order)
        except ModelError:  # order above the numerical Hankel rank
            break
    return models


def io_reduced(data: Dataset, na: int, order: int = 4) -> LPVSS:
    """LPR-ARX (na = nb, nk = 1) realized and reduced by Lemma 1 of seed 000."""
    return reduce(identify_arx(data, na, na, 1, "affine").to_ss(), order=order)


def orders_run(seed: int) -> dict:
    u, p, y = validation_set(seed)
    data, _ = verdult_experiment(1000, np.random.default_rng([seed, 7]), 20.0)
    fits: dict[str, dict[int, float]] = {}
    for past in range(2, 6):
        for future in (past, past - 1):
            if future < 2:
                continue
            orders = list(range(1, min(future * 3, MAX_ORDER) + 1))
            models = identify_pbsid_orders(data, orders, past, future, form="kernel", regularization="gcv")
            fits[f"pbsid p={past} f={future}"] = {
                m.nx: float(bfr(y, simulated(m, u, p)).mean()) for m in models}
    for na in range(1, 5):
        fits[f"lpr-arx+reduce na=nb={na}"] = {
            n: float(bfr(y, simulated(m, u, p)).mean()) for n, m in io_reduced_models(data, na).items()}
    for na in range(1, 4):
        fits[f"lpr-armax+reduce na=nb=nc={na}"] = {
            n: float(bfr(y, simulated(m, u, p)).mean()) for n, m in io_reduced_models(data, na, True).items()}
    return fits


def cost(fn) -> tuple[float, float]:
    """Best-of-3 wall time (s, untraced) and peak traced memory (MB, one traced call)."""
    elapsed = best_of(fn, 3)
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return elapsed, peak


def one_run_costs() -> dict:
    data, _ = verdult_experiment(1000, np.random.default_rng(123), 20.0)

    out = {"io_lpr_arx_na5_reduce4": cost(lambda: io_reduced(data, 5))}
    for form in ("kernel", "primal"):
        out[f"pbsid_{form}_p5_gcv"] = cost(
            lambda f=form: identify_pbsid(data, 4, 5, form=f, regularization="gcv"))
    return {k: {"seconds": v[0], "peak_MB": v[1]} for k, v in out.items()}


def bench_orders(runs: int, workers: int) -> dict:
    results = run_pool(orders_run, list(range(runs)), workers, "fit-per-order runs")
    settings = sorted(results[0])
    mean = {s: {n: float(np.mean([r[s].get(n, 0.0) for r in results])) for n in results[0][s]}
            for s in settings}
    best = {}
    for family in FAMILIES:
        best[family] = {}
        for n in range(1, MAX_ORDER + 1):
            cands = [(mean[s][n], s) for s in settings if s.startswith(family) and n in mean[s]]
            if cands:
                fit, setting = max(cands)
                best[family][n] = {"bfr": round(fit, 2), "setting": setting}
    costs = one_run_costs()
    top = {f: max(best[f].items(), key=lambda kv: kv[1]["bfr"]) for f in best}
    fastest_pbsid = min(costs["pbsid_kernel_p5_gcv"]["seconds"], costs["pbsid_primal_p5_gcv"]["seconds"])
    io_best = max((top[f][1]["bfr"], f) for f in FAMILIES if f != "pbsid")
    payload = {"runs": runs, "snr_db": 20.0, "N": 1000, "mean_bfr": mean, "best_per_order": best,
               "best_order": {f: {"order": n, **v} for f, (n, v) in top.items()},
               "io_best_minus_pbsid_best_bfr": io_best[0] - top["pbsid"][1]["bfr"],
               "one_run_costs": costs,
               "time_ratio_pbsid_over_io": fastest_pbsid / costs["io_lpr_arx_na5_reduce4"]["seconds"]}
    save("orders", payload)
    print(f"\n### Mean BFR (%) per model order, SNR 20 dB, N = 1000, {runs} runs (best setting per order)\n")
    print("| order | PBSIDopt (kernel+GCV) | LPR-ARX + reduction | LPR-ARMAX + reduction |")
    print("|---|---|---|---|")
    for n in range(1, MAX_ORDER + 1):
        cells = [best[f].get(n) for f in FAMILIES]
        print(f"| {n} | " + " | ".join(f"{v['bfr']:.1f} ({v['setting'].split(' ', 1)[1]})" if v else "–"
                                        for v in cells) + " |")
    gap = payload["io_best_minus_pbsid_best_bfr"]
    print(f"\nBest IO + reduction minus best PBSIDopt: {gap:+.1f} BFR points")
    print("\n| one run (p = na = 5, n_μ = 4, N = 1000) | wall time (s) | peak traced memory (MB) |")
    print("|---|---|---|")
    for k, v in costs.items():
        print(f"| {k} | {v['seconds']:.3f} | {v['peak_MB']:.1f} |")
    print(f"\nPBSIDopt (fastest form) / IO + reduction time ratio: {payload['time_ratio_pbsid_over_io']:.1f}")
    return payload


# ------------------------------------------------------------------------------------ (c) scaling
def scaling_data(n_mu: int, rng: np.random.Generator) -> Dataset:
    """The benchmark's A^(1), B^(1), C, K^(1) plus n_μ − 1 random scheduled parts, p ~ U(0, 1)."""
    base = verdult_benchmark()
    A = np.concatenate([base.A[:1], 0.3 / n_mu * rng.uniform(-1, 1, size=(n_mu - 1, 4, 4))])
    B = np.concatenate([base.B[:1], 0.3 * rng.uniform(-1, 1, size=(n_mu - 1, 4, 2))])
    K = np.zeros((n_mu, 4, 3))
    K[0] = base.K[0]
    C = np.zeros((n_mu, 3, 4))
    C[0] = base.C[0]
    system = LPVSS(A, B, C, np.zeros((n_mu, 3, 2)), Basis.affine(n_mu - 1), 1.0, K=K)
    u, _ = verdult_signals(1000, rng)
    p = rng.uniform(0, 1, size=(1000, n_mu - 1))
    y = system.simulate(u, p, e=0.05 * rng.normal(size=(1000, 3)))
    return Dataset(u, y, p, 1.0)


PRIMAL_ROW_LIMIT = 12000


def bench_scaling() -> dict:
    from lpvflow.identify.pbsid import regression_rows

    rows = []
    grid = [(m, p) for m in range(2, 7) for p in range(2, 6)]
    for n_mu, past in tqdm(grid, desc="scaling grid"):
        data = scaling_data(n_mu, np.random.default_rng([n_mu, past]))
        q = regression_rows(2, 3, n_mu, past)
        row = {"n_mu": n_mu, "p": past, "primal_rows": q,
               "io": best_of(lambda d=data, a=past: io_reduced(d, a), 2),
               "kernel": best_of(lambda d=data, a=past: identify_pbsid(d, 4, a, form="kernel"), 1),
               "primal": (best_of(lambda d=data, a=past: identify_pbsid(d, 4, a, form="primal"), 1)
                          if q <= PRIMAL_ROW_LIMIT else None)}
        rows.append(row)
    payload = {"N": 1000, "rows": rows, "primal_row_limit": PRIMAL_ROW_LIMIT}
    save("scaling", payload)
    plot_scaling(rows, Path(__file__).parent / "pbsid_scaling.png")
    print("\n### Wall time (s), N = 1000, order 4 (primal skipped above "
          f"{PRIMAL_ROW_LIMIT} regression rows)\n")
    print("| n_μ | p | rows of [Z;U] | PBSIDopt primal | PBSIDopt kernel | LPR-ARX(na=nb=p) + reduction |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        primal = "–" if r["primal"] is None else f"{r['primal']:.3f}"
        print(f"| {r['n_mu']} | {r['p']} | {r['primal_rows']} | {primal} | {r['kernel']:.3f} | "
              f"{r['io']:.4f} |")
    return payload


def plot_scaling(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    styles = {"primal": ("PBSIDopt primal", "tab:red"), "kernel": ("PBSIDopt kernel", "tab:blue"),
              "io": ("LPR-ARX + reduction", "tab:green")}
    for key, (label, color) in styles.items():
        for past, ls in ((3, "--"), (5, "-")):
            pts = [(r["n_mu"], r[key]) for r in rows if r["p"] == past and r[key] is not None]
            if pts:
                axes[0].semilogy(*zip(*pts, strict=True), ls, marker="o", color=color,
                                 label=f"{label}, p={past}")
        pts = [(r["p"], r[key]) for r in rows if r["n_mu"] == 4 and r[key] is not None]
        axes[1].semilogy(*zip(*pts, strict=True), "-", marker="o", color=color, label=label)
    axes[0].set(xlabel="number of scheduling functions n_μ", ylabel="wall time (s)", title="vs n_μ")
    axes[1].set(xlabel="past window p (IO: na = nb = p)", title="vs p at n_μ = 4")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Identification time, N = 1000, nu = 2, ny = 3, order 4")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("part", nargs="?", default="all", choices=["table2", "orders", "scaling", "all"])
    parser.add_argument("--runs", type=int, default=100, help="Monte Carlo runs for table2 (default 100)")
    parser.add_argument("--order-runs", type=int, default=20, help="Monte Carlo runs for orders (default 20)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    if args.part in ("scaling", "all"):
        bench_scaling()
    if args.part in ("orders", "all"):
        bench_orders(args.order_runs, args.workers)
    if args.part in ("table2", "all"):
        bench_table2(args.runs, args.workers)


if __name__ == "__main__":
    main()
