"""An input nonlinearity material in one-step prediction but not in simulation (step 5 of
:mod:`lpvflow.validate.diagnose`): named with its level when the prediction evidence is significant
and the consistent refit does not contradict it."""

from __future__ import annotations

from dataclasses import replace

import scipy.stats

from lpvflow.validate.diagnose_noise_round import oe_context, refits_by_output_error
from lpvflow.validate.diagnose_summary import NOISE
from lpvflow.validate.extensions import Candidate, Context
from lpvflow.validate.metrics import bfr
from lpvflow.validate.noise_analysis import normalised_sq_error
from lpvflow.validate.residuals import block_signed_rank

#: The cause judged here: a dead zone or saturation, a map of the recorded input.
CAUSE = "input_nonlinearity"
#: Smallest drop of the one-step loss (log det of the residual covariance, per output) that is
#: material: about 10 % less prediction-error variance. Between the misfit an input map takes up in an
#: approximate structure (airpath FMU, clean records, poly:2: a throttle saturation 0.03–0.05, seeds
#: 0–2) and the tanks' pump dead zone (0.31–0.33, seeds 0–1).
MATERIAL_PREDICTION = 0.1
#: The output-error refit's level must lie within this fraction of the LS level (a stable choice).
STABLE_LEVEL = 0.1


def prediction_likelihood_ratio(ctx: Context, cand: Candidate) -> tuple[float, int]:
    """The likelihood-ratio statistic of the extension against the nominal fit in one-step prediction
    on estimation data and its degrees of freedom: Λ = n_eff·(V_nominal − V_extension), V the log det
    of the one-step residual covariance, n_eff = N − max lag; under the nominal model Λ ~ χ²(k), k the
    added coefficients plus the chosen level (Ljung, *System Identification*, 2nd ed., Sec. 16.4)."""
    n_eff = ctx.est.N - cand.fit.model.max_lag
    extra = cand.fit.n_params + cand.choices - ctx.nominal.n_params
    return float(n_eff * (ctx.nominal.loss - cand.fit.loss)), int(extra)


def material_in_prediction(ctx: Context, candidates: dict[str, Candidate], cause: str,
                           alpha: float) -> Candidate | None:
    """The output-error refit of the input nonlinearity, named although its simulation gain is not
    significant, or None.

    Conditions (open loop, the verdict so far ``none`` or a noise verdict):

    * one-step prediction: its LS fit beats the nominal at level ``alpha`` by the likelihood-ratio test
      of :func:`prediction_likelihood_ratio` — the map is a function of the recorded input, which the
      output noise does not enter — and materially: the loss drops by MATERIAL_PREDICTION per output;
    * simulation does not contradict it: refitted by output error (consistent under output noise), the
      map keeps its kind, channel and level (within STABLE_LEVEL of the LS level) and does not lose
      BFR against the output-error refit of the nominal structure.

    Tanks FMU with a 3 V pump dead zone under 0.2 mm level noise (``tests/diagnosis_fmu_cases.py``,
    seeds 0–2): Λ = 622 / 660 / 554 at one degree of freedom, LS width 3.11 / 3.11 / 3.08 V, output-error
    width 3.07 / 3.15 / 3.08 V, +1.06 / +0.47 / +0.79 points in simulation (p = 0.07 / 0.015 / 0.010).
    The nominal poly:3 structure absorbs the dead zone in simulation (flow ∝ V − 3 gives an equilibrium
    gain smooth in the level) but not in prediction; on the clean records Λ ≈ 1.
    """
    if (ctx.loop is not None or cause not in ("none", NOISE, "colored_noise") or CAUSE not in candidates
            or NOISE not in candidates):
        return None
    ls = candidates[CAUSE]
    ratio, extra = prediction_likelihood_ratio(ctx, ls)
    p_prediction = float(scipy.stats.chi2.sf(ratio, extra))
    drop = (ctx.nominal.loss - ls.fit.loss) / ctx.ny
    if ls.fit.diverged or p_prediction >= alpha or drop < MATERIAL_PREDICTION:
        return None
    refit = refits_by_output_error({CAUSE: ls}, oe_context(ctx, candidates)).get(CAUSE)
    if refit is None or refit.fit.diverged:
        return None
    kind, what = ls.parameters["kind"], ("width" if ls.parameters["kind"] == "dead_zone" else "limit")
    level, oe_level = ls.parameters[what], refit.parameters.get(what)
    if (refit.parameters["kind"] != kind or refit.parameters["channel"] != ls.parameters["channel"]
            or abs(oe_level - level) > STABLE_LEVEL * abs(level)):
        return None
    nominal = candidates[NOISE].fit
    gain = float((bfr(ctx.val.y, refit.fit.y_val) - bfr(ctx.val.y, nominal.y_val)).mean())
    if gain < 0:
        return None
    _, p_simulation = block_signed_rank(normalised_sq_error(ctx.val.y, nominal.y_val),
                                        normalised_sq_error(ctx.val.y, refit.fit.y_val))
    evidence = {"material": "in one-step prediction, not in simulation",
                "prediction_likelihood_ratio": ratio, "prediction_p_value": p_prediction,
                "prediction_loss_drop": drop,
                f"least_squares_{what}": level, "simulation_gain": gain, "simulation_p_value": p_simulation}
    description = (f"{refit.description} (material in one-step prediction: likelihood ratio {ratio:.0f}, "
                   f"p = {p_prediction:.2g}; in simulation +{gain:.2f} points, p = {p_simulation:.2g})")
    return replace(refit, parameters=refit.parameters | evidence, description=description)
