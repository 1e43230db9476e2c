"""The central H∞ controller at a given level, from an LMI solution and explicit formulas.

:func:`lpvflow.synth.vertex_synthesis.synthesize_vertices` returns the controller the level SDP's solver
stops at: the largest-margin point of the LMIs, whose controller has a high-frequency gain of about γ
(measured 4–10× the Riccati central controller's on the ADIP loop-shaping plants). The *central*
controller (Doyle, Glover, Khargonekar & Francis 1989, "State-space solutions to standard H2 and H∞
control problems", IEEE TAC 34(8)) is the one the Riccati solutions give; here it is reached from the LMIs
alone, in two steps, on the Cayley image of every vertex in the balanced coordinates of
:mod:`lpvflow.synth.eliminated`:

1. **The largest R, S at γ.** The eliminated conditions of Gahinet & Apkarian (1994, Thm. 4.3) in R, S
   (:func:`lpvflow.synth.eliminated.eliminated_matrices`) are equivalent, for one plant, to two Riccati
   inequalities in R⁻¹ and S⁻¹ and a coupling; their solution set has a largest element in the
   positive-semidefinite order — the stabilizing Riccati solutions, on its boundary, where the central
   controller lives. :func:`central_solution` measures margins relative to the size of each condition
   (:func:`_relative_margin`: [R I; I S] ⪰ ε·blkdiag(R, S), each projected matrix ⪯ −ε·Nᵀ blkdiag(R or S,
   γI) N, linear in R, S for fixed ε): ε_w of the widest point (max t of the plain conditions), then
   max trace R + trace S keeping ε = ``CENTRAL_MARGIN``·ε_w, with R ⪯ ``CAP``·R_w, S ⪯ ``CAP``·S_w (directions
   the performance output does not see leave R, S unbounded), and that point moved towards the widest one
   by the exact convex combination that restores ε where the solver left it short (the conditions are
   affine in R, S, so the largest eigenvalue is convex along the segment).
2. **Explicit controller variables** (in the spirit of Gahinet, "Explicit controller formulas for
   LMI-based H∞ synthesis", Automatica 32(7), 1996: for fixed R, S choose the controller in closed form,
   not by another SDP). In the change of variables of Scherer, Gahinet & Chilali (1997, IEEE TAC 42(7),
   §IV) with Y = R, X = S the closed-loop bounded-real inequality reads, blocks [Y-row; X-row; w; z],

       [AR + RAᵀ + B2Ĉ + (·)ᵀ   Âᵀ + A + B2D̂C2        N1       ]
       [        ·              SA + AᵀS + B̂C2 + (·)ᵀ   N2       ]  ≺ 0,   H = [−γI  D̂11ᵀ; D̂11  −γI],
       [        ·                      ·               H        ]

   N1 = [B1 + B2D̂D21, (C1R + D12Ĉ)ᵀ], N2 = [SB1 + B̂D21, (C1 + D12D̂C2)ᵀ], D̂11 = D11 + D12D̂D21. With
   D̂ = −D12⁺D11D21⁺ (the least-squares D̂11), Â cancels the Schur complement's coupling,
   Â = (N1H⁻¹N2ᵀ − A − B2D̂C2)ᵀ, and the inequality splits into Φ11(Ĉ) ≺ 0 and Φ22(B̂) ≺ 0, quadratic
   in Ĉ and B̂; completing the squares,

       Φ11 = Φ11⁰ + EĈ + ĈᵀEᵀ + ĈᵀQĈ,  E = B2 − b1H_wz D12 − RC1ᵀH_zz D12,  Q = −D12ᵀH_zz D12 ≻ 0,
       Ĉ = −Q⁻¹Eᵀ;
       Φ22 = Φ22⁰ + B̂G + GᵀB̂ᵀ + B̂PB̂ᵀ,  G = C2 − D21H_ww B1ᵀS − D21H_wz c1,  P = −D21H_ww D21ᵀ ≻ 0,
       B̂ = −GᵀP⁻¹

   (b1 = B1 + B2D̂D21, c1 = C1 + D12D̂C2, H⁻¹ partitioned by w, z). Each is the smallest Φ in the
   semidefinite order, so the split inequality holds whenever any controller of the class meets γ with this
   R, S (Gahinet & Apkarian 1994, Lemma 3.1: the projected conditions are exactly that). The controller is
   then step 6 of :mod:`lpvflow.synth.vertex_synthesis` (M Nᵀ = I − RS), and the certificate the same
   numpy re-check of the discrete closed loop with 𝒳 = [S N; Nᵀ ·] (:func:`certificate_margin`). When
   that 𝒳 fails the re-check (the reconstruction from R, S near their largest loses it to round-off while
   the loop itself meets γ), the controller's own bounded-real analysis supplies 𝒳 — for one plant the
   stabilizing solution of its bounded-real Riccati equation, for several vertices an SDP — re-checked the
   same way (:func:`closed_loop_lyapunov_factor`).

At the largest R, S the split blocks are singular and the controller is the Riccati central one; the
relative margin keeps it strictly inside. Step 6 runs in the coordinates that balance R, S (R = S = Σ, so
I − RS is diagonal). Measured (scratch runs, 2026-11-28; benchmarks/README.md): on 10 of the 28
loop-shaping plants of the bundled ADIP design 0.1–0.7 % from the Riccati central controller at the same
level (max over frequency of the difference, relative to its largest gain); on 30 random loop-shaping
plants 28 certified (b ≥ 1/γ), 25 of them within 10 % of the Riccati central controller. On random
mixed-sensitivity plants of tests/hinf_cases.py at 1.01 × hinfsyn's γ (2026-11-29, numpy 2.4.6, cvxpy
1.9.3, Clarabel 0.11.1; draws of 20 with seeds 2026, 2027, 2031): 20, 17 and 18 certified (8, 11 and 15
with the synthesis's 𝒳 alone, whose controllers python-control / AB13DD found below γ all the same); the
others end in a SynthesisError "accuracy" (an eliminated-LMI or analysis solve that Clarabel ends in error).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import control
import cvxpy as cp
import numpy as np
import scipy.linalg
from slycot.exceptions import SlycotError

from lpvflow.errors import SynthesisError
from lpvflow.synth.bilinear import (
    balancing_transform,
    cayley,
    cayley_vertex,
    certificate_margin,
    closed_loop,
    inverse_cayley,
)
from lpvflow.synth.eliminated import (
    Preconditioned,
    eliminated_matrices,
    preconditioned,
    projections,
    strict_constraints,
    sym,
)
from lpvflow.synth.plant import VertexPlant
from lpvflow.synth.riccati import riccati_judgement, riccati_witness
from lpvflow.synth.sdp import SolveReport, solve
from lpvflow.synth.vertex_synthesis import (
    HinfResult,
    VertexController,
    check_assumptions,
    closed_loop_lyapunov,
    homogenizing_scale,
    loop_shift,
    reconstruct_controller,
)

#: ε of :func:`_riccati_factor`, in the coordinates where the synthesis's 𝒳 is I: the strictness of the
#: Riccati certificate. Larger values move the equation's solvability limit below γ on loops with poles near
#: the unit circle (tests/hinf_cases.py seed 3003 case 13: 1e-6 and above had no stabilizing solution).
RICCATI_REGULARIZATION = 1e-8
#: The relative margin the central point keeps, a fraction of the widest point's (:func:`_relative_margin`).
CENTRAL_MARGIN = 0.05
#: R ⪯ CAP·R_w, S ⪯ CAP·S_w (R_w, S_w the widest point): the bound on directions the conditions leave
#: unbounded (states the performance output does not see, whose Riccati solution is singular). Measured:
#: 1e2 keeps the ADIP loop-shaping controllers up to 107 % from the Riccati central one (the bound binds),
#: 1e3 within 0.7 %; on 14 random mixed-sensitivity plants 11 are certified at 1e3, 6 at 1e4, 3 at 1e5
#: (step 6 loses the certificate to round-off as R, S grow).
CAP = 1e3


def explicit_hats(v: VertexPlant, R: np.ndarray, S: np.ndarray, gamma: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Â, B̂, Ĉ, D̂) of the module docstring for the continuous vertex ``v`` (D22 left to the loop shift).

    Raises:
        SynthesisError: ‖D11 + D12D̂D21‖ ≥ γ (no controller reaches γ: category ``"infeasible"``), or D12
            (D21) without full column (row) rank (``"assumption"``).
    """
    A, B1, B2, C1, C2, D11, D12, D21 = v.A, v.B1, v.B2, v.C1, v.C2, v.D11, v.D12, v.D21
    nw, nz = B1.shape[1], C1.shape[0]
    Dh = -np.linalg.pinv(D12) @ D11 @ np.linalg.pinv(D21)
    D11h = D11 + D12 @ Dh @ D21
    if not np.linalg.norm(D11h, 2) < gamma:
        raise SynthesisError(f"the feed-through from w to z cannot be brought below γ = {gamma:.6g} "
                             f"(‖D11 + D12 D_K D21‖ ≥ {np.linalg.norm(D11h, 2):.6g}); raise the level",
                             category="infeasible")
    Hi = np.linalg.inv(np.block([[-gamma * np.eye(nw), D11h.T], [D11h, -gamma * np.eye(nz)]]))
    Hww, Hwz, Hzz = Hi[:nw, :nw], Hi[:nw, nw:], Hi[nw:, nw:]
    b1, c1 = B1 + B2 @ Dh @ D21, C1 + D12 @ Dh @ C2
    Q, P = -D12.T @ Hzz @ D12, -D21 @ Hww @ D21.T
    if max(np.linalg.cond(Q), np.linalg.cond(P)) > 1.0 / np.finfo(float).eps:
        raise SynthesisError("D12 of the bilinear image has no full column rank or D21 no full row rank (a "
                             "singular problem): the explicit central controller needs a regular one; use "
                             "hinfsyn's controller", category="assumption")
    E = B2 - b1 @ Hwz @ D12 - R @ C1.T @ Hzz @ D12
    Ch = -np.linalg.solve(Q, E.T)
    G = C2 - D21 @ Hww @ B1.T @ S - D21 @ Hwz @ c1
    Bh = -np.linalg.solve(P, G).T
    N1 = np.hstack([b1, (C1 @ R + D12 @ Ch).T])
    N2 = np.hstack([S @ B1 + Bh @ D21, c1.T])
    Ah = (N1 @ Hi @ N2.T - A - B2 @ Dh @ C2).T
    return Ah, Bh, Ch, Dh


