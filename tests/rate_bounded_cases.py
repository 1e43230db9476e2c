"""Random one-signal LPV mixed-sensitivity plants for the rate-bounded synthesis tests and benchmark.

Plant part: ``states``/2 modes of ẍ = −2ζω(p)ẋ − ω(p)²x with ω 0.5–10 rad/s and ζ 0.02–0.5 (log-uniform;
stable, down to lightly damped), ω(p)² varying by up to ±30 % over p ∈ [−1, 1], the modes coupled
through a random input vector B(p) = B₀ + pB₁ and output row C (constant); the frozen plant at each
breakpoint is sampled by zero-order hold at Ts. Weights as a robust-control engineer sets them, in
continuous time and sampled at Ts so that the design means the same at every Ts: W_S the first-order
weight of bandwidth 1 rad/s with integral action (pole moved to z = 1 − 0.01·Ts·1 rad/s), high-frequency
gain 2; W_K = 0.05; W_B = a strictly proper first-order actuator lag of 20 rad/s (ZOH), which keeps B2
constant across the breakpoints. The design plant is the piecewise-linear interpolation of these vertex
plants between the breakpoints. A draw whose DC gain comes within 10 % of zero somewhere in the range
(where no controller keeps integral action) is redrawn.
"""

from __future__ import annotations

import control
import numpy as np
import scipy.linalg

from lpvflow.synth.plant import VertexPlant, augment, weight_systems

#: Actuator-lag bandwidth of W_B, rad/s.
ACTUATOR_BANDWIDTH = 20.0


def weights(Ts: float) -> dict:
    """The mixed-sensitivity weights of the module docstring at the sampling time Ts."""
    a = float(np.exp(-ACTUATOR_BANDWIDTH * Ts))
    return {"S": {"bandwidth": 1.0, "hf_gain": 2.0}, "K": {"num": [0.05], "den": [1]},
            "B": {"num": [0, 1 - a], "den": [1, -a]}, "integrator_shift": 1e-2 * Ts}


def _continuous(rng: np.random.Generator, states: int):
    """One draw of the plant family of the module docstring: p ↦ the continuous frozen plant."""
    modes = states // 2
    omega = np.exp(rng.uniform(np.log(0.5), np.log(10.0), modes))
    zeta = np.exp(rng.uniform(np.log(0.02), np.log(0.5), modes))
    spread = rng.uniform(-0.3, 0.3, modes)
    B0, B1 = rng.standard_normal((states, 1)), 0.3 * rng.standard_normal((states, 1))
    C = rng.standard_normal((1, states))

    def at(p: float) -> control.StateSpace:
        A = scipy.linalg.block_diag(*(np.array([[0.0, 1.0], [-(w * w) * (1 + s * p), -2 * z * w]])
                                      for w, z, s in zip(omega, zeta, spread, strict=True)))
        return control.ss(A, B0 + p * B1, C, 0.0)

    return at


def random_scheduled_plant(seed: int, states: int, breakpoints: int, Ts: float
                           ) -> tuple[list[VertexPlant], np.ndarray]:
    """(vertex generalized plants, breakpoints on [−1, 1]) of the module docstring; ``states`` even."""
    rng = np.random.default_rng(seed)
    while True:
        continuous = _continuous(rng, states)
        dc = np.array([float(np.real(continuous(p)(0.0))) for p in np.linspace(-1.0, 1.0, 41)])
        if np.all(dc * np.sign(dc[0]) > 0.1 * np.max(np.abs(dc))):
            break  # else redraw: the DC gain nears zero inside the range, where integral action is lost
    W = weight_systems(weights(Ts), 1, 1, Ts)
    b = np.linspace(-1.0, 1.0, breakpoints)
    vertices = [VertexPlant.from_ss(augment(control.c2d(continuous(p), Ts, method="zoh"), W, Ts), nw=1, nz=2)
                for p in b]
    return vertices, b
