"""Monte Carlo harness for estimator studies: R seeded realizations, local processes or Dask.

A *trial* is a picklable function ``trial(rng) -> {method: parameter vector}`` that draws one data
realization from ``rng`` and runs every estimator on it (a method that fails returns NaNs).
Realization i gets its own generator from ``numpy.random.SeedSequence(seed).spawn(R)[i]``, so the
numbers depend only on (seed, R, trial) — not on where or in which order the realizations run:
serially, on a local process pool (default), or on a Dask distributed cluster (``client=`` a
``distributed.Client`` or a scheduler address ``"tcp://host:port"``).

The thesis Chapter 4 benchmark (systems (4.31)–(4.35), SNR (4.33)) is provided as a ready trial,
:func:`ch4_trial`, used by benchmarks/bench_chapter4.py and the tests.

Statistics over the R estimates p̂ (thesis (4.19)–(4.20)):

    Bias     = ‖p₀ − E{p̂}‖₂
    Variance = ‖E{(p̂ − E{p̂})²}‖₂   (2-norm of the vector of per-parameter variances)
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numba
import numpy as np
import scipy.signal
from tqdm.auto import tqdm

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.errors import DataError, LpvflowError
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.iv import (
    identify_iv_arx,
    identify_iv_oe,
    identify_oe_paa,
    identify_riv,
    parameter_vector,
)
from lpvflow.identify.oe import identify_oe
from lpvflow.lpvio import LPVIO

Trial = Callable[[np.random.Generator], dict[str, np.ndarray]]
#: BLAS thread variables pinned to 1 in pool workers: many small solves in parallel processes are
#: far faster single-threaded than with oversubscribed BLAS threads.
_BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _run_one(task: tuple[Trial, np.random.SeedSequence]) -> dict[str, np.ndarray]:
    trial, seed_seq = task
    result = trial(np.random.default_rng(seed_seq))
    return {name: np.asarray(value, dtype=float).ravel() for name, value in result.items()}


@contextmanager
def _single_threaded_blas_env():
    """Environment inherited by spawned workers: one BLAS thread each (restored afterwards)."""
    saved = {k: os.environ.get(k) for k in _BLAS_THREAD_VARS}
    os.environ.update({k: "1" for k in _BLAS_THREAD_VARS})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _stack(results: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    names = list(results[0])
    for i, res in enumerate(results):
        if list(res) != names:
            raise DataError(f"realization {i} returned methods {list(res)}, the first one {names}; "
                            "a trial must always return the same methods")
    return {name: np.vstack([res[name] for res in results]) for name in names}


def run_monte_carlo(trial: Trial, runs: int, seed: int = 0, client: Any = None, workers: int | None = None,
                    progress: bool = True, description: str = "Monte Carlo") -> dict[str, np.ndarray]:
    """Run ``trial`` on ``runs`` independent realizations; returns {method: estimates (runs, n)}.

    Args:
        trial: picklable ``trial(rng) -> {method: parameter vector}`` (a module-level function or a
            ``functools.partial`` of one).
        seed: root of the SeedSequence; realization i uses child i.
        client: a ``distributed.Client`` or a scheduler address ``"tcp://…"``; runs on Dask.
        workers: local processes when ``client`` is None (default: CPU count); 0 or 1 runs
            serially in this process.
        progress: show a tqdm progress bar.
    """
    if runs < 1:
        raise DataError(f"runs must be >= 1, got {runs}")
    tasks = [(trial, child) for child in np.random.SeedSequence(seed).spawn(runs)]
    bar = tqdm(total=runs, desc=description, disable=not progress)
    try:
        if client is not None:
            results = _run_dask(tasks, client, bar)
        elif workers is not None and workers <= 1:
            results = []
            for task in tasks:
                results.append(_run_one(task))
                bar.update()
        else:
            n_workers = min(workers or os.cpu_count() or 1, runs)
            with _single_threaded_blas_env(), ProcessPoolExecutor(
                    n_workers, mp_context=get_context("spawn")) as pool:
                results = []
                for res in pool.map(_run_one, tasks, chunksize=max(1, runs // (4 * n_workers))):
                    results.append(res)
                    bar.update()
    finally:
        bar.close()
    return _stack(results)


def _run_dask(tasks: list, client: Any, bar: Any) -> list[dict[str, np.ndarray]]:
    from distributed import Client, as_completed

    own = isinstance(client, str)
    if own:
        client = Client(client)
    try:
        futures = client.map(_run_one, tasks, pure=False)
        for _ in as_completed(futures):
            bar.update()
        return client.gather(futures)
    finally:
        if own:
            client.close()


def summarize(estimates: np.ndarray, p0: np.ndarray) -> dict[str, Any]:
    """Bias (4.19), Variance (4.20), per-parameter mean/std over the runs that did not fail (no NaN)."""
    estimates = np.atleast_2d(np.asarray(estimates, dtype=float))
    p0 = np.asarray(p0, dtype=float).ravel()
    if estimates.shape[1] != p0.size:
        raise DataError(f"estimates have {estimates.shape[1]} parameters, p0 has {p0.size}")
    ok = np.isfinite(estimates).all(axis=1)
    if not ok.any():
        return {"bias": float("nan"), "variance": float("nan"), "runs": 0, "failed": len(ok)}
    good = estimates[ok]
    mean = good.mean(axis=0)
    var = ((good - mean) ** 2).mean(axis=0)
    return {
        "bias": float(np.linalg.norm(p0 - mean)),
        "variance": float(np.linalg.norm(var)),
        "mean": mean.tolist(),
        "std": np.sqrt(var).tolist(),
        "runs": int(ok.sum()),
        "failed": int((~ok).sum()),
    }


def write_json(path: str | os.PathLike, payload: dict) -> None:
    """Write a results dictionary as indented JSON (parent folders created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(payload, indent=1) + "\n")