def _sizes(verts: list[VertexPlant], gamma: float, R: cp.Variable, S: cp.Variable) -> list[cp.Expression]:
    """The size each eliminated condition is measured against, in the order of
    :func:`lpvflow.synth.eliminated.eliminated_matrices`: blkdiag(R, S) for [R I; I S], and
    N_Rᵀ blkdiag(R, γI, γI) N_R, N_Sᵀ blkdiag(S, γI, γI) N_S for the projected conditions (linear in R, S)."""
    n = R.shape[0]
    out = [cp.bmat([[R, np.zeros((n, n))], [np.zeros((n, n)), S]])]
    for v in verts:
        nw, nz = v.dims[1], v.dims[3]
        NR, NS = projections(v)
        out += [sym(NR.T @ cp.bmat([[R, np.zeros((n, nz + nw))],
                                    [np.zeros((nz + nw, n)), gamma * np.eye(nz + nw)]]) @ NR),
                sym(NS.T @ cp.bmat([[S, np.zeros((n, nw + nz))],
                                    [np.zeros((nw + nz, n)), gamma * np.eye(nw + nz)]]) @ NS)]
    return out


def _relative_margin(matrices: list[cp.Expression], sizes: list[cp.Expression]) -> float:
    """The largest ε with [R I; I S] ⪰ ε·blkdiag(R, S) and every projected matrix ⪯ −ε·its size, at the
    variables' current values (generalized eigenvalues; −inf when a size is not positive definite)."""
    out = []
    for k, (M, D) in enumerate(zip(matrices, sizes, strict=True)):
        Mv, Dv = (0.5 * (X.value + X.value.T) for X in (M, D))
        try:
            eig = scipy.linalg.eigvalsh(Mv if k == 0 else -Mv, Dv)
        except np.linalg.LinAlgError:
            return -np.inf
        out.append(eig[0])
    return float(min(out))


