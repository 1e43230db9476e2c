"""Frozen-point validation of an LPV model over its scheduling box (Boonto's thesis §6.1).

For LPV models the ν-gap test is applied to frozen LTI models: at each scheduling point p of a grid
over the box, δν(G_ref(p), Ĝ(p)) is compared with b(Ĝ(p), K) (criterion (6.4): δν < b). There is
no LPV ν-gap; this is the thesis's (ad hoc) frozen-point procedure.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import control
import numpy as np

from lpvflow.errors import ModelError
from lpvflow.validate.margins import loop_margins, stability_margin
from lpvflow.validate.nugap import nugap


@dataclass(frozen=True)
class FrozenPoint:
    """One grid point: scheduling value p, where it lies in the box, and the frozen LTI model."""

    p: np.ndarray
    kind: str
    system: control.StateSpace


def scheduling_grid(box: object, n: int) -> list[tuple[np.ndarray, str]]:
    """Tensor grid with `n` ≥ 2 points per scheduling signal, each tagged by where it lies.

    Tags: "vertex" (every coordinate at a bound), "edge" (one coordinate free), "interior" (all
    free), "face" (otherwise, for three or more signals). With one signal the two ends are vertices.
    """
    box = _as_box(box)
    if n < 2:
        raise ModelError(f"a frozen grid needs at least 2 points per scheduling signal, got n = {n}")
    axes = [np.linspace(lo, hi, n) for lo, hi in box]
    grid = []
    for point in itertools.product(*axes):
        p = np.array(point)
        free = int(np.sum((p > box[:, 0]) & (p < box[:, 1])))
        kind = "vertex" if free == 0 else "interior" if free == len(p) else "edge" if free == 1 else "face"
        grid.append((p, kind))
    return grid


def frozen_grid(model: object, n: int, box: object = None) -> list[FrozenPoint]:
    """Frozen LTI models `model.frozen(p)` on `scheduling_grid(box, n)`; box defaults to the model's range."""
    box = _model_box(model) if box is None else _as_box(box)
    return [FrozenPoint(p, kind, model.frozen(p)) for p, kind in scheduling_grid(box, n)]


def compare_frozen(
    model: object, reference: object, n: int, controller: object = None, box: object = None,
    points: object = None,
) -> list[dict]:
    """Frozen ν-gap table: one row per grid point, with b(Ĝ(p), K) and δν < b when a controller is given.

    `points`: scheduling points (rows) to use instead of the `n`-point grid of `box` (kind "point"), e.g.
    points along a curve that tied scheduling signals follow.

    `reference`: another LPV model (anything with `frozen(p)`), a callable p ↦ LTI system (e.g. a
    local model identified at a frozen operating point), or None (no ν-gap; b and margins only).
    `controller`: an LTI K or an LPV controller with `frozen(p)`, in negative feedback u = −K y (see
    margins.py). Rows with a controller also get `loop_margins` (classical and disk margins for
    SISO, multiloop disk margins for MIMO); `passes` needs both a reference and a controller.
    """
    reference_at = None if reference is None else _frozen_getter(reference, "reference")
    controller_at = None if controller is None else _frozen_getter(controller, "controller")
    rows = []
    if points is None:
        grid = frozen_grid(model, n, box)
    else:
        grid = [FrozenPoint(p, "point", model.frozen(p)) for p in np.atleast_2d(np.asarray(points, float))]
    for point in grid:
        row: dict = {"p": point.p.tolist(), "kind": point.kind}
        if reference_at is not None:
            try:
                gap = nugap(reference_at(point.p), point.system)
            except ModelError as err:
                raise ModelError(f"the ν-gap at the scheduling point {np.round(point.p, 4).tolist()} "
                                 f"(P1 the reference, P2 the model): {err}") from None
            row.update({"nugap": gap.value, "nugap_frequency_rad_s": gap.frequency,
                        "winding_condition_held": gap.winding_condition_held})
        if controller_at is not None:
            K = controller_at(point.p)
            row["stability_margin_b"] = stability_margin(point.system, K)
            if reference_at is not None:
                row["passes"] = bool(row["nugap"] < row["stability_margin_b"])
            row["margins"] = loop_margins(point.system, K)
        rows.append(row)
    return rows


def _frozen_getter(thing: object, name: str) -> Callable[[np.ndarray], object]:
    if hasattr(thing, "frozen"):
        return thing.frozen
    if isinstance(thing, control.LTI):
        return lambda p: thing
    if callable(thing):
        return thing
    raise ModelError(f"the {name} must be an LPV model with frozen(p), an LTI system or a callable p -> LTI")


def _model_box(model: object) -> np.ndarray:
    basis = getattr(model, "basis", None)
    if basis is None or basis.p_min is None:
        raise ModelError("the model has no recorded scheduling range; pass box=[[min, max], ...]")
    return _as_box(np.column_stack([basis.p_min, basis.p_max]))


def _as_box(box: object) -> np.ndarray:
    box = np.asarray(box, dtype=float)
    if box.ndim == 1 and box.size == 2:
        box = box.reshape(1, 2)
    if box.ndim != 2 or box.shape[1] != 2 or not np.all(np.isfinite(box)) or np.any(box[:, 1] <= box[:, 0]):
        raise ModelError(f"the scheduling box must be [[min, max], ...] with min < max, got {box.tolist()}")
    return box
