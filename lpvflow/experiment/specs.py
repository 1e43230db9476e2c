"""Signal specifications: the text ``KIND:key=value,...`` of ``--input NAME=SPEC``, parsed and generated.

Kinds and keys (frequencies in Hz, durations in seconds, each a whole number of samples Ts):

    multisine:f_lo=F,f_hi=F,rms=A|peak=A[,period=T][,phases=schroeder|random][,offset=V]
    prbs:order=N,clock=T,amp=A[,offset=V]          levels offset ± amp
    aprbs:lo=V,hi=V,min_hold=T,max_hold=T
    levels:lo=V,hi=V,min_hold=T,max_hold=T[,ramp=T]
    const:value=V
    triangle:amp=A,period=T[,offset=V]             offset + A·tri(t/T): 0 → A → −A → 0 each period

``multisine``, ``prbs`` and ``triangle`` are centred on ``offset``; when it is not given, the caller's
operating value is used (the FMU input's start value in open loop, 0 for an excitation added to a controller
output). The other kinds give absolute values. ``period`` defaults to the whole experiment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lpvflow.errors import DataError
from lpvflow.experiment import signals

#: For each kind: required keys, optional keys. Values are floats except where noted in _TEXT_KEYS.
_KEYS: dict[str, tuple[frozenset[str], frozenset[str]]] = {
    "multisine": (frozenset({"f_lo", "f_hi"}), frozenset({"rms", "peak", "period", "phases", "offset"})),
    "prbs": (frozenset({"order", "clock", "amp"}), frozenset({"offset"})),
    "aprbs": (frozenset({"lo", "hi", "min_hold", "max_hold"}), frozenset()),
    "levels": (frozenset({"lo", "hi", "min_hold", "max_hold"}), frozenset({"ramp"})),
    "const": (frozenset({"value"}), frozenset()),
    "triangle": (frozenset({"amp", "period"}), frozenset({"offset"})),
}
_TEXT_KEYS = frozenset({"phases"})
_DURATION_KEYS = frozenset({"period", "clock", "min_hold", "max_hold", "ramp"})
CENTRED_KINDS = frozenset({"multisine", "prbs", "triangle"})


@dataclass(frozen=True)
class SignalSpec:
    """A parsed signal specification; ``text`` is the string it came from (kept for the sidecar)."""

    kind: str
    params: dict[str, float | str] = field(default_factory=dict)
    text: str = ""

    def to_dict(self) -> dict[str, object]:
        return {"text": self.text, "kind": self.kind, "params": dict(self.params)}


def parse_spec(text: str) -> SignalSpec:
    """Parse ``KIND:key=value,...`` (or a bare ``KIND`` without keys) into a :class:`SignalSpec`."""
    kind, _, body = text.strip().partition(":")
    kind = kind.strip().lower()
    if kind not in _KEYS:
        raise DataError(f"signal spec {text!r}: unknown kind {kind!r}; use one of {', '.join(_KEYS)}")
    params: dict[str, float | str] = {}
    for item in filter(None, (part.strip() for part in body.split(","))):
        key, eq, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not eq or not key or not value:
            raise DataError(f"signal spec {text!r}: {item!r} is not key=value")
        if key in params:
            raise DataError(f"signal spec {text!r}: key {key!r} given twice")
        if key in _TEXT_KEYS:
            params[key] = value
            continue
        try:
            params[key] = float(value)
        except ValueError:
            raise DataError(f"signal spec {text!r}: {key}={value!r} is not a number") from None
        if not np.isfinite(params[key]):
            raise DataError(f"signal spec {text!r}: {key}={value} must be finite")
    required, optional = _KEYS[kind]
    missing = sorted(required - params.keys())
    unknown = sorted(params.keys() - required - optional)
    if missing:
        raise DataError(f"signal spec {text!r}: {kind} needs {', '.join(missing)}")
    if unknown:
        raise DataError(
            f"signal spec {text!r}: {kind} does not take {', '.join(unknown)}; "
            f"allowed: {', '.join(sorted(required | optional))}"
        )
    return SignalSpec(kind=kind, params=params, text=text.strip())


def _samples(spec: SignalSpec, key: str, Ts: float) -> int:
    """Duration key in seconds -> whole number of samples; refuse durations that are not multiples of Ts."""
    seconds = float(spec.params[key])
    count = round(seconds / Ts)
    if count < 1 or abs(seconds / Ts - count) > 1e-6:
        raise DataError(
            f"signal spec {spec.text!r}: {key}={seconds:g} s must be a positive multiple of Ts={Ts:g} s"
        )
    return count


def generate(
    spec: SignalSpec, n: int, Ts: float, rng: np.random.Generator, offset: float = 0.0
) -> np.ndarray:
    """Samples x(0..n-1) of ``spec`` at sampling time Ts; ``offset`` centres multisine/prbs unless the
    spec gives its own ``offset``."""
    p = spec.params
    centre = float(p.get("offset", offset))
    try:
        if spec.kind == "multisine":
            period = _samples(spec, "period", Ts) if "period" in p else n
            rms = float(p["rms"]) if "rms" in p else None
            peak = float(p["peak"]) if "peak" in p else None
            phases = str(p.get("phases", "schroeder"))
            band = float(p["f_lo"]), float(p["f_hi"])
            return centre + signals.multisine(n, Ts, *band, period, rms, peak, phases, rng)
        if spec.kind == "prbs":
            order = float(p["order"])
            if order != int(order):
                raise DataError(f"order={order:g} must be an integer")
            amp = float(p["amp"])
            return signals.prbs(n, int(order), _samples(spec, "clock", Ts), centre - amp, centre + amp, rng)
        if spec.kind in ("aprbs", "levels"):
            holds = _samples(spec, "min_hold", Ts), _samples(spec, "max_hold", Ts)
            args = (n, float(p["lo"]), float(p["hi"]), *holds, rng)
            if spec.kind == "aprbs":
                return signals.aprbs(*args)
            return signals.random_levels(*args, ramp=_samples(spec, "ramp", Ts) if "ramp" in p else 0)
        if spec.kind == "triangle":
            return centre + signals.triangle(n, _samples(spec, "period", Ts), float(p["amp"]))
        return np.full(n, float(p["value"]))
    except DataError as exc:
        if spec.text and spec.text in str(exc):
            raise
        raise DataError(f"signal spec {spec.text!r}: {exc}") from None
