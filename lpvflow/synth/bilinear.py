"""The well-conditioned coordinates every synthesis LMI is posed in, and the closed-loop certificate.

**Bilinear (Cayley) image.** With Ts = 1–5 ms every pole of a sampled plant and of its integral weights
sits within 1e-6…1e-2 of z = 1, and the discrete bounded-real LMI carries its information in O(Ts)
differences of O(‖𝒳‖) blocks, which an interior-point solver resolves only to ~1e-8/Ts. The map
z = (1 + s)/(1 − s),

    A_c = (A − I)(I + A)⁻¹,  B_c = √2 (I + A)⁻¹B,  C_c = √2 C(I + A)⁻¹,  D_c = D − C(I + A)⁻¹B,

preserves ‖·‖∞ and maps the discrete bounded-real inequality with Lyapunov matrix 𝒳 onto the continuous
one with the *same* 𝒳 (Gahinet & Apkarian 1994, §5 derive the discrete conditions through it), so a
condition imposed vertex by vertex can be solved on the images, where poles clustered at z = 1 become
poles spread over the left half plane.

**Scalings that change nothing but the numbers** (:class:`Coordinates`): a frequency normalisation
s = ω₀s' (A_c/ω₀, B_c/√ω₀, C_c/√ω₀: the continuous LMIs are invariant under it with the same 𝒳), a state
transform x = T x̄, and diagonal scalings of u and y. Controllers map y to u, so none of these changes the
closed loop's transfer function; :meth:`Coordinates.controller` maps a controller back.

**Certificate** (:func:`certificate_margin`): the closed loop is rebuilt from the returned discrete plant
and controller numbers, mapped by :func:`cayley`, written where 𝒳 = I, and its bounded-real matrix must be
negative definite with a Jacobi-scaled margin above round-off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from lpvflow.synth.plant import VertexPlant, interpolate
from lpvflow.validate.stability import scaled_margin

#: Largest condition number of the balancing state transform T that is used.
MAX_BALANCING_CONDITION = 1e8
#: Relative floor of :func:`lqg_balancing`: an eigenvalue of X or Y below this times the largest is raised
#: to it (such eigenvalues carry no reliable digit of a Riccati solution in double precision), so a stable
#: mode no input drives (or no output sees) in floating point does not make the LQG pair singular; a pair
#: above the floor is used exactly as solved. Measured on seed 2047's case 20 of tests/hinf_cases.py (a
#: 10-state chain whose T-weight state is driven through a relative degree of 10, |w·[B1 B2]| ≈ 1e-21):
#: without it Y had an eigenvalue −1e-19, no balancing was used and γ ended 5.49× SB10DD; with it 1.0031×.
LQG_FLOOR = 1e-12


def cayley(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, ...]:
    """Bilinear image (A_c, B_c, C_c, D_c) of a discrete system, z = (1 + s)/(1 − s) (module docstring)."""
    n = A.shape[0]
    M = np.linalg.inv(np.eye(n) + A)
    return (A - np.eye(n)) @ M, np.sqrt(2.0) * M @ B, np.sqrt(2.0) * C @ M, D - C @ M @ B


def inverse_cayley(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, ...]:
    """The discrete system whose :func:`cayley` image is (A, B, C, D)."""
    n = A.shape[0]
    M = np.linalg.inv(np.eye(n) - A)
    return (np.eye(n) + A) @ M, np.sqrt(2.0) * M @ B, np.sqrt(2.0) * C @ M, D + C @ M @ B


def cayley_vertex(v: VertexPlant) -> VertexPlant:
    """:func:`cayley` of a partitioned generalized plant, partition kept."""
    nw, nz = v.dims[1], v.dims[3]
    B, C = np.hstack([v.B1, v.B2]), np.vstack([v.C1, v.C2])
    D = np.block([[v.D11, v.D12], [v.D21, v.D22]])
    Ac, Bc, Cc, Dc = cayley(v.A, B, C, D)
    return VertexPlant(Ac, Bc[:, :nw], Bc[:, nw:], Cc[:nz], Cc[nz:], Dc[:nz, :nw], Dc[:nz, nw:],
                       Dc[nz:, :nw], Dc[nz:, nw:])


def closed_loop(v: VertexPlant, K: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """(𝒜, ℬ, 𝒞, 𝒟) of the vertex plant with u = K y, state [x; x_K]; with D22 ≠ 0 the algebraic loop
    u = E(C_K x_K + D_K C2 x + D_K D21 w), E = (I − D_K D22)⁻¹, is solved."""
    Ak, Bk, Ck, Dk = K
    E = np.linalg.inv(np.eye(Dk.shape[0]) - Dk @ v.D22)
    Fx, Fk, Fw = E @ Dk @ v.C2, E @ Ck, E @ Dk @ v.D21        # u = Fx x + Fk x_K + Fw w
    Gx, Gk, Gw = v.C2 + v.D22 @ Fx, v.D22 @ Fk, v.D21 + v.D22 @ Fw  # y = Gx x + Gk x_K + Gw w
    A = np.block([[v.A + v.B2 @ Fx, v.B2 @ Fk], [Bk @ Gx, Ak + Bk @ Gk]])
    B = np.vstack([v.B1 + v.B2 @ Fw, Bk @ Gw])
    C = np.hstack([v.C1 + v.D12 @ Fx, v.D12 @ Fk])
    return A, B, C, v.D11 + v.D12 @ Fw


def bounded_real_matrix(loop: tuple[np.ndarray, ...], X: np.ndarray, gamma: float) -> np.ndarray:
    """[𝒜ᵀ𝒳 + 𝒳𝒜  𝒳ℬ  𝒞ᵀ; ℬᵀ𝒳  −γI  𝒟ᵀ; 𝒞  𝒟  −γI] of a continuous loop: ≺ 0 ⟺ stable with ‖·‖∞ < γ
    certified by V = ξᵀ𝒳ξ (bounded-real lemma, Gahinet & Apkarian 1994, Lemma 2.1)."""
    A, B, C, D = loop
    nw, nz = B.shape[1], C.shape[0]
    return np.block([[A.T @ X + X @ A, X @ B, C.T],
                     [B.T @ X, -gamma * np.eye(nw), D.T],
                     [C, D, -gamma * np.eye(nz)]])


def certificate_margin(v: VertexPlant, K: tuple[np.ndarray, ...], F: np.ndarray, gamma: float) -> float:
    """Jacobi-scaled margin of the vertex certificate 𝒳 = FᵀF minus its round-off bound (> 0: accepted).

    The discrete closed loop of ``v`` and ``K`` is rebuilt from their numbers and mapped by :func:`cayley`
    (exact: the discrete bounded-real inequality with 𝒳 holds iff the continuous one holds for the image
    with the same 𝒳), then written in the coordinates ξ̃ = Fξ where 𝒳 becomes I (𝒜̃ = F𝒜F⁻¹, ℬ̃ = Fℬ,
    𝒞̃ = 𝒞F⁻¹: a congruence, so definiteness is unchanged, while the small and large directions of 𝒳 no
    longer share one floating-point scale). With M = :func:`bounded_real_matrix` there, M̃ = D⁻¹(−M)D⁻¹
    (D² = |diag M|) and the margin is :func:`lpvflow.validate.stability.scaled_margin` of −M with its own
    absolute values as the size of its terms: λ_min(M̃) − ROUNDOFF_FACTOR·m·ε·‖|M̃|‖₂. A loop with a pole
    at z = −1 (no Cayley image) or non-finite numbers has margin −inf.
    """
    try:
        A, B, C, D = cayley(*closed_loop(v, K))
        Fi = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        return -np.inf
    M = bounded_real_matrix((F @ A @ Fi, F @ B, C @ Fi, D), np.eye(len(F)), gamma)
    if not np.all(np.isfinite(M)):
        return -np.inf
    return scaled_margin(-M, np.abs(M))


@dataclass
class Coordinates:
    """x = T x̄, s = ω₀s', u = D_u ū, y = D_y ȳ applied to the Cayley image of a vertex (D_u, D_y
    diagonal; module docstring)."""

    T: np.ndarray
    omega: float
    du: np.ndarray
    dy: np.ndarray

    def apply(self, vc: VertexPlant) -> VertexPlant:
        Ti, r, du, dy = np.linalg.inv(self.T), np.sqrt(self.omega), self.du, self.dy
        return VertexPlant(Ti @ vc.A @ self.T / self.omega, Ti @ vc.B1 / r, Ti @ vc.B2 * du / r,
                           vc.C1 @ self.T / r, (vc.C2 @ self.T / r) / dy[:, None], vc.D11, vc.D12 * du,
                           vc.D21 / dy[:, None], vc.D22 * du / dy[:, None])

    def controller(self, K: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        """The continuous controller from y to u of one designed from ȳ to ū in s' (same state)."""
        Ak, Bk, Ck, Dk = K
        r, du, dy = np.sqrt(self.omega), self.du, self.dy
        return self.omega * Ak, r * Bk / dy[None, :], r * du[:, None] * Ck, du[:, None] * Dk / dy[None, :]

    def transformed(self, T: np.ndarray) -> Coordinates:
        """These coordinates followed by the state transform x̄ = T x̃."""
        return Coordinates(self.T @ T, self.omega, self.du, self.dy)

    def discrete(self) -> Coordinates:
        """The state and u/y scalings without the frequency scale (ω₀ = 1), for LMIs posed on the discrete
        vertices themselves (the state transform commutes with the Cayley map)."""
        return Coordinates(self.T, 1.0, self.du, self.dy)