def _shifted_margin(matrices: list[cp.Expression], sizes: list[cp.Expression], eps: float) -> float:
    """λ_min([R I; I S] − ε·blkdiag(R, S)) and −λ_max(M + ε·size) of every projected matrix M, the smallest,
    at the variables' current values (≥ 0: the point keeps the relative margin ε)."""
    out = []
    for k, (M, D) in enumerate(zip(matrices, sizes, strict=True)):
        shifted = M.value - eps * D.value if k == 0 else -(M.value + eps * D.value)
        out.append(np.linalg.eigvalsh(0.5 * (shifted + shifted.T))[0])
    return float(min(out))


def _relative(matrices: list[cp.Expression], sizes: list[cp.Expression], eps: float) -> list[cp.Constraint]:
    pairs = zip(matrices[1:], sizes[1:], strict=True)
    return [matrices[0] >> eps * sizes[0]] + [M << -eps * D for M, D in pairs]


def _no_strict_solution(accurate: bool, gamma: float, riccati_optimum: Callable[[], float] | None
                        ) -> tuple[str, str]:
    """What a widest point without a positive margin means, and its category (:func:`central_solution`)."""
    if not accurate:
        return "the solve is not accurate enough to tell; raise the level", "accuracy"
    if riccati_optimum is None:
        return "no controller of this class reaches the level; raise it", "infeasible"
    judgement, category = riccati_judgement(riccati_optimum(), gamma)
    return f"{judgement}; raise the level", category


