"""ADIP, exact model: gridded, rate-bounded output-feedback H∞ — does a θ-dependent slack help? (issue 7)

bench_adip_reach (section 4) shows that over cos φ1 ∈ [0.25, 1] (±75.5°) state feedback is certifiable
only when the slack of the dilated LMI depends on θ and the scheduling rate is bounded. This bench asks the
same of output feedback, on the setting of bench_adip_oracle (exact ZOH linearisations at θ = cos φ1,
Ts = 5 ms, the weights of the bundled lpvflow/pipeline/examples/adip.toml, W_B in the plant).

Synthesis (de Oliveira, Geromel & Bernussou 2002 dilated bounded-real lemma, the change of variables of
lpvflow.synth.lmi_hinf's module docstring, here gridded as in LPVTools): X(θ), S(θ), P̄(θ), Q(θ), L(θ),
F(θ), R(θ) piecewise-linear in θ between nodes, Y and Ṽ = I constant, so that the congruence
T = [I Yᵀ; 0 I] is the same at k and k+1 and P̄(θ(k+1)) in the (1,1) block is the next sample's
Lyapunov matrix (a θ-dependent Y would need θ(k+1) in the controller). At every θ of a grid containing
the nodes and every θ⁺ ∈ {θ − ν, θ, θ + ν} ∩ range,

    ⎡ P̄(θ⁺)   Φ(θ)                                Ψ(θ)   0     ⎤
    ⎢ ⋆       [X+Xᵀ  I+Sᵀ; I+S  Y+Yᵀ](θ) − P̄(θ)   0      Ω(θ)ᵀ ⎥ ⪰ t·I,   P̄, sym 𝒢 ⪯ 1e6·I,
    ⎢ ⋆       ⋆                                    γI     Δ(θ)ᵀ ⎥
    ⎣ ⋆       ⋆                                    ⋆      γI    ⎦

with Φ, Ψ, Ω, Δ those of lmi_hinf._vertex_blocks at the exact plant A(θ) (products like A(θ)X(θ) are
numbers times variables on the grid). γ is fixed and the margin t maximised (t > 0: feasible). The plant
is put in balanced coordinates first (lmi_hinf._balancing_transform of the frozen plant at the middle
node; a state transform leaves feasibility unchanged) and diagonally scaled (lmi_hinf._scalings).

Re-check, trusting neither solver nor change of variables: the controller K(θ) is reconstructed
(lmi_hinf.reconstruct, Ṽ = I, U = S − YX) at every θ of a grid 4× finer than the synthesis grid, the
closed loop with the exact generalized plant at θ is built (lpvflow.synth.certify.closed_loop), and the
bounded-real LMI (E) of lmi_hinf's docstring with 𝒫(θ⁺) in (1,1), 𝒢(θ) and 𝒫(θ) mapped back to closed-loop
coordinates is evaluated at every rate pair; its smallest Jacobi-scaled eigenvalue is reported (> 0: the
certificate holds at those points, including between synthesis grid points).

Nonlinear check of certified designs: controllers tabulated every 0.0025 in θ and interpolated linearly,
run on the nonlinear ADIP (bench_adip_oracle.arm_step: RK4, ±10 V, arm steps at t = 0.5 s, issue 7's
metrics) for targets up to the range's end.

Run: .venv/bin/python benchmarks/bench_adip_gridded.py   → results/adip_gridded.json (about 15 minutes)
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cvxpy as cp
import numpy as np
import scipy.linalg

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_adip_oracle as oracle  # noqa: E402
import bench_adip_reach as reach  # noqa: E402

from lpvflow.synth import lmi_hinf  # noqa: E402
from lpvflow.synth.certify import bounded_real_lmi, closed_loop, jacobi_min_eig  # noqa: E402
from lpvflow.synth.controller import series_input_filter  # noqa: E402
from lpvflow.synth.sdp import SynthesisError, psd, solve  # noqa: E402

RECHECK_REFINE = 4
TABLE_STEP = 0.0025
#: (nodes θ = cos φ1, synthesis grid points, rate ν per sample, γ values, arm targets for the nonlinear check)
CASES = (
    ((1.0, 0.85, 0.7), 13, 0.02, (2.5,), (30, 45)),
    ((1.0, 0.7, 0.5), 11, 0.02, (5.0, 15.0), (30, 45, 60)),
    ((1.0, 0.7, 0.5, 0.35, 0.25), 13, 0.02, (10.0, 100.0), (30, 45, 60, 75)),
    ((1.0, 0.7, 0.5, 0.35, 0.25), 13, 0.0, (10.0,), (30, 45, 60, 75)),
)


def mix(lam: np.ndarray, values: list):
    return sum(w * v for w, v in zip(lam, values, strict=True) if w != 0)


def rate_pairs(grid: np.ndarray, rate: float) -> list[tuple[float, float]]:
    """(θ, θ⁺), θ ascending on ``grid``, θ⁺ from bench_adip_reach.next_thetas within the grid's range."""
    lo, hi = float(grid.min()), float(grid.max())
    return [(float(th), th_next) for th in sorted(grid)
            for th_next in reach.next_thetas(float(th), rate, lo, hi)]


