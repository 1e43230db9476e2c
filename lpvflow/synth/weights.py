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

The table is parsed once (:meth:`Weights.parse`, when the design file is read) into a :class:`Weights` of
typed channel specs that does not depend on Ts; :meth:`Weights.discretize` turns it into the
:data:`WeightSystems` at the plant's Ts, once, where the generalized plant is built
(:func:`lpvflow.synth.plant.generalized_plant`), and every later step reads those systems.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import control
import numpy as np

from lpvflow.errors import ModelError

DEFAULT_INTEGRATOR_SHIFT = 1e-3


@dataclass(frozen=True)
class ZWeight:
    """W(z) = num(z)/den(z), coefficients in descending powers of z (the plant's Ts is implied)."""

    num: tuple[float, ...]
    den: tuple[float, ...]

    def coefficients(self, Ts: float, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) in z."""
        return np.asarray(self.num, dtype=float), np.asarray(self.den, dtype=float)


@dataclass(frozen=True)
class BandwidthWeight:
    """W(s) = (s/M + ωB)/(s + ωB A) (Skogestad & Postlethwaite 2005, eq. 2.105): ``bandwidth`` ωB [rad/s],
    ``hf_gain`` 1/M, ``dc_gain`` 1/A (None: A = 0, integral action)."""

    bandwidth: float
    hf_gain: float = 0.0
    dc_gain: float | None = None

    def coefficients(self, Ts: float, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) in z of the bilinear (Tustin) image at Ts; ωB must lie below the Nyquist π/Ts."""
        wb, a = self.bandwidth, 1.0 / self.dc_gain if self.dc_gain is not None else 0.0
        if wb * Ts >= np.pi:
            raise ModelError(f"weight {name}: bandwidth {wb} rad/s must be in (0, π/Ts = {np.pi / Ts:.4g})")
        tf_d = control.sample_system(control.tf([self.hf_gain, wb], [1.0, wb * a]), Ts, method="bilinear")
        return np.asarray(tf_d.num[0][0], float), np.asarray(tf_d.den[0][0], float)


#: One channel's weight.
ChannelWeight = ZWeight | BandwidthWeight
#: A weight: one channel spec used for every channel, or one per channel.
Weight = ChannelWeight | tuple[ChannelWeight, ...]
#: The discrete diagonal weights at the plant's Ts, by letter (S, K and those of B, T, R, N given).
WeightSystems = dict[str, control.StateSpace]
#: Which loop signal each weight acts on: "y" (one channel per output) or "u" (one per input).
CHANNELS = {"S": "y", "K": "u", "B": "u", "T": "y", "R": "y", "N": "y"}


def _shift_poles(den: np.ndarray, eps: float) -> np.ndarray:
    """The denominator with every root of modulus ≥ 1 − ε moved radially to modulus 1 − ε."""
    roots = np.roots(den)
    if roots.size == 0:
        return den
    radius = np.abs(roots)
    moved = np.where(radius >= 1.0 - eps, roots / np.maximum(radius, 1e-300) * (1.0 - eps), roots)
    return np.real(np.poly(moved)) * den[0]


def channel_weight(spec: Any, name: str) -> ChannelWeight:
    """One channel's TOML table (module docstring) as a typed spec; a typed spec is returned as it is."""
    if isinstance(spec, ZWeight | BandwidthWeight):
        return spec
    if not isinstance(spec, Mapping):
        raise ModelError(f"weight {name}: expected a table {{num, den}} or {{bandwidth, ...}}, got {spec!r}")
    if "num" in spec or "den" in spec:
        try:
            num = np.atleast_1d(np.asarray(spec["num"], dtype=float))
            den = np.atleast_1d(np.asarray(spec["den"], dtype=float))
        except (KeyError, ValueError, TypeError):
            raise ModelError(f"weight {name}: give num and den as lists of numbers (powers of z)") from None
        if num.ndim != 1 or den.ndim != 1:
            raise ModelError(f"weight {name}: give num and den as lists of numbers (powers of z)")
        if den[0] == 0 or len(num) > len(den):
            raise ModelError(f"weight {name} is not proper (deg num > deg den or leading den coefficient 0)")
        if not np.all(np.isfinite(num)) or not np.all(np.isfinite(den)):
            raise ModelError(f"weight {name} has non-finite coefficients")
        return ZWeight(tuple(float(v) for v in num), tuple(float(v) for v in den))
    if "bandwidth" in spec:
        try:
            wb, inv_m = float(spec["bandwidth"]), float(spec.get("hf_gain", 0.0))
            dc = float(spec["dc_gain"]) if "dc_gain" in spec else None
        except (ValueError, TypeError):
            raise ModelError(f"weight {name}: bandwidth, dc_gain and hf_gain must be numbers") from None
        if not wb > 0:
            raise ModelError(f"weight {name}: bandwidth {wb} rad/s must be > 0")
        return BandwidthWeight(wb, inv_m, dc)
    raise ModelError(f"weight {name}: give num/den (in z) or bandwidth [, dc_gain, hf_gain]")


