"""Scheduling bases ψ(p): the functions every LPV coefficient is a linear combination of.

A coefficient matrix M(p) is stored as its basis components M_l and evaluated as
M(p) = Σ_l ψ_l(p) M_l, with ψ_0(p) = 1 always (thesis (3.3), Schulz et al. Sec. II: μ = [1 θᵀ]ᵀ).

Three families:

* ``affine``: ψ = [1, p_1, …, p_np]; the LPV state space is then affine in p and has a polytope.
* ``poly``: all monomials of total degree ≤ D in the n_p scheduling signals (with cross terms), or
  per-signal powers only (``cross=False``); thesis (2.8)/(4.4).
* ``spline``: truncated-power cubic spline per signal, ψ = [1, p, |p − η_1|³, …, |p − η_m|³]
  (thesis (3.13)–(3.14), Lancaster & Šalkauskas form); knots are shared by all coefficients.

A basis records the scheduling range seen in the identification data (``p_min``, ``p_max``) and
warns when evaluated outside it: an identified model is an extrapolation there.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from lpvflow.errors import ModelError


class SchedulingRangeWarning(UserWarning):
    """Evaluating a basis outside the scheduling range it was identified on."""


@dataclass(frozen=True)
class Basis:
    """Scheduling basis ψ(p) with ψ_0 = 1.

    Attributes:
        kind: ``"affine"``, ``"poly"`` or ``"spline"``.
        n_p: number of scheduling signals.
        degree: total polynomial degree (``poly``) or 1 (``affine``, ``spline``).
        cross: ``poly`` only: include mixed monomials p_i p_j.
        knots: ``spline`` only: one tuple of knots per scheduling signal.
        p_min, p_max: scheduling range seen in the data, or ``None`` when not recorded.
    """

    kind: str
    n_p: int
    degree: int = 1
    cross: bool = True
    knots: tuple[tuple[float, ...], ...] = ()
    p_min: tuple[float, ...] | None = None
    p_max: tuple[float, ...] | None = None
    _exponents: tuple[tuple[int, ...], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in ("affine", "poly", "spline"):
            raise ModelError(f"unknown basis kind {self.kind!r}; use affine, poly:D or spline:KNOTS")
        if self.n_p < 1:
            raise ModelError("a basis needs at least one scheduling signal")
        if self.kind == "poly" and self.degree < 1:
            raise ModelError(f"polynomial degree must be >= 1, got {self.degree}")
        if self.kind == "spline":
            if len(self.knots) != self.n_p:
                raise ModelError(f"spline basis needs one knot list per scheduling signal ({self.n_p})")
            for k in self.knots:
                if list(k) != sorted(k) or len(set(k)) != len(k):
                    raise ModelError(f"spline knots must be strictly increasing, got {list(k)}")
        object.__setattr__(self, "_exponents", self._monomial_exponents())

    # ----------------------------------------------------------------- construction helpers
    @classmethod
    def affine(cls, n_p: int = 1) -> Basis:
        return cls("affine", n_p)

    @classmethod
    def poly(cls, degree: int, n_p: int = 1, cross: bool = True) -> Basis:
        return cls("poly", n_p, degree=degree, cross=cross)

    @classmethod
    def spline(cls, knots: list[list[float]] | list[float], n_p: int | None = None) -> Basis:
        per_signal = [knots] if knots and np.isscalar(knots[0]) else knots
        per_signal = tuple(tuple(float(v) for v in k) for k in per_signal)
        return cls("spline", n_p or len(per_signal), knots=per_signal)

    @classmethod
    def from_spec(cls, spec: str, n_p: int) -> Basis:
        """Parse a CLI basis spec: ``affine``, ``poly:D``, ``poly:D:nocross``, ``spline:K1,K2[;K1,..]``."""
        head, _, rest = spec.partition(":")
        try:
            if head == "affine" and not rest:
                return cls.affine(n_p)
            if head == "poly":
                deg, _, opt = rest.partition(":")
                if opt not in ("", "nocross"):
                    raise ValueError(opt)
                return cls.poly(int(deg), n_p, cross=opt != "nocross")
            if head == "spline":
                groups = [[float(v) for v in g.split(",") if v.strip()] for g in rest.split(";")]
                if len(groups) == 1 and n_p > 1:
                    groups = groups * n_p
                return cls.spline(groups, n_p)
        except ModelError:
            raise  # a well-formed spec with a bad value (e.g. unordered knots): keep its own message
        except ValueError:
            pass  # a malformed number: the generic message below says what a spec looks like
        raise ModelError(
            f"bad basis spec {spec!r}; use affine, poly:D, poly:D:nocross or spline:K1,K2,... "
            "(one ';'-separated knot list per scheduling signal)"
        )

    def with_range(self, p: np.ndarray) -> Basis:
        """The same basis, recording the range of the scheduling data ``p`` (N, n_p)."""
        p = np.asarray(p, dtype=float).reshape(len(p), -1)
        return replace(self, p_min=tuple(p.min(axis=0).tolist()), p_max=tuple(p.max(axis=0).tolist()))

    # ----------------------------------------------------------------------------- evaluation
    def _monomial_exponents(self) -> tuple[tuple[int, ...], ...]:
        if self.kind == "affine":
            return tuple(tuple(int(i == j) for j in range(self.n_p)) for i in range(-1, self.n_p))
        if self.kind == "poly":
            exps = []
            for total in range(self.degree + 1):
                for e in sorted(itertools.product(range(total + 1), repeat=self.n_p), reverse=True):
                    if sum(e) == total and (self.cross or sum(1 for v in e if v) <= 1):
                        exps.append(tuple(e))
            return tuple(exps)
        return ()

    @property
    def exponents(self) -> tuple[tuple[int, ...], ...]:
        """Monomial exponents of ``affine``/``poly`` bases, one tuple per basis function (ψ_0: zeros)."""
        return self._exponents

    @property
    def n_psi(self) -> int:
        """Number of basis functions, including ψ_0 = 1."""
        if self.kind == "spline":
            return 1 + sum(1 + len(k) for k in self.knots)
        return len(self._exponents)

    @property
    def term_names(self) -> list[str]:
        """Human-readable names of the basis functions, e.g. ``['1', 'p0', 'p0^2']``."""
        if self.kind == "spline":
            names = ["1"]
            for i, knots in enumerate(self.knots):
                names.append(f"p{i}")
                names += [f"|p{i}-{k:g}|^3" for k in knots]
            return names
        names = []
        for e in self._exponents:
            factors = [f"p{i}" + (f"^{v}" if v > 1 else "") for i, v in enumerate(e) if v]
            names.append("*".join(factors) or "1")
        return names

    @property
    def is_affine(self) -> bool:
        """True when ψ = [1, p_1, …, p_np], i.e. the model is affine in the scheduling signals."""
        return self.kind == "affine" or (self.kind == "poly" and self.degree == 1)

    def eval(self, p: np.ndarray, *, check_range: bool = True) -> np.ndarray:
        """ψ(p) for every row of ``p`` (N, n_p) or a single point (n_p,): returns (N, n_psi)."""
        p = np.asarray(p, dtype=float)
        if p.ndim <= 1:
            p = p.reshape(-1, self.n_p) if p.size == self.n_p else p.reshape(-1, 1)
        if p.shape[1] != self.n_p:
            raise ModelError(f"basis expects {self.n_p} scheduling signal(s), got {p.shape[1]}")
        if check_range and self.p_min is not None and len(p):
            lo, hi = np.asarray(self.p_min), np.asarray(self.p_max)
            span = np.maximum(hi - lo, 1e-12)
            if np.any(p.min(axis=0) < lo - 1e-9 * span) or np.any(p.max(axis=0) > hi + 1e-9 * span):
                warnings.warn(
                    f"scheduling outside the identified range [{list(self.p_min)}, {list(self.p_max)}]: "
                    "the model extrapolates there",
                    SchedulingRangeWarning,
                    stacklevel=2,
                )
        if self.kind == "spline":
            cols = [np.ones(len(p))]
            for i, knots in enumerate(self.knots):
                cols.append(p[:, i])
                cols += [np.abs(p[:, i] - k) ** 3 for k in knots]
            return np.column_stack(cols)
        out = np.ones((len(p), len(self._exponents)))
        for col, e in enumerate(self._exponents):
            for i, v in enumerate(e):
                if v:
                    out[:, col] *= p[:, i] ** v
        return out

    # -------------------------------------------------------------------------- serialisation
    def to_dict(self) -> dict:
        d: dict = {"kind": self.kind, "n_p": self.n_p}
        if self.kind == "poly":
            d.update(degree=self.degree, cross=self.cross)
        if self.kind == "spline":
            d["knots"] = [list(k) for k in self.knots]
        if self.p_min is not None:
            d.update(p_min=list(self.p_min), p_max=list(self.p_max))
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Basis:
        try:
            rng = {}
            if "p_min" in d:
                rng = {"p_min": tuple(d["p_min"]), "p_max": tuple(d["p_max"])}
            if d["kind"] == "spline":
                return replace(cls.spline(d["knots"], d["n_p"]), **rng)
            return cls(d["kind"], int(d["n_p"]), degree=int(d.get("degree", 1)),
                       cross=bool(d.get("cross", True)), **rng)
        except KeyError as exc:
            raise ModelError(f"basis description lacks the field {exc.args[0]!r}") from None
