"""The built-in estimators of :data:`lpvflow.identify.methods.IDENTIFICATION_METHODS`, each in the
registry's form ``estimator(data, settings)``: which estimator module a method runs and which of the
:class:`~lpvflow.identify.methods.EstimationSettings` it reads. The estimators themselves (and their
papers) are in the modules named here; the heavier ones are imported on first use."""

from __future__ import annotations

import numpy as np

from lpvflow.data import Dataset
from lpvflow.identify.arx import identify_arx
from lpvflow.identify.methods import EstimationSettings
from lpvflow.identify.spline_sls import free_knot_count
from lpvflow.lfr import LPVLFR
from lpvflow.lpvio import LPVIO
from lpvflow.models import LPVSS


def _arx(data: Dataset | list[Dataset], s: EstimationSettings, form: str) -> LPVIO:
    """:func:`lpvflow.identify.arx.identify_arx`, or with a ``spline:free:K`` basis
    :func:`lpvflow.identify.spline_sls.identify_spline_sls` (the knots estimated too)."""
    n_knots = free_knot_count(s.basis)
    if n_knots is not None:
        from lpvflow.identify.spline_sls import identify_spline_sls

        return identify_spline_sls(data, s.na, s.nb, s.nk, n_knots, form=form)
    return identify_arx(data, s.na, s.nb, s.nk, s.basis, form=form, ridge=s.ridge)


def lpr_arx(data: Dataset | list[Dataset], s: EstimationSettings) -> LPVIO:
    """LPV-ARX in the shifted (realizable) form."""
    return _arx(data, s, "shifted")


def static_arx(data: Dataset | list[Dataset], s: EstimationSettings) -> LPVIO:
    """LPV-ARX in the static (Bamieh–Giarré) form."""
    return _arx(data, s, "static")


def iv_arx(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.iv.identify_iv_arx`."""
    from lpvflow.identify.iv import identify_iv_arx

    return identify_iv_arx(data, s.na, s.nb, s.nk, s.basis, form="shifted")


def iv_oe(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.iv.identify_iv_oe`."""
    from lpvflow.identify.iv import identify_iv_oe

    return identify_iv_oe(data, s.na, s.nb, s.nk, s.basis, form="shifted")


def oe_paa(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.iv.identify_oe_paa`."""
    from lpvflow.identify.iv import identify_oe_paa

    return identify_oe_paa(data, s.na, s.nb, s.nk, s.basis, form="shifted")


def oe(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.oe.identify_oe`."""
    from lpvflow.identify.oe import identify_oe

    return identify_oe(data, s.na, s.nb, s.nk, s.basis, form="shifted")


def armax(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.armax.identify_armax`, noise order ``nc`` (default the largest na)."""
    from lpvflow.identify.armax import identify_armax

    return identify_armax(data, s.na, s.nb, s.nk, s.nc or int(np.max(s.na)), s.basis, form="shifted")


def riv(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.iv.identify_riv`."""
    from lpvflow.identify.iv import identify_riv

    return identify_riv(data, s.na, s.nb, s.nk, s.basis, form="shifted")


def sriv(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.iv.identify_riv` with ``simplified`` (H = 1)."""
    from lpvflow.identify.iv import identify_riv

    return identify_riv(data, s.na, s.nb, s.nk, s.basis, form="shifted", simplified=True)


def two_step(data: Dataset, s: EstimationSettings) -> LPVIO:
    """:func:`lpvflow.identify.two_step.identify_two_step` with the external excitation."""
    from lpvflow.identify.two_step import identify_two_step

    return identify_two_step(data, np.asarray(s.excitation, dtype=float), s.na, s.nb, s.nk, s.basis,
                             form="shifted")


def pbsid(data: Dataset, s: EstimationSettings) -> LPVSS:
    """:func:`lpvflow.identify.pbsid.identify_pbsid`, kernel form, GCV regularization."""
    from lpvflow.identify.pbsid import identify_pbsid

    return identify_pbsid(data, order=s.order, past=s.past, basis=s.basis, form="kernel",
                          regularization="gcv")


def cva(data: Dataset, s: EstimationSettings) -> LPVSS:
    """:func:`lpvflow.identify.cva.identify_cva`, with a feed-through when every nk is 0."""
    from lpvflow.identify.cva import identify_cva

    return identify_cva(data, s.basis, state_order=s.order, feedthrough=bool(np.all(np.asarray(s.nk) == 0)))


def kcca_lfr(data: Dataset, s: EstimationSettings) -> LPVLFR:
    """:func:`lpvflow.identify.kcca_lfr.identify_kcca_lfr` (order 2 unless given)."""
    from lpvflow.identify.kcca_lfr import identify_kcca_lfr

    return identify_kcca_lfr(data, s.order or 2)


def kcca_lfr_affine(data: Dataset, s: EstimationSettings) -> LPVLFR:
    """:func:`lpvflow.identify.kcca_lfr.identify_kcca_lfr` with affine dependence."""
    from lpvflow.identify.kcca_lfr import identify_kcca_lfr

    return identify_kcca_lfr(data, s.order or 2, affine=True)