def initial_coordinates(cayleys: list[VertexPlant]) -> Coordinates:
    """Coordinates that need no SDP: the state transform of :func:`lqg_balancing` at the mean of the
    vertices (identity when it does not exist), then ω₀ = the largest ‖A_c‖₂ and D_u, D_y giving every
    column of [B2; D12] and every row of [C2 D21] unit norm at the first vertex (the whole column and row:
    a 2-DOF reference has no state in it, and a measurement in other units has its size in D21 as much as
    in C2). w and z are not scaled per channel: that would change ‖T_zw‖∞.

    The state transform makes the coordinates the user's realization was given in irrelevant (a diagonal
    state scaling of condition 95 made a 9-state chain of tests/hinf_cases.py unsolvable in them, and one
    of the README plant left it 79 % above SB10DD). Diagonal balancing of |A_c| alone
    (``scipy.linalg.matrix_balance``) is not used: it ignores B and C, and on 14 random weighted plants
    (seed 2026) it left 11 more than 1 % from SB10DD."""
    n = cayleys[0].dims[0]
    mean = interpolate(cayleys, np.full(len(cayleys), 1.0 / len(cayleys)))
    T = lqg_balancing(Coordinates(np.eye(n), 1.0, *_io_scales(mean, np.eye(n), 1.0)).apply(mean))
    T = np.eye(n) if T is None else T
    Ti = np.linalg.inv(T)
    omega = max(float(np.linalg.norm(Ti @ vc.A @ T, 2)) for vc in cayleys)
    return Coordinates(T, omega, *_io_scales(cayleys[0], T, omega))


