"""Discrete-time weighting filters of a mixed-sensitivity design (Boonto's thesis Sec. 6.2–6.3).

A weight is a diagonal of SISO filters, one per channel, each given in the design TOML either as a
transfer function in z (coefficients in descending powers of z),

    {num = [0.02, 0.02], den = [1, -1]}                          W(z) = (0.02 z + 0.02)/(z − 1),

or as a bandwidth/gain spec, the first-order weight of Skogestad & Postlethwaite (2005, eq. 2.105)

    {bandwidth = ωB [rad/s], dc_gain = 1/A, hf_gain = 1/M}      W(s) = (s/M + ωB)/(s + ωB A),

discretized by the bilinear (Tustin) map at the plant's Ts. ``dc_gain`` omitted means A = 0: integral
action, a pole at s = 0, i.e. z = 1. A single entry is used for every channel.

Poles on or outside the unit circle (integrators z = 1, the pole z = −1 of the thesis' ADIP W_K) make
the generalized plant not stabilizable, so every pole with |z| ≥ 1 − ε is moved radially to
|z| = 1 − ε (ε = ``integrator_shift``, default 1e-3; the thesis does not say what it did).
The numerator is kept, so the weight changes only near that pole: an integrator's infinite DC gain
becomes |num(1)|/ε-ish, finite but large.
"""

from __future__ import annotations

from collections.abc import Sequence

import control
import numpy as np

from lpvflow.errors import ModelError

DEFAULT_INTEGRATOR_SHIFT = 1e-3


def _shift_poles(den: np.ndarray, eps: float) -> np.ndarray:
    """The denominator with every root of modulus ≥ 1 − ε moved radially to modulus 1 − ε."""
    roots = np.roots(den)
    if roots.size == 0:
        return den
    radius = np.abs(roots)
    moved = np.where(radius >= 1.0 - eps, roots / np.maximum(radius, 1e-300) * (1.0 - eps), roots)
    return np.real(np.poly(moved)) * den[0]


def siso_weight(
    spec: dict, Ts: float, name: str, eps: float = DEFAULT_INTEGRATOR_SHIFT,
) -> control.TransferFunction:
    """One channel of a weight from its TOML table (module docstring), poles shifted inside by ε."""
    if not isinstance(spec, dict):
        raise ModelError(f"weight {name}: expected a table {{num, den}} or {{bandwidth, ...}}, got {spec!r}")
    if "num" in spec or "den" in spec:
        try:
            num = np.atleast_1d(np.asarray(spec["num"], dtype=float))
            den = np.atleast_1d(np.asarray(spec["den"], dtype=float))
        except (KeyError, ValueError, TypeError):
            raise ModelError(f"weight {name}: give num and den as lists of numbers (powers of z)") from None
        if den[0] == 0 or len(num) > len(den):
            raise ModelError(f"weight {name} is not proper (deg num > deg den or leading den coefficient 0)")
    elif "bandwidth" in spec:
        wb = float(spec["bandwidth"])
        inv_m = float(spec.get("hf_gain", 0.0))
        a = 1.0 / float(spec["dc_gain"]) if "dc_gain" in spec else 0.0
        if wb <= 0 or wb * Ts >= np.pi:
            raise ModelError(f"weight {name}: bandwidth {wb} rad/s must be in (0, π/Ts = {np.pi / Ts:.4g})")
        tf_d = control.sample_system(control.tf([inv_m, wb], [1.0, wb * a]), Ts, method="bilinear")
        num, den = np.asarray(tf_d.num[0][0], float), np.asarray(tf_d.den[0][0], float)
    else:
        raise ModelError(f"weight {name}: give num/den (in z) or bandwidth [, dc_gain, hf_gain]")
    if not np.all(np.isfinite(num)) or not np.all(np.isfinite(den)):
        raise ModelError(f"weight {name} has non-finite coefficients")
    den_shifted = _shift_poles(den, eps)
    return control.tf(num, den_shifted, Ts)


def diagonal_weight(
    spec: dict | Sequence[dict], n: int, Ts: float, name: str, eps: float = DEFAULT_INTEGRATOR_SHIFT,
) -> control.StateSpace:
    """diag(W_1, …, W_n) as a StateSpace (dt = Ts); one spec is repeated for every channel."""
    specs = [spec] * n if isinstance(spec, dict) else list(spec)
    if len(specs) != n:
        raise ModelError(f"weight {name} has {len(specs)} channel(s) but the loop has {n}")
    blocks = [control.ss(siso_weight(s, Ts, f"{name}[{i}]", eps)) for i, s in enumerate(specs)]
    return control.append(*blocks) if len(blocks) > 1 else blocks[0]
