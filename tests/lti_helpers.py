"""Small LTI test fixtures shared by the ν-gap and margin tests."""

import control as ct
import numpy as np


def gain(k, dt=0):
    return ct.ss([], [], [], np.atleast_2d(k), dt)


def random_ss(rng, n, p, m, dt=0, spread=(0.2, 0.9)):
    """Seeded random minimal system; stable with spectral radius (abscissa) drawn from `spread`."""
    A = rng.standard_normal((n, n))
    eig = np.linalg.eigvals(A)
    if dt:
        A = A * rng.uniform(*spread) / np.max(np.abs(eig))
    else:
        A = A - (np.max(eig.real) + rng.uniform(*spread)) * np.eye(n)
    return ct.ss(A, rng.standard_normal((n, m)), rng.standard_normal((p, n)), rng.standard_normal((p, m)), dt)
