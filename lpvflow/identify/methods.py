"""The identification methods: one registry from a method name to its estimator, read by
``lpvflow identify`` (``--method``), the design file's ``[identify] method`` and the design's identify
stage, so every method is available in all three.

IO methods (left polynomial / shifted or static form) map to ``(estimator kind, form)``; the state-space
methods (pbsid, cva) and the LFR methods (kcca-lfr[-affine]) return their own model classes. Adding an
estimator: its module under :mod:`lpvflow.identify`, one entry here (and in :func:`estimate`), its row in
``docs/features.md``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.spline_sls import free_knot_count
from lpvflow.lfr import LPVLFR
from lpvflow.lpvio import LPVIO
from lpvflow.models import LPVSS

#: IO methods: name → (estimator kind, form). The state-space and LFR methods are handled apart.
IO_METHODS = {
    "lpr-arx": ("arx", "shifted"), "static-arx": ("arx", "static"), "iv-arx": ("iv-arx", "shifted"),
    "iv-oe": ("iv-oe", "shifted"), "oe-paa": ("oe-paa", "shifted"), "oe": ("oe", "shifted"),
    "armax": ("armax", "shifted"), "riv": ("riv", "shifted"), "sriv": ("sriv", "shifted"),
    "two-step": ("two-step", "shifted"),
}
SS_METHODS = ("pbsid", "cva", "kcca-lfr", "kcca-lfr-affine")
METHODS = sorted([*IO_METHODS, *SS_METHODS])

#: The methods that estimate from several records at once (:func:`lpvflow.identify.arx.identify_arx`).
MULTI_RECORD_METHODS = ("lpr-arx", "static-arx")

#: The methods whose model has a state-space realization (``[identify] method``): static-arx has none.
STATE_SPACE_METHODS = tuple(m for m in METHODS if m != "static-arx")


def estimate(
    data: Dataset | Sequence[Dataset],
    method: str = "lpr-arx",
    na: int | np.ndarray = 2,
    nb: int | np.ndarray = 2,
    nk: int | np.ndarray = 1,
    basis: str = "affine",
    *,
    ridge: float = 0.0,
    nc: int | None = None,
    excitation: np.ndarray | None = None,
    past: int | None = None,
    order: int | None = None,
) -> LPVIO | LPVSS | LPVLFR:
    """The model of ``method`` (one of :data:`METHODS`) on ``data``: an :class:`LPVIO` for the IO
    methods (``spline:free:K`` bases estimate their knots), an :class:`LPVSS` for pbsid and cva, an
    :class:`LPVLFR` for kcca-lfr[-affine]. ``excitation`` is the external excitation two-step needs (one
    value per sample), ``nc`` the armax noise order (default na), ``past`` the pbsid past window and
    ``order`` the state order of the state-space and LFR methods (default: their own choice; 2 for LFR).
    Several records (a sequence of datasets) are one estimation problem for the methods in
    :data:`MULTI_RECORD_METHODS`.
    """
    if method not in METHODS:
        raise DataError(f"method {method!r} is unknown; use one of {', '.join(METHODS)}")
    if not isinstance(data, Dataset):
        records = list(data)
        if len(records) > 1 and (method not in MULTI_RECORD_METHODS or free_knot_count(basis) is not None):
            raise DataError(f"method {method!r} estimates from one record; several records need "
                            f"{' or '.join(MULTI_RECORD_METHODS)} with a fixed basis")
        if len(records) > 1:
            return identify_arx(records, na, nb, nk, basis, form=IO_METHODS[method][1], ridge=ridge)
        data = records[0]
    if method in SS_METHODS:
        if method == "pbsid":
            from lpvflow.identify.pbsid import identify_pbsid

            return identify_pbsid(data, order=order, past=past, basis=basis, form="kernel",
                                  regularization="gcv")
        if method == "cva":
            from lpvflow.identify.cva import identify_cva

            return identify_cva(data, basis, state_order=order, feedthrough=bool(np.all(np.asarray(nk) == 0)))
        from lpvflow.identify.kcca_lfr import identify_kcca_lfr

        return identify_kcca_lfr(data, order or 2, affine=method == "kcca-lfr-affine")
    kind, form = IO_METHODS[method]
    n_knots = free_knot_count(basis)
    if kind == "two-step":
        from lpvflow.identify.two_step import identify_two_step

        if excitation is None:
            raise DataError("method two-step needs the external excitation signal")
        return identify_two_step(data, np.asarray(excitation, dtype=float), na, nb, nk, basis, form=form)
    if n_knots is not None:
        if kind != "arx":
            raise DataError("free spline knots (spline:free:K) are estimated with the methods lpr-arx "
                            "or static-arx")
        from lpvflow.identify.spline_sls import identify_spline_sls

        return identify_spline_sls(data, na, nb, nk, n_knots, form=form)
    if kind == "arx":
        return identify_arx(data, na, nb, nk, basis, form=form, ridge=ridge)
    from lpvflow.identify import armax, iv, oe

    if kind == "armax":
        return armax.identify_armax(data, na, nb, nk, nc or int(np.max(na)), basis, form=form)
    if kind in ("riv", "sriv"):
        return iv.identify_riv(data, na, nb, nk, basis, form=form, simplified=kind == "sriv")
    estimator = {"iv-arx": iv.identify_iv_arx, "iv-oe": iv.identify_iv_oe, "oe-paa": iv.identify_oe_paa,
                 "oe": oe.identify_oe}[kind]
    return estimator(data, na, nb, nk, basis, form=form)
