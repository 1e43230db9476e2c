"""Input maps on the plant bench (tests/diagnosis_fmu_cases.py): the decision when the LS nominal
model's simulation fails, checked on the record it was found on and on held-out seeds."""

from __future__ import annotations

import pytest

from lpvflow.validate.diagnose import diagnose
from tests.diagnosis_fmu_cases import make_record, outcome


def _diagnose(plant: str, effect: str, seed: int):
    record = make_record(plant, effect, seed)
    return record, diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())


def test_a_failed_ls_nominal_simulation_sends_every_extension_to_the_output_error_round():
    """Pump saturation 8 V under 0.2 mm level noise, seed 0: the LS nominal model simulates at 0 %
    on validation, so no LS extension can show a gain (BFR is floored at 0); its output-error refit
    does not fail. Every extension is refitted by output error and scored against that refit: the
    saturation is named with its limit (it was ``unexplained``)."""
    record, result = _diagnose("tanks", "pump saturation 8 V", 0)
    assert result.bfr_before[0] == 0.0  # the case: the LS nominal simulation fails
    assert result.noise_round
    assert {r["cause"] for r in result.refit_ranking} >= {"input_nonlinearity", "model_order", "backlash"}
    assert result.cause == "input_nonlinearity", result.refit_ranking
    assert result.parameters["kind"] == "saturation"
    assert outcome(record, result.cause, result.parameters) == "right"  # limit within 20 % of 8 V
    assert result.bfr_after[0] > 90


@pytest.mark.parametrize("seed", [1, 3])
def test_a_working_ls_nominal_keeps_the_ls_ranking(seed):
    """The same effect on records whose LS nominal simulation works (seed 1 of the bench, seed 3
    held out): no output-error round, the saturation named from the LS ranking."""
    record, result = _diagnose("tanks", "pump saturation 8 V", seed)
    assert result.bfr_before[0] > 0
    assert not result.noise_round
    assert outcome(record, result.cause, result.parameters) == "right", result.ranking