def central_solution(verts: list[VertexPlant], gamma: float, solver: str,
                     riccati_optimum: Callable[[], float] | None = None
                     ) -> tuple[np.ndarray, np.ndarray, float, SolveReport]:
    """Step 1 of the module docstring on the (continuous, balanced) vertices: (R, S, the relative margin ε
    they keep, report). Margins are relative (:func:`_relative_margin`): ε_w of the widest point (max t of
    the plain conditions), then max trace R + trace S keeping ε = CENTRAL_MARGIN·ε_w, moved towards the
    widest point where the solver left it short — the widest point itself when that solve returns no point
    (``report.status`` says so). ``riccati_optimum``: for one plant, its SB10DD optimum
    (:func:`lpvflow.synth.riccati.riccati_witness`), asked only when an accurate solve finds no strict
    solution: the conditions are exact for one plant (Gahinet & Apkarian 1994), so where SB10DD reaches γ
    the solver's verdict was round-off.

    Raises:
        SynthesisError: the conditions have no strict solution at γ (category ``"infeasible"`` when the
            solve was accurate and SB10DD, if asked, does not reach γ either; else ``"accuracy"``), or a
            solve returned no point (``"accuracy"``).
    """
    n = verts[0].dims[0]
    R, S, t = cp.Variable((n, n), symmetric=True), cp.Variable((n, n), symmetric=True), cp.Variable()
    matrices, sizes = eliminated_matrices(verts, gamma, R, S), _sizes(verts, gamma, R, S)
    what = f"the eliminated H∞ LMIs at γ = {gamma:.6g}"
    widest = solve(cp.Problem(cp.Maximize(t), [*strict_constraints(matrices, t, None), t <= 1]), solver, what,
                   fine=True)
    attempts = list(widest.attempts)
    eps_widest = _relative_margin(matrices, sizes)
    if not eps_widest > 0:
        verdict, category = _no_strict_solution(widest.accurate, gamma, riccati_optimum)
        raise SynthesisError(f"{what} have no strict solution (largest margin {float(t.value):.3g}, "
                             f"{widest.solver}: {widest.status}): {verdict}", category=category)
    widest_point = (R.value.copy(), S.value.copy())
    eps = CENTRAL_MARGIN * eps_widest
    cap = [R << CAP * widest_point[0], S << CAP * widest_point[1]]
    largest = cp.Problem(cp.Maximize(cp.trace(R) + cp.trace(S)), [*_relative(matrices, sizes, eps), *cap])
    start = time.perf_counter()
    try:
        central = solve(largest, solver, what, fine=True)
        central_point = (R.value.copy(), S.value.copy())
    except SynthesisError as exc:
        if exc.category != "accuracy":
            raise
        # no point from the largest solve: the widest point keeps ε_w > ε and is the answer (λ = 1 below);
        # random draws, tests/hinf_cases.py seed 2027 cases 1 and 5: Clarabel NumericalError at the fine and
        # the default tolerances, the widest point's controllers certified at 1.01 × hinfsyn's γ
        status = f"no point, widest point kept ({exc})"
        central = SolveReport(solver.upper(), status, 0.0, [(solver.upper(), status,
                                                            time.perf_counter() - start)])
        central_point = widest_point
    attempts += central.attempts
    # with ε fixed the conditions M + ε·size are affine in (R, S): their margin along the segment to the
    # widest point is at least the linear interpolation of the end margins, so this step restores ε exactly
    R.value, S.value = central_point
    shortfall = _shifted_margin(matrices, sizes, eps)
    R.value, S.value = widest_point
    spare = _shifted_margin(matrices, sizes, eps)
    lam = min(1.0, max(0.0, -shortfall / (spare - shortfall))) if shortfall < 0 else 0.0
    Rc, Sc = ((1 - lam) * C + lam * W for C, W in zip(central_point, widest_point, strict=True))
    R.value, S.value = Rc, Sc
    report = SolveReport(central.solver, central.status, sum(a[2] for a in attempts), attempts)
    return 0.5 * (Rc + Rc.T), 0.5 * (Sc + Sc.T), _relative_margin(matrices, sizes), report


