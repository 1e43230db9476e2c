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


def test_coulomb_friction_on_the_maglev_under_sensor_noise_is_named_on_the_disk_that_shows_it():
    """Maglev, 0.02 N of Coulomb friction on both disks, 2 µm position noise, in the example's loop
    (seed 0; it was ``model_order``). Two causes: the closed-loop IV refit of the nominal structure
    failed its instrument test (ζᵀφ looked singular through the poly:2 basis' collinearity), so no
    consistent round ran; and the friction output was chosen by the one-step loss on the noisy
    measured sign (the upper disk). Now the round runs and the friction extension, on the disk whose
    friction model simulates best in the loop after closed-loop IV, gains over the refit."""
    _, result = _diagnose("maglev", "Coulomb friction 0.02 N", 0)
    assert result.noise_round
    assert result.cause == "friction", result.refit_ranking
    assert result.parameters["output"] == "lower_disk_position"
    row = next(r for r in result.refit_ranking if r["cause"] == "friction")
    assert row["bfr_gain"] > 3 and row["p_value"] < 1e-3
