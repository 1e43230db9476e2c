"""A small affine LPV plant shared by the synthesis tests (two states, one input, one output, p ∈ [−1, 1])."""

import numpy as np

from lpvflow.basis import Basis
from lpvflow.models import LPVSS


def two_state_plant() -> LPVSS:
    """x⁺ = (A0 + p A1) x + (B0 + p B1) u, y = x₁: stable for every p in [−1, 1], B depends on p."""
    basis = Basis("affine", 1, p_min=(-1.0,), p_max=(1.0,))
    A = np.array([[[0.9, 0.1], [0.0, 0.8]], [[0.05, 0.0], [0.0, 0.02]]])
    B = np.array([[[0.0], [1.0]], [[0.0], [0.3]]])
    C = np.array([[[1.0, 0.0]], [[0.0, 0.0]]])
    return LPVSS(A, B, C, np.zeros((2, 1, 1)), basis, 0.01)
