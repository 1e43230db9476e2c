"""How far in arm angle can the ADIP be controlled with the bundled design's weights? (issue 7)

Physical model of fmu_plants/adip (fmu_plants/reference_models.py), linearised at the upright
equilibria φ1 = arccos θ, φ2 = 0 and discretised with zero-order hold at Ts = 5 ms. Only cos φ1 enters
the linearisation, so θ = cos φ1 is the natural scheduling variable and ±φ1 give the same plant.

1. Control authority: holding voltage V_eq(φ1) = −d1 sin φ1 / k_τ, unstable poles, and the voltage →
   pendulum-acceleration entry of B (it scales like cos φ1 and vanishes at 90°).
2. One LTI controller: the LQR + predictor observer of fmu_plants/adip/stabilizing_controller.py,
   designed at φ1 = 0: the largest angle up to which the frozen closed loops stay stable.
3. Polytopic H∞ synthesis (lpvflow.synth, common Lyapunov matrix, the weights of the bundled
   lpvflow/pipeline/examples/adip.toml) on the affine-in-θ least-squares fit of the linearisations
   over θ ∈ [θ_lo, 1], for decreasing θ_lo: γ or the reason it is infeasible, and the fit error;
   where the common LMIs are infeasible, the dilated ones (vertex Lyapunov matrices) alone as well.
   ``synthesize`` retries ill-conditioned cases (bisection needed, or failed) in balanced state
   coordinates (lmi_hinf._balanced_common); the status says which attempt gave γ.
4. Whether *any* gain-scheduled state feedback can be certified on the two-vertex polytope spanned by
   the exact linearisations at θ_lo and 1 (with the input filter W_B = 0.3/(z − 0.7) of assumption A3,
   as the synthesis uses): the largest margin t of
     quadratic (common X):       [[X, (A_iX + B W_i)ᵀ], [⋆, X]] ⪰ t I,  0 ⪯ X ⪯ I,
     poly-quadratic (dilated):   [[P_j, A_iG + B W_i], [⋆, G + Gᵀ − P_i]] ⪰ t I for all i, j
                                 (Daafouz & Bernussou 2001; de Oliveira et al. 1999), 0 ⪯ P_i ⪯ I,
     frozen (rate 0, same G):    as poly-quadratic with i = j only.
   t > 0 certifies; t ≤ 0 (to solver accuracy ~1e-8) means that family of Lyapunov functions
   cannot certify that range whatever the controller. For scale: one frozen LTI point at 75° has
   t ≈ 1e-6, at 0° t ≈ 2e-5. All three share one slack G for the whole range. Then, with the slack
   depending on θ too (gridded, rate-bounded; :func:`gridded_margin`): P(θ), G(θ), W(θ) affine in
   θ, the controller K(θ) = W(θ)G(θ)⁻¹, the exact linearisations A(θ) on a grid of step 0.01 and
   |θ(k+1) − θ(k)| ≤ ν,
     [[P(θ⁺), A(θ)G(θ) + B W(θ)], [⋆, G(θ) + G(θ)ᵀ − P(θ)]] ⪰ t I  at θ⁺ ∈ {θ − ν, θ, θ + ν},
   which gives V = xᵀP(θ)⁻¹x decreasing along every scheduling trajectory with that rate bound
   (de Oliveira, Bernussou & Geromel 1999 dilation; G(θ(k)) is allowed because it multiplies only
   time-k data). A(θ)G(θ) is quadratic in θ, so the grid is not a proof between its points: the
   solved P, G, W are re-checked on a 10× finer grid (smallest eigenvalue reported). These margins
   are computed in the coordinates of a dlqr design at the box centre (x = T x̄, TTᵀ its closed-loop
   Lyapunov matrix): a state transform changes t, not whether t > 0, and lifts t from ~1e-7 to ~1e-4
   here, far above the solver's accuracy; the shared-slack families are given there too.
5. An idealised upper bound for linear gain-scheduled control, no identification and no certificate:
   full-state LQR gains K(φ1) (python-control ``dlqr`` on the ZOH linearisations every 5°, interpolated
   linearly in the measured arm angle), u = V_eq(r) − K(φ1)(x − x_eq(r)), |u| ≤ 10 V, on the nonlinear
   model (RK4, 1 ms sub-steps), the reference r moving from 0 to the target along a smoothstep
   3s² − 2s³ of duration T_r. Over a grid of LQR weights and T_r: the fastest ±1° arm settling per
   target (from the start of the move), with the overshoot, the pendulum's largest angle after
   settling and the peak voltage. A step (T_r = 0) or T_r ≤ 1.2 s loses the pendulum at 75°.

Run: .venv/bin/python benchmarks/bench_adip_reach.py [SECTION ...]   → results/adip_reach.json (only the
named sections, e.g. state_feedback_certifiable_margin, are re-run and replaced)
"""