# ============================================= thesis Chapter 4 benchmark
#: True parameters [a_{1,0..2}, a_{2,0..2}, b_{0,0..2}, b_{1,0..2}] of (4.31)–(4.32), ψ = [1, θ, θ²].
CH4_P0 = np.array([1.0, -0.5, 0.2, 0.5, -0.7, -0.1, 0.5, -0.4, 0.01, 0.2, -0.3, -0.02])
#: Quasi-LPV system (4.34)–(4.35): a₂ has leading coefficient 1.
CH4_QUASI_P0 = np.array([1.0, -0.5, 0.2, 1.0, -0.7, -0.1, 0.5, -0.4, 0.01, 0.2, -0.3, -0.02])
#: Scheduling frequency: θ(k) = 0.5 sin(0.35π t) + 0.5 sampled at t = 0.1 k (see bench_chapter4.py).
CH4_OMEGA = 0.035 * np.pi
#: Coloured-noise filter H = 1/(1 − q⁻¹ + 0.2 q⁻²) (corrected misprint).
CH4_NOISE_DEN = np.array([1.0, -1.0, 0.2])


def ch4_model(p0: np.ndarray = CH4_P0, form: str = "static") -> LPVIO:
    """The Chapter 4 system as an LPVIO: na = 2, input lags 1–2, ψ = [1, θ, θ²]."""
    A = np.zeros((2, 3, 1, 1))
    B = np.zeros((3, 3, 1, 1))
    A[0, :, 0, 0], A[1, :, 0, 0] = p0[0:3], p0[3:6]
    B[1, :, 0, 0], B[2, :, 0, 0] = p0[6:9], p0[9:12]
    one = np.ones((1, 1), dtype=int)
    return LPVIO(A, B, Basis.poly(2), 1.0, form=form, na=2 * one, nb=2 * one, nk=one)


@numba.njit(cache=True)
def _quasi_lpv_output(u: np.ndarray, p0: np.ndarray) -> np.ndarray:
    """x(k) = −a₁(θ)x(k−1) − a₂(θ)x(k−2) + b₀(θ)u(k−1) + b₁(θ)u(k−2), θ(k) = 0.5 cos(x(k−1))."""
    n = len(u)
    x = np.zeros(n)
    for k in range(n):
        x1 = x[k - 1] if k >= 1 else 0.0
        x2 = x[k - 2] if k >= 2 else 0.0
        u1 = u[k - 1] if k >= 1 else 0.0
        u2 = u[k - 2] if k >= 2 else 0.0
        th = 0.5 * np.cos(x1)
        c = np.array([1.0, th, th * th])
        x[k] = (-(c @ p0[0:3]) * x1 - (c @ p0[3:6]) * x2 + (c @ p0[6:9]) * u1 + (c @ p0[9:12]) * u2)
    return x


