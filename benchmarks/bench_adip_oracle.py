"""Is the ADIP's ±75° limit in the identified model or in the synthesis? The exact model (issue 7)

The bundled design identifies a model and synthesizes a polytopic H∞ controller from it. This bench
removes identification: the vertex plants are the exact linearisations of fmu_plants/adip (ZOH, Ts = 5 ms,
bench_adip_reach.linearised) at θ = cos φ1 on a few nodes, with the weights of the bundled
lpvflow/pipeline/examples/adip.toml, and the controllers are run on the nonlinear equations.

1. Frozen optimum: ``synthesize`` on one node alone — the H∞ γ of the best LTI controller there with these
   weights, a lower bound for every polytopic design whose polytope contains that plant — with the bound β
   on the scaled Lyapunov matrices (lyapunov_bound) as shipped (1e6) and raised to 1e8, against the
   Riccati solution of the same problem (lpvflow.synth.certify.riccati_gamma: SLICOT SB10DD, bisected on
   γ to 0.5 %, each controller accepted only if python-control finds the closed loop stable with
   ‖·‖∞ ≤ γ): an answer independent of the LMIs. Then the LMI γ at θ = 0.2495, cos 75.5°, 0.2505 (arm
   angles 0.02° apart): how sensitive the returned γ is to the plant near the hardest point.
2. Polytopic, common Lyapunov matrix, on the node set θ_1 = 1 > θ_2 > … (the plant between two adjacent
   nodes taken as their convex combination; the controller vertices interpolated with the same
   piecewise-linear hat coordinates λ_i(cos φ1), so one common certificate covers every segment). The
   node set {1, 0.7, 0.5} is solved with the bundled weights, with W_K five times smaller, and with the
   bound β on the scaled Lyapunov matrices (lyapunov_bound, 1e6) raised to 1e9. In exact arithmetic a
   smaller W_K cannot raise the optimal γ (every certificate stays feasible: the bounded-real LMI only
   loses a positive semidefinite C1ᵀC1 part), and neither can a larger β; a γ that moves the other way
   is the solver's inaccuracy, not the plant's.
3. The controllers of 2 on the nonlinear model (RK4, 1 ms sub-steps, |u| ≤ 10 V, scheduling cos of the
   measured arm angle, clipped to the node range): the spectral radius of the frozen closed loops with
   the exact linearisations, and arm steps at t = 0.5 s to ±30…75° with issue 7's metrics (±1° settling
   from the step, overshoot, largest pendulum angle after settling) or when the pendulum passed 0.5 rad.
   The plant and the controller are odd-symmetric, so −φ gives the same numbers as +φ; only + is run.
4. The same steps (30°, 45°) with the best LTI controllers at 0° of section 1 — the LMI one and the
   Riccati one (lpvflow.synth.certify.riccati_controller at 1.05 × the Riccati γ), W_B in series: whether
   the bundled weights allow issue 7's 1.5 s at all, with any synthesis.

Run: .venv/bin/python benchmarks/bench_adip_oracle.py   → results/adip_oracle.json (about 6 minutes)
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import control
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "benchmarks"), str(ROOT / "fmu_plants"), str(ROOT / "fmu_plants" / "adip")]

import bench_adip_reach as reach  # noqa: E402

import lpvflow.synth.lmi_hinf as lmi_hinf  # noqa: E402
from lpvflow.synth.certify import riccati_controller, riccati_gamma  # noqa: E402
from lpvflow.synth.controller import series_input_filter  # noqa: E402
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant, augment, check_a3, weight_systems  # noqa: E402
from lpvflow.synth.polytope import Polytope  # noqa: E402
from lpvflow.synth.sdp import SynthesisError  # noqa: E402

TS = reach.TS
STEP_AT = 0.5
DURATION = 4.0
PENDULUM_LOST = 0.5  # rad, as the bundled scenarios' output_bounds
TARGETS_DEG = (30, 45, 60, 75)
#: θ within ±0.0005 of 0.25 (arm 75.48…75.56°; cos 75.5° = 0.25038): section 1's LMI γ there.
SENSITIVITY_COS = (0.2495, float(np.cos(np.deg2rad(75.5))), 0.2505)


def weights(k_scale: float = 1.0) -> dict:
    """The bundled ADIP weights, W_K multiplied by ``k_scale``."""
    table = reach.bundled_weights()
    return {**table, "K": {**table["K"], "num": [k_scale * v for v in table["K"]["num"]]}}


def node_plant(nodes: tuple[float, ...], weight_table: dict) -> GeneralizedPlant:
    """Generalized plants of the exact linearisations at θ = cos φ1 ∈ ``nodes`` (one vertex each)."""
    W = weight_systems(weight_table, 2, 1, TS)
    vertices = [VertexPlant.from_ss(augment(reach.linearised(np.arccos(c)), W, TS), nw=2, nz=3)
                for c in nodes]
    check_a3(vertices)
    # The polytope object only labels the result; this bench interpolates with hat_coordinates.
    polytope = Polytope("box", np.array([[min(nodes), max(nodes)]]), np.array([[1.0, c] for c in nodes]))
    return GeneralizedPlant(vertices, polytope, TS, 4, ["W_S e[0]", "W_S e[1]", "W_K u[0]"], W.get("B"))


def hat_coordinates(nodes: np.ndarray, theta: float) -> np.ndarray:
    """Piecewise-linear convex coordinates of θ on the descending ``nodes`` (θ clipped to their range)."""
    theta = float(np.clip(theta, nodes.min(), nodes.max()))
    lam = np.zeros(len(nodes))
    for i in range(len(nodes) - 1):
        if nodes[i + 1] <= theta <= nodes[i]:
            s = (theta - nodes[i + 1]) / (nodes[i] - nodes[i + 1])
            lam[i], lam[i + 1] = s, 1.0 - s
            return lam
    return np.ones(1)  # one node


def polytopic(nodes: tuple[float, ...], weight_table: dict,
              bound: float = lmi_hinf.LYAPUNOV_BOUND) -> tuple[dict, list | None]:
    """γ, status and time of the common-Lyapunov synthesis on ``nodes``; vertex controllers with W_B."""
    row = {"nodes_cos": list(nodes), "arm_up_to_deg": float(np.rad2deg(np.arccos(min(nodes)))),
           "W_K": weight_table["K"]["num"][0], "lyapunov_bound": bound}
    plant = node_plant(nodes, weight_table)
    t0 = time.perf_counter()
    try:
        result = lmi_hinf.synthesize(plant, "common", lyapunov_bound=bound)
    except SynthesisError as exc:
        row.update(gamma=None, reason=str(exc), seconds=time.perf_counter() - t0)
        return row, None
    row.update(gamma=float(result.gamma), status=result.report.status, seconds=time.perf_counter() - t0)
    return row, [series_input_filter(k, plant.input_filter) for k in result.K_vertices]


def interpolated(K: list, lam: np.ndarray) -> list[np.ndarray]:
    return [sum(w * k[m] for w, k in zip(lam, K, strict=True)) for m in range(4)]


def frozen_radius(K: list, nodes: np.ndarray, degrees: float) -> float:
    """Spectral radius of the exact linearisation at φ1 with the controller frozen there (u = K(r − y))."""
    phi1 = np.deg2rad(degrees)
    controller = control.ss(*interpolated(K, hat_coordinates(nodes, np.cos(phi1))), TS)
    return reach.frozen_radius(controller, phi1, -1)


def arm_step(K: list, nodes: np.ndarray, target_deg: float) -> dict:
    """Arm step 0 → target at STEP_AT on the nonlinear model; issue 7's metrics or when the pendulum fell."""
    target = np.deg2rad(target_deg)
    state = {"xk": np.zeros(K[0][0].shape[0])}

    def law(k: int, x: np.ndarray) -> float:
        e = np.array([(target if k * TS >= STEP_AT else 0.0) - x[0], -x[1]])
        Ak, Bk, Ck, Dk = interpolated(K, hat_coordinates(nodes, np.cos(x[0])))
        u = (Ck @ state["xk"] + Dk @ e)[0]
        state["xk"] = Ak @ state["xk"] + Bk @ e
        return u

    rows, lost_at = reach.nonlinear_run(law, DURATION, lambda k, x: not abs(x[1]) < PENDULUM_LOST)
    if lost_at is not None:
        peak = float(np.abs(rows[:, 3]).max())
        return {"target_deg": target_deg, "pendulum_lost_at_s": lost_at, "peak_voltage": peak}
    return {"target_deg": target_deg, **reach.move_metrics(*rows.T, target, STEP_AT)}


