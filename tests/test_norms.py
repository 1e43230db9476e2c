"""lpvflow.validate.norms.hinf_norm: finite where python-control's norm gives ∞ for a stable loop sampled at
1 ms, checked against a dense frequency grid that reaches the loop's slowest pole."""

import control
import numpy as np
import pytest

from lpvflow.validate.norms import hinf_norm, is_stable
from tests.hinf_cases import weighted_cases
from tests.lti_helpers import random_ss


def _grid_norm(sys: control.StateSpace) -> float:
    """max σ over 20 000 log-spaced frequencies from 1e-9 rad/sample to π (independent of SLICOT)."""
    w = np.concatenate([np.logspace(-9, np.log10(np.pi), 20000), [np.pi]])
    resp = sys.frequency_response(w / sys.dt)
    return float(np.max([np.linalg.svd(resp.fresp[:, :, k], compute_uv=False)[0] for k in range(len(w))]))


def test_a_stable_loop_with_a_pole_near_one_gets_a_finite_norm_equal_to_the_grid_maximum():
    """The weighted 1 ms-class plants of the synthesis tests, closed by a stabilizing SB10DD controller,
    have poles within 1e-5 of z = 1: control.norm says ∞, hinf_norm agrees with the grid within 0.5 %."""
    import warnings

    from lpvflow.synth.plant import VertexPlant
    from lpvflow.synth.riccati import riccati_controller, riccati_gamma

    checked = 0
    for case in weighted_cases(14, 2026):
        v = VertexPlant.from_ss(case.P, case.P.ninputs - case.ncon, case.P.noutputs - case.nmeas)
        K = riccati_controller(v, case.P.dt, 1.2 * riccati_gamma(v, case.P.dt))
        loop = case.P.lft(control.ss(*K, case.P.dt), case.ncon, case.nmeas)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if np.isfinite(control.norm(loop, "inf")):
                continue
        checked += 1
        assert is_stable(loop)
        assert hinf_norm(loop) == pytest.approx(_grid_norm(loop), rel=5e-3)
    assert checked >= 3  # the property is exercised, not skipped


def test_unstable_is_infinite_and_ordinary_systems_match_python_control():
    rng = np.random.default_rng(5)
    for _ in range(10):
        sys = random_ss(rng, 4, 2, 2, dt=0.01)
        assert hinf_norm(sys) == pytest.approx(float(control.norm(sys, "inf")), rel=1e-6)
    unstable = control.ss([[1.01]], [[1.0]], [[1.0]], [[0.0]], 0.01)
    assert hinf_norm(unstable) == np.inf
