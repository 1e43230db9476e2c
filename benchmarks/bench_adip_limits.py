"""Physical limit of the ADIP arm step: minimum-time transfers on the nonlinear model (issue 7).

Issue 7 asks for arm steps 0 → ±75° settled (±1°) within 1.5 s, overshoot ≤ 2°, pendulum within ±1°
after settling, |V| ≤ 10 V. Whether the voltage limit forbids it is a property of the plant, not of a
controller: the minimum time T*(φt, Vmax) of a transfer from the upright equilibrium at φ1 = 0 to the
one at φ1 = φt (pendulum up, at rest exactly at T) under |V| ≤ Vmax, solved by direct multiple
shooting (fmu_plants/adip/min_time.py: the model of fmu_plants/reference_models.py, voltage held on
≈ 20 ms intervals, RK4 sub-steps ≤ 1 ms, SLSQP). The plant is odd, f(−x, −V) = −f(x, V) (checked
below), so +φt stands for ±φt.

Every problem is solved from several initial guesses (the smoothstep φ1 = φt(3τ² − 2τ³) with its
rate and the equilibrium voltage V_eq(φ1), stretched over T_guess) and the best converged result is
kept; every start's T is recorded. Trajectory extremes are taken at the RK4 sub-steps.

1. T*(φt, 10 V) for φt ∈ {30, 45, 60, 70, 75}°: peak |V|, share of intervals at the bound, holding
   voltage, arm overshoot and undershoot and largest pendulum angle during the transfer.
2. T*(75°, Vmax) for Vmax ∈ {5, 6, 8, 10, 12} V; an infeasible request (4 V < V_eq(75°)) is refused.
3. The spec's settling instead of exact rest, at 75°:
   (a) terminal |φ1 − φt| ≤ 1°, |φ2| ≤ 1° and nothing else: both must hold at the settling instant
       (measured from the step at t = 0), so its global minimum bounds the ±1° settling time of any
       controller with |V| ≤ 10 V from below (a weak bound: the arm may cross the band at speed);
   (b) the same with |ω1|, |ω2| ≤ 0.05 rad/s, its end state then held by an LQR (linearisation at φt,
       Q = diag(100, 100, 1, 1), R = 1, |V| ≤ 10 V, 5 ms ZOH, 3 s): whether the band is kept;
   (c) the settling-time-optimal transfer that meets the whole spec: N = K + M intervals, the nodes
       k ≥ K inside the band (|φ1 − φt| ≤ 1°, |φ2| ≤ 1°), φ1 ≤ φt + 2° at every node, exact rest at
       node N; minimising T = N h minimises the settling time T_s = K h. The node bounds are shrunk
       until the sub-step trajectory meets the spec too. At 10 V and 5 V. This problem has many
       local minima: T_s is the best found, i.e. an achievable settling time, an upper bound.
4. FMU cross-check: the 75°/10 V transfer re-solved with T fixed at 20 ms · ceil(T*/20 ms) on a 20 ms
   grid (4 FMU steps; minimum input energy), applied open loop to fmu_plants/build/adip.fmu at its
   5 ms step (same 1 ms RK4 sub-steps); arm and pendulum at T against the target and against the
   same profile on the Python model.
Checks: each profile re-simulated by scipy's solve_ivp (RK45, rtol 1e-10) interval by interval on
reference_models.adip_derivatives; T* at 75° from the solver's generic guess and on 10 / 40 ms grids.

Run: .venv/bin/python benchmarks/bench_adip_limits.py
     → results/adip_limits.json, docs/adip_min_time.png
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import matplotlib
import numpy as np
import scipy.linalg
from scipy.integrate import solve_ivp

matplotlib.use("Agg")
import matplotlib.pyplot as plt

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "fmu_plants"))
sys.path.insert(0, str(ROOT / "fmu_plants" / "adip"))
import min_time as mt  # noqa: E402
import reference_models as rm  # noqa: E402

from lpvflow.fmu import open_fmu  # noqa: E402

P = rm.default_parameters("adip")
F = rm.adip_derivatives
TS = 0.005  # FMU communication step
INTERVAL = 0.02
SPEC_SECONDS, SPEC_OVERSHOOT_DEG, SPEC_BAND_DEG = 1.5, 2.0, 1.0
ANGLES = (30, 45, 60, 70, 75)
VOLTAGES = (5, 6, 8, 10, 12)
STARTS = (0.8, 1.5, 2.5)  # T_guess of the smoothstep initial guesses
SETTLE_STARTS = (1.0, 1.4, 1.8)  # guesses of T_s for item 3 (c)
SETTLE_TAIL = 20  # M: intervals from settling to rest in item 3 (c)
HOLD_WEIGHTS = (np.diag([100.0, 100.0, 1.0, 1.0]), np.array([[1.0]]))  # LQR of item 3 (b)


def symmetry_error(samples: int = 200) -> float:
    """max |f(−x, −V) + f(x, V)| over random states and voltages (reference_models)."""
    rng = np.random.default_rng(1)
    errors = [
        np.abs(rm.adip_derivatives(-x, -u, P) + rm.adip_derivatives(x, u, P)).max()
        for x, u in zip(rng.normal(size=(samples, 4)), rng.uniform(-10, 10, (samples, 1)), strict=True)
    ]
    return float(max(errors))


def endpoints(phi_deg: float, p: dict = P) -> tuple[np.ndarray, ...]:
    """x0, xf, u_eq0, u_eq_f of the transfer 0 → phi_deg (the order of `minimum_time_transfer`)."""
    (x0, u0), (xf, uf) = rm.adip_equilibrium(0.0, p), rm.adip_equilibrium(np.deg2rad(phi_deg), p)
    return x0, xf, u0, uf


def quasi_static_guess(phi_t: float, T: float, N: int, p: dict = P) -> tuple[np.ndarray, np.ndarray]:
    """Quasi-static path: φ1 = φt s(t/T), s = 3τ² − 2τ³, its rate, φ2 = ω2 = 0, and the voltage V_eq(φ1)
    that would hold the arm at rest at each point (min_time.smoothstep_guess interpolates states and
    voltages between two given end points instead)."""
    tau = np.linspace(0.0, 1.0, N + 1)
    mid = (tau[:-1] + tau[1:]) / 2
    voltage = np.array([rm.adip_equilibrium(phi_t * s * s * (3 - 2 * s), p)[1][0] for s in mid])
    states = np.array([phi_t * tau**2 * (3 - 2 * tau), 0 * tau, phi_t * 6 * tau * (1 - tau) / T, 0 * tau])
    return voltage[None, :], states


def transfer(
    phi_deg: float,
    vmax: float,
    T_guess: float = 1.5,
    interval: float = INTERVAL,
    generic: bool = False,
    p: dict = P,
    **options,
) -> mt.Transfer:
    """0 → phi_deg, |V| ≤ vmax, on the plant with parameters p, from `quasi_static_guess` or (generic=True)
    the solver's default guess; `options` go to `minimum_time_transfer` (duration, path, ...)."""
    guess = (
        None
        if generic
        else quasi_static_guess(np.deg2rad(phi_deg), T_guess, max(2, round(T_guess / interval)), p)
    )
    return mt.minimum_time_transfer(
        F,
        *endpoints(phi_deg, p),
        vmax,
        p,
        interval=interval,
        T_guess=T_guess,
        guess=guess,
        state_scale=mt.ADIP_STATE_SCALE,
        **options,
    )


