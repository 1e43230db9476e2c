"""Gain-scheduled observer-based 2-DOF controller: frozen LQG designs at the breakpoints, interpolated
(``[synth] method = "observer"``).

At every breakpoint b_i of a piecewise polytope the 2-DOF generalized plant of
:func:`lpvflow.synth.plant.generalized_plant` (state x = [x_G; x_W]: the model's states, then the weights')
gets an observer-based controller in the *same* state coordinates — the model's observable-form states and
the weights' — so that the controllers at neighbouring breakpoints mean the same thing and interpolating
their matrices with the plant's own λ(p) is interpolating gains (interpolating state-space matrices of
controllers realized in different coordinates is not; Rugh & Shamma 2000, "Research on gain scheduling",
Automatica 36(10), discuss this realization issue). The parts:

* **State feedback** u = F x̂: the LQ regulator of the weighted plant, the H2 cost ‖z‖² = ‖C1x + D12u‖²
  of the design's own weights (W_S on the tracking error, W_K on u): ``control.dlqr(A, B2, C1ᵀC1, D12ᵀD12,
  C1ᵀD12)``.
* **Weight states copied exactly**: a weight's state obeys x_W⁺ = A_W x_W + B_W(r − y) (W_S) or is driven
  by u (W_B); r, y_m and u are known to the controller, so its copy uses them directly (observer rows
  L_W = [B1_W D21_r⁺, A_WG C_G⁺]) instead of estimating them. The integral action of W_S therefore acts on
  the *measured* error.
* **Kalman filter for the model states with an input-disturbance state** d (x_G⁺ = A_G x_G + B_G(u_p + d),
  d⁺ = d): ``control.dlqe`` with process noise ``input``·B_G B_Gᵀ + ``state``·I on the model,
  ``disturbance`` on d and measurement noise ``noise``² (standard deviation ``noise``). u subtracts
  K_d d̂, K_d = (I − F_B(I − A_B)⁻¹B_B) W_B(1)⁻¹ (F_B: F on W_B's state): a constant load or trim error is
  cancelled exactly at steady state, at the observer's speed rather than the integrator's.
* **Reference feed-forward** (2-DOF): for every reference channel whose steady state the model can reach
  (x_ss = N_x r, u_ss = N_u r from [A_G − I, B_G; C_G, 0][N_x; N_u] = [0; e_j]), u = u_ss + F(x̂ − x_ss).
  A channel the plant cannot hold at DC (the ADIP's pendulum) has none.
* **Anti-windup** (:func:`antiwindup_gains`): when the actuator saturates, the model estimate is driven by
  the applied input, x̂_G⁺ += B_G(u_a − u) — the observer form of anti-windup (Åström & Rundqwist 1989,
  "Integrator windup and how to avoid it", ACC): the estimate, and with it the integral action on the
  measured error, stays consistent with the plant.
* **Reference filter** (optional): every reference passes ω²/(s² + 2ζωs + ω²) (zero-order hold) before
  the controller, so a step asks for a move the loop can follow (``reference_filter = { bandwidth = ω,
  damping = ζ }``).

The controller is strictly the frozen LQG design at every breakpoint. Between breakpoints and under a
moving p it is *not* certified by an LMI: :func:`frozen_check` evaluates the frozen closed loops on a grid
ten times finer than the breakpoints (spectral radius, ‖T_zw‖∞ with python-control), and the FMU runs of
``lpvflow verify`` are the witness for the time-varying, nonlinear loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.models import LPVSS
from lpvflow.synth.certify import design_coordinates, interpolated_loops
from lpvflow.synth.controller import LPVController, series_input_filter
from lpvflow.synth.plant import GeneralizedPlant, VertexPlant, state_blocks
from lpvflow.synth.polytope import vertex_matrices

#: Relative residual above which a weight state is not a function of r, y and u (a dynamic W_R or W_N).
_COPY_TOL = 1e-9
#: Relative residual below which a reference channel's steady state is reachable (feed-forward applies).
_REACH_TOL = 1e-8
#: Frozen-check grid: points per breakpoint interval (ten times finer than the breakpoints).
FROZEN_PER_SEGMENT = 11


@dataclass(frozen=True)
class ObserverSettings:
    """Noise model of the Kalman filter (covariances per sample: ``input`` on the plant input, ``state`` on
    every model state, ``disturbance`` on the disturbance state; ``noise`` the measurement noise's standard
    deviation) and the optional reference filter (rad/s, damping ratio)."""

    input: float = 1.0
    state: float = 1e-6
    disturbance: float = 1.0
    noise: float = 1e-3
    filter_bandwidth: float | None = None
    filter_damping: float = 1.0

    def __post_init__(self) -> None:
        for name in ("input", "state", "disturbance", "noise"):
            if not getattr(self, name) > 0:
                raise ModelError(f"[synth] observer.{name} must be positive, got {getattr(self, name)!r}")
        if self.filter_bandwidth is not None and not self.filter_bandwidth > 0:
            raise ModelError(f"[synth] reference_filter.bandwidth must be positive (rad/s), got "
                             f"{self.filter_bandwidth!r}")
        if not self.filter_damping > 0:
            raise ModelError(f"[synth] reference_filter.damping must be positive, got "
                             f"{self.filter_damping!r}")


@dataclass
class FrozenCheck:
    """Frozen closed loops of the interpolated controller on the design's plant, on a grid ten times finer
    than the breakpoints: the largest spectral radius and ‖T_zw‖∞ (python-control ``lft`` and ``norm``)."""

    spectral_radius: float
    hinf_max: float
    points: int

    @property
    def ok(self) -> bool:
        """Every frozen loop is stable."""
        return self.spectral_radius < 1.0

    def lines(self) -> list[str]:
        return [f"frozen closed loops at {self.points} points (10× the breakpoints): largest spectral radius "
                f"{self.spectral_radius:.6f} (must be < 1), largest ‖T_zw‖∞ {self.hinf_max:.4g}",
                "no LMI certificate for a moving scheduling signal: the FMU runs are the witness"]


def reference_filter(bandwidth: float | None, damping: float, ny: int, Ts: float
                     ) -> tuple[np.ndarray, ...] | None:
    """(A_f, B_f, C_f, D_f) of ω²/(s² + 2ζωs + ω²) (ω = ``bandwidth``, ζ = ``damping``) on each of the ny
    references, zero-order hold; None without a bandwidth."""
    if bandwidth is None:
        return None
    w, z = bandwidth, damping
    one = control.ss(control.sample_system(control.tf([w * w], [1.0, 2 * z * w, w * w]), Ts, method="zoh"))
    F = control.append(*[one] * ny) if ny > 1 else one
    return tuple(np.asarray(M, dtype=float) for M in (F.A, F.B, F.C, F.D))


def with_reference_filter(K: tuple[np.ndarray, ...], filt: tuple[np.ndarray, ...], ny: int
                           ) -> tuple[np.ndarray, ...]:
    """K from [r; y] with r = filter(r_raw): state [x_K; x_f],
    A = [Ak  Bk_r C_f; 0  A_f], B = [Bk_r D_f  Bk_y; B_f  0], C = [Ck  Dk_r C_f], D = [Dk_r D_f  Dk_y]."""
    Ak, Bk, Ck, Dk = K
    Af, Bf, Cf, Df = filt
    nk, nf = Ak.shape[0], Af.shape[0]
    A = np.block([[Ak, Bk[:, :ny] @ Cf], [np.zeros((nf, nk)), Af]])
    B = np.block([[Bk[:, :ny] @ Df, Bk[:, ny:]], [Bf, np.zeros((nf, ny))]])
    return A, B, np.hstack([Ck, Dk[:, :ny] @ Cf]), np.hstack([Dk[:, :ny] @ Df, Dk[:, ny:]])


def _copy_gains(v: VertexPlant, G: slice, ny: int) -> np.ndarray:
    """Observer rows of the weight states, [B1_W D21_r⁺, A_WG C_G⁺] (module docstring); ModelError when a
    weight state depends on the noise or on anything but r, y and u."""
    n = v.A.shape[0]
    W = np.setdiff1d(np.arange(n), np.arange(n)[G])
    D21_r, C_G = v.D21[:ny], v.C2[ny:, G]
    L_r = v.B1[W] @ np.linalg.pinv(D21_r)
    L_y = v.A[np.ix_(W, np.arange(n)[G])] @ np.linalg.pinv(C_G)
    residual = max(np.linalg.norm(v.B1[W] - L_r @ D21_r), np.linalg.norm(v.A[np.ix_(W, np.arange(n)[G])]
                                                                           - L_y @ C_G))
    if residual > _COPY_TOL * max(1.0, np.linalg.norm(v.A)):
        raise ModelError("a weight state of the generalized plant is not driven by r, y and u alone (a "
                         "dynamic W_R or W_N): the observer design needs static W_R and W_N")
    L = np.zeros((n, 2 * ny))
    L[W, :ny], L[W, ny:] = L_r, L_y
    return L


def _input_filter_dc(WB: control.StateSpace | None, nu: int) -> tuple[np.ndarray, np.ndarray]:
    """(W_B(1), (I − A_B)⁻¹B_B): W_B's DC gain and its state per unit of constant u (identity and an empty
    map without an input filter)."""
    if WB is None:
        return np.eye(nu), np.zeros((0, nu))
    A, B, C, D = (np.asarray(M, dtype=float) for M in (WB.A, WB.B, WB.C, WB.D))
    state = np.linalg.solve(np.eye(A.shape[0]) - A, B)
    return C @ state + D, state


def _feedforward(Ag: np.ndarray, Bg: np.ndarray, Cg: np.ndarray, F: np.ndarray, blocks: dict[str, slice],
                 n: int, WB: control.StateSpace | None) -> np.ndarray:
    """(nu, ny) gains u = u_ss − F x_ss per reference (module docstring), W_B's equilibrium included."""
    nG, nu, ny = Ag.shape[0], Bg.shape[1], Cg.shape[0]
    M = np.block([[Ag - np.eye(nG), Bg], [Cg, np.zeros((ny, nu))]])
    dc, per_u = _input_filter_dc(WB, nu)
    out = np.zeros((nu, ny))
    for j in range(ny):
        target = np.r_[np.zeros(nG), np.eye(ny)[j]]
        sol = np.linalg.lstsq(M, target, rcond=None)[0]
        if np.linalg.norm(M @ sol - target) > _REACH_TOL:
            continue  # this output cannot be held at a nonzero value: no feed-forward on its reference
        u = np.linalg.solve(dc, sol[nG:])  # u_p = W_B(1) u at steady state
        x_ss = np.zeros(n)
        x_ss[blocks["G"]] = sol[:nG]
        if "B" in blocks:
            x_ss[blocks["B"]] = per_u @ u
        out[:, j] = u - F @ x_ss
    return out