def closed_loop_lyapunov_factor(vertices: list[VertexPlant], K_vertices: list[tuple[np.ndarray, ...]],
                                start: np.ndarray, gamma: float, solver: str
                                ) -> tuple[np.ndarray, SolveReport]:
    """A factor F (𝒳 = FᵀF) of a common Lyapunov matrix proving the level γ for the controller itself.

    The 𝒳 of step 2 (:func:`lpvflow.synth.vertex_synthesis.closed_loop_lyapunov`, factor ``start`` = F₀)
    is exact only for the R, S, M, N it is built from; near the largest R, S (‖S‖ up to 1e7 on the random
    mixed-sensitivity plants of tests/hinf_cases.py) the controller's floating-point reconstruction no
    longer satisfies the bounded-real inequality with it, although its closed loop meets γ (python-control
    / AB13DD). So the certificate is the controller's own analysis (bounded-real lemma, Gahinet & Apkarian
    1994, Lemma 2.1): in the coordinates ξ̃ = F₀ξ of every vertex's Cayley-image closed loop (𝒜̃, ℬ̃, 𝒞̃, 𝒟)
    find 𝒴 with [𝒜̃ᵀ𝒴 + 𝒴𝒜̃, 𝒴ℬ̃, 𝒞̃ᵀ; ·, −γI, 𝒟ᵀ; ·, ·, −γI] ≺ 0 and 𝒴 ≻ 0, homogenized as step 5 of
    :mod:`lpvflow.synth.vertex_synthesis` (𝒞̃, 𝒟, γI multiplied by τ, 𝒴 ⪯ I, max t with the matrices ⪯ −tI
    and 𝒴 ⪰ tI); then 𝒳 = F₀ᵀ(𝒴/τ)F₀. In those coordinates 𝒴 ≈ τI when F₀ is nearly right, so the SDP is
    well scaled. Its answer is only a candidate: :func:`certificate_margin` re-checks it in numpy. For one
    plant no SDP: 𝒳 is the bounded-real Riccati equation's stabilizing solution (:func:`_riccati_factor`;
    held-out draws of tests/hinf_cases.py, seeds 3001–3004 and 2031: never fewer central controllers
    certified than with the SDP, 2 more on seed 3003 and 2 more on 2031).

    Raises:
        SynthesisError: ``"accuracy"`` when the analysis returns no point (τ ≤ 0, or 𝒴/τ not positive
            definite; for one plant: no stabilizing Riccati solution, or one not positive definite).
    """
    if len(vertices) == 1:
        return _riccati_factor(vertices[0], K_vertices[0], start, gamma)
    inverse = np.linalg.inv(start)
    m = start.shape[0]
    Y, t, tau = cp.Variable((m, m), symmetric=True), cp.Variable(), cp.Variable()
    constraints = [Y >> t * np.eye(m), Y << np.eye(m)]
    for v, K in zip(vertices, K_vertices, strict=True):
        A, B, C, D = cayley(*closed_loop(v, K))
        A, B, C = start @ A @ inverse, start @ B, C @ inverse
        nw, nz = B.shape[1], C.shape[0]
        matrix = cp.bmat([[A.T @ Y + Y @ A, Y @ B, tau * C.T],
                          [B.T @ Y, -gamma * tau * np.eye(nw), tau * D.T],
                          [tau * C, tau * D, -gamma * tau * np.eye(nz)]])
        constraints.append(sym(matrix) << -t * np.eye(matrix.shape[0]))
    what = f"the closed-loop bounded-real LMIs of the central controller at γ = {gamma:.6g}"
    report = solve(cp.Problem(cp.Maximize(t), constraints), solver, what, refined=True)
    try:
        lyapunov = 0.5 * (Y.value + Y.value.T) / homogenizing_scale(tau)
        return np.linalg.cholesky(lyapunov).T @ start, report
    except np.linalg.LinAlgError:
        raise SynthesisError(f"{what} have no solution ({report.solver}: {report.status}): the controller "
                             "cannot be certified at this level; raise it", category="accuracy") from None


