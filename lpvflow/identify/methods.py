"""The identification methods: one registry from a method name to its estimator, read by
``lpvflow identify`` (``--method``), the design file's ``[identify] method`` and the design's identify
stage, which all call :func:`estimate`, so every method is available in all three.

A method is

* one module with an estimator ``estimator(data, settings) -> LPVIO | LPVSS | LPVLFR``: ``data`` one
  :class:`~lpvflow.data.Dataset` (a list of them for a method with ``several_records``), ``settings`` the
  :class:`EstimationSettings` of the command line or the ``[identify]`` table;
* one line in :data:`IDENTIFICATION_METHODS` (its ``entry`` is ``"module:function"``, imported on first
  use), saying what the estimator returns and what it needs;
* its row in ``docs/features.md`` (and a key of its own in the ``[identify]`` schema, if it has one).

``docs/identification_methods.md`` walks through adding one.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.spline_sls import free_knot_count
from lpvflow.lfr import LPVLFR
from lpvflow.lpvio import LPVIO
from lpvflow.models import LPVSS


@dataclass(frozen=True)
class EstimationSettings:
    """What an estimator may read: the orders ``na``, ``nb``, ``nk`` (whole numbers or per-channel
    matrices), the scheduling ``basis`` spec, the Tikhonov weight ``ridge`` (ARX), the ARMAX noise order
    ``nc`` (None: na), the external ``excitation`` (one value per sample, two-step), the pbsid ``past``
    window and the state ``order`` of the state-space and LFR methods (None: their own choice)."""

    na: int | np.ndarray = 2
    nb: int | np.ndarray = 2
    nk: int | np.ndarray = 1
    basis: str = "affine"
    ridge: float = 0.0
    nc: int | None = None
    excitation: np.ndarray | None = None
    past: int | None = None
    order: int | None = None


@dataclass(frozen=True)
class IdentificationMethod:
    """One identification method: ``summary`` (one line, shown by ``lpvflow identify --help``),
    ``entry`` (``"module:function"`` of its estimator), ``result`` (``"io"``: an :class:`LPVIO`, realized
    exactly by ``to_ss``, with one-step residuals; ``"state-space"``: an :class:`LPVSS` or
    :class:`LPVLFR`), ``several_records`` (estimates from several records at once), ``free_knots``
    (estimates the knots of a ``spline:free:K`` basis), ``needs_excitation`` (reads the external
    excitation) and ``realizable`` (its model has a state-space realization)."""

    summary: str
    entry: str
    result: str = "io"
    several_records: bool = False
    free_knots: bool = False
    needs_excitation: bool = False
    realizable: bool = True

    def estimator(self) -> Callable[[Dataset | list[Dataset], EstimationSettings], LPVIO | LPVSS | LPVLFR]:
        """The estimator named by ``entry``."""
        module, _, name = self.entry.partition(":")
        return getattr(importlib.import_module(module), name)


_BUILT_IN = "lpvflow.identify.estimators"

#: Method name → its method. The first is the default of ``lpvflow identify``.
IDENTIFICATION_METHODS: dict[str, IdentificationMethod] = {
    "lpr-arx": IdentificationMethod("LPV-ARX, shifted form, realizable", f"{_BUILT_IN}:lpr_arx",
                                    several_records=True, free_knots=True),
    "static-arx": IdentificationMethod("LPV-ARX, Bamieh–Giarré static form (no realization)",
                                       f"{_BUILT_IN}:static_arx", several_records=True, free_knots=True,
                                       realizable=False),
    "iv-arx": IdentificationMethod("instrumental-variable ARX", f"{_BUILT_IN}:iv_arx"),
    "iv-oe": IdentificationMethod("instrumental-variable OE (thesis Alg. 4.1)", f"{_BUILT_IN}:iv_oe"),
    "oe-paa": IdentificationMethod("OE by the recursive PAA", f"{_BUILT_IN}:oe_paa"),
    "oe": IdentificationMethod("OE by prediction-error minimisation", f"{_BUILT_IN}:oe"),
    "armax": IdentificationMethod("ARMAX by pseudo-linear regression", f"{_BUILT_IN}:armax"),
    "riv": IdentificationMethod("refined instrumental variables", f"{_BUILT_IN}:riv"),
    "sriv": IdentificationMethod("simplified refined instrumental variables", f"{_BUILT_IN}:sriv"),
    "two-step": IdentificationMethod("two-step closed-loop estimation (needs the excitation)",
                                     f"{_BUILT_IN}:two_step", needs_excitation=True),
    "pbsid": IdentificationMethod("predictor-based subspace identification", f"{_BUILT_IN}:pbsid",
                                  result="state-space"),
    "cva": IdentificationMethod("canonical variate analysis (subspace)", f"{_BUILT_IN}:cva",
                                result="state-space"),
    "kcca-lfr": IdentificationMethod("LFR model by kernel CCA", f"{_BUILT_IN}:kcca_lfr",
                                     result="state-space"),
    "kcca-lfr-affine": IdentificationMethod("LFR model by kernel CCA, affine dependence",
                                            f"{_BUILT_IN}:kcca_lfr_affine", result="state-space"),
}


def method_of(name: str) -> IdentificationMethod:
    """The registered method ``name``; an unknown name is one DataError line."""
    if name not in IDENTIFICATION_METHODS:
        raise DataError(f"method {name!r} is unknown; use one of {', '.join(sorted(IDENTIFICATION_METHODS))}")
    return IDENTIFICATION_METHODS[name]


def method_names(*, realizable: bool = False, several_records: bool = False) -> list[str]:
    """The registered method names (sorted), only the realizable ones or those that estimate from several
    records if asked."""
    return sorted(name for name, m in IDENTIFICATION_METHODS.items()
                  if (m.realizable or not realizable) and (m.several_records or not several_records))


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
    """The model of ``method`` (a name of :data:`IDENTIFICATION_METHODS`) on ``data``: its estimator with
    these :class:`EstimationSettings`. Several records (a sequence of datasets) are one estimation
    problem for the methods with ``several_records`` and a fixed basis; ``spline:free:K`` bases are
    estimated by the methods with ``free_knots``; ``excitation`` must be given to a method that needs it.
    """
    chosen = method_of(method)
    records = [data] if isinstance(data, Dataset) else list(data)
    free = free_knot_count(basis) is not None
    if len(records) > 1 and (not chosen.several_records or free):
        raise DataError(f"method {method!r} estimates from one record; several records need "
                        f"{' or '.join(method_names(several_records=True))} with a fixed basis")
    if free and not chosen.free_knots:
        raise DataError("free spline knots (spline:free:K) are estimated with the methods "
                        f"{' or '.join(m for m, e in IDENTIFICATION_METHODS.items() if e.free_knots)}")
    if chosen.needs_excitation and excitation is None:
        raise DataError(f"method {method} needs the external excitation signal")
    settings = EstimationSettings(na, nb, nk, basis, ridge, nc, excitation, past, order)
    return chosen.estimator()(records[0] if len(records) == 1 else records, settings)