def _vertex_controller(v: VertexPlant, model_matrices: tuple[np.ndarray, ...], blocks: dict[str, slice],
                       WB: control.StateSpace | None, settings: ObserverSettings) -> tuple[np.ndarray, ...]:
    """(Ak, Bk, Ck, Dk) from [r; y_m] to u (before W_B) at one breakpoint, state [x̂; d̂] (module
    docstring): x̂⁺ = A x̂ + B2 u + E d̂ + L([r; y_m] − C2 x̂), d̂⁺ = d̂ + L_d(y_m − C_G x̂_G),
    u = F x̂ − K_d d̂ + N r."""
    Ag, Bg, Cg, _ = model_matrices
    n, _, nu, _, nmeas = v.dims
    ny, nG, G = nmeas // 2, Ag.shape[0], blocks["G"]
    if not np.allclose(v.A[G, G], Ag, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(Ag).max())):
        raise ModelError("the generalized plant's first states are not the model's (augment changed its "
                         "state order): the observer cannot copy the weights")
    K, _, _ = control.dlqr(v.A, v.B2, v.C1.T @ v.C1, v.D12.T @ v.D12, v.C1.T @ v.D12)
    F = -np.asarray(K, dtype=float)
    Aa = np.block([[Ag, Bg], [np.zeros((nu, nG)), np.eye(nu)]])
    Ca = np.hstack([Cg, np.zeros((ny, nu))])
    Q = np.zeros((nG + nu, nG + nu))
    Q[:nG, :nG] = settings.input * Bg @ Bg.T + settings.state * np.eye(nG)
    Q[nG:, nG:] = settings.disturbance * np.eye(nu)
    La, _, _ = control.dlqe(Aa, np.eye(nG + nu), Ca, Q, settings.noise ** 2 * np.eye(ny))
    La = np.asarray(La, dtype=float)
    L = _copy_gains(v, G, ny)
    L[G, ny:] = La[:nG]
    E = np.zeros((n, nu))
    E[G] = Bg
    # u = F x̂ − K_d d̂ with K_d = (I − F_B (I − A_B)⁻¹B_B) W_B(1)⁻¹: the load is cancelled at steady state
    # including W_B's own state, on which F also acts
    dc, per_u = _input_filter_dc(WB, nu)
    F_B = F[:, blocks["B"]] if "B" in blocks else np.zeros((nu, 0))
    Fc = np.hstack([F, -(np.eye(nu) - F_B @ per_u) @ np.linalg.inv(dc)])
    Ao = np.block([[v.A - L @ v.C2, E], [np.hstack([-La[nG:] @ Cg, np.zeros((nu, n - nG))]), np.eye(nu)]])
    Bo = np.vstack([L, np.hstack([np.zeros((nu, ny)), La[nG:]])])
    Bu = np.vstack([v.B2, np.zeros((nu, nu))])
    Dff = np.hstack([_feedforward(Ag, Bg, Cg, F, blocks, n, WB), np.zeros((nu, ny))])
    return Ao + Bu @ Fc, Bo + Bu @ Dff, Fc, Dff


