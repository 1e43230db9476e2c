"""Causes of misdiagnosis on the plant bench (tests/diagnosis_fmu_cases.py), each fixed and checked on
records of seeds other than the ones the cause was found on (benchmarks/README.md, 'Diagnosis on
plant records')."""

from __future__ import annotations

import numpy as np
import pytest

from lpvflow.validate.diagnose import diagnose
from lpvflow.validate.noise_analysis import features
from tests.diagnosis_fmu_cases import PLANTS, make_record


def test_adequacy_features_do_not_explain_the_noise_of_a_measured_scheduling_signal():
    """A quasi-LPV scheduling signal is a measured output, p = s + n with the output's sensor noise
    n: a regression of n on the features (fitted on one half, applied to the other) must not predict
    it — the features take p one sample late (with p(k), n was predicted almost exactly)."""
    rng = np.random.default_rng(7)
    n_samples = 4000
    u = rng.normal(size=(n_samples, 1))
    s = np.convolve(u[:, 0], 0.1 * 0.9 ** np.arange(60))[:n_samples]  # a slow output, noise-free
    noise = 0.05 * rng.normal(size=n_samples)
    f = features(u, (s + noise)[:, None], 5)
    half = n_samples // 2
    coef = np.linalg.lstsq(f[10:half], noise[10:half], rcond=None)[0]
    predicted = f[half:] @ coef
    assert abs(np.corrcoef(predicted, noise[half:])[0, 1]) < 0.1


@pytest.mark.parametrize("seed", [5, 6])
def test_white_level_noise_on_the_tanks_is_output_noise_bias_with_its_level(seed):
    """Tanks, y = p = the lower level with 1 mm of white sensor noise (on top of the bench's 0.2 mm).
    The adequacy test regressed the output-error refit's error on features in p(k), i.e. on the noise
    itself: 3.6 points "input-explained" and the verdict unexplained (seeds 0–3), the level estimated
    at about half the truth. Now: output_noise_bias, σ within 25 % of √(1² + 0.2²) mm."""
    record = make_record("tanks", "level sensor noise 1 mm", seed)
    result = diagnose(record.data, record.structure, record.channels)
    assert result.cause == "output_noise_bias", (result.cause, result.adequacy)
    truth = np.hypot(1e-3, PLANTS["tanks"].noise["lower_level"])
    assert result.noise["level"]["noise_std"][0] == pytest.approx(truth, rel=0.25)


@pytest.mark.parametrize("seed", [2, 4])
def test_white_pressure_noise_on_the_airpath_is_white(seed):
    """Airpath, 4 kPa of white noise on the manifold pressure, na = nb = 1, poly:2. The noise was read
    from the refit's error minus what input lags 0–20 explain; the model error of the valve lift
    (held 50–200 samples) stayed in it and looked coloured: colored_noise (seeds 1, 2). With the
    adequacy test's regressors (lags to the settling time, the model's own simulation) it is white."""
    record = make_record("airpath", "pressure sensor noise 4 kPa", seed)
    result = diagnose(record.data, record.structure, record.channels)
    assert result.cause == "output_noise_bias", (result.cause, result.noise["noise_model"][0]["ar"])
    truth = np.hypot(4.0, PLANTS["airpath"].noise["manifold_pressure"])
    assert result.noise["level"]["noise_std"][0] == pytest.approx(truth, rel=0.25)


@pytest.mark.parametrize("seed", [5, 6])
def test_a_sensor_offset_that_the_data_cannot_determine_is_stated_not_guessed(seed):
    """Tanks, y = p = the lower level (poly:3), 1 cm sensor offset: every offset from about −19 to +2 cm
    fits the estimation data equally well (likelihood-ratio set at 10⁻³), because the offset shifts p
    too and the scheduling dependence absorbs it. The diagnosis says so and does not name an offset
    (bench seeds 0–2: output_noise_bias without a word on the offset; held-out seeds here)."""
    record = make_record("tanks", "level sensor offset 1 cm", seed)
    result = diagnose(record.data, record.structure, record.channels, causes=["offset"])
    statement = result.not_identifiable["offset"]
    assert "not identifiable" in statement and "scheduling signal is this measured output" in statement
    assert statement in result.summary
    assert result.cause != "offset" or result.parameters.get("kind") != "sensor"