def quasi_scheduling(y: np.ndarray) -> np.ndarray:
    """θ(k) = 0.5 cos(y(k−1)) (θ(0) from y(−1) = 0): thesis §4.6 quasi-LPV scheduling."""
    y = np.asarray(y, dtype=float).reshape(len(y), -1)[:, 0]
    return 0.5 * np.cos(np.concatenate([[0.0], y[:-1]]))[:, None]


def ch4_data(rng: np.random.Generator, snr_db: float, noise: str = "white", n: int = 5000,
             omega: float = CH4_OMEGA) -> Dataset:
    """One realization: u ~ U[−1, 1], output noise scaled to SNR = 10 log₁₀(P_x / P_v) (4.33).

    ``noise``: ``"white"`` (Table 4.1), ``"coloured"`` (v = H e, Table 4.4) or ``"quasi"`` (the
    quasi-LPV system with white noise, Table 4.8; the true θ uses the noise-free output, the
    identifier sees θ computed from the noisy y). ``omega``: θ(k) = 0.5 sin(ω k) + 0.5.
    """
    u = rng.uniform(-1.0, 1.0, n)
    e = rng.standard_normal(n)
    if noise == "quasi":
        x = _quasi_lpv_output(u, CH4_QUASI_P0)
    elif noise in ("white", "coloured"):
        theta = 0.5 * np.sin(omega * np.arange(n)) + 0.5
        x = ch4_model().simulate(u[:, None], theta[:, None])[:, 0]
        if noise == "coloured":
            e = scipy.signal.lfilter([1.0], CH4_NOISE_DEN, e)
    else:
        raise DataError(f"noise must be 'white', 'coloured' or 'quasi', got {noise!r}")
    v = e * np.sqrt(np.mean(x**2) / np.mean(e**2) / 10 ** (snr_db / 10))
    y = x + v
    p = quasi_scheduling(y) if noise == "quasi" else theta[:, None]
    return Dataset(u[:, None], y[:, None], p, 1.0)


def _ch4_estimators(quasi: bool) -> dict[str, Callable[[Dataset], LPVIO]]:
    orders = (2, 2, 1, Basis.poly(2))
    sched = quasi_scheduling if quasi else None
    return {
        "LS": lambda d: identify_arx(d, *orders, form="static"),
        "OE": lambda d: identify_oe_paa(d, *orders, form="static"),
        "OE-PEM": lambda d: identify_oe(d, *orders, form="static"),
        "IV-ARX": lambda d: identify_iv_arx(d, *orders, form="static", scheduling=sched),
        "IV-OE": lambda d: identify_iv_oe(d, *orders, form="static", scheduling=sched),
        "IV-OE-batch": lambda d: identify_iv_oe(d, *orders, form="static", auxiliary="batch",
                                                scheduling=sched),
        "RIV": lambda d: identify_riv(d, *orders, form="static"),
        "SRIV": lambda d: identify_riv(d, *orders, form="static", simplified=True),
    }


def ch4_trial(rng: np.random.Generator, snr_db: float, noise: str = "white", n: int = 5000,
              methods: tuple[str, ...] = ("LS", "IV-OE"), omega: float = CH4_OMEGA) -> dict[str, np.ndarray]:
    """One Chapter 4 realization identified by ``methods`` (static form); NaNs where a method fails."""
    data = ch4_data(rng, snr_db, noise, n, omega)
    estimators = _ch4_estimators(noise == "quasi")
    out = {}
    for name in methods:
        try:
            out[name] = parameter_vector(estimators[name](data))
        except LpvflowError:
            out[name] = np.full(CH4_P0.size, np.nan)
    return out


def ch4_table_trial(rng: np.random.Generator, snrs: tuple[float, ...], noise: str = "white",
                    n: int = 5000, methods: tuple[str, ...] = ("LS", "IV-OE"),
                    omega: float = CH4_OMEGA) -> dict[str, np.ndarray]:
    """One realization per SNR (drawn in turn from ``rng``): keys ``"<method>@<snr>"``."""
    out = {}
    for snr in snrs:
        for name, value in ch4_trial(rng, snr, noise, n, methods, omega).items():
            out[f"{name}@{snr:g}"] = value
    return out
