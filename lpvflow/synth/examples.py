"""Small synthetic plants with the thesis' weight sets (Boonto 2011, §6.2–6.3), for tests and benchmarks.

The thesis' identified models and data are not published, so these plants only
resemble them: same sampling time, input/output and scheduling structure, observable-form output
matrix (C constant, D = 0) and input matrix B(ψ) depending on the scheduling signal. Continuous
dynamics M ẍ = … are discretized by forward Euler, A = I + Ts·A_c(ψ), which keeps the model affine in ψ.

Weights: the thesis' transfer functions, with two documented changes. (1) The printed W_B has a
feed-through, which leaves B2 parameter dependent (thesis §6.2.3 does not discuss it); here W_B is the
strictly proper z⁻¹·(printed W_B) for the maglev and a first-order strictly proper low-pass for the ADIP.
(2) Poles on the unit circle are shifted inside by ε (:mod:`lpvflow.synth.weights`). (3) ADIP: one
torque cannot hold both angle errors at zero for every reference direction of this 1-DOF loop (the
thesis used a 2-DOF loop), so W_S on φ2 has its pole at 0.9 instead of the thesis' 0.999; with
0.999 the optimal γ exceeds 60 and Clarabel stops with a numerical error.
"""

from __future__ import annotations

import numpy as np

from lpvflow.basis import Basis
from lpvflow.models import LPVSS


def _euler(Ac: np.ndarray, Bc: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Basis components of A = I + Ts A_c(ψ), B = Ts B_c(ψ) (A_c, B_c given per basis term)."""
    A = Ts * Ac
    A[0] += np.eye(Ac.shape[1])
    return A, Ts * Bc


def maglev_like() -> tuple[LPVSS, dict]:
    """Two-disk maglev-like plant: 4 states, 2 currents, 2 positions, ψ(y2) = [1, y2, y2²], |y2| ≤ 1."""
    Ts = 0.002
    Ac = np.zeros((3, 4, 4))
    Ac[0] = [[0, 1, 0, 0], [-400, -8, 60, 0], [0, 0, 0, 1], [80, 0, -900, -12]]
    Ac[1, 3, 2] = 150.0   # local stiffness of the upper disk changes with its position …
    Ac[2, 3, 2] = -200.0  # … quadratically
    Bc = np.zeros((3, 4, 2))
    Bc[0, 1, 0], Bc[0, 3, 1], Bc[0, 3, 0] = 300.0, 500.0, -40.0
    Bc[1, 3, 1] = 120.0
    Bc[2, 3, 1] = 60.0
    A, B = _euler(Ac, Bc, Ts)
    C = np.zeros((3, 2, 4))
    C[0, 0, 0] = C[0, 1, 2] = 1.0
    basis = Basis("poly", 1, degree=2, p_min=(-1.0,), p_max=(1.0,))
    model = LPVSS(A, B, C, np.zeros((3, 2, 2)), basis, Ts, u_names=["i1", "i2"], y_names=["y1", "y2"],
                  p_names=["y2"])
    weights = {
        "S": [{"num": [0.02, 0.02], "den": [1, -1]}, {"num": [0.2, 0.2], "den": [1, -1]}],
        "K": [{"num": [9.901e-5, 0], "den": [1, 0.9802]}, {"num": [9.901e-4, 0], "den": [1, 0.9802]}],
        "B": {"num": [0.9901, 0.9901], "den": [1, 0.9802, 0]},
    }
    return model, weights


def adip_like(Ts: float = 0.02) -> tuple[LPVSS, dict]:
    """Double-inverted-pendulum-like plant: 4 states, 1 torque, 2 angles, θ = sin φ1 ∈ [−0.96, 0.96].

    Ts defaults to 20 ms, not the thesis' 5 ms: at 5 ms the Euler model's poles crowd z = 1 and
    Clarabel stops with a numerical error on the output-feedback LMIs.
    """
    Ac = np.zeros((2, 4, 4))
    Ac[0] = [[0, 1, 0, 0], [-30, -2, 12, 0], [0, 0, 0, 1], [25, 0, 20, -1]]  # unstable: φ2 falls
    Ac[1, 3, 0] = 8.0
    Ac[1, 3, 2] = -6.0
    Bc = np.zeros((2, 4, 1))
    Bc[0, 1, 0], Bc[0, 3, 0] = 40.0, -25.0
    Bc[1, 3, 0] = 6.0
    A, B = _euler(Ac, Bc, Ts)
    C = np.zeros((2, 2, 4))
    C[0, 0, 0] = C[0, 1, 2] = 1.0
    basis = Basis("affine", 1, p_min=(-0.96,), p_max=(0.96,))
    model = LPVSS(A, B, C, np.zeros((2, 2, 1)), basis, Ts, u_names=["u"], y_names=["phi1", "phi2"],
                  p_names=["sin_phi1"])
    weights = {
        "S": [{"num": [0.0125, 0.0125], "den": [1, -0.99]}, {"num": [0.05553, 0.05553], "den": [1, -0.9]}],
        "K": {"num": [0.1013, 0.09867], "den": [1, 1]},
        "B": {"num": [0, 0.3], "den": [1, -0.7]},
    }
    return model, weights


def random_lpv(seed: int, nx: int = 3, n_p: int = 1, nu: int = 1, ny: int = 1) -> LPVSS:
    """A random stable-at-the-centre affine LPVSS with constant C, D = 0 (for random-polytope tests)."""
    rng = np.random.default_rng(seed)
    A = 0.3 * rng.standard_normal((1 + n_p, nx, nx)) / np.sqrt(nx)
    A[0] += np.diag(rng.uniform(0.5, 1.02, nx))
    B = rng.standard_normal((1 + n_p, nx, nu))
    B[1:] *= 0.3
    C = np.zeros((1 + n_p, ny, nx))
    C[0] = rng.standard_normal((ny, nx))
    basis = Basis("affine", n_p, p_min=(-1.0,) * n_p, p_max=(1.0,) * n_p)
    return LPVSS(A, B, C, np.zeros((1 + n_p, ny, nu)), basis, 0.01)