def dense(result: mt.Transfer, p: dict = P) -> tuple[np.ndarray, np.ndarray]:
    """Times and states at every RK4 sub-step of the transfer (on the plant with parameters p)."""
    return mt.simulate(F, result.states[0], result.voltage, result.interval, result.substeps, p)


def solve_ivp_end(result: mt.Transfer) -> np.ndarray:
    """Terminal state of the profile on reference_models.adip_derivatives, RK45 rtol 1e-10 per interval."""
    x = result.states[0]
    for t0, t1, u in zip(result.grid[:-1], result.grid[1:], result.voltage, strict=True):
        x = solve_ivp(
            lambda t, x, u=u: rm.adip_derivatives(x, u, P), (t0, t1), x, method="RK45", rtol=1e-10, atol=1e-12
        ).y[:, -1]
    return x


def summary(result: mt.Transfer, phi_deg: float, vmax: float) -> dict:
    """Numbers of one transfer; trajectory extremes from the RK4 sub-steps."""
    x = dense(result)[1]
    target = np.deg2rad(phi_deg)
    v = np.abs(result.voltage[:, 0])
    return {
        "target_deg": phi_deg,
        "vmax": vmax,
        "T": result.T,
        "success": result.success,
        "status": result.status,
        "intervals": len(v),
        "interval_s": result.interval,
        "substeps": result.substeps,
        "iterations": result.iterations,
        "max_defect": result.max_defect,
        "peak_voltage": float(v.max()),
        "share_at_bound": float(np.mean(v > 0.999 * vmax)),
        "holding_voltage": float(abs(rm.adip_equilibrium(target, P)[1][0])),
        "overshoot_deg": float(np.rad2deg(max(0.0, x[:, 0].max() - target))),
        "undershoot_deg": float(np.rad2deg(max(0.0, -x[:, 0].min()))),
        "max_pendulum_deg": float(np.rad2deg(np.abs(x[:, 1]).max())),
        "peak_arm_rate": float(np.abs(x[:, 2]).max()),
        "solve_ivp_end_error": [float(e) for e in solve_ivp_end(result) - result.states[-1]],
    }


