"""Are the model's coefficients the same in both halves of the record? (step 6 of
:mod:`lpvflow.validate.diagnose`, open loop).

A time-invariant plant inside the model set has one coefficient vector θ for the whole record; an
effect that changes the plant over time — a drifting actuator gain, an actuator that sticks now and
then — gives each half of the record its own. The split-sample test of parameter constancy (Chow,
"Tests of equality between sets of coefficients in two linear regressions", Econometrica 28(3), 1960,
Sec. 2: the structure fitted on two sub-samples separately against one coefficient vector) is posed
here in simulation, where the diagnosis judges every model: θ_a is the LPV-ARX least-squares fit of
the structure on the estimation split, θ_b on the validation split, both simulated on each split
from a zero past (the start-up transient costs both alike), and

    S = [BFR_b(θ_b) − BFR_b(θ_a)] + [BFR_a(θ_a) − BFR_a(θ_b)]

(BFR in points on the split named by the index, mean over outputs) is what each half loses with the
other half's coefficients. S is never exactly 0 on a constant plant: each fit is scored in-sample on
its own half, and an approximate structure weighs the two halves' operating points differently. The
coefficients are not constant when S ≥ CONSTANCY_GAIN and the block signed-rank test
(:func:`~lpvflow.validate.residuals.block_signed_rank`) of the normalised squared simulation errors of
the cross-applied coefficients against each half's own, over both halves together, gives
p < ``alpha``.
The F statistic of the regression form rejects the approximate structures of clean plant records at
any useful α (h35v's correlation tests did the same), hence a size in BFR points, like the adequacy
test's.
"""

from __future__ import annotations

import warnings

import numpy as np

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError
from lpvflow.identify.arx import identify_arx
from lpvflow.validate import residuals
from lpvflow.validate.extension_core import Structure, bounded
from lpvflow.validate.metrics import bfr
from lpvflow.validate.noise_analysis import normalised_sq_error

#: Smallest S (BFR points) that shows the coefficients changed between the halves. Measured on the
#: FMU records of tests/diagnosis_fmu_cases.py (seeds 0–9 clean, 0–4 out of vocabulary): airpath clean
#: 1.2–5.6 (p ≥ 3·10⁻⁶), drifting gain 8.2–12.7 (p ≤ 4·10⁻⁵); tanks clean −0.6–3.4, drifting gain
#: 48–67.
CONSTANCY_GAIN = 6.5


def split_constancy(est: Dataset, val: Dataset, structure: Structure, alpha: float) -> dict | None:
    """The split-sample constancy test of ``structure`` on the two splits (module docstring):
    S, its two halves, the block signed-rank p and ``significant``; None when a split alone does not
    determine the coefficients (e.g. its scheduling stays constant: the regressor is rank deficient)."""
    basis = structure.basis_for(est.p.shape[1])
    halves = (est, val)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        try:
            models = [identify_arx(half, structure.na, structure.nb, structure.nk, basis, form=structure.form)
                      for half in halves]
        except DataError:
            return None
        # sims[i][j]: the coefficients of half j simulated on half i
        sims = [[bounded(model.simulate(half.u, half.p), half.y)[0] for model in models] for half in halves]
    gains = [float(np.mean(bfr(half.y, sims[i][i]) - bfr(half.y, sims[i][1 - i])))
             for i, half in enumerate(halves)]
    loss_own, loss_other = (np.concatenate([normalised_sq_error(half.y, sims[i][(i + j) % 2])
                                            for i, half in enumerate(halves)]) for j in (0, 1))
    p_value = residuals.block_signed_rank(loss_other, loss_own)[1]
    statistic = sum(gains)
    return {"statistic": statistic, "estimation_gain": gains[0], "validation_gain": gains[1],
            "p_value": p_value, "threshold": CONSTANCY_GAIN, "alpha": alpha,
            "significant": bool(statistic >= CONSTANCY_GAIN and p_value < alpha)}