def frozen_upright_steps(lmi_gamma: float, lmi_K: list, riccati_gamma_opt: float, weight_table: dict) -> dict:
    """Section 4: section 1's best LTI controllers at 0° — the LMI one (γ, vertex controller with W_B) and
    SB10DD's at 1.05 × the Riccati optimum — on the nonlinear plant: can these weights give 1.5 s at all?"""
    plant = node_plant((1.0,), weight_table)
    node = np.array([1.0])
    gamma = 1.05 * riccati_gamma_opt
    riccati = series_input_filter(riccati_controller(plant.vertices[0], TS, gamma), plant.input_filter)
    out = {}
    for name, (g, K) in {"lmi": (lmi_gamma, lmi_K[0]), "riccati": (gamma, riccati)}.items():
        out[name] = {"gamma": g, "frozen_radius_0deg": frozen_radius([K], node, 0.0),
                     "steps": [arm_step([K], node, d) for d in (30, 45)]}
    print(out, flush=True)
    return out


def main() -> None:
    default = weights()
    results: dict = {"frozen_optimum": [], "frozen_sensitivity_near_75deg": [], "polytopic": [],
                     "nonlinear": []}
    for theta in (1.0, 0.7, 0.5, 0.25):
        row, K = polytopic((theta,), default)
        row["gamma_bound_1e8"] = polytopic((theta,), default, 1e8)[0]["gamma"]
        row["gamma_riccati"] = riccati_gamma(node_plant((theta,), default).vertices[0], TS)
        results["frozen_optimum"].append(row)
        print(row, flush=True)
        if theta == 1.0:
            upright = (row["gamma"], K, row["gamma_riccati"])
    for theta in SENSITIVITY_COS:
        row, _ = polytopic((theta,), default)
        results["frozen_sensitivity_near_75deg"].append(row)
        print(row, flush=True)
    cases = [((1.0, 0.7), default, 1e6), ((1.0, 0.7, 0.5), default, 1e6),
             ((1.0, 0.7, 0.5), weights(0.2), 1e6), ((1.0, 0.7, 0.5), default, 1e9),
             ((1.0, 0.7, 0.5, 0.25), default, 1e6)]
    for nodes, table, bound in cases:
        row, K = polytopic(nodes, table, bound)
        results["polytopic"].append(row)
        print(row, flush=True)
        if K is None or table is not default or bound != lmi_hinf.LYAPUNOV_BOUND:
            continue
        node_array = np.array(nodes)
        runs = {"nodes_cos": list(nodes), "gamma": row["gamma"],
                "frozen_radius": {d: frozen_radius(K, node_array, d) for d in (0, 15, 30, 45, 60, 75)},
                "steps": [arm_step(K, node_array, d) for d in TARGETS_DEG]}
        results["nonlinear"].append(runs)
        print(runs, flush=True)
    results["frozen_upright_on_the_nonlinear_plant"] = frozen_upright_steps(*upright, default)
    out = Path(__file__).parent / "results" / "adip_oracle.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
