"""Core performance, measured as ratios in one run (issue 2).

1. LPR-ARX on N = 10⁶ samples (SISO, na = nb = 2, nk = 1, one scheduling signal, poly:2): wall time
   of ``identify_arx`` (regressor built in chunks + chunked QR) against a bare ``numpy.linalg.lstsq``
   on the *prebuilt* regressor (regressor construction not timed for the baseline), and the peak
   memory that ``identify_arx`` allocates (tracemalloc) relative to the bytes of u, y, p.
2. ``LPVSS.simulate`` throughput with nx = 4, nψ = 3 (samples per second, after JIT warm-up).
3. ``Dataset.read`` of a CSV with 10⁶ rows, reading 5 of its 6 columns (time, u, two y, p; issue 25):
   wall time and peak resident-memory growth against pyarrow's ``read_csv`` of the same 5 columns
   converted to numpy, each in a fresh subprocess (peak = VmHWM after resetting it through
   /proc/self/clear_refs, minus the resident size before the read), memory relative to the bytes of
   the 5 float64 columns.

Run: ``.venv/bin/python benchmarks/bench_core.py`` → benchmarks/results/core.json
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import tracemalloc
from functools import partial
from pathlib import Path

import numpy as np
from timing import best_of

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.identify.arx import identify_arx
from lpvflow.models import LPVSS


def lpr_regressor(u: np.ndarray, y: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """The same 12-column shifted-form regressor identify_arx builds, in one piece."""
    n = len(y)
    cols = []
    for lag in (1, 2):
        cols += [-y[2 - lag : n - lag, 0] * psi[2 - lag : n - lag, l] for l in range(3)]
    for lag in (1, 2):
        cols += [u[2 - lag : n - lag, 0] * psi[2 - lag : n - lag, l] for l in range(3)]
    return np.column_stack(cols)


def bench_identify(n: int = 1_000_000) -> dict:
    rng = np.random.default_rng(0)
    u, p = rng.normal(size=(n, 1)), rng.uniform(-1, 1, size=(n, 1))
    y = np.convolve(u[:, 0], [0, 1.0, 0.5], mode="full")[:n, None] + 0.1 * rng.normal(size=(n, 1))
    data = Dataset(u, y, p, 1.0)
    psi = Basis.poly(2).eval(p)
    phi = lpr_regressor(u, y, psi)
    target = y[2:, 0]
    t_lstsq = best_of(partial(np.linalg.lstsq, phi, target, rcond=None))
    t_ours = best_of(partial(identify_arx, data, 2, 2, 1, "poly:2"))
    theta_ref = np.linalg.lstsq(phi, target, rcond=None)[0]
    est = identify_arx(data, 2, 2, 1, "poly:2")
    theta_ours = np.concatenate([est.A[:, :, 0, 0].ravel(), est.B[1:, :, 0, 0].ravel()])
    del phi
    tracemalloc.start()
    identify_arx(data, 2, 2, 1, "poly:2")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    input_bytes = u.nbytes + y.nbytes + p.nbytes
    return {
        "N": n,
        "time_identify_arx_s": t_ours,
        "time_lstsq_prebuilt_s": t_lstsq,
        "time_ratio": t_ours / t_lstsq,
        "peak_alloc_bytes": peak,
        "input_bytes": input_bytes,
        "memory_ratio": peak / input_bytes,
        "max_coefficient_difference_vs_lstsq": float(np.max(np.abs(theta_ours - theta_ref))),
    }


def bench_simulate(n: int = 2_000_000, nx: int = 4, n_psi: int = 3) -> dict:
    rng = np.random.default_rng(1)
    A = rng.normal(size=(n_psi, nx, nx)) * 0.1
    A[0] += 0.5 * np.eye(nx)
    ss = LPVSS(A, rng.normal(size=(n_psi, nx, 1)), rng.normal(size=(n_psi, 1, nx)), np.zeros((n_psi, 1, 1)),
               Basis.poly(2), 1.0)
    u, p = rng.normal(size=(n, 1)), rng.uniform(-1, 1, size=(n, 1))
    ss.simulate(u[:100], p[:100])  # JIT warm-up
    t = best_of(lambda: ss.simulate(u, p))
    return {"N": n, "nx": nx, "n_psi": n_psi, "time_s": t, "samples_per_s": n / t}


#: Run in a fresh interpreter by :func:`bench_read_csv`: argv = CSV path, "lpvflow" or "pyarrow";
#: prints the wall time and the peak resident-memory growth (bytes) of one read as JSON.
READ_PROBE = """
import json, sys, time
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from lpvflow.data import Dataset

COLUMNS = ["time", "u", "y1", "y2", "p"]

def status(key):
    line = next(l for l in open("/proc/self/status") if l.startswith(key + ":"))
    return int(line.split()[1]) * 1024