from __future__ import annotations

import json
import os
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import control
import cvxpy as cp
import numpy as np
import scipy.linalg

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "fmu_plants"))
sys.path.insert(0, str(ROOT / "fmu_plants" / "adip"))
import min_time as mt  # noqa: E402
import reference_models as rm  # noqa: E402
import stabilizing_controller  # noqa: E402

from lpvflow.basis import Basis  # noqa: E402
from lpvflow.models import LPVSS  # noqa: E402
from lpvflow.pipeline.config import bundled_config  # noqa: E402
from lpvflow.synth.lmi_hinf import synthesize  # noqa: E402
from lpvflow.synth.plant import generalized_plant  # noqa: E402
from lpvflow.synth.sdp import SynthesisError  # noqa: E402

TS = 0.005
PARAMETERS = rm.default_parameters("adip")
LOWER_BOUNDS = (0.85, 0.7, 0.6, 0.5, 0.25)  # θ_lo = cos φ1: 31.8°, 45.6°, 53.1°, 60°, 75.5°


def bundled_weights() -> dict:
    """The ``[synth] weights`` table of the bundled ADIP design (lpvflow/pipeline/examples/adip.toml)."""
    return tomllib.loads(bundled_config("adip").read_text())["synth"]["weights"]


def linearised(phi1: float) -> control.StateSpace:
    """ZOH discretisation of the linearisation at the upright equilibrium with the arm at φ1."""
    a, b = rm.adip_linearization(phi1, PARAMETERS)
    return control.c2d(control.ss(a, b, np.eye(2, 4), np.zeros((2, 1))), TS, method="zoh")


def authority() -> list[dict]:
    rows = []
    for degrees in (0, 30, 45, 60, 75, 85):
        phi1 = np.deg2rad(degrees)
        u_op = rm.adip_equilibrium(phi1, PARAMETERS)[1]
        a, b = rm.adip_linearization(phi1, PARAMETERS)
        poles = np.linalg.eigvals(a)
        rows.append({"arm_deg": degrees, "holding_voltage": float(u_op[0]),
                     "unstable_poles_rad_s": sorted(float(s.real) for s in poles if s.real > 0),
                     "pendulum_accel_per_volt": float(b[3, 0])})
    return rows


def frozen_radius(K: control.StateSpace, phi1: float, sign: int) -> float:
    """Spectral radius of the linearisation at φ1 in feedback with the LTI controller K: u = K y for
    sign = +1 (the identification controllers), u = K (r − y) for sign = −1 (the H∞ designs)."""
    loop = control.feedback(linearised(phi1), K, sign=sign)
    return float(np.max(np.abs(np.linalg.eigvals(loop.A))))


def lti_reach() -> dict:
    """Largest φ1 (1° grid) up to which the φ1 = 0 LQR/observer controller keeps every frozen loop stable."""
    doc = stabilizing_controller.design(PARAMETERS)
    K = control.ss(*(np.array(doc[k]) for k in "ABCD"), TS)
    radii = [frozen_radius(K, np.deg2rad(degrees), +1) for degrees in range(0, 86)]
    unstable = [d for d, r in enumerate(radii) if r >= 1.0]
    return {"stable_up_to_deg": (unstable[0] - 1) if unstable else 85,
            "spectral_radius_at_75deg": radii[75]}


