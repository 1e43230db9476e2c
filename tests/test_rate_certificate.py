"""The robustness stage's moving-parameter line (lpvflow.pipeline.rate_certificate, report_robustness)."""

import math

import numpy as np
import pytest

from lpvflow.pipeline.rate_certificate import scheduling_signal
from lpvflow.pipeline.report_robustness import rate_statement
from lpvflow.pipeline.report_text import DisplayUnit

ADIP = ["sin(arm_angle)", "1/(1 - 0.3785*cos(arm_angle)**2)", "cos(arm_angle)/(1 - 0.3785*cos(arm_angle)**2)"]


def test_the_scheduling_signal_is_the_one_output_every_expression_reads():
    assert scheduling_signal(ADIP, ["arm_angle", "pendulum_angle"]) == "arm_angle"
    assert scheduling_signal(["lower_level"], ["lower_level"]) == "lower_level"  # the output itself
    assert scheduling_signal([*ADIP, "pendulum_angle**2"], ["arm_angle", "pendulum_angle"]) is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_rate_line_converts_per_sample_to_display_units_per_second(seed):
    rng = np.random.default_rng(seed)
    Ts, peak = float(rng.choice([0.002, 0.005, 0.01])), float(rng.uniform(1e-3, 5e-3))
    rates = [peak / 16, peak / 4, peak, None]
    cert = {"signal": "arm_angle", "peak_per_sample": peak, "peak_scenario": "arm to -70 deg", "Ts": Ts,
            "rates": rates, "reason": "not certified at ν = … per sample: block of 16 states"}
    units = {"arm_angle": DisplayUnit.of("rad")}

    def speed(per_sample: float) -> str:
        return f"{math.degrees(per_sample) / Ts:.3g} °/s"

    tail = f"the fastest verify scenario (arm to -70 deg) peaks at {speed(peak)}"
    certified = {"largest": rates[1], "certified": [True, True, False]}
    line = rate_statement({"rate_certificate": cert | certified}, units)
    assert line == f"stability certified for arm_angle rates up to {speed(rates[1])}; {tail}"
    line = rate_statement({"rate_certificate": cert | {"largest": 0.0, "certified": [False]}}, units)
    assert line.startswith(f"stability not certified for arm_angle changing even at {speed(rates[0])} ")
    assert "block of 16 states" in line and line.endswith(tail)
    line = rate_statement({"rate_certificate": cert | {"largest": None, "certified": [True] * 4}}, units)
    assert line == f"stability certified for arm_angle changing at any rate; {tail}"
    assert rate_statement({"rate_certificate_note": "not assessed: why"}, units) == \
        "moving scheduling: not assessed: why"
    assert rate_statement({}, units) == ""
