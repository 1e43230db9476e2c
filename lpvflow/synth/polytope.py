"""Polytopic form of an LPVSS: vertex systems and the convex coordinates of any scheduling point.

An LPVSS is affine in the basis vector ψ(p) = [1, ψ_1(p), …, ψ_m(p)] (design.md). Treating the
non-constant terms θ = (ψ_1, …, ψ_m) as independent parameters, any set Θ = conv{θ^1, …, θ^N}
that contains θ(p) for every p of the scheduling box gives

    M(ψ(p)) = Σ_v λ_v(p) M(θ^v),    λ_v ≥ 0,  Σ_v λ_v = 1,  Σ_v λ_v θ^v = θ(p),

because M is affine in θ (Apkarian, Gahinet & Becker 1995, Sec. 2: polytopic LPV systems).

Three polytopes, the tightest that applies is chosen and named in :attr:`Polytope.kind`:

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lpvflow.basis import Basis
from lpvflow.errors import ModelError
from lpvflow.models import LPVSS

_MAX_VERTICES = 64
_TERM_GRID = 201


@dataclass(frozen=True)
class Polytope:
    """Vertices θ^v (in basis-term coordinates) of a polytope containing θ(p) over a scheduling box.

    Attributes:
        kind: ``"box"``, ``"parabola-triangle"`` or ``"term-box"`` (see module docstring).
        box: (n_p, 2) scheduling box [lo, hi] per signal.
        psi_vertices: (N, n_psi) basis vectors ψ^v = [1, θ^v] at the vertices.
        term_box: (m, 2) bounds of each non-constant term, ``"term-box"`` only.
        breakpoints: (N,) ascending values b_0 < … < b_{N−1} of the first scheduling signal at the
            vertices, ``"piecewise"`` only (:meth:`coordinates_at`).
    """

    kind: str
    box: np.ndarray
    psi_vertices: np.ndarray
    term_box: np.ndarray | None = None
    breakpoints: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return len(self.psi_vertices)

    def coordinates(self, psi: np.ndarray) -> np.ndarray:
        """Convex coordinates λ (N,) with Σ λ_v ψ^v = ψ for one basis vector ψ (n_psi,).

        Points slightly outside the polytope (round-off, or scheduling outside the box) are
        projected onto it by clipping: λ is always a valid convex combination.
        """
        psi = np.asarray(psi, dtype=float).reshape(-1)
        if self.kind == "point":
            return np.ones(1)
        if self.kind == "parabola-triangle":
            lam = np.linalg.solve(self.psi_vertices.T, psi)
            lam = np.clip(lam, 0.0, None)
            return lam / lam.sum()
        bounds = self.box if self.kind == "box" else self.term_box
        lo, hi = bounds[:, 0], bounds[:, 1]
        t = np.clip((psi[1:] - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0, 1.0)
        lam = np.ones(1)
        for tk in t:  # corner order of _corners: first coordinate varies slowest
            lam = np.concatenate([lam * (1.0 - tk), lam * tk]).reshape(2, -1).T.reshape(-1)
        return lam

    def coordinates_at(self, basis: Basis, p: np.ndarray) -> np.ndarray:
        """λ (N,) at the scheduling point p (n_p,).

        ``"piecewise"``: the hat functions of t = clip(p_1, b_0, b_{N−1}) on the breakpoints: with j the
        largest index ≤ N − 2 such that b_j ≤ t, λ_{j+1} = (t − b_j)/(b_{j+1} − b_j), λ_j = 1 − λ_{j+1},
        every other λ zero. Any other kind: :meth:`coordinates` of ψ(p) in ``basis``.
        """
        p = np.atleast_1d(np.asarray(p, dtype=float)).reshape(-1)
        if self.kind != "piecewise":
            return self.coordinates(basis.eval(p.reshape(1, -1), check_range=False)[0])
        return hat_coordinates(self.breakpoints, p[0])

    def coordinates_of_p(self, model: LPVSS, p: np.ndarray) -> np.ndarray:
        """Convex coordinates of the scheduling point p (n_p,) for ``model``'s basis."""
        return self.coordinates_at(model.basis, p)


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
    return Polytope("piecewise", box, psi, breakpoints=first)


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
        return Polytope("point", box, basis.eval(box[:, 0].reshape(1, -1), check_range=False))
    if basis.is_affine:
        psi_v = np.column_stack([np.ones(2**basis.n_p), _corners(box)])
        return Polytope("box", box, psi_v)
    if basis.kind == "poly" and basis.n_p == 1 and basis.degree == 2:
        a, b = box[0]
        verts = np.array([[1.0, a, a * a], [1.0, 0.5 * (a + b), a * b], [1.0, b, b * b]])
        return Polytope("parabola-triangle", box, verts)
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
    return Polytope("term-box", box, psi_v, term_box)


def vertex_matrices(model: LPVSS, polytope: Polytope) -> list[tuple[np.ndarray, ...]]:
    """(A_v, B_v, C_v, D_v) = Σ_l ψ^v_l (A_l, B_l, C_l, D_l) for every vertex v of the polytope."""
    return [tuple(np.tensordot(psi, M, axes=1) for M in (model.A, model.B, model.C, model.D))
            for psi in polytope.psi_vertices]