def weight_entries(table: Mapping[str, Any]) -> dict[str, Weight | float]:
    """The entries of a (possibly partial) weights table, typed: a weight letter to its :data:`Weight`,
    ``integrator_shift`` to a number in (0, 0.5)."""
    unknown = sorted(set(table) - set(CHANNELS) - {"integrator_shift"})
    if unknown:
        raise ModelError(f"weights have unknown key(s) {unknown}; known: {[*CHANNELS, 'integrator_shift']}")
    entries: dict[str, Weight | float] = {}
    for key, spec in table.items():
        if key == "integrator_shift":
            eps = float(spec)
            if not 0.0 < eps < 0.5:
                raise ModelError(f"integrator_shift must be in (0, 0.5), got {eps}")
            entries[key] = eps
        elif isinstance(spec, list | tuple):
            entries[key] = tuple(channel_weight(s, f"W_{key}[{i}]") for i, s in enumerate(spec))
        else:
            entries[key] = channel_weight(spec, f"W_{key}")
    return entries


@dataclass(frozen=True)
class Weights:
    """The ``[synth] weights`` table, typed and independent of Ts: W_S on the error and W_K on the control
    (required), the optional W_B (input filter), W_T (on y), W_R (reference), W_N (2-DOF measurement noise),
    and the pole shift ε of the module docstring."""

    S: Weight
    K: Weight
    B: Weight | None = None
    T: Weight | None = None
    R: Weight | None = None
    N: Weight | None = None
    integrator_shift: float = DEFAULT_INTEGRATOR_SHIFT

    @classmethod
    def parse(cls, table: Mapping[str, Any]) -> Weights:
        """The typed weights of a TOML table ``{S = …, K = …, [B, T, R, N], [integrator_shift]}``."""
        missing = [k for k in ("S", "K") if k not in table]
        if missing:
            raise ModelError(f"design spec lacks the weight(s) {missing} "
                             "(W_S on e and W_K on u are required)")
        return cls(**weight_entries(table))

    @property
    def given(self) -> tuple[str, ...]:
        """The letters of the weights given (S and K first)."""
        return tuple(k for k in CHANNELS if getattr(self, k) is not None)

    def replaced(self, entries: Mapping[str, Any]) -> Weights:
        """These weights with some entries replaced (a scheduled weight at one vertex)."""
        return dataclasses.replace(self, **weight_entries(entries))

    def discretize(self, ny: int, nu: int, Ts: float) -> WeightSystems:
        """diag(W_1, …, W_n) of every weight given as a StateSpace at Ts, poles shifted inside by ε."""
        sizes = {"y": ny, "u": nu}
        return {k: diagonal_weight(getattr(self, k), sizes[CHANNELS[k]], Ts, f"W_{k}", self.integrator_shift)
                for k in self.given}


def as_weights(weights: Weights | Mapping[str, Any]) -> Weights:
    """``weights`` if typed, else the TOML table parsed (:meth:`Weights.parse`): the entry of the library's
    public functions that take a weights table."""
    return weights if isinstance(weights, Weights) else Weights.parse(weights)


def siso_weight(spec: ChannelWeight | Mapping[str, Any], Ts: float, name: str,
                eps: float = DEFAULT_INTEGRATOR_SHIFT) -> control.TransferFunction:
    """One channel of a weight at Ts, poles shifted inside by ε (module docstring)."""
    num, den = channel_weight(spec, name).coefficients(Ts, name)
    return control.tf(num, _shift_poles(den, eps), Ts)


def diagonal_weight(weight: Weight, n: int, Ts: float, name: str, eps: float = DEFAULT_INTEGRATOR_SHIFT,
                    ) -> control.StateSpace:
    """diag(W_1, …, W_n) as a StateSpace (dt = Ts); one spec is repeated for every channel."""
    specs = list(weight) if isinstance(weight, tuple) else [weight] * n
    if len(specs) != n:
        raise ModelError(f"weight {name} has {len(specs)} channel(s) but the loop has {n}")
    blocks = [control.ss(siso_weight(s, Ts, f"{name}[{i}]", eps)) for i, s in enumerate(specs)]
    return control.append(*blocks) if len(blocks) > 1 else blocks[0]
