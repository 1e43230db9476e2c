"""Polytopic form of an LPVSS: vertex systems and the convex coordinates of any scheduling point.

An LPVSS is affine in the basis vector ψ(p) = [1, ψ_1(p), …, ψ_m(p)] (design.md). Treating the
non-constant terms θ = (ψ_1, …, ψ_m) as independent parameters, any set Θ = conv{θ^1, …, θ^N}
that contains θ(p) for every p of the scheduling box gives

    M(ψ(p)) = Σ_v λ_v(p) M(θ^v),    λ_v ≥ 0,  Σ_v λ_v = 1,  Σ_v λ_v θ^v = θ(p),

because M is affine in θ (Apkarian, Gahinet & Becker 1995, Sec. 2: polytopic LPV systems).

The tightest polytope that applies is chosen (:func:`polytope_of`); each kind is a class of its own
(its convex coordinates, the tables an exported controller needs for them, the rule in words), named in
:attr:`Polytope.kind`:

* ``"box"`` — ψ affine in p (θ = p): the 2^{n_p} corners of the box, multilinear coordinates
  λ_v = Π_k (t_k or 1 − t_k), t_k = (p_k − lo_k)/(hi_k − lo_k) (a simplex, i.e. a segment, for n_p = 1).
* ``"parabola-triangle"`` — one signal with ψ = [1, p, p²] on [a, b]: the triangle bounded by the
  chord and the tangents at a and b, vertices (a, a²), ((a+b)/2, ab), (b, b²); barycentric
  coordinates. It contains the parabola segment (the parabola is convex, so it lies above its
  tangents and below its chord) and is much tighter than the box [a, b] × [min p², max p²].
* ``"point"`` — a degenerate box (min = max for every signal): one vertex ψ(p₀), λ = [1]; the
  polytopic design is then the LTI design at p₀ (the pipeline's LTI baseline).
* ``"term-box"`` — any other basis: the bounding box of the term values over a grid of the scheduling
  box (conservative; vertex count 2^m), multilinear coordinates in the term values.
* ``"piecewise"`` — vertices at ascending breakpoints of the first scheduling signal
  (:func:`piecewise_polytope`), hat-function coordinates in p (:func:`hat_coordinates`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import ClassVar

import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS

_MAX_VERTICES = 64
_TERM_GRID = 201


@dataclass(frozen=True)
class Polytope(ABC):
    """Vertices θ^v (in basis-term coordinates) of a polytope containing θ(p) over a scheduling box; one
    subclass per kind (module docstring).

    Attributes:
        box: (n_p, 2) scheduling box [lo, hi] per signal.
        psi_vertices: (N, n_psi) basis vectors ψ^v = [1, θ^v] at the vertices.
        term_box: (m, 2) bounds of each non-constant term, :class:`TermBoxPolytope` only.
        breakpoints: (N,) ascending values b_0 < … < b_{N−1} of the first scheduling signal at the
            vertices, :class:`PiecewisePolytope` only.
    """

    box: np.ndarray
    psi_vertices: np.ndarray
    term_box: np.ndarray | None = None
    breakpoints: np.ndarray | None = None
    #: The kind's name in files and reports.
    kind: ClassVar[str]

    @property
    def n_vertices(self) -> int:
        return len(self.psi_vertices)

    @property
    def expected_vertices(self) -> int:
        """How many vertices a polytope of this kind has for its basis size (2^m for a box over m terms)."""
        return 2 ** (self.psi_vertices.shape[1] - 1)

    @property
    def design_box(self) -> np.ndarray | None:
        """The scheduling box a design on this polytope covers; None for a design at one point."""
        return np.asarray(self.box, dtype=float)

    @abstractmethod
    def coordinates(self, psi: np.ndarray) -> np.ndarray:
        """Convex coordinates λ (N,) with Σ λ_v ψ^v = ψ for one basis vector ψ (n_psi,).

        Points slightly outside the polytope (round-off, or scheduling outside the box) are
        projected onto it by clipping: λ is always a valid convex combination.
        """

    def coordinates_at(self, basis: Basis, p: np.ndarray) -> np.ndarray:
        """λ (N,) at the scheduling point p (n_p,): :meth:`coordinates` of ψ(p) in ``basis``."""
        p = np.atleast_1d(np.asarray(p, dtype=float)).reshape(-1)
        return self.coordinates(basis.eval(p.reshape(1, -1), check_range=False)[0])

    def coordinates_of_p(self, model: LPVSS, p: np.ndarray) -> np.ndarray:
        """Convex coordinates of the scheduling point p (n_p,) for ``model``'s basis."""
        return self.coordinates_at(model.basis, p)

    @property
    def vertex_breakpoints(self) -> np.ndarray | None:
        """The values b_0 < … < b_{N−1} of the one scheduling signal at the vertices when λ(p) is the hat
        functions of p between them (each λ_i linear between neighbouring vertices); None when λ is not
        of that form."""
        return None

    def design_points(self, per_axis: int) -> np.ndarray:
        """(n, n_p) scheduling points covering the design, where its certificate checks are evaluated:
        the ``per_axis`` grid of the box (:func:`box_grid`)."""
        return box_grid(self.box, per_axis)

    @abstractmethod
    def tables(self) -> dict[str, np.ndarray]:
        """The numbers an exported controller needs besides ψ(p) to compute λ (name → array)."""

    @abstractmethod
    def rule(self, psi: str, names: Sequence[str]) -> str:
        """How λ(p) is computed, in words (``psi``: ψ(p) in words, ``names``: the scheduling signals)."""