@dataclass
class ObserverResult:
    """The vertex controllers (from [r; y_m] to u before W_B, reference filter included), the exported
    :class:`LPVController` (W_B in series), its anti-windup gains (N, n, nu) and the frozen check."""

    K_vertices: list[tuple[np.ndarray, ...]]
    controller: LPVController
    antiwindup_gains: np.ndarray
    check: FrozenCheck


def antiwindup_gains(model_B: list[np.ndarray], order: int) -> np.ndarray:
    """(N, order, nu) gains L_i of the exported controller's anti-windup x⁺ += L_i(u_a − u): the model's
    B_G at vertex i at the model-estimate rows (its first states), zero elsewhere (module docstring)."""
    gains = np.zeros((len(model_B), order, model_B[0].shape[1]))
    for L, B in zip(gains, model_B, strict=True):
        L[:B.shape[0]] = B
    return gains


def frozen_check(plant: GeneralizedPlant, K_vertices: list[tuple[np.ndarray, ...]]) -> FrozenCheck:
    """:class:`FrozenCheck` of the controller Σλ_iK_i on the plant Σλ_iP_i along the breakpoints."""
    lams = design_coordinates(plant.polytope, plant.basis, FROZEN_PER_SEGMENT)
    loops = interpolated_loops(plant.vertices, K_vertices, lams, plant.Ts)
    radius = max(float(np.abs(loop.poles()).max()) for loop in loops)
    return FrozenCheck(radius, max(float(control.norm(loop, "inf")) for loop in loops), len(lams))


