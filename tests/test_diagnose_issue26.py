"""Diagnosis, issue 26: unexplained, noise judged on its own terms, velocity-output friction,
backlash, sensor saturation, structural choices counted, evidence for every channel.

Synthetic cases of tests/diagnosis_cases.py (one seed each, so that the tests stay fast); hit rates
over ten seeds and the clean controls: benchmarks/bench_diagnose.py (benchmarks/README.md).
"""

import json

import numpy as np
import pytest

from lpvflow.data import Dataset
from lpvflow.identify.arx import identify_arx
from lpvflow.validate import residuals
from lpvflow.validate.diagnose import MATERIAL_CHANGE, diagnose, frozen_response
from tests.diagnosis_cases import NOMINAL, make_case


def test_friction_on_a_velocity_output_is_named_with_its_level():
    """v(k+1) = a(p)v + b(u − F_c sign v), output = velocity, F_c = 0.2: friction on the output
    itself (the issue's case was none: friction was only modelled on the differenced output)."""
    data, channels, expected = make_case("friction_velocity", seed=31)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "friction", result.ranking
    assert result.parameters["output_kind"] == "velocity"
    assert result.parameters["coulomb_level_input_units"] == pytest.approx(expected, rel=0.2)
    assert result.bfr_after[0] > result.bfr_before[0] + 5


def test_backlash_is_named_with_its_width():
    data, channels, expected = make_case("backlash", seed=32)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "backlash", result.ranking
    assert result.parameters["width"] == pytest.approx(expected, rel=0.2)
    gains = {r["cause"]: r["bfr_gain"] for r in result.ranking}
    assert gains["backlash"] > gains["input_nonlinearity"] + 5  # memory matters: not a dead zone


def test_sensor_saturation_is_named_with_its_limits():
    data, channels, limit = make_case("sensor_saturation", seed=33)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "sensor_saturation", result.ranking
    assert result.parameters["upper_limit"] == pytest.approx(limit, rel=0.2)
    assert result.parameters["lower_limit"] == pytest.approx(-limit, rel=0.2)


def test_sensor_saturation_is_untested_on_unclipped_data():
    """Without clipping no output piles up at an extreme: the cause is untested, with the reason."""
    data, channels, _ = make_case("none", seed=34)
    result = diagnose(data, NOMINAL, channels, causes=["sensor_saturation"])
    assert result.untested == ["sensor_saturation"] and result.cause == "none"
    assert "piles up" in result.untested_reasons["sensor_saturation"]


def test_an_effect_outside_the_vocabulary_is_unexplained():
    """An even input map u + 0.8(u² − 1/3): no extension gains, but a correction from the input
    history alone does — the model is not adequate, so the verdict is unexplained, not none."""
    data, channels, _ = make_case("out_of_vocabulary", seed=35)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "unexplained", result.ranking
    assert not any(r["significant"] for r in result.ranking)
    assert result.adequacy["significant"] and result.adequacy["bfr_gain"] > 10
    assert result.parameters["p_value"] < 1e-3
    assert "cause unexplained" in result.summary
    json.dumps(result.to_dict())


@pytest.mark.parametrize("seed", [36, 37])
def test_an_adequate_model_is_none_and_its_error_is_not_input_explained(seed):
    """Right structure, equation noise (inside the model set): none, with the adequacy test as the
    evidence that the simulation error is noise."""
    data, channels, _ = make_case("none", seed=seed, snr_db=20)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "none", result.ranking
    assert not result.adequacy["significant"] and result.adequacy["bfr_gain"] < 1


def test_white_sensor_noise_is_output_noise_bias_with_its_level():
    """White sensor noise of 10 %: LS is biased (material change of the frozen response), the
    output-error refit gains and the noise model is white — output_noise_bias, not colored_noise."""
    data, channels, level = make_case("sensor_noise", seed=38, snr_db=20)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "output_noise_bias", (result.ranking, result.refit_ranking)
    assert result.parameters["relative_noise"] == pytest.approx(level, rel=0.2)
    assert result.noise["biased"] and not result.noise["colored"]
    assert result.parameters["frozen_response_change"] > MATERIAL_CHANGE
    assert "refit by output error" in result.summary
    json.dumps(result.to_dict())


def test_ar2_noise_is_colored_noise_with_its_spectrum():
    """Sensor noise 1/(1 − 1.5q⁻¹ + 0.7q⁻²)·e at 3 dB: simulation BFR barely moves, but the
    AR noise model predicts one step far better than white noise and the LS bias is significant:
    colored_noise, its AR model close to the true one."""
    data, channels, level = make_case("ar2_noise", seed=39, snr_db=3)
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "colored_noise", (result.ranking, result.refit_ranking)
    assert result.parameters["relative_noise"] == pytest.approx(level, rel=0.2)
    ar = np.asarray(result.parameters["ar"])
    assert ar.size >= 2 and ar[:2] == pytest.approx([-1.5, 0.7], abs=0.15)
    spectrum = result.parameters["spectrum"]
    peak = spectrum["frequency_hz"][int(np.argmax(spectrum["psd"]))]
    assert peak == pytest.approx(np.angle(np.roots([1, -1.5, 0.7])[0]) / (2 * np.pi * data.Ts), abs=3.2)
    assert result.noise["prediction_gain"][0] > 10
    assert "coloured output noise (AR order" in result.summary
    json.dumps(result.to_dict())  # the CLI's report: plain JSON types only


