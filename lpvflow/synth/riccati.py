"""LMI-free reference for one generalized plant: SLICOT's discrete H∞ Riccati synthesis (SB10DD).

:func:`riccati_gamma` bisects on γ with :func:`riccati_controller`, accepting a level only when SB10DD
returns a controller whose closed loop, rebuilt and measured independently (``StateSpace.lft``,
:func:`lpvflow.validate.norms.hinf_norm`), is stable with ‖T_zw‖∞ ≤ γ. It is the optimum the LMI synthesis
must reach at one vertex, and a lower bound for every polytope containing that plant. SB10DD assumes
(A, B2) stabilizable, (C2, A) detectable, D12 full column rank, D21 full row rank and no invariant zeros
of the P12, P21 blocks on the unit circle (SLICOT documentation of SB10DD).
"""

from __future__ import annotations

import control
import numpy as np
import slycot

from lpvflow.errors import ModelError
from lpvflow.synth.plant import VertexPlant
from lpvflow.validate.norms import hinf_norm


def riccati_controller(vertex: VertexPlant, Ts: float, gamma: float) -> tuple[np.ndarray, ...] | None:
    """(Ak, Bk, Ck, Dk) from y to u of SLICOT SB10DD (slycot; the discrete-time H∞ controller formulae
    from two Riccati equations) for ``vertex`` at level γ, if its closed loop is stable with
    ‖T_zw‖∞ ≤ γ (``StateSpace.lft``, :func:`hinf_norm`, relative slack 1e-3); None otherwise."""
    n, nw, nu, nz, ny = vertex.dims
    B, C = np.hstack([vertex.B1, vertex.B2]), np.vstack([vertex.C1, vertex.C2])
    D = np.block([[vertex.D11, vertex.D12], [vertex.D21, vertex.D22]])
    try:
        K = tuple(np.asarray(m) for m in slycot.sb10dd(n, nw + nu, nz + ny, nu, ny, gamma,
                                                        A=vertex.A, B=B, C=C, D=D)[1:5])
    except slycot.exceptions.SlycotError:
        return None
    loop = vertex.ss(Ts).lft(control.ss(*K, Ts), nu, ny)
    return K if hinf_norm(loop) <= gamma * (1 + 1e-3) else None


#: The largest γ :func:`riccati_gamma` tries before it says SB10DD finds no controller.
RICCATI_GAMMA_LIMIT = 1e6


def riccati_gamma(vertex: VertexPlant, Ts: float, rel: float = 1e-4) -> float:
    """Smallest γ (to relative width ``rel``) at which :func:`riccati_controller` returns a controller:
    the frozen optimum the LMI synthesis should reach at one vertex, found without any LMI.

    The bracket is found first: from γ = 1, doubled until achieved or halved until not achieved (within
    [1e-6, 1e6]); then geometric bisection.

    Raises:
        ModelError: no γ up to 1e6 is achieved.
    """
    def achieved(gamma: float) -> bool:
        return riccati_controller(vertex, Ts, gamma) is not None

    lo = hi = 1.0
    if achieved(hi):
        while lo > 1e-6 and achieved(lo):
            hi, lo = lo, lo / 2.0
    else:
        while not achieved(hi):
            if hi >= RICCATI_GAMMA_LIMIT:
                raise ModelError(f"SB10DD finds no controller with γ ≤ {RICCATI_GAMMA_LIMIT:g} for this "
                                 "vertex")
            lo, hi = hi, hi * 2.0
    while hi / lo > 1 + rel:
        mid = (lo * hi) ** 0.5
        lo, hi = (lo, mid) if achieved(mid) else (mid, hi)
    return hi


def riccati_witness(vertex: VertexPlant, Ts: float) -> float:
    """:func:`riccati_gamma` to 0.1 %, or inf where SB10DD reaches no γ ≤ 1e6: the independent optimum a
    failed LMI synthesis is judged by (at or below the level asked for, the LMI failure was the solver's;
    above it, no controller of any kind reaches that level for this plant)."""
    try:
        return riccati_gamma(vertex, Ts, rel=1e-3)
    except ModelError:
        return float("inf")


def riccati_judgement(optimum: float, gamma: float) -> tuple[str, str]:
    """What SB10DD's optimum (:func:`riccati_witness`) says of an LMI synthesis that failed at level γ for
    one plant: (the phrase for the error line, its category). The LMIs are exact for one plant (Gahinet &
    Apkarian 1994), so where SB10DD reaches γ the failure was the solver's round-off (``"accuracy"``);
    where it does not, no controller of any kind reaches γ (``"infeasible"``). Callers add the remedy."""
    if optimum <= gamma:
        return f"SLICOT SB10DD reaches γ = {optimum:.4g}, so the LMI solve failed numerically", "accuracy"
    if np.isfinite(optimum):
        return (f"SLICOT SB10DD finds no controller with γ ≤ {gamma:.4g} either (its optimum is "
                f"{optimum:.4g})"), "infeasible"
    return f"SLICOT SB10DD finds no controller with γ ≤ {RICCATI_GAMMA_LIMIT:g} either", "infeasible"