def read(path):
    if sys.argv[2] == "lpvflow":
        return Dataset.read(path, ["u"], ["y1", "y2"], ["p"])
    table = pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(
        include_columns=COLUMNS, column_types=dict.fromkeys(COLUMNS, pa.float64())))
    return {name: table.column(name).to_numpy() for name in COLUMNS}

read(sys.argv[3])  # warm-up on a small file: imports and lazy initialisation are not measured
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # reset the peak resident size (VmHWM) to the current one
before = status("VmRSS")
t0 = time.perf_counter()
result = read(sys.argv[1])
seconds = time.perf_counter() - t0
print(json.dumps({"seconds": seconds, "peak_growth_bytes": status("VmHWM") - before}))
"""


def _read_probe(path: Path, small: Path, reader: str, repeats: int = 3) -> dict:
    """Best time and smallest peak memory growth of ``repeats`` fresh-interpreter reads."""
    runs = [json.loads(subprocess.run([sys.executable, "-c", READ_PROBE, str(path), reader, str(small)],
                                      check=True, capture_output=True, text=True).stdout)
            for _ in range(repeats)]
    return {"time_s": min(r["seconds"] for r in runs),
            "peak_growth_bytes": min(r["peak_growth_bytes"] for r in runs)}


def bench_read_csv(n: int = 1_000_000) -> dict:
    rng = np.random.default_rng(2)
    columns = {"time": np.arange(n) * 0.01, "u": rng.normal(size=n), "y1": rng.normal(size=n),
               "y2": rng.normal(size=n), "p": rng.uniform(-1, 1, size=n), "unused": rng.normal(size=n)}
    with tempfile.TemporaryDirectory() as tmp:
        path, small = Path(tmp) / "data.csv", Path(tmp) / "small.csv"
        header = ",".join(columns)
        np.savetxt(path, np.column_stack(list(columns.values())), delimiter=",", header=header,
                   comments="", fmt="%.17g")
        np.savetxt(small, np.column_stack(list(columns.values()))[:100], delimiter=",", header=header,
                   comments="", fmt="%.17g")
        file_bytes = path.stat().st_size
        ours, arrow = _read_probe(path, small, "lpvflow"), _read_probe(path, small, "pyarrow")
    data_bytes = 5 * n * 8
    return {
        "N": n, "file_columns": len(columns), "columns_read": 5, "file_bytes": file_bytes,
        "data_bytes": data_bytes,
        "time_dataset_read_s": ours["time_s"], "time_pyarrow_s": arrow["time_s"],
        "time_ratio": ours["time_s"] / arrow["time_s"],
        "peak_growth_dataset_read_bytes": ours["peak_growth_bytes"],
        "peak_growth_pyarrow_bytes": arrow["peak_growth_bytes"],
        "memory_ratio_to_data": ours["peak_growth_bytes"] / data_bytes,
        "memory_ratio_to_pyarrow": ours["peak_growth_bytes"] / arrow["peak_growth_bytes"],
    }


def main() -> None:
    results = {"lpr_arx": bench_identify(), "lpvss_simulate": bench_simulate(), "read_csv": bench_read_csv()}
    out = Path(__file__).parent / "results" / "core.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    r, s = results["lpr_arx"], results["lpvss_simulate"]
    print("| measurement | ours | baseline | ratio | goal |")
    print("|---|---|---|---|---|")
    print(f"| LPR-ARX N=10⁶ wall time | {r['time_identify_arx_s']:.3f} s | lstsq on prebuilt regressor "
          f"{r['time_lstsq_prebuilt_s']:.3f} s | {r['time_ratio']:.2f}× | ≤ 1.5× |")
    print(f"| LPR-ARX peak allocation | {r['peak_alloc_bytes'] / 1e6:.1f} MB | input data "
          f"{r['input_bytes'] / 1e6:.1f} MB | {r['memory_ratio']:.2f}× | ≤ 3× |")
    print(f"| LPVSS.simulate nx=4, nψ=3 | {s['samples_per_s'] / 1e6:.2f}·10⁶ samples/s | — | — | ≥ 2·10⁶ |")
    c = results["read_csv"]
    print(f"| Dataset.read CSV 10⁶ × 5 of 6 columns | {c['time_dataset_read_s']:.3f} s | pyarrow "
          f"{c['time_pyarrow_s']:.3f} s | {c['time_ratio']:.2f}× | ≤ 1 s |")
    print(f"| Dataset.read peak memory growth | {c['peak_growth_dataset_read_bytes'] / 1e6:.1f} MB | pyarrow "
          f"{c['peak_growth_pyarrow_bytes'] / 1e6:.1f} MB; data {c['data_bytes'] / 1e6:.1f} MB | "
          f"{c['memory_ratio_to_data']:.2f}× data | ≤ 2× data |")


if __name__ == "__main__":
    main()