def test_a_sensor_offset_the_data_determine_is_named_small_or_large():
    """Synthetic plant with p independent of y, sensor offsets of random size from 1 % to 50 % of the
    output's extent: the likelihood-ratio set is bounded (nothing stated not identifiable), the offset
    is named and within 20 % (the bench's case is one size, 0.5 ≈ 7 %)."""
    from dataclasses import replace

    from tests.diagnosis_cases import NOMINAL, make_case

    rng = np.random.default_rng(35)
    for seed in (3000, 3001, 3002):
        data, channels, _ = make_case("none", seed=seed, snr_db=30.0)
        offset = float(rng.uniform(0.01, 0.5)) * float(np.max(np.abs(data.y)))
        result = diagnose(replace(data, y=data.y + offset), NOMINAL, channels, causes=["offset"])
        assert result.not_identifiable == {}
        assert result.cause == "offset", (seed, offset, result.ranking)
        assert result.parameters["output_offset"] == pytest.approx(offset, rel=0.2)


@pytest.mark.parametrize("seed", [3, 4])
def test_an_angle_sensor_offset_in_the_loop_is_a_sensor_offset_on_both_angles(seed):
    """ADIP under its LTI controller, 10 mrad on both measured angles (the FMU's effect_sensor_offset):
    the controller reads the offset angles, the dynamics act on the true ones. The closed-loop offset
    extension fits that sensor offset, not an equation constant (whose output-equivalent came out
    10.1 and 11.7–11.9 mrad on these seeds and 12.2 mrad on the pendulum on seed 2), and the saved
    map is the sensor offset the loop simulation applies."""
    record = make_record("adip", "angle sensor offset 10 mrad", seed)
    result = diagnose(record.data, record.structure, record.channels, **record.diagnose_arguments())
    assert result.cause == "offset", result.summary
    assert result.parameters["kind"] == "sensor"
    assert result.parameters["output_offset"] == pytest.approx([0.01, 0.01], rel=0.2)
    assert result.winner.model_map.kind == "sensor_offset"


def test_a_physical_fault_is_named_only_when_it_beats_every_structural_fix():
    """Structure first: friction on top of the ranking is named only when its squared simulation errors
    are clearly smaller (block test) than those of every structural fix with a positive gain; when a
    change of order does as well, the order is named (or none when the order is not significant).
    A sensor offset is physical, an equation constant structural. Random losses, fixed seed."""
    from types import SimpleNamespace

    from lpvflow.validate.diagnose import _structure_first

    rng = np.random.default_rng(35)
    kind = {"friction": {}, "model_order": {}, "offset": {"kind": "sensor"}}
    candidates = {c: SimpleNamespace(parameters=p) for c, p in kind.items()}
    for _ in range(5):
        base = rng.exponential(size=2000)
        tied = base * rng.uniform(0.95, 1.05, size=2000)
        clearly_worse = 3 * base
        others = [{"cause": "model_order", "bfr_gain": 4.0}]
        losses = {"friction": base, "model_order": tied}
        assert _structure_first("friction", others, candidates, losses, {"friction", "model_order"}) \
            == "model_order"
        assert _structure_first("friction", others, candidates, losses, {"friction"}) == "none"
        losses["model_order"] = clearly_worse
        assert _structure_first("friction", others, candidates, losses, {"friction", "model_order"}) \
            == "friction"
        # a sensor offset is not a structural fix: friction stays named against it
        losses = {"friction": base, "offset": tied}
        offset_row = [{"cause": "offset", "bfr_gain": 4.0}]
        named = _structure_first("friction", offset_row, candidates, losses, {"friction", "offset"})
        assert named == "friction"