def _io_scales(vc: VertexPlant, T: np.ndarray, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """D_u, D_y giving the columns of [B2; D12] and rows of [C2 D21] of ``vc`` unit norm in (T, ω₀)."""
    nu, ny = vc.dims[2], vc.dims[4]
    v = Coordinates(T, omega, np.ones(nu), np.ones(ny)).apply(vc)
    du = 1.0 / np.maximum(np.linalg.norm(np.vstack([v.B2, v.D12]), axis=0), 1e-300)
    dy = np.maximum(np.linalg.norm(np.hstack([v.C2, v.D21]), axis=1), 1e-300)
    return du, dy


def lqg_balancing(vc: VertexPlant) -> np.ndarray | None:
    """The state transform that balances the LQG Riccati pair of a continuous system (Jonckheere &
    Silverman 1983, "A new set of invariants for linear systems — application to reduced order
    compensator design", IEEE TAC 28(10)), here of the generalized plant as one system with all its
    inputs B = [B1 B2] and outputs C = [C1; C2]: the stabilizing X, Y ⪰ 0 of

        AᵀX + XA − XBBᵀX + CᵀC = 0,    AY + YAᵀ − YCᵀCY + BBᵀ = 0,

    and T with T⁻¹YT⁻ᵀ = TᵀXT = Σ (:func:`balancing_transform`). Unlike Gramians they exist for unstable
    plants; they depend on the realization only through T, so the coordinates T gives do not depend on
    the state basis the plant was given in. (The H2 pair of the H∞ problem itself is singular for mixed
    sensitivity: the weight states driven by the measured error are estimated exactly.) Eigenvalues of X
    and Y below :data:`LQG_FLOOR` times their largest are raised to that floor (X, Y ≻ 0 also when a stable
    mode is, in floating point, uncontrollable from every input or unobservable from every output, e.g. a
    weight state driven through a plant of high relative degree). None when either equation has no
    stabilizing solution or the pair is not positive definite."""
    B, C = np.hstack([vc.B1, vc.B2]), np.vstack([vc.C1, vc.C2])
    try:
        X = scipy.linalg.solve_continuous_are(vc.A, B, C.T @ C, np.eye(B.shape[1]))
        Y = scipy.linalg.solve_continuous_are(vc.A.T, C.T, B @ B.T, np.eye(C.shape[0]))
    except (np.linalg.LinAlgError, ValueError):
        return None
    return balancing_transform(_floored(Y), _floored(X))


def _floored(M: np.ndarray) -> np.ndarray:
    """Symmetric M with its eigenvalues raised to at least :data:`LQG_FLOOR` times the largest; M itself
    when none is below."""
    w, U = np.linalg.eigh(0.5 * (M + M.T))
    floor = LQG_FLOOR * max(w[-1], 0.0)
    return M if w[0] >= floor else (U * np.maximum(w, floor)) @ U.T


def balancing_transform(R: np.ndarray, S: np.ndarray) -> np.ndarray | None:
    """T with T⁻¹RT⁻ᵀ = TᵀST = Σ (R = LLᵀ, LᵀSL = VΣ²Vᵀ, T = LVΣ^(−1/2)), or None unless R and S are
    positive definite and T is finite with cond(T) ≤ :data:`MAX_BALANCING_CONDITION`."""
    R, S = 0.5 * (R + R.T), 0.5 * (S + S.T)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(S))):
        return None
    r, U = np.linalg.eigh(R)
    if r[0] <= 0 or np.linalg.eigvalsh(S)[0] <= 0:
        return None
    L = U * np.sqrt(r)[None, :]
    w, V = np.linalg.eigh(L.T @ S @ L)
    if w[0] <= 0:
        return None
    T = L @ V / w[None, :] ** 0.25
    return T if np.all(np.isfinite(T)) and np.linalg.cond(T) <= MAX_BALANCING_CONDITION else None