def affine_model(theta_lo: float) -> tuple[LPVSS, float]:
    """Least-squares fit M(θ) = M0 + θ M1 of the discretised A, B over 12 points of [θ_lo, 1]."""
    thetas = np.linspace(theta_lo, 1.0, 12)
    systems = [linearised(np.arccos(t)) for t in thetas]
    regressor = np.column_stack([np.ones_like(thetas), thetas])
    parts, errors = [], []
    for key in ("A", "B"):
        stacked = np.array([getattr(s, key) for s in systems])
        coef, *_ = np.linalg.lstsq(regressor, stacked.reshape(len(thetas), -1), rcond=None)
        residual = stacked.reshape(len(thetas), -1) - regressor @ coef
        errors.append(np.abs(residual).max() / np.abs(stacked).max())
        parts.append(coef.reshape((2, *stacked.shape[1:])))
    C = np.array([np.eye(2, 4), np.zeros((2, 4))])
    basis = Basis("affine", 1, p_min=(theta_lo,), p_max=(1.0,))
    model = LPVSS(parts[0], parts[1], C, np.zeros((2, 2, 1)), basis, TS,
                  u_names=["voltage"], y_names=["arm_angle", "pendulum_angle"], p_names=["cos_arm"])
    return model, float(max(errors))


def synthesis_reach(weights: dict) -> list[dict]:
    rows = []
    for theta_lo in LOWER_BOUNDS:
        model, fit_error = affine_model(theta_lo)
        row = {"theta_lo": theta_lo, "arm_deg": float(np.rad2deg(np.arccos(theta_lo))),
               "affine_fit_rel_error": fit_error}
        t0 = time.perf_counter()
        plant = generalized_plant(model, weights, [[theta_lo, 1.0]])
        try:
            result = synthesize(plant, "common")
            row["gamma"], row["status"] = float(result.gamma), result.report.status  # says if balanced
        except SynthesisError as exc:
            row["gamma"] = None
            row["reason"] = str(exc)
            try:  # vertex Lyapunov matrices, any rate (common failed, so this is the dilated point)
                row["gamma_dilated"] = float(synthesize(plant, "dilated").gamma)
            except SynthesisError as exc_dilated:
                row["gamma_dilated"] = None
                row["reason_dilated"] = str(exc_dilated)
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        print(row, flush=True)
    return rows