def _riccati_factor(v: VertexPlant, K: tuple[np.ndarray, ...], start: np.ndarray, gamma: float
                    ) -> tuple[np.ndarray, SolveReport]:
    """:func:`closed_loop_lyapunov_factor` for one plant, without an SDP: the discrete closed loop
    (𝒜, ℬ, 𝒞, 𝒟) in the coordinates ξ̃ = F₀ξ, and 𝒳̃ the stabilizing solution of the discrete
    bounded-real Riccati equation (the Schur complement of the bounded-real inequality on its −γI block,
    regularized by εI so that it holds strictly):

        𝒳̃ = 𝒜ᵀ𝒳̃𝒜 + 𝒞ᵀ𝒞/γ + εI − (𝒜ᵀ𝒳̃ℬ + 𝒞ᵀ𝒟/γ)(ℬᵀ𝒳̃ℬ − γI + 𝒟ᵀ𝒟/γ)⁻¹(ℬᵀ𝒳̃𝒜 + 𝒟ᵀ𝒞/γ),

    which has one exactly when the loop is stable with ‖T‖∞ < γ (and ε small), by python-control's
    ``dare`` (SLICOT through slycot, as :mod:`lpvflow.synth.controller` uses it) with the indefinite
    R = 𝒟ᵀ𝒟/γ − γI. The discrete inequality with 𝒳 holds iff the
    continuous one of the Cayley image does (:func:`certificate_margin` re-checks it there)."""
    start_time = time.perf_counter()
    A, B, C, D = closed_loop(v, K)
    inverse = np.linalg.inv(start)
    A, B, C = start @ A @ inverse, start @ B, C @ inverse
    what = f"the bounded-real Riccati equation of the central controller's loop at γ = {gamma:.6g}"
    try:
        X, _, _ = control.dare(A, B, C.T @ C / gamma + RICCATI_REGULARIZATION * np.eye(len(A)),
                               D.T @ D / gamma - gamma * np.eye(B.shape[1]), C.T @ D / gamma)
        factor = np.linalg.cholesky(0.5 * (X + X.T)).T @ start
    except (np.linalg.LinAlgError, ValueError, ArithmeticError, SlycotError) as exc:
        raise SynthesisError(f"{what} has no stabilizing solution ({str(exc).split('.')[0]}): the controller "
                             "cannot be certified at this level; raise it", category="accuracy") from None
    seconds = time.perf_counter() - start_time
    return factor, SolveReport("slycot", "riccati", seconds, [("slycot", "riccati", seconds)])


