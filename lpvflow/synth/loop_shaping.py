"""H∞ loop shaping (McFarlane & Glover 1990) for discrete plants: the Riccati design and its LMI form.

Feedback convention u = K y (positive feedback), as :mod:`lpvflow.validate.robust_stability`, whose
b(G, K) and b_opt(G) this module's designs attain.

**Riccati (central) controller.** For the continuous bilinear image (A, B, C, D) of the plant, X, Z the
stabilizing solutions of its GCARE/GFARE (:func:`lpvflow.validate.robust_stability.ncf_riccati`) and
γ > γ_opt = (1 + λmax(XZ))^{1/2} (Zhou, Doyle & Glover, "Robust and Optimal Control", 1996, Thm. 18.3
with D ≠ 0 after Cor. 13.29; McFarlane & Glover 1990, §3.3):

    R = I + DᵀD,  F = −R⁻¹(DᵀC + BᵀX),  W = I + XZ − γ²I,  L = γ² W⁻ᵀ Z Cᵀ,
    K_c = [A + BF + L(C + DF) | L ; BᵀX | −Dᵀ],

and b(G_c, K_c) ≥ 1/γ; the discrete controller is the inverse bilinear image of K_c (the map keeps the
closed loop and ‖T‖∞, module docstring of robust_stability).
"""

from __future__ import annotations

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.validate.lti_eval import as_statespace
from lpvflow.validate.robust_stability import ncf_riccati


def riccati_controller(G: object, gamma_factor: float = 1.01) -> tuple[control.StateSpace, float]:
    """The central loop-shaping controller of the discrete plant G at γ = gamma_factor·γ_opt, and that γ.

    The returned K (u = K y, dt = G.dt) has b(G, K) ≥ 1/γ (module docstring). gamma_factor must be > 1:
    at γ_opt itself W is singular.
    """
    if not gamma_factor > 1.0:
        raise ModelError(f"gamma_factor is {gamma_factor}; it must be > 1 (the central controller at "
                         "gamma_opt itself does not exist), e.g. 1.01")
    G = as_statespace(G, "G")
    ric = ncf_riccati(G)
    A, B, C, D, X, Z = ric.A, ric.B, ric.C, ric.D, ric.X, ric.Z
    gamma = gamma_factor * ric.gamma_opt
    n = A.shape[0]
    F = -np.linalg.solve(np.eye(B.shape[1]) + D.T @ D, D.T @ C + B.T @ X)
    L = gamma**2 * np.linalg.solve((np.eye(n) + X @ Z - gamma**2 * np.eye(n)).T, Z @ C.T)
    Ak, Bk, Ck, Dk = A + B @ F + L @ (C + D @ F), L, B.T @ X, -D.T
    return control.ss(*_inverse_bilinear(Ak, Bk, Ck, Dk), G.dt), float(gamma)


def _inverse_bilinear(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, ...]:
    """The discrete system whose bilinear image (lti_eval.bilinear_to_continuous, rotation 0) is (A, B, C, D).

    z = (1 + s)/(1 − s):  A_d = (I + A)(I − A)⁻¹, B_d = √2 (I − A)⁻¹B, C_d = √2 C(I − A)⁻¹,
    D_d = D + C(I − A)⁻¹B.
    """
    M = np.linalg.inv(np.eye(A.shape[0]) - A)
    return (np.eye(A.shape[0]) + A) @ M, np.sqrt(2.0) * M @ B, np.sqrt(2.0) * C @ M, D + C @ M @ B
