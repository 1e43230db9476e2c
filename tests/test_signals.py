"""Excitation signals: spectral support, crest factor, m-sequence properties, bounds, seeding."""

import numpy as np
import pytest

from lpvflow.errors import DataError
from lpvflow.experiment import signals
from lpvflow.experiment.specs import generate, parse_spec


def _bins_with_power(x: np.ndarray, rel: float = 1e-20) -> np.ndarray:
    power = np.abs(np.fft.rfft(x)) ** 2
    return np.flatnonzero(power > rel * power.max())


def test_multisine_power_only_on_band_lines():
    Ts, period = 0.01, 1000  # grid df = 0.1 Hz
    x = signals.multisine(3 * period, Ts, f_lo=1.0, f_hi=5.0, period=period, rms=0.5)
    excited = _bins_with_power(x)  # three whole periods -> bins 3k of the 3000-point FFT
    freqs = excited / (len(x) * Ts)
    np.testing.assert_allclose(freqs, np.arange(10, 51) * 0.1, rtol=1e-12)
    assert np.sqrt(np.mean(x**2)) == pytest.approx(0.5, rel=1e-12)
    assert np.mean(x) == pytest.approx(0.0, abs=1e-12)


def test_multisine_peak_scaling_and_periodicity():
    x = signals.multisine(2500, 0.002, f_lo=2.0, f_hi=40.0, period=500, peak=1.5)
    assert np.max(np.abs(x)) == pytest.approx(1.5, rel=1e-12)
    np.testing.assert_array_equal(x[:500], x[500:1000])


def test_schroeder_crest_factor_below_random_phases():
    kw = {"n": 2000, "Ts": 0.01, "f_lo": 0.5, "f_hi": 20.0, "rms": 1.0}
    schroeder = signals.crest_factor(signals.multisine(**kw))
    random = [
        signals.crest_factor(signals.multisine(**kw, phases="random", rng=np.random.default_rng(seed)))
        for seed in range(30)
    ]
    # same amplitude spectrum, only phases differ; Schroeder beats every random draw here
    assert schroeder < min(random)
    assert schroeder < 2.0 < np.median(random)


def test_multisine_band_without_grid_line_is_refused():
    with pytest.raises(DataError, match="holds no line"):
        signals.multisine(100, 0.01, f_lo=0.2, f_hi=0.5, rms=1.0)  # df = 1 Hz


@pytest.mark.parametrize("order", sorted(signals.PRBS_TAPS))
def test_mls_is_maximum_length_with_two_level_autocorrelation(order):
    bits = signals.mls_bits(order, np.random.default_rng(order))
    m = 2**order - 1
    x = 2.0 * bits - 1.0
    circular = np.real(np.fft.ifft(np.abs(np.fft.fft(x)) ** 2))
    # two-level autocorrelation R(0) = M, R(tau) = -1 otherwise: implies the period is exactly M
    assert circular[0] == pytest.approx(m)
    np.testing.assert_allclose(circular[1:], -1.0, atol=1e-6)
    assert bits.sum() == 2 ** (order - 1)


def test_prbs_clock_levels_and_period():
    order, clock = 5, 3
    x = signals.prbs(2 * 31 * clock, order, clock, lo=-0.5, hi=2.0, rng=np.random.default_rng(1))
    assert set(np.unique(x)) == {-0.5, 2.0}
    np.testing.assert_array_equal(x[: 31 * clock], x[31 * clock :])
    held = x.reshape(-1, clock)
    assert np.all(held == held[:, :1])  # every bit held exactly `clock` samples