def best_of(phi_deg: float, vmax: float, starts: tuple = (1.5,), **options) -> tuple[mt.Transfer, dict]:
    """The shortest converged transfer over the initial guesses T_guess ∈ starts, with every start's T."""
    t0 = time.perf_counter()
    runs = [transfer(phi_deg, vmax, T_guess=T, **options) for T in starts]
    best = min(runs, key=lambda r: (not r.success, r.T))
    row = summary(best, phi_deg, vmax) | {
        "starts_T_guess": list(starts),
        "T_by_start": [r.T if r.success else None for r in runs],
        "seconds": time.perf_counter() - t0,
    }
    print({k: row[k] for k in ("target_deg", "vmax", "T", "T_by_start", "seconds")}, flush=True)
    return best, row


def lqr_hold(x_start: np.ndarray, phi_t: float, vmax: float, seconds: float = 3.0) -> dict:
    """Item 3 (b): u = V_eq − K (x − x_eq), |u| ≤ vmax, 5 ms ZOH, from x_start; largest deviations in deg."""
    x_eq, u_eq = rm.adip_equilibrium(phi_t, P)
    a, b = rm.adip_linearization(phi_t, P)
    Q, R = HOLD_WEIGHTS
    K = np.linalg.solve(R, b.T @ scipy.linalg.solve_continuous_are(a, b, Q, R))
    x, worst, peak = np.asarray(x_start, dtype=float)[:, None], np.zeros(2), 0.0
    for _ in range(round(seconds / TS)):
        u = np.clip(u_eq - K @ (x[:, 0] - x_eq), -vmax, vmax)
        peak = max(peak, float(abs(u[0])))
        x = mt.rk4(F, x, u[:, None], TS / 5, 5, P)
        worst = np.maximum(worst, np.abs(x[:2, 0] - x_eq[:2]))
    return {
        "max_arm_error_deg": float(np.rad2deg(worst[0])),
        "max_pendulum_deg": float(np.rad2deg(worst[1])),
        "peak_voltage": peak,
        "stays_in_band": bool(np.all(np.rad2deg(worst) <= SPEC_BAND_DEG)),
    }


