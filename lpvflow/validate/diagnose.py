"""Diagnosis: what a model's simulation gets wrong, why, and how much an extension gains.

Protocol (every choice made on the estimation split, every score on the validation split):

1. Fit the user's structure (LPV-ARX, :func:`identify_arx`) and simulate it on validation data
   (the whole record is simulated, the estimation split serving as warm-up, so that the validation
   part does not start from a zero past): BFR/VAF per output, and *where* the error lives
   (spectrum, RMS against scheduling value, input amplitude and time).
2. Residual tests on the one-step residuals of the estimation data: Ljung–Box whiteness,
   cross-correlation with inputs at lags −5 … 30, correlation with candidate features (99 % bands).
3. One extension per cause (:mod:`lpvflow.validate.extensions`), scored by its validation BFR gain,
   the p-value of a signed-rank test on block means of its squared simulation errors against
   the nominal ones (:func:`residuals.block_signed_rank`), and the
   change of BIC/AIC on estimation data.
   A cause whose extension cannot be fitted (e.g. IV-OE diverges, no candidate channel) is listed
   as ``untested`` and can never be named.

Closed-loop data (``controller`` given): every simulation above — nominal and extensions — runs in
the identification loop (:mod:`lpvflow.validate.closed_loop`): the controller acts on the simulated
outputs with the recorded excitation, the quasi-LPV scheduling is recomputed from the simulated
outputs, and an extension's input map, dead time or velocity sign acts on the input the loop
produces. An unstable plant's model cannot be scored by an open-loop simulation, and a model error
that the loop hides or amplifies (an offset the controller fights, friction in a loop that keeps
reversing) is scored as the plant ran.
4. Decision. A cause is *significant* when its gain ≥ ``min_gain`` BFR points and p < ``alpha``.
   The best significant cause is named when it beats the runner-up clearly: its block test against
   the runner-up gives p < 0.05. When other causes reach practically the same gain (within 5 % of it),
   the extension with the fewest added parameters is named (a dead time explained by extra input
   lags is still a dead time); a tie between different causes is ``none``. Otherwise ``none``.
   Structure first (:func:`_structure_first`): a physical fault is named only when it also clearly
   beats every structural fix (orders, basis, scheduling variable, equation constant) that gains.
   One parameter (:mod:`lpvflow.validate.diagnose_consistency`): a dead time named among least-squares
   fits in open loop must hold on the equations after small and after large input moves (a
   likelihood-ratio test per group at α/2); the delay that imitates a rate limiter grows with the move,
   and such a verdict is ``unexplained``.
   A parameter the data cannot determine (a sensor offset whose likelihood-ratio set is unbounded,
   :func:`~lpvflow.validate.extensions_structural._sensor_offset`) is stated in ``not_identifiable``
   instead of a guess (the sensor-offset variant is then not offered).
5. Output noise (open loop): level, colour and LS bias. The nominal structure refitted by output error
   (extension ``output_noise_bias``, consistent under any output noise independent of the input —
   Boonto's thesis Sec. 4.2.2, OE predictor, and 4.4.1–4.4.2) is judged on its own terms by
   :func:`noise_analysis`:
   the noise *level* (:func:`residuals.noise_level`: σ̂ and SNR from the part of the refit's
   simulation error the inputs do not explain),
   its *colour* (AR noise model, BIC order, and the one-step prediction gain of the Box–Jenkins-type
   predictor over the white-noise one on validation data) and the *bias* LS carries
   (:func:`bias_test`: Wald test of θ_OE − θ_LS, LS bias (4.17)–(4.18) of the thesis Sec. 4.3, and the
   change of the frozen frequency response the noise makes, ``noise_bias_change``), and whether the
   simulation error is output noise at all (:func:`prediction_ratio`: an ARX predictor does not
   beat the Box–Jenkins-type one). When LS is biased by output noise (Wald p < ``alpha``,
   noise_bias_change ≥ MATERIAL_CHANGE, ρ ≥ OUTPUT_NOISE_RATIO), step 4 would compare biased fits:
   every extension significant among the LS fits (open loop;
   :func:`~lpvflow.validate.diagnose_noise_round.noise_round`) is refitted by output error — its level
   then chosen by the output-error loss, its delay by the refits' equation error
   (:func:`~lpvflow.validate.extensions_structural.equation_loss`) — and scored against the output-error
   refit of the nominal structure (``refit_ranking``); a dead time chosen there counts as significant
   at p < ``alpha`` whatever its gain (:func:`_dead_time_by_significance`). So is every extension
   refitted when the LS nominal simulation fails (BFR 0 on an output) and its output-error refit gains
   significantly
   (:func:`~lpvflow.validate.diagnose_noise_round.ls_simulation_failed`): against a failed nominal the LS
   ranking shows no gain at all. A structural cause that still gains is named; otherwise
   ``colored_noise`` (biased, and the AR noise model predicts significantly better than white
   noise; the AR coefficients and spectrum are its parameters) or ``output_noise_bias`` (biased,
   white, the refit gains significantly in simulation: "refit by OE/IV"), else ``none``. Open loop, a
   ``none`` or noise verdict gives way to a dead zone or saturation material in one-step prediction
   whose output-error refit keeps its level and loses nothing in simulation
   (:func:`~lpvflow.validate.diagnose_prediction.material_in_prediction`).
   Closed loop: the consistent refit is closed-loop IV (:func:`~lpvflow.validate.extensions.closed_loop_iv`,
   instruments from the model's own loop simulation), and the noise round — every extension refitted
   the same way with its own drive in the loop, a dead time chosen again by that refit's loss
   (:func:`~lpvflow.validate.extensions.input_delay_in_loop`) — runs whenever that refit gains
   significantly; its verdict is ``output_noise_bias`` (no noise model is fitted in the loop).
6. Adequacy: is the error input-explained? Output noise is independent of the inputs, so the
   simulation error of an adequate model has no part a function of the input history explains
   (:func:`input_explained`, on the nominal model or, after a noise round, its output-error refit).
   When that part is significant (gain ≥ ADEQUACY_GAIN·``min_gain``, p < ``alpha``) and no cause was
   named, the verdict is ``unexplained``, with that test as its evidence; a named cause must pass the
   same test with its extended model (:func:`~lpvflow.validate.diagnose_adequacy.final_verdict`).
   Open loop, ``none`` also needs the structure's coefficients to be the same on both splits
   (:mod:`lpvflow.validate.parameter_constancy`); a drifting plant is ``unexplained``.
   A verdict whose model leaves an error that steps with the direction of the output's motion (sensor
   play) is ``unexplained`` (:mod:`lpvflow.validate.diagnose_direction`), and so is one whose model leaves
   the response to a rate limiter's deficit (open loop, :mod:`lpvflow.validate.diagnose_rate`); so is,
   in closed loop, a ``none`` or noise verdict whose model finds the commanded input held in short
   windows (actuator dropouts, :mod:`lpvflow.validate.diagnose_dropouts`) or a dead time whose model's
   error still depends on the direction of motion (sensor play the loop moved into the input,
   :mod:`lpvflow.validate.diagnose_loop_delay`).
   Closed loop: the plant input is fed back from the error, so the error is tested against the loop's
   exogenous history instead — the excitation, set-points and the model's own loop signals, over lags
   that reach the loop's settling time (:mod:`lpvflow.validate.loop_adequacy`). ``none`` means the
   model is adequate, not only that no extension of the vocabulary helped; and a noise verdict needs the
   consistent refit to be adequate (the even input map of the synthetic out-of-vocabulary case,
   seed 1001: LS materially biased, the refit gains 1.4 points, its error still input-explained by
   22 points — unexplained, not colored_noise).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from tqdm.auto import tqdm

from lpvflow.basis import SchedulingRangeWarning
from lpvflow.data import Dataset
from lpvflow.errors import DataError, LpvflowError, ModelError
from lpvflow.experiment.controller import GriddedController, LtiController
from lpvflow.identify.arx import prediction_residuals
from lpvflow.lpvio import LPVIO
from lpvflow.validate import residuals
from lpvflow.validate.closed_loop import Loop
from lpvflow.validate.diagnose_adequacy import (  # noqa: F401  (ADEQUACY_GAIN, INADEQUATE_ALPHA: re-exported)
    ADEQUACY_GAIN,
    INADEQUATE_ALPHA,
    INADEQUATE_GAIN,
    final_verdict,
)
from lpvflow.validate.diagnose_consistency import delay_consistency
from lpvflow.validate.diagnose_direction import direction_verdict
from lpvflow.validate.diagnose_dropouts import dropout_verdict
from lpvflow.validate.diagnose_evidence import evidence, where
from lpvflow.validate.diagnose_loop_delay import loop_delay_verdict
from lpvflow.validate.diagnose_noise_round import noise_round, oe_context, refits_by_output_error
from lpvflow.validate.diagnose_prediction import material_in_prediction
from lpvflow.validate.diagnose_rate import rate_verdict
from lpvflow.validate.diagnose_summary import AMBIGUOUS, NOISE, summary, verdict_parameters
from lpvflow.validate.extensions import (
    EXTENSIONS,
    Candidate,
    Context,
    Fit,
    Structure,
    fit,
    loop_simulator,
)
from lpvflow.validate.extensions_structural import delayed_splits
from lpvflow.validate.metrics import bfr, vaf
from lpvflow.validate.noise_analysis import (  # noqa: F401  (frozen_response, MATERIAL_CHANGE: re-exported)
    FEATURE_LAGS,
    MATERIAL_CHANGE,
    OUTPUT_NOISE_RATIO,
    adequacy_lags,
    explained_within_validation,
    frozen_response,
    input_explained,
    noise_analysis,
    normalised_sq_error,
)

#: Smallest validation split the diagnosis accepts, in samples.
MIN_VALIDATION = 200
#: Gains within this fraction of the best one count as practically equivalent.
EQUIVALENCE = 0.05
#: model_order on top of a named dead time must gain this share of the delay's gain to win
#: (:func:`_delay_before_order`).
DELAY_SHARE = 0.2
#: Smallest noise_bias_change at which an LS winner is checked by output error when the bias is not
#: material (:func:`_confirmed_by_output_error`): above equation noise (0.014–0.017), below 3 % white
#: sensor noise (0.026–0.029). Checking every significant bias refitted friction by output error on
#: 30 dB equation noise and lost it (synthetic friction, seed 1003: +7.0 points among LS fits).
NOTICEABLE_CHANGE = 0.02
#: Significance level of that check (:func:`_confirmed_by_output_error`).
CONFIRM_ALPHA = 0.05


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_dict` is the JSON the CLI writes."""

    bfr_before: list[float]
    bfr_after: list[float]
    vaf_before: list[float]
    vaf_after: list[float]
    cause: str
    parameters: dict
    evidence: list[dict]
    ranking: list[dict]
    summary: str
    where: dict
    refit_ranking: list[dict] = field(default_factory=list)  # the noise round (_choose), else empty
    noise_round: bool = False  # the extensions were refitted consistently (module docstring, step 5)
    noise: dict | None = None  # noise_analysis; None in closed loop or without an OE refit
    adequacy: dict | None = None  # input_explained of the final model (in closed loop: explained_in_loop)
    simulation: str = "open loop"  # or "closed loop": in the identification loop (module docstring)
    loop_scheduling: dict[str, str] = field(default_factory=dict)  # recomputed in the loop
    untested: list[str] = field(default_factory=list)  # extensions that could not be fitted (reasons below)
    unchanged: list[str] = field(default_factory=list)  # tried: the data chose the modelled structure
    untested_reasons: dict[str, str] = field(default_factory=dict)
    #: cause → why the data cannot determine it (stated, never guessed: it cannot be the verdict)
    not_identifiable: dict[str, str] = field(default_factory=dict)
    winner: Candidate | None = field(default=None, repr=False)
    nominal_y_val: np.ndarray | None = field(default=None, repr=False)
    error_spectrum: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        hidden = ("winner", "nominal_y_val", "error_spectrum")
        return {k: v for k, v in self.__dict__.items() if k not in hidden}