@pytest.mark.parametrize("snr_db", [80.0, 10.0])
def test_noise_level_measure_reads_the_snr(snr_db):
    """The noise level from the output-error refit's simulation error: 80 dB and 10 dB read within
    1 dB. The noise share it replaces (LS one-step over OE simulation error) is ≈ 1 + Σaᵢ² whatever
    the level: 2.4–3.1 for 3–10 % white noise on this plant."""
    data, channels, level = make_case("sensor_noise", seed=40, snr_db=snr_db)
    result = diagnose(data, NOMINAL, channels, causes=["output_noise_bias"])
    measured = result.noise["level"]
    assert measured["snr_db"][0] == pytest.approx(snr_db, abs=1.0)
    assert measured["relative_noise"][0] == pytest.approx(level, rel=0.12)
    assert result.noise["biased"] == (snr_db == 10.0)


@pytest.mark.parametrize("level", [0.01, 0.03])
def test_small_white_sensor_noise_gives_none(level):
    """The clean controls: 1–3 % white sensor noise with the right structure is none."""
    data, channels, _ = make_case("sensor_noise", seed=41, snr_db=-20 * np.log10(level))
    result = diagnose(data, NOMINAL, channels)
    assert result.cause == "none", (result.ranking, result.refit_ranking)


def test_structural_choices_count_as_parameters():
    """A chosen delay has the nominal parameter count but is one structural choice: +1 parameter in
    BIC/AIC; a dead-zone width adds one to its fit's."""
    data, channels, _ = make_case("input_delay", seed=42)
    result = diagnose(data, NOMINAL, channels, causes=["input_delay", "input_nonlinearity"])
    rows = {r["cause"]: r for r in result.ranking}
    assert rows["input_delay"]["extra_parameters"] == 1
    assert rows["input_nonlinearity"]["extra_parameters"] == 1


def test_frozen_response_equals_the_realization_frozen_at_p():
    """frozen_response(model, p) is the frequency response of model.to_ss().frozen(p)."""
    data, _, _ = make_case("none", seed=43)
    model = identify_arx(data, 2, 2, 1, "affine")
    rows = np.array([[-0.8], [0.3]])
    g = frozen_response(model, rows, n_freq=8)
    w = np.linspace(np.pi / 8, np.pi, 8)
    for i, p in enumerate(rows):
        ss = model.to_ss().frozen(p)
        ref = np.array([ss(np.exp(1j * wk)) for wk in w]).reshape(8, 1, 1)
        assert g[i] == pytest.approx(ref, rel=1e-8)


def test_ar_noise_model_recovers_an_ar2_process():
    rng = np.random.default_rng(0)
    import scipy.signal

    v = scipy.signal.lfilter([1.0], [1.0, -1.5, 0.7], rng.normal(size=20_000))
    d, s2 = residuals.ar_noise_model(v)
    assert d[:2] == pytest.approx([-1.5, 0.7], abs=0.03) and s2 == pytest.approx(1.0, rel=0.05)
    assert residuals.ar_noise_model(rng.normal(size=20_000))[0].size == 0  # white: order 0


def test_evidence_and_where_cover_every_input_and_scheduling_channel():
    """MIMO evidence: a second input and a second scheduling signal get their own rows."""
    data, _, _ = make_case("none", seed=44)
    rng = np.random.default_rng(1)
    two = Dataset(np.column_stack([data.u, rng.uniform(-1, 1, data.N)]),
                  data.y, np.column_stack([data.p, rng.uniform(-1, 1, data.N)]), data.Ts,
                  ["u", "w"], ["y"], ["p", "s"])
    result = diagnose(two, NOMINAL, causes=["input_delay"])
    where = result.where["outputs"][0]
    assert [r["channel"] for r in where["rms_vs_scheduling"]] == ["p", "s"]
    assert [r["channel"] for r in where["rms_vs_input_amplitude"]] == ["u", "w"]
    features = {e["feature"] for e in result.evidence if e["test"] == "feature_correlation"}
    assert {"|u| (input amplitude)", "|w| (input amplitude)", "p^2 * y(k-1)", "s^2 * y(k-1)"} <= features
    assert {e["input"] for e in result.evidence if e["test"] == "cross_correlation"} == {"u", "w"}