def band_bounds(phi_deg: float, vmax: float) -> list[dict]:
    """Item 3 (a), (b): terminal band on the angles only, or on the angles and the rates."""
    angles = np.deg2rad([SPEC_BAND_DEG, SPEC_BAND_DEG])
    rows = []
    for name, band in (("angles", [*angles, np.inf, np.inf]), ("angles and rates", [*angles, 0.05, 0.05])):
        result, row = best_of(phi_deg, vmax, STARTS, band=np.array(band))
        hold = lqr_hold(result.states[-1], np.deg2rad(phi_deg), vmax)
        rows.append({"band": name, "end_state": [float(e) for e in result.states[-1]], "hold": hold} | row)
    return rows


def spec_violation(result: mt.Transfer, settle_time: float, phi_deg: float, p: dict = P) -> float:
    """Largest excess (deg) over the spec on the sub-step trajectory: overshoot beyond 2°, arm or
    pendulum outside ±1° after settle_time. ≤ 0 when the transfer meets the spec."""
    t, x = dense(result, p)
    error = np.rad2deg(x[:, :2] - [np.deg2rad(phi_deg), 0.0])
    after = t >= settle_time - 1e-9
    return float(max(error[:, 0].max() - SPEC_OVERSHOOT_DEG, np.abs(error[after]).max() - SPEC_BAND_DEG))


def settling_transfer(
    phi_deg: float, vmax: float, settle_guess: float, p: dict = P
) -> tuple[mt.Transfer, float, float]:
    """Item 3 (c) from one guess: (transfer, T_s = K h, node-bound margin in deg), on parameters p."""
    phi_t = np.deg2rad(phi_deg)
    x0, xf, u0, uf = endpoints(phi_deg, p)
    K, M = round(settle_guess / INTERVAL), SETTLE_TAIL
    u, x = quasi_static_guess(phi_t, settle_guess, K, p)
    guess = (
        np.hstack([u, np.repeat(uf[:, None], M, axis=1)]),
        np.hstack([x, np.repeat(xf[:, None], M, axis=1)]),
    )
    margin, T_start = 0.1, settle_guess * (K + M) / K
    for _ in range(4):
        lo, hi = np.full((K + M - 1, 4), -np.inf), np.full((K + M - 1, 4), np.inf)
        hi[:, 0] = phi_t + np.deg2rad(SPEC_OVERSHOOT_DEG - margin)
        band = np.deg2rad(SPEC_BAND_DEG - margin)
        lo[K - 1 :, :2], hi[K - 1 :, :2] = [phi_t - band, -band], [phi_t + band, band]
        result = mt.minimum_time_transfer(
            F,
            x0,
            xf,
            u0,
            uf,
            vmax,
            p,
            interval=settle_guess / K,
            T_guess=T_start,
            guess=guess,
            path=(lo, hi),
            state_scale=mt.ADIP_STATE_SCALE,
            max_iterations=1500,
        )
        excess = spec_violation(result, result.grid[K], phi_deg, p)
        if not result.success or excess <= 0 or margin + excess + 0.02 >= SPEC_BAND_DEG / 2:
            break  # met, failed, or not to be met by shrinking the node bounds
        margin += excess + 0.02
        guess, T_start = (result.voltage.T, result.states.T), result.T
    return result, float(result.grid[K]), margin


def best_settling(phi_deg: float, vmax: float) -> tuple[mt.Transfer, dict]:
    """Item 3 (c): the shortest settling over SETTLE_STARTS among transfers that meet the spec."""
    t0 = time.perf_counter()
    runs = []
    for guess in SETTLE_STARTS:
        result, settle, margin = settling_transfer(phi_deg, vmax, guess)
        runs.append((result, settle, margin, result.success and spec_violation(result, settle, phi_deg) <= 0))
    best, settle, margin, ok = min(runs, key=lambda run: (not run[3], run[1]))
    row = summary(best, phi_deg, vmax) | {
        "settling_time": settle,
        "rest_time": best.T,
        "node_margin_deg": margin,
        "meets_spec": ok,
        "spec_excess_deg": spec_violation(best, settle, phi_deg),
        "settle_guesses": list(SETTLE_STARTS),
        "settling_by_start": [run[1] if run[3] else None for run in runs],
        "seconds": time.perf_counter() - t0,
    }
    print(
        {k: row[k] for k in ("vmax", "settling_time", "rest_time", "settling_by_start", "seconds")},
        flush=True,
    )
    return best, row