class Gridded:
    """One gridded design: coordinates, solved variables, controller and certificate at any θ."""

    def __init__(self, nodes: tuple[float, ...], points: int, rate: float):
        self.nodes = np.array(nodes)
        self.rate = rate
        self.grid = np.unique(np.concatenate([np.linspace(min(nodes), 1.0, points), self.nodes]))[::-1]
        self.weights = oracle.weights()
        middle = float(self.nodes[len(self.nodes) // 2])
        self.T = lmi_hinf._balancing_transform(oracle.node_plant((middle,), self.weights), (1e1, 1e2, 1e3))
        if self.T is None:
            raise SynthesisError(f"no balancing transform at θ = {middle}")
        self.scalings = lmi_hinf._scalings(self._plants(self.grid))
        self.values: dict | None = None
        self.gamma = float("nan")
        self._vertices: dict[float, tuple] = {}

    def _plants(self, thetas) -> list:
        plant = oracle.node_plant(tuple(float(t) for t in thetas), self.weights)
        return lmi_hinf._transformed(plant, self.T).vertices

    def _scaled(self, thetas) -> list:
        return [lmi_hinf._scaled(v, *self.scalings) for v in self._plants(thetas)]

    def vertices(self, theta: float) -> tuple:
        """(the generalized plant at θ, the same in the synthesis coordinates), computed once per θ."""
        if theta not in self._vertices:
            self._vertices[theta] = (oracle.node_plant((theta,), self.weights).vertices[0],
                                     self._scaled([theta])[0])
        return self._vertices[theta]

    def solve(self, gamma: float) -> dict:
        verts = self._scaled(self.grid)
        n, nw, nu, nz, ny = verts[0].dims
        N, I = len(self.nodes), np.eye(n)
        X, S, Q = ([cp.Variable((n, n)) for _ in range(N)] for _ in range(3))
        P = [cp.Variable((2 * n, 2 * n), symmetric=True) for _ in range(N)]
        L, F, R = ([cp.Variable(shape) for _ in range(N)] for shape in ((nu, n), (n, ny), (nu, ny)))
        Y, t = cp.Variable((n, n)), cp.Variable()
        constraints = [t <= 1] + [Pi << lmi_hinf.LYAPUNOV_BOUND * np.eye(2 * n) for Pi in P]
        constraints += [0.5 * cp.bmat([[X[i] + X[i].T, I + S[i].T], [I + S[i], Y + Y.T]])
                        << lmi_hinf.LYAPUNOV_BOUND * np.eye(2 * n) for i in range(N)]
        by_theta = dict(zip(self.grid.tolist(), verts, strict=True))
        pairs = rate_pairs(self.grid, self.rate)
        for th, th_next in pairs:
            lam = oracle.hat_coordinates(self.nodes, th)
            Xg, Sg, Pg = mix(lam, X), mix(lam, S), mix(lam, P)
            blocks = lmi_hinf._vertex_blocks(by_theta[th], Xg, Y, *(mix(lam, V) for V in (Q, L, F, R)))
            current = cp.bmat([[Xg + Xg.T, I + Sg.T], [I + Sg, Y + Y.T]]) - Pg
            P_next = mix(oracle.hat_coordinates(self.nodes, th_next), P)
            M = lmi_hinf._lmi(P_next, blocks[0], current, *blocks[1:], gamma, nw, nz)
            constraints.append(psd(M, t))
        report = solve(cp.Problem(cp.Maximize(t), constraints), "CLARABEL", "the gridded LMIs")
        self.values = {k: [np.array(v.value) for v in var]
                       for k, var in dict(X=X, S=S, Q=Q, P=P, L=L, F=F, R=R).items()}
        self.values["Y"] = np.array(Y.value)
        self.gamma = gamma
        return {"gamma": gamma, "margin": float(t.value), "status": report.status,
                "seconds": round(report.seconds, 1), "rate_pairs": len(pairs)}

    def at(self, theta: float) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray]:
        """(K(θ) from e to u, 𝒢(θ), 𝒫(θ)) in the closed-loop coordinates of the original plant."""
        v = self.vertices(theta)[1]
        lam = oracle.hat_coordinates(self.nodes, theta)
        X, S, Q, P, L, F, R = (mix(lam, self.values[k]) for k in ("X", "S", "Q", "P", "L", "F", "R"))
        Y = self.values["Y"]
        n = Y.shape[0]
        U = S - Y @ X
        K = lmi_hinf._unscaled_controller(lmi_hinf.reconstruct(v, X, Y, S, Q, L, F, R, U, np.eye(n)),
                                          *self.scalings[1:])
        s = self.scalings[0]
        back = scipy.linalg.block_diag(self.T * s[None, :], np.eye(n)) @ np.linalg.inv(
            np.block([[np.eye(n), Y.T], [np.zeros((n, n)), np.eye(n)]])).T
        G = self.gamma * back @ np.block([[X, np.eye(n)], [S, Y]]) @ back.T
        return K, G, self.gamma * back @ P @ back.T

    def recheck(self, refine: int) -> float:
        """Smallest Jacobi-scaled eigenvalue of (E) over the rate pairs of a ``refine``× finer grid."""
        fine = np.linspace(self.grid.min(), 1.0, refine * (len(self.grid) - 1) + 1)[::-1]
        pairs = rate_pairs(fine, self.rate)
        points = {th: self.at(th) for pair in pairs for th in pair}  # (K, 𝒢, 𝒫) at θ

        def min_eig(th: float, th_next: float) -> float:
            (K, G, P), P_next = points[th], points[th_next][2]
            loop = closed_loop(self.vertices(th)[0], K)
            return jacobi_min_eig(bounded_real_lmi(loop, P_next, P, G, self.gamma))

        return min(min_eig(*pair) for pair in pairs)

    def table(self) -> tuple[list, np.ndarray]:
        """Implementable controllers (W_B in series) every TABLE_STEP in θ, descending."""
        thetas = np.linspace(1.0, self.nodes.min(), round((1.0 - self.nodes.min()) / TABLE_STEP) + 1)
        plant = oracle.node_plant((1.0,), self.weights)
        return [series_input_filter(self.at(th)[0], plant.input_filter) for th in thetas], thetas


def run_case(nodes, points, rate, gammas, targets) -> list[dict]:
    rows = []
    design = Gridded(nodes, points, rate)
    for gamma in gammas:
        row = {"nodes_cos": list(nodes), "arm_up_to_deg": round(float(np.rad2deg(np.arccos(min(nodes)))), 1),
               "rate_per_sample": rate, "grid_points": len(design.grid)}
        try:
            row |= design.solve(gamma)
        except SynthesisError as exc:
            rows.append(row | {"gamma": gamma, "error": str(exc)})
            continue
        if row["margin"] > 0:
            row["recheck_min_eig_on_grid"] = design.recheck(1)
            row["recheck_min_eig_4x_finer"] = design.recheck(RECHECK_REFINE)
            K, thetas = design.table()
            radii = [oracle.frozen_radius(K, thetas, float(d)) for d in np.rad2deg(np.arccos(thetas[::8]))]
            row["frozen_spectral_radius_max"] = max(radii)
            row["arm_steps"] = [oracle.arm_step(K, thetas, target) for target in targets]
        rows.append(row)
        print(row, flush=True)
    return rows


def main() -> None:
    start = time.perf_counter()
    rows = [row for case in CASES for row in run_case(*case)]
    out = Path(__file__).parent / "results" / "adip_gridded.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"rows": rows, "seconds": round(time.perf_counter() - start, 1)}, indent=1))


if __name__ == "__main__":
    main()