def _runs(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    edges = np.flatnonzero(np.diff(x)) + 1
    starts = np.r_[0, edges]
    return x[starts], np.diff(np.r_[starts, len(x)])


def test_aprbs_levels_and_hold_times_within_bounds():
    x = signals.aprbs(5000, lo=-2.0, hi=3.0, min_hold=4, max_hold=25, rng=np.random.default_rng(7))
    levels, holds = _runs(x)
    assert np.all((levels >= -2.0) & (levels <= 3.0))
    assert np.all(holds[:-1] >= 4) and np.all(holds <= 25)  # the last hold may be cut by n
    assert holds[:-1].min() == 4 and holds.max() == 25  # both ends of the range are used
    assert levels.max() - levels.min() > 4.5  # the levels spread over the range


def test_random_levels_ramp_bounds_the_rate():
    lo, hi, ramp = 800.0, 6000.0, 10
    x = signals.random_levels(4000, lo, hi, 50, 200, np.random.default_rng(3), ramp=ramp)
    assert x.min() >= lo and x.max() <= hi
    assert np.max(np.abs(np.diff(x))) <= (hi - lo) / ramp + 1e-9
    assert np.max(np.abs(np.diff(x))) > 0


@pytest.mark.parametrize(
    "text",
    [
        "multisine:f_lo=0.1,f_hi=5,rms=0.2,period=10",
        "multisine:f_lo=0.1,f_hi=5,peak=1,phases=random",
        "prbs:order=7,clock=0.03,amp=1,offset=2",
        "aprbs:lo=0,hi=1,min_hold=0.1,max_hold=0.5",
        "levels:lo=1000,hi=5000,min_hold=1,max_hold=3,ramp=0.5",
    ],
)
def test_specs_are_deterministic_by_seed(text):
    spec = parse_spec(text)
    a = generate(spec, 2000, 0.01, np.random.default_rng(11))
    b = generate(spec, 2000, 0.01, np.random.default_rng(11))
    c = generate(spec, 2000, 0.01, np.random.default_rng(12))
    np.testing.assert_array_equal(a, b)
    if spec.kind != "multisine" or spec.params.get("phases") == "random":
        assert not np.array_equal(a, c)


def test_spec_offset_and_seconds_to_samples():
    spec = parse_spec("prbs:order=3,clock=0.05,amp=0.5")
    x = generate(spec, 70, 0.01, np.random.default_rng(0), offset=3.0)
    assert set(np.unique(x)) == {2.5, 3.5}
    assert np.all(x.reshape(-1, 5) == x.reshape(-1, 5)[:, :1])  # clock 0.05 s = 5 samples


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("chirp:f=1", "unknown kind"),
        ("multisine:f_lo=1", "needs f_hi"),
        ("multisine:f_lo=1,f_hi=2,rms=x", "is not a number"),
        ("prbs:order=7,clock=0.03,amp=1,speed=3", "does not take speed"),
        ("aprbs:lo=0,hi=1,min_hold", "is not key=value"),
        ("aprbs:lo=0,lo=1,hi=1,min_hold=1,max_hold=2", "given twice"),
    ],
)
def test_malformed_specs_are_refused(text, message):
    with pytest.raises(DataError, match=message):
        parse_spec(text)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("prbs:order=7,clock=0.015,amp=1", "multiple of Ts"),
        ("prbs:order=40,clock=0.01,amp=1", "not tabulated"),
        ("aprbs:lo=2,hi=1,min_hold=0.1,max_hold=0.2", "lo <= hi"),
        ("aprbs:lo=0,hi=1,min_hold=0.3,max_hold=0.2", "max_hold"),
        ("multisine:f_lo=1,f_hi=2", "exactly one of rms= or peak="),
        ("multisine:f_lo=1,f_hi=2,rms=1,phases=flat", "phases"),
        ("levels:lo=0,hi=1,min_hold=0.1,max_hold=0.2,ramp=0.1", "shorter than min_hold"),
    ],
)
def test_invalid_spec_values_name_the_spec(text, message):
    with pytest.raises(DataError, match=message) as info:
        generate(parse_spec(text), 500, 0.01, np.random.default_rng(0))
    assert text in str(info.value) and "\n" not in str(info.value)