def fmu_cross_check(T_star: float, phi_deg: float, vmax: float) -> dict:
    """Item 4: fixed 20 ms grid over 20 ms · ceil(T*/20 ms), open loop on the FMU at 5 ms."""
    interval = 4 * TS
    duration = interval * np.ceil(T_star / interval - 1e-9)
    result = transfer(phi_deg, vmax, T_guess=duration, interval=interval, duration=duration)
    target = np.array([np.deg2rad(phi_deg), 0.0, 0.0, 0.0])
    names = [f"diag_state_{s}" for s in ("arm_angle", "pendulum_angle", "arm_rate", "pendulum_rate")]
    with open_fmu(ROOT / "fmu_plants" / "build" / "adip.fmu", outputs=names) as fmu:
        fmu.reset([0.0])
        for v in np.repeat(result.voltage[:, 0], round(interval / TS)):
            end_fmu = fmu.step([v], TS)
    end_python = dense(result)[1][-1]
    return {
        "duration": float(duration),
        "intervals": len(result.voltage),
        "substeps": result.substeps,
        "success": result.success,
        "status": result.status,
        "peak_voltage": float(np.abs(result.voltage).max()),
        "share_at_bound": float(np.mean(np.abs(result.voltage) > 0.999 * vmax)),
        "fmu_end_state": [float(e) for e in end_fmu],
        "arm_error_deg": float(np.rad2deg(end_fmu[0] - target[0])),
        "pendulum_deg": float(np.rad2deg(end_fmu[1])),
        "fmu_minus_python_rk4": [float(e) for e in end_fmu - end_python],
        "python_rk4_minus_target": [float(e) for e in end_python - target],
    }


def figure(optimal: mt.Transfer, settling: mt.Transfer, settle: float, phi_deg: float, vmax: float) -> None:
    """φ1, φ2 (deg) and V of both transfers, at rest (equilibrium held) after their end."""
    hold = rm.adip_equilibrium(np.deg2rad(phi_deg), P)[1][0]
    t_end = 2.0
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 8))
    cases = (
        (optimal, "-", f"minimum time to rest, T* = {optimal.T:.3f} s"),
        (settling, "--", f"spec-compliant, settled at {settle:.3f} s, rest at {settling.T:.3f} s"),
    )
    for result, style, label in cases:
        t, x = dense(result)
        t = np.concatenate([[-0.1], t, [t_end]])
        x = np.rad2deg(np.vstack([np.zeros(4), x, x[-1]]))
        color = axes[0].plot(t, x[:, 0], style, label=label)[0].get_color()
        axes[1].plot(t, x[:, 1], style, color=color)
        v = np.concatenate([[0.0], result.voltage[:, 0], [hold, hold]])
        axes[2].step(np.concatenate([[-0.1], result.grid, [t_end]]), v, style, where="post", color=color)
        for ax in axes:
            ax.axvline(result.T, color=color, ls=":", lw=1)
    for ax in axes:
        ax.axvline(settle, color="C1", ls="-", lw=0.8)
    axes[0].axhspan(phi_deg - SPEC_BAND_DEG, phi_deg + SPEC_BAND_DEG, color="0.8", label="±1° band")
    axes[1].axhspan(-SPEC_BAND_DEG, SPEC_BAND_DEG, color="0.8")
    axes[2].axhline(hold, color="0.5", ls=":", label=f"holding voltage {hold:.2f} V")
    for sign in (-1, 1):
        axes[2].axhline(sign * vmax, color="k", lw=0.8)
    for ax, unit in zip(axes, ("arm φ1 [deg]", "pendulum φ2 [deg]", "voltage [V]"), strict=True):
        ax.axvline(SPEC_SECONDS, color="k", ls="-.", label="spec: settled by 1.5 s")
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower right", fontsize=7)
    axes[2].legend(loc="lower right", fontsize=7)
    axes[0].set_title(f"ADIP arm 0 → {phi_deg}°, |V| ≤ {vmax:g} V, reference_models (open loop)", fontsize=10)
    axes[2].set_xlabel("t [s] (reference step at t = 0)")
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "adip_min_time.png", dpi=120)
    plt.close(fig)


