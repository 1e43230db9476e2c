"""Random weighted generalized plants for the H∞ synthesis tests, drawn with a fixed seed.

Each case is a mixed-sensitivity problem as a robust-control engineer poses it (python-control's ``augw``):
a SISO or 2×2 continuous plant of one of the kinds below, sampled by zero-order hold at Ts ∈ [1 ms, 50 ms]
(log-uniform), an integral-like performance weight on S with DC gain 10–1000, a control weight (constant
or high-pass), optionally a weight on T, and the measured output and control input scaled by random
factors (non-standard D12, D21). Frequencies are relative to a bandwidth ω_b drawn so that ω_b·Ts spans
1e-3…0.3 (a bandwidth between Nyquist/3000 and Nyquist/10): poles near z = 1 at millisecond sampling —
the integral weight's at 1 − ω_b·Ts/1000, down to 1 − 1e-6 — are the hard cases the synthesis must survive.

Plant kinds: ``stable`` (real poles), ``unstable`` (one real pole in the right half plane),
``lightly_damped`` (two modes with ζ = 0.005–0.05), ``nonminimum_phase`` (a real zero in the right half
plane near the bandwidth), ``near_integrator`` (a pole at −1e-3·ω_b), ``coupled`` (2×2, two masses coupled
by a spring), ``chain`` (a mass–spring chain of 3–5 masses, force on the first, position of the last).
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np
import scipy.linalg

KINDS = ("stable", "unstable", "lightly_damped", "nonminimum_phase", "near_integrator", "coupled", "chain")


@dataclass
class WeightedCase:
    """One drawn case: the discrete generalized plant (inputs [w, u], outputs [z, y]) and its partition."""

    P: control.StateSpace
    nmeas: int
    ncon: int
    label: str
    plant_states: int = 0


def _continuous_plant(rng: np.random.Generator, kind: str, wb: float) -> control.StateSpace:
    s = control.tf("s")
    if kind == "stable":
        poles = wb * 10 ** rng.uniform(-1, 1, size=rng.integers(1, 4))
        G = control.tf([float(np.prod(poles))], [1.0])
        for p in poles:
            G = G / (s + p)
    elif kind == "unstable":
        a, b = wb * 10 ** rng.uniform(-1, -0.3), wb * 10 ** rng.uniform(0, 1)
        G = a * b / ((s - a) * (s + b))
    elif kind == "lightly_damped":
        G = control.tf([1.0], [1.0])
        for _ in range(2):
            w, z = wb * 10 ** rng.uniform(-0.5, 1), rng.uniform(0.005, 0.05)
            G = G * w**2 / (s**2 + 2 * z * w * s + w**2)
    elif kind == "nonminimum_phase":
        z0, p1 = wb * 10 ** rng.uniform(0.2, 0.7), wb * 10 ** rng.uniform(-1, 0)
        p2 = wb * 10 ** rng.uniform(0, 1)
        G = p1 * p2 / z0 * (z0 - s) / ((s + p1) * (s + p2))
    elif kind == "near_integrator":
        p = wb * 10 ** rng.uniform(0, 1)
        G = p * wb / ((s + 1e-3 * wb) * (s + p))
    elif kind == "coupled":
        k, c = wb**2 * 10 ** rng.uniform(-0.5, 0.5), wb * rng.uniform(0.02, 0.3)
        A = np.array([[0, 1, 0, 0], [-2 * k, -c, k, 0], [0, 0, 0, 1], [k, 0, -2 * k, -c]], dtype=float)
        B = np.array([[0, 0], [1, 0], [0, 0], [0, 1]], dtype=float) * wb
        return control.ss(A, B, np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), np.zeros((2, 2)))
    elif kind == "chain":
        m = int(rng.integers(3, 6))
        k, c = wb**2 * 10 ** rng.uniform(0, 1), wb * rng.uniform(0.01, 0.1)
        K = k * (2 * np.eye(m) - np.eye(m, k=1) - np.eye(m, k=-1))
        K[-1, -1] = k
        A = np.block([[np.zeros((m, m)), np.eye(m)], [-K - 0.05 * k * np.eye(m), -c * np.eye(m)]])
        B = np.zeros((2 * m, 1))
        B[m, 0] = k
        C = np.zeros((1, 2 * m))
        C[0, m - 1] = 1.0
        return control.ss(A, B, C, np.zeros((1, 1)))
    else:
        raise ValueError(kind)
    return control.ss(G)


def _diag(systems: list[control.StateSpace]) -> control.StateSpace:
    return control.append(*systems) if len(systems) > 1 else systems[0]


def weighted_case(rng: np.random.Generator, kind: str | None = None) -> WeightedCase:
    """Draw one mixed-sensitivity case (module docstring)."""
    kind = kind or str(rng.choice(KINDS))
    Ts = float(10 ** rng.uniform(-3, np.log10(0.05)))
    wb = float(10 ** rng.uniform(np.log10(1e-3 / Ts), np.log10(0.3 / Ts)))
    G = _continuous_plant(rng, kind, wb)
    ny, nu = G.noutputs, G.ninputs
    s = control.tf("s")
    dc = float(10 ** rng.uniform(1, 3))
    W1 = _diag([control.ss((s / 2 + wb) / (s + wb / dc))] * ny)
    c = float(10 ** rng.uniform(-2, 0))
    if rng.uniform() < 0.5:
        W2 = _diag([control.ss(control.tf([c], [1.0]))] * nu)
    else:
        W2 = _diag([control.ss(c * (s + wb) / (0.01 * s + 10 * wb))] * nu)
    W3 = _diag([control.ss(0.5 * (s + wb) / (0.05 * s + 5 * wb))] * ny) if rng.uniform() < 0.3 else None
    Gd = control.c2d(G, Ts, "zoh")
    W = [None if w is None else control.c2d(w, Ts, "tustin") for w in (W1, W2, W3)]
    P = control.augw(Gd, *W)
    # non-standard D12 and D21: the control input and the measured output in other units
    su, sy = 10 ** rng.uniform(-1, 1, size=nu), 10 ** rng.uniform(-1, 1, size=ny)
    B, C = np.array(P.B, dtype=float), np.array(P.C, dtype=float)
    D = np.array(P.D, dtype=float)
    B[:, -nu:] *= su
    D[:, -nu:] *= su
    C[-ny:, :] *= sy[:, None]
    D[-ny:, :] *= sy[:, None]
    P = control.ss(P.A, B, C, D, Ts)
    label = f"{kind}, {ny}x{nu}, Ts = {Ts * 1e3:.3g} ms, wb·Ts = {wb * Ts:.2g}, DC weight {dc:.0f}"
    return WeightedCase(P, ny, nu, label, Gd.nstates)


def weighted_cases(count: int, seed: int) -> list[WeightedCase]:
    """``count`` cases, the kinds in turn (every kind equally often), from one seeded generator."""
    rng = np.random.default_rng(seed)
    return [weighted_case(rng, KINDS[i % len(KINDS)]) for i in range(count)]


def polytopic_case(rng: np.random.Generator) -> tuple[list[control.StateSpace], int, int, str]:
    """A 2–4-vertex family: a drawn SISO case (Ts ≥ 10 ms) whose plant dynamics A_c = logm(A_G)/Ts are moved
    at each vertex by a random perturbation of 2–15 % of ‖A_c‖ and sampled again, A_G,i = expm(A_c,i Ts)
    (a fraction of ‖A_G‖ itself would move poles near z = 1 far outside the circle). The input matrix is
    the nominal one at every vertex, so B2, C2, D12, D21 stay constant and D22 = 0, as the polytopic
    design needs."""
    while True:
        kind = str(rng.choice(("stable", "unstable", "nonminimum_phase", "near_integrator")))
        case = weighted_case(rng, kind)
        if case.P.dt >= 0.01 and np.allclose(np.asarray(case.P.D)[-case.nmeas:, -case.ncon:], 0):
            break
    count, size = int(rng.integers(2, 5)), float(rng.uniform(0.02, 0.15))
    A, nG, Ts = np.asarray(case.P.A, dtype=float), case.plant_states, case.P.dt
    Ac = np.real(scipy.linalg.logm(A[-nG:, -nG:])) / Ts  # augw puts the plant's states last
    vertices = []
    for _ in range(count):
        delta = rng.standard_normal((nG, nG))
        Ai = A.copy()
        moved = Ac + size * np.linalg.norm(Ac, 2) * delta / np.linalg.norm(delta, 2)
        Ai[-nG:, -nG:] = scipy.linalg.expm(moved * Ts)
        vertices.append(control.ss(Ai, case.P.B, case.P.C, case.P.D, Ts))
    return vertices, case.nmeas, case.ncon, f"{count} vertices ±{100 * size:.0f} %, {case.label}"
