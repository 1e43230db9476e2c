"""Mixed-sensitivity generalized plant at every vertex of the polytope (Boonto's thesis §6.2, Fig. 6.6).

Signals (1-DOF loop, reference r, control u from the controller, plant input u_p):

    u_p = W_B u   (u_p = u without input filter),   y = G(θ) u_p,   e = r − y,   r = W_R w (r = w without
    reference weight: W_R = diag(1, 0.01) says the second output's "reference" is only small noise),
    z = [W_S e ; W_K u ; W_T y (optional)],          measured output of the generalized plant: e.

2-DOF loop (``structure = "2dof"``; Apkarian et al. 1995 and the thesis §6.3 use this structure): the
controller reads the reference and the measurement separately, u = K [r; y_m], with y_m = y + W_N n
(measurement noise n, W_N default 0.01·I: without it D21 has no full row rank and the H∞ problem is
singular), exogenous inputs [w; n], and z = [W_S e ; W_K u ; W_T y] with e = r − y as above. The
controller may then shape the reference path (feed-forward) apart from the feedback.

With state x = [x_G; x_weights] this is the discrete-time LFT plant of Apkarian, Gahinet & Becker
(1995, eq. (2))

    x⁺ = A(θ) x + B1(θ) r + B2(θ) u,     z = C1(θ) x + D11 r + D12(θ) u,     e = C2(θ) x + D21 r + D22 u,

built per vertex with ``control.interconnect`` (the state order is the same at every vertex because
the weights are). The output-feedback LMIs need B2, C2, D12, D21 parameter-independent and D22 = 0
(Apkarian et al. 1995, assumptions (A1)–(A2); the thesis calls the B2 condition "(A3)"): then the
closed loop is affine in θ. An identified observable-form model has C constant and D = 0 but B(θ)
varies; a strictly proper input filter W_B makes B2 = [0; B_WB] constant. :func:`check_a3` says
which matrix breaks the assumption instead of returning a controller without a guarantee.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import control
import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.synth.polytope import Polytope, piecewise_polytope, polytope_of, vertex_matrices
from lpvflow.synth.weights import Weights, WeightSystems, as_weights

_CONST_TOL = 1e-10


@dataclass(frozen=True)
class VertexPlant:
    """Partitioned generalized plant at one vertex (exogenous w = r, measured output e)."""

    A: np.ndarray
    B1: np.ndarray
    B2: np.ndarray
    C1: np.ndarray
    C2: np.ndarray
    D11: np.ndarray
    D12: np.ndarray
    D21: np.ndarray
    D22: np.ndarray

    @property
    def dims(self) -> tuple[int, int, int, int, int]:
        """(n, nw, nu, nz, ny)."""
        return self.A.shape[0], self.B1.shape[1], self.B2.shape[1], self.C1.shape[0], self.C2.shape[0]

    def ss(self, Ts: float) -> control.StateSpace:
        """The vertex plant as one StateSpace, inputs [w, u], outputs [z, y]."""
        B = np.hstack([self.B1, self.B2])
        C = np.vstack([self.C1, self.C2])
        D = np.block([[self.D11, self.D12], [self.D21, self.D22]])
        return control.ss(self.A, B, C, D, Ts)

    @classmethod
    def from_ss(cls, P: control.StateSpace, nw: int, nz: int) -> VertexPlant:
        A, B, C, D = (np.asarray(M, dtype=float) for M in (P.A, P.B, P.C, P.D))
        return cls(A, B[:, :nw], B[:, nw:], C[:nz], C[nz:],
                   D[:nz, :nw], D[:nz, nw:], D[nz:, :nw], D[nz:, nw:])


@dataclass(frozen=True)
class GeneralizedPlant:
    """Vertex generalized plants of a polytopic LPV design; P(θ) = Σ_v λ_v(θ) P_v exactly."""

    vertices: list[VertexPlant]
    polytope: Polytope
    Ts: float
    n_plant_states: int
    z_names: list[str]
    weights: WeightSystems
    basis: Basis | None = None
    structure: str = "1dof"

    @property
    def input_filter(self) -> control.StateSpace | None:
        """W_B (None without an input filter)."""
        return self.weights.get("B")

    @property
    def dims(self) -> tuple[int, int, int, int, int]:
        return self.vertices[0].dims

    def at(self, lam: np.ndarray) -> VertexPlant:
        """The plant at convex coordinates λ."""
        return interpolate(self.vertices, lam)


def interpolate(vertices: list[VertexPlant], lam: np.ndarray) -> VertexPlant:
    """Σ_i λ_i (vertex plant i), matrix by matrix."""
    return VertexPlant(**{k: sum(w * getattr(v, k) for w, v in zip(lam, vertices, strict=True))
                          for k in VertexPlant.__dataclass_fields__})


def check_a3(vertices: list[VertexPlant]) -> None:
    """Raise ModelError unless B2, C2, D12, D21 are the same at every vertex and D22 = 0."""
    ref = vertices[0]
    if np.max(np.abs(ref.D22), initial=0.0) > _CONST_TOL:
        raise ModelError("the generalized plant has D22 ≠ 0 (plant feed-through into e): add a strictly "
                         "proper input filter W_B, or identify with an input delay nk >= 1")
    hints = {"B2": "use a strictly proper input filter W_B (e.g. num = [0, b], den = [1, -a])",
             "C2": "the plant's C(θ) varies: realize it in observable form (constant C)",
             "D12": "W_K's feed-through is scheduled, or the plant's D(θ) varies: keep W_K's gain the same "
                    "at every vertex (schedule W_S or W_T instead) and use a strictly proper W_B",
             "D21": "the plant feed-through D(θ) varies: use a strictly proper W_B"}
    for name, hint in hints.items():
        spread = max(np.max(np.abs(getattr(v, name) - getattr(ref, name)), initial=0.0) for v in vertices)
        scale = max(1.0, np.max(np.abs(getattr(ref, name)), initial=0.0))
        if spread > _CONST_TOL * scale:
            raise ModelError(f"{name} of the generalized plant depends on the scheduling parameter (spread "
                             f"{spread:.3g}), so vertex controllers cannot be interpolated exactly: {hint}")


def _named_ss(M: control.StateSpace, inp: str, out: str, name: str) -> control.StateSpace:
    return control.ss(M, inputs=[f"{inp}[{i}]" for i in range(M.ninputs)],
                      outputs=[f"{out}[{i}]" for i in range(M.noutputs)], name=name)


def weight_systems(weights: Weights | Mapping[str, Any], ny: int, nu: int, Ts: float) -> WeightSystems:
    """The diagonal weights W_S, W_K and the optional W_B, W_T, W_R, W_N (2-DOF measurement noise) at Ts
    (:meth:`lpvflow.synth.weights.Weights.discretize`)."""
    return as_weights(weights).discretize(ny, nu, Ts)


#: Measurement-noise weight of the 2-DOF loop when the design gives no ``weights.N``.
DEFAULT_NOISE_WEIGHT = 0.01
#: Controller structures: "1dof" (the controller reads e = r − y) or "2dof" (it reads [r; y]).
STRUCTURES = ("1dof", "2dof")


def augment(G: control.StateSpace, W: dict[str, control.StateSpace], Ts: float, structure: str = "1dof"
            ) -> control.StateSpace:
    """Interconnect one frozen plant with the weights (module docstring). 1-DOF: inputs [r (or w), u],
    outputs [z_S, z_K, (z_T), e]; 2-DOF: inputs [r (or w), n, u], outputs [z_S, z_K, (z_T), r, y_m]."""
    if structure not in STRUCTURES:
        raise ModelError(f"unknown controller structure {structure!r}; use one of {STRUCTURES}")
    ny = G.noutputs
    two = structure == "2dof"
    blocks = [
        _named_ss(G, "up" if "B" in W else "u", "y", "G"),
        _named_ss(W["S"], "e", "zS", "WS"),
        _named_ss(W["K"], "u", "zK", "WK"),
        control.summing_junction(inputs=["r", "-y"], output="e", dimension=ny, name="sum"),
    ]
    if two:
        WN = W.get("N", control.ss([], [], [], DEFAULT_NOISE_WEIGHT * np.eye(ny), Ts))
        blocks += [_named_ss(WN, "n", "nw", "WN"),
                   control.summing_junction(inputs=["y", "nw"], output="ym", dimension=ny, name="noise")]
    outputs = ["zS", "zK"]
    shaped_reference = "R" in W or two  # a 2-DOF controller measures r: W_R defaults to I so r is a signal
    if shaped_reference:
        blocks.append(_named_ss(W.get("R", control.ss([], [], [], np.eye(ny), Ts)), "w", "r", "WR"))
    if "B" in W:
        blocks.append(_named_ss(W["B"], "u", "up", "WB"))
    if "T" in W:
        blocks.append(_named_ss(W["T"], "y", "zT", "WT"))
        outputs.append("zT")
    exogenous = ["w" if shaped_reference else "r"] + (["n"] if two else [])
    measured = ["r", "ym"] if two else ["e"]
    return control.interconnect(blocks, inplist=[*exogenous, "u"], outlist=[*outputs, *measured], dt=Ts)


def state_blocks(model: LPVSS, W: WeightSystems, structure: str = "1dof") -> dict[str, slice]:
    """Where each part of :func:`augment`'s state lies: ``"G"`` (the plant model) first, then the weights
    ``W`` in the order of its blocks (W_S, W_K, W_N for 2-DOF, W_R, W_B, W_T; ``control.interconnect``
    stacks the blocks' states in list order). Only the parts with states are listed."""
    order = ["S", "K"] + (["N"] if structure == "2dof" and "N" in W else []) + [k for k in ("R", "B", "T")
                                                                                  if k in W]
    blocks, start = {"G": slice(0, model.nx)}, model.nx
    for key in order:
        if W[key].nstates:
            blocks[key] = slice(start, start + W[key].nstates)
            start += W[key].nstates
    return blocks


def generalized_plant(model: LPVSS, weights: Weights | Mapping[str, Any],
                      box: np.ndarray | list | None = None, structure: str = "1dof",
                      breakpoints: np.ndarray | list | None = None,
                      vertex_weights: Sequence[Mapping[str, Any]] | None = None) -> GeneralizedPlant:
    """The augmented plant (1-DOF or 2-DOF, :func:`augment`) at each vertex of the tightest polytope of
    ``model`` over ``box``, or at ``breakpoints`` of its one scheduling signal (a piecewise polytope,
    :func:`lpvflow.synth.polytope.piecewise_polytope`). The weights (typed, or a ``[synth] weights`` table)
    are discretized here at the model's Ts, once; the plant carries them (``weights``).

    Scheduled weights (thesis §6.3: W_S1, W_S2, W_S3 at the vertices 0, ±φ_t): ``vertex_weights[i]``
    replaces entries of ``weights`` at vertex i; the weights are then interpolated with the plant's own
    λ(p) (their state-space matrices must have the same orders). A scheduled weight that makes B2, C2,
    D12 or D21 vertex-dependent is refused by :func:`check_a3`, which names the matrix."""
    weights = as_weights(weights)
    polytope = polytope_of(model, box) if breakpoints is None else piecewise_polytope(model, box, breakpoints)
    ny, nu = model.ny, model.nu
    if vertex_weights is not None and len(vertex_weights) != polytope.n_vertices:
        raise ModelError(f"vertex_weights gives {len(vertex_weights)} weight tables for a polytope with "
                         f"{polytope.n_vertices} vertices ({polytope.kind}): give one per vertex")
    W = weights.discretize(ny, nu, model.Ts)
    at_vertices = [W] * polytope.n_vertices if vertex_weights is None else [
        weights.replaced(override).discretize(ny, nu, model.Ts) for override in vertex_weights]
    nz = ny + nu + (ny if "T" in W else 0)
    nw = 2 * ny if structure == "2dof" else ny
    vertices, orders = [], set()
    for Wv, (A, B, C, D) in zip(at_vertices, vertex_matrices(model, polytope), strict=True):
        orders.add(tuple((k, w.nstates) for k, w in sorted(Wv.items())))
        P = augment(control.ss(A, B, C, D, model.Ts), Wv, model.Ts, structure)
        vertices.append(VertexPlant.from_ss(P, nw=nw, nz=nz))
    if len(orders) > 1:
        raise ModelError("vertex_weights change the order of a weight between vertices: a scheduled weight "
                         "must keep its numerator and denominator degrees (change gains and poles only)")
    check_a3(vertices)
    z_names = [f"W_S e[{i}]" for i in range(ny)] + [f"W_K u[{i}]" for i in range(nu)]
    z_names += [f"W_T y[{i}]" for i in range(ny)] if "T" in W else []
    return GeneralizedPlant(vertices, polytope, model.Ts, model.nx, z_names, W, model.basis, structure)