def box_grid(box: np.ndarray, per_axis: int) -> np.ndarray:
    """(per_axis^{n_p}, n_p) grid of the scheduling box; a degenerate axis (lo = hi, an LTI design's point)
    contributes one value, not per_axis copies of it."""
    axes = [np.linspace(lo, hi, per_axis if hi > lo else 1) for lo, hi in box]
    return np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(box), -1).T


def _multilinear(bounds: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """λ_v = Π_k (t_k or 1 − t_k), t_k = clip((θ_k − lo_k)/(hi_k − lo_k), 0, 1) of the terms θ = ψ[1:]
    in the box ``bounds`` (m, 2), corners in the order of :func:`_corners`."""
    psi = np.asarray(psi, dtype=float).reshape(-1)
    lo, hi = bounds[:, 0], bounds[:, 1]
    t = np.clip((psi[1:] - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0, 1.0)
    lam = np.ones(1)
    for tk in t:  # corner order of _corners: first coordinate varies slowest
        lam = np.concatenate([lam * (1.0 - tk), lam * tk]).reshape(2, -1).T.reshape(-1)
    return lam


def box_words(box: np.ndarray, names: Sequence[str]) -> str:
    """``name ∈ [lo, hi]`` per scheduling signal."""
    return ", ".join(f"{name} ∈ [{lo:g}, {hi:g}]" for name, (lo, hi) in zip(names, box, strict=True))


class _MultilinearPolytope(Polytope):
    """A polytope whose coordinates are multilinear in the values of ψ's terms within ``bounds``
    (:func:`_multilinear`); its controller table carries those bounds."""

    @property
    @abstractmethod
    def bounds(self) -> np.ndarray:
        """[[lo, hi], …] of the values the multilinear coordinates are taken in."""

    def coordinates(self, psi: np.ndarray) -> np.ndarray:
        return _multilinear(self.bounds, psi)

    def tables(self) -> dict[str, np.ndarray]:
        return {"term_bounds": np.asarray(self.bounds, dtype=float)}


@dataclass(frozen=True)
class BoxPolytope(_MultilinearPolytope):
    """``"box"``: ψ affine in p, the corners of the scheduling box, multilinear coordinates."""

    kind = "box"

    @property
    def bounds(self) -> np.ndarray:
        return self.box

    @property
    def vertex_breakpoints(self) -> np.ndarray | None:
        """A box over one signal is the segment [lo, hi]: its two ends (λ linear in p); None for more."""
        return self.box[0] if len(self.box) == 1 else None

    def rule(self, psi: str, names: Sequence[str]) -> str:
        return (f"{psi}; box polytope over {box_words(self.box, names)}: "
                "t_k = clip((p_k − lo_k)/(hi_k − lo_k), 0, 1), λ_v = Π_k (t_k at the upper, 1 − t_k at the "
                "lower bound of corner v), corners ordered with the first signal varying slowest")


@dataclass(frozen=True)
class TermBoxPolytope(_MultilinearPolytope):
    """``"term-box"``: the bounding box ``term_box`` of the non-constant terms, multilinear coordinates
    in the term values."""

    kind = "term-box"

    def __post_init__(self) -> None:
        if self.term_box is None:
            raise ModelError("a term-box polytope needs the bounds of its terms (term_box)")

    @property
    def bounds(self) -> np.ndarray:
        return self.term_box

    def rule(self, psi: str, names: Sequence[str]) -> str:
        return (f"{psi}; term box (bounds of each non-constant term of ψ over the scheduling box "
                f"{box_words(self.box, names)}): t_j = clip((ψ_j − lo_j)/(hi_j − lo_j), 0, 1), "
                "λ multilinear in t as for a box, first term varying slowest")


@dataclass(frozen=True)
class ParabolaTriangle(Polytope):
    """``"parabola-triangle"``: ψ = [1, p, p²] on [a, b], the triangle of the chord and the tangents at a
    and b; barycentric coordinates λ = V⁻¹ ψ (V the vertex basis vectors as columns), clipped at 0 and
    normalized."""

    kind = "parabola-triangle"

    @property
    def expected_vertices(self) -> int:
        return 3

    def vertex_inverse(self) -> np.ndarray:
        """V⁻¹ with V the vertex basis vectors as columns."""
        return np.linalg.inv(self.psi_vertices.T)

    def coordinates(self, psi: np.ndarray) -> np.ndarray:
        psi = np.asarray(psi, dtype=float).reshape(-1)
        lam = np.linalg.solve(self.psi_vertices.T, psi)
        lam = np.clip(lam, 0.0, None)
        return lam / lam.sum()

    def tables(self) -> dict[str, np.ndarray]:
        return {"vertex_inverse": self.vertex_inverse()}

    def rule(self, psi: str, names: Sequence[str]) -> str:
        return (f"{psi}; triangle around the parabola over {box_words(self.box, names)} (vertices "
                "ψ at a, (a+b)/2 with ab, b): λ = vertex_inverse · ψ(p) (barycentric), negative entries "
                "set to 0 and λ divided by its sum")


@dataclass(frozen=True)
class PointPolytope(Polytope):
    """``"point"``: a degenerate box (min = max for every signal), one vertex ψ(p₀), λ = [1]."""

    kind = "point"

    @property
    def expected_vertices(self) -> int:
        return 1

    @property
    def design_box(self) -> None:
        return None

    def coordinates(self, psi: np.ndarray) -> np.ndarray:
        return np.ones(1)

    def tables(self) -> dict[str, np.ndarray]:
        return {}

    def rule(self, psi: str, names: Sequence[str]) -> str:
        at = ", ".join(f"{name} = {lo:g}" for name, (lo, _) in zip(names, self.box, strict=True))
        return f"one vertex: an LTI controller designed at {at}; λ = [1] (only the trim reads the scheduling)"


@dataclass(frozen=True)
class PiecewisePolytope(Polytope):
    """``"piecewise"``: vertices at ascending ``breakpoints`` of the first scheduling signal, one per
    vertex, at least 2; λ the hat functions of p₁ (:func:`hat_coordinates`)."""

    kind = "piecewise"

    def __post_init__(self) -> None:
        b, N = self.breakpoints, self.n_vertices
        if b is None or len(b) != N or N < 2 or np.any(np.diff(b) <= 0):
            raise ModelError(f"a piecewise polytope needs one strictly ascending breakpoint per vertex "
                             f"({N}), at least 2; got {None if b is None else np.asarray(b).tolist()}")

    @property
    def expected_vertices(self) -> int:
        return len(self.breakpoints)

    @property
    def vertex_breakpoints(self) -> np.ndarray:
        return self.breakpoints

    def coordinates(self, psi: np.ndarray) -> np.ndarray:
        raise ModelError("a piecewise polytope's coordinates are those of the scheduling point p "
                         "(coordinates_at), not of ψ")

    def coordinates_at(self, basis: Basis, p: np.ndarray) -> np.ndarray:
        """The hat functions of t = clip(p_1, b_0, b_{N−1}) on the breakpoints: with j the largest index
        ≤ N − 2 such that b_j ≤ t, λ_{j+1} = (t − b_j)/(b_{j+1} − b_j), λ_j = 1 − λ_{j+1}, every other
        λ zero."""
        p = np.atleast_1d(np.asarray(p, dtype=float)).reshape(-1)
        return hat_coordinates(self.breakpoints, p[0])

    def tables(self) -> dict[str, np.ndarray]:
        return {"breakpoints": np.asarray(self.breakpoints, dtype=float)}

    def design_points(self, per_axis: int) -> np.ndarray:
        """(n, 1): ``per_axis`` values of the first signal per breakpoint interval (the ends shared)."""
        b = self.breakpoints
        return np.unique(np.concatenate([np.linspace(lo, hi, per_axis) for lo, hi in pairwise(b)]))[:, None]

    def rule(self, psi: str, names: Sequence[str]) -> str:
        b = ", ".join(f"{v:g}" for v in self.breakpoints)
        return (f"piecewise over {names[0]} with breakpoints b = [{b}] (vertex i at b_i): "
                f"t = clip({names[0]}, b_0, b_last), j the last segment start with b_j ≤ t, "
                "λ_(j+1) = (t − b_j)/(b_(j+1) − b_j), λ_j = 1 − λ_(j+1), every other λ zero")


#: The polytope classes by the kind named in files.
KINDS: dict[str, type[Polytope]] = {cls.kind: cls for cls in (BoxPolytope, TermBoxPolytope, ParabolaTriangle,
                                                              PointPolytope, PiecewisePolytope)}


def polytope_of_kind(kind: str, box: np.ndarray, psi_vertices: np.ndarray, term_box: np.ndarray | None = None,
                     breakpoints: np.ndarray | None = None) -> Polytope:
    """The polytope of the kind named ``kind`` (a file's ``polytope.kind``); an unknown kind is one
    ModelError line."""
    if kind not in KINDS:
        raise ModelError(f"unknown polytope kind {kind!r}; known: {', '.join(KINDS)}")
    return KINDS[kind](box, psi_vertices, term_box, breakpoints)


def hat_coordinates(breakpoints: np.ndarray, p1: float) -> np.ndarray:
    """Hat functions of t = clip(p1, b_0, b_{N−1}) on the breakpoints: with j the largest index ≤ N − 2 such
    that b_j ≤ t, λ_{j+1} = (t − b_j)/(b_{j+1} − b_j), λ_j = 1 − λ_{j+1}, every other λ zero."""
    b = np.asarray(breakpoints, dtype=float)
    t = min(max(float(p1), b[0]), b[-1])
    j = min(int(np.searchsorted(b, t, side="right")) - 1, len(b) - 2)
    lam = np.zeros(len(b))
    lam[j + 1] = (t - b[j]) / (b[j + 1] - b[j])
    lam[j] = 1.0 - lam[j + 1]
    return lam


def piecewise_polytope(model: LPVSS, box: np.ndarray | list | None, breakpoints: np.ndarray | list
                       ) -> Polytope:
    """The ``"piecewise"`` polytope (multi-simplex) along the first scheduling signal: vertices ψ(b_i) at
    ascending breakpoints from the box's lower to its upper end of that signal. ``breakpoints`` are values
    of the one scheduling signal, or rows of full scheduling points (b_i1, …, b_in_p) when the signals are
    tied to one another (sin and cos of one angle), ascending in the first. The model frozen at the
    breakpoints and interpolated with the hat functions of the first signal is exact between them when ψ
    is affine in p along the segment (one affine signal), else a piecewise-linear model of the curve."""
    box = scheduling_box(model, box)
    b = np.asarray(breakpoints, dtype=float)
    b = b.reshape(-1, 1) if b.ndim == 1 else b
    if b.shape[1] != model.basis.n_p:
        raise ModelError(f"breakpoints need {model.basis.n_p} value(s) per row (one per scheduling signal), "
                         f"got rows of {b.shape[1]}")
    first = b[:, 0]
    if len(b) < 2 or not np.all(np.diff(first) > 0) or not np.allclose([first[0], first[-1]], box[0]):
        raise ModelError(f"breakpoints must ascend in the first scheduling signal from the box's lower to "
                         f"its upper end {box[0].tolist()}, got {first.tolist()}")
    psi = model.basis.eval(b, check_range=False)
    return PiecewisePolytope(box, psi, breakpoints=first)


def _corners(bounds: np.ndarray) -> np.ndarray:
    """(2^k, k) corners of a box, first coordinate varying slowest (matches Polytope.coordinates)."""
    grids = np.meshgrid(*bounds, indexing="ij")
    return np.array(grids).reshape(len(bounds), -1).T


def scheduling_box(model: LPVSS, box: np.ndarray | list | None = None) -> np.ndarray:
    """The (n_p, 2) scheduling box: ``box`` if given, else the range recorded in the basis."""
    if box is None:
        if model.basis.p_min is None:
            raise ModelError("the model records no scheduling range; "
                             "give box = [[min, max], ...] in [polytope]")
        box = np.column_stack([model.basis.p_min, model.basis.p_max])
    box = np.asarray(box, dtype=float)
    point = box.shape == (model.basis.n_p, 2) and np.all(box[:, 1] == box[:, 0])
    if box.shape != (model.basis.n_p, 2) or not (point or np.all(box[:, 1] > box[:, 0])):
        raise ModelError(f"scheduling box must be {model.basis.n_p} rows of [min, max] with min < max "
                         f"(or min = max in every row for an LTI design), got {box.tolist()}")
    return box


def polytope_of(model: LPVSS, box: np.ndarray | list | None = None) -> Polytope:
    """The tightest supported polytope (module docstring) around θ(p) for p in the scheduling box."""
    box = scheduling_box(model, box)
    basis = model.basis
    if np.all(box[:, 1] == box[:, 0]):
        return PointPolytope(box, basis.eval(box[:, 0].reshape(1, -1), check_range=False))
    if basis.is_affine:
        psi_v = np.column_stack([np.ones(2**basis.n_p), _corners(box)])
        return BoxPolytope(box, psi_v)
    if basis.kind == "poly" and basis.n_p == 1 and basis.degree == 2:
        a, b = box[0]
        verts = np.array([[1.0, a, a * a], [1.0, 0.5 * (a + b), a * b], [1.0, b, b * b]])
        return ParabolaTriangle(box, verts)
    grid = _corners(box) if basis.n_p > 3 else np.array(
        np.meshgrid(*[np.linspace(lo, hi, _TERM_GRID) for lo, hi in box], indexing="ij")
    ).reshape(basis.n_p, -1).T
    terms = basis.eval(grid, check_range=False)[:, 1:]
    term_box = np.column_stack([terms.min(axis=0), terms.max(axis=0)])
    term_box[:, 1] = np.maximum(term_box[:, 1], term_box[:, 0] + 1e-12)
    if 2 ** len(term_box) > _MAX_VERTICES:
        raise ModelError(f"the {basis.kind} basis has {len(term_box)} scheduling terms: a term box would "
                         f"have 2^{len(term_box)} vertices; identify with an affine or poly:2 basis")
    psi_v = np.column_stack([np.ones(2 ** len(term_box)), _corners(term_box)])
    return TermBoxPolytope(box, psi_v, term_box)


def vertex_matrices(model: LPVSS, polytope: Polytope) -> list[tuple[np.ndarray, ...]]:
    """(A_v, B_v, C_v, D_v) = Σ_l ψ^v_l (A_l, B_l, C_l, D_l) for every vertex v of the polytope."""
    return [tuple(np.tensordot(psi, M, axes=1) for M in (model.A, model.B, model.C, model.D))
            for psi in polytope.psi_vertices]
