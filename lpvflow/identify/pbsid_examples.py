"""Test systems of van Wingerden & Verhaegen (2009) Sec. 7: the Verdult–Verhaegen 4th-order MIMO LPV
benchmark (Sec. 7.1).

The paper prints no matrices or signals; they are those of the PBSID toolbox example
``ex20_lpv_mimo.m`` (I. Houtzager, PBSID toolbox v0.6; not from the paper): n = 4, m = 4, r = 2, ℓ = 3,

    μ_k = [1, ρ_k, 0.5 sin(2πk/100) ρ_k, 0.5 cos(2πk/100) ρ_k],   ρ_k ~ U(0, 1) i.i.d.,
    u_k = [filter([0.75 1.05 0.15], 1, η) + filter(butter(2, 0.2), ν);  ξ],   η, ν, ξ ~ N(0, 1),

with innovation e_k white. Scheduling signals here are p_k = μ_k^(2:4) with the affine basis.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from lpvflow.basis import Basis
from lpvflow.data import Dataset
from lpvflow.models import LPVSS

_COMPANION = np.array([[0.0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])


def verdult_benchmark() -> LPVSS:
    """The benchmark system as an affine LPVSS in p = μ^(2:4) (innovation form with K)."""
    A = np.zeros((4, 4, 4))
    A[0] = _COMPANION.copy()
    A[0, 0] = [-1.3, -0.6325, -0.1115, 0.0596]
    A[1] = _COMPANION.copy()
    A[1, 0] = [-0.51, -0.1075, -0.007275, -0.0000625]
    A[2] = np.diag([0.2, 0.4, 0.0, 0.0])
    A[3] = np.diag([0.0, 0.0, 0.3, 0.3])
    B = np.zeros((4, 4, 2))
    B[0] = [[0, 1], [1, 0], [1, 0], [0, 1]]
    B[1:, 3] = 0.3
    K = np.zeros((4, 4, 3))
    K[0] = [[0.16, 0, 0], [0, 0.16, 0], [0, 0, 0.16], [0.16, 0, 0]]
    C = np.zeros((4, 3, 4))
    C[0] = np.eye(3, 4)
    D = np.zeros((4, 3, 2))
    return LPVSS(A, B, C, D, Basis.affine(3), 1.0, K=K)


def verdult_signals(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Input u (n, 2) and scheduling p (n, 3) of one benchmark experiment."""
    rho = rng.uniform(0.0, 1.0, n)
    k = np.arange(n)
    phase = 2 * np.pi * k / 100
    p = np.column_stack([rho, 0.5 * np.sin(phase) * rho, 0.5 * np.cos(phase) * rho])
    b, a = scipy.signal.butter(2, 0.2)
    u1 = scipy.signal.lfilter([0.75, 1.05, 0.15], 1.0, rng.normal(size=n)) + scipy.signal.lfilter(
        b, a, rng.normal(size=n))
    return np.column_stack([u1, rng.normal(size=n)]), p


def verdult_experiment(
    n: int, rng: np.random.Generator, snr_db: float = np.inf,
) -> tuple[Dataset, np.ndarray]:
    """One identification dataset and its noise-free output.

    The innovation e = σ·N(0, I) enters through K and at the output; σ is set per experiment so
    that 10 log10(Σ var(y_det) / Σ var(y − y_det)) = snr_db (the paper does not define its SNR).
    """
    system = verdult_benchmark()
    u, p = verdult_signals(n, rng)
    y_det = system.simulate(u, p)
    if np.isinf(snr_db):
        return Dataset(u, y_det, p, 1.0), y_det
    e = rng.normal(size=(n, 3))
    noise = system.simulate(np.zeros_like(u), p, e=e)
    sigma = np.sqrt(np.var(y_det, axis=0).sum() / np.var(noise, axis=0).sum() / 10 ** (snr_db / 10))
    return Dataset(u, y_det + sigma * noise, p, 1.0), y_det
