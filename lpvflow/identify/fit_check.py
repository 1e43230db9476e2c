"""A fit no better than the output's own mean is useless: say so in one line instead of a silent 0 %.

Every estimator goes through ``lpvflow identify``, which checks the estimation-data simulation of the
model it wrote with :func:`useless_fit_message` and exits 1 with that line; :func:`identify_kcca_lfr
<lpvflow.identify.kcca_lfr.identify_kcca_lfr>` also warns from Python (:class:`UselessFitWarning`).
"""

from __future__ import annotations

import math

#: Best fit ratio (percent) at or below which a simulated output counts as not explained at all.
USELESS_BFR = 5.0


class UselessFitWarning(UserWarning):
    """The identified model's simulation explains (almost) none of an output."""


def useless_fit_message(fit: dict, method: str) -> str | None:
    """One line naming every output whose BFR (of :func:`lpvflow.validate.metrics.fit_report`) is at
    most :data:`USELESS_BFR` or not finite, and what to try; None when every output is explained."""
    bad = [f"{name} BFR {bfr:.2f} % (MSE {mse:.3g})"
           for name, bfr, mse in zip(fit["outputs"], fit["bfr"], fit["mse"], strict=True)
           if not (math.isfinite(bfr) and bfr > USELESS_BFR)]
    if not bad:
        return None
    return (f"{method}: useless fit on the estimation data, {', '.join(bad)}: the model's simulation "
            "explains none of it; try another --method, order or basis, remove the offsets, or check that "
            "the columns are the plant's input, output and scheduling")