def main() -> None:
    start = time.perf_counter()
    results: dict = {"symmetry_error": symmetry_error()}
    by_angle = {deg: best_of(deg, 10.0, STARTS) for deg in ANGLES}
    results["by_angle_10V"] = [row for _, row in by_angle.values()]
    by_voltage = {v: by_angle[75] if v == 10 else best_of(75, float(v), STARTS) for v in VOLTAGES}
    results["by_voltage_75deg"] = [row for _, row in by_voltage.values()]
    try:
        transfer(75, 4.0)
    except ValueError as exc:
        results["below_holding_voltage"] = str(exc)
    results["band_75deg_10V"] = band_bounds(75, 10.0)
    settling = {v: best_settling(75, v) for v in (10.0, 5.0)}
    results["settling_optimal_75deg"] = [row for _, row in settling.values()]
    checks = {"generic guess (rates 0, V interpolated)": {"generic": True}, "10 ms grid": {"interval": 0.01}}
    checks["40 ms grid"] = {"interval": 0.04}
    results["convergence_75deg_10V"] = [{"case": k} | best_of(75, 10.0, **o)[1] for k, o in checks.items()]
    results["fmu_cross_check"] = fmu_cross_check(by_angle[75][0].T, 75, 10.0)
    figure(by_angle[75][0], settling[10.0][0], settling[10.0][1]["settling_time"], 75, 10.0)
    results["wall_seconds"] = time.perf_counter() - start
    (Path(__file__).parent / "results" / "adip_limits.json").write_text(json.dumps(results, indent=1))
    table(results)


def rounded(values: list) -> list:
    return [None if v is None else round(v, 4) for v in values]


def table(results: dict) -> None:
    print(f"\nsymmetry: max |f(-x,-V) + f(x,V)| = {results['symmetry_error']:.1e}")
    print("target  Vmax   T*[s]  peak|V|  at bound  holding  overshoot  undershoot  max|φ2|  T by start")
    for row in results["by_angle_10V"] + results["by_voltage_75deg"]:
        print(
            f"{row['target_deg']:5}° {row['vmax']:5.1f} {row['T']:7.4f} {row['peak_voltage']:8.2f} "
            f"{row['share_at_bound']:8.0%} {row['holding_voltage']:8.2f} {row['overshoot_deg']:9.2f}° "
            f"{row['undershoot_deg']:10.2f}° {row['max_pendulum_deg']:7.1f}°  {rounded(row['T_by_start'])}"
            f"{'' if row['success'] else '  NOT CONVERGED: ' + row['status']}"
        )
    print(results.get("below_holding_voltage"))
    for row in results["band_75deg_10V"]:
        print(f"band on {row['band']}: T = {row['T']:.4f} s, end rates {np.round(row['end_state'][2:], 3)}")
        print(f"    LQR hold from there: {row['hold']}")
    for row in results["settling_optimal_75deg"]:
        print(
            f"spec-compliant, {row['vmax']} V: settled at {row['settling_time']:.4f} s, rest at "
            f"{row['rest_time']:.4f} s, overshoot {row['overshoot_deg']:.2f}°, meets spec "
            f"{row['meets_spec']}, by start {rounded(row['settling_by_start'])}"
        )
    for row in results["convergence_75deg_10V"]:
        print(
            f"{row['case']}: T* = {row['T']:.4f} s ({row['intervals']} intervals, success {row['success']})"
        )
    print("FMU:", results["fmu_cross_check"])
    print(f"wall time {results['wall_seconds']:.0f} s")


if __name__ == "__main__":
    main()
