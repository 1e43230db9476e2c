"""Signal scaling for the frozen ν-gap and b(P, K): D_y⁻¹ G D_u, D_u⁻¹ K D_y."""

import control
import numpy as np

from lpvflow.validate.margins import stability_margin
from lpvflow.validate.scaling import SignalScaling
from tests.lti_helpers import random_ss


def test_scaled_plant_is_dy_inverse_g_du_and_the_loop_keeps_its_poles():
    rng = np.random.default_rng(0)
    G = random_ss(rng, 3, 2, 1, 0.1)
    K = control.ss([[0.5]], [[0.1, -0.2]], [[0.3]], [[-0.05, 0.02]], 0.1)  # u = −K y (margins.py)
    scaling = SignalScaling(np.array([4.0]), np.array([0.01, 2.0]))
    Gs, Ks = scaling.plant(G), scaling.controller(K)
    for z in np.exp(1j * np.array([0.1, 1.0, 2.5])):
        expected = np.diag([100.0, 0.5]) @ G(z) @ np.diag([4.0])
        assert np.allclose(Gs(z), expected, rtol=1e-12)
    poles = [np.sort_complex(control.feedback(P, C).poles()) for P, C in ((G, K), (Gs, Ks))]
    assert np.allclose(poles[0], poles[1], atol=1e-10)
    # b(P, K) is unit dependent: a 100× rescaled output changes it
    assert abs(stability_margin(Gs, Ks) - stability_margin(G, K)) > 1e-3


def test_disabled_scaling_is_the_identity():
    rng = np.random.default_rng(1)
    G = random_ss(rng, 2, 1, 1, 0.1)
    scaling = SignalScaling(np.array([3.0]), np.array([5.0]), enabled=False)
    assert scaling.plant(G) is G and scaling.controller(None) is None
