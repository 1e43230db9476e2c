"""The words of a diagnosis: the parameters a verdict reports and its one-line summary."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lpvflow.validate.extensions import Candidate

if TYPE_CHECKING:
    from lpvflow.validate.diagnose import Diagnosis

#: The extension that re-estimates the nominal structure consistently (output error / closed-loop IV).
NOISE = "output_noise_bias"
#: The verdict on two significant extensions of different causes that no test separates.
AMBIGUOUS = "ambiguous"


def verdict_parameters(cause: str, winner: Candidate | None, noise: dict | None, adequacy: dict | None,
                ranked: list[dict]) -> dict:
    """The parameters of the verdict: the extension's, the noise level and spectrum for a noise
    verdict, the adequacy test for ``unexplained``, both tied extensions for ``ambiguous``."""
    if cause == "unexplained":
        params = {"input_explained_bfr_gain": adequacy["bfr_gain"], "p_value": adequacy["p_value"]}
        for key in ("unnamed_extension", "partial_extension", "inconsistent_parameter", "motion_direction",
                    "held_input", "delay_direction", "input_rate"):
            if key in adequacy:
                params[key] = adequacy[key]
        return params
    if cause == AMBIGUOUS:
        tied = [r for r in ranked if r["significant"] and "ruled_out" not in r][:2]
        return {"candidates": [{"cause": r["cause"], "bfr_gain": r["bfr_gain"], "p_value": r["p_value"],
                                "parameters": r["parameters"]} for r in tied]}
    params = dict(winner.parameters) if winner else {}
    if cause in (NOISE, "colored_noise") and noise is not None:
        level = noise["level"]
        params |= {"relative_noise": scalar(level["relative_noise"]), "snr_db": scalar(level["snr_db"]),
                   "frozen_response_change": noise["bias"]["frozen_response_change"]}
        if cause == "colored_noise":
            models = noise["noise_model"]
            params |= {"ar": scalar([m["ar"] for m in models]),
                       "spectrum": scalar([m["spectrum"] for m in models])}
    return params


def scalar(values: list):
    """A per-output list as its only element for one output."""
    return values[0] if len(values) == 1 else values



def summary(result: Diagnosis, winner: Candidate | None) -> str:
    """The verdict in one line, followed by what the data cannot determine (``not_identifiable``)."""
    return "; ".join([_verdict_line(result, winner), *result.not_identifiable.values()])


def _verdict_line(result: Diagnosis, winner: Candidate | None) -> str:
    before, after = np.mean(result.bfr_before), np.mean(result.bfr_after)
    if result.cause == AMBIGUOUS:
        a, b = result.parameters["candidates"]
        return (f"validation BFR {before:.1f} %; two extensions gain and no test separates them: "
                f"{a['cause']} (+{a['bfr_gain']:.1f} points) and {b['cause']} (+{b['bfr_gain']:.1f}): "
                "cause ambiguous")
    if result.cause == "unexplained" and "unnamed_extension" in result.parameters:
        ext = result.parameters["unnamed_extension"]
        return (f"validation BFR {before:.1f} %; the model is inadequate — {ext['cause']} gains "
                f"{ext['bfr_gain']:.1f} points (p = {ext['p_value']:.2g}) — but no cause of the vocabulary "
                "is significant and unambiguous: cause unexplained")
    history = ("the input history" if result.simulation == "open loop"
               else "the loop's excitation and set-points (and the model's loop signals)")
    if result.cause == "unexplained" and "partial_extension" in result.parameters:
        ext = result.parameters["partial_extension"]
        left = ext["left_input_explained_bfr_gain"]
        return (f"validation BFR {before:.1f} %; {ext['cause']} gains {ext['bfr_gain']:.1f} points but its "
                f"model still leaves an error {history} explains (+{left:.1f} points, "
                f"p = {ext['p_value']:.2g}): a partial explanation, cause unexplained")
    if result.cause == "unexplained" and "inconsistent_parameter" in result.parameters:
        check = result.parameters["inconsistent_parameter"]
        return (f"validation BFR {before:.1f} %; {check['cause']} gains, but the named {check['parameter']} "
                f"{check['named']} does not hold after small and large input moves alike (re-estimated "
                f"{check['small_moves']} and {check['large_moves']}, likelihood ratios "
                f"{', '.join(f'{v:.1f}' for v in check['likelihood_ratio'])} at α = {check['alpha']:g}): "
                "no single dead time explains the data, cause unexplained")
    if result.cause == "unexplained" and "motion_direction" in result.parameters:
        test = result.parameters["motion_direction"]
        return (f"validation BFR {before:.1f} %; the error of the {test['cause']} model steps with the "
                f"direction of the output's motion ({test['step_over_sigma']:.1f} standard deviations of its "
                f"unpredictable part, t = {test['t']:.1f}), as sensor play or hysteresis makes it; no cause "
                "of the vocabulary explains that: cause unexplained")
    if result.cause == "unexplained" and "delay_direction" in result.parameters:
        test = result.parameters["delay_direction"]
        return (f"validation BFR {before:.1f} %; a dead time (nk = {test['nk']}) gains, but its model's "
                f"error still depends on the direction of the output's motion (t = {test['t']:.1f}, bound "
                f"{test['bound']:.1f}), as sensor play makes it; no single dead time explains the data: "
                "cause unexplained")
    if result.cause == "unexplained" and "held_input" in result.parameters:
        test = result.parameters["held_input"]
        return (f"validation BFR {before:.1f} %; the {test['cause']} model's one-step errors show the "
                f"commanded {test['input']} held at its last value in {test['windows']} short windows "
                f"(likelihood ratio up to {test['largest_ratio']:.0f}, bound {test['bound']:.1f}), as "
                "actuator dropouts make them; no cause of the vocabulary explains that: cause unexplained")
    if result.cause == "unexplained" and "input_rate" in result.parameters:
        test = result.parameters["input_rate"]
        return (f"validation BFR {before:.1f} %; the error of the {test['cause']} model follows the lag "
                f"of a rate-limited input {test['input']} ({test['size_over_sigma']:.2f} standard deviations "
                f"of its unpredictable part, t = {test['t']:.1f}), as an actuator rate limit makes it; no "
                "cause of the vocabulary explains that: cause unexplained")
    if result.cause == "unexplained":
        a = result.adequacy
        return (f"validation BFR {before:.1f} %; the simulation error is larger than the output noise "
                f"explains — a correction from {history} alone gains {a['bfr_gain']:.1f} points "
                f"(p = {a['p_value']:.2g}) — and no extension of the vocabulary gains significantly: "
                "cause unexplained")
    if winner is None:
        tested = ", ".join(r["cause"] for r in result.ranking) or "nothing"
        return (f"validation BFR {before:.1f} %; no extension gives a significant, unambiguous gain "
                f"(tested: {tested}) and the simulation error is not explained by the inputs: cause none")
    verb = "raises" if after >= before else "lowers"
    text = (f"{winner.description} {verb} validation BFR from {before:.1f} % to {after:.1f} % "
            f"(cause: {result.cause})")
    if result.cause == "colored_noise":
        order = max(m["ar_order"] for m in result.noise["noise_model"])
        text += (f"; coloured output noise (AR order {order}, "
                 f"SNR {np.mean(result.parameters['snr_db']):.1f} dB) biases least squares")
    elif result.cause == NOISE and result.noise is not None:
        text += (f"; white output noise (SNR {np.mean(result.parameters['snr_db']):.1f} dB) biases least "
                 "squares: refit by output error or IV")
    elif result.noise_round:
        text += "; output noise biases least squares, so every model was refitted by output error"
    return text
