"""lpvflow.validate.norms.hinf_norm: finite where python-control's norm gives ∞ for a stable loop sampled at
1 ms, checked against a dense frequency grid that reaches the loop's slowest pole."""

import control
import numpy as np
import pytest

from lpvflow.validate.norms import hinf_norm, is_stable
from tests.lti_helpers import random_ss


def _grid_norm(sys: control.StateSpace) -> float:
    """max σ over 20 000 log-spaced frequencies from 1e-9 rad/sample to π (independent of SLICOT)."""
    w = np.concatenate([np.logspace(-9, np.log10(np.pi), 20000), [np.pi]])
    resp = sys.frequency_response(w / sys.dt)
    return float(np.max([np.linalg.svd(resp.fresp[:, :, k], compute_uv=False)[0] for k in range(len(w))]))


def test_a_stable_system_with_a_pole_near_one_gets_a_finite_norm_equal_to_the_grid_maximum():
    """Ten seeded systems with one pole at 1 − ε, ε ∈ [1e-7, 5e-6] (an integral weight at 1 ms sampling):
    control.norm says ∞, hinf_norm agrees with the grid within 0.5 %."""
    import warnings

    import scipy.linalg

    rng = np.random.default_rng(8)
    for _ in range(10):
        fast = random_ss(rng, 3, 2, 2, dt=0.001, spread=(0.3, 0.9))
        eps = 10 ** rng.uniform(-7, np.log10(5e-6))
        A = scipy.linalg.block_diag(fast.A, [[1.0 - eps]])
        B = np.vstack([fast.B, rng.standard_normal((1, 2)) * eps * 10])
        C = np.hstack([fast.C, rng.standard_normal((2, 1))])
        sys = control.ss(A, B, C, fast.D, 0.001)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert np.isinf(control.norm(sys, "inf"))
        assert is_stable(sys)
        assert hinf_norm(sys) == pytest.approx(_grid_norm(sys), rel=5e-3)


def test_unstable_is_infinite_and_ordinary_systems_match_python_control():
    rng = np.random.default_rng(5)
    for _ in range(10):
        sys = random_ss(rng, 4, 2, 2, dt=0.01)
        assert hinf_norm(sys) == pytest.approx(float(control.norm(sys, "inf")), rel=1e-6)
    unstable = control.ss([[1.01]], [[1.0]], [[1.0]], [[0.0]], 0.01)
    assert hinf_norm(unstable) == np.inf
