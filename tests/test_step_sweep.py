"""The largest step a controller holds (lpvflow.pipeline.step_sweep): bisection on the ADIP FMU."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lpvflow.errors import DataError
from lpvflow.pipeline.scenarios import Loop, Requirements, Scenario, Signal
from lpvflow.pipeline.step_sweep import (
    DEFAULT_RESOLUTION,
    largest_held_step,
    scaled_step,
    step_is_held,
)
from tests.test_antiwindup import ADIP, upright_controller

LOOP = Loop(("arm_angle", "pendulum_angle"), ("voltage",), ("sin(arm_angle)",),
            actuator_limits={"voltage": (-10.0, 10.0)})
#: The bundled design's +75° arm step with issue 7's specification.
TEMPLATE = Scenario("arm to +75 deg", 4.0, reference={"arm_angle": Signal(steps=((0.5, 1.309),))},
                    settling_band={"arm_angle": 0.0175}, output_bounds={"pendulum_angle": (-0.5, 0.5)},
                    requirements=Requirements(1.5, 0.0349, {"pendulum_angle": 0.0175}))


@pytest.fixture(scope="module")
def lti_controller():
    """The H∞ controller at the upright point (an LTI controller on the exact linearization)."""
    return upright_controller()


@pytest.mark.parametrize("criterion", ["bounded", "passes"])
def test_the_largest_held_step_is_held_and_one_resolution_more_is_not(lti_controller, criterion):
    amplitude = largest_held_step(lti_controller, ADIP, LOOP, TEMPLATE, criterion=criterion)
    assert 0.0 < amplitude < 1.309  # the LTI controller holds some steps, not the 75° one
    held = step_is_held(lti_controller, ADIP, LOOP, scaled_step(TEMPLATE, "arm_angle", amplitude), criterion)
    more = scaled_step(TEMPLATE, "arm_angle", amplitude + DEFAULT_RESOLUTION)
    assert held and not step_is_held(lti_controller, ADIP, LOOP, more, criterion)


def test_holding_the_bounds_is_easier_than_meeting_the_specification(lti_controller):
    """Losing the pendulum is a stricter failure than missing 1.5 s: the bounded sweep reaches further."""
    bounded = largest_held_step(lti_controller, ADIP, LOOP, TEMPLATE, criterion="bounded")
    passing = largest_held_step(lti_controller, ADIP, LOOP, TEMPLATE, criterion="passes")
    assert bounded > passing + DEFAULT_RESOLUTION


def test_bisection_brackets_the_threshold_within_the_resolution():
    tried = []

    def judge(scenario: Scenario) -> bool:
        ((_, size),) = scenario.reference["arm_angle"].steps
        tried.append(size)
        return abs(size) <= 0.7

    negative = Scenario("arm to -75 deg", 4.0, reference={"arm_angle": Signal(steps=((0.5, -1.309),))})
    amplitude = largest_held_step(None, ADIP, LOOP, negative, resolution=0.01, held=judge)
    assert 0.7 - 0.01 <= amplitude <= 0.7
    assert all(size < 0 for size in tried)  # the template's sign is kept
    assert len(tried) <= math.ceil(math.log2(1.309 / 0.01)) + 1
    assert largest_held_step(None, ADIP, LOOP, negative, held=lambda s: True) == 1.309
    assert largest_held_step(None, ADIP, LOOP, negative, held=lambda s: False) == 0.0
    assert largest_held_step(None, ADIP, LOOP, negative, max_step=0.5, held=judge) == 0.5


def test_scaled_step_keeps_everything_but_the_step_size():
    scaled = scaled_step(TEMPLATE, "arm_angle", 0.25)
    assert scaled.reference["arm_angle"].steps == ((0.5, 0.25),)
    assert (scaled.duration, scaled.output_bounds, scaled.requirements) == (
        TEMPLATE.duration, TEMPLATE.output_bounds, TEMPLATE.requirements)
    assert np.isclose(scaled.reference["arm_angle"].sample(np.array([4.0]))[0], 0.25)


@pytest.mark.parametrize(("template", "kwargs", "message"), [
    (Scenario("two", 1.0, reference={"arm_angle": Signal(steps=((0.1, 1.0), (0.5, 1.0)))}), {},
     "must be one step"),
    (Scenario("none", 1.0, settling_band={"arm_angle": 0.1}), {}, "exactly one output with a reference step"),
    (TEMPLATE, {"criterion": "settled"}, "unknown step-sweep criterion 'settled'"),
    (TEMPLATE, {"resolution": 0.0}, "resolution = 0.0 must be a positive step size"),
])
def test_bad_input_is_one_clear_line(template, kwargs, message):
    with pytest.raises(DataError, match=message):
        largest_held_step(None, ADIP, LOOP, template, held=lambda s: True, **kwargs)


def test_the_verify_stage_records_the_largest_step_each_controller_holds(tmp_path, lti_controller):
    """[verify] largest_step: the stage runs the sweep for the LPV controller and the baseline, and the
    summary card states it."""
    from lpvflow.pipeline import stages
    from lpvflow.pipeline.config import check_table
    from lpvflow.pipeline.report_card import summary_card

    lti_controller.save(tmp_path / "controller.json")
    lti_controller.save(tmp_path / "baseline.json")
    loop = {"measured": ["arm_angle", "pendulum_angle"], "actuated": ["voltage"],
            "scheduling": ["sin(arm_angle)"], "actuator_limits": {"voltage": [-10.0, 10.0]}}
    step = {"name": "arm to +75 deg", "duration": 4.0, "reference": {"arm_angle": {"steps": [[0.5, 1.309]]}},
            "settling_band": {"arm_angle": 0.0175}, "output_bounds": {"pendulum_angle": [-0.5, 0.5]}}
    verify = check_table("verify", {"loop": loop, "scenario": [step], "largest_step": {
        "scenario": "arm to +75 deg", "criterion": "bounded"}}, "design.toml")  # parsed as a design file's
    config = {"design": {"plant": str(ADIP)}, "verify": verify}
    outputs, _ = stages.verify(stages.StageContext(tmp_path, config))
    record = outputs["largest_held_step"]
    assert record["output"] == "arm_angle" and record["criterion"] == "bounded"
    # the upright controller loses the pendulum on the full 75° step (the scenario's own verdict) ...
    assert not outputs["scenarios"][0]["controller"]["stable"]
    # ... but holds a smaller one; the same controller twice gives the same amplitude
    assert 0.0 < record["baseline"] < 1.309 and record["lpv"] == record["baseline"]
    summary = {"name": "t", "stages": {"verify": {"status": "ran", "outputs": outputs}}}
    assert f"{math.degrees(record['baseline']):.1f}" in summary_card(summary, {"arm_angle": "rad"})

    config["verify"] = dataclasses.replace(verify, largest_step={"scenario": "arm to +80 deg",
                                                                 "criterion": "bounded"})
    with pytest.raises(DataError, match="names no scenario; known: \\['arm to \\+75 deg'\\]"):
        stages.verify(stages.StageContext(tmp_path, config))