def filtered_plant(theta: float, coordinates: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact linearisation at θ = cos φ1 with the input filter x_f⁺ = 0.7 x_f + 0.3 v, u = x_f (A3);
    in x̄ = T⁻¹x when ``coordinates`` T are given."""
    G = linearised(np.arccos(min(theta, 1.0)))
    A = np.block([[G.A, G.B], [np.zeros((1, 4)), np.array([[0.7]])]])
    B = np.vstack([np.zeros((4, 1)), [[0.3]]])
    if coordinates is None:
        return A, B
    Ti = np.linalg.inv(coordinates)
    return Ti @ A @ coordinates, Ti @ B


def filtered_vertices(theta_lo: float, coordinates: np.ndarray | None = None) -> list[tuple[np.ndarray, ...]]:
    """:func:`filtered_plant` at θ_lo and 1."""
    return [filtered_plant(theta, coordinates) for theta in (theta_lo, 1.0)]


def lqr_coordinates(theta: float) -> np.ndarray:
    """T with TTᵀ = X, the closed-loop Lyapunov matrix (A_cl X A_clᵀ − X = −I) of a dlqr design at θ."""
    A, B = filtered_plant(theta)
    K, _, _ = control.dlqr(A, B, np.diag([10.0, 60.0, 0.1, 0.1, 0.01]), np.eye(1))
    return np.linalg.cholesky(scipy.linalg.solve_discrete_lyapunov(A - B @ K, np.eye(A.shape[0])))


def certifiable_margin(theta_lo: float, kind: str, coordinates: np.ndarray | None = None) -> float:
    """Largest t of the state-feedback LMIs of item 4 (module docstring), in x̄ = T⁻¹x if T is given."""
    vertices = filtered_vertices(theta_lo, coordinates)
    n = vertices[0][0].shape[0]
    t = cp.Variable()
    W = [cp.Variable((1, n)) for _ in vertices]
    constraints = [t <= 1]
    if kind == "quadratic":
        X = cp.Variable((n, n), symmetric=True)
        constraints += [X >> 0, X << np.eye(n)]
        for (A, B), Wi in zip(vertices, W, strict=True):
            M = cp.bmat([[X, (A @ X + B @ Wi).T], [A @ X + B @ Wi, X]])
            constraints.append((M + M.T) / 2 >> t * np.eye(2 * n))
    else:
        G = cp.Variable((n, n))
        P = [cp.Variable((n, n), symmetric=True) for _ in vertices]
        constraints += [c for Pi in P for c in (Pi >> 0, Pi << np.eye(n))]
        for i, ((A, B), Wi) in enumerate(zip(vertices, W, strict=True)):
            for j in (range(len(vertices)) if kind == "poly-quadratic" else [i]):
                M = cp.bmat([[P[j], A @ G + B @ Wi], [(A @ G + B @ Wi).T, G + G.T - P[i]]])
                constraints.append((M + M.T) / 2 >> t * np.eye(2 * n))
    cp.Problem(cp.Maximize(t), constraints).solve(solver="CLARABEL")
    return float(t.value)


#: Rate bounds ν on |θ(k+1) − θ(k)| per 5 ms sample for :func:`gridded_margin`. The 0 → 75° references
#: of bench_adip_feedforward reach |d cos φ1/dt| = |sin φ1 · φ1'| ≈ 0.012–0.014 per sample (minimum energy
#: over 1.2 s) and 0.026–0.037 (minimum time at 5–8 V): 0.05 covers every one of them, 0.02 the 1.2 s ones.
RATES = (0.05, 0.02, 0.005)
GRID_STEP = 0.01
RECHECK_STEP = 0.001


def _dilated_lmi(A, B, P_next, P_now, G, W) -> np.ndarray | cp.Expression:
    """[[P(θ⁺), AG + BW], [⋆, G + Gᵀ − P(θ)]] (numbers or cvxpy expressions)."""
    H = A @ G + B @ W
    if isinstance(H, cp.Expression):
        return cp.bmat([[P_next, H], [H.T, G + G.T - P_now]])
    return np.block([[P_next, H], [H.T, G + G.T - P_now]])


def next_thetas(theta: float, rate: float, lo: float, hi: float = 1.0) -> list[float]:
    """The θ⁺ checked after θ under |θ⁺ − θ| ≤ ν: {θ − ν, θ, θ + ν} ∩ [lo, hi], ascending."""
    return sorted({float(np.clip(theta + d, lo, hi)) for d in (-rate, 0.0, rate)})


def rate_lmis(plants: dict[float, tuple[np.ndarray, np.ndarray]], rate: float, theta_lo: float, P, G, W):
    """Item 4's matrix at every θ of ``plants`` (θ → filtered plant) and θ⁺ of :func:`next_thetas`, with
    P, G, W given at θ_lo and 1 and affine in between (numbers or cvxpy variables)."""
    def at(values, theta):
        s = (theta - theta_lo) / (1.0 - theta_lo)
        return (1.0 - s) * values[0] + s * values[1]

    for th, (A, B) in plants.items():
        for th_next in next_thetas(th, rate, theta_lo):
            yield _dilated_lmi(A, B, at(P, th_next), at(P, th), at(G, th), at(W, th))


def theta_grid(theta_lo: float, step: float) -> np.ndarray:
    return np.linspace(theta_lo, 1.0, round((1.0 - theta_lo) / step) + 1)


def gridded_margin(theta_lo: float, rate: float, n: int, plants: dict, fine_plants: dict) -> dict:
    """Item 4's gridded, rate-bounded margin t on [θ_lo, 1] with the filtered plants (state dimension n)
    on the synthesis grid (step GRID_STEP) and its re-check on the 10× finer grid (RECHECK_STEP)."""
    P = [cp.Variable((n, n), symmetric=True) for _ in range(2)]  # at θ_lo and 1, affine in between
    G = [cp.Variable((n, n)) for _ in range(2)]
    W = [cp.Variable((1, n)) for _ in range(2)]
    t = cp.Variable()
    constraints = [t <= 1] + [c for Pi in P for c in (Pi >> t * np.eye(n), Pi << np.eye(n))]
    constraints += [(M + M.T) / 2 >> t * np.eye(2 * n) for M in rate_lmis(plants, rate, theta_lo, P, G, W)]
    cp.Problem(cp.Maximize(t), constraints).solve(solver="CLARABEL")
    P, G, W = ([np.array(v.value) for v in var] for var in (P, G, W))
    recheck = min(np.linalg.eigvalsh(M)[0] for M in rate_lmis(fine_plants, rate, theta_lo, P, G, W))
    return {"rate_per_sample": rate, "margin": float(t.value), "recheck_min_eig": float(recheck)}


def lyapunov_reach() -> list[dict]:
    rows = []
    for theta_lo in LOWER_BOUNDS:
        row = {"theta_lo": theta_lo, "arm_deg": float(np.rad2deg(np.arccos(theta_lo)))}
        kinds = ("quadratic", "poly-quadratic", "frozen")
        row |= {kind: certifiable_margin(theta_lo, kind) for kind in kinds}
        T = lqr_coordinates(0.5 * (theta_lo + 1.0))
        row["lqr_coordinates"] = {kind: certifiable_margin(theta_lo, kind, T) for kind in kinds}
        plants, fine_plants = ({float(th): filtered_plant(th, T) for th in theta_grid(theta_lo, step)}
                               for step in (GRID_STEP, RECHECK_STEP))
        row["lqr_coordinates"]["gridded"] = [gridded_margin(theta_lo, rate, T.shape[0], plants, fine_plants)
                                             for rate in RATES]
        rows.append(row)
        print(row, flush=True)
    return rows


#: (arm, pendulum) state weights [1/rad²] and input weight [1/V²] tried in section 5; rates get 0.1.
LQR_WEIGHTS = ((10, 60, 10), (10, 60, 1), (100, 100, 1), (100, 300, 0.3), (30, 300, 1))
MOVE_TIMES = (0.0, 1.0, 1.5, 2.0, 2.5)
SIM_SECONDS = 6.0


def nonlinear_run(law: Callable[[int, np.ndarray], float], seconds: float,
                  lost: Callable[[int, np.ndarray], bool]) -> tuple[np.ndarray, float | None]:
    """The nonlinear ADIP from rest at 0 under u(k) = clip(law(k, x(k)), ±10 V), held over each 5 ms sample
    (RK4, 1 ms sub-steps), for ``seconds``: rows (t, arm, pendulum, u) up to the sample at which
    ``lost(k, x(k + 1))`` first holds, and that time (s), or None when it never does."""
    x, rows = np.zeros(4), []
    for k in range(round(seconds / TS)):
        u = float(np.clip(law(k, x), -10.0, 10.0))
        rows.append((k * TS, x[0], x[1], u))
        x = mt.rk4(rm.adip_derivatives, x, np.array([u]), TS / 5, 5, PARAMETERS)
        if lost(k, x):
            return np.array(rows), round((k + 1) * TS, 3)
    return np.array(rows), None


def scheduled_lqr(weights: tuple) -> Callable[[np.ndarray, float], float]:
    """Section 5's law u(x, r) = V_eq(r) − K(φ1)(x − x_eq(r)): dlqr gains with Q = diag(w_arm, w_pendulum,
    0.1, 0.1), R = w_u on the ZOH linearisations every 5° of arm angle (−85…85°), interpolated linearly in
    the measured arm angle φ1 = x[0]; r the arm reference (rad)."""
    grid = np.deg2rad(np.arange(-85, 86, 5))
    Q, R = np.diag([weights[0], weights[1], 0.1, 0.1]), np.array([[weights[2]]])
    gains = np.array([control.dlqr(linearised(g).A, linearised(g).B, Q, R)[0][0] for g in grid])

    def law(x: np.ndarray, reference: float) -> float:
        x_eq, u_eq = rm.adip_equilibrium(reference, PARAMETERS)
        K = np.array([np.interp(x[0], grid, gains[:, i]) for i in range(4)])
        return u_eq[0] - K @ (x - x_eq)

    return law


def scheduled_lqr_move(target_deg: float, weights: tuple, move_time: float) -> dict | None:
    """Section 5: one move of the arm from 0 to target_deg; None when the pendulum passes 0.9 rad."""
    lqr = scheduled_lqr(weights)
    target, start = np.deg2rad(target_deg), 0.5

    def law(k: int, x: np.ndarray) -> float:
        s = float(np.clip((k * TS - start) / move_time, 0, 1)) if move_time > 0 else float(k * TS >= start)
        return lqr(x, target * s * s * (3 - 2 * s))

    rows, lost_at = nonlinear_run(law, SIM_SECONDS, lambda k, x: abs(x[1]) > 0.9)
    if lost_at is not None:
        return None
    return {"target_deg": target_deg, "move_time_s": move_time, "lqr_weights": list(weights),
            **move_metrics(*rows.T, target, start)}


def move_metrics(t: np.ndarray, arm: np.ndarray, pendulum: np.ndarray, u: np.ndarray, target: float,
                 start: float) -> dict:
    """Issue 7's metrics of an arm move started at ``start``: ±1° settling time (None if the last sample
    is outside the band), overshoot, largest pendulum angle after settling, peak voltage."""
    outside = np.flatnonzero(np.abs(arm - target) > np.deg2rad(1.0))
    settled = not outside.size or outside[-1] + 1 < len(t)
    settling = (t[outside[-1]] + TS - start if outside.size else 0.0) if settled else None
    return {"settling_s": None if settling is None else float(settling),
            "overshoot_deg": float(np.rad2deg(max(0.0, np.max(arm - target)))),
            "pendulum_after_settling_deg": None if settling is None
            else float(np.rad2deg(np.max(np.abs(pendulum[t >= start + settling])))),
            "peak_voltage": float(np.max(np.abs(u)))}


def scheduled_lqr_reach() -> list[dict]:
    """Section 5: per target, the fastest-settling move over LQR_WEIGHTS × MOVE_TIMES."""
    rows = []
    for target in (60, 70, 75):
        runs = [scheduled_lqr_move(target, w, m) for w in LQR_WEIGHTS for m in MOVE_TIMES]
        held = [r for r in runs if r is not None]
        settled = [r for r in held if r["settling_s"] is not None]
        best = min(settled, key=lambda r: r["settling_s"]) if settled else {"target_deg": target}
        rows.append(best | {"runs": len(runs), "pendulum_lost": len(runs) - len(held)})
        print(rows[-1], flush=True)
    return rows


def main(sections: list[str]) -> None:
    """Run every section, or only the named ones (keys of results/adip_reach.json), updating the file."""
    runners = {"authority": authority, "lti_controller": lti_reach,
               "state_feedback_certifiable_margin": lyapunov_reach,
               "common_lyapunov_synthesis": lambda: synthesis_reach(bundled_weights()),
               "scheduled_lqr_on_the_nonlinear_model": scheduled_lqr_reach}
    unknown = sorted(set(sections) - set(runners))
    if unknown:
        raise SystemExit(f"unknown section(s) {', '.join(unknown)}; use any of {', '.join(runners)}")
    out = Path(__file__).parent / "results" / "adip_reach.json"
    results = json.loads(out.read_text()) if sections and out.exists() else {}
    for name in sections or runners:
        results[name] = runners[name]()
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({name: results[name] for name in runners if name in results}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