def central_vertices(vertices: list[VertexPlant], Ts: float, gamma: float, solver: str = "CLARABEL",
                     preconditioning: Preconditioned | None = None) -> HinfResult:
    """The central controller of the discrete vertex plants at level ``gamma`` (module docstring), with the
    certificate of :func:`lpvflow.synth.bilinear.certificate_margin` at every vertex. ``preconditioning``:
    the coordinates of :func:`lpvflow.synth.eliminated.preconditioned` for these vertices when already
    computed (``HinfResult.preconditioning`` of hinfsyn on the same plants), else computed here.

    Raises:
        SynthesisError: an assumption fails (``"assumption"``), no controller reaches γ (``"infeasible"``;
            for one plant only where SB10DD does not reach γ either, else ``"accuracy"``), or the controller
            fails its certificate (``"accuracy"``: round-off at this level; raise it).
    """
    check_assumptions(vertices)
    cayleys = [cayley_vertex(v) for v in vertices]
    pre = preconditioning or preconditioned(cayleys, gamma, solver)
    single = (lambda: riccati_witness(vertices[0], Ts)) if len(vertices) == 1 else None
    R, S, margin, report = central_solution(pre.vertices, gamma, solver, single)
    if preconditioning is None:  # SDPs solved by this call only
        report.attempts[:0] = pre.attempts
    # the same R, S in the coordinates that balance them (R = S = Σ, a congruence of every condition):
    # I − RS is then diagonal and step 6 inverts no ill-conditioned M, N
    coords = pre.coordinates
    T = balancing_transform(R, S)
    if T is not None:
        coords = coords.transformed(T)
        Ti = np.linalg.inv(T)
        R, S = Ti @ R @ Ti.T, T.T @ S @ T
        R, S = 0.5 * (R + R.T), 0.5 * (S + S.T)
    n = R.shape[0]
    W, sig, Zt = np.linalg.svd(np.eye(n) - R @ S)
    M, N = W * np.sqrt(sig), Zt.T * np.sqrt(sig)
    K_vertices = []
    for vc in cayleys:
        v = coords.apply(vc)
        K = loop_shift(reconstruct_controller(v, R, S, M, N, explicit_hats(v, R, S, gamma)), v.D22)
        K_vertices.append(inverse_cayley(*coords.controller(K)))
    back = scipy.linalg.block_diag(np.linalg.inv(coords.T), np.eye(n))
    try:
        start = np.linalg.cholesky(closed_loop_lyapunov(R, S, M, N)).T @ back
    except np.linalg.LinAlgError:
        raise SynthesisError(f"the central solution at γ = {gamma:.6g} gives a closed-loop Lyapunov matrix "
                             "that is not positive definite in floating point: raise the level",
                             category="accuracy") from None
    F = start
    certificate = [certificate_margin(v, K, F, gamma) for v, K in zip(vertices, K_vertices, strict=True)]
    if min(certificate) <= 0:  # the synthesis's 𝒳 lost to the reconstruction's round-off: analyse the loop
        F, analysis = closed_loop_lyapunov_factor(vertices, K_vertices, start, gamma, solver)
        report.attempts += analysis.attempts
        certificate = [certificate_margin(v, K, F, gamma) for v, K in zip(vertices, K_vertices, strict=True)]
    if min(certificate) <= 0:
        raise SynthesisError(f"the central controller at γ = {gamma:.6g} fails its certificate (margin "
                             f"{min(certificate):.3g}, LMI margin {margin:.3g}): round-off at this level; "
                             "raise it", category="accuracy")
    ss = [control.ss(*K, Ts) for K in K_vertices]
    controller = ss[0] if len(ss) == 1 else VertexController(K_vertices, Ts)
    return HinfResult(gamma, None, K_vertices, ss, controller, certificate, F, vertices, Ts, report)