def observer_design(plant: GeneralizedPlant, model: LPVSS, settings: ObserverSettings) -> ObserverResult:
    """The controller of the module docstring at every breakpoint of ``plant`` (a 2-DOF generalized plant
    of ``model`` with its weights on a piecewise polytope), interpolated with the plant's λ(p).

    Raises:
        ModelError: a 1-DOF plant, a polytope without breakpoints, or a dynamic W_R or W_N.
    """
    if plant.structure != "2dof":
        raise ModelError('the observer design reads references and measurements separately: set [synth] '
                         'structure = "2dof"')
    if plant.polytope.breakpoints is None:
        raise ModelError("the observer design interpolates frozen designs between breakpoints: give [synth] "
                         f"breakpoints (this design's polytope is {plant.polytope.kind!r})")
    blocks = state_blocks(model, plant.weights, plant.structure)
    WB = plant.input_filter
    model_vertices = vertex_matrices(model, plant.polytope)
    K = [_vertex_controller(v, mats, blocks, WB, settings)
         for v, mats in zip(plant.vertices, model_vertices, strict=True)]
    filt = reference_filter(settings.filter_bandwidth, settings.filter_damping, model.ny, model.Ts)
    if filt is not None:
        K = [with_reference_filter(k, filt, model.ny) for k in K]
    check = frozen_check(plant, K)
    exported = K if WB is None else [series_input_filter(k, WB) for k in K]
    stacks = [np.array([k[m] for k in exported]) for m in range(4)]
    info = {"method": "observer", "gamma": check.hinf_max, "spectral_radius": check.spectral_radius,
            "breakpoints": [float(b) for b in plant.polytope.breakpoints],
            "observer": {"input": settings.input, "state": settings.state,
                         "disturbance": settings.disturbance, "noise": settings.noise},
            "reference_filter": None if filt is None else {"bandwidth": settings.filter_bandwidth,
                                                           "damping": settings.filter_damping}}
    controller = LPVController(*stacks, plant.polytope, plant.basis, plant.Ts, info=info,
                               structure=plant.structure)
    gains = antiwindup_gains([B for _, B, _, _ in model_vertices], controller.order)
    return ObserverResult(K, controller, gains, check)