def _rank(est: Dataset, val: Dataset, nominal: Fit, candidates: dict[str, Candidate], min_gain: float,
          alpha: float) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Score every candidate against ``nominal`` on the validation split, best gain first."""
    base_loss = normalised_sq_error(val.y, nominal.y_val)
    bfr_nom = bfr(val.y, nominal.y_val)
    losses, ranked = {}, []
    for cause, cand in candidates.items():
        losses[cause] = normalised_sq_error(val.y, cand.fit.y_val)
        gain = float(np.mean(bfr(val.y, cand.fit.y_val) - bfr_nom))
        _, p_value = residuals.block_signed_rank(base_loss, losses[cause])
        n_eff = est.N - cand.fit.model.max_lag
        extra = cand.fit.n_params + cand.choices - nominal.n_params  # a chosen level or delay counts
        ranked.append({
            "cause": cause, "bfr_gain": gain, "p_value": p_value,
            "bic_change": cand.fit.bic + cand.choices * np.log(n_eff) - nominal.bic,
            "aic_change": n_eff * (cand.fit.loss - nominal.loss) + 2 * extra,
            "extra_parameters": extra,
            "parameters": cand.parameters,
            "diverged": cand.fit.diverged,
            "significant": bool(gain >= min_gain and p_value < alpha and not cand.fit.diverged),
        })
    ranked.sort(key=lambda r: -r["bfr_gain"])
    return ranked, losses




def _choose(ranked: list[dict], candidates: dict[str, Candidate], losses: dict[str, np.ndarray]) -> str:
    """The verdict (module docstring, steps 4–5) from the ranking, best gain first.

    Output noise — the decision and why. White sensor noise e on the output makes the equation error
    of the LS (ARX) fit A(q)·e, coloured and correlated with the regressors: the estimate is biased,
    the more so the more the lagged outputs are collinear (tanks FMU at Ts = 1 s, τ ≈ 15 s: 0.5 mm of
    noise on a 35 mm signal costs the nominal model 7 BFR points). Any extension with extra lags or
    parameters then recovers part of that bias on validation (na = 5, nb = 3: +5 to +11 points), so
    comparing LS fits names ``model_order`` on effect-free data and on a hidden dead time. The cause
    is the noise, not the order: refitted by output error (consistent under white output noise), the
    nominal structure reaches 97 % and the higher order adds < 0.5 point. Hence:

    * the extensions are compared on an equal footing, all fitted by output error, when LS is
      biased (diagnose's noise round, ``refit_ranking``; the bias test of :func:`bias_test`); a
      structural cause is named only if it still gains significantly there (tanks given
      na = nb = 1: +13 to +16 points over the output-error nominal fit; a 2-sample dead time on the
      synthetic plant: +5 points);
    * effect-free data with material sensor noise is ``output_noise_bias`` (white) or
      ``colored_noise`` (coloured), not ``none`` (:func:`_noise_verdict`): for a control engineer the
      model *is* wrong — its simulation misses by the LS bias — and the fix (IV/OE with the same
      structure) is exactly what the verdict says. ``none`` is the verdict on effect-free data whose
      noise is immaterial: noise-free, equation-error noise (inside the ARX model set) or sensor
      noise too small for the bias to cost ``min_gain``. That is where the no-false-alarm control
      (≥ 95 % ``none``) is stated;
    * a dead time is the exception to ``min_gain`` there: chosen again by the output-error loss it adds
      no coefficient, so a significant gain of any size names it (:func:`_dead_time_by_significance`:
      the tanks' 3 s dead time gains 9 points noise-free but 0.2 point between output-error fits,
      because a third-order model absorbs 3 samples of delay on a 15 s plant).
    """
    ranked = [r for r in ranked if "ruled_out" not in r]
    significant = [r for r in ranked if r["significant"]]
    if not significant:
        return "none"
    significant_causes = {r["cause"] for r in significant}
    # a tie is reported only between strong gains; small ones (an approximate structure's misfit) are none
    strong_causes = {r["cause"] for r in significant if r["bfr_gain"] >= INADEQUATE_GAIN}
    top, top_gain = significant[0]["cause"], significant[0]["bfr_gain"]
    others = [r for r in ranked if r["cause"] != top and r["bfr_gain"] > 0]
    equivalent = [r["cause"] for r in others if r["bfr_gain"] >= (1 - EQUIVALENCE) * top_gain]
    if equivalent:  # practically the same gain: the extension with the fewest parameters explains it
        peers = [top, *equivalent]
        fewest = min(candidates[c].fit.n_params for c in peers)
        simplest = [c for c in peers if candidates[c].fit.n_params == fewest]
        if len(simplest) > 1:
            return AMBIGUOUS if len([c for c in simplest if c in strong_causes]) > 1 else "none"
        winner = simplest[0]
        return winner if winner in significant_causes else "none"
    if others and residuals.block_signed_rank(losses[others[0]["cause"]], losses[top])[1] >= 0.05:
        # not clearly better than the runner-up: a tie when the runner-up gains significantly too
        return AMBIGUOUS if {top, others[0]["cause"]} <= strong_causes else "none"
    return _structure_first(top, others, candidates, losses, significant_causes)


#: Extensions that change the user's structure, not the plant's physics: orders, basis, scheduling
#: variable, and the equation constant of ``offset`` (a sensor offset is physical).
STRUCTURAL = ("model_order", "scheduling_dependence", "scheduling_variable", "offset")


def _structure_first(top: str, others: list[dict], candidates: dict[str, Candidate],
                     losses: dict[str, np.ndarray], significant_causes: set[str]) -> str:
    """``top``, unless it is a physical fault that does not clearly beat (block test p < 0.05) every
    structural fix with a positive gain: then the best such structural fix when it is significant
    (the user's structure is what is inadequate), else ``none``. A physical fault is named only when
    it explains more than a change of the structure the user chose (otherwise the misfit of an
    approximate structure is named as a dead zone or friction)."""
    if _is_structural(top, candidates):
        return top
    for row in others:
        cause = row["cause"]
        if not _is_structural(cause, candidates):
            continue
        if residuals.block_signed_rank(losses[cause], losses[top])[1] >= 0.05:
            return cause if cause in significant_causes else "none"
    return top


def _is_structural(cause: str, candidates: dict[str, Candidate]) -> bool:
    return cause in STRUCTURAL and candidates[cause].parameters.get("kind") != "sensor"


def _confirmed_by_output_error(cause: str, candidates: dict[str, Candidate], ctx: Context,
                               min_gain: float, alpha: float) -> str:
    """``cause``, or ``none`` when its extension refitted by output error does not gain significantly
    over the output-error refit of the nominal structure.

    Used when LS is significantly but not materially biased (no noise round) and the noise changes
    the LS fit noticeably (NOTICEABLE_CHANGE): a small bias is enough
    for an extension with more lags to gain among LS fits by absorbing it — white sensor noise of 3 %
    on the synthetic plant with the right structure: na = nb = 4 gained 1.0 point (seed 1001).
    A check of a cause already significant among LS fits, not a discovery: the refit must gain
    ≥ ``min_gain`` at p < CONFIRM_ALPHA (friction under 30 dB equation noise, seed 1003: +5.1 points
    refitted, p = 0.0012).
    """
    refit = refits_by_output_error({cause: candidates[cause]}, oe_context(ctx, candidates))
    if cause not in refit:
        return cause
    row = _rank(ctx.est, ctx.val, candidates[NOISE].fit, refit, min_gain, alpha)[0][0]
    return cause if row["bfr_gain"] >= min_gain and row["p_value"] < CONFIRM_ALPHA else "none"


def _noise_verdict(noisy: dict | None, noise: dict | None) -> str:
    """No structural cause in the noise round: ``colored_noise`` when LS is biased and the AR noise
    model predicts significantly better than white noise; ``output_noise_bias`` when LS is biased and
    the output-error refit gains significantly in simulation; else ``none``."""
    if noisy is None:
        return "none"
    if noise is None:  # closed loop: the refit's gain is the evidence
        return NOISE if noisy["significant"] else "none"
    if noise["biased"] and noise["colored"]:
        return "colored_noise"
    return NOISE if noisy["significant"] else "none"


def _judge_noise(ctx: Context, candidates: dict[str, Candidate], noisy: dict | None, min_gain: float,
                 alpha: float) -> dict | None:
    """:func:`noise_analysis` of the output-error refit (open loop), its findings written into the
    refit's ranking row; a refit that removes no material noise bias is ruled out."""
    if ctx.loop is not None or noisy is None:
        return None
    noise = noise_analysis(ctx.est, ctx.val, ctx.nominal, candidates[NOISE].fit, alpha, min_gain,
                            noisy["significant"])
    noisy |= {"bias_p_value": noise["bias"]["p_value"], "colored": noise["colored"]}
    if not noise["biased"]:
        bias = noise["bias"]
        noisy["significant"] = False
        noisy["ruled_out"] = (f"no material noise bias of LS: Wald p = {bias['p_value']:.2g}, frozen "
                              f"response change the noise explains {bias['noise_bias_change']:.3f}")
    return noise


def _decide(ctx: Context, candidates: dict[str, Candidate], ranked: list[dict], losses: dict,
            noisy: dict | None, noise: dict | None, min_gain: float,
            alpha: float) -> tuple[str, dict[str, Candidate], list[dict] | None]:
    """The verdict before the adequacy test (module docstring, steps 4–5): (cause, the candidates it
    names from, the noise round's ranking — None when the round did not run)."""
    refits = noise_round(candidates, ctx, noisy, noise, ranked, min_gain, alpha)
    if refits is None:
        cause = _choose(ranked, candidates, losses)
        suspect = (noise is not None and noise["bias"]["p_value"] < alpha
                   and noise["prediction_ratio"] >= OUTPUT_NOISE_RATIO
                   and noise["bias"]["noise_bias_change"] >= NOTICEABLE_CHANGE)
        if suspect and cause in candidates:
            cause = _confirmed_by_output_error(cause, candidates, ctx, min_gain, alpha)
        cause = _delay_before_order(cause, candidates, ranked, ctx, min_gain, alpha)
        in_prediction = material_in_prediction(ctx, candidates, cause, alpha)
        if in_prediction is None:
            return cause, candidates, None
        return in_prediction.cause, candidates | {in_prediction.cause: in_prediction}, None
    # The noise round (module docstring, step 5; docstring of _choose): every extension refitted
    # consistently, scored against the consistent refit of the nominal structure.
    refit_ranked, refit_losses = _rank(ctx.est, ctx.val, candidates[NOISE].fit, refits, min_gain, alpha)
    _dead_time_by_significance(refit_ranked, alpha)
    cause = _choose(refit_ranked, refits, refit_losses)
    if cause != "none":
        return cause, refits, refit_ranked
    cause = _noise_verdict(noisy, noise)
    in_prediction = material_in_prediction(ctx, candidates, cause, alpha)
    if in_prediction is None:
        return cause, candidates, refit_ranked
    row = _rank(ctx.est, ctx.val, candidates[NOISE].fit, {in_prediction.cause: in_prediction}, min_gain,
                alpha)[0][0]
    refit_ranked = [r for r in refit_ranked if r["cause"] != in_prediction.cause] + [row]
    return in_prediction.cause, candidates | {in_prediction.cause: in_prediction}, refit_ranked


def _dead_time_by_significance(refit_ranked: list[dict], alpha: float) -> None:
    """In the noise round a dead time counts as significant when its consistent refit gains at all
    (> 0 BFR points) at block p < ``alpha``, without ``min_gain``: marked in its row.

    There the delay is chosen again by the consistent estimator's loss (output error, or closed-loop
    IV), a discrete choice that adds no coefficient, so it cannot absorb noise the way extra lags do:
    on the tanks FMU with 1 mm of white sensor noise and no dead time the LS delay gains +4.7 to +7.1
    points (seeds 0–4) and the output-error search keeps the modelled nk every time. What a delay gains
    in simulation is small when the structure's other lags approximate it: a 3 s dead time on the
    tanks (Ts = 1 s, τ ≈ 15 s, na = 3), refitted by output error, +0.16 to +0.24 points at
    p ≤ 8·10⁻⁵ (seeds 0–2) with the estimation loss n_eff·ΔV ≈ −490 at no extra parameter; under
    ``min_gain`` that dead time was named ``output_noise_bias``.
    """
    for row in refit_ranked:
        if (row["cause"] == "input_delay" and row["bfr_gain"] > 0 and row["p_value"] < alpha
                and not row["diverged"]):
            row["significant"] = True


def _delay_before_order(cause: str, candidates: dict[str, Candidate], ranked: list[dict], ctx: Context,
                        min_gain: float, alpha: float) -> str:
    """``input_delay`` instead of ``model_order`` when both gain significantly and the higher order,
    fitted on top of the dead time the data chose, gains nothing significant over the dead time alone,
    or less than DELAY_SHARE of the dead time's own gain (the order then only refines an
    approximate structure: ADIP +3.9 points on top of the dead time's +29.1).

    Extra lags absorb a dead time (na + 2, nb + 2 cover three samples of delay and also the small
    misfit of an approximate structure), so the order extension can out-gain the dead time that is
    there: closed-loop ADIP with a 15 ms (3-sample) dead time, model_order +33.2 and input_delay
    +29.1 points. The nested comparison asks whether the order adds anything once the delay is right.
    """
    significant = {r["cause"] for r in ranked if r["significant"]}
    if cause != "model_order" or "input_delay" not in significant:
        return cause
    delay = candidates["input_delay"]
    if delay.model_map is None:
        delayed = replace(ctx, structure=replace(ctx.structure, nk=np.asarray(delay.parameters["nk"])),
                          nominal=delay.fit)
    else:  # the inputs and scheduling images delayed in the data, the structure's nk kept
        est, val = delayed_splits(ctx, delay.model_map)
        delayed = replace(ctx, est=est, val=val, nominal=delay.fit)
    try:
        order = EXTENSIONS["model_order"](delayed)
    except LpvflowError:
        return cause
    row = _rank(ctx.est, ctx.val, delay.fit, {"model_order": order}, min_gain, alpha)[0][0]
    delay_gain = next(r["bfr_gain"] for r in ranked if r["cause"] == "input_delay")
    secondary = not row["significant"] or row["bfr_gain"] < DELAY_SHARE * delay_gain
    return "input_delay" if secondary else cause


def diagnose(
    data: Dataset, structure: Structure, channels: dict[str, np.ndarray] | None = None,
    split: float = 0.5, alpha: float = 1e-3, min_gain: float = 1.0, causes: list[str] | None = None,
    controller: LtiController | GriddedController | None = None, scheduling: Mapping[str, str] | None = None,
    model: LPVIO | None = None, progress: bool = False, setpoints: np.ndarray | None = None,
    remove_trim: bool = False,
) -> Diagnosis:
    """Fit ``structure`` on the first ``split`` of ``data``, diagnose its validation simulation.

    Args:
        channels: other recorded signals (full length) that may be scheduling variables.
        alpha: significance level of the validation-error test; min_gain: smallest BFR gain (points)
            that counts.
        causes: restrict the extensions tried (default: all of the vocabulary).
        controller: the LTI or gridded controller the data were recorded under: every model is then
            simulated in that loop (module docstring), the excitation recovered as u − K(y)
            (:class:`~lpvflow.validate.closed_loop.Loop`; with ``data.offsets`` the controller reads the
            outputs plus the removed means).
        scheduling: scheduling column → expression in the output names (the experiment's sidecar
            ``scheduling``), recomputed from the simulated outputs in the loop; columns without an
            expression are taken as recorded.
        model: the user's identified model of ``structure`` (``Structure.of_model``): it is the
            nominal model as it is — its validation simulation is the reported nominal fit — instead
            of the structure refitted on the estimation split; the extensions are fitted there.
        progress: show a tqdm bar over the extensions (the CLI does on a terminal).
        setpoints: with ``controller``, its recorded set-points (N, outputs it reads; NaN where none).
        remove_trim: with ``controller``, the data's inputs are the plant's minus the controller's trim
            (``[identify] remove_trim``); every loop takes the trim at its own scheduling off the command.
    """
    channels = channels or {}
    for name, values in channels.items():
        if len(values) != data.N or not np.all(np.isfinite(values)):
            raise DataError(f"candidate channel {name!r} must have {data.N} finite samples")
    est, val = data.split(split)
    if val.N < MIN_VALIDATION:
        raise DataError(f"the validation part has {val.N} samples; diagnosis needs at least "
                        f"{MIN_VALIDATION}: record longer data or change the split")
    unknown = sorted(set(causes or []) - set(EXTENSIONS))
    if unknown:
        raise DataError(f"unknown cause(s) {unknown}; choose from {sorted(EXTENSIONS)}")
    k = est.N
    split_channels = {c: (np.asarray(v, float)[:k], np.asarray(v, float)[k:]) for c, v in channels.items()}
    loop = (Loop.from_record(data, controller, scheduling, setpoints, remove_trim)
            if controller is not None else None)
    if model is None:
        basis = structure.basis_for(data.p.shape[1])
        nominal = fit(est, val, structure.na, structure.nb, structure.nk, basis, structure.form,
                      loop_simulator(est, val, loop))
    else:
        nominal = Fit.of_model(model, est, val, loop_simulator(est, val, loop))
    ctx = Context(est, val, structure, nominal, split_channels, loop)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SchedulingRangeWarning)
        candidates = {}
        tried = list(causes or EXTENSIONS)
        untested_reasons: dict[str, str] = {}
        for cause in tqdm(tried, desc="diagnose: fitting extensions", unit="cause", disable=not progress):
            try:
                cand = EXTENSIONS[cause](ctx)
            except LpvflowError as exc:  # e.g. a richer structure the data cannot identify
                untested_reasons[cause] = str(exc)
                continue
            if cand is not None:
                candidates[cause] = cand
    bfr_nom = bfr(val.y, nominal.y_val)
    ranked, losses = _rank(est, val, nominal, candidates, min_gain, alpha)
    noisy = next((r for r in ranked if r["cause"] == NOISE), None)
    noise = _judge_noise(ctx, candidates, noisy, min_gain, alpha)
    cause, pool, refit_ranked = _decide(ctx, candidates, ranked, losses, noisy, noise, min_gain, alpha)
    noise_round = refit_ranked is not None
    used = refit_ranked if noise_round else ranked
    final = candidates[NOISE].fit if noise_round else nominal
    cause, adequacy, pool = final_verdict(ctx, cause, final, pool, used, min_gain, alpha)
    cause, adequacy = _one_dead_time(ctx, cause, pool, noise_round, adequacy, alpha)
    cause, adequacy = direction_verdict(ctx, cause, final, pool, adequacy, alpha)
    cause, adequacy = rate_verdict(ctx, cause, final, pool, adequacy, alpha)
    cause, adequacy = dropout_verdict(ctx, cause, final, adequacy, alpha)
    cause, adequacy = loop_delay_verdict(ctx, cause, pool, adequacy, alpha)
    _refuse_diverged(cause, nominal, candidates)
    winner = pool.get(NOISE if cause == "colored_noise" else cause)
    after = winner.fit.y_val if winner else nominal.y_val
    result = Diagnosis(
        bfr_before=bfr_nom.tolist(), bfr_after=bfr(val.y, after).tolist(),
        vaf_before=vaf(val.y, nominal.y_val).tolist(), vaf_after=vaf(val.y, after).tolist(),
        cause=cause, parameters=verdict_parameters(cause, winner, noise, adequacy, used),
        evidence=evidence(est, prediction_residuals(nominal.model, est), split_channels),
        ranking=ranked, refit_ranking=refit_ranked or [], noise_round=noise_round, noise=noise,
        adequacy=adequacy, summary="",
        where=where(val, val.y - nominal.y_val), winner=winner,
        simulation="open loop" if loop is None else "closed loop",
        loop_scheduling=dict(loop.scheduling) if loop is not None else {},
        untested=list(untested_reasons), untested_reasons=untested_reasons,
        not_identifiable=dict(ctx.not_identifiable),
        unchanged=[c for c in tried if c not in candidates and c not in untested_reasons],
        nominal_y_val=nominal.y_val,
        error_spectrum=residuals.error_spectrum(val.y[:, 0] - nominal.y_val[:, 0], val.Ts),
    )
    result.summary = summary(result, winner)
    return result


def _one_dead_time(ctx: Context, cause: str, pool: dict[str, Candidate], noise_round: bool,
                   adequacy: dict | None, alpha: float) -> tuple[str, dict | None]:
    """A dead time named among least-squares fits on open-loop data must be one dead time: re-estimated
    on the equations after small and after large input moves, the named delay must be inside the
    likelihood-ratio set of each at ``alpha``/2
    (:func:`~lpvflow.validate.diagnose_consistency.delay_consistency`); otherwise the delay stands in
    for an effect outside the vocabulary (a rate limiter, whose equivalent delay grows with the move)
    and the cause is ``unexplained``."""
    if cause != "input_delay" or noise_round or ctx.loop is not None:
        return cause, adequacy
    check = delay_consistency(ctx, pool[cause], alpha)
    if check is None or not check["inconsistent"]:
        return cause, adequacy
    return "unexplained", (adequacy or {}) | {"inconsistent_parameter": check}


def _refuse_diverged(cause: str, nominal: Fit, candidates: dict[str, Candidate]) -> None:
    """A verdict that rests on a diverged simulation is an error with its reason, never ``none``:
    the nominal model's validation simulation (for ``none``) or the consistent refit's (for a noise
    verdict) left ten times the data's extent (:func:`~lpvflow.validate.extensions.bounded`)."""
    refit = candidates.get(NOISE)
    if cause == "none" and nominal.diverged:
        raise ModelError("the nominal model's validation simulation diverges, so its adequacy cannot be "
                         "judged: check the orders and the basis, remove the signals' offsets "
                         "(--remove-offsets; in a design [identify] remove_offsets), or give the "
                         "controller of closed-loop data (--controller; in a design [experiment] controller)")
    if cause in (NOISE, "colored_noise") and refit is not None and refit.fit.diverged:
        raise ModelError("the output-error refit of the nominal structure diverges in simulation, so the "
                         "noise cannot be judged: check the orders and the basis")
